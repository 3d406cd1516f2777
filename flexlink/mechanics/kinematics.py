"""Positions and velocities of the sections of a flexible link, to first or second order.

A link lies along +x of its joint frame; in-plane bending v is along ``axis × x``, out-of-plane bending
w along ``axis``, torsion α about x.  The section at abscissa x sits at ``s(x) = (x + u(x), v(x), w(x))``
in the link's basis ``(e_x, e_v, e_axis)``.  First-order kinematics keep ``u = 0``; second-order
kinematics add the foreshortening ``u = −½∫₀ˣ (v'² + w'²) dξ`` (seed 000 §2.5, eq. 3.32), which is what
brings the geometric stiffening.  The tip frame is the link frame turned by the tip rotation
ψ = (α(L), −w'(L), v'(L)) (seed 000 §2.4).

Everything the kinetic and gravitational energies need from the distributed mass is a handful of
*inertia invariants* — ∫ρs, ∫ρssᵀ, ∫ρ s×ṡ, ∫ρ|ṡ|² — polynomials in η with the constant shape integrals
as coefficients (seed 000 §3.4.2), built as matrix operations on constant ``DM`` blocks so that the
symbolic expressions stay small whatever the number of shape functions.  Terms of order three and more
in η are left out: no model keeps them (docs/mechanics.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TypeVar

import casadi as ca
import numpy as np
import numpy.typing as npt

from flexlink.mechanics.points import PointIntegration, PointShapes
from flexlink.mechanics.shapes import ShapeIntegrals
from flexlink.mechanics.shapes.base import PointRule
from flexlink.mechanics.shapes.body import BodyIntegrals
from flexlink.mechanics.shapes.torsion import TorsionIntegrals

#: A CasADi matrix of any kind: numeric (DM) or symbolic (SX, MX); skew() keeps the kind it is given.
Matrix = TypeVar("Matrix", ca.DM, ca.SX, ca.MX)
#: A symbolic scalar that is a plain number when the field it comes from is absent (a rigid direction).
Scalar = ca.MX | float
#: A factor of the foreshortening sums Σ w a b: a field at the points, absent (None), or named ("u", "u_dot")
#: when the sums come from ForeshorteningTensors.
Factor = ca.MX | ca.DM | str | None


#: The base's frame as the first joint's parent (R, Ṙ, ω, V): fixed, at rest.
BASE_FRAME = (ca.DM.eye(3), ca.DM.zeros(3, 3), ca.DM.zeros(3), ca.DM.zeros(3))


def link_basis(axis: npt.ArrayLike) -> np.ndarray:
    """Columns e_x, e_v = axis × e_x, e_axis of a link's frame, in its joint's parent frame."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    ex = np.array([1.0, 0.0, 0.0])
    return np.column_stack([ex, np.cross(a, ex), a])


def skew(w: Matrix) -> Matrix:
    """The cross-product matrix [w×] of a 3-vector, so that [w×] y = w × y (also for numbers, as a DM)."""
    return ca.vertcat(ca.horzcat(0, -w[2], w[1]), ca.horzcat(w[2], 0, -w[0]), ca.horzcat(-w[1], w[0], 0))


def rotation(axis: npt.ArrayLike, angle: ca.MX) -> ca.MX:
    """Rotation by ``angle`` about the unit vector ``axis`` (Rodrigues)."""
    a = ca.DM(np.asarray(axis, dtype=float) / np.linalg.norm(axis))
    K = skew(a)
    return ca.DM.eye(3) + ca.sin(angle) * K + (1 - ca.cos(angle)) * ca.mtimes(K, K)


def small_rotation(psi: ca.MX, second_order: bool) -> ca.MX:
    """The tip rotation by the small rotation vector ψ: I + [ψ×] (first order), + ½[ψ×]² (second)."""
    K = skew(psi)
    R = ca.DM.eye(3) + K
    return R + 0.5 * ca.mtimes(K, K) if second_order else R


def _dm(a: npt.ArrayLike) -> ca.DM:
    """A constant block of the model: the numbers enter the expressions as one dense DM, not as scalars."""
    return ca.DM(np.asarray(a, dtype=float))


def _quad(x: ca.MX, matrix: np.ndarray, y: ca.MX | None = None) -> ca.MX:
    """The quadratic (bilinear when ``y`` is given) form xᵀ matrix y with a constant matrix."""
    y = x if y is None else y
    return ca.dot(x, ca.mtimes(ca.sparsify(_dm(matrix)), y))     # exact zeros (diagonal mode integrals) skipped


