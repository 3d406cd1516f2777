"""The scene's vocabulary: its data classes, the values its keywords may take, and the table of its keys.

The data classes are plain, frozen and in SI units; :data:`KEYS` is the table of every key a scene file may
hold.

:mod:`flexlink.scene.loader` turns a TOML file into these objects; everything downstream reads only them.
The loader takes the keys each section accepts, their defaults, units and bounds from :data:`KEYS`, so the
table is the scene reference: a key is accepted if and only if it is listed there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from flexlink.scene.solver import THETA_RULE, SolverSettings

__all__ = [
    "KEYS",
    "SECTIONS",
    "FmuSettings",
    "Joint",
    "Key",
    "Link",
    "Payload",
    "Scene",
    "Section",
    "Segment",
    "Shapes",
    "Tool",
    "Trajectory",
    "key_spec",
    "rpy_rotation",
    "section_keys",
]

DRIVES = ("torque", "position", "free")
DEFORMATIONS = ("v", "w", "alpha")
SHAPE_KINDS = ("clamped-free", "polynomial", "fe", "shell")
SHELL_SECTIONS = ("plate", "box")
MESH_PATTERNS = ("symmetric", "A", "B")
SHELL_KINEMATICS = ("linear", "first-order")
KINEMATICS = ("linear", "first-order", "second-order")
INITIAL_DEFORMATIONS = ("undeformed", "static")
#: Sensors a link may carry besides those every link has (joint encoder, root strain gauge): each costs generated
#: outputs, so a scene declares it (``sensors = ["accelerometer"]``: ``<link>.tip.sx``, ``.sy``, ``.sz``).
LINK_SENSORS = ("accelerometer",)
INTEGRATORS = ("ss22",)
NEWTON_MATRIX_FORMS = ("auto", "dense", "columns")
AXIS_TOLERANCE = 1e-9

# Names that already start FMU variable names of their own (tip.x, energy.kinetic, solver.step, gravity[1]).
RESERVED_NAMES = ("tip", "energy", "solver", "gravity")
LINK_TUNABLE = ("kelvin_voigt", "payload.mass", "payload.inertia")
JOINT_TUNABLE = ("stiffness", "damping")

Vec3 = tuple[float, float, float]


def rpy_rotation(rpy: Vec3) -> np.ndarray:
    """The 3×3 rotation of a frame placed with roll, pitch, yaw, as URDF places its frames.

    R = Rz(yaw)·Ry(pitch)·Rx(roll), whose columns are the placed frame's axes in the parent frame: the same
    convention as URDF, so that a robot's frames can be copied from its URDF file unchanged.
    """
    roll, pitch, yaw = rpy
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


# ----------------------------------------------------------------------------------------------- objects


@dataclass(frozen=True)
class Segment:
    """θ(t) = Σ poly[k] t^k + Σ amp·cos(w·t + phase), t absolute, valid for t < until."""

    until: float
    poly: tuple[float, ...] = ()
    cos: tuple[tuple[float, float, float], ...] = ()

    def evaluate(self, t: float) -> tuple[float, float, float]:
        """(θ, θ̇, θ̈) by Horner, so that long polynomials stay accurate far from t = 0."""
        p = d = dd = 0.0
        for c in reversed(self.poly):
            dd = dd * t + 2.0 * d
            d = d * t + p
            p = p * t + c
        for amp, w, phase in self.cos:
            arg = w * t + phase
            c, s = math.cos(arg), math.sin(arg)
            p += amp * c
            d -= amp * w * s
            dd -= amp * w * w * c
        return p, d, dd


@dataclass(frozen=True)
class Trajectory:
    """A piecewise law for a position-driven joint; segments are ordered by ``until``."""

    segments: tuple[Segment, ...]

    def segment_at(self, t: float) -> Segment:
        """The segment with t < until; the last one beyond its end, so a law never runs out."""
        for seg in self.segments:
            if t < seg.until:
                return seg
        return self.segments[-1]

    def evaluate(self, t: float) -> tuple[float, float, float]:
        """(θ, θ̇, θ̈) at absolute time t."""
        return self.segment_at(t).evaluate(t)


@dataclass(frozen=True)
class Joint:
    """A revolute joint, placed in its parent frame and driving the next link.

    Its frame is placed in the parent frame (the previous link's tip frame, the world frame for the first
    joint) by ``origin`` and ``rpy``; ``axis`` is a unit vector in that joint frame, and the link it drives is
    clamped in the joint frame turned by the joint angle about ``axis``.
    """

    name: str
    axis: Vec3
    inertia: float = 0.0
    damping: float = 0.0
    drive: str = "torque"
    stiffness: float = 0.0
    initial_angle: float = 0.0
    initial_rate: float = 0.0
    trajectory: Trajectory | None = None
    origin: Vec3 = (0.0, 0.0, 0.0)           # m, the joint frame's origin in the parent frame
    rpy: Vec3 = (0.0, 0.0, 0.0)              # rad, the joint frame's orientation in the parent frame (URDF)

    @property
    def is_elastic(self) -> bool:
        """An elastic joint adds a motor coordinate (docs/scene.md: only if stiffness > 0)."""
        return self.stiffness > 0.0

    def placement_rotation(self) -> np.ndarray:
        """The joint frame's orientation in the parent frame (3×3): Rz(yaw)·Ry(pitch)·Rx(roll)."""
        return rpy_rotation(self.rpy)


