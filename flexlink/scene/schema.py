"""The scene's vocabulary: its data classes (plain, frozen, SI units) and the values its keywords may take.

:mod:`flexlink.scene.loader` turns a TOML file into these objects; everything downstream reads only them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "FmuSettings",
    "Joint",
    "Link",
    "Payload",
    "Scene",
    "Segment",
    "Shapes",
    "Trajectory",
]

DRIVES = ("torque", "position", "free")
DEFORMATIONS = ("v", "w", "alpha")
SHAPE_KINDS = ("clamped-free", "polynomial", "fe", "shell")
SHELL_SECTIONS = ("plate", "box")
MESH_PATTERNS = ("symmetric", "A", "B")
SHELL_KINEMATICS = ("linear", "first-order")
KINEMATICS = ("linear", "first-order", "second-order")
INITIAL_DEFORMATIONS = ("undeformed", "static")
INTEGRATORS = ("ss22",)
AXIS_TOLERANCE = 1e-9

# Names that already start FMU variable names of their own (tip.x, energy.kinetic, solver.step, gravity[1]).
RESERVED_NAMES = ("tip", "energy", "solver", "gravity")
LINK_TUNABLE = ("kelvin_voigt", "payload.mass", "payload.inertia")
JOINT_TUNABLE = ("stiffness", "damping")

Vec3 = tuple[float, float, float]


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
    name: str
    axis: Vec3
    inertia: float = 0.0
    damping: float = 0.0
    drive: str = "torque"
    stiffness: float = 0.0
    initial_angle: float = 0.0
    initial_rate: float = 0.0
    trajectory: Trajectory | None = None

    @property
    def is_elastic(self) -> bool:
        """An elastic joint adds a motor coordinate (SCENE.md: only if stiffness > 0)."""
        return self.stiffness > 0.0


@dataclass(frozen=True)
class Payload:
    mass: float = 0.0
    inertia: float | Vec3 = 0.0
    offset: Vec3 = (0.0, 0.0, 0.0)

    @property
    def is_present(self) -> bool:
        """SCENE.md: a payload is in the model only if its mass or inertia is non-zero."""
        inertia = self.inertia if isinstance(self.inertia, tuple) else (self.inertia,)
        return self.mass != 0.0 or any(j != 0.0 for j in inertia)


@dataclass(frozen=True)
class Shapes:
    """A beam family (``count`` functions or elements), or a shell mesh; ``modes``: reduce an FE link to its
    first modes with the joint held (None: keep every finite-element coordinate)."""

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
        """Area of the shell's cross-section (mid-surface perimeter × thickness)."""
        if self.section == "box":
            return 2.0 * (self.width + self.height) * self.thickness
        return self.width * self.thickness


@dataclass(frozen=True)
class Link:
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

    @property
    def is_shell(self) -> bool:
        return self.shapes.kind == "shell"


@dataclass(frozen=True)
class FmuSettings:
    step: float = 1e-3
    integrator: str = "ss22"
    theta: tuple[float, float] = (0.5, 0.5)
    tolerance: float = 1e-10
    tunable: tuple[str, ...] = ()
    tip_load_inputs: bool = False


@dataclass(frozen=True)
class Scene:
    name: str
    model_identifier: str
    gravity: Vec3
    joints: tuple[Joint, ...]
    links: tuple[Link, ...]
    fmu: FmuSettings = FmuSettings()
    path: str | None = None

    @property
    def has_gravity(self) -> bool:
        """SCENE.md: gravity terms are generated only if the vector is non-zero."""
        return any(g != 0.0 for g in self.gravity)