def _rate(eta_dot: ca.MX | None) -> ca.MX:
    """The rate of a field the caller has found present: LinkDeformation holds a field and its rate, or neither."""
    assert eta_dot is not None, "a field's rate is set with the field (ChainAssembly.deformation)"
    return eta_dot


@dataclass
class LinkDeformation:
    """The elastic coordinates of one link split by field (any of them may be empty)."""

    v: ca.MX | None
    w: ca.MX | None
    alpha: ca.MX | None
    v_dot: ca.MX | None
    w_dot: ca.MX | None
    alpha_dot: ca.MX | None


@dataclass
class Invariants:
    """Inertia invariants of a link per unit linear density, in the link basis."""

    first_moment: ca.MX | ca.DM           # ∫ s dx                 (3)    (DM: a link without bending)
    second_moment: ca.MX | ca.DM          # ∫ s sᵀ dx              (3×3)
    angular_momentum: ca.MX | ca.DM       # ∫ s × ṡ dx             (3)
    relative_kinetic: Scalar              # ∫ |ṡ|² dx (less ``rate_gram``'s Σ w u̇² where that is set)
    rate_gram: RateGram | None = None     # the foreshortening rate's Σ w u̇², kept apart for the mass matrix

    def inertia(self) -> ca.MX | ca.DM:
        """∫ (|s|² I − s sᵀ) dx, the inertia tensor about the link frame's origin."""
        S = self.second_moment
        return ca.trace(S) * ca.DM.eye(3) - S


@dataclass
class RateGram:
    """The foreshortening rate's share Σ_k w_k u̇_k² of ∫|ṡ|², with u̇ = A(η) η̇ at the rule's points.

    Its Hessian in the rates is the Gram form 2 Aᵀ W A: a few dense products where CasADi's Hessian of the
    point sums takes ~4 times the operations (96 points, 32 modes: 221 600 scalar operations).  ``rates``
    names the fields whose rates η̇ stacks, in order ("v" then "w").
    """

    energy: ca.MX              # Σ w u̇², the same expression the point sums give
    jacobian: ca.MX            # A = ∂u̇/∂η̇ (K × n per field, fields side by side)
    weights: ca.DM             # w (K)
    rates: tuple[str, ...]

    def hessian(self) -> ca.MX:
        """∂²(Σ w u̇²)/∂η̇² = 2 Aᵀ W A."""
        A = self.jacobian
        return 2 * ca.mtimes(A.T, ca.mtimes(ca.diag(self.weights), A))


