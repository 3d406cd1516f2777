"""Assumed shapes of the twist α(x) = φ(x)ᵀ η of a root-clamped link (docs/mechanics.md).

Torsion is a second-order field (GJ α'' = ρI_p α̈): the shapes need only φ(0) = 0.

* ``"clamped-free"``: the torsion eigenfunctions sin((2i−1)πx/2L), normalised so that
  ∫ μ φ_i φ_j = δ_ij for the polar mass moment μ = ρI_p given (or ∫φ² = 1 when μ = 0);
* ``"polynomial"``: (x/L)^k, k = 1..count;
* ``"fe"``: linear elements, count elements, root node clamped (count coordinates, node by node).

Integrals are for unit μ and unit GJ, exact by Gauss–Legendre quadrature.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt
from numpy.polynomial.legendre import leggauss

KINDS = ("clamped-free", "polynomial", "fe")


@dataclass(frozen=True)
class TorsionIntegrals:
    """Constant integrals of the twist shapes for unit polar mass moment and unit GJ (multiply later).

    They are all the torsion field adds to the Lagrangian: kinetic ½ η̇ᵀ(μ ∫φφᵀ)η̇, strain ½ ηᵀ(GJ ∫φ'φ'ᵀ)η,
    and the tip twist that carries the next joint's frame.
    """

    phi_phi: np.ndarray       # ∫ φ φᵀ dx
    phi: np.ndarray           # ∫ φ dx
    stiff: np.ndarray         # ∫ φ' φ'ᵀ dx
    tip: np.ndarray           # φ(L)


class TorsionBasis:
    """Assumed shapes α(x) = φ(x)ᵀ η of the twist of one root-clamped link, of one of the three ``KINDS``.

    Torsion is second order in x, so only φ(0) = 0 is imposed and linear elements are conforming; the
    eigenfunctions are scaled by ``polar_inertia`` so that their mass matrix is the identity.
    """

    def __init__(self, kind: str, count: int, length: float, polar_inertia: float = 0.0):
        if kind not in KINDS:
            raise ValueError(f"unknown shape kind {kind!r}: expected one of {', '.join(map(repr, KINDS))}")
        if int(count) != count or count < 1:
            raise ValueError(f"count must be a positive integer, got {count!r}")
        self.kind, self.count, self.length = kind, int(count), float(length)
        self.scale = 1.0 / np.sqrt(polar_inertia * length / 2) if polar_inertia > 0 else np.sqrt(2.0 / length)

    @property
    def n(self) -> int:
        """Number of twist coordinates η: one per shape (per node for ``"fe"``)."""
        return self.count

    def evaluate(self, x: npt.ArrayLike, derivative: int = 0) -> np.ndarray:
        """d^k φ/dx^k (k = ``derivative``) at the points ``x``, shape (len(x), n).

        The linear elements' second and higher derivatives are zero inside the elements (their jumps
        at the nodes are never integrated), and their slope at a node is that of the element on its left.
        """
        x = np.atleast_1d(np.asarray(x, dtype=float))
        L, n = self.length, self.count
        if self.kind == "clamped-free":
            k = (2 * np.arange(1, n + 1) - 1) * np.pi / (2 * L)
            arg = np.outer(x, k)
            phases: list[Callable[[np.ndarray], np.ndarray]] = [
                np.sin, np.cos, lambda a: -np.sin(a), lambda a: -np.cos(a)]
            phase = phases[derivative % 4]
            return self.scale * phase(arg) * k**derivative
        if self.kind == "polynomial":
            p = np.arange(1, n + 1)
            coef = np.ones(n)
            for j in range(derivative):
                coef = coef * (p - j)
            return coef * (x[:, None] / L) ** np.maximum(p - derivative, 0) / L**derivative * (p >= derivative)
        h = L / n                                           # fe: hat functions on nodes 1..n
        nodes = h * np.arange(1, n + 1)
        d = (x[:, None] - nodes[None, :]) / h
        if derivative == 0:
            hat = np.clip(1 - np.abs(d), 0, None)
            hat[:, -1] = np.where(d[:, -1] <= 0, hat[:, -1], 0.0)   # the last node is the free end
            return hat
        if derivative == 1:
            left = (d > -1) & (d <= 0)
            right = (d > 0) & (d < 1)
            slope = np.where(left, 1 / h, 0.0) + np.where(right, -1 / h, 0.0)
            slope[:, -1] = np.where(left[:, -1], 1 / h, 0.0)
            return slope
        return np.zeros((len(x), n))

    @cached_property
    def integrals(self) -> TorsionIntegrals:
        """The :class:`TorsionIntegrals`, by Gauss–Legendre quadrature exact for each kind, computed once.

        The elements are integrated element by element at interior points only, so that the slope,
        discontinuous at the nodes, is always taken on the element that holds the point.
        """
        L = self.length
        if self.kind == "fe":
            edges = np.linspace(0.0, L, self.count + 1)
            pts = 3
        else:
            edges = np.linspace(0.0, L, max(2, self.count + 1) if self.kind == "clamped-free" else 2)
            pts = 2 * self.count + 4
        t, w = leggauss(pts)
        xs, ws = [], []
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            xs.append(0.5 * (b - a) * (t + 1) + a)
            ws.append(0.5 * (b - a) * w)
        x, wt = np.concatenate(xs), np.concatenate(ws)
        # interior points only: the FE slope is taken on the element that holds the point
        P, D = self.evaluate(x), self.evaluate(x, 1)
        return TorsionIntegrals(phi_phi=(P * wt[:, None]).T @ P, phi=wt @ P, stiff=(D * wt[:, None]).T @ D,
                                tip=self.evaluate([L])[0])


def make_torsion_basis(kind: str, count: int, length: float, polar_inertia: float = 0.0) -> TorsionBasis:
    """The twist basis of a link's ``shapes`` table: ``kind`` and ``count`` as the scene gives them (docs/scene.md).

    ``polar_inertia`` is the polar mass moment per length ρI_p (kg m), 0 when the scene leaves it out.
    """
    return TorsionBasis(kind, count, length, polar_inertia)
