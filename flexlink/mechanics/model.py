"""The symbolic model of a scene: energies → Lagrange equations → CasADi Functions.

The mechanics is written once, as energies (seed 000 chapter 3, generalised): kinetic energy T from
the inertia invariants of :mod:`flexlink.mechanics.kinematics`, elastic and gravitational potential V, and
Rayleigh's dissipation function R.  CasADi's automatic differentiation then gives the equations

    r(q, v, a, u, p) = d/dt ∂L/∂q̇ − ∂L/∂q + ∂R/∂q̇ − Q = M(q) a + h(q, v, u, p) = 0,

with no hand-derived Coriolis term.  The three kinematic models differ only in T and V:

* ``"linear"``: first-order kinematics, T evaluated at η = 0 except for the relative motion
  (seed 000 eq. 3.7): with no gravity the equations are linear;
* ``"first-order"``: first-order kinematics, full T: the model loses stiffness with the hub rate;
* ``"second-order"``: foreshortening included, then the equations are truncated to first order in
  the elastic coordinates (seed 000 §3.4.3: terms of order two in η would need third-order
  kinematics to be consistent).

Coordinates are split into *free* ones (integrated by the FMU) and *prescribed* ones
(position-driven joints, whose position, rate and acceleration enter as inputs u); the residual of a
prescribed joint's equation is the torque that its law needs (seed 001 §2.10), an output.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.mechanics.kinematics import (
    LinkDeformation,
    beam_invariants,
    body_invariants,
    body_tip_kinematics,
    link_basis,
    rotation,
    small_rotation,
    tip_kinematics,
    torsion_kinetic,
)
from flexlink.mechanics.shapes import make_basis
from flexlink.mechanics.shapes.body import shell_body
from flexlink.mechanics.shapes.reduction import ModalBeamBasis, ModalTorsionBasis
from flexlink.mechanics.shapes.torsion import make_torsion_basis
from flexlink.scene.loader import Scene, Trajectory


@dataclass(frozen=True)
class Parameter:
    """A tunable physical parameter of the generated model (an FMU parameter)."""

    name: str
    value: float
    unit: str
    description: str
    min: float = -np.inf
    min_exclusive: bool = False


@dataclass(frozen=True)
class Signal:
    """A named entry of the model's input vector u or output vector y."""

    name: str
    unit: str
    description: str
    start: float = 0.0
    fmu_variable: bool = True      # False for the slots of a built-in law (no FMU input)
    feedthrough: bool = False      # output depends directly on inputs (through the acceleration)


@dataclass(frozen=True)
class Law:
    """A position-driven joint: u[u_offset : u_offset + 3] = (θ, θ̇, θ̈)."""

    joint: str
    u_offset: int
    trajectory: Trajectory | None   # None: the host sets <joint>.theta_ref/omega_ref/alpha_ref


@dataclass(frozen=True)
class StartValue:
    """A fixed FMU parameter giving the initial position or rate of a free coordinate."""

    name: str
    coordinate: int
    rate: bool
    value: float
    unit: str
    description: str