def beam_invariants(g: ShapeIntegrals, length: float, d: LinkDeformation, rule: PointRule | None = None,
                    gram: bool = False) -> Invariants:
    """Invariants of a link bending in v and/or w (the same shape family in both planes).

    Without ``rule``: first-order kinematics, s = (x, v, w), every invariant exact from the constant integrals.
    With a :class:`~flexlink.mechanics.shapes.base.PointRule`: second-order kinematics, s = (x + u, v, w), and
    every invariant still exact: the terms in u beyond second order (∫u², ∫uv, ∫uw, ∫(u v̇ − v u̇),
    ∫(w u̇ − u ẇ), ∫u̇²) as sums over the rule's points.  Nothing is dropped, so the kinetic energy
    ½∫ρ|V + ω×s + ṡ|² formed from them is a sum of squares (docs/mechanics.md, "Why the second-order model is
    consistent").  With ``gram`` and the point sums, ∫u̇² is returned apart as the invariants' ``rate_gram``
    (its rates' Hessian as a Gram form, :class:`RateGram`) and left out of ``relative_kinetic``.
    """
    L = float(length)
    zero: Scalar = 0.0
    v1: Scalar
    w1: Scalar
    v1 = ca.dot(_dm(g.phi), d.v) if d.v is not None else zero
    w1 = ca.dot(_dm(g.phi), d.w) if d.w is not None else zero
    xx: Scalar = L**3 / 3
    xv: Scalar = zero
    xw: Scalar = zero
    vv: Scalar = zero
    ww: Scalar = zero
    vw: Scalar = zero
    x_moment: Scalar = L**2 / 2
    if d.v is not None:
        xv = ca.dot(_dm(g.x_phi), d.v)
        vv = _quad(d.v, g.phi_phi)
    if d.w is not None:
        xw = ca.dot(_dm(g.x_phi), d.w)
        ww = _quad(d.w, g.phi_phi)
    if d.v is not None and d.w is not None:
        vw = _quad(d.v, g.phi_phi, d.w)
    # ∫ s × ṡ = (v ẇ − w v̇, w u̇ − (x+u) ẇ, (x+u) v̇ − v u̇)
    hx: Scalar = zero
    hy: Scalar = zero
    hz: Scalar = zero
    if d.v is not None:
        hz = ca.dot(_dm(g.x_phi), _rate(d.v_dot))
    if d.w is not None:
        hy = -ca.dot(_dm(g.x_phi), _rate(d.w_dot))
    if d.v is not None and d.w is not None:
        hx = _quad(d.v, g.phi_phi, _rate(d.w_dot)) - _quad(d.w, g.phi_phi, _rate(d.v_dot))
    relative: Scalar = zero
    rate_gram: RateGram | None = None
    for rate in (d.v_dot, d.w_dot):
        if rate is not None:
            relative = relative + _quad(rate, g.phi_phi)
    if rule is not None:
        fields = sum(eta is not None for eta in (d.v, d.w))
        p = _foreshortening_tensors(rule, d) if use_tensors(rule, fields) else _foreshortening_points(rule, d)
        if isinstance(p, _PointFields) and rule.factor is not None:
            # ∫ u and ∫ 2 x u as sums over the points, exact for the piecewise-cubic modes (u has degree 5 on
            # each element): K operations where the quadratic forms below take n² each
            x_moment = x_moment + ca.dot(p.weights, p.u)
            xx = xx + 2 * ca.dot(p.weights * ca.DM(rule.x), p.u)
        else:
            for eta in (d.v, d.w):                 # ∫ u = −½ ηᵀ fs η,  ∫ 2 x u = −ηᵀ fs_x η
                if eta is not None:
                    x_moment = x_moment - 0.5 * _quad(eta, g.fs)
                    xx = xx - _quad(eta, g.fs_x)
        xx = xx + p.dot(p.u, p.u)
        xv = xv + p.dot(p.u, p.v)
        xw = xw + p.dot(p.u, p.w)
        hy = hy + p.dot(p.w, p.u_dot) - p.dot(p.u, p.w_dot)
        hz = hz + p.dot(p.u, p.v_dot) - p.dot(p.v, p.u_dot)
        rate_energy = p.dot(p.u_dot, p.u_dot)
        if gram and isinstance(p, _PointFields) and isinstance(rate_energy, ca.MX):
            rate_gram = RateGram(rate_energy, foreshortening_rate_jacobian(rule, d), p.weights,
                                 tuple(name for name in ("v", "w") if getattr(d, name) is not None))
        else:
            relative = relative + rate_energy
    first = ca.vertcat(x_moment, v1, w1)
    second = ca.vertcat(ca.horzcat(xx, xv, xw), ca.horzcat(xv, vv, vw), ca.horzcat(xw, vw, ww))
    return Invariants(first, second, ca.vertcat(hx, hy, hz), relative, rate_gram)


@dataclass
class _PointFields:
    """u, v, w and their rates at a rule's points (K-vectors; None for an absent field), and Σ w_k a_k b_k."""

    weights: ca.DM
    u: ca.MX | ca.DM           # DM (zeros) for a link without bending
    u_dot: ca.MX | ca.DM
    v: ca.MX | None
    w: ca.MX | None
    v_dot: ca.MX | None
    w_dot: ca.MX | None

    def dot(self, a: Factor, b: Factor) -> Scalar:
        """Σ_k w_k a_k b_k over the rule's points; zero when a field is absent."""
        if a is None or b is None:
            return 0.0
        assert not isinstance(a, str) and not isinstance(b, str), "the point sums hold the factors themselves"
        return ca.dot(self.weights * a, b)


def _foreshortening_points(rule: PointRule, d: LinkDeformation) -> _PointFields:
    """U = −½∫₀ˣ(v'² + w'²) and u̇ = −∫₀ˣ(v'v̇' + w'ẇ') at the rule's points, with v, w, v̇, ẇ there."""
    local, sums, start = (ca.sparsify(ca.DM(m)) for m in (rule.local, rule.panel_sums, rule.start))

    def integral(f: ca.MX | float) -> ca.MX | ca.DM:  # ∫₀^{x_k} f at every point: this panel's + earlier panels
        return ca.mtimes(local, f) + ca.mtimes(start, ca.mtimes(sums, f))

    values_and_slopes = PointShapes(rule).at_points   # through the nodal values where the rule has them

    squares: ca.MX | float = 0
    rates: ca.MX | float = 0
    fields: dict[str, ca.MX | None] = {}
    for name in ("v", "w"):
        eta, eta_dot = getattr(d, name), getattr(d, f"{name}_dot")
        if eta is None:
            fields[name] = fields[f"{name}_dot"] = None
            continue
        (value, s), (value_dot, s_dot) = values_and_slopes(eta), values_and_slopes(_rate(eta_dot))
        squares, rates = squares + s * s, rates + s * s_dot
        fields[name], fields[f"{name}_dot"] = value, value_dot
    return _PointFields(ca.DM(rule.w), -0.5 * integral(squares), -integral(rates), **fields)


