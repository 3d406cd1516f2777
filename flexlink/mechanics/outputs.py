"""What a chain's model reports: joint and link outputs, joint reactions, the end effector, energies, validity.

Every output is an expression in the full coordinates (q, q̇, q̈) of a :class:`ChainAssembly`; the builder
turns them into one Function of the free coordinates.  The *validity* function measures, as ratios that must
stay ≤ 1, how far the state is from what a small-deflection beam model is meant for; the FMU refuses a step
that leaves this range instead of returning numbers the model cannot stand behind (docs/integrator.md, "Guards").
"""

from __future__ import annotations

from typing import Any

import casadi as ca

from flexlink.mechanics.assembly import ChainAssembly, Frame, LinkParts
from flexlink.mechanics.kinematics import TipKinematics
from flexlink.mechanics.symbolic import Signal

#: Largest tip deflection a link's beam model is trusted for, as a fraction of its length.  The mass matrix
#: of the second-order model stays positive definite well beyond it (its smallest eigenvalue is 0.99 of the
#: undeformed one at 10 % and 0.61 at 20 % for smooth deflections of a two-link arm, tests/test_mass_matrix.py),
#: and the small-rotation kinematics of the tip frame are off by ≈ ψ²/6 ≈ 1 % at this size.
DEFLECTION_LIMIT = 0.2
#: Largest tip rotation (bending slope or twist, rad) the small-rotation tip frame is trusted for (20°).
ROTATION_LIMIT = 0.35


def _tip(part: LinkParts) -> TipKinematics:
    """The link's tip kinematics: ``ChainAssembly.assemble_kinematics`` sets them on every link, rigid ones too."""
    assert part.tip is not None, "outputs are formed after the chain's kinematics"
    return part.tip


def _stiffness_index(part: LinkParts) -> int:
    """Where the link's bending stiffness (EI, or E of a shell) sits in p: every elastic link has one."""
    assert part.i_EI is not None, "a beam link with v, or a shell link, has a stiffness parameter"
    return part.i_EI


def _link_outputs(chain: ChainAssembly, i: int) -> list[tuple[Signal, ca.MX | ca.DM]]:
    """Joint i's angle, rate (and prescribed torque), its link's tip deflections, root moment and coordinates."""
    joint, link, part = chain.scene.joints[i], chain.scene.links[i], chain.parts[i]
    qa, va, p = chain.qa, chain.va, chain.p
    out: list[tuple[Signal, ca.MX | ca.DM]] = [
        (Signal(f"{joint.name}.theta", "rad", "joint angle (link side)"), qa[chain.joint_coord[i]]),
        (Signal(f"{joint.name}.omega", "rad/s", "joint rate (link side)"), va[chain.joint_coord[i]])]
    motor = chain.motor_coord[i]
    if motor is not None:
        out.append((Signal(f"{joint.name}.motor_theta", "rad", "motor angle of the elastic joint"), qa[motor]))
    if chain.driven(i) in chain.prescribed:
        out.append((Signal(f"{joint.name}.tau", "N.m", "joint torque the prescribed law needs", feedthrough=True),
                    chain.r_all_expr[chain.driven(i)]))
    tip = _tip(part)
    if part.body is not None:
        where = "the mid-point of the free edge" if link.shapes.section == "plate" else "the end section"
        for k, c in ((1, "v"), (2, "w")):
            out.append((Signal(f"{link.name}.tip.{c}", "m", f"tip deflection {c} at {where}"),
                        tip.position[k] - float(part.body.tip_point[k])))
        out.append((Signal(f"{link.name}.tip.twist", "rad", "twist of the end section (rigid fit of its nodes)"),
                    tip.rotation_vector[0]))
        out.append((Signal(f"{link.name}.root.moment", "N.m", "elastic bending moment at the root about the "
                           "joint axis (clamp reactions of the modes)"),
                    p[_stiffness_index(part)] * ca.dot(ca.DM(part.body.root_moment), chain.eta_of(part, qa))))
    if "v" in part.fields:
        out.append((Signal(f"{link.name}.tip.v", "m", "in-plane tip deflection v(L)"), tip.position[1]))
    if "w" in part.fields:
        out.append((Signal(f"{link.name}.tip.w", "m", "out-of-plane tip deflection w(L)"), tip.position[2]))
    if "alpha" in part.fields:
        out.append((Signal(f"{link.name}.tip.twist", "rad", "tip twist alpha(L)"), tip.rotation_vector[0]))
    if "v" in part.fields:
        assert part.bending is not None, "a link with v coordinates has a bending basis"
        curv0 = ca.DM(part.bending.evaluate([0.0], 2)[0])
        ev = ca.vertcat(*[qa[k] for k in part.fields["v"]])
        out.append((Signal(f"{link.name}.root.moment", "N.m", "bending moment at the root EI v''(0)"),
                    p[_stiffness_index(part)] * ca.dot(curv0, ev)))
    for n_k, k in enumerate(part.eta):
        out.append((Signal(f"{link.name}.eta[{n_k + 1}]", "", f"elastic coordinate {n_k + 1}"), qa[k]))
    return out