@dataclass
class SymbolicModel:
    """Everything code generation, analysis and the reference simulation need about a scene."""

    scene: Scene
    coordinates: list[str]
    nominal_q: np.ndarray
    parameters: list[Parameter]
    inputs: list[Signal]
    laws: list[Law]
    outputs: list[Signal]
    start_values: list[StartValue]
    static_coordinates: list[int]
    residual: ca.Function          # (q, v, a, u, p) -> r
    outputs_function: ca.Function  # (q, v, a, u, p) -> y
    linear_in_state: bool
    jacobian_constant: bool
    terms: list[str] = field(default_factory=list)   # what the model contains and why (explain)
    coordinate_kinds: list[str] = field(default_factory=list)   # "joint" | "link_angle" | "elastic"

    @property
    def n_q(self) -> int:
        return len(self.coordinates)

    @property
    def p0(self) -> np.ndarray:
        return np.array([par.value for par in self.parameters], dtype=float)

    def parameter_index(self, name: str) -> int:
        for i, par in enumerate(self.parameters):
            if par.name == name:
                return i
        raise KeyError(name)

    def output_index(self, name: str) -> int:
        for i, sig in enumerate(self.outputs):
            if sig.name == name:
                return i
        raise KeyError(name)

    def newton_matrix_function(self) -> ca.Function:
        """J = ca ∂r/∂a + cv ∂r/∂v + cq ∂r/∂q as one directional Jacobian (what an implicit step needs)."""
        q, v, a, u, p = (ca.MX.sym(n, *self.residual.size_in(i)) for i, n in enumerate("qvaup"))
        c = [ca.MX.sym(n) for n in ("ca", "cv", "cq")]
        d = ca.MX.sym("d", self.n_q)
        r = self.residual(q + c[2] * d, v + c[1] * d, a + c[0] * d, u, p)
        J = ca.jacobian(r, d)
        J = ca.substitute(J, d, ca.DM.zeros(self.n_q))
        return ca.Function("newton_matrix", [q, v, a, u, p, *c], [ca.densify(J)],
                           ["q", "v", "a", "u", "p", "ca", "cv", "cq"], ["J"])

    def residual_forward_function(self) -> ca.Function:
        """dr = ∂r/∂q dq + ∂r/∂v dv + ∂r/∂a da: one forward directional derivative (compact code for large
        models, whose Newton matrix the C side assembles column by column)."""
        q, v, a, u, p = (ca.MX.sym(n, *self.residual.size_in(i)) for i, n in enumerate("qvaup"))
        dq, dv, da = (ca.MX.sym("d" + n, self.n_q) for n in "qva")
        r = self.residual(q, v, a, u, p)
        dr = ca.jtimes(r, ca.vertcat(q, v, a), ca.vertcat(dq, dv, da))
        return ca.Function("residual_forward", [q, v, a, u, p, dq, dv, da], [ca.densify(dr)],
                           ["q", "v", "a", "u", "p", "dq", "dv", "da"], ["dr"])

    def mass_matrix_function(self) -> ca.Function:
        q, v, a, u, p = (ca.MX.sym(n, *self.residual.size_in(i)) for i, n in enumerate("qvaup"))
        M = ca.jacobian(self.residual(q, v, a, u, p), a)
        return ca.Function("mass_matrix", [q, u, p], [ca.substitute(M, ca.vertcat(v, a), ca.DM.zeros(2 * self.n_q))])

    def default_inputs(self, t: float = 0.0) -> np.ndarray:
        """Model inputs at time t: input start values, built-in laws evaluated."""
        u = np.array([s.start for s in self.inputs], dtype=float)
        for law in self.laws:
            if law.trajectory is not None:
                u[law.u_offset:law.u_offset + 3] = law.trajectory.evaluate(t)
        return u

    def start_state(self) -> tuple[np.ndarray, np.ndarray]:
        q = np.zeros(self.n_q)
        v = np.zeros(self.n_q)
        for s in self.start_values:
            (v if s.rate else q)[s.coordinate] = s.value
        return q, v


def _unsupported(scene: Scene, what: str) -> FlexlinkError:
    where = scene.path or scene.name
    return FlexlinkError(f"{where}: {what} is not supported yet")


def _check_supported(scene: Scene) -> None:
    kinds = {link.kinematics for link in scene.links}
    if len(kinds) > 1:
        raise _unsupported(scene, f"a chain mixing kinematic models {sorted(kinds)} (use one for every link)")
    for link in scene.links:
        if not link.deformation:
            raise _unsupported(scene, f'link "{link.name}": a rigid link (deformation = [])')
        if link.shapes.kind not in ("clamped-free", "polynomial", "fe", "shell"):
            raise _unsupported(scene, f'link "{link.name}": shapes kind {link.shapes.kind!r}')


class _Params:
    """Collects the tunable parameters as they are met; ``sym`` then gives their symbols."""

    def __init__(self):
        self.items: list[Parameter] = []
        self.p: ca.MX | None = None

    def add(self, *args, **kwargs) -> int:
        self.items.append(Parameter(*args, **kwargs))
        return len(self.items) - 1

    def __call__(self, i):
        return 0 if i is None else self.p[i]


@dataclass
class _LinkParts:
    """Per-link bookkeeping while the chain is assembled."""

    eta: list[int]                 # indices of the link's elastic coordinates in the full vector
    fields: dict[str, list[int]]   # "v", "w", "alpha" → indices
    bending: object | None         # ShapeBasis for v and w
    torsion: object | None         # TorsionBasis
    body: object | None = None     # BodyIntegrals of a shell link (its modes deform in every direction)
    i_rho: int = 0
    i_EI: int | None = None
    i_EIo: int | None = None
    i_GJ: int | None = None
    i_mu: int | None = None
    i_kv: int | None = None
    i_pm: int | None = None
    i_pj: int | None = None


def _vee_skew(A):
    """The vector of the skew-symmetric part of a 3×3 matrix (ω from Rᵀ Ṙ)."""
    return 0.5 * ca.vertcat(A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1])