def foreshortening_rate_jacobian(rule: PointRule, d: LinkDeformation) -> ca.MX:
    """A = ∂u̇/∂η̇ at the rule's points: u̇ = −C Σ_fields diag(S η) S η̇, so A = −C diag(S η) S per field.

    C = ``local + start·panel_sums`` integrates from the root; S is the points' slope matrix (constant).
    K·n products for diag(Sη)S and sparse products with the integration blocks: the matrix the mass matrix's
    Gram form needs.
    """
    slope = ca.DM(rule.slope)
    local, sums = (ca.sparsify(ca.DM(m)) for m in (rule.local, rule.panel_sums))
    # start·Z is the sum of the panels before each point's own: a running sum over the P panels, then each
    # point takes its panel's row (K gathers where the K×P product takes K·P/2 multiply-adds a column)
    panel = [int(k) for k in np.rint(rule.start.sum(axis=1))]
    blocks = []
    for eta in (d.v, d.w):
        if eta is not None:
            Y = ca.mtimes(ca.diag(ca.mtimes(slope, eta)), slope)           # diag(Sη) S
            before = ca.vertcat(ca.MX.zeros(1, Y.size2()), ca.cumsum(ca.mtimes(sums, Y), 0))
            blocks.append(-(ca.mtimes(local, Y) + before[panel, :]))
    return ca.horzcat(*blocks)


@dataclass(frozen=True)
class ForeshorteningTensors:
    """The rule's sums over its points as polynomials in η, for bases with few shape functions.

    With G_k = Σ_j C_kj φ'_j φ'_jᵀ (C: the rule's integration from the root, ``local + start·panel_sums``),
    u_k = −½ Σ_fields ηᵀ G_k η = −½ g_k·p and u̇_k = −Σ_fields ηᵀ G_k η̇ = −vec(G_k)·r, where p holds the
    products η_a η_b (a ≤ b; g_k the matching entries of G_k, off-diagonal ones doubled) and r the products
    η_a η̇_b, each summed over the fields v, w (they share the basis).  Then, exactly as the point sums:

        Σ w u² = pᵀ A p,   Σ w u (φ·y) = pᵀ B y,   Σ w (φ·y) u̇ = yᵀ E r,   Σ w u̇² = rᵀ D r

    with A = ¼ Σ w g gᵀ, B = −½ Σ w g φᵀ, E = −Σ w φ vec(G)ᵀ, D = Σ w vec(G) vec(G)ᵀ: a few hundred operations
    for three shapes where the points take thousands, the same kinetic energy to rounding.
    """

    rows: np.ndarray      # the pairs (a, b), a ≤ b, of p
    cols: np.ndarray
    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    D: np.ndarray


#: The tensors grow like n⁴ in the number of shape functions n, the point sums like n: past this many the
#: points are cheaper.  Measured on the whole model (build, generated C, step) of one 16-element link reduced
#: to n modes, both forms built in the same session, with the points' equations in Kane's form
#: (docs/performance.md, "The tensors' threshold"): at 7 modes the tensors trade a step 1.5 times the points' for
#: 0.70 of their C and a shorter build, at 8 the points' step is half the tensors' for as much C.
TENSOR_MAX_SHAPES = 7


def use_tensors(rule: PointRule, fields: int) -> bool:
    """Whether the foreshortening terms are formed from :class:`ForeshorteningTensors` (else from the points)."""
    return fields > 0 and rule.slope.shape[1] <= TENSOR_MAX_SHAPES


def foreshortening_tensors(rule: PointRule) -> ForeshorteningTensors:
    """The tensors of a point rule (see :class:`ForeshorteningTensors`)."""
    C = rule.local + rule.start @ rule.panel_sums
    G = np.einsum("kj,ja,jb->kab", C, rule.slope, rule.slope)
    G = 0.5 * (G + G.transpose(0, 2, 1))
    n = G.shape[1]
    rows, cols = np.triu_indices(n)
    g = G[:, rows, cols] * np.where(rows == cols, 1.0, 2.0)
    vecG = G.reshape(G.shape[0], n * n)
    w = rule.w
    return ForeshorteningTensors(rows, cols, 0.25 * g.T @ (w[:, None] * g), -0.5 * g.T @ (w[:, None] * rule.phi),
                                 -rule.phi.T @ (w[:, None] * vecG), vecG.T @ (w[:, None] * vecG))


