"""Common interface of the shape families and the constant integrals the Lagrangian needs.

Every family reduces its integrals to one quadrature rule ``(x, w)`` that is exact (or converged to
machine precision) for its integrands; :func:`integrals_from_rule` then forms all of them with a few
dense matrix products, so they are computed once, offline, and never at simulation time.
"""

from __future__ import annotations

import abc
import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from numpy.polynomial.legendre import leggauss


@dataclass(frozen=True)
class ShapeIntegrals:
    """Constant integrals for UNIT linear density and UNIT stiffness (multiply by ρ, EI later).

    The arrays are read-only: they are cached on the basis and shared by every model built from it.
    """

    phi: np.ndarray  # (n,)   ∫ φ dx
    x_phi: np.ndarray  # (n,)   ∫ x φ dx
    phi_phi: np.ndarray  # (n,n)  ∫ φ φᵀ dx
    curv: np.ndarray  # (n,n)  ∫ φ'' φ''ᵀ dx
    fs: np.ndarray  # (n,n)  ∫₀ᴸ ∫₀ˣ φ'φ'ᵀ dξ dx   (foreshortening u(x) = −½ ηᵀ[∫₀ˣ φ'φ'ᵀ dξ]η)
    fs_x: np.ndarray  # (n,n)  ∫₀ᴸ x ∫₀ˣ φ'φ'ᵀ dξ dx
    fs_tip: np.ndarray  # (n,n)  ∫₀ᴸ φ'φ'ᵀ dx          (u(L))
    tip: np.ndarray  # (n,)   φ(L)
    tip_slope: np.ndarray  # (n,)   φ'(L)
    root_curvature: np.ndarray  # (n,) φ''(0)


class ShapeBasis(abc.ABC):
    """Assumed shapes φ(x) of one clamped-root link, v(x, t) = φ(x)ᵀ η(t), 0 ≤ x ≤ L."""

    kind: str = ""

    def __init__(self, count: int, length: float, linear_density: float = 1.0):
        self.count = _check_count(count)
        self.length = _check_positive(length, "length")
        self.linear_density = _check_positive(linear_density, "linear_density")

    @property
    @abc.abstractmethod
    def n(self) -> int:
        """Number of generalized coordinates η."""

    @abc.abstractmethod
    def _evaluate(self, x: np.ndarray, derivative: int) -> np.ndarray:
        """d^k φ/dx^k at the (validated, 1-D) points x, shape (len(x), n)."""

    @abc.abstractmethod
    def _quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        """Nodes and weights on [0, L] exact (or converged) for every integrand of ShapeIntegrals."""

    def evaluate(self, x: npt.ArrayLike, derivative: int = 0) -> np.ndarray:
        """d^k φ/dx^k (k = ``derivative``) at the points ``x`` in [0, L]; shape (len(x), n)."""
        if isinstance(derivative, bool) or not isinstance(derivative, (int, np.integer)) or derivative < 0:
            raise ValueError(f"derivative must be a non-negative integer, got {derivative!r}")
        xs = np.atleast_1d(np.asarray(x, dtype=float)).ravel()
        # Round-off of callers' grids (e.g. k*L/N) must not make x = L fail.
        slack = 1e-12 * self.length
        if xs.size and (not np.all(np.isfinite(xs)) or xs.min() < -slack or xs.max() > self.length + slack):
            raise ValueError(f"x must lie in [0, L] = [0, {self.length:g}]")
        return self._evaluate(np.clip(xs, 0.0, self.length), int(derivative))

    @functools.cached_property
    def integrals(self) -> ShapeIntegrals:
        """The constant integrals of this basis, computed once from its quadrature rule and cached.

        Every model built from the basis shares them, which is why the arrays are read-only.
        """
        x, w = self._quadrature()
        return integrals_from_rule(self, x, w)

    def panel_edges(self) -> np.ndarray:
        """Edges of the intervals on which φ is smooth (one interval, cut in 8 panels, unless piecewise)."""
        return np.linspace(0.0, self.length, 9)

    def nodal_basis(self) -> tuple[ShapeBasis, np.ndarray] | None:
        """A local basis and the matrix Ψ with φ = (its shapes) Ψ, when this basis is a reduction of one.

        The point rule then evaluates the fields through the local shapes (:class:`Factorisation`).
        """
        return None

    @functools.cached_property
    def points(self) -> PointRule:
        """The material points of the second-order kinematics (:func:`point_rule`), computed once and cached."""
        return point_rule(self)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(count={self.count}, length={self.length:g}, n={self.n})"