def _subtree_sums(chain: ChainAssembly) -> list[dict]:
    """Mass, first moment, momentum and angular momentum (about the world origin) beyond each joint.

    Suffix sums from the tip, so the n subtrees cost n additions, not n²/2.  The momenta of the bodies' records
    are differentiated by CasADi; a link whose foreshortening's equations take Kane's form
    (:class:`~flexlink.mechanics.kane.KaneLink`) adds that share's momenta with their rates formed by hand
    (``momentum_rate``, ``spin_rate``: zero where every body is differentiated by CasADi).
    """
    n = len(chain.scene.joints)
    sums: list[dict] = [{}] * n
    running: dict[str, Any] = dict(mass=0, moment=ca.DM.zeros(3), momentum=ca.DM.zeros(3), spin=ca.DM.zeros(3),
                   momentum_rate=ca.DM.zeros(3), spin_rate=ca.DM.zeros(3), kane_momentum=ca.DM.zeros(3),
                   kane_spin=ca.DM.zeros(3))
    kane = {id(k.part): k for k in chain.kane_links}
    for i in reversed(range(n)):
        for b in (b for b in chain.bodies if b["joint"] == i):
            running = {k: running[k] + b[k] if k in b else running[k] for k in running}
        if id(chain.parts[i]) in kane:
            momentum, momentum_rate, spin, spin_rate = kane[id(chain.parts[i])].momenta(chain)
            running = {**running, "momentum": running["momentum"] + momentum, "spin": running["spin"] + spin,
                       "momentum_rate": running["momentum_rate"] + momentum_rate,
                       "spin_rate": running["spin_rate"] + spin_rate,
                       "kane_momentum": running["kane_momentum"] + momentum, "kane_spin": running["kane_spin"] + spin}
        sums[i] = running
    return sums


def _joint_reactions(chain: ChainAssembly) -> list[tuple[Signal, ca.MX | ca.DM]]:
    """The force and moment the parent exerts on everything beyond each joint (seed 001 §2.10).

    Newton–Euler on that subtree: F = d/dt Σ∫ṙ − Σ m g − F_tip and
    M_O = d/dt Σ∫(r−O)×ṙ + Ȯ × Σ∫ṙ − Σ (∫r − m O) × g − (P_tip − O) × F_tip − M_tip, in the joint frame.
    The time derivatives of every subtree's momenta are one forward derivative of their stacked vector.
    """
    qa, va, aa, u, g = chain.qa, chain.va, chain.aa, chain.u, chain.g_vec
    sums = _subtree_sums(chain)
    origins = [O for O, _ in chain.joint_frames]
    # the momenta CasADi differentiates (without the Kane links' foreshortening share), then that share's rates
    stacked = ca.vertcat(*[ca.vertcat(s["momentum"] - s["kane_momentum"],
                                      s["spin"] - s["kane_spin"] - ca.cross(O, s["momentum"] - s["kane_momentum"]))
                           for s, O in zip(sums, origins, strict=True)])
    rates = ca.jtimes(stacked, qa, va) + ca.jtimes(stacked, va, aa)
    out: list[tuple[Signal, ca.MX | ca.DM]] = []
    for i, (s, (O, Rjf)) in enumerate(zip(sums, chain.joint_frames, strict=True)):
        O_dot = chain.frames[i].velocity
        kane = s["kane_momentum"]
        force = rates[6 * i:6 * i + 3] + s["momentum_rate"] - s["mass"] * g
        # d/dt of the Kane share's spin − O × momentum: Ṡ − Ȯ × P − O × Ṗ
        torque = (rates[6 * i + 3:6 * i + 6] + s["spin_rate"] - ca.cross(O_dot, kane)
                  - ca.cross(O, s["momentum_rate"]) + ca.cross(O_dot, s["momentum"])
                  - ca.cross(s["moment"] - s["mass"] * O, g))
        if chain.tip_load is not None:
            k0 = chain.tip_load
            force -= u[k0:k0 + 3]
            torque -= ca.cross(chain.tool.tip_origin - O, u[k0:k0 + 3]) + u[k0 + 3:k0 + 6]
        f_local, m_local = ca.mtimes(Rjf.T, force), ca.mtimes(Rjf.T, torque)
        name = chain.scene.joints[i].name
        out += ([(Signal(f"{name}.reaction.f{c}", "N", f"force transmitted by the joint, joint frame {c}",
                         feedthrough=True), f_local[k]) for k, c in enumerate("xyz")]
                + [(Signal(f"{name}.reaction.m{c}", "N.m", f"moment transmitted by the joint about its origin, "
                           f"joint frame {c}", feedthrough=True), m_local[k]) for k, c in enumerate("xyz")])
    return out