@dataclass
class _TensorFields:
    """u, u̇, v, w, v̇, ẇ of a link as the factors of :class:`ForeshorteningTensors`.

    ``dot(a, b)`` is the same weighted sum Σ w a b as :class:`_PointFields` gives, formed from the tensors.
    """

    t: ForeshorteningTensors
    p: ca.MX | float           # 0 only when no field is present, and then no sum is formed
    r: ca.MX | float
    v: ca.MX | None
    w: ca.MX | None
    v_dot: ca.MX | None
    w_dot: ca.MX | None
    u = "u"
    u_dot = "u_dot"

    def dot(self, a: Factor, b: Factor) -> Scalar:
        """Σ w a b from the tensors; ``a`` or ``b`` is the name "u" or "u_dot" of a foreshortening factor."""
        if a is None or b is None:
            return 0.0
        if isinstance(b, str):                  # the sums are symmetric: the named factor first
            a, b = b, a
        if isinstance(b, str):
            if a != b:
                raise ValueError(f"no tensor for Σ w {a} {b}")
            return (ca.dot(self.p, ca.mtimes(_dm(self.t.A), self.p)) if a == "u"
                    else ca.dot(self.r, ca.mtimes(_dm(self.t.D), self.r)))
        if a == "u":
            return ca.dot(self.p, ca.mtimes(_dm(self.t.B), b))
        return ca.dot(b, ca.mtimes(_dm(self.t.E), self.r))


def _foreshortening_tensors(rule: PointRule, d: LinkDeformation) -> _TensorFields:
    """The factors p (products η_a η_b) and r (η_a η̇_b) of a link's fields, summed over v and w."""
    t = foreshortening_tensors(rule)
    p: ca.MX | float = 0
    r: ca.MX | float = 0
    for eta, rate in ((d.v, d.v_dot), (d.w, d.w_dot)):
        if eta is not None:
            p = p + eta[t.rows.tolist()] * eta[t.cols.tolist()]
            r = r + ca.vec(ca.mtimes(_rate(rate), eta.T))      # column-major vec(η̇ ηᵀ): entry a·n + b is η_a η̇_b
    return _TensorFields(t, p, r, d.v, d.w, d.v_dot, d.w_dot)


def torsion_kinetic(t: TorsionIntegrals, length: float, d: LinkDeformation, omega_x: ca.MX) -> ca.MX:
    """∫ (ω_x + α̇)² dx per unit polar mass moment (rotary inertia of sections in bending neglected)."""
    alpha_dot = _rate(d.alpha_dot)
    return (float(length) * omega_x**2 + 2 * omega_x * ca.dot(_dm(t.phi), alpha_dot)
            + _quad(alpha_dot, t.phi_phi))


@dataclass
class TipKinematics:
    """Tip point s(L) and tip rotation vector ψ = (α(L), −w'(L), v'(L)) in the link basis."""

    position: ca.MX | ca.DM           # DM for a rigid link
    rotation_vector: ca.MX | ca.DM


def tip_kinematics(g: ShapeIntegrals | None, t: TorsionIntegrals | None, length: float, d: LinkDeformation,
                   second_order: bool, rule: PointRule | None = None) -> TipKinematics:
    """The tip point and rotation vector of a beam link from its fields (the bending basis also for w).

    In second-order kinematics the tip is drawn back along x by the foreshortening u(L).  ``g`` is None for a
    link that only twists (its axis stays straight), ``t`` for one that only bends.
    """
    x_tip: Scalar = float(length)
    v_tip: Scalar = 0.0
    w_tip: Scalar = 0.0
    slope_v: Scalar = 0.0
    slope_w: Scalar = 0.0
    twist: Scalar = 0.0
    if d.v is not None or d.w is not None:
        assert g is not None, "a link with bending coordinates has a bending basis"
    if d.v is not None and g is not None:
        v_tip = ca.dot(_dm(g.tip), d.v)
        slope_v = ca.dot(_dm(g.tip_slope), d.v)
    if d.w is not None and g is not None:
        w_tip = ca.dot(_dm(g.tip), d.w)
        slope_w = ca.dot(_dm(g.tip_slope), d.w)
    if d.alpha is not None:
        assert t is not None, "a link with twist coordinates has a torsion basis"
        twist = ca.dot(_dm(t.tip), d.alpha)
    if second_order and g is not None:
        # u(L) = −½ ηᵀ fs_tip η; on a rule with nodal values, the same sum over the points' slopes, exact for the
        # piecewise cubics, which the Kane form's slopes share (the tip's acceleration: N·n + 4K, not 3 n²)
        shapes = PointShapes(rule) if rule is not None and rule.factor is not None else None
        for eta in (d.v, d.w):
            if eta is not None and shapes is not None:
                slope = shapes.at_points(eta)[1]
                x_tip = x_tip - 0.5 * ca.dot(ca.DM(shapes.weights) * slope, slope)
            elif eta is not None:
                x_tip = x_tip - 0.5 * _quad(eta, g.fs_tip)
    return TipKinematics(ca.vertcat(x_tip, v_tip, w_tip), ca.vertcat(twist, -slope_w, slope_v))


