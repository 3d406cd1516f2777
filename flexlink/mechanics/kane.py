"""The foreshortening's share of a second-order link's equations in Kane's form, on the point sums.

Why not CasADi's Lagrange derivative, as for the rest of the chain: past the tensors' threshold
(:data:`~flexlink.mechanics.kinematics.TENSOR_MAX_SHAPES`) the foreshortening energy T_u is a sum over the
link's points, reached through the nodal values and the rule's running integral of v'².  Automatic
differentiation takes d/dt ∂T_u/∂q̇ − ∂T_u/∂q forward over reverse through that whole graph, several times
over; Kane's form writes the same derivative down once from the points' u, u̇, ü.  The link's first-order
kinetic energy still goes through CasADi (``ChainAssembly.T_rest``); T_u's share is

* on the link's own coordinates, Kane's sums Σ m [(∂s/∂η)ᵀ a − (∂s⁰/∂η)ᵀ a⁰]
  (:func:`~flexlink.mechanics.kinematics.foreshortening_forces`);
* on the coordinates upstream, through the link's frame: ∂V_L/∂q̇ᵀ Ṗ_V + ∂ω/∂q̇ᵀ Ṗ_ω with T_u's momenta and
  their rates, plus the Lagrange derivative of V_L·P_V + ω·P_ω with the momenta held fixed
  (:func:`frame_transport`), which CasADi takes on the frame's own expressions only.

The same equations to round-off (tests/test_kane_foreshortening.py, against the AD builder), in about two
thirds of the residual's operations (docs/mechanics.md, "Past the tensors"; docs/performance.md, "The
foreshortening's equations in Kane's form").  A chain with a linear link keeps the AD form: its T is evaluated
at η = 0, which is not the Kane sums' energy (:func:`takes_kane_form`).

The builder (:mod:`flexlink.mechanics.assembly`) decides per link, records a :class:`KaneLink` and adds
:func:`kane_forces` to its residual; :mod:`flexlink.mechanics.outputs` reads the links' momenta.  This module
imports nothing of the builder: it sees the chain through :class:`KaneChain`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import casadi as ca

from flexlink.mechanics.kinematics import (
    ForeshorteningForces,
    FrameMotion,
    LinkDeformation,
    foreshortening_forces,
    use_tensors,
)
from flexlink.mechanics.shapes.base import ShapeBasis
from flexlink.scene.loader import Link


class BeamPart(Protocol):
    """What Kane's form reads of a link's bookkeeping (``assembly.LinkParts``)."""

    fields: dict[str, list[int]]   # "v", "w", "alpha" → indices of the link's coordinates
    bending: ShapeBasis | None

    @property
    def second_order(self) -> bool:
        """Whether the link keeps the foreshortening."""


class KaneChain(Protocol):
    """What Kane's form reads of the chain being assembled (``assembly.ChainAssembly``)."""

    qa: ca.MX            # the full coordinates, their rates and accelerations
    va: ca.MX
    aa: ca.MX
    coordinates: list[str]
    kane_links: list[KaneLink]

    def deformation(self, part: Any, q: ca.MX, v: ca.MX) -> LinkDeformation:
        """The link's elastic coordinates and rates picked out of full vectors."""


def takes_kane_form(part: BeamPart, with_linear_link: bool) -> bool:
    """Whether a beam link's foreshortening can enter the equations in Kane's form.

    A second-order link on the point sums (past the tensors' threshold), in a chain without a linear link
    (whose masked T, evaluated at η = 0, is not the Kane sums' energy).
    """
    if not (part.second_order and part.bending is not None):
        return False
    fields = sum(name in part.fields for name in ("v", "w"))
    return not use_tensors(part.bending.points, fields) and not with_linear_link


