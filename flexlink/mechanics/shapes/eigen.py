"""Clamped–free (cantilever) beam eigenfunctions, mass-normalised, evaluated without cancellation.

φ_i = a_i [sin z − sinh z + c_i (cos z − cosh z)], z = λ_i x/L, cos λ cosh λ + 1 = 0,
c_i = −(sin λ_i + sinh λ_i)/(cos λ_i + cosh λ_i).

Written naively, sinh z and c cosh z are both ~e^λ/2 at the tip and cancel: at λ_12 ≈ 36 the
round-off is ~e^36·1e-16 ≈ 0.2 of an O(1) result (11 % measured near the tip). Splitting the
hyperbolic part into exponentials,

    sinh z + c cosh z = A e^z − B e^{−z},  A = (1 + c)/2,  B = (1 − c)/2,

with 1 + c = (cos λ − sin λ + e^{−λ})/(cos λ + cosh λ) (no cancellation at the roots, where
|sin λ| ≈ 1) and A e^z = Q e^{z−λ}, Q = (cos λ − sin λ + e^{−λ})/(1 + 2 cos λ e^{−λ} + e^{−2λ}), leaves
only O(1) terms, and no cosh λ ever appears (so nothing overflows for any mode count).
"""

from __future__ import annotations

import math

import numpy as np

from .base import ShapeBasis, composite_gauss_legendre

_GL_ORDER = 16
# Panel width in units of z: each panel spans at most this many radians of the highest mode, where a
# 16-point rule is already exact to round-off (error ~ 2^32/32! for the products of two modes).
_PANEL_RADIANS = 2.0


def _sech(x: float) -> float:
    e = math.exp(-x)
    return 2.0 * e / (1.0 + e * e)


def clamped_free_roots(count: int) -> np.ndarray:
    """First ``count`` roots of cos λ cosh λ + 1 = 0, ascending.

    Solved as cos λ + sech λ = 0, which stays O(1) and well conditioned for every root; root i lies
    in ((i−1)π, iπ), where the function changes sign exactly once.  Bisected to adjacent floats, not with
    scipy's ``brentq``: importing ``scipy.optimize`` costs a command that builds a model about 0.2 s
    (issue 22's start-up), and 60 halvings of 32 brackets cost nothing.
    """
    return np.array([_bisect(lambda lam: math.cos(lam) + _sech(lam), (i - 1) * math.pi, i * math.pi)
                     for i in range(1, count + 1)])


def _bisect(f, lo: float, hi: float) -> float:
    """The sign change of ``f`` in [lo, hi] (one, signs opposite at the ends) to adjacent floats."""
    f_lo, f_hi = f(lo), f(hi)
    if f_lo == 0.0 or f_hi == 0.0:
        return lo if f_lo == 0.0 else hi
    if (f_lo < 0.0) == (f_hi < 0.0):
        raise ValueError(f"no sign change of f in [{lo!r}, {hi!r}]")
    while True:
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:                   # lo and hi adjacent floats
            return lo if abs(f_lo) <= abs(f(hi)) else hi
        f_mid = f(mid)
        if f_mid == 0.0:
            return mid
        if (f_mid < 0.0) == (f_lo < 0.0):
            lo, f_lo = mid, f_mid
        else:
            hi = mid


class ClampedFreeBasis(ShapeBasis):
    """Cantilever eigenfunctions: ∫ρ0 φ_i φ_j dx = δ_ij, ∫φ_i''φ_j'' dx = (λ_i/L)^4/ρ0 δ_ij."""

    kind = "clamped-free"

    def __init__(self, count: int, length: float, linear_density: float = 1.0):
        super().__init__(count, length, linear_density)
        lam = clamped_free_roots(self.count)
        e = np.exp(-lam)
        cos, sin = np.cos(lam), np.sin(lam)
        q = (cos - sin + e) / (1.0 + 2.0 * cos * e + e * e)
        c = 2.0 * q * e - 1.0  # 1 + c = 2 Q e^{−λ}, tiny for high modes and kept exact this way
        self.lambdas = lam
        self.c = c
        self._q = q  # A e^z = Q e^{z−λ}
        self._b = 1.0 - q * e  # B = (1 − c)/2
        # ∫₀ᴸ (sin z − sinh z + c(cos z − cosh z))² dx = c² L (it is −c times the classical
        # cosh − cos − σ(sinh − sin) mode whose square integrates to L), hence a_i:
        self.amplitude = 1.0 / (np.abs(c) * math.sqrt(self.linear_density * self.length))

    @property
    def n(self) -> int:
        """The number of shape functions."""
        return self.count

    def _evaluate(self, x: np.ndarray, derivative: int) -> np.ndarray:
        lam = self.lambdas
        z = np.outer(x / self.length, lam)
        s, co = np.sin(z), np.cos(z)
        # d^k/dz^k of (sin z + c cos z): the derivative cycle, without phase-shift round-off.
        trig = [(s, co), (co, -s), (-s, -co), (-co, s)][derivative % 4]
        sign_b = -1.0 if derivative % 2 else 1.0
        value = (
            trig[0]
            + self.c * trig[1]
            - self._q * np.exp(z - lam)  # −A e^z
            + sign_b * self._b * np.exp(-z)  # +(−1)^k B e^{−z}
        )
        return value * (self.amplitude * (lam / self.length) ** derivative)

    def panel_edges(self) -> np.ndarray:
        """The edges of the quadrature panels along the link (m)."""
        # about one radian of the highest mode per panel: the point rule's integrands (u², u̇²) oscillate 4×
        return np.linspace(0.0, self.length, max(4, math.ceil(self.lambdas[-1])) + 1)

    def _quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        panels = max(2, math.ceil(self.lambdas[-1] / _PANEL_RADIANS))
        return composite_gauss_legendre(np.linspace(0.0, self.length, panels + 1), _GL_ORDER)