@dataclass(frozen=True)
class Payload:
    """A rigid body carried at a link's tip.

    ``mass`` (kg) with its centre at ``offset`` (m, in the tip frame) and its ``inertia`` about that centre
    (kg m²: one moment about the joint axis, or (Jxx, Jyy, Jzz) about the tip axes).  All zero by default,
    which means no payload: the model then holds no payload terms (:attr:`is_present`).
    """

    mass: float = 0.0
    inertia: float | Vec3 = 0.0
    offset: Vec3 = (0.0, 0.0, 0.0)

    @property
    def is_present(self) -> bool:
        """docs/scene.md: a payload is in the model only if its mass or inertia is non-zero."""
        inertia = self.inertia if isinstance(self.inertia, tuple) else (self.inertia,)
        return self.mass != 0.0 or any(j != 0.0 for j in inertia)


@dataclass(frozen=True)
class Shapes:
    """A link's shape basis: a beam family (``count`` functions or elements), or a shell mesh.

    ``modes`` reduces an FE link to its first modes with the joint held (None: keep every finite-element
    coordinate).  The shell fields (``section`` to ``pattern``) are set for a shell link only.
    """

    kind: str = "clamped-free"
    count: int = 3
    modes: int | None = None
    section: str | None = None                  # shell: "plate" | "box"
    width: float | None = None                  # shell: along the joint axis (plate) / box width
    height: float | None = None                 # box: along the in-plane bending direction v
    thickness: float | None = None
    mesh: tuple[int, ...] = ()                  # shell: [nx, nw] (plate) or [nx, nw, nh] (box)
    pattern: str = "symmetric"                  # shell: diagonals of the triangles (seed 001 fig. 5.5)

    @property
    def section_area(self) -> float:
        """Area of the shell's cross-section (mid-surface perimeter × thickness).

        Raises
        ------
        ValueError
            For a basis that is not a shell (its section has no width, height or thickness).
        """
        width, height, thickness = self.width, self.height, self.thickness
        if width is None or thickness is None or (self.section == "box" and height is None):
            raise ValueError(f'section_area is for a shell basis (kind = "shell"), not "{self.kind}": its '
                             "section's width, height or thickness is not set")
        if self.section == "box" and height is not None:
            return 2.0 * (width + height) * thickness
        return width * thickness


