"""What a scene will cost before anything is built, and the budgets past which it is refused (issue 21).

:func:`estimate` reads only the :class:`~flexlink.scene.schema.Scene` (no shape function, no CasADi): per link
the shape functions per field, the finite elements or shell mesh nodes, its coordinates, and the bytes of the
largest arrays its shape stage allocates; for the chain the model's coordinates (equal to
``build_model(scene).n_q``, tests/test_budget.py) and a rough build time and generated-code size.
:func:`check_budget` refuses a scene past a budget with one :class:`SceneError` naming the key that makes it
large; :func:`flexlink.mechanics.model.build_model` calls it first, since every path that builds a model
(each CLI command, ``build_fmu``, ``cached_fmu``, the controllers, a ``Scene`` made in Python) passes there,
while ``load_scene`` must still read a large scene so that ``flexlink explain --estimate`` can say why.

What ``count`` allocates (flexlink/mechanics/shapes/): the point rule of a beam (base.point_rule) holds a dense
K × K integration matrix, K = 6 Gauss points per panel, one panel per radian of the highest clamped-free mode
(λ_n ≈ (n − ½)π panels) or one per finite element; the integrals' quadrature evaluates φ, φ', φ'' at 8λ_n
(clamped-free), 4·count (fe) points; clamped-free torsion shapes take 2·count + 4 points on each of count
panels.  A shell link's reduction (reduction.fixed_interface_modes) makes its stiffness and mass dense over the
6 degrees of freedom of each node off the root, and solves a dense eigenproblem of half that size.

Build time and code size are a rough model, fitted to builds at the default optimisation
(``FLEXLINK_OPTIMISE`` unset, this machine, 2026-11-27: one ``build_fmu(scene, dir)`` per scene, wall time; the
operations and C bytes are its BuildReport's; the directional derivatives by the complex step, which adds no
code, and the Newton matrix by differences of the residual, "auto"'s form at every size):

    scene                  n_q  operations  C [MB]  build [s]
    rotating_link            4       3 289    0.11       5.5
    two_link_payload         6       4 624    0.14       7.2
    steel_beam_gravity      10      20 867    0.50       7.4
    planar_chain_5          20      31 218    0.70      18.9

operations ≈ OPERATIONS_PER_TERM · Σ_links (1 + n_i)^LINK_EXPONENT · (1 + n_q / DENSE_NEWTON_SCALE where a
scene asks for a dense Newton matrix) (a link's energy gathers products of its own coordinates; a dense Newton
matrix is n_q derivatives of the residual: the scale is from the earlier fit, when "auto" was dense up to 12
coordinates), code ≈ BYTES_PER_OPERATION · operations, build ≈ SECONDS_PER_OPERATION · operations + 1 s.  Fit:
the exponent (1.0 … 2.0) that minimises the worst log-error of the operations on these four (38 %), the factor
their geometric mean; bytes and seconds per operation are the means of the four (22.6 … 34.3 B, 3.1 … 13.8 ·
10⁻⁴ s: the machine was loaded, and the small builds are mostly the generic C's compile).

On the six other examples timed the same way (elastic_joint, plate_raise, six_axis_arm, steel_beam_two_links,
spatial_cantilever, fast_two_link) it lands within a factor of 3 of the measured operations, code and time
(tests/test_budget.py holds them; worst: plate_raise's operations 2.1x over: the model is fitted on
second-order kinematics, whose foreshortening terms its first-order shell has none of).  Treat it as an order of
magnitude; the timings were taken on 2 cores shared with other sessions, so they are inflated.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace

from flexlink.errors import SceneError
from flexlink.scene.schema import Link, Scene

__all__ = [
    "ALLOW_LARGE_ENV",
    "MAX_COORDINATES",
    "MAX_LINKS",
    "MAX_SHAPE_BYTES",
    "MAX_SHELL_NODES",
    "LinkCost",
    "SceneCost",
    "allow_large_from_env",
    "check_budget",
    "estimate",
    "key_value",
]

#: Coordinates of the whole model: above it the generated code is no longer expanded to scalar code
#: (flexlink.export.codegen.EXPAND_MAX_COORDINATES), each step is much slower and the build takes hours.
MAX_COORDINATES = 160
#: Bytes of the largest arrays of one link's shape stage: above 2 GiB a shared machine runs out of memory.
MAX_SHAPE_BYTES = 2 * 1024**3
#: Nodes of one shell mesh: 1 200 nodes make dense reduction matrices of ~1 GB and an eigenproblem of 3 600.
MAX_SHELL_NODES = 1200
#: Links of the chain: build time grows faster than linearly with depth (8 links of 3 modes: 24 s,
#: benchmarks/scaling.md); 24 links are a few minutes.
MAX_LINKS = 24
#: An expected build longer than this is announced on stderr before it starts.
ANNOUNCE_SECONDS = 30.0
#: ``flexlink --allow-large`` sets it to 1: every command (and the controllers') then builds past the budgets.
ALLOW_LARGE_ENV = "FLEXLINK_ALLOW_LARGE"

# The rough cost model (module docstring): operations = OPERATIONS_PER_TERM · Σ (1 + n_i)^LINK_EXPONENT · form.
# The directional derivatives add no code (the complex step on the residual and outputs,
# flexlink.export.derivatives), so [fmu] directional_derivatives does not enter it (a model past 160
# coordinates keeps CasADi's forward functions; such scenes are past MAX_COORDINATES anyway).
OPERATIONS_PER_TERM = 855.0
LINK_EXPONENT = 1.2
DENSE_NEWTON_SCALE = 16.0              # a dense Newton matrix multiplies the code by 1 + n_q / 16
BYTES_PER_OPERATION = 27.7
SECONDS_PER_OPERATION = 9.0e-4


@dataclass(frozen=True)
class LinkCost:
    """One link's sizes; ``key`` is the scene key that sets its size (``link[i].shapes.count`` …)."""

    name: str
    index: int                         # 1-based, as in the scene's keys
    kind: str                          # clamped-free, polynomial, fe, shell, rigid
    fields: dict[str, int]             # shape functions per deformation field (a shell: "modes")
    elements: int                      # finite elements (fe), triangles (shell), 0 otherwise
    mesh_nodes: int                    # shell mesh nodes, 0 otherwise
    shape_bytes: int                   # the largest arrays of its shape stage together
    key: str

    @property
    def coordinates(self) -> int:
        """The link's coordinates, all fields together."""
        return sum(self.fields.values())


