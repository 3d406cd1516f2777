"""Assembly of a serial chain's Lagrangian: coordinates, parameters, inputs, energies, equations.

The chain is walked once from the base: joint i sits on the tip frame of link i−1 and drives link i.
Every body contributes its kinetic energy from its inertia invariants (:mod:`flexlink.mechanics.kinematics`),
its gravitational and elastic potential and its Rayleigh dissipation; Lagrange's equations then come from
CasADi's automatic differentiation.  With ``kinematics = "second-order"`` each body's energy is kept to
second order in its own elastic coordinates and the bodies are composed exactly along the chain: nothing is
truncated after differentiation, so ``M = ∂²T/∂q̇²`` stays symmetric and T + V is conserved by the exact
flow (docs/mechanics.md, "Why the second-order model is consistent").

The builder keeps its working state in :class:`ChainAssembly`, which :mod:`flexlink.mechanics.outputs`
reads to form the outputs; :func:`flexlink.mechanics.model.build_model` runs the stages in order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.mechanics.composite import composite_mass_matrix, placement
from flexlink.mechanics.kane import KaneLink, kane_forces, takes_kane_form
from flexlink.mechanics.kinematics import (
    BASE_FRAME,
    LinkDeformation,
    RateGram,
    TipKinematics,
    beam_invariants,
    body_invariants,
    body_tip_kinematics,
    link_basis,
    rotation,
    skew,
    small_rotation,
    tip_kinematics,
    torsion_kinetic,
)
from flexlink.mechanics.shapes import make_basis
from flexlink.mechanics.shapes.base import ShapeBasis
from flexlink.mechanics.shapes.body import BodyIntegrals, shell_body
from flexlink.mechanics.shapes.reduction import ModalBeamBasis, ModalTorsionBasis
from flexlink.mechanics.shapes.torsion import TorsionBasis, make_torsion_basis
from flexlink.mechanics.symbolic import Law, Parameter, Signal, StartValue
from flexlink.scene.loader import Joint, Link, Scene

#: Whether the builder forms the foreshortening's share of a second-order link's equations on the point sums in
#: Kane's form (:mod:`flexlink.mechanics.kane`); False takes CasADi's Lagrange derivative through the point sums,
#: the same equations (tests/test_kane_foreshortening.py and ``benchmarks/tensor_threshold.py --kane`` compare the
#: two by setting this switch of the builder's).
KANE_FORESHORTENING = True


def _unsupported(scene: Scene, what: str) -> FlexlinkError:
    where = scene.path or scene.name
    return FlexlinkError(f"{where}: {what} is not supported yet")


def check_supported(scene: Scene) -> None:
    """Refuse, with the scene's name, a link whose shape family the builder has no kinematics for.

    The scene loader accepts every kind the schema names; this is where a kind the mechanics cannot model
    yet becomes a clear error instead of a failure deep in the symbolic model.
    """
    for link in scene.links:
        if not link.is_rigid and link.shapes.kind not in ("clamped-free", "polynomial", "fe", "shell"):
            raise _unsupported(scene, f'link "{link.name}": shapes kind {link.shapes.kind!r}')


class _Params:
    """Collects the tunable parameters as they are met; after :meth:`freeze` ``self(i)`` is their symbol."""

    def __init__(self) -> None:
        self.items: list[Parameter] = []
        self.p: ca.MX | None = None

    def add(self, *args: Any, **kwargs: Any) -> int:
        self.items.append(Parameter(*args, **kwargs))
        return len(self.items) - 1

    def freeze(self) -> ca.MX:
        self.p = ca.MX.sym("p", len(self.items))
        return self.p

    def __call__(self, i: int | None) -> ca.MX | int:
        if i is None:
            return 0
        assert self.p is not None, "parameters are read once frozen"
        return self.p[i]


@dataclass
class LinkParts:
    """Per-link bookkeeping while the chain is assembled: where its coordinates and parameters are."""

    eta: list[int]                 # indices of the link's elastic coordinates in the full vector
    fields: dict[str, list[int]]   # "v", "w", "alpha" (or "modes" of a shell) → indices
    bending: ShapeBasis | None     # for v and w
    torsion: TorsionBasis | ModalTorsionBasis | None
    body: BodyIntegrals | None = None     # of a shell link (its modes deform in every direction)
    i_rho: int = 0
    i_EI: int | None = None
    i_EIo: int | None = None
    i_GJ: int | None = None
    i_mu: int | None = None
    i_kv: int | None = None
    i_pm: int | None = None
    i_pj: int | list[int] | None = None
    tip: TipKinematics | None = None      # once the energies are formed
    axis: tuple = (0.0, 0.0, 1.0)  # the joint axis in the link frame (z of a beam's basis; any for a rigid link)
    kinematics: str = "second-order"   # the link's own kinematic model
    rigid: bool = False
    i_m: int | None = None         # rigid link: mass, centre of mass (3), inertia about it (6: xx yy zz xy xz yz)
    i_c: list[int] | None = None
    i_I: list[int] | None = None

    @property
    def second_order(self) -> bool:
        """Whether the link keeps the foreshortening (second-order kinematics, docs/mechanics.md)."""
        return self.kinematics == "second-order"


@dataclass
class Frame:
    """A link's floating frame and its tip frame, with their velocities.

    Origins and their velocities are in the world, rotations map to the world, and angular velocities are
    resolved in the frame itself (body components).

    Origin velocities are propagated from the parent's, ``V_tip = V + Ṙ s_tip + R ṡ_tip``, with the rotation's
    own rate Ṙ carried along the chain too, rather than differentiated from the positions: each body adds
    a constant amount of expression whatever its depth (differentiating body i's origin walks the i bodies
    before it: n² in all), and the result is still the exact derivative of the position, also across the
    second-order tip rotation I + [ψ×] + ½[ψ×]², which is orthogonal only to second order (so R(ω×s) would
    not be).
    """

    origin: ca.MX | ca.DM                 # constant (DM) for the first link, whose origin is the base's
    rotation: ca.MX
    omega: ca.MX
    velocity: ca.MX
    rotation_rate: ca.MX
    tip_origin: ca.MX
    tip_rotation: ca.MX
    tip_omega: ca.MX
    tip_velocity: ca.MX
    tip_rotation_rate: ca.MX


def _vee_skew(A):
    """The vector of the skew-symmetric part of a 3×3 matrix (ω from Rᵀ Ṙ)."""
    return 0.5 * ca.vertcat(A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1])


@dataclass
class ChainAssembly:
    """The working state of one chain's assembly, in the order the stages fill it."""

    scene: Scene
    coordinates: list[str] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    nominal: list[float] = field(default_factory=list)
    joint_coord: list[int] = field(default_factory=list)          # link-side angle of joint i
    motor_coord: list[int | None] = field(default_factory=list)   # motor angle of elastic joint i
    parts: list[LinkParts] = field(default_factory=list)
    terms: list[str] = field(default_factory=list)
    P: _Params = field(default_factory=_Params)
    i_Ih: list[int] = field(default_factory=list)
    i_damp: list[int | None] = field(default_factory=list)
    i_k: list[int | None] = field(default_factory=list)
    i_g: list[int] | None = None
    inputs: list[Signal] = field(default_factory=list)
    laws: list[Law] = field(default_factory=list)
    tau_input: dict[int, int] = field(default_factory=dict)   # coordinate → u index of its torque
    prescribed: dict[int, int] = field(default_factory=dict)  # coordinate → u offset of its law
    tip_load: int | None = None
    bodies: list[dict] = field(default_factory=list)   # per body: mass, ∫ρr, ∫ρṙ, ∫ρ r×ṙ (world)
    joint_frames: list[tuple] = field(default_factory=list)   # per joint: origin, rotation (world)
    frames: list[Frame] = field(default_factory=list)
    # per second-order link on the point sums: its density, its Σ w u̇² and the coordinates of the rates in it
    rate_grams: list[tuple[ca.MX, RateGram, list[int]]] = field(default_factory=list)
    # per second-order link whose foreshortening enters the equations in Kane's form: what that form needs
    kane_links: list[KaneLink] = field(default_factory=list)
    linear_mask: ca.DM | None = None   # 0 on the linear links' η, 1 elsewhere (None: no linear link)
    # the walk's cursor (add_energies): the current joint's or tip's origin, and the last link's tip rotation
    origin: ca.MX | ca.DM = field(init=False, repr=False, compare=False)
    Rdef: ca.MX | ca.DM = field(init=False, repr=False, compare=False)

    def driven(self, i: int) -> int:
        """The coordinate joint i's actuator acts on: the motor angle of an elastic joint, else the joint angle."""
        motor = self.motor_coord[i]
        return motor if motor is not None else self.joint_coord[i]

    def deformation(self, part: LinkParts, q: ca.MX, v: ca.MX) -> LinkDeformation:
        """The link's elastic coordinates and rates picked out of full vectors ``q``, ``v``, field by field."""
        f = part.fields

        def pick(x: ca.MX, name: str) -> ca.MX | None:
            return ca.vertcat(*[x[i] for i in f[name]]) if name in f else None

        return LinkDeformation(pick(q, "v"), pick(q, "w"), pick(q, "alpha"),
                               pick(v, "v"), pick(v, "w"), pick(v, "alpha"))

    def assemble_kinematics(self) -> None:
        """Run the stages every user of the chain's frames needs: coordinates, parameters, inputs, energies.

        The model adds potential, dissipation and equations; a drawing (centreline.py) stops here.
        """
        self.add_coordinates()
        self.add_parameters()
        self.add_inputs()
        self.add_energies()

    # ---- coordinates: per joint its angle (and motor angle if elastic), then its link's η (v, w, α)
    def _new(self, name: str, kind: str, nominal: float = 1.0) -> int:
        self.coordinates.append(name)
        self.kinds.append(kind)
        self.nominal.append(nominal)
        return len(self.coordinates) - 1

    def add_joint_coordinates(self, joint: Joint) -> None:
        """The joint's angle; an elastic joint has two, the motor's (driven) and the link's (through the spring)."""
        if joint.is_elastic:
            self.motor_coord.append(self._new(f"{joint.name}.motor_theta", "joint"))
            self.joint_coord.append(self._new(f"{joint.name}.theta", "link_angle"))
        else:
            self.motor_coord.append(None)
            self.joint_coord.append(self._new(f"{joint.name}.theta", "joint"))

    def add_shell_coordinates(self, link: Link) -> None:
        """A shell link's modal coordinates: its mesh is assembled and reduced here, once, at build time.

        A mesh the shell elements refuse becomes a scene error naming the link.
        """
        try:
            body = shell_body(link)
        except ValueError as exc:
            raise FlexlinkError(f'{self.scene.path or self.scene.name}: link "{link.name}": {exc}') from None
        eta = [self._new(f"{link.name}.eta[{k + 1}]", "elastic") for k in range(body.n)]
        self.parts.append(LinkParts(eta, {"modes": eta}, None, None, body, kinematics=link.kinematics))
        shape = link.shapes
        self.terms.append(f'link "{link.name}": {body.n} modes of a {shape.section} of DKT + CST shell elements '
                          f"(mesh {'x'.join(map(str, shape.mesh))}, joint held), {link.kinematics} kinematics")

    def add_beam_coordinates(self, link: Link) -> None:
        """A beam link's η for each of its fields (v, w, α), with nominal values that scale them to metres.

        The nominal value of a coordinate is the inverse of its shape's peak deflection (or slope times
        length), so that the integrator's error control weighs every η alike whatever the basis.
        """
        bending: ShapeBasis | None = None
        torsion: TorsionBasis | ModalTorsionBasis | None = None
        xs = np.linspace(0.0, link.length, 401)
        if "v" in link.deformation or "w" in link.deformation:
            bending = make_basis(link.shapes.kind, link.shapes.count, link.length, link.linear_density)
            if link.shapes.modes is not None:
                bending = ModalBeamBasis(bending, link.shapes.modes)
            scale = np.maximum(np.max(np.abs(bending.evaluate(xs)), axis=0),
                               link.length * np.max(np.abs(bending.evaluate(xs, 1)), axis=0))
        if "alpha" in link.deformation:
            torsion = make_torsion_basis(link.shapes.kind, link.shapes.count, link.length, link.polar_inertia or 0.0)
            if link.shapes.modes is not None:
                torsion = ModalTorsionBasis(torsion, link.shapes.modes)
        fields: dict[str, list[int]] = {}
        eta: list[int] = []
        for name in ("v", "w", "alpha"):
            if name not in link.deformation:
                continue
            basis = torsion if name == "alpha" else bending
            assert basis is not None                # made above for every field the link deforms in
            nominal = (1.0 / np.max(np.abs(basis.evaluate(xs)), axis=0)) if name == "alpha" else 1.0 / scale
            fields[name] = [self._new(f"{link.name}.eta[{len(eta) + k + 1}]", "elastic", float(nominal[k]))
                            for k in range(basis.n)]
            eta += fields[name]
        self.parts.append(LinkParts(eta, fields, bending, torsion, kinematics=link.kinematics))
        kind = link.shapes.kind if link.shapes.modes is None else f"{link.shapes.kind} ({link.shapes.modes} modes)"
        self.terms.append(f'link "{link.name}": ' + ", ".join(f"{len(fields[f])} {kind} coordinates for {f}"
                                                              for f in fields) + f", {link.kinematics} kinematics")

    def add_rigid_link(self, link: Link) -> None:
        """A rigid link: no coordinates, only its record (its inertia comes with the parameters)."""
        self.parts.append(LinkParts([], {}, None, None, rigid=True))
        mass, _, inertia = link.rigid_body()
        what = "massless connector" if mass == 0 and not np.any(inertia) else "rigid body"
        self.terms.append(f'link "{link.name}": {what} (deformation = []), no elastic coordinates')

    def add_coordinates(self) -> None:
        """Every coordinate, joint by joint then its link, and the symbols qa, va, aa of the full vectors."""
        for joint, link in zip(self.scene.joints, self.scene.links, strict=True):
            self.add_joint_coordinates(joint)
            if link.is_rigid:
                self.add_rigid_link(link)
            elif link.is_shell:
                self.add_shell_coordinates(link)
            else:
                self.add_beam_coordinates(link)
        n = len(self.coordinates)
        self.qa, self.va, self.aa = ca.MX.sym("qa", n), ca.MX.sym("va", n), ca.MX.sym("aa", n)

    # ---- parameters: a term is in the model only if the scene needs it, or [fmu] tunable asks
    def add_rigid_parameters(self, link: Link, part: LinkParts) -> None:
        """A rigid link's ten inertial parameters (as in robot identification), the ones its scene needs.

        Mass and centre of mass if it has mass, the inertia tensor about the centre if it is non-zero.
        """
        P = self.P
        mass, centre, inertia = link.rigid_body()
        if mass > 0:
            part.i_m = P.add(f"{link.name}.mass", mass, "kg", "mass of the rigid link", 0.0)
            part.i_c = [P.add(f"{link.name}.center_of_mass[{k + 1}]", float(centre[k]), "m",
                              f"centre of mass {c}, link frame") for k, c in enumerate("xyz")]
        if np.any(inertia):
            entries = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
            part.i_I = [P.add(f"{link.name}.inertia[{k + 1}]", float(inertia[a, b]), "kg.m2",
                              f"inertia I{'xyz'[a]}{'xyz'[b]} about the centre of mass, link frame",
                              0.0 if a == b else -np.inf) for k, (a, b) in enumerate(entries)]

    def add_link_parameters(self, link: Link, part: LinkParts, tunable: set[str]) -> None:
        """A link's density (or rigid inertia), its stiffness and damping, and its payload, as FMU parameters."""
        P = self.P
        if link.is_rigid:
            self.add_rigid_parameters(link, part)
        elif link.is_shell:
            part.i_rho = P.add(f"{link.name}.density", link.density, "kg/m3", "density of the shell", 0.0, True)
            part.i_EI = P.add(f"{link.name}.E", link.E, "Pa", "Young's modulus of the shell (its modes are kept)",
                              0.0, True)
        else:
            part.i_rho = P.add(f"{link.name}.linear_density", link.linear_density, "kg/m", "mass per unit length",
                               0.0, True)
        if not link.is_rigid:
            self.add_elastic_parameters(link, part, tunable)
        self.add_payload_parameters(link, part, tunable)

    def add_elastic_parameters(self, link: Link, part: LinkParts, tunable: set[str]) -> None:
        """The stiffness of each field the link deforms in, and Kelvin–Voigt damping if set or made tunable."""
        P = self.P
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
            self.terms.append(f'link "{link.name}": Kelvin-Voigt structural damping')

    def add_payload_parameters(self, link: Link, part: LinkParts, tunable: set[str]) -> None:
        """The tip payload's mass and inertia (about the axis, or three principal moments) when it has one.

        A payload absent from the scene is still added when ``[fmu] tunable`` names it, so a user can attach it
        to the FMU later.
        """
        P = self.P
        pay = link.payload
        if pay.is_present or {f"{link.name}.payload.mass", f"{link.name}.payload.inertia"} & tunable:
            part.i_pm = P.add(f"{link.name}.payload.mass", pay.mass, "kg", "tip payload mass", 0.0)
            if isinstance(pay.inertia, int | float):
                part.i_pj = P.add(f"{link.name}.payload.inertia", float(pay.inertia), "kg.m2",
                                  "tip payload inertia about the joint axis", 0.0)
            else:
                part.i_pj = [P.add(f"{link.name}.payload.inertia[{k + 1}]", float(pay.inertia[k]), "kg.m2",
                                   f"tip payload inertia J{'xyz'[k]}{'xyz'[k]}, tip frame", 0.0) for k in range(3)]
            self.terms.append(f'link "{link.name}": tip payload')

    def add_parameters(self) -> None:
        """Every parameter the scene needs (links, joints, gravity), then the symbol p that holds them.

        A term absent from the scene (zero damping, no gravity) is left out of the model unless ``[fmu]
        tunable`` asks for it: a generated model contains only what its scene needs.
        """
        scene, P = self.scene, self.P
        tunable = set(scene.fmu.tunable)
        for link, part in zip(scene.links, self.parts, strict=True):
            self.add_link_parameters(link, part, tunable)
        self.i_Ih = [P.add(f"{j.name}.inertia", j.inertia, "kg.m2", "rotor / hub inertia about the axis", 0.0)
                     for j in scene.joints]
        self.i_damp = [P.add(f"{j.name}.damping", j.damping, "N.m.s/rad", "viscous joint damping", 0.0)
                       if (j.damping > 0 or f"{j.name}.damping" in tunable) else None for j in scene.joints]
        self.i_k = [P.add(f"{j.name}.stiffness", j.stiffness, "N.m/rad", "joint stiffness (motor to link)", 0.0, True)
                    if j.is_elastic else None for j in scene.joints]
        if scene.has_gravity or "gravity" in tunable:
            self.i_g = [P.add(f"gravity[{k + 1}]", scene.gravity[k], "m/s2", "gravity, inertial frame")
                        for k in range(3)]
            self.terms.append("gravity (non-zero in the scene or tunable)")
        self.p = P.freeze()
        self.g_vec = ca.vertcat(*[self.p[i] for i in self.i_g]) if self.i_g is not None else ca.DM.zeros(3)

    # ---- inputs: torques, prescribed laws, tip loads
    def add_inputs(self) -> None:
        """The FMU's inputs: a torque per torque-driven joint, (θ, θ̇, θ̈) per prescribed one, and the tip load.

        A built-in trajectory keeps its three slots (the model reads them) but they are not FMU variables.
        """
        inputs = self.inputs
        for i, joint in enumerate(self.scene.joints):
            if joint.drive == "torque":
                self.tau_input[self.driven(i)] = len(inputs)
                inputs.append(Signal(f"{joint.name}.tau", "N.m", "joint torque (motor side)"))
            elif joint.drive == "position":
                builtin = joint.trajectory is not None
                self.prescribed[self.driven(i)] = len(inputs)
                self.laws.append(Law(joint.name, len(inputs), joint.trajectory))
                for suffix, unit, what in (("theta_ref", "rad", "angle"), ("omega_ref", "rad/s", "rate"),
                                           ("alpha_ref", "rad/s2", "acceleration")):
                    inputs.append(Signal(f"{joint.name}.{suffix}", unit, f"prescribed joint {what}",
                                         fmu_variable=not builtin))
        if self.scene.fmu.tip_load_inputs:
            self.tip_load = len(inputs)
            for c, unit, what in (("fx", "N", "force"), ("fy", "N", "force"), ("fz", "N", "force"),
                                  ("mx", "N.m", "moment"), ("my", "N.m", "moment"), ("mz", "N.m", "moment")):
                inputs.append(Signal(f"tip.{c}", unit,
                                     f"external {what} at the tool frame's origin (the last tip), inertial frame"))
            self.terms.append("tip force and moment inputs ([fmu] tip_load_inputs)")
        self.u = ca.MX.sym("u", len(inputs))

    # ---- kinetic and gravitational energy along the chain (seed 000 ch. 2–3, generalised)
    def link_energy(self, i: int, link: Link, part: LinkParts, VL: ca.MX, RL: ca.MX, wL: ca.MX,
                    RL_dot: ca.MX) -> tuple:
        """Kinetic energy of link i's material, its body record, its gravitational energy, and T less Kane's share.

        The last is the kinetic energy less the foreshortening's share where that share's equations are formed
        in Kane's form (:meth:`invariant_body`), else the kinetic energy itself.
        """
        qa, va, p = self.qa, self.va, self.p
        if part.rigid:
            T, record = self.rigid_body(part, VL, RL, wL)
            T_rest = T
        else:
            T, record, T_rest = self.invariant_body(link, part, VL, RL, wL, RL_dot)
        if part.torsion is not None:
            assert part.i_mu is not None            # a twisting link has its polar inertia (add_elastic_parameters)
            d = self.deformation(part, qa, va)
            assert d.alpha_dot is not None          # its twist rates come with its twist coordinates
            T_twist = 0.5 * p[part.i_mu] * torsion_kinetic(part.torsion.integrals, link.length, d, wL[0])
            T, T_rest = T + T_twist, T_rest + T_twist
            record["spin"] += ca.mtimes(RL, ca.vertcat(p[part.i_mu] * (link.length * wL[0] + ca.dot(
                ca.DM(part.torsion.integrals.phi), d.alpha_dot)), 0, 0))
        record["spin"] += ca.cross(self.origin, record["momentum"])
        self.bodies.append(dict(joint=i, **record))
        Vg = -ca.dot(self.g_vec, record["moment"]) if self.i_g is not None else 0
        return T, Vg, T_rest

    def floating_body(self, scale, mass, S1, S1d, J, H, relative, VL, RL, wL) -> tuple:
        """T = ½ scale (m|V|² + 2 RᵀV·(ω×S1 + Ṡ1) + ωᵀJω + 2ω·H + E) of a body in a floating frame.

        The frame has origin velocity V in the world, rotation R and angular velocity ω in the frame; the
        body's inertia invariants are its mass m, first moment S1 and inertia J about the origin, relative
        angular momentum H and kinetic energy E, all per unit of ``scale`` (the density parameter of a
        flexible link, 1 for a rigid one).
        """
        T = 0.5 * scale * (mass * ca.dot(VL, VL) + 2 * ca.dot(ca.mtimes(RL.T, VL), ca.cross(wL, S1) + S1d)
                           + ca.dot(wL, ca.mtimes(J, wL)) + 2 * ca.dot(wL, H) + relative)
        # ∫ρ ṙ = ρ(m V + R(ω×S1 + Ṡ1));  ∫ρ (s × ṙ) = R ρ(S1 × (RᵀV) + J ω + H)
        momentum = scale * (mass * VL + ca.mtimes(RL, ca.cross(wL, S1) + S1d))
        spin = ca.mtimes(RL, scale * (ca.cross(S1, ca.mtimes(RL.T, VL)) + ca.mtimes(J, wL) + H))
        return T, dict(mass=scale * mass, moment=scale * mass * self.origin + ca.mtimes(RL, scale * S1),
                       momentum=momentum, spin=spin)

    def invariant_body(self, link: Link, part: LinkParts, VL, RL, wL, RL_dot=None) -> tuple:
        """T = ½∫ρ|V + ω×s + ṡ|² from the link's inertia invariants, exact for every kinematic model.

        Returns T, the body record and the T the Lagrange derivative is taken of: T itself, or, for a link whose
        foreshortening's equations come in Kane's form (:meth:`kane_form`), its first-order kinetic energy.
        """
        qa, va = self.qa, self.va
        rho = self.p[part.i_rho]
        zero = ca.DM.zeros(3)
        if part.body is not None:
            inv = body_invariants(part.body, self.eta_of(part, qa), self.eta_of(part, va))
            m_unit = part.body.volume           # mass per unit of the density parameter
        elif part.bending is not None:
            rule = part.bending.points if part.second_order else None
            d = self.deformation(part, qa, va)
            inv = beam_invariants(part.bending.integrals, link.length, d, rule, gram=True)
            m_unit = link.length
            if inv.rate_gram is not None:       # ½ρ Σ w u̇²: added to T by add_energies, kept apart for M
                self.rate_grams.append((rho, inv.rate_gram, [k for f in inv.rate_gram.rates for k in part.fields[f]]))
            if self.kane_form(part):
                T, record = self.floating_body(rho, m_unit, inv.first_moment, ca.jtimes(inv.first_moment, qa, va),
                                               inv.inertia(), inv.angular_momentum, inv.relative_kinetic, VL, RL, wL)
                first = beam_invariants(part.bending.integrals, link.length, d)
                T_first, first_record = self.floating_body(rho, m_unit, first.first_moment,
                                                           ca.jtimes(first.first_moment, qa, va), first.inertia(),
                                                           first.angular_momentum, first.relative_kinetic, VL, RL, wL)
                # the record's momenta are the first-order ones: the outputs add the foreshortening's with their
                # rates formed by hand (KaneLink.momenta); its first moment is whole (gravity)
                record.update(momentum=first_record["momentum"], spin=first_record["spin"])
                self.kane_links.append(KaneLink(part, link, rho, self.origin, VL, RL, RL_dot, wL))
                return T, record, T_first
        else:                                   # torsion only: the link's axis stays straight
            L = link.length
            J = ca.diag(ca.vertcat(0, L**3 / 3, L**3 / 3))
            T, record = self.floating_body(rho, L, ca.vertcat(L**2 / 2, 0, 0), zero, J, zero, 0, VL, RL, wL)
            return T, record, T             # no foreshortening: the Lagrangian's T is the whole T
        S1 = inv.first_moment
        T, record = self.floating_body(rho, m_unit, S1, ca.jtimes(S1, qa, va), inv.inertia(), inv.angular_momentum,
                                       inv.relative_kinetic, VL, RL, wL)
        return T, record, T

    def kane_form(self, part: LinkParts) -> bool:
        """Whether a beam link's foreshortening enters the equations in Kane's form (KANE_FORESHORTENING).

        When the switch allows it, :func:`~flexlink.mechanics.kane.takes_kane_form` decides.
        """
        linear = any(p.kinematics == "linear" for p in self.parts if not p.rigid and p.eta)
        return KANE_FORESHORTENING and takes_kane_form(part, linear)

    def rigid_body(self, part: LinkParts, VL, RL, wL) -> tuple:
        """A rigid link from its ten inertial parameters: S1 = m c, J_O = I_c + m(|c|² 1 − c cᵀ)."""
        p, zero = self.p, ca.DM.zeros(3)
        mass = p[part.i_m] if part.i_m is not None else 0
        centre = ca.vertcat(*[p[k] for k in part.i_c]) if part.i_c is not None else zero
        J: ca.MX | ca.DM = ca.DM.zeros(3, 3)
        if part.i_I is not None:
            xx, yy, zz, xy, xz, yz = (p[k] for k in part.i_I)
            J = ca.vertcat(ca.horzcat(xx, xy, xz), ca.horzcat(xy, yy, yz), ca.horzcat(xz, yz, zz))
        if part.i_m is not None:
            J = J + mass * (ca.dot(centre, centre) * ca.DM.eye(3) - ca.mtimes(centre, centre.T))
        return self.floating_body(1, mass, mass * centre, zero, J, zero, 0, VL, RL, wL)

    def eta_of(self, part: LinkParts, x: ca.MX) -> ca.MX:
        """The link's elastic coordinates (all fields, in order) picked out of a full vector ``x``."""
        return ca.vertcat(*[x[k] for k in part.eta])

    def link_tip(self, link: Link, part: LinkParts, VL, RL, RL_dot, wL) -> Frame:
        """The tip frame of a link: position, rotation and angular velocity (world-resolved)."""
        qa, va = self.qa, self.va
        if part.rigid:
            part.tip = TipKinematics(ca.DM([link.length, 0.0, 0.0]), ca.DM.zeros(3))
            self.Rdef = ca.DM.eye(3)
            s_tip = part.tip.position
            return Frame(self.origin, RL, wL, VL, RL_dot, self.origin + ca.mtimes(RL, s_tip), RL, wL,
                         VL + ca.mtimes(RL_dot, s_tip), RL_dot)
        if part.body is not None:
            tip = body_tip_kinematics(part.body, self.eta_of(part, qa))
        else:
            d = self.deformation(part, qa, va)
            tip = tip_kinematics(part.bending.integrals if part.bending else None,
                                 part.torsion.integrals if part.torsion else None, link.length, d, part.second_order,
                                 part.bending.points if part.bending is not None and self.kane_form(part) else None)
        part.tip = tip
        assert isinstance(tip.rotation_vector, ca.MX)   # an elastic link's tip rotates with its coordinates
        Rdef = small_rotation(tip.rotation_vector, part.second_order)
        Rdef_dot = ca.reshape(ca.jtimes(ca.vec(Rdef), qa, va), 3, 3)
        wt = ca.mtimes(Rdef.T, wL) + _vee_skew(ca.mtimes(Rdef.T, Rdef_dot))
        self.Rdef = Rdef
        s_dot = ca.jtimes(tip.position, qa, va)          # local: the link's own elastic rates
        return Frame(self.origin, RL, wL, VL, RL_dot, self.origin + ca.mtimes(RL, tip.position),
                     ca.mtimes(RL, Rdef), wt, VL + ca.mtimes(RL_dot, tip.position) + ca.mtimes(RL, s_dot),
                     ca.mtimes(RL_dot, Rdef) + ca.mtimes(RL, Rdef_dot))

    def payload_energy(self, i: int, link: Link, part: LinkParts, VL, frame: Frame) -> tuple:
        """Kinetic and gravitational energy of link i's tip payload, and its body record."""
        p, RL, wL, Pp = self.p, frame.rotation, frame.omega, self.origin
        # the payload's velocity in the link basis: base velocity + ω × s_p + ṡ_p (no world rotation in it,
        # so that a linear model stays structurally linear)
        assert part.tip is not None and part.i_pm is not None and part.i_pj is not None   # link_tip ran; a payload
        offset = ca.DM(np.asarray(link.payload.offset, float))                             # has mass and inertia
        sp = part.tip.position + ca.mtimes(self.Rdef, offset)
        Vp = ca.mtimes(RL.T, VL) + ca.cross(wL, sp) + ca.jtimes(sp, self.qa, self.va)
        rp = Pp + ca.mtimes(RL, sp)
        if isinstance(part.i_pj, list):
            Jp = ca.diag(ca.vertcat(*[p[k] for k in part.i_pj]))
        else:                                   # about the joint axis (the link basis' z for a beam)
            e = ca.DM(part.axis)
            Jp = p[part.i_pj] * ca.mtimes(e, e.T)
        wt = frame.tip_omega
        T = 0.5 * p[part.i_pm] * ca.dot(Vp, Vp) + 0.5 * ca.dot(wt, ca.mtimes(Jp, wt))
        Vg = -p[part.i_pm] * ca.dot(self.g_vec, rp) if self.i_g is not None else 0
        mom_p = p[part.i_pm] * ca.mtimes(RL, Vp)
        self.bodies.append(dict(joint=i, mass=p[part.i_pm], moment=p[part.i_pm] * rp, momentum=mom_p,
                                spin=ca.cross(rp, mom_p) + ca.mtimes(frame.tip_rotation, ca.mtimes(Jp, wt))))
        return T, Vg

    def joint_frame(self, joint: Joint, parent: tuple) -> tuple:
        """Joint i's placed frame on its parent's tip frame: the fixed placement (origin, rpy).

        The parent is (rotation R, its rate Ṙ, angular velocity w in it, origin velocity V), with its origin in
        self.origin.  Moves self.origin to the joint's origin and returns the placed frame's (R, Ṙ, w, V).
        """
        R, R_dot, w, V = parent
        if not (any(joint.origin) or any(joint.rpy)):
            return parent
        offset, Ro = ca.DM(np.asarray(joint.origin, float)), ca.DM(joint.placement_rotation())
        self.origin = self.origin + ca.mtimes(R, offset)
        return ca.mtimes(R, Ro), ca.mtimes(R_dot, Ro), ca.mtimes(Ro.T, w), V + ca.mtimes(R_dot, offset)

    def body_step(self, i: int, parent: tuple) -> tuple:
        """Joint i, its rotor, link i and its payload on the parent's tip frame: T, T less Kane's share, V_g, tip, R.

        ``parent`` is the tip frame's (R, Ṙ, ω, V), its origin in ``self.origin``; returns the energies, the
        link's :class:`Frame` and the joint's rotation in the world.  Moves ``self.origin`` to the joint.
        """
        joint, link, part = self.scene.joints[i], self.scene.links[i], self.parts[i]
        qa, va = self.qa, self.va
        a = np.asarray(joint.axis, float) / np.linalg.norm(joint.axis)
        R0, R0_dot, w0, VL = self.joint_frame(joint, parent)
        th, thd = qa[self.joint_coord[i]], va[self.joint_coord[i]]
        Rj = rotation(a, th)
        Rj_dot = ca.mtimes(Rj, skew(ca.DM(a))) * thd
        B = ca.DM.eye(3) if part.rigid else ca.DM(link_basis(a))   # a rigid link's frame is the joint's
        part.axis = tuple(np.asarray(B.T @ ca.DM(a)).ravel())
        RL = ca.mtimes(ca.mtimes(R0, Rj), B)
        RL_dot = ca.mtimes(ca.mtimes(R0_dot, Rj) + ca.mtimes(R0, Rj_dot), B)
        wL = ca.mtimes(B.T, ca.mtimes(Rj.T, w0) + ca.DM(a) * thd)
        motor_rate = va[self.driven(i)]
        # the rotor spins about the joint axis with the shaft: angular momentum only (it sits at the joint)
        rotor_rate = ca.dot(ca.DM(a), w0) + motor_rate
        T_rotor = 0.5 * self.P(self.i_Ih[i]) * rotor_rate ** 2
        self.bodies.append(dict(joint=i, mass=0, moment=ca.DM.zeros(3), momentum=ca.DM.zeros(3),
                                spin=self.P(self.i_Ih[i]) * rotor_rate * ca.mtimes(R0, ca.DM(a))))
        T_link, Vg, T_rest_link = self.link_energy(i, link, part, VL, RL, wL, RL_dot)
        frame = self.link_tip(link, part, VL, RL, RL_dot, wL)
        T, T_rest = T_rotor + T_link, T_rotor + T_rest_link
        if part.i_pm is not None:
            T_pay, Vg_pay = self.payload_energy(i, link, part, VL, frame)
            T, Vg, T_rest = T + T_pay, Vg + Vg_pay, T_rest + T_pay
        return T, T_rest, Vg, frame, ca.mtimes(R0, Rj)

    def add_energies(self) -> None:
        """T and V_gravity of the whole chain, walking the frames from the base."""
        qa, va = self.qa, self.va
        T: ca.MX | float = 0
        T_rest: ca.MX | float = 0
        Vg: ca.MX | float = 0
        self.origin = ca.DM.zeros(3)
        parent: tuple[ca.MX | ca.DM, ...] = BASE_FRAME
        # (R, Ṙ, ω, V of the base, then of each tip frame in turn)
        for i in range(len(self.parts)):
            T_body, T_rest_body, Vg_body, frame, joint_rotation = self.body_step(i, parent)
            T, T_rest, Vg = T + T_body, T_rest + T_rest_body, Vg + Vg_body
            self.joint_frames.append((self.origin, joint_rotation))
            self.frames.append(frame)
            self.origin = frame.tip_origin
            parent = (frame.tip_rotation, frame.tip_rotation_rate, frame.tip_omega, frame.tip_velocity)
        self.tool = self.tool_frame(self.frames[-1])
        linear = {k for part in self.parts if part.kinematics == "linear" for k in part.eta}
        if linear:
            # T at η = 0 for the linear links, the rates kept (seed 000 eq. 3.7)
            mask = ca.DM([0.0 if k in linear else 1.0 for k in range(len(self.coordinates))])
            self.linear_mask = mask
            T = ca.Function("T", [qa, va, self.p], [T])(qa * mask, va, self.p)
        # T without the foreshortening rates' Σ w u̇² (whose Hessian the mass matrix forms as a Gram product), then
        # the whole T; a linear link has none, so the mask above does not touch them
        self.T_without_grams = T
        for rho, gram, _ in self.rate_grams:
            T = T + 0.5 * rho * gram.energy
        self.T, self.Vg = T, Vg
        # the Lagrangian's T: without the foreshortening of the links whose equations take it in Kane's form
        self.T_rest = T_rest if self.kane_links else T

    def tool_frame(self, last: Frame) -> Frame:
        """The end-effector frame ([tool] origin, rpy in the last link's tip frame) as a Frame.

        Its tip_* fields are the tool's; without a [tool] table it is the last tip frame itself.
        """
        tool = self.scene.tool
        if not (any(tool.origin) or any(tool.rpy)):
            return last
        offset, Ro = ca.DM(np.asarray(tool.origin, float)), ca.DM(tool.placement_rotation())
        R, R_dot = last.tip_rotation, last.tip_rotation_rate
        return Frame(last.origin, last.rotation, last.omega, last.velocity, last.rotation_rate,
                     last.tip_origin + ca.mtimes(R, offset), ca.mtimes(R, Ro), ca.mtimes(Ro.T, last.tip_omega),
                     last.tip_velocity + ca.mtimes(R_dot, offset), ca.mtimes(R_dot, Ro))

    # ---- elastic potential, dissipation and generalized forces
    def add_potential_and_dissipation(self) -> None:
        """The elastic energy Ve and Rayleigh's dissipation R of the links' fields and of the joints.

        Kelvin–Voigt damping is the stiffness matrix times its coefficient, so it damps each mode in
        proportion to its frequency squared.
        """
        qa, va, p = self.qa, self.va, self.p
        Ve: ca.MX | float = 0
        R: ca.MX | float = 0
        for i, (joint, part) in enumerate(zip(self.scene.joints, self.parts, strict=True)):
            if part.body is not None:
                assert part.i_EI is not None        # a shell's Young's modulus (add_link_parameters)
                x, xd, K = self.eta_of(part, qa), self.eta_of(part, va), ca.DM(part.body.stiffness)
                Ve += 0.5 * p[part.i_EI] * ca.dot(x, ca.mtimes(K, x))
                if part.i_kv is not None:
                    R += 0.5 * p[part.i_kv] * p[part.i_EI] * ca.dot(xd, ca.mtimes(K, xd))
            q_d = self.deformation(part, qa, va)
            for name, stiff_i in (("v", part.i_EI), ("w", part.i_EIo), ("alpha", part.i_GJ)):
                if name not in part.fields:
                    continue
                if name == "alpha":
                    assert part.torsion is not None
                    K = ca.DM(part.torsion.integrals.stiff)
                else:
                    assert part.bending is not None
                    K = ca.DM(part.bending.integrals.curv)
                assert stiff_i is not None              # each field's stiffness (add_elastic_parameters)
                x, xd = getattr(q_d, name), getattr(q_d, f"{name}_dot")
                Ve += 0.5 * p[stiff_i] * ca.dot(x, ca.mtimes(K, x))
                if part.i_kv is not None:
                    R += 0.5 * p[part.i_kv] * p[stiff_i] * ca.dot(xd, ca.mtimes(K, xd))
            damping, stiffness, motor = self.i_damp[i], self.i_k[i], self.motor_coord[i]
            if damping is not None:
                R += 0.5 * p[damping] * va[self.driven(i)] ** 2
            if stiffness is not None:
                assert motor is not None                # an elastic joint has a motor angle
                Ve += 0.5 * p[stiffness] * (qa[motor] - qa[self.joint_coord[i]]) ** 2
                self.terms.append(f'joint "{joint.name}": elastic (stiffness > 0), motor and link angles')
        self.Ve, self.R = Ve, R

    def generalized_forces(self):
        """Joint torques and the tip load's power F·ṙ_tip + M·ω_tip, as forces on the coordinates."""
        u = self.u
        Q = ca.MX.zeros(len(self.coordinates))
        for k, j in self.tau_input.items():
            Q[k] = u[j]
        if self.tip_load is not None:
            last = self.tool
            power = (ca.dot(u[self.tip_load:self.tip_load + 3], last.tip_velocity)
                     + ca.dot(u[self.tip_load + 3:self.tip_load + 6], ca.mtimes(last.tip_rotation, last.tip_omega)))
            Q += ca.gradient(power, self.va)
        return Q

    # ---- Lagrange's equations by automatic differentiation, then free and prescribed coordinates
    def add_equations(self) -> None:
        """Lagrange's equations of every coordinate by CasADi's AD, then the residual r of the free ones.

        A prescribed coordinate is replaced by its law's inputs, so the residual the integrator solves has only
        the free coordinates; the prescribed ones' residuals are the torques their laws need (an output).
        """
        qa, va, aa = self.qa, self.va, self.aa
        Lag = self.T_rest - self.Ve - self.Vg
        dL_dv = ca.gradient(Lag, va)
        # d/dt ∂L/∂q̇ = ∂²L/∂q̇∂q q̇ + ∂²L/∂q̇² q̈ as one directional derivative along (q̇, q̈): one forward
        # sweep through the gradient's graph instead of two (18 % fewer operations on a 5-link chain)
        r_all = (ca.jtimes(dL_dv, ca.vertcat(qa, va), ca.vertcat(va, aa)) - ca.gradient(Lag, qa)
                 + ca.gradient(self.R, va) - self.generalized_forces() + kane_forces(self))
        self.r_all_expr = r_all            # the outputs read the prescribed joints' torques from it
        self.r_all = ca.Function("r_all", [qa, va, aa, self.u, self.p], [r_all])
        if any(part.second_order for part in self.parts if not part.rigid and part.eta):
            self.terms.append("second-order kinematics: foreshortening; each body's energy to second order in its "
                              "own elastic coordinates, the chain composed exactly (a Lagrangian: M symmetric)")
        if len(self.parts) > 1:
            self.terms.append(f"mass matrix by composite inertia over the {len(self.parts)} bodies: each body's "
                              "kinetic energy a quadratic form in its parent tip's velocity, folded from the tip")
        n_all = len(self.coordinates)
        self.free = [k for k in range(n_all) if k not in self.prescribed]
        if not self.free:
            raise _unsupported(self.scene, "a chain with no free coordinate (every joint position-driven and "
                                           "every link rigid: nothing to integrate; drive a joint by torque or "
                                           "make a link flexible)")
        n_free = len(self.free)
        self.q, self.v, self.a = ca.MX.sym("q", n_free), ca.MX.sym("v", n_free), ca.MX.sym("a", n_free)
        # the full coordinate vectors seen from the free ones: a prescribed coordinate's value, rate and
        # acceleration are slots 0, 1, 2 of its law's inputs
        self.qa_e, self.va_e, self.aa_e = (
            ca.vertcat(*[self.u[self.prescribed[k] + slot] if k in self.prescribed else x[self.free.index(k)]
                         for k in range(n_all)])
            for slot, x in enumerate((self.q, self.v, self.a)))
        r_full = self.r_all(self.qa_e, self.va_e, self.aa_e, self.u, self.p)
        self.residual = ca.Function("residual", [self.q, self.v, self.a, self.u, self.p], [r_full[self.free]],
                                    ["q", "v", "a", "u", "p"], ["r"])

    def mass_matrix_all(self) -> ca.MX:
        """∂²T/∂q̇² of every coordinate, an expression in qa, u, p (T is quadratic in q̇: no q̇ left in it).

        The Hessian of T less the foreshortening rates' Σ w u̇², by composite inertia along the chain
        (:mod:`flexlink.mechanics.composite`; 17 100 operations instead of CasADi's Hessian's 30 200 on an 8-link
        chain, tests/test_composite_mass_matrix.py), plus their Gram forms ρ Aᵀ W A placed on their links' rate
        coordinates (:class:`~flexlink.mechanics.kinematics.RateGram`: a quarter of the operations of the Hessian
        through the point sums, tests/test_mass_matrix_gram.py).
        """
        H = composite_mass_matrix(self)
        if self.linear_mask is not None:        # T at η = 0 for the linear links (add_energies)
            H = ca.substitute(H, self.qa, self.qa * self.linear_mask)
        n = len(self.coordinates)
        for rho, gram, rates in self.rate_grams:
            place = placement(n, rates)
            H = H + ca.mtimes(place, ca.mtimes(0.5 * rho * gram.hessian(), place.T))
        return H

    def free_mass_matrix(self) -> ca.Function:
        """M(q, u, p) = ∂r/∂a of the free coordinates, as the Hessian ∂²T/∂q̇² (:meth:`mass_matrix_all`).

        r is M a + h and only T holds q̇ quadratically; the Hessian's scalar code grows with the chain like
        the residual's, where a Jacobian of the residual repeats the whole residual's derivative for every
        column.
        """
        H = self.mass_matrix_all()
        inner = ca.Function("mass_matrix_all", [self.qa, self.u, self.p], [H])
        value = inner(self.qa_e, self.u, self.p)[self.free, self.free]
        return ca.Function("mass_matrix", [self.q, self.u, self.p], [ca.densify(value)], ["q", "u", "p"], ["M"])

    def free_function(self, name: str, expressions: list, with_rates: bool = True) -> ca.Function:
        """A Function of the free (q, v, a, u, p) — or (q, u, p) — from expressions in the full coordinates."""
        inner = ca.Function(f"{name}_all", [self.qa, self.va, self.aa, self.u, self.p], [ca.vertcat(*expressions)])
        if with_rates:
            # dense: an entry may be structurally zero (a turntable's tip acceleration), the C wants every one
            value = ca.densify(inner(self.qa_e, self.va_e, self.aa_e, self.u, self.p))
            return ca.Function(name, [self.q, self.v, self.a, self.u, self.p], [value],
                               ["q", "v", "a", "u", "p"], ["y"])
        zeros = ca.DM.zeros(len(self.coordinates))
        value = ca.densify(inner(self.qa_e, zeros, zeros, self.u, self.p))
        return ca.Function(name, [self.q, self.u, self.p], [value], ["q", "u", "p"], ["g"])

    # ---- start values and initial deformation
    def start_values(self) -> tuple[list[StartValue], list[int]]:
        """The start-value parameters (initial angles and rates) and the coordinates started static.

        The second list holds the free coordinates solved for their static deflection at the start
        (``initial_deformation = "static"``), the link side of an elastic joint included.
        """
        start: list[StartValue] = []
        static: list[int] = []
        free = self.free
        for i, (joint, link, part) in enumerate(zip(self.scene.joints, self.scene.links, self.parts, strict=True)):
            for k in (self.motor_coord[i], self.joint_coord[i]):
                if k is None or k in self.prescribed:
                    continue
                suffix = "motor_" if k == self.motor_coord[i] else ""
                angle = joint.initial_angle
                if joint.trajectory is not None:          # a position-driven elastic joint: start unstretched
                    angle = joint.trajectory.evaluate(0.0)[0]
                what = suffix.replace("_", " ")
                start.append(StartValue(f"{joint.name}.{suffix}initial_angle", free.index(k), False, angle,
                                        "rad", f"initial {what}angle"))
                start.append(StartValue(f"{joint.name}.{suffix}initial_rate", free.index(k), True,
                                        joint.initial_rate, "rad/s", f"initial {what}rate"))
            if link.initial_deformation == "static":
                static += [free.index(k) for k in part.eta]
                if self.motor_coord[i] is not None and self.joint_coord[i] not in self.prescribed:
                    static.append(free.index(self.joint_coord[i]))
        return start, sorted(static)


def structure(residual: ca.Function) -> tuple[bool, bool, np.ndarray | None]:
    """(linear in the state, Newton matrix constant, input matrix) of a residual.

    The input matrix is B = ∂r/∂u where it is a constant (no coordinate, rate, acceleration, input or
    parameter in it), else None: the generalized forces of the inputs are then −B u, which the FMU's energy
    guard takes without the two residuals a difference r(u = 0) − r(u) costs at every communication point
    (fmu_src/guards.c; a joint torque's column is −1 on its joint, whatever the arm's pose).  Decided on the
    scalar expansion, where CasADi folds structural zeros that the matrix graph keeps.
    """
    f = residual.expand()
    q, v, a, u, p = (ca.SX.sym(n, *f.size_in(i)) for i, n in enumerate("qvaup"))
    state = ca.vertcat(q, v, a)
    r = f(q, v, a, u, p)
    J = ca.jacobian(r, state)
    linear = not ca.depends_on(J, state)
    B = ca.jacobian(r, u)
    constant_inputs = not ca.depends_on(B, ca.vertcat(state, u, p))
    return linear, linear and not ca.depends_on(J, u), np.array(ca.evalf(B)) if constant_inputs else None