@dataclass(frozen=True)
class Link:
    """A beam link, a shell link (``shapes.kind == "shell"``) or a rigid link (``deformation == ()``).

    A rigid link's mass properties are either a uniform slender rod (``linear_density``, ``polar_inertia``;
    ``mass`` is None) or a body (``mass``, ``center_of_mass``, ``inertia`` = (Ixx, Iyy, Izz, Ixy, Ixz, Iyz)
    about the centre of mass, all three set, and ``linear_density`` 0); :meth:`rigid_body` gives either as
    (mass, centre, inertia tensor). A rigid link has ``EI`` None and keeps the defaults of the keys that mean
    nothing for it (shapes, kinematics, kelvin_voigt).
    """

    name: str
    length: float
    linear_density: float
    EI: float | None
    EI_out: float | None = None
    GJ: float | None = None
    polar_inertia: float | None = None
    kelvin_voigt: float = 0.0
    deformation: tuple[str, ...] = ("v",)
    shapes: Shapes = Shapes()
    kinematics: str = "second-order"
    payload: Payload = Payload()
    initial_deformation: str = "undeformed"
    density: float | None = None              # shell links: kg/m³
    E: float | None = None                    # shell links: Young's modulus, Pa
    poisson: float | None = None              # shell links
    mass: float | None = None                 # rigid link given as a body: kg
    center_of_mass: Vec3 | None = None        # rigid body: m, in the link frame
    inertia: tuple[float, ...] | None = None  # rigid body: kg m², (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) about the centre
    sensors: tuple[str, ...] = ()             # declared sensors (LINK_SENSORS) that add outputs to the model

    @property
    def is_shell(self) -> bool:
        """Whether the link is a thin-walled shell, modelled by a triangle mesh rather than a beam basis."""
        return self.shapes.kind == "shell"

    @property
    def is_rigid(self) -> bool:
        """Whether the link does not deform (``deformation = []``): it then has no elastic coordinates."""
        return self.deformation == ()

    def rigid_body(self) -> tuple[float, np.ndarray, np.ndarray]:
        """The mass properties of a rigid link, from whichever form it was given in.

        Returns
        -------
        mass : float
            In kg.
        centre : numpy.ndarray
            The centre of mass (3,) in the link frame, m.
        inertia : numpy.ndarray
            The inertia tensor (3×3) about the centre of mass in the link axes, kg m²; the tip payload is not
            included.

        Raises
        ------
        ValueError
            For a flexible link, or a body given by ``mass`` without its centre of mass or inertia.
        """
        if not self.is_rigid:
            raise ValueError(f'link "{self.name}" is flexible: rigid_body() is for a rigid link (deformation = [])')
        if self.mass is not None:
            if self.inertia is None or self.center_of_mass is None:
                raise ValueError(f'link "{self.name}": a rigid body given by mass needs center_of_mass and inertia')
            ixx, iyy, izz, ixy, ixz, iyz = self.inertia
            tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
            return self.mass, np.array(self.center_of_mass, dtype=float), tensor
        rho, length = self.linear_density, self.length
        mu = self.polar_inertia or 0.0
        mass = rho * length
        bend = rho * length**3 / 12.0
        return mass, np.array([length / 2.0, 0.0, 0.0]), np.diag([mu * length, bend, bend])


@dataclass(frozen=True)
class Tool:
    """The end-effector frame, placed in the last link's tip frame by ``origin`` (m) and ``rpy`` (rad)."""

    origin: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 = (0.0, 0.0, 0.0)

    def placement_rotation(self) -> np.ndarray:
        """The tool frame's orientation in the last link's tip frame (3×3): Rz(yaw)·Ry(pitch)·Rx(roll)."""
        return rpy_rotation(self.rpy)


@dataclass(frozen=True)
class FmuSettings:
    """The ``[fmu]`` table: the integrator and its settings, the terms kept tunable and the tip-load inputs.

    The settings are a :class:`~flexlink.scene.solver.SolverSettings`, their one owner.
    """

    solver: SolverSettings = SolverSettings()
    integrator: str = "ss22"
    tunable: tuple[str, ...] = ()
    tip_load_inputs: bool = False
    newton_matrix: str = "auto"
    directional_derivatives: bool = True


@dataclass(frozen=True)
class Scene:
    """A whole scene file: the chain of joints and links, gravity, the tool frame and the FMU settings.

    The one object the loader hands downstream; every later stage reads only it, never the TOML.  ``path`` is
    the file it was read from (None for a string), which relative paths and messages refer to.
    """

    name: str
    model_identifier: str
    gravity: Vec3
    joints: tuple[Joint, ...]
    links: tuple[Link, ...]
    fmu: FmuSettings = FmuSettings()
    path: str | None = None
    tool: Tool = Tool()

    @property
    def has_gravity(self) -> bool:
        """docs/scene.md: gravity terms are generated only if the vector is non-zero."""
        return any(g != 0.0 for g in self.gravity)


# ------------------------------------------------------------------------------------------- key table