@dataclass
class KaneLink:
    """A second-order link on the point sums whose foreshortening's equations are formed in Kane's form.

    Its first-order kinetic energy stays in the Lagrangian CasADi differentiates (``ChainAssembly.T_rest``);
    the foreshortening's share is :func:`~flexlink.mechanics.kinematics.foreshortening_forces` at its frame.
    """

    part: BeamPart
    link: Link
    rho: ca.MX
    origin: ca.MX | ca.DM        # the frame's origin and its velocity (world), its rotation, the rotation's
    velocity: ca.MX | ca.DM      # rate, and its angular velocity (link basis)
    rotation: ca.MX
    rotation_rate: ca.MX
    omega: ca.MX
    _forces: ForeshorteningForces | None = field(default=None, init=False, repr=False)

    def forces(self, chain: KaneChain) -> ForeshorteningForces:
        """The link's :func:`~flexlink.mechanics.kinematics.foreshortening_forces`, formed once.

        The residual and the outputs share them.
        """
        if self._forces is None:
            part, qa, va, aa = self.part, chain.qa, chain.va, chain.aa
            assert part.bending is not None         # takes_kane_form: a beam link that bends
            state, rates = ca.vertcat(qa, va), ca.vertcat(va, aa)
            velocity = self.link_velocity
            frame = FrameMotion(velocity, ca.jtimes(velocity, state, rates), self.omega,
                                ca.jtimes(self.omega, state, rates))
            accelerations: dict[str, ca.MX] = {name: ca.vertcat(*[aa[j] for j in part.fields[name]])
                                               for name in ("v", "w") if name in part.fields}
            self._forces = foreshortening_forces(part.bending.points, part.bending.integrals,
                                                 chain.deformation(part, qa, va), accelerations, self.rho, frame)
        return self._forces

    @property
    def link_velocity(self) -> ca.MX:
        """V_L = Rᵀ V, the origin's velocity as the link's energy sees it."""
        return ca.mtimes(self.rotation.T, self.velocity)

    def momenta(self, chain: KaneChain) -> tuple[ca.MX, ca.MX, ca.MX, ca.MX]:
        """The foreshortening's momentum and angular momentum about the world origin (world), and their rates.

        R P_V and R P_ω + o × R P_V, differentiated as products: Ṙ and ȯ are the frame's exact rates.
        """
        f = self.forces(chain)
        R, R_dot, o = self.rotation, self.rotation_rate, self.origin
        momentum = ca.mtimes(R, f.momentum)
        momentum_rate = ca.mtimes(R_dot, f.momentum) + ca.mtimes(R, f.momentum_rate)
        spin = ca.mtimes(R, f.angular_momentum) + ca.cross(o, momentum)
        spin_rate = (ca.mtimes(R_dot, f.angular_momentum) + ca.mtimes(R, f.angular_momentum_rate)
                     + ca.cross(self.velocity, momentum) + ca.cross(o, momentum_rate))
        return momentum, momentum_rate, spin, spin_rate


def kane_forces(chain: KaneChain) -> ca.MX | float:
    """The foreshortening's share of the equations of the chain's :class:`KaneLink` links, on every coordinate.

    A link's own coordinates take its Kane sums.  Its frame's coordinates take ∂V_L/∂q̇ᵀ Ṗ_V + ∂ω/∂q̇ᵀ Ṗ_ω,
    with P_V, P_ω the foreshortening energy's momenta (V_L = Rᵀ V, ω: the frame's velocities as the energy
    sees them), plus the Lagrange derivative of V_L·P_V + ω·P_ω with the momenta held fixed
    (:func:`frame_transport`): only the frame's own expressions, however many points the link has.
    """
    if not chain.kane_links:
        return 0
    qa, va, aa = chain.qa, chain.va, chain.aa
    entries: list[ca.MX | float] = [0.0] * len(chain.coordinates)
    total: ca.MX | float = 0
    for k in chain.kane_links:
        part, f, velocity = k.part, k.forces(chain), k.link_velocity
        total = (total + ca.jtimes(velocity, va, f.momentum_rate, True)
                 + ca.jtimes(k.omega, va, f.angular_momentum_rate, True)
                 + frame_transport(chain, velocity, k.omega)(qa, va, aa, f.momentum, f.angular_momentum))
        for name, Q in f.fields.items():
            for j, coordinate in enumerate(part.fields[name]):
                entries[coordinate] = entries[coordinate] + Q[j]
    return total + ca.vertcat(*entries)


def frame_transport(chain: KaneChain, velocity: ca.MX, omega: ca.MX) -> ca.Function:
    """E(V_L·c + ω·d) = d/dt ∂/∂q̇ − ∂/∂q of the frame's velocities against fixed vectors c, d.

    For a rigid frame these are the ω × P terms of Euler's equations; written as a derivative, they also
    hold where the frame's R is orthogonal only to second order (a second-order link's tip upstream).
    """
    qa, va, aa = chain.qa, chain.va, chain.aa
    c, d = ca.MX.sym("c", 3), ca.MX.sym("d", 3)
    power = ca.dot(velocity, c) + ca.dot(omega, d)
    transport = (ca.jtimes(ca.gradient(power, va), ca.vertcat(qa, va), ca.vertcat(va, aa))
                 - ca.gradient(power, qa))
    return ca.Function("frame_transport", [qa, va, aa, c, d], [transport])