@dataclass(frozen=True)
class SceneCost:
    """The estimated size of a whole scene: its links, its joints and what they cost to build and hold."""

    source: str
    links: tuple[LinkCost, ...]
    joint_coordinates: int             # free joint (and motor) angles
    operations: int
    code_bytes: int
    build_seconds: float
    over: tuple[tuple[str, str], ...] = field(default=())   # (key, why) of each budget the scene exceeds

    @property
    def coordinates(self) -> int:
        """The model's free coordinates, ``build_model(scene).n_q``."""
        return self.joint_coordinates + sum(link.coordinates for link in self.links)

    def lines(self) -> list[str]:
        """The estimate as a few lines for the CLI."""
        out = [f"estimate: {self.coordinates} coordinates, ~{self.operations:,} operations, "
               f"~{self.code_bytes / 1e6:.2g} MB generated C, ~{_duration(self.build_seconds)} to build (rough)"]
        for c in self.links:
            sizes = ", ".join(f"{n} for {f}" for f, n in c.fields.items()) or "no elastic coordinates"
            extra = (f", {c.elements} elements" if c.elements else "") + (
                f", {c.mesh_nodes} mesh nodes" if c.mesh_nodes else "")
            memory = f", shapes ~{_size(c.shape_bytes)}" if c.shape_bytes else ""
            out.append(f'  link "{c.name}" ({c.kind}): {sizes}{extra}{memory}')
        out += [f"  over budget: {key}: {why}" for key, why in self.over]
        return out


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min" if seconds < 7200 else \
        f"{seconds / 3600:.0f} h"


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{n:.0f} B"
        n /= 1024
    raise AssertionError


def allow_large_from_env() -> bool:
    """True if ``$FLEXLINK_ALLOW_LARGE`` is set to anything but "", "0", "no", "false"."""
    return os.environ.get(ALLOW_LARGE_ENV, "").strip().lower() not in ("", "0", "no", "false")


# ----------------------------------------------------------------------------------------------- sizes


def _beam_shape_bytes(kind: str, count: int, fields: tuple[str, ...]) -> int:
    """Bytes of the dense arrays :mod:`flexlink.mechanics.shapes` allocates for one beam (module docstring)."""
    total = 0
    if {"v", "w"} & set(fields):
        if kind == "clamped-free":
            lam = (count - 0.5) * math.pi
            points, quadrature, n = 6 * max(4, math.ceil(lam)), 16 * max(2, math.ceil(lam / 2)), count
        elif kind == "fe":
            points, quadrature, n = 6 * count, 4 * count, 2 * count
        else:
            points, quadrature, n = 48, count + 2, count
        total += 8 * (points * points + 2 * points * n + 3 * quadrature * n)
    if "alpha" in fields:
        torsion_points = count * (2 * count + 4) if kind == "clamped-free" else 3 * count if kind == "fe" else \
            2 * count + 4
        total += 8 * 2 * torsion_points * count
    return total


def _beam_cost(link: Link, index: int) -> LinkCost:
    s = link.shapes
    bending = s.modes if s.modes is not None else 2 * s.count if s.kind == "fe" else s.count
    twist = min(s.modes, s.count) if s.modes is not None else s.count
    fields = {f: (twist if f == "alpha" else bending) for f in link.deformation}
    key = f"link[{index}].shapes.modes" if s.modes is not None else f"link[{index}].shapes.count"
    return LinkCost(link.name, index, s.kind, fields, s.count if s.kind == "fe" else 0, 0,
                    _beam_shape_bytes(s.kind, s.count, link.deformation), key)