class _Marker:
    """A default that is not a value: the key must be given, or may be left out (and then means nothing)."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text


REQUIRED = _Marker("required")
OPTIONAL = _Marker("optional")       # no default value: absent means "not there" (its description says what)
EMPTY_TABLE: Any = MappingProxyType({})
NUMBER_BOUNDS = ("", "> 0", "≥ 0")   # the bounds the loader reads itself; any other text is checked in code
# A number's bounds may also be one of these followed by "; " and a rule in words that code checks on top
# (e.g. "> 0; required for a flexible link"): the loader applies the part before the semicolon.


@dataclass(frozen=True)
class Section:
    """A table of the scene file; ``id`` is how :class:`Key` rows name it."""

    id: str
    header: str          # as it is written in TOML
    description: str


@dataclass(frozen=True)
class Key:
    """One key of one section: what it holds, its unit and default, and the values it may take.

    ``default`` is the TOML value an absent key stands for (lists as tuples, tables as ``EMPTY_TABLE``),
    or :data:`REQUIRED` / :data:`OPTIONAL`. ``bounds`` is one of :data:`NUMBER_BOUNDS` for the numbers the
    loader bounds from this table (optionally followed by "; " and a further rule in words, checked in code),
    otherwise the rule in words; ``choices`` are the only strings allowed.
    """

    section: str
    name: str
    type: str
    unit: str = ""
    default: Any = REQUIRED
    bounds: str = ""
    choices: tuple[str, ...] = ()
    description: str = ""

    def toml_default(self) -> Any:
        """A fresh copy of the default in the form TOML would give it (lists, dicts)."""
        return _thaw(self.default)


def _thaw(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_thaw(v) for v in value]
    if isinstance(value, MappingProxyType):
        return {k: _thaw(v) for k, v in value.items()}
    return value


SECTIONS: tuple[Section, ...] = (
    Section("scene", "(top level)", "the scene: its name, gravity, the chain and the export settings"),
    Section("joint", "[[joint]]", "a revolute joint; joint i drives link i, and sits at the tip of link i − 1 "
            "(placed there by origin and rpy)"),
    Section("joint.trajectory", "[joint.trajectory]", 'the position law θ(t) of a joint with drive = "position"'),
    Section("joint.trajectory.segments", "[joint.trajectory] segments = [{…}, …]",
            "one piece of the law: θ(t) = Σ poly[k] t^k + Σ amp cos(ω t + phase), t absolute, for t < until"),
    Section("link", "[[link]]", "a beam link (Euler–Bernoulli), clamped in its joint's frame, or a rigid link "
            "(deformation = []): a uniform rod (linear_density) or a body (mass, center_of_mass, inertia)"),
    Section("link.shapes", "[link.shapes]", "the beam's shape functions or finite elements"),
    Section("link.payload", "[link.payload]", "a rigid body at the link's tip (beam, shell and rigid links)"),
    Section("shell_link", '[[link]] with shapes.kind = "shell"',
            "a plate or thin-walled box link of DKT + CST shell elements: material, not section properties"),
    Section("shell_link.shapes", '[link.shapes] with kind = "shell"', "the shell link's section and mesh"),
    Section("tool", "[tool]", "the end-effector frame, placed in the last link's tip frame"),
    Section("fmu", "[fmu]", "export settings: the SS22 solver and the FMU's interface"),
)

_VEC0 = (0.0, 0.0, 0.0)
_NAME_RULE = "letters, digits, _; not starting with a digit; not tip, energy, solver, gravity; unique"
_K = Key
_SOLVER = SolverSettings()   # the defaults of the [fmu] solver keys
KEYS: tuple[Key, ...] = (
    # ---------------------------------------------------------------------------------- top level
    _K("scene", "name", "string", bounds="non-empty",
       description="model name (FMU modelName); the modelIdentifier is it made a C identifier"),
    _K("scene", "gravity", "[x, y, z]", "m/s²", _VEC0,
       description="gravity in the base frame; gravity terms are generated only if it is non-zero"),
    _K("scene", "joint", "array of tables", bounds="as many as [[link]]", description="the joints"),
    _K("scene", "link", "array of tables", bounds="as many as [[joint]]", description="the links, base to tip"),
    _K("scene", "tool", "table", default=EMPTY_TABLE, description="the end-effector frame, see [tool]"),
    _K("scene", "fmu", "table", default=EMPTY_TABLE, description="export settings"),
    # -------------------------------------------------------------------------------------- joint
    _K("joint", "name", "name", bounds=_NAME_RULE, description="the joint's name, prefix of its FMU variables"),
    _K("joint", "axis", "[x, y, z]", "", (0.0, 0.0, 1.0),
       "non-zero; normal to [1, 0, 0] if the joint's link is flexible (beam or shell), any if it is rigid",
       description="rotation axis in the joint frame (normalised); a flexible link's x axis is normal to it"),
    _K("joint", "origin", "[x, y, z]", "m", _VEC0,
       description="the joint frame's origin in the parent frame (the previous link's tip frame; the world "
                   "frame for the first joint)"),
    _K("joint", "rpy", "[roll, pitch, yaw]", "rad", _VEC0,
       description="the joint frame's orientation in the parent frame, URDF convention: "
                   "R = Rz(yaw)·Ry(pitch)·Rx(roll)"),
    _K("joint", "inertia", "number", "kg m²", 0.0, "≥ 0", description="rotor inertia about the axis"),
    _K("joint", "damping", "number", "N m s/rad", 0.0, "≥ 0", description="viscous damping of the joint"),
    _K("joint", "drive", "string", "", "torque", choices=DRIVES,
       description="the input: a torque, a position law (trajectory or theta_ref inputs), or none (free)"),
    _K("joint", "stiffness", "number", "N m/rad", 0.0, "≥ 0",
       description="> 0: an elastic joint, a spring between the motor and the link"),
    _K("joint", "initial_angle", "number", "rad", 0.0, description="joint angle at the start"),
    _K("joint", "initial_rate", "number", "rad/s", 0.0, description="joint rate at the start"),
    _K("joint", "trajectory", "table", default=OPTIONAL, bounds='only with drive = "position"',
       description="the position law; without it, the inputs theta_ref, omega_ref, alpha_ref"),
    # --------------------------------------------------------------------------------- trajectory
    _K("joint.trajectory", "segments", "list of tables", bounds="non-empty",
       description="the pieces of the law, by increasing until; the last one extends beyond its end"),
    _K("joint.trajectory.segments", "until", "number", "s", math.inf, "strictly increasing; inf allowed",
       description="end of the segment: it holds for t < until"),
    _K("joint.trajectory.segments", "poly", "list of numbers", "rad", (),
       description="coefficients of t^0, t^1, …"),
    _K("joint.trajectory.segments", "cos", "list of [amp, ω, phase]", "rad, rad/s, rad", (),
       description="cosine terms amp cos(ω t + phase)"),
    # ---------------------------------------------------------------------------------- beam link
    _K("link", "name", "name", bounds=_NAME_RULE, description="the link's name, prefix of its FMU variables"),
    _K("link", "length", "number", "m", REQUIRED, "> 0; ≥ 0 for a rigid link",
       description="length along the link's x axis (its tip frame's origin); a rigid link may have length 0"),
    _K("link", "linear_density", "number", "kg/m", OPTIONAL, "> 0",
       description="mass per length; required unless density and area are given (not both), or, for a rigid "
                   "link, mass"),
    _K("link", "density", "number", "kg/m³", OPTIONAL, "> 0",
       description="with area, instead of linear_density: mass per length = density·area"),
    _K("link", "area", "number", "m²", OPTIONAL, "> 0", description="cross-section area, with density"),
    _K("link", "EI", "number", "N m²", OPTIONAL, "> 0; required for a flexible link, refused for a rigid one",
       description="bending stiffness in the joint's plane (v)"),
    _K("link", "EI_out", "number", "N m²", OPTIONAL, "> 0",
       description='bending stiffness out of the plane (w); required if deformation includes "w"'),
    _K("link", "GJ", "number", "N m²", OPTIONAL, "> 0",
       description='torsional stiffness; required if deformation includes "alpha"'),
    _K("link", "polar_inertia", "number", "kg m", OPTIONAL, "≥ 0",
       description='polar mass moment of the section per length; required if deformation includes "alpha"; '
                   "a rigid rod's (absent: 0)"),
    _K("link", "kelvin_voigt", "number", "s", 0.0, "≥ 0",
       description="Kelvin–Voigt damping: the stiffness times this is the damping"),
    _K("link", "deformation", "list of strings", "", ("v",), "distinct", DEFORMATIONS,
       description="deformation fields: v in the joint's plane, w out of it, alpha torsion; [] a rigid link"),
    _K("link", "shapes", "table", default=EMPTY_TABLE, description="the shape family, see [link.shapes]"),
    _K("link", "kinematics", "string", "", "second-order", choices=KINEMATICS,
       description="order of the deformation's kinematics (second-order: the geometric stiffening)"),
    _K("link", "payload", "table", default=EMPTY_TABLE, description="a tip body, see [link.payload]"),
    _K("link", "initial_deformation", "string", "", "undeformed", choices=INITIAL_DEFORMATIONS,
       description="static: start at the deformation that balances the initial loads"),
    _K("link", "sensors", "list of strings", "", (), "distinct", LINK_SENSORS,
       description="sensors that add outputs: accelerometer, a triaxial accelerometer at the link's tip "
                   "(<link>.tip.sx, .sy, .sz: specific force, gravity included, in the link's tip frame; the "
                   "last link's tip always has tip.sx … tip.sz, in the [tool] frame)"),
    _K("link", "mass", "number", "kg", OPTIONAL, "≥ 0; rigid link only",
       description="a rigid link given as a body: its mass (instead of linear_density); with center_of_mass "
                   "and inertia"),
    _K("link", "center_of_mass", "[x, y, z]", "m", OPTIONAL, "rigid link only, with mass",
       description="the rigid body's centre of mass in the link frame; absent with mass: [0, 0, 0]"),
    _K("link", "inertia", "[Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]", "kg m²", OPTIONAL,
       "rigid link only, with mass; positive semi-definite, Ixx ≤ Iyy + Izz etc.",
       description="the rigid body's inertia tensor about its centre of mass, link axes; products are the "
                   "tensor's off-diagonal entries (Ixy = −∫ρxy, URDF); absent with mass: 0"),
    # ------------------------------------------------------------------------------ [link.shapes]
    _K("link.shapes", "kind", "string", "", "clamped-free", choices=SHAPE_KINDS,
       description='clamped-free beam modes, polynomials, Hermite finite elements; "shell": a shell link'),
    _K("link.shapes", "count", "integer", "", 3, "≥ 1",
       description="number of shape functions, or of elements (fe)"),
    _K("link.shapes", "modes", "integer", "", OPTIONAL, 'kind = "fe" only; 1 … 2·count',
       description="reduce the FE link to its first modes with the joint held; absent: keep every coordinate"),
    # ----------------------------------------------------------------------------- [link.payload]
    _K("link.payload", "mass", "number", "kg", 0.0, "≥ 0", description="payload mass"),
    _K("link.payload", "inertia", "number or [Jxx, Jyy, Jzz]", "kg m²", 0.0, "≥ 0",
       description="payload inertia about its centre of mass: about the joint axis, or about the tip axes"),
    _K("link.payload", "offset", "[x, y, z]", "m", _VEC0,
       description="centre of mass in the tip frame"),
    # ---------------------------------------------------------------------------------- shell link
    _K("shell_link", "name", "name", bounds=_NAME_RULE, description="the link's name, prefix of its FMU variables"),
    _K("shell_link", "length", "number", "m", REQUIRED, "> 0", description="length along the link's x axis"),
    _K("shell_link", "density", "number", "kg/m³", REQUIRED, "> 0", description="density of the material"),
    _K("shell_link", "E", "number", "Pa", REQUIRED, "> 0", description="Young's modulus"),
    _K("shell_link", "poisson", "number", "", REQUIRED, "-1 < poisson < 0.5", description="Poisson's ratio"),
    _K("shell_link", "kelvin_voigt", "number", "s", 0.0, "≥ 0",
       description="Kelvin–Voigt damping: the stiffness times this is the damping"),
    _K("shell_link", "shapes", "table", bounds='kind = "shell"', description="section and mesh, see below"),
    _K("shell_link", "kinematics", "string", "", "first-order", choices=SHELL_KINEMATICS,
       description="order of the deformation's kinematics"),
    _K("shell_link", "payload", "table", default=EMPTY_TABLE, description="a tip body, see [link.payload]"),
    _K("shell_link", "initial_deformation", "string", "", "undeformed", choices=INITIAL_DEFORMATIONS,
       description="static: start at the deformation that balances the initial loads"),
    _K("shell_link", "sensors", "list of strings", "", (), "distinct", LINK_SENSORS,
       description="sensors that add outputs, as for a beam link (see [[link]] sensors)"),
    # ------------------------------------------------------------------------- shell [link.shapes]
    _K("shell_link.shapes", "kind", "string", "", REQUIRED, choices=("shell",),
       description="shell: this table describes a plate or box mesh"),
    _K("shell_link.shapes", "section", "string", "", REQUIRED, choices=SHELL_SECTIONS,
       description="plate, or thin-walled rectangular box"),
    _K("shell_link.shapes", "width", "number", "m", REQUIRED, "> 0",
       description="along the joint axis (plate), or the box's width"),
    _K("shell_link.shapes", "height", "number", "m", OPTIONAL, "> 0",
       description='box only (required there): along the in-plane bending direction v'),
    _K("shell_link.shapes", "thickness", "number", "m", REQUIRED, "> 0",
       description="wall thickness, below half the width and the height (a thin wall)"),
    _K("shell_link.shapes", "mesh", "list of integers", "", REQUIRED, "each ≥ 1; even across if symmetric",
       description="elements [nx, nw] (plate) or [nx, nw, nh] (box): along the length, width, height"),
    _K("shell_link.shapes", "pattern", "string", "", "symmetric", choices=MESH_PATTERNS,
       description="the triangles' diagonals: mirrored about the mid-line, or all one way (A, B)"),
    _K("shell_link.shapes", "modes", "integer", "", OPTIONAL, "1 … the mesh's translations off the root",
       description="reduce to the first modes with the joint held; absent: keep every mode"),
    # ------------------------------------------------------------------------------------- [tool]
    _K("tool", "origin", "[x, y, z]", "m", _VEC0, description="the tool frame's origin in the last link's tip frame"),
    _K("tool", "rpy", "[roll, pitch, yaw]", "rad", _VEC0,
       description="the tool frame's orientation in the last link's tip frame: R = Rz(yaw)·Ry(pitch)·Rx(roll)"),
    # -------------------------------------------------------------------------------------- [fmu]
    _K("fmu", "step", "number", "s", _SOLVER.step, "> 0", description="the SS22 step (the FMU's fixed step)"),
    _K("fmu", "integrator", "string", "", "ss22", choices=INTEGRATORS, description="the integrator"),
    _K("fmu", "theta", "[Θ1, Θ2]", "", _SOLVER.theta, THETA_RULE,
       description="SS22 parameters (unconditionally stable in this range; > 0.5 damps high frequencies)"),
    _K("fmu", "tolerance", "number", "", _SOLVER.tolerance, "> 0",
       description="Newton tolerance: a step's rate change against the coordinate's nominal scale"),
    _K("fmu", "tunable", "list of strings", "", (), "distinct",
       description="terms kept as FMU parameters even at zero: <link>.kelvin_voigt, <link>.payload.mass, "
                   "<link>.payload.inertia, <joint>.stiffness, <joint>.damping, gravity"),
    _K("fmu", "tip_load_inputs", "boolean", "", False,
       description="add inputs tip.fx … tip.mz: a force and moment at the [tool] frame's origin, the last "
                   "link's tip without one (inertial frame)"),
    _K("fmu", "newton_matrix", "string", "", "auto", choices=NEWTON_MATRIX_FORMS,
       description="the SS22 Newton matrix in the generated C: one dense symbolic Jacobian (fastest to refresh, "
                   "code n times the residual's), or by columns from the mass matrix and differences of the "
                   "residual (no code); \"columns\" takes exact columns from the directional derivatives "
                   "(the complex step, a few residuals a column) where they are compiled; auto: differences "
                   "(the same steps as dense at a third to a half of the code)"),
    _K("fmu", "directional_derivatives", "boolean", "", True,
       description="provide fmi2GetDirectionalDerivative: the forward derivatives of the residual and the "
                   "outputs by the complex step on their generated code (no derivative code is generated; "
                   "docs/fmi.md); false leaves out its two small complex units, builds a Newton matrix by "
                   "columns from differences of the residual and declares "
                   "providesDirectionalDerivative=\"false\""),
)
del _K, _SOLVER

_BY_KEY = {(k.section, k.name): k for k in KEYS}


def section_keys(section: str) -> tuple[str, ...]:
    """The keys a section accepts, in table order (the order of the loader's "expected one of" list)."""
    return tuple(k.name for k in KEYS if k.section == section)


def key_spec(section: str, name: str) -> Key:
    """The row of one key; a KeyError is a programming error (the loader reading a key not in the table)."""
    return _BY_KEY[(section, name)]
