"""Positions and velocities of the sections of a flexible link, to first or second order.

A link lies along +x of its joint frame; in-plane bending v is along ``axis × x``; the section at
abscissa x sits at ``s(x) = (x + u(x), v(x), w(x))`` in the link's basis ``(e_x, e_v, e_axis)``.
First-order kinematics keep ``u = 0``; second-order kinematics add the foreshortening
``u = −½∫₀ˣ v'² dξ`` (seed 000 §2.5, eq. 3.32), which is what brings the geometric stiffening.

Everything the kinetic and gravitational energies need from the distributed mass is a handful of
*inertia invariants*, polynomials in η with the constant shape integrals as coefficients (seed 000
§3.4.2).  They are built here as matrix operations on constant ``DM`` blocks so that the symbolic
expressions stay small whatever the number of shape functions.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from flexlink.shapes import ShapeIntegrals


def link_basis(axis) -> np.ndarray:
    """Columns e_x, e_v = axis × e_x, e_axis of a link's frame, in its joint's parent frame."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    ex = np.array([1.0, 0.0, 0.0])
    return np.column_stack([ex, np.cross(a, ex), a])


def rot_z(angle) -> ca.MX:
    """Rotation by ``angle`` about the third basis vector (the joint axis in the link basis)."""
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


@dataclass
class BeamInvariants:
    """Inertia invariants of a uniform link per unit linear density, in the link basis.

    ``first_moment`` = ∫ s dx (3), ``planar_inertia`` = ∫ (s_x² + s_v²) dx,
    ``angular_momentum_z`` = ∫ (s_x ṡ_v − s_v ṡ_x) dx, ``relative_kinetic`` = ∫ |ṡ|² dx.
    Terms of order three and more in η are left out: no model keeps them (DESIGN.md §2).
    """

    first_moment: ca.MX
    planar_inertia: ca.MX
    angular_momentum_z: ca.MX
    relative_kinetic: ca.MX


@dataclass
class TipKinematics:
    """Tip point s(L), its rate, and the tip slope angle ψ = v'(L) in the link basis."""

    position: ca.MX
    velocity: ca.MX
    slope: ca.MX
    slope_rate: ca.MX


def _dm(a) -> ca.DM:
    return ca.DM(np.asarray(a, dtype=float))


def _quad(eta: ca.MX, matrix: np.ndarray, other: ca.MX | None = None) -> ca.MX:
    other = eta if other is None else other
    return ca.dot(eta, ca.mtimes(_dm(matrix), other))


def beam_invariants(integrals: ShapeIntegrals, length: float, eta: ca.MX, eta_dot: ca.MX,
                    second_order: bool) -> BeamInvariants:
    """Invariants of the v-bending link, with first- or second-order kinematics."""
    L = float(length)
    g = integrals
    v_moment = ca.dot(_dm(g.phi), eta)
    x_moment = L**2 / 2
    planar = L**3 / 3 + _quad(eta, g.phi_phi)
    if second_order:
        # ∫ u dx = −½ ηᵀ fs η,  ∫ 2 x u dx = −ηᵀ fs_x η  (∫ u² is of order four)
        x_moment = x_moment - 0.5 * _quad(eta, g.fs)
        planar = planar - _quad(eta, g.fs_x)
    first_moment = ca.vertcat(x_moment, v_moment, 0)
    # ∫ (x + u) v̇ − v u̇: the u-terms are of order three
    angular = ca.dot(_dm(g.x_phi), eta_dot)
    relative = _quad(eta_dot, g.phi_phi)
    return BeamInvariants(first_moment, planar, angular, relative)


def tip_kinematics(integrals: ShapeIntegrals, length: float, eta: ca.MX, eta_dot: ca.MX,
                   second_order: bool) -> TipKinematics:
    """The tip point and slope, to the order of the kinematic model (for payloads and outputs)."""
    g = integrals
    v_tip = ca.dot(_dm(g.tip), eta)
    x_tip = float(length)
    if second_order:
        x_tip = x_tip - 0.5 * _quad(eta, g.fs_tip)
    position = ca.vertcat(x_tip, v_tip, 0)
    velocity = ca.jtimes(position, eta, eta_dot)
    slope = ca.dot(_dm(g.tip_slope), eta)
    return TipKinematics(position, velocity, slope, ca.dot(_dm(g.tip_slope), eta_dot))