def body_invariants(b: BodyIntegrals, eta: ca.MX, eta_dot: ca.MX) -> Invariants:
    """Invariants of a reduced finite-element link (its :class:`BodyIntegrals`), per unit density.

    s = X + Φη, first-order kinematics (the membrane strain of large deflections is not in the shell element).
    """
    first = _dm(b.first) + ca.mtimes(_dm(b.modal), eta)
    lin = ca.vertcat(*[ca.horzcat(*[ca.dot(_dm(b.x_modal[a, c]), eta) for c in range(3)]) for a in range(3)])
    quad = ca.vertcat(*[ca.horzcat(*[_quad(eta, b.pairs[a, c]) for c in range(3)]) for a in range(3)])
    second = _dm(b.second) + lin + lin.T + quad

    def cross(a: int, c: int) -> ca.MX:                        # ∫ s_a ṡ_c
        return ca.dot(_dm(b.x_modal[a, c]), eta_dot) + _quad(eta, b.pairs[a, c], eta_dot)

    angular = ca.vertcat(cross(1, 2) - cross(2, 1), cross(2, 0) - cross(0, 2), cross(0, 1) - cross(1, 0))
    return Invariants(first, second, angular, _quad(eta_dot, b.mass_matrix))


def body_tip_kinematics(b: BodyIntegrals, eta: ca.MX) -> TipKinematics:
    """Tip point and end-section rotation vector of a reduced finite-element link, linear in its modes."""
    return TipKinematics(_dm(b.tip_point) + ca.mtimes(_dm(b.tip_translation), eta),
                         ca.mtimes(_dm(b.tip_rotation), eta))


# ---- the foreshortening's share of the equations in Kane's form (issue 15: the 32-mode link's residual)

@dataclass
class FrameMotion:
    """What the foreshortening's equations need of a link's floating frame, all in the link basis.

    ``velocity`` is V_L = Rᵀ V (the origin's velocity as the link's energy sees it), ``velocity_rate`` its time
    derivative, ``omega`` and ``alpha`` the angular velocity and its rate.  R need not be a rotation: the tip
    rotation I + [ψ×] + ½[ψ×]² of a second-order link upstream is orthogonal only to second order, and the
    energy is written in V_L and ω, so the equations are derived in them (``acceleration``).
    """

    velocity: ca.MX
    velocity_rate: ca.MX
    omega: ca.MX
    alpha: ca.MX

    @property
    def acceleration(self) -> ca.MX:
        """V̇_L + ω × V_L: what a point's acceleration takes from the origin, d/dt b + ω × b at s = 0."""
        return self.velocity_rate + ca.cross(self.omega, self.velocity)


@dataclass
class ForeshorteningForces:
    """The Lagrange derivative of a link's foreshortening energy T_u, with what its frame's coordinates need.

    ``fields`` maps "v" and "w" to the generalized forces on the link's own coordinates of that field.  The
    frame's momenta P_V = ∂T_u/∂V_L and P_ω = ∂T_u/∂ω and their rates give a coordinate upstream its share,
    ∂V_L/∂q̇ᵀ Ṗ_V + ∂ω/∂q̇ᵀ Ṗ_ω plus the Lagrange derivative of V_L·P_V + ω·P_ω with P_V, P_ω held fixed.
    """

    momentum: ca.MX
    momentum_rate: ca.MX
    angular_momentum: ca.MX
    angular_momentum_rate: ca.MX
    energy: ca.MX              # T_u itself (the kinetic-energy output adds it to the first-order T)
    fields: dict[str, ca.MX]


def _weighted(a: ca.MX | None, b: ca.MX | None) -> Scalar:
    """Σ_k a_k b_k where the caller has already weighted ``a`` by the points' masses; 0 for an absent field."""
    return 0.0 if a is None or b is None else ca.dot(a, b)


def _modal_functionals(g: ShapeIntegrals, rho: ca.MX, motion: dict[str, tuple[ca.MX, ca.MX, ca.MX]],
                       which: np.ndarray) -> list[Scalar]:
    """The functional ρ∫c u and its first two rates from its modal form ∫c u = −½ Σ ηᵀ F η.

    F = ``which``: fs for c = 1, fs_x for c = x; how the invariants take ∫u and ∫xu on a rule without nodal
    values.
    """
    out: list[Scalar] = [0.0, 0.0, 0.0]
    for eta, rate, acc in motion.values():
        out[0] = out[0] - 0.5 * rho * _quad(eta, which)
        out[1] = out[1] - rho * _quad(eta, which, rate)
        out[2] = out[2] - rho * (_quad(rate, which) + _quad(eta, which, acc))
    return out


