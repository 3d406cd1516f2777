"""The symbolic model of a scene: energies → Lagrange equations → CasADi Functions.

The mechanics is written once, as energies (seed 000 chapter 3, generalised): kinetic energy T from
the inertia invariants of :mod:`flexlink.kinematics`, elastic and gravitational potential V, and
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
from flexlink.kinematics import beam_invariants, link_basis, rot_z, tip_kinematics
from flexlink.scene import Scene, Trajectory
from flexlink.shapes import make_basis


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
    return FlexlinkError(f"{where}: {what} is not supported yet (chains and spatial links come with "
                         "the chains issue); this version models one planar link (deformation = [\"v\"])")


def _check_supported(scene: Scene) -> None:
    if len(scene.links) != 1:
        raise _unsupported(scene, f"a chain of {len(scene.links)} links")
    link, joint = scene.links[0], scene.joints[0]
    if tuple(link.deformation) != ("v",):
        raise _unsupported(scene, f'link "{link.name}": deformation {list(link.deformation)}')
    if joint.stiffness > 0:
        raise _unsupported(scene, f'joint "{joint.name}": an elastic joint (stiffness > 0)')
    if not isinstance(link.payload.inertia, int | float):
        raise _unsupported(scene, f'link "{link.name}": a 3-axis payload inertia')
    if any(x != 0 for x in link.payload.offset):
        raise _unsupported(scene, f'link "{link.name}": a payload offset')
    if scene.fmu.tip_load_inputs:
        raise _unsupported(scene, "tip load inputs (tip.fx … tip.mz)")


class _Params:
    """Collects the tunable parameters as they are met, then hands out their symbols."""

    def __init__(self):
        self.items: list[Parameter] = []

    def add(self, *args, **kwargs) -> int:
        self.items.append(Parameter(*args, **kwargs))
        return len(self.items) - 1


def build_model(scene: Scene) -> SymbolicModel:
    """Build the symbolic model of a one-link scene (a joint on a fixed base driving one link)."""
    _check_supported(scene)
    link, joint = scene.links[0], scene.joints[0]
    tunable = set(scene.fmu.tunable)
    terms: list[str] = []

    basis = make_basis(link.shapes.kind, link.shapes.count, link.length, link.linear_density)
    shp = basis.integrals
    n_eta = basis.n
    second = link.kinematics == "second-order"
    terms.append(f'link "{link.name}": {n_eta} {link.shapes.kind} shape coordinates for v, '
                 f'{link.kinematics} kinematics')

    # ---- parameters
    P = _Params()
    i_rho = P.add(f"{link.name}.linear_density", link.linear_density, "kg/m", "mass per unit length", 0.0, True)
    i_EI = P.add(f"{link.name}.EI", link.EI, "N.m2", "bending stiffness in the joint's plane", 0.0, True)
    i_kv = None
    if link.kelvin_voigt > 0 or f"{link.name}.kelvin_voigt" in tunable:
        i_kv = P.add(f"{link.name}.kelvin_voigt", link.kelvin_voigt, "s", "Kelvin-Voigt damping coefficient", 0.0)
        terms.append("Kelvin-Voigt structural damping (kelvin_voigt > 0 or tunable)")
    pay = link.payload
    has_payload = pay.is_present or {f"{link.name}.payload.mass", f"{link.name}.payload.inertia"} & tunable
    i_pm = i_pj = None
    if has_payload:
        i_pm = P.add(f"{link.name}.payload.mass", pay.mass, "kg", "tip payload mass", 0.0)
        i_pj = P.add(f"{link.name}.payload.inertia", float(pay.inertia), "kg.m2",
                     "tip payload inertia about the joint axis", 0.0)
        terms.append("tip payload (mass or inertia non-zero, or tunable)")
    i_Ih = P.add(f"{joint.name}.inertia", joint.inertia, "kg.m2", "rotor / hub inertia about the axis", 0.0)
    i_mu = None
    if joint.damping > 0 or f"{joint.name}.damping" in tunable:
        i_mu = P.add(f"{joint.name}.damping", joint.damping, "N.m.s/rad", "viscous joint damping", 0.0)
        terms.append("viscous joint damping (damping > 0 or tunable)")
    i_g = None
    if scene.has_gravity or "gravity" in tunable:
        i_g = [P.add(f"gravity[{k + 1}]", scene.gravity[k], "m/s2", "gravity, inertial frame") for k in range(3)]
        terms.append("gravity (non-zero in the scene or tunable)")
    params = P.items
    p = ca.MX.sym("p", len(params))

    def par(i):
        return 0 if i is None else p[i]

    rho, EI = p[i_rho], p[i_EI]
    m_p, J_p = par(i_pm), par(i_pj)

    # ---- all coordinates: joint angle, then the elastic coordinates
    theta, theta_d, theta_dd = ca.MX.sym("theta"), ca.MX.sym("theta_d"), ca.MX.sym("theta_dd")
    eta, eta_d, eta_dd = ca.MX.sym("eta", n_eta), ca.MX.sym("eta_d", n_eta), ca.MX.sym("eta_dd", n_eta)
    qa, va, aa = ca.vertcat(theta, eta), ca.vertcat(theta_d, eta_d), ca.vertcat(theta_dd, eta_dd)

    # ---- inputs
    inputs: list[Signal] = []
    laws: list[Law] = []
    if joint.drive == "torque":
        inputs.append(Signal(f"{joint.name}.tau", "N.m", "joint torque"))
    elif joint.drive == "position":
        builtin = joint.trajectory is not None
        laws.append(Law(joint.name, len(inputs), joint.trajectory))
        for suffix, unit, what in (("theta_ref", "rad", "angle"), ("omega_ref", "rad/s", "rate"),
                                   ("alpha_ref", "rad/s2", "acceleration")):
            inputs.append(Signal(f"{joint.name}.{suffix}", unit, f"prescribed joint {what}",
                                 fmu_variable=not builtin))
    u = ca.MX.sym("u", len(inputs))

    # ---- energies (seed 000 eqs. 3.5-3.10 and 3.32-3.36)
    def kinetic_and_gravity(second_order: bool):
        inv = beam_invariants(shp, link.length, eta, eta_d, second_order)
        T = 0.5 * rho * (theta_d**2 * inv.planar_inertia + 2 * theta_d * inv.angular_momentum_z
                         + inv.relative_kinetic)
        T += 0.5 * par(i_Ih) * theta_d**2
        tip = tip_kinematics(shp, link.length, eta, eta_d, second_order)
        if has_payload:
            s, sd = tip.position, tip.velocity
            T += 0.5 * m_p * (theta_d**2 * (s[0]**2 + s[1]**2) + 2 * theta_d * (s[0] * sd[1] - s[1] * sd[0])
                              + ca.dot(sd, sd))
            T += 0.5 * J_p * (theta_d + tip.slope_rate)**2
        Vg = 0
        rotation = ca.mtimes(ca.DM(link_basis(joint.axis)), rot_z(theta))
        if i_g is not None:
            g = ca.vertcat(*[p[i] for i in i_g])
            Vg = -ca.dot(g, ca.mtimes(rotation, rho * inv.first_moment + m_p * tip.position))
        return T, Vg, tip, rotation

    T, Vg, tip, rotation = kinetic_and_gravity(second)
    if link.kinematics == "linear":
        T = ca.substitute(T, eta, ca.DM.zeros(n_eta))
    curv = ca.DM(shp.curv)
    Ve = 0.5 * EI * ca.dot(eta, ca.mtimes(curv, eta))
    R = 0.5 * par(i_mu) * theta_d**2
    if i_kv is not None:
        R += 0.5 * p[i_kv] * EI * ca.dot(eta_d, ca.mtimes(curv, eta_d))
    Q = ca.MX.zeros(1 + n_eta)
    if joint.drive == "torque":
        Q[0] = u[0]

    # ---- Lagrange's equations by automatic differentiation
    Lag = T - Ve - Vg
    dL_dv = ca.gradient(Lag, va)
    r_all = (ca.jtimes(dL_dv, va, aa) + ca.jtimes(dL_dv, qa, va) - ca.gradient(Lag, qa)
             + ca.gradient(R, va) - Q)
    r_all_f = ca.Function("r_all", [qa, va, aa, u, p], [r_all])
    if second:
        # keep the equations exact to first order in (η, η̇, η̈) (seed 000 §3.4.3)
        eps = ca.MX.sym("eps")
        scale = ca.vertcat(1, eps * ca.DM.ones(n_eta))
        r_eps = r_all_f(qa * scale, va * scale, aa * scale, u, p)
        both = ca.Function("trunc", [eps, qa, va, aa, u, p], [r_eps, ca.jtimes(r_eps, eps, ca.DM(1))])
        r0, r1 = both(0, qa, va, aa, u, p)
        r_all_f = ca.Function("r_all", [qa, va, aa, u, p], [r0 + r1])
        terms.append("second-order kinematics: foreshortening, equations kept to first order in η")

    # ---- free and prescribed coordinates
    prescribed = joint.drive == "position"
    n_free = n_eta + (0 if prescribed else 1)
    q, v, a = ca.MX.sym("q", n_free), ca.MX.sym("v", n_free), ca.MX.sym("a", n_free)
    if prescribed:
        o = laws[0].u_offset
        qa_e, va_e, aa_e = (ca.vertcat(u[o + k], x) for k, x in enumerate((q, v, a)))
        free_rows = list(range(1, 1 + n_eta))
    else:
        qa_e, va_e, aa_e = q, v, a
        free_rows = list(range(1 + n_eta))
    r_full = r_all_f(qa_e, va_e, aa_e, u, p)
    residual = ca.Function("residual", [q, v, a, u, p], [r_full[free_rows]],
                           ["q", "v", "a", "u", "p"], ["r"])

    coordinates = ([] if prescribed else [f"{joint.name}.theta"]) + [f"{link.name}.eta[{k + 1}]"
                                                                      for k in range(n_eta)]
    xs = np.linspace(0.0, link.length, 401)
    phi_max = np.max(np.abs(basis.evaluate(xs)), axis=0)
    slope_max = link.length * np.max(np.abs(basis.evaluate(xs, 1)), axis=0)
    nominal_eta = 1.0 / np.maximum(phi_max, slope_max)
    nominal_q = np.concatenate([[] if prescribed else [1.0], nominal_eta])

    # ---- outputs
    out: list[tuple[Signal, ca.MX]] = []
    out.append((Signal(f"{joint.name}.theta", "rad", "joint angle"), theta))
    out.append((Signal(f"{joint.name}.omega", "rad/s", "joint rate"), theta_d))
    if prescribed:
        out.append((Signal(f"{joint.name}.tau", "N.m", "joint torque the prescribed law needs",
                           feedthrough=True), r_all_f(qa, va, aa, u, p)[0]))
    out.append((Signal(f"{link.name}.tip.v", "m", "in-plane tip deflection v(L)"), tip.position[1]))
    out.append((Signal(f"{link.name}.root.moment", "N.m", "bending moment at the root EI v''(0)"),
                EI * ca.dot(ca.DM(shp.root_curvature), eta)))
    for k in range(n_eta):
        out.append((Signal(f"{link.name}.eta[{k + 1}]", "", f"elastic coordinate {k + 1}"), eta[k]))
    r_tip = ca.mtimes(rotation, tip.position)
    v_tip = ca.jtimes(r_tip, qa, va)
    a_tip = ca.jtimes(v_tip, qa, va) + ca.jtimes(v_tip, va, aa)
    for k, c in enumerate("xyz"):
        out.append((Signal(f"tip.{c}", "m", f"end-effector position {c}, inertial frame"), r_tip[k]))
    for k, c in enumerate("xyz"):
        out.append((Signal(f"tip.a{c}", "m/s2", f"end-effector absolute acceleration {c}", feedthrough=True),
                    a_tip[k]))
    g_vec = ca.vertcat(*[p[i] for i in i_g]) if i_g is not None else ca.DM.zeros(3)
    tip_frame = ca.mtimes(rotation, rot_z(tip.slope))
    specific = ca.mtimes(tip_frame.T, a_tip - g_vec)
    for k, c in enumerate("xyz"):
        out.append((Signal(f"tip.s{c}", "m/s2", f"tip accelerometer specific force {c}, tip frame",
                           feedthrough=True), specific[k]))
    out.append((Signal("energy.kinetic", "J", "kinetic energy"), T))
    out.append((Signal("energy.potential", "J", "elastic and gravitational potential energy"), Ve + Vg))
    y_all = ca.vertcat(*[e for _, e in out])
    y_f = ca.Function("y_all", [qa, va, aa, u, p], [y_all])
    outputs_function = ca.Function("outputs", [q, v, a, u, p], [y_f(qa_e, va_e, aa_e, u, p)],
                                   ["q", "v", "a", "u", "p"], ["y"])

    # ---- start values and initial deformation
    start_values: list[StartValue] = []
    if not prescribed:
        start_values.append(StartValue(f"{joint.name}.initial_angle", 0, False, joint.initial_angle, "rad",
                                       "initial joint angle"))
        start_values.append(StartValue(f"{joint.name}.initial_rate", 0, True, joint.initial_rate, "rad/s",
                                       "initial joint rate"))
    first_eta = 0 if prescribed else 1
    static = list(range(first_eta, n_free)) if link.initial_deformation == "static" else []

    # ---- structure: which equations are linear (CasADi tells)
    linear, constant = _structure(residual)

    return SymbolicModel(
        scene=scene, coordinates=coordinates, nominal_q=nominal_q, parameters=params, inputs=inputs,
        laws=laws, outputs=[s for s, _ in out], start_values=start_values, static_coordinates=static,
        residual=residual, outputs_function=outputs_function, linear_in_state=linear,
        jacobian_constant=constant, terms=terms)


def _structure(residual: ca.Function) -> tuple[bool, bool]:
    """(linear in the state, Newton matrix constant) — decided on the scalar expansion, where CasADi
    folds structural zeros that the matrix graph keeps."""
    f = residual.expand()
    q, v, a, u, p = (ca.SX.sym(n, *f.size_in(i)) for i, n in enumerate("qvaup"))
    state = ca.vertcat(q, v, a)
    J = ca.jacobian(f(q, v, a, u, p), state)
    linear = not ca.depends_on(J, state)
    return linear, linear and not ca.depends_on(J, u)