def _tip_acceleration(chain: ChainAssembly, frame: Frame) -> ca.MX:
    """The absolute acceleration of a frame's tip origin: d/dt of its velocity along (q̇, q̈).

    Exact, so it reads the torques through q̈ (feedthrough).
    """
    v_tip = frame.tip_velocity
    return ca.jtimes(v_tip, chain.qa, chain.va) + ca.jtimes(v_tip, chain.va, chain.aa)


def _specific_force(chain: ChainAssembly, frame: Frame, a_tip: ca.MX) -> ca.MX:
    """What an accelerometer fixed in a frame's tip reads: ``Rᵀ (a − g)``.

    The acceleration less gravity (at rest it reads +g upwards), resolved in that tip frame.
    """
    return ca.mtimes(frame.tip_rotation.T, a_tip - chain.g_vec)


def _link_accelerometer(chain: ChainAssembly, i: int) -> list[tuple[Signal, ca.MX]]:
    """A triaxial accelerometer at link i's tip (declared in the scene: ``sensors = ["accelerometer"]``).

    It sits at the link's tip frame, where the next joint is placed, and reads as ``tip.sx`` … ``tip.sz`` read
    at the last tip: the specific force, gravity included, in the (deflected) tip frame.
    """
    frame = chain.frames[i]
    specific = _specific_force(chain, frame, _tip_acceleration(chain, frame))
    name = chain.scene.links[i].name
    return [(Signal(f"{name}.tip.s{c}", "m/s2", f"tip accelerometer of {name}: specific force {c} (gravity included), "
                    "its tip frame", feedthrough=True), specific[k]) for k, c in enumerate("xyz")]


def _end_effector(chain: ChainAssembly) -> list[tuple[Signal, ca.MX]]:
    """Position, absolute acceleration and accelerometer specific force of the last link's tip."""
    last = chain.tool
    a_tip = _tip_acceleration(chain, last)
    specific = _specific_force(chain, last, a_tip)
    return ([(Signal(f"tip.{c}", "m", f"end-effector position {c}, inertial frame"), last.tip_origin[k])
             for k, c in enumerate("xyz")]
            + [(Signal(f"tip.a{c}", "m/s2", f"end-effector absolute acceleration {c}", feedthrough=True), a_tip[k])
               for k, c in enumerate("xyz")]
            + [(Signal(f"tip.s{c}", "m/s2", f"tip accelerometer specific force {c}, tip frame", feedthrough=True),
                specific[k]) for k, c in enumerate("xyz")])