@dataclass
class _PointMotion:
    """A second-order link's fields at the rule's points, with their first two rates.

    Values and slopes of v, w, the foreshortening u, u̇, ü, and ρ∫u, ρ∫xu with their rates (point sums, or
    their modal forms).
    """

    mass: ca.MX
    values: dict[str, list[ca.MX]]
    slopes: dict[str, list[ca.MX]]
    u: list[ca.MX]
    U: list[Scalar]
    X: list[Scalar]


def _point_motion(rule: PointRule, g: ShapeIntegrals, motion: dict[str, tuple[ca.MX, ca.MX, ca.MX]],
                  rho: ca.MX, shapes: PointShapes, integral: PointIntegration) -> _PointMotion:
    """The :class:`_PointMotion`: u = −½C Σ s², u̇ = −C Σ s ṡ, ü = −C Σ (s s̈ + ṡ²) from the slopes s = φ'η."""
    m = rho * ca.DM(rule.w)
    values: dict[str, list[ca.MX]] = {}
    slopes: dict[str, list[ca.MX]] = {}
    for name, triple in motion.items():
        values[name], slopes[name] = (list(t) for t in zip(*(shapes.at_points(e) for e in triple), strict=True))
    first, *more = slopes.values()               # a link on the points bends in v, w or both
    q2, q1, q0 = first[0] * first[0], first[0] * first[1], first[0] * first[2] + first[1] * first[1]
    for s in more:
        q2, q1, q0 = q2 + s[0] * s[0], q1 + s[0] * s[1], q0 + s[0] * s[2] + s[1] * s[1]
    u = [-0.5 * integral(q2), -integral(q1), -integral(q0)]
    if rule.factor is not None:                 # ∫u, ∫xu as point sums, as beam_invariants takes them
        U: list[Scalar] = [ca.dot(m, f) for f in u]
        X: list[Scalar] = [ca.dot(m * ca.DM(rule.x), f) for f in u]
    else:
        U, X = _modal_functionals(g, rho, motion, g.fs), _modal_functionals(g, rho, motion, g.fs_x)
    return _PointMotion(m, values, slopes, u, U, X)


def _frame_momenta(p: _PointMotion, frame: FrameMotion) -> tuple[ca.MX, ca.MX, ca.MX, ca.MX, ca.MX]:
    """P_V, Ṗ_V, P_ω, Ṗ_ω and T_u itself of T_u = ½[2V_L·(ω × ΔS1 + ΔṠ1) + ωᵀΔJω + 2ω·ΔH + ΔE] (ρ in the sums).

    ΔS1 = e_x ρ∫u; ΔJ from ΔS, whose non-zero entries are ρ∫(2xu + u²), ρ∫uv, ρ∫uw; ΔH = ρ∫(0, wu̇ − uẇ, uv̇ − vu̇):
    the invariants' terms in u (:func:`beam_invariants`), with their rates from the points' u, u̇, ü.
    """
    u, u_dot, u_acc = p.u
    mu = p.mass * u
    absent: list[ca.MX | None] = [None, None, None]
    v: list[ca.MX | None] = list(p.values["v"]) if "v" in p.values else absent
    w: list[ca.MX | None] = list(p.values["w"]) if "w" in p.values else absent
    mv = None if v[0] is None else p.mass * v[0]
    mw = None if w[0] is None else p.mass * w[0]
    uv = [_weighted(mu, v[0]), _weighted(mu, v[1]) + _weighted(mv, u_dot)]
    uw = [_weighted(mu, w[0]), _weighted(mu, w[1]) + _weighted(mw, u_dot)]
    uu = [2 * p.X[0] + ca.dot(mu, u), 2 * p.X[1] + 2 * ca.dot(mu, u_dot)]
    S = [ca.vertcat(ca.horzcat(uu[k], uv[k], uw[k]), ca.horzcat(uv[k], 0, 0), ca.horzcat(uw[k], 0, 0))
         for k in range(2)]
    J = [ca.trace(m) * ca.DM.eye(3) - m for m in S]
    H = ca.vertcat(0, _weighted(mw, u_dot) - _weighted(mu, w[1]), _weighted(mu, v[1]) - _weighted(mv, u_dot))
    H_dot = ca.vertcat(0, _weighted(mw, u_acc) - _weighted(mu, w[2]), _weighted(mu, v[2]) - _weighted(mv, u_acc))
    e_x = ca.DM([1.0, 0.0, 0.0])
    S1 = [e_x * U for U in p.U]
    omega, alpha, V = frame.omega, frame.alpha, frame.velocity
    P_V = ca.cross(omega, S1[0]) + S1[1]
    P_V_dot = ca.cross(alpha, S1[0]) + ca.cross(omega, S1[1]) + S1[2]
    P_w = ca.cross(S1[0], V) + ca.mtimes(J[0], omega) + H
    P_w_dot = (ca.cross(S1[1], V) + ca.cross(S1[0], frame.velocity_rate) + ca.mtimes(J[1], omega)
               + ca.mtimes(J[0], alpha) + H_dot)
    energy = (ca.dot(V, 2 * ca.cross(omega, S1[0]) + 2 * S1[1]) + ca.dot(omega, ca.mtimes(J[0], omega))
              + 2 * ca.dot(omega, H) + ca.dot(p.mass * u_dot, u_dot))
    return P_V, P_V_dot, P_w, P_w_dot, 0.5 * energy


