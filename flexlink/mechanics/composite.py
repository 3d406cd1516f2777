"""The mass matrix by composite inertia: each body's kinetic energy a quadratic form, folded from the tip.

M = ∂²T/∂q̇² of a chain as CasADi's Hessian of the whole kinetic energy expands every body's energy through
the kinematics of every body before it: its scalar code grows with the pairs of coordinates, 57 operations
an entry of an 8-link planar chain.  Here the chain is cut at every tip frame.  Body b (joint b, its rotor,
link b and its payload) sees its parent only through the parent tip's velocity σ = (vec Ṙ, ω, V), 15
numbers, so that

    T = Σ_b ½ z_bᵀ H_b z_b,   z_b = (σ_{b−1}, q̇_b),   σ_b = A_b z_b,

with H_b and A_b functions of the positions only (T is quadratic in the rates, the tip's velocity linear).
Featherstone's composite-rigid-body recursion, run on these quadratic forms instead of 6×6 spatial
inertias, folds the chain from the tip: the composite form of the bodies past b in σ_b is K_b,
Ĥ_b = H_b + A_bᵀ K_{b+1} A_b holds body b's diagonal block of M and, in its σ rows, K_b and the cross block
of σ_{b−1} with q̇_b; each cross block travels one body down per step (A_bᵀ F) and leaves its rows of M on
the way.  The same matrix to rounding (tests/test_composite_mass_matrix.py), in 17 100 operations instead of
30 200 on the 8-link chain (docs/performance.md).

Why σ carries Ṙ and ω, not a 6-number twist: a second-order link's tip rotation I + [ψ×] + ½[ψ×]² is
orthogonal only to second order, and the chain composes the next body's frame from it exactly
(:class:`flexlink.mechanics.assembly.Frame`), so Ṙ is not R[ω×].  The cut does not change the model:
each body's energy is the same expression as in the whole chain's walk, with its parent's velocities as
symbols.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import casadi as ca
import numpy as np

from flexlink.mechanics.kinematics import BASE_FRAME

#: What a tip frame hands the next body: vec Ṙ (9), ω (3), V (3).
TWIST_SIZE = 15


class CutChain(Protocol):
    """What the recursion reads of the chain being assembled (``assembly.ChainAssembly``), its walk done."""

    qa: ca.MX
    va: ca.MX
    p: ca.MX
    P: Any                          # the parameters' table (their values: .items)
    coordinates: list[str]
    kinds: list[str]
    parts: list[Any]
    frames: list[Any]
    motor_coord: list[int | None]
    joint_coord: list[int]
    bodies: list[dict]
    rate_grams: list[Any]
    kane_links: list[Any]
    origin: ca.MX | ca.DM
    Rdef: ca.MX | ca.DM

    def body_step(self, i: int, parent: tuple) -> tuple:
        """Joint i to link i's payload on the parent's tip frame: (T, T less Kane's share, V_g, tip, joint R)."""


@dataclass
class BodyForm:
    """One body's kinetic energy as a quadratic form in z = (σ of its parent, its own rates)."""

    rates: list[int]      # the body's own coordinates in the full vector: motor, joint, elastic
    energy_hessian: ca.MX  # H_b = ∂²T_b/∂z² (no rate left in it)
    tip_map: ca.MX        # A_b = ∂σ_b/∂z (σ_b is linear in z)
    cut: bool             # whether z starts with the parent's σ (every body but the first, on the fixed base)


def _velocity(frame) -> ca.MX:
    """σ of a frame: vec Ṙ, ω, V."""
    return ca.vertcat(ca.vec(frame.tip_rotation_rate), frame.tip_omega, frame.tip_velocity)


def body_forms(chain: CutChain) -> list[BodyForm]:
    """Every body's (H_b, A_b), from the chain's own body step walked again with symbolic parent velocities.

    The positions are the chain's (its frames, already walked).  The second walk records into fresh lists
    (bodies, rate grams, Kane links) that are dropped, and each link's tip is put back: the chain's own objects
    are left as the first walk made them.
    """
    kept = {name: getattr(chain, name) for name in ("bodies", "rate_grams", "kane_links")}
    kept_origin, kept_rdef, kept_tips = chain.origin, chain.Rdef, [part.tip for part in chain.parts]
    forms = []
    try:
        for name in kept:
            setattr(chain, name, [])
        for i in range(len(chain.parts)):
            forms.append(_body_form(chain, i))
    finally:
        for name, value in kept.items():
            setattr(chain, name, value)
        chain.origin, chain.Rdef = kept_origin, kept_rdef
        for part, tip in zip(chain.parts, kept_tips, strict=True):
            part.tip = tip
    return forms


def _body_form(chain: CutChain, i: int) -> BodyForm:
    """Body i's form: its energy's Hessian and its tip velocity's Jacobian in z = (σ of its parent, own rates)."""
    if i == 0:
        sigma, parent = None, BASE_FRAME
        chain.origin = ca.DM.zeros(3)
    else:
        sigma = ca.MX.sym(f"sigma_{i}", TWIST_SIZE)
        above = chain.frames[i - 1]
        parent = (above.tip_rotation, ca.reshape(sigma[0:9], 3, 3), sigma[9:12], sigma[12:15])
        chain.origin = above.tip_origin
    energy, _, _, frame, _ = chain.body_step(i, parent)
    tip = _velocity(frame)
    rates = [k for k in (chain.motor_coord[i], chain.joint_coord[i]) if k is not None] + list(chain.parts[i].eta)
    n = len(chain.coordinates)
    own = ca.MX.sym(f"rates_{i}", len(rates))
    only = ca.vertcat(*[own[rates.index(k)] if k in rates else 0 for k in range(n)])
    cut_energy, cut_tip = (ca.substitute(x, chain.va, only) for x in (energy, tip))
    z = own if sigma is None else ca.vertcat(sigma, own)
    at_rest = ca.DM.zeros(z.numel())
    H = ca.substitute(ca.hessian(cut_energy, z)[0], z, at_rest)
    A = ca.substitute(ca.jacobian(cut_tip, z), z, at_rest)
    _check_premise(chain, i, ca.vertcat(energy, tip), own, rates, sigma,
                   ca.vertcat(0.5 * ca.bilin(H, z, z), ca.mtimes(A, z)))
    return BodyForm(rates, H, A, sigma is not None)


def _check_premise(chain: CutChain, i: int, exact: ca.MX, own: ca.MX, rates: list[int], sigma: ca.MX | None,
                   folded: ca.MX) -> None:
    """The recursion's premise, checked at one random state: the body's energy is ½ zᵀHz and its tip's velocity
    A z, with z its parent's velocity and its own rates (no other coordinate's rate in them).

    CasADi's matrix graph cannot tell this structurally (a link's energy is formed with directional derivatives
    along every rate), so a body step that broke it would otherwise give a wrong M without a word.
    """
    rng = np.random.default_rng(i)
    n = len(chain.coordinates)
    symbols = [chain.qa, chain.va, chain.p] + ([sigma] if sigma is not None else [])
    values = [rng.uniform(-1, 1, n) * np.where(np.array(chain.kinds) == "elastic", 0.01, 1.0),
              rng.normal(size=n), np.array([item.value for item in chain.P.items])]
    values += [rng.normal(size=sigma.numel())] if sigma is not None else []
    check = ca.Function("premise", symbols + [own], [exact, folded])
    got_exact, got_folded = (np.array(x).ravel() for x in check(*values, values[1][rates]))
    if not np.all(np.isfinite(got_exact)):
        return                  # a degenerate scene (overflowing shapes): the model's own checks name it
    scale = max(1.0, float(np.max(np.abs(got_exact))))
    if not np.all(np.abs(got_exact - got_folded) <= 1e-6 * scale):     # a broken premise is O(1) off
        raise RuntimeError(f"body {i}: its energy and tip velocity are not a quadratic and a linear form in its "
                           "parent's velocity and its own rates: the composite-inertia recursion does not apply")


def placement(n: int, rows: list[int]) -> ca.DM:
    """The n × len(rows) matrix that puts a block's rows at ``rows`` of an n-vector."""
    return ca.DM(ca.Sparsity.triplet(n, len(rows), rows, list(range(len(rows)))), 1.0)


def composite_mass_matrix(chain: CutChain) -> ca.MX:
    """∂²T/∂q̇² of every coordinate (without the rate grams' share) by the recursion of the module docstring.

    An expression in the positions (and parameters) alone.
    """
    n = len(chain.coordinates)
    forms = body_forms(chain)
    M = ca.MX(n, n)
    composite: ca.MX | None = None          # K_{b+1}: the bodies past b, in σ_b
    crossing: dict[int, ca.MX] = {}         # body j → the cross block of σ_b with q̇_j (bodies past b)
    for b in reversed(range(len(forms))):
        form = forms[b]
        H, A = form.energy_hessian, form.tip_map
        if composite is not None:
            H = H + ca.mtimes(A.T, ca.mtimes(composite, A))
        s = TWIST_SIZE if form.cut else 0
        here = placement(n, form.rates)
        M = M + ca.mtimes(here, ca.mtimes(H[s:, s:], here.T))
        travelled: dict[int, ca.MX] = {}
        for j, F in crossing.items():
            G = ca.mtimes(A.T, F)            # z_b against q̇_j
            block = ca.mtimes(here, ca.mtimes(G[s:, :], placement(n, forms[j].rates).T))
            M = M + block + block.T
            if form.cut:
                travelled[j] = G[:s, :]
        if form.cut:
            travelled[b] = H[:s, s:]
            composite = H[:s, :s]
        crossing = travelled
    return M
