"""Cubic Hermite beam finite elements (seed 001 part 4, bending only, inextensible axis), root clamped.

``count`` equal elements; coordinates node by node, η = (w_1, θ_1, w_2, θ_2, …, w_N, θ_N), θ = dv/dx,
node 0 (the root) clamped and therefore absent. The global shape functions are the assembled element
functions, so φ is C¹ and piecewise cubic; φ'' and φ''' jump at the nodes (evaluated from the element on
the right, except at x = L).
"""

from __future__ import annotations

import numpy as np

from .base import ShapeBasis, composite_gauss_legendre

# Local Hermite functions on s ∈ [0, 1] as cubic coefficients (constant first) of
# N1 = 1 − 3s² + 2s³, N2/h = s − 2s² + s³, N3 = 3s² − 2s³, N4/h = −s² + s³.
_HERMITE = np.array(
    [
        [1.0, 0.0, -3.0, 2.0],
        [0.0, 1.0, -2.0, 1.0],
        [0.0, 0.0, 3.0, -2.0],
        [0.0, 0.0, -1.0, 1.0],
    ]
)
# Every integrand is a polynomial of degree ≤ 6 on an element (φφᵀ, and φ'φ'ᵀ times (L² − x²)/2):
# 4 Gauss points per element are exact to degree 7.
_GL_ORDER = 4


def _hermite_derivative(s: np.ndarray, k: int) -> np.ndarray:
    """d^k N/ds^k of the four local functions (N2, N4 without their factor h), shape (len(s), 4)."""
    coef = _HERMITE.copy()
    for _ in range(k):
        coef = np.concatenate([coef[:, 1:] * np.arange(1, coef.shape[1]), np.zeros((4, 1))], axis=1)
    powers = s[:, None] ** np.arange(4)[None, :]
    return powers @ coef.T


class HermiteFEBasis(ShapeBasis):
    """Clamped-root cubic Hermite beam elements: C¹ piecewise-cubic shapes, converging as the mesh is refined.

    Unlike the eigenfunction and polynomial families, the shapes are local, so the mass and stiffness
    integrals are banded and the quadrature is exact element by element (degree ≤ 7 with 4 Gauss points).
    """

    kind = "fe"

    @property
    def n(self) -> int:
        """Two coordinates (deflection and slope) per node, the clamped root excluded."""
        return 2 * self.count

    @property
    def element_length(self) -> float:
        """The length h of each of the ``count`` equal elements (m)."""
        return self.length / self.count

    def _evaluate(self, x: np.ndarray, derivative: int) -> np.ndarray:
        h = self.element_length
        t = x / h
        # A node given as k·L/N may land a rounding error below k: snap it, so that φ'' and φ''' at a
        # node always come from the element on its right.
        nearest = np.rint(t)
        t = np.where(np.abs(t - nearest) < 1e-9, nearest, t)
        element = np.minimum(np.floor(t).astype(int), self.count - 1)
        s = t - element
        local = _hermite_derivative(s, derivative) * np.array([1.0, h, 1.0, h]) / h**derivative
        out = np.zeros((x.size, self.n))
        rows = np.arange(x.size)
        # Right node (element + 1) is global node index element, columns 2e and 2e + 1.
        out[rows, 2 * element] = local[:, 2]
        out[rows, 2 * element + 1] = local[:, 3]
        # Left node (element) exists only off the clamped root.
        inner = element >= 1
        left = 2 * (element[inner] - 1)
        out[rows[inner], left] = local[inner, 0]
        out[rows[inner], left + 1] = local[inner, 1]
        return out

    def _quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        return composite_gauss_legendre(self.panel_edges(), _GL_ORDER)

    def panel_edges(self) -> np.ndarray:
        """The element nodes: the second and third derivatives jump there, so each element is one panel."""
        return np.linspace(0.0, self.length, self.count + 1)