def foreshortening_forces(rule: PointRule, g: ShapeIntegrals, d: LinkDeformation,
                          accelerations: Mapping[str, ca.MX], rho: ca.MX, frame: FrameMotion) -> ForeshorteningForces:
    """E(T_u) = d/dt ∂T_u/∂q̇ − ∂T_u/∂q of a link's foreshortening energy T_u, formed from the points by hand.

    T_u is the kinetic energy the foreshortening u adds to a link's first-order one: ½ Σ_k m_k (|b_k|² − |b⁰_k|²)
    with b = V_L + ω × s + ṡ, s_k = (x_k + u_k, v_k, w_k) against s⁰_k = (x_k, v_k, w_k) (the invariants' terms
    in u of :func:`beam_invariants`).  On the link's own coordinates it is Kane's sum Σ m (∂s/∂η)ᵀ a − (∂s⁰/∂η)ᵀ a⁰
    with a = ḃ + ω × b = A + (α × + ω × ω ×) s + 2 ω × ṡ + s̈: Σ m [φᵀ (a − a⁰)_field + (∂u/∂η)ᵀ a_x], one pass
    back through the rule's integral and the nodal values.  The frame's share comes as its momenta and their
    rates (:class:`ForeshorteningForces`).  The same equations as CasADi's Lagrange derivative through the
    point sums (tests/test_kane_foreshortening.py) in about two thirds of the operations: the sums' derivatives
    are formed once from u, u̇, ü at the points instead of forward over reverse.  ∫u and ∫xu are the point
    sums where the invariants take them so (a rule with nodal values), else their modal forms.
    """
    shapes, integral = PointShapes(rule), PointIntegration(rule)
    motion = {name: (getattr(d, name), _rate(getattr(d, f"{name}_dot")), accelerations[name])
              for name in ("v", "w") if getattr(d, name) is not None}
    p = _point_motion(rule, g, motion, rho, shapes, integral)
    u, u_dot, u_acc = p.u
    A, Om = frame.acceleration, skew(frame.omega)
    W = skew(frame.alpha) + ca.mtimes(Om, Om)         # α × s + ω × (ω × s) = W s
    column = {"v": 1, "w": 2}
    # a_x at the points less what ∫u and ∫xu carry (A_x + W_xx x) where those are modal
    a_x = W[0, 0] * u + u_acc
    for name, (value, rate, _) in p.values.items():
        a_x = a_x + W[0, column[name]] * value + 2 * Om[0, column[name]] * rate
    if rule.factor is not None:
        a_x = a_x + A[0] + W[0, 0] * ca.DM(rule.x)
    back = integral.transpose(p.mass * a_x)
    fields: dict[str, ca.MX] = {}
    for name, (eta, _, _) in motion.items():
        c = column[name]
        Q = shapes.project(p.mass * (W[c, 0] * u + 2 * Om[c, 0] * u_dot), -(p.slopes[name][0] * back))
        if rule.factor is None:                 # A_x ∂(ρ∫u)/∂η + W_xx ∂(ρ∫xu)/∂η in their modal forms
            Q = Q - rho * (A[0] * ca.mtimes(ca.sparsify(_dm(g.fs)), eta)
                           + W[0, 0] * ca.mtimes(ca.sparsify(_dm(g.fs_x)), eta))
        fields[name] = Q
    P_V, P_V_dot, P_w, P_w_dot, energy = _frame_momenta(p, frame)
    return ForeshorteningForces(P_V, P_V_dot, P_w, P_w_dot, energy, fields)