def build_model(scene: Scene) -> SymbolicModel:
    """Build the symbolic model of a serial chain: joint i on the tip frame of link i−1 drives link i."""
    _check_supported(scene)
    tunable = set(scene.fmu.tunable)
    terms: list[str] = []
    kinematics = scene.links[0].kinematics
    second = kinematics == "second-order"
    P = _Params()

    # ---- coordinates: per joint its angle (and motor angle if elastic), then its link's η (v, w, α)
    coordinates: list[str] = []
    kinds: list[str] = []
    nominal: list[float] = []
    joint_coord: list[int] = []        # link-side angle of joint i
    motor_coord: list[int | None] = []
    parts: list[_LinkParts] = []
    for joint, link in zip(scene.joints, scene.links, strict=True):
        if joint.is_elastic:
            motor_coord.append(len(coordinates))
            coordinates.append(f"{joint.name}.motor_theta")
            kinds.append("joint")
            nominal.append(1.0)
            joint_coord.append(len(coordinates))
            coordinates.append(f"{joint.name}.theta")
            kinds.append("link_angle")
            nominal.append(1.0)
        else:
            motor_coord.append(None)
            joint_coord.append(len(coordinates))
            coordinates.append(f"{joint.name}.theta")
            kinds.append("joint")
            nominal.append(1.0)
        bending = torsion = None
        fields: dict[str, list[int]] = {}
        eta: list[int] = []
        if link.is_shell:
            try:
                body = shell_body(link)
            except ValueError as exc:
                raise FlexlinkError(f'{scene.path or scene.name}: link "{link.name}": {exc}') from None
            fields["modes"] = eta = list(range(len(coordinates), len(coordinates) + body.n))
            coordinates += [f"{link.name}.eta[{k + 1}]" for k in range(body.n)]
            kinds += ["elastic"] * body.n
            nominal += [1.0] * body.n
            parts.append(_LinkParts(eta, fields, None, None, body))
            shape = link.shapes
            terms.append(f'link "{link.name}": {body.n} modes of a {shape.section} of DKT + CST shell elements '
                         f"(mesh {'x'.join(map(str, shape.mesh))}, joint held), {kinematics} kinematics")
            continue
        if "v" in link.deformation or "w" in link.deformation:
            bending = make_basis(link.shapes.kind, link.shapes.count, link.length, link.linear_density)
            if link.shapes.modes is not None:
                bending = ModalBeamBasis(bending, link.shapes.modes)
            xs = np.linspace(0.0, link.length, 401)
            scale = np.maximum(np.max(np.abs(bending.evaluate(xs)), axis=0),
                               link.length * np.max(np.abs(bending.evaluate(xs, 1)), axis=0))
        if "alpha" in link.deformation:
            torsion = make_torsion_basis(link.shapes.kind, link.shapes.count, link.length, link.polar_inertia or 0.0)
            if link.shapes.modes is not None:
                torsion = ModalTorsionBasis(torsion, link.shapes.modes)
        for name in ("v", "w", "alpha"):
            if name not in link.deformation:
                continue
            basis = torsion if name == "alpha" else bending
            idx = list(range(len(coordinates), len(coordinates) + basis.n))
            fields[name] = idx
            for k in range(basis.n):
                coordinates.append(f"{link.name}.eta[{len(eta) + k + 1}]")
                kinds.append("elastic")
            if name == "alpha":
                nominal.extend(1.0 / np.max(np.abs(torsion.evaluate(np.linspace(0, link.length, 401))), axis=0))
            else:
                nominal.extend(1.0 / scale)
            eta += idx
        parts.append(_LinkParts(eta, fields, bending, torsion))
        kind = link.shapes.kind if link.shapes.modes is None else f"{link.shapes.kind} ({link.shapes.modes} modes)"
        terms.append(f'link "{link.name}": ' + ", ".join(f"{len(fields[f])} {kind} coordinates for {f}"
                                                         for f in fields) + f", {kinematics} kinematics")

    # ---- parameters (a term is in the model only if the scene needs it, or [fmu] tunable asks)
    for link, part in zip(scene.links, parts, strict=True):
        if link.is_shell:
            part.i_rho = P.add(f"{link.name}.density", link.density, "kg/m3", "density of the shell", 0.0, True)
            part.i_EI = P.add(f"{link.name}.E", link.E, "Pa", "Young's modulus of the shell (its modes are kept)",
                              0.0, True)
        else:
            part.i_rho = P.add(f"{link.name}.linear_density", link.linear_density, "kg/m", "mass per unit length",
                               0.0, True)
        if "v" in part.fields:
            part.i_EI = P.add(f"{link.name}.EI", link.EI, "N.m2", "bending stiffness in the joint's plane", 0.0, True)
        if "w" in part.fields:
            part.i_EIo = P.add(f"{link.name}.EI_out", link.EI_out, "N.m2", "out-of-plane bending stiffness",
                               0.0, True)
        if "alpha" in part.fields:
            part.i_GJ = P.add(f"{link.name}.GJ", link.GJ, "N.m2", "torsional stiffness", 0.0, True)
            part.i_mu = P.add(f"{link.name}.polar_inertia", link.polar_inertia, "kg.m",
                              "polar mass moment of the section per unit length", 0.0)
        if link.kelvin_voigt > 0 or f"{link.name}.kelvin_voigt" in tunable:
            part.i_kv = P.add(f"{link.name}.kelvin_voigt", link.kelvin_voigt, "s", "Kelvin-Voigt damping coefficient",
                              0.0)
            terms.append(f'link "{link.name}": Kelvin-Voigt structural damping')
        pay = link.payload
        if pay.is_present or {f"{link.name}.payload.mass", f"{link.name}.payload.inertia"} & tunable:
            part.i_pm = P.add(f"{link.name}.payload.mass", pay.mass, "kg", "tip payload mass", 0.0)
            if isinstance(pay.inertia, int | float):
                part.i_pj = P.add(f"{link.name}.payload.inertia", float(pay.inertia), "kg.m2",
                                  "tip payload inertia about the joint axis", 0.0)
            else:
                part.i_pj = [P.add(f"{link.name}.payload.inertia[{k + 1}]", float(pay.inertia[k]), "kg.m2",
                                   f"tip payload inertia J{'xyz'[k]}{'xyz'[k]}, tip frame", 0.0) for k in range(3)]
            terms.append(f'link "{link.name}": tip payload')
    i_Ih = [P.add(f"{j.name}.inertia", j.inertia, "kg.m2", "rotor / hub inertia about the axis", 0.0)
            for j in scene.joints]
    i_damp = [P.add(f"{j.name}.damping", j.damping, "N.m.s/rad", "viscous joint damping", 0.0)
              if (j.damping > 0 or f"{j.name}.damping" in tunable) else None for j in scene.joints]
    i_k = [P.add(f"{j.name}.stiffness", j.stiffness, "N.m/rad", "joint stiffness (motor to link)", 0.0, True)
           if j.is_elastic else None for j in scene.joints]
    i_g = None
    if scene.has_gravity or "gravity" in tunable:
        i_g = [P.add(f"gravity[{k + 1}]", scene.gravity[k], "m/s2", "gravity, inertial frame") for k in range(3)]
        terms.append("gravity (non-zero in the scene or tunable)")
    params = P.items
    P.p = p = ca.MX.sym("p", len(params))
    g_vec = ca.vertcat(*[p[i] for i in i_g]) if i_g is not None else ca.DM.zeros(3)

    # ---- inputs: torques, prescribed laws, tip loads
    inputs: list[Signal] = []
    laws: list[Law] = []
    tau_input: dict[int, int] = {}
    prescribed: dict[int, int] = {}      # coordinate → u offset of its law
    for i, joint in enumerate(scene.joints):
        driven = motor_coord[i] if motor_coord[i] is not None else joint_coord[i]
        if joint.drive == "torque":
            tau_input[driven] = len(inputs)
            inputs.append(Signal(f"{joint.name}.tau", "N.m", "joint torque (motor side)"))
        elif joint.drive == "position":
            builtin = joint.trajectory is not None
            prescribed[driven] = len(inputs)
            laws.append(Law(joint.name, len(inputs), joint.trajectory))
            for suffix, unit, what in (("theta_ref", "rad", "angle"), ("omega_ref", "rad/s", "rate"),
                                       ("alpha_ref", "rad/s2", "acceleration")):
                inputs.append(Signal(f"{joint.name}.{suffix}", unit, f"prescribed joint {what}",
                                     fmu_variable=not builtin))
    tip_load = None
    if scene.fmu.tip_load_inputs:
        tip_load = len(inputs)
        for c, unit, what in (("fx", "N", "force"), ("fy", "N", "force"), ("fz", "N", "force"),
                              ("mx", "N.m", "moment"), ("my", "N.m", "moment"), ("mz", "N.m", "moment")):
            inputs.append(Signal(f"tip.{c}", unit, f"external {what} on the tip, inertial frame"))
        terms.append("tip force and moment inputs ([fmu] tip_load_inputs)")
    u = ca.MX.sym("u", len(inputs))

    n_all = len(coordinates)
    qa, va, aa = ca.MX.sym("qa", n_all), ca.MX.sym("va", n_all), ca.MX.sym("aa", n_all)

    def deformation(part: _LinkParts, q, v) -> LinkDeformation:
        f = part.fields

        def pick(x, name):
            return ca.vertcat(*[x[i] for i in f[name]]) if name in f else None

        return LinkDeformation(pick(q, "v"), pick(q, "w"), pick(q, "alpha"),
                               pick(v, "v"), pick(v, "w"), pick(v, "alpha"))

    # ---- energies along the chain (seed 000 ch. 2–3, generalised)
    chain_bodies: list[dict] = []      # per body: mass, ∫ρr, ∫ρṙ, ∫ρ r×ṙ (world, about the world origin)
    joint_frames: list[tuple] = []     # per joint: origin, rotation of the joint frame (world)

    def energies(second_order: bool):
        T = 0
        Vg = 0
        Pp, Rp, wp = ca.DM.zeros(3), ca.DM.eye(3), ca.DM.zeros(3)       # parent frame: origin, rotation, ω
        frames = []
        chain_bodies.clear()
        joint_frames.clear()
        for i, (joint, link, part) in enumerate(zip(scene.joints, scene.links, parts, strict=True)):
            a = np.asarray(joint.axis, float)
            B = ca.DM(link_basis(a))
            th, thd = qa[joint_coord[i]], va[joint_coord[i]]
            Rj = rotation(a, th)
            RL = ca.mtimes(ca.mtimes(Rp, Rj), B)
            wL = ca.mtimes(B.T, ca.mtimes(Rj.T, wp) + ca.DM(a) * thd)
            motor_rate = va[motor_coord[i]] if motor_coord[i] is not None else thd
            T += 0.5 * P(i_Ih[i]) * (ca.dot(ca.DM(a), wp) + motor_rate) ** 2
            joint_frame = ca.mtimes(Rp, Rj)
            # the rotor spins about the joint axis with the shaft: angular momentum only (it sits at the joint)
            bodies = [dict(joint=i, mass=0, moment=ca.DM.zeros(3), momentum=ca.DM.zeros(3),
                           spin=P(i_Ih[i]) * (ca.dot(ca.DM(a), wp) + motor_rate) * ca.mtimes(Rp, ca.DM(a)))]
            rho = p[part.i_rho]
            d = deformation(part, qa, va)
            VL = ca.jtimes(Pp, qa, va) if i > 0 else ca.DM.zeros(3)
            m_unit = link.length                    # mass per unit of the density parameter
            inv = None
            if part.body is not None:
                eta_q = ca.vertcat(*[qa[k] for k in part.eta])
                inv = body_invariants(part.body, eta_q, ca.vertcat(*[va[k] for k in part.eta]))
                m_unit = part.body.volume
            elif part.bending is not None:
                inv = beam_invariants(part.bending.integrals, link.length, d, second_order)
            if inv is not None:
                S1 = inv.first_moment
                S1d = ca.jtimes(S1, qa, va)
                T += 0.5 * rho * (m_unit * ca.dot(VL, VL)
                                  + 2 * ca.dot(ca.mtimes(RL.T, VL), ca.cross(wL, S1) + S1d)
                                  + ca.dot(wL, ca.mtimes(inv.inertia(), wL)) + 2 * ca.dot(wL, inv.angular_momentum)
                                  + inv.relative_kinetic)
            else:                                   # torsion only: the link's axis stays straight
                S1 = ca.vertcat(link.length**2 / 2, 0, 0)
                J = ca.diag(ca.vertcat(0, link.length**3 / 3, link.length**3 / 3))
                T += 0.5 * rho * (link.length * ca.dot(VL, VL) + 2 * ca.dot(ca.mtimes(RL.T, VL), ca.cross(wL, S1))
                                  + ca.dot(wL, ca.mtimes(J, wL)))
            J_link = inv.inertia() if inv is not None else J
            H_link = inv.angular_momentum if inv is not None else ca.DM.zeros(3)
            S1d_link = S1d if inv is not None else ca.DM.zeros(3)
            # ∫ρ ṙ = ρ(L V + R(ω×S1 + Ṡ1));  ∫ρ (r × ṙ) = P × ∫ρṙ + R ρ(S1 × (RᵀV) + J ω + H)
            momentum = rho * (m_unit * VL + ca.mtimes(RL, ca.cross(wL, S1) + S1d_link))
            spin = ca.mtimes(RL, rho * (ca.cross(S1, ca.mtimes(RL.T, VL)) + ca.mtimes(J_link, wL) + H_link))
            if part.torsion is not None:
                T += 0.5 * p[part.i_mu] * torsion_kinetic(part.torsion.integrals, link.length, d, wL[0])
                tor = part.torsion.integrals
                spin += ca.mtimes(RL, ca.vertcat(p[part.i_mu] * (link.length * wL[0]
                                                                 + ca.dot(ca.DM(tor.phi), d.alpha_dot)), 0, 0))
            bodies.append(dict(joint=i, mass=rho * m_unit, moment=rho * m_unit * Pp + ca.mtimes(RL, rho * S1),
                               momentum=momentum, spin=spin + ca.cross(Pp, momentum)))
            if i_g is not None:
                Vg += -ca.dot(g_vec, rho * m_unit * Pp + ca.mtimes(RL, rho * S1))
            if part.body is not None:
                tip = body_tip_kinematics(part.body, eta_q)
            else:
                tip = tip_kinematics(part.bending.integrals if part.bending else None,
                                     part.torsion.integrals if part.torsion else None, link.length, d, second_order)
            Rdef = small_rotation(tip.rotation_vector, second_order)
            Pt = Pp + ca.mtimes(RL, tip.position)
            Rt = ca.mtimes(RL, Rdef)
            Rdef_dot = ca.reshape(ca.jtimes(ca.vec(Rdef), qa, va), 3, 3)
            wt = ca.mtimes(Rdef.T, wL) + _vee_skew(ca.mtimes(Rdef.T, Rdef_dot))
            if part.i_pm is not None:
                # the payload's velocity in the link basis: base velocity + ω × s_p + ṡ_p (no world
                # rotation in it, so that a linear model stays structurally linear)
                offset = ca.DM(np.asarray(link.payload.offset, float))
                sp = tip.position + ca.mtimes(Rdef, offset)
                Vp = ca.mtimes(RL.T, VL) + ca.cross(wL, sp) + ca.jtimes(sp, qa, va)
                rp = Pp + ca.mtimes(RL, sp)
                T += 0.5 * p[part.i_pm] * ca.dot(Vp, Vp)
                if isinstance(part.i_pj, list):
                    Jp = ca.diag(ca.vertcat(*[p[k] for k in part.i_pj]))
                else:
                    Jp = ca.diag(ca.vertcat(0, 0, p[part.i_pj]))
                T += 0.5 * ca.dot(wt, ca.mtimes(Jp, wt))
                if i_g is not None:
                    Vg += -p[part.i_pm] * ca.dot(g_vec, rp)
                mom_p = p[part.i_pm] * ca.mtimes(RL, Vp)
                bodies.append(dict(joint=i, mass=p[part.i_pm], moment=p[part.i_pm] * rp, momentum=mom_p,
                                   spin=ca.cross(rp, mom_p) + ca.mtimes(Rt, ca.mtimes(Jp, wt))))
            chain_bodies.extend(bodies)
            joint_frames.append((Pp, joint_frame))
            frames.append((Pp, RL, wL, Pt, Rt, wt, tip))
            Pp, Rp, wp = Pt, Rt, wt
        return T, Vg, frames

    T, Vg, frames = energies(second)
    eta_all = [k for part in parts for k in part.eta]
    if kinematics == "linear":
        # T at η = 0, the rates kept (seed 000 eq. 3.7)
        mask = ca.DM([0.0 if k in set(eta_all) else 1.0 for k in range(len(coordinates))])
        T = ca.Function("T", [qa, va, p], [T])(qa * mask, va, p)
    Ve = 0
    R = 0
    for i, (joint, part) in enumerate(zip(scene.joints, parts, strict=True)):
        q_d = deformation(part, qa, va)
        if part.body is not None:
            x = ca.vertcat(*[qa[k] for k in part.eta])
            xd = ca.vertcat(*[va[k] for k in part.eta])
            K = ca.DM(part.body.stiffness)
            Ve += 0.5 * p[part.i_EI] * ca.dot(x, ca.mtimes(K, x))
            if part.i_kv is not None:
                R += 0.5 * p[part.i_kv] * p[part.i_EI] * ca.dot(xd, ca.mtimes(K, xd))
        for name, stiff_i in (("v", part.i_EI), ("w", part.i_EIo), ("alpha", part.i_GJ)):
            if name not in part.fields:
                continue
            K = ca.DM(part.torsion.integrals.stiff if name == "alpha" else part.bending.integrals.curv)
            x = getattr(q_d, name)
            xd = getattr(q_d, f"{name}_dot")
            Ve += 0.5 * p[stiff_i] * ca.dot(x, ca.mtimes(K, x))
            if part.i_kv is not None:
                R += 0.5 * p[part.i_kv] * p[stiff_i] * ca.dot(xd, ca.mtimes(K, xd))
        driven = motor_coord[i] if motor_coord[i] is not None else joint_coord[i]
        if i_damp[i] is not None:
            R += 0.5 * p[i_damp[i]] * va[driven] ** 2
        if i_k[i] is not None:
            Ve += 0.5 * p[i_k[i]] * (qa[motor_coord[i]] - qa[joint_coord[i]]) ** 2
            terms.append(f'joint "{joint.name}": elastic (stiffness > 0), motor and link angles')

    # generalized forces: joint torques and the tip load's power F·ṙ_tip + M·ω_tip
    Q = ca.MX.zeros(n_all)
    for k, j in tau_input.items():
        Q[k] = u[j]
    Pt_last, Rt_last, wt_last = frames[-1][3], frames[-1][4], frames[-1][5]
    if tip_load is not None:
        power = (ca.dot(u[tip_load:tip_load + 3], ca.jtimes(Pt_last, qa, va))
                 + ca.dot(u[tip_load + 3:tip_load + 6], ca.mtimes(Rt_last, wt_last)))
        Q += ca.gradient(power, va)

    # ---- Lagrange's equations by automatic differentiation
    Lag = T - Ve - Vg
    dL_dv = ca.gradient(Lag, va)
    r_all = (ca.jtimes(dL_dv, va, aa) + ca.jtimes(dL_dv, qa, va) - ca.gradient(Lag, qa)
             + ca.gradient(R, va) - Q)
    r_all_f = ca.Function("r_all", [qa, va, aa, u, p], [r_all])
    if second:
        # keep the equations exact to first order in (η, η̇, η̈) (seed 000 §3.4.3)
        eps = ca.MX.sym("eps")
        scale = ca.vertcat(*[eps if k in set(eta_all) else 1 for k in range(n_all)])
        r_eps = r_all_f(qa * scale, va * scale, aa * scale, u, p)
        both = ca.Function("trunc", [eps, qa, va, aa, u, p], [r_eps, ca.jtimes(r_eps, eps, ca.DM(1))])
        r0, r1 = both(0, qa, va, aa, u, p)
        r_all_f = ca.Function("r_all", [qa, va, aa, u, p], [r0 + r1])
        terms.append("second-order kinematics: foreshortening, equations kept to first order in η")

    # ---- free and prescribed coordinates
    free = [k for k in range(n_all) if k not in prescribed]
    n_free = len(free)
    q, v, a = ca.MX.sym("q", n_free), ca.MX.sym("v", n_free), ca.MX.sym("a", n_free)

    def assemble(x, slot):
        parts_ = []
        for k in range(n_all):
            parts_.append(u[prescribed[k] + slot] if k in prescribed else x[free.index(k)])
        return ca.vertcat(*parts_)

    qa_e, va_e, aa_e = assemble(q, 0), assemble(v, 1), assemble(a, 2)
    r_full = r_all_f(qa_e, va_e, aa_e, u, p)
    residual = ca.Function("residual", [q, v, a, u, p], [r_full[free]], ["q", "v", "a", "u", "p"], ["r"])

    # ---- outputs
    out: list[tuple[Signal, ca.MX]] = []
    r_prescribed = r_all_f(qa, va, aa, u, p)
    for i, (joint, link, part) in enumerate(zip(scene.joints, scene.links, parts, strict=True)):
        out.append((Signal(f"{joint.name}.theta", "rad", "joint angle (link side)"), qa[joint_coord[i]]))
        out.append((Signal(f"{joint.name}.omega", "rad/s", "joint rate (link side)"), va[joint_coord[i]]))
        if motor_coord[i] is not None:
            out.append((Signal(f"{joint.name}.motor_theta", "rad", "motor angle of the elastic joint"),
                        qa[motor_coord[i]]))
        driven = motor_coord[i] if motor_coord[i] is not None else joint_coord[i]
        if driven in prescribed:
            out.append((Signal(f"{joint.name}.tau", "N.m", "joint torque the prescribed law needs",
                               feedthrough=True), r_prescribed[driven]))
        tip = frames[i][6]
        if part.body is not None:
            where = "the mid-point of the free edge" if link.shapes.section == "plate" else "the end section"
            for k, c in ((1, "v"), (2, "w")):
                out.append((Signal(f"{link.name}.tip.{c}", "m", f"tip deflection {c} at {where}"),
                            tip.position[k] - float(part.body.tip_point[k])))
            out.append((Signal(f"{link.name}.tip.twist", "rad", "twist of the end section (rigid fit of its nodes)"),
                        tip.rotation_vector[0]))
            out.append((Signal(f"{link.name}.root.moment", "N.m", "elastic bending moment at the root about the "
                               "joint axis (clamp reactions of the modes)"),
                        p[part.i_EI] * ca.dot(ca.DM(part.body.root_moment), ca.vertcat(*[qa[k] for k in part.eta]))))
        if "v" in part.fields:
            out.append((Signal(f"{link.name}.tip.v", "m", "in-plane tip deflection v(L)"), tip.position[1]))
        if "w" in part.fields:
            out.append((Signal(f"{link.name}.tip.w", "m", "out-of-plane tip deflection w(L)"), tip.position[2]))
        if "alpha" in part.fields:
            out.append((Signal(f"{link.name}.tip.twist", "rad", "tip twist alpha(L)"), tip.rotation_vector[0]))
        if "v" in part.fields:
            curv0 = ca.DM(part.bending.evaluate([0.0], 2)[0])
            ev = ca.vertcat(*[qa[k] for k in part.fields["v"]])
            out.append((Signal(f"{link.name}.root.moment", "N.m", "bending moment at the root EI v''(0)"),
                        p[part.i_EI] * ca.dot(curv0, ev)))
        for n_k, k in enumerate(part.eta):
            out.append((Signal(f"{link.name}.eta[{n_k + 1}]", "", f"elastic coordinate {n_k + 1}"), qa[k]))
    # joint reactions (seed 001 §2.10): the force and moment the parent exerts on everything beyond joint i,
    # from Newton–Euler on that subtree: F = d/dt Σ∫ṙ − Σ m g − F_tip,
    # M_O = d/dt Σ∫(r−O)×ṙ + Ȯ × Σ∫ṙ − Σ (∫r − m O) × g − (P_tip − O) × F_tip − M_tip, in the joint frame
    def rate(x):
        return ca.jtimes(x, qa, va) + ca.jtimes(x, va, aa)

    for i, joint in enumerate(scene.joints):
        sub = [b for b in chain_bodies if b["joint"] >= i]
        O, Rjf = joint_frames[i]
        mass = sum(b["mass"] for b in sub)
        moment = sum(b["moment"] for b in sub)
        momentum = sum(b["momentum"] for b in sub)
        spin = sum(b["spin"] for b in sub)
        force = rate(momentum) - mass * g_vec
        O_dot = ca.jtimes(O, qa, va) if i > 0 else ca.DM.zeros(3)
        torque = rate(spin - ca.cross(O, momentum)) + ca.cross(O_dot, momentum) - ca.cross(moment - mass * O, g_vec)
        if tip_load is not None:
            force -= u[tip_load:tip_load + 3]
            torque -= ca.cross(Pt_last - O, u[tip_load:tip_load + 3]) + u[tip_load + 3:tip_load + 6]
        f_local, m_local = ca.mtimes(Rjf.T, force), ca.mtimes(Rjf.T, torque)
        for k, c in enumerate("xyz"):
            out.append((Signal(f"{joint.name}.reaction.f{c}", "N", f"force transmitted by the joint, joint frame {c}",
                               feedthrough=True), f_local[k]))
        for k, c in enumerate("xyz"):
            out.append((Signal(f"{joint.name}.reaction.m{c}", "N.m",
                               f"moment transmitted by the joint about its origin, joint frame {c}",
                               feedthrough=True), m_local[k]))
    v_tip = ca.jtimes(Pt_last, qa, va)
    a_tip = ca.jtimes(v_tip, qa, va) + ca.jtimes(v_tip, va, aa)
    for k, c in enumerate("xyz"):
        out.append((Signal(f"tip.{c}", "m", f"end-effector position {c}, inertial frame"), Pt_last[k]))
    for k, c in enumerate("xyz"):
        out.append((Signal(f"tip.a{c}", "m/s2", f"end-effector absolute acceleration {c}", feedthrough=True),
                    a_tip[k]))
    specific = ca.mtimes(Rt_last.T, a_tip - g_vec)
    for k, c in enumerate("xyz"):
        out.append((Signal(f"tip.s{c}", "m/s2", f"tip accelerometer specific force {c}, tip frame",
                           feedthrough=True), specific[k]))
    out.append((Signal("energy.kinetic", "J", "kinetic energy"), T))
    out.append((Signal("energy.potential", "J", "elastic and gravitational potential energy"), Ve + Vg))
    y_f = ca.Function("y_all", [qa, va, aa, u, p], [ca.vertcat(*[e for _, e in out])])
    outputs_function = ca.Function("outputs", [q, v, a, u, p], [y_f(qa_e, va_e, aa_e, u, p)],
                                   ["q", "v", "a", "u", "p"], ["y"])

    # ---- start values and initial deformation
    start_values: list[StartValue] = []
    static: list[int] = []
    for i, (joint, link, part) in enumerate(zip(scene.joints, scene.links, parts, strict=True)):
        for k in (motor_coord[i], joint_coord[i]):
            if k is None or k in prescribed:
                continue
            suffix = "motor_" if k == motor_coord[i] else ""
            angle = joint.initial_angle
            if joint.trajectory is not None:          # a position-driven elastic joint: start unstretched
                angle = joint.trajectory.evaluate(0.0)[0]
            start_values.append(StartValue(f"{joint.name}.{suffix}initial_angle", free.index(k), False, angle,
                                           "rad", f"initial {suffix.replace('_', ' ')}angle"))
            start_values.append(StartValue(f"{joint.name}.{suffix}initial_rate", free.index(k), True,
                                           joint.initial_rate, "rad/s", f"initial {suffix.replace('_', ' ')}rate"))
        if link.initial_deformation == "static":
            static += [free.index(k) for k in part.eta]
            if motor_coord[i] is not None and joint_coord[i] not in prescribed:
                static.append(free.index(joint_coord[i]))

    linear, constant = _structure(residual)
    return SymbolicModel(
        scene=scene, coordinates=[coordinates[k] for k in free], nominal_q=np.array([nominal[k] for k in free]),
        parameters=params, inputs=inputs, laws=laws, outputs=[s for s, _ in out], start_values=start_values,
        static_coordinates=sorted(static), residual=residual, outputs_function=outputs_function,
        linear_in_state=linear, jacobian_constant=constant, terms=terms,
        coordinate_kinds=[kinds[k] for k in free])


def _structure(residual: ca.Function) -> tuple[bool, bool]:
    """(linear in the state, Newton matrix constant) — decided on the scalar expansion, where CasADi
    folds structural zeros that the matrix graph keeps."""
    f = residual.expand()
    q, v, a, u, p = (ca.SX.sym(n, *f.size_in(i)) for i, n in enumerate("qvaup"))
    state = ca.vertcat(q, v, a)
    J = ca.jacobian(f(q, v, a, u, p), state)
    linear = not ca.depends_on(J, state)
    return linear, linear and not ca.depends_on(J, u)