def _shell_cost(link: Link, index: int) -> LinkCost:
    s = link.shapes
    nx, nw = s.mesh[0], s.mesh[1]
    per_section = 2 * (nw + s.mesh[2]) if s.section == "box" else nw + 1
    nodes, free = (nx + 1) * per_section, nx * per_section
    triangles = 2 * nx * (per_section if s.section == "box" else nw)
    dof = 6 * free
    modes = s.modes if s.modes is not None else 3 * free          # the translations off the root have mass
    # dense K and M, the condensation's blocks (half massless), the eigenvectors; the modal integrals (3,3,N,N)
    shape_bytes = 8 * (3 * dof * dof + (dof // 2) * modes + 9 * modes * modes + 9 * nodes * modes)
    key = f"link[{index}].shapes.modes" if s.modes is not None else f"link[{index}].shapes.mesh"
    return LinkCost(link.name, index, "shell", {"modes": modes}, triangles, nodes, shape_bytes, key)


def _link_cost(link: Link, index: int) -> LinkCost:
    if link.is_rigid:
        return LinkCost(link.name, index, "rigid", {}, 0, 0, 0, f"link[{index}]")
    return _shell_cost(link, index) if link.is_shell else _beam_cost(link, index)


def estimate(scene: Scene) -> SceneCost:
    """The sizes, a rough build cost and the budgets exceeded, from the scene alone (nothing is allocated)."""
    links = tuple(_link_cost(link, i) for i, link in enumerate(scene.links, 1))
    joints = sum(1 + j.is_elastic - (j.drive == "position") for j in scene.joints)
    n_q = joints + sum(c.coordinates for c in links)
    terms = sum((1 + c.coordinates) ** LINK_EXPONENT for c in links)
    dense = scene.fmu.newton_matrix == "dense"      # "auto" assembles it by columns (flexlink.export.codegen)
    operations = int(OPERATIONS_PER_TERM * terms * ((1 + n_q / DENSE_NEWTON_SCALE) if dense else 1.0))
    cost = SceneCost(scene.path or scene.name, links, joints, operations, int(BYTES_PER_OPERATION * operations),
                     1.0 + SECONDS_PER_OPERATION * operations)
    return replace(cost, over=tuple(_over_budget(cost)))


def _over_budget(cost: SceneCost):
    """(key, why) for each budget exceeded, the most specific first."""
    n_links = len(cost.links)
    if n_links > MAX_LINKS:
        yield "link", (f"{n_links} links, above the budget of {MAX_LINKS} links (build time grows faster "
                       "than the chain's length)")
    for c in cost.links:
        what = "shape functions" if c.kind in ("clamped-free", "polynomial") else "elements" \
            if c.kind == "fe" else "modes" if c.key.endswith("modes") else "mesh"
        if c.mesh_nodes > MAX_SHELL_NODES:
            yield c.key.replace(".modes", ".mesh"), (
                f'{c.mesh_nodes} mesh nodes (link "{c.name}"), above the budget of {MAX_SHELL_NODES} nodes '
                f"(the modal reduction's dense matrices need ~{_size(c.shape_bytes)})")
        elif c.shape_bytes > MAX_SHAPE_BYTES:
            yield c.key, (f'the {what} of link "{c.name}" need ~{_size(c.shape_bytes)} of memory, above the budget '
                          f"of {_size(MAX_SHAPE_BYTES)} for one link's shapes")
        elif c.coordinates > MAX_COORDINATES:
            yield c.key, (f'{c.coordinates} coordinates in link "{c.name}" alone, above the budget of '
                          f"{MAX_COORDINATES} coordinates (the generated code is no longer expanded)")
    if cost.coordinates > MAX_COORDINATES and all(c.coordinates <= MAX_COORDINATES for c in cost.links):
        yield "link", (f"{cost.coordinates} coordinates in the chain, above the budget of {MAX_COORDINATES} "
                       "(the generated code is no longer expanded)")


def check_budget(scene: Scene, cost: SceneCost | None = None) -> SceneCost:
    """The estimate, or one SceneError naming the key of the first budget the scene exceeds."""
    cost = estimate(scene) if cost is None else cost
    if cost.over:
        key, why = cost.over[0]
        raise SceneError(f"{cost.source}: {key}{key_value(scene, key)}: {why}; "
                         "flexlink --allow-large to build it anyway")
    return cost


def key_value(scene: Scene, key: str) -> str:
    """" = VALUE" of a shapes key, as the scene gave it."""
    if ".shapes." not in key:
        return ""
    index, name = int(key[len("link["):key.index("]")]), key.rsplit(".", 1)[1]
    shapes = scene.links[index - 1].shapes
    value = {"count": shapes.count, "modes": shapes.modes, "mesh": list(shapes.mesh)}[name]
    return f" = {value}"