def chain_outputs(chain: ChainAssembly) -> tuple[list[Signal], list[ca.MX | ca.DM | float]]:
    """Every output of the chain, in the order the FMU lists them: links, reactions, end effector, energies.

    Each link's outputs are followed by those of the sensors it declares (its tip accelerometer).

    The energies are plain numbers only for a chain without mass or stiffness; the builder takes both.
    """
    out: list[tuple[Signal, ca.MX | ca.DM | float]] = []
    for i, link in enumerate(chain.scene.links):
        out += _link_outputs(chain, i)
        if "accelerometer" in link.sensors:
            out += _link_accelerometer(chain, i)
    out += _joint_reactions(chain)
    out += _end_effector(chain)
    # T as the Lagrangian's T_rest and the Kane links' foreshortening share, from the points (the same value)
    kinetic = chain.T_rest + sum((k.forces(chain).energy for k in chain.kane_links), ca.MX(0))
    out.append((Signal("energy.kinetic", "J", "kinetic energy"), kinetic))
    out.append((Signal("energy.potential", "J", "elastic and gravitational potential energy"),
                chain.Ve + chain.Vg))
    return [s for s, _ in out], [e for _, e in out]


def validity(chain: ChainAssembly) -> tuple[ca.Function, list[str]]:
    """g(q, u, p): per beam link, |tip deflection| / (DEFLECTION_LIMIT · L) and |tip rotation| / ROTATION_LIMIT.

    A shell link's modes are checked by their tip deflection against the same fraction of its length.
    Returns the Function and the name of each entry (what the FMU's log line quotes when one exceeds 1).
    """
    names: list[str] = []
    ratios: list = []
    for link, part in zip(chain.scene.links, chain.parts, strict=True):
        tip = _tip(part)
        reach = DEFLECTION_LIMIT * link.length
        offset = part.body.tip_point if part.body is not None else (0.0, 0.0, 0.0)
        bends = [(k, c) for k, c in ((1, "v"), (2, "w")) if c in part.fields or part.body is not None]
        for k, c in bends:
            names.append(f"{link.name}.tip.{c} / ({DEFLECTION_LIMIT:g} x length)")
            ratios.append(ca.fabs(tip.position[k] - float(offset[k])) / reach)
        if part.body is None:
            for k, c in bends:
                names.append(f"{link.name} tip slope d{c}/dx / {ROTATION_LIMIT:g} rad")
                ratios.append(ca.fabs(tip.rotation_vector[3 - k]) / ROTATION_LIMIT)
        if "alpha" in part.fields or part.body is not None:
            names.append(f"{link.name}.tip.twist / {ROTATION_LIMIT:g} rad")
            ratios.append(ca.fabs(tip.rotation_vector[0]) / ROTATION_LIMIT)
    return chain.free_function("model_validity", ratios, with_rates=False), names


def parameter_checks(chain: ChainAssembly) -> tuple[ca.Function | None, list[str]]:
    """h(p): every rigid link's inertial parameters describe a body while every h ≥ 0.

    A tensor J about the centre of mass is a body's exactly when its second moments Σ = ∫ρ r rᵀ = ½ tr(J) 1 − J
    are positive semi-definite (J ⪰ 0 and the triangle inequalities J_xx ≤ J_yy + J_zz … follow): all seven
    principal minors of Σ ≥ 0, each scaled by ½ tr(J) to its power so that the FMU compares them with a
    relative tolerance.  The bounds of single parameters (mass ≥ 0) are the variables' own ``min``.
    Returns None when no rigid link has an inertia tensor.
    """
    names: list[str] = []
    checks: list = []
    p = chain.p
    for link, part in zip(chain.scene.links, chain.parts, strict=True):
        if part.i_I is None:
            continue
        xx, yy, zz, xy, xz, yz = (p[k] for k in part.i_I)
        J = ca.vertcat(ca.horzcat(xx, xy, xz), ca.horzcat(xy, yy, yz), ca.horzcat(xz, yz, zz))
        s = 0.5 * ca.trace(J)
        S = s * ca.DM.eye(3) - J
        minors = [(S[k, k], f"second moment {'xyz'[k]}{'xyz'[k]}", 1) for k in range(3)]
        minors += [(S[a, a] * S[b, b] - S[a, b] ** 2, f"second moments {'xyz'[a]}{'xyz'[b]} minor", 2)
                   for a, b in ((0, 1), (0, 2), (1, 2))]
        minors.append((ca.det(S), "second moments determinant", 3))
        for minor, what, power in minors:
            names.append(f"{link.name}.inertia: {what} >= 0 (a body's inertia: Ixx <= Iyy + Izz ...)")
            checks.append(ca.if_else(s > 0, minor / s**power, 0))
    if not checks:
        return None, []
    return ca.Function("parameter_check", [p], [ca.vertcat(*checks)], ["p"], ["h"]), names
