"""Polynomial assumed shapes φ_k = (x/L)^(k+1), k = 1..count (seed 000 §3.5.2).

They satisfy only the geometric root conditions φ(0) = φ'(0) = 0, which is all the Ritz method needs.
Monomials grow ill-conditioned as count grows (the Gram matrix is a Hilbert-like matrix): a handful of
them is the intended use.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial.legendre import leggauss

from .base import ShapeBasis


class PolynomialBasis(ShapeBasis):
    """Polynomial shape functions of a clamped link (``shapes.kind = "polynomial"``, docs/scene.md)."""

    kind = "polynomial"

    def __init__(self, count: int, length: float, linear_density: float = 1.0):
        super().__init__(count, length, linear_density)
        self.powers = np.arange(2, self.count + 2)

    @property
    def n(self) -> int:
        """The number of shape functions."""
        return self.count

    def _evaluate(self, x: np.ndarray, derivative: int) -> np.ndarray:
        p = self.powers
        k = derivative
        # p!/(p−k)! as a falling factorial; zero once the derivative exceeds the degree.
        coef = np.ones(p.shape)
        for j in range(k):
            coef = coef * (p - j)
        exponent = np.maximum(p - k, 0)
        xi = (x / self.length)[:, None]
        return coef * xi**exponent / self.length**k

    def _quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        # Highest degree: φ'φ'ᵀ (L² − x²)/2 and φφᵀ, both 2·count + 2; m points are exact to 2m − 1.
        m = self.count + 2
        t, wt = leggauss(m)
        half = 0.5 * self.length
        return half * (t + 1.0), half * wt