def prune_rounding(gram: np.ndarray, terms: int) -> np.ndarray:
    """A Gram matrix Σ_k w_k a_k a_kᵀ (w ≥ 0) with the entries that are rounding noise set to exactly 0.

    Why: modes orthogonal in mass or stiffness have off-diagonal integrals of 1e-17 instead of 0, and every
    such entry becomes an operation in every generated function (issue 22: 37 % of a residual's constants).
    The rule: an entry is noise when it is within the rounding bound of its own sum, (``terms`` + 2) ε
    √(G_ii G_jj) (the floating-point error of a sum of ``terms`` products of three factors is at most
    γ_{terms+2} Σ|w_k a_ik a_jk|, itself at most √(G_ii G_jj) by Cauchy–Schwarz), so no entry that the
    quadrature could tell from zero is dropped.
    """
    d = np.sqrt(np.clip(np.diag(gram), 0.0, None))
    noise = np.abs(gram) <= (terms + 2) * np.finfo(float).eps * np.outer(d, d)
    np.fill_diagonal(noise, False)
    return np.where(noise, 0.0, gram)


def integrals_from_rule(basis: ShapeBasis, x: np.ndarray, w: np.ndarray) -> ShapeIntegrals:
    """All ShapeIntegrals from one quadrature rule.

    The double integrals are turned into single ones by swapping the order of integration,
    ∫₀ᴸ f(x) ∫₀ˣ g(ξ) dξ dx = ∫₀ᴸ g(ξ) ∫_ξᴸ f(x) dx dξ, i.e. weights (L − ξ) for ``fs`` and
    (L² − ξ²)/2 for ``fs_x``: this accumulates the contributions of all earlier elements exactly and
    only raises the polynomial degree by 2.
    """
    length = basis.length
    phi0 = basis.evaluate(x, 0)
    phi1 = basis.evaluate(x, 1)
    phi2 = basis.evaluate(x, 2)

    def gram(a: np.ndarray, weights: np.ndarray) -> np.ndarray:
        m = a.T @ (weights[:, None] * a)
        m = 0.5 * (m + m.T)  # exactly symmetric for eigh, Cholesky and the symbolic model
        return prune_rounding(m, x.size)

    ends = np.array([0.0, length])
    fields = dict(
        phi=w @ phi0,
        x_phi=(w * x) @ phi0,
        phi_phi=gram(phi0, w),
        curv=gram(phi2, w),
        fs=gram(phi1, w * (length - x)),
        fs_x=gram(phi1, w * 0.5 * (length**2 - x**2)),
        fs_tip=gram(phi1, w),
        tip=basis.evaluate(ends[1:], 0)[0],
        tip_slope=basis.evaluate(ends[1:], 1)[0],
        root_curvature=basis.evaluate(ends[:1], 2)[0],
    )
    for value in fields.values():
        value.setflags(write=False)
    return ShapeIntegrals(**fields)


@dataclass(frozen=True)
class Factorisation:
    """φ and φ' at a rule's points as ``local @ modal``: sparse local shapes of nodal coordinates, dense modes.

    A reduced finite-element basis (:class:`~flexlink.mechanics.shapes.reduction.ModalBeamBasis`) is
    piecewise cubic: at each point only the four nodal coordinates of its element count.  Forming the
    nodal values ``modal @ η`` once (N·n operations) and then the points from them (4 per point) costs
    far less than the dense ``phi @ η`` (K·n) when the modes are many: the point fields then cost N·n + 4K,
    not K·n (issue 15, docs/performance.md).
    """

    phi: np.ndarray      # (K, N)  nodal shapes at the points (4 non-zeros a row for Hermite elements)
    slope: np.ndarray    # (K, N)
    modal: np.ndarray    # (N, n)  the modes in nodal coordinates


