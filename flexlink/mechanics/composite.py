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
the way.  The same matrix to rounding (tests/test_mass_matrix_gram.py), in 17 100 operations instead of
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

from flexlink.mechanics.kinematics import BASE_FRAME

#: What a tip frame hands the next body: vec Ṙ (9), ω (3), V (3).
TWIST_SIZE = 15


class CutChain(Protocol):
    """What the recursion reads of the chain being assembled (``assembly.ChainAssembly``), its walk done."""

    va: ca.MX
    coordinates: list[str]
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

    The positions are the chain's (its frames, already walked); the second walk's records (bodies, rate
    grams, Kane links) are dropped: they are the first walk's again.
    """
    kept = {name: list(getattr(chain, name)) for name in ("bodies", "rate_grams", "kane_links")}
    kept_origin, kept_rdef = chain.origin, chain.Rdef
    n = len(chain.coordinates)
    forms = []
    try:
        for i, part in enumerate(chain.parts):
            if i == 0:
                sigma, parent = None, BASE_FRAME
                chain.origin = ca.DM.zeros(3)
            else:
                sigma = ca.MX.sym(f"sigma_{i}", TWIST_SIZE)
                above = chain.frames[i - 1]
                parent = (above.tip_rotation, ca.reshape(sigma[0:9], 3, 3), sigma[9:12], sigma[12:15])
                chain.origin = above.tip_origin
            energy, _, _, frame, _ = chain.body_step(i, parent)
            rates = [k for k in (chain.motor_coord[i], chain.joint_coord[i]) if k is not None] + list(part.eta)
            own = ca.MX.sym(f"rates_{i}", len(rates))
            # the body's energy and tip in its own rates alone (no other coordinate's rate enters them)
            only = ca.vertcat(*[own[rates.index(k)] if k in rates else 0 for k in range(n)])
            energy, tip = (ca.substitute(x, chain.va, only) for x in (energy, _velocity(frame)))
            z = own if sigma is None else ca.vertcat(sigma, own)
            at_rest = ca.DM.zeros(z.numel())        # quadratic and linear in z: nothing of z left but structure
            forms.append(BodyForm(rates, ca.substitute(ca.hessian(energy, z)[0], z, at_rest),
                                  ca.substitute(ca.jacobian(tip, z), z, at_rest), sigma is not None))
    finally:
        for name, value in kept.items():
            setattr(chain, name, value)
        chain.origin, chain.Rdef = kept_origin, kept_rdef
    return forms


def _place(n: int, rows: list[int]) -> ca.DM:
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
        here = _place(n, form.rates)
        M = M + ca.mtimes(here, ca.mtimes(H[s:, s:], here.T))
        travelled: dict[int, ca.MX] = {}
        for j, F in crossing.items():
            G = ca.mtimes(A.T, F)            # z_b against q̇_j
            block = ca.mtimes(here, ca.mtimes(G[s:, :], _place(n, forms[j].rates).T))
            M = M + block + block.T
            if form.cut:
                travelled[j] = G[:s, :]
        if form.cut:
            travelled[b] = H[:s, s:]
            composite = H[:s, :s]
        crossing = travelled
    return M