@dataclass(frozen=True)
class PointRule:
    """Material points of a link and their weights, with what the foreshortened field needs at each.

    With second-order kinematics a point at x moves to s(x) = (x + u, v, w), u(x) = −½ ∫₀ˣ (v'² + w'²) dξ.
    The points are Gauss points on panels; u at them is the integral of the squared slopes *at the same
    points*: within a panel the integral from the panel's start of the polynomial through its points (the
    Gauss integration matrix), plus the Gauss sums of the earlier panels, exact for
    the piecewise-polynomial finite-element shapes, converged for the others.  Integrals over the link
    become sums Σ_k w_k f(s(x_k)): the kinetic energy is then a sum of squares, so its mass matrix is
    positive semi-definite for every deflection.
    """

    x: np.ndarray     # (K,)     points
    w: np.ndarray     # (K,)     weights
    phi: np.ndarray   # (K, n)   φ(x_k)
    slope: np.ndarray  # (K, n)  φ'(x_k)
    local: np.ndarray   # (K, K)  block diagonal: ∫ from the panel's start to x_k of the panel's polynomial
    panel_sums: np.ndarray   # (P, K)  the Gauss sum over each panel
    start: np.ndarray   # (K, P)  1 where panel p lies wholly before x_k: ∫₀^{x_k} f = local f + start (panel_sums f)
    factor: Factorisation | None = None   # phi and slope as sparse local values of a few nodal fields


#: Gauss points per panel of the point rule: the integration matrix is exact for v'² of cubic elements
#: (degree 4) and the weights for u² and u̇² (degree 10) to degree 11.
POINT_RULE_ORDER = 6


def gauss_integration_matrix(order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes t, weights w on [−1, 1] and S with S_ij = ∫_{−1}^{t_i} ℓ_j (ℓ_j: Lagrange basis)."""
    t, w = np.polynomial.legendre.leggauss(order)
    V = np.vander(t, order, increasing=True)                  # V_ij = t_i^j
    powers = np.arange(1, order + 1)
    integrals = (t[:, None] ** powers - (-1.0) ** powers) / powers   # ∫_{−1}^{t_i} τ^j dτ
    return t, w, integrals @ np.linalg.inv(V)


def point_rule(basis: ShapeBasis, order: int = POINT_RULE_ORDER) -> PointRule:
    """The :class:`PointRule` of a basis: ``order`` Gauss points on each of its panels."""
    edges = np.asarray(basis.panel_edges(), dtype=float)
    t, wt, S = gauss_integration_matrix(order)
    half = 0.5 * np.diff(edges)
    x = ((0.5 * (edges[:-1] + edges[1:]))[:, None] + half[:, None] * t[None, :]).ravel()
    w = (half[:, None] * wt[None, :]).ravel()
    P = half.size
    local = np.zeros((x.size, x.size))
    panel_sums = np.zeros((P, x.size))
    start = np.zeros((x.size, P))
    for p, h in enumerate(half):
        rows = slice(p * order, (p + 1) * order)
        local[rows, rows] = h * S                          # this panel, up to each point
        panel_sums[p, rows] = w[rows]
        start[rows, :p] = 1.0                              # the earlier panels, whole
    nodal = basis.nodal_basis()
    factor = None if nodal is None else Factorisation(nodal[0].evaluate(x, 0), nodal[0].evaluate(x, 1), nodal[1])
    return PointRule(x, w, basis.evaluate(x, 0), basis.evaluate(x, 1), local, panel_sums, start, factor)


def composite_gauss_legendre(edges: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre rule with ``order`` points on each interval [edges[i], edges[i+1]]."""
    t, wt = leggauss(order)
    a, b = np.asarray(edges[:-1], dtype=float), np.asarray(edges[1:], dtype=float)
    half = 0.5 * (b - a)
    x = (0.5 * (a + b))[:, None] + half[:, None] * t[None, :]
    w = half[:, None] * wt[None, :]
    return x.ravel(), w.ravel()


def _check_count(count: object) -> int:
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)):
        raise ValueError(f"shape count must be an integer >= 1, got {count!r}")
    if count < 1:
        raise ValueError(f"shape count must be >= 1, got {count}")
    return int(count)


def _check_positive(value: Any, name: str) -> float:  # Any: it validates whatever the caller was given
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not (np.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v
