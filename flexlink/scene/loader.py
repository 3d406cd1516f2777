"""TOML scene → validated, typed, SI objects (the contract of SCENE.md).

Everything downstream trusts these objects, so every check happens here, once, and every mistake is
reported as one :class:`SceneError` of the form ``FILE: KEY: expected WHAT, got VALUE`` (or ``FILE: KEY:
missing; expected WHAT``, ``FILE: KEY: unknown key; did you mean …``). Keys are dotted
paths with 1-based indices into the arrays of tables, e.g. ``link[1].EI``, ``joint[2].trajectory.segments[1].
until``, ``fmu.theta``, because the index exists even when the name is missing or wrong.
"""

from __future__ import annotations

import difflib
import json
import math
import os
import re
import tomllib
from typing import Any

from flexlink.errors import SceneError
from flexlink.scene.schema import (
    AXIS_TOLERANCE,
    DEFORMATIONS,
    DRIVES,
    INITIAL_DEFORMATIONS,
    INTEGRATORS,
    JOINT_TUNABLE,
    KINEMATICS,
    LINK_TUNABLE,
    MESH_PATTERNS,
    RESERVED_NAMES,
    SHAPE_KINDS,
    SHELL_KINEMATICS,
    SHELL_SECTIONS,
    FmuSettings,
    Joint,
    Link,
    Payload,
    Scene,
    Segment,
    Shapes,
    Trajectory,
)

__all__ = [
    "FmuSettings",
    "Joint",
    "Link",
    "Payload",
    "Scene",
    "Segment",
    "Shapes",
    "Trajectory",
    "load_scene",
    "parse_scene",
    "sanitise_identifier",
]

_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if inline int "
    "long register restrict return short signed sizeof static struct switch typedef union unsigned void "
    "volatile while _Bool _Complex _Imaginary".split()
)

_TOP_KEYS = ("name", "gravity", "joint", "link", "fmu")
_JOINT_KEYS = (
    "name", "axis", "inertia", "damping", "drive", "stiffness", "initial_angle", "initial_rate", "trajectory",
)
_LINK_KEYS = (
    "name", "length", "linear_density", "density", "area", "EI", "EI_out", "GJ", "polar_inertia",
    "kelvin_voigt", "deformation", "shapes", "kinematics", "payload", "initial_deformation", "E", "poisson",
)
_SHELL_LINK_KEYS = (
    "name", "length", "density", "E", "poisson", "kelvin_voigt", "shapes", "kinematics", "payload",
    "initial_deformation",
)
_SHAPES_KEYS = ("kind", "count", "modes")
_SHELL_SHAPES_KEYS = ("kind", "section", "width", "height", "thickness", "mesh", "pattern", "modes")
_PAYLOAD_KEYS = ("mass", "inertia", "offset")
_TRAJECTORY_KEYS = ("segments",)
_SEGMENT_KEYS = ("until", "poly", "cos")
_FMU_KEYS = ("step", "integrator", "theta", "tolerance", "tunable", "tip_load_inputs")


# ------------------------------------------------------------------------------------------ public API


def sanitise_identifier(name: str) -> str:
    """modelIdentifier names files and C symbols, so it must be a C identifier (and not a keyword)."""
    ident = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not ident or ident[0].isdigit():
        ident = "_" + ident
    if ident in _C_KEYWORDS:
        ident += "_"
    return ident


def load_scene(path: str | os.PathLike[str]) -> Scene:
    """Read and validate a scene file; any problem (I/O, syntax, content) becomes one SceneError."""
    source = os.fspath(path)
    try:
        with open(source, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise SceneError(f"{source}: file not found; expected a TOML scene file") from None
    except IsADirectoryError:
        raise SceneError(f"{source}: is a directory; expected a TOML scene file") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{source}: TOML syntax error: {e}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"{source}: not UTF-8 text ({e.reason} at byte {e.start}); "
                         "expected a TOML scene file") from None
    except OSError as e:
        raise SceneError(f"{source}: cannot read the file ({e.strerror or e}); "
                         "expected a readable TOML scene file") from None
    return parse_scene(data, source, _path=source)


def parse_scene(data: dict, source: str = "<scene>", *, _path: str | None = None) -> Scene:
    """Validate an already-parsed TOML document (tests, programmatic scenes)."""
    return _Parser(source).scene(data, _path)


# ---------------------------------------------------------------------------------------- validation


_MISSING = object()


def _show(value: Any, limit: int = 60) -> str:
    """The offending value in TOML spelling, shortened, so that the message stays one line."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, float):
        text = "nan" if math.isnan(value) else ("inf" if value == math.inf else
                                                 "-inf" if value == -math.inf else repr(value))
    elif isinstance(value, int):
        text = repr(value)
    elif isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)  # TOML basic-string escapes: one line, always
    elif isinstance(value, list | tuple):
        text = "[" + ", ".join(_show(v, limit) for v in value) + "]"
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{k} = {_show(v, limit)}" for k, v in value.items()) + "}"
    else:
        text = f"a {type(value).__name__}"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


class _Parser:
    def __init__(self, source: str) -> None:
        self.source = source

    # -------------------------------------------------------------------------------- error helpers

    def fail(self, key: str, expected: str, value: Any = _MISSING) -> SceneError:
        if value is _MISSING:
            return SceneError(f"{self.source}: {key}: missing; expected {expected}")
        return SceneError(f"{self.source}: {key}: expected {expected}, got {_show(value)}")

    def table(self, value: Any, key: str, known: tuple[str, ...], what: str = "a table") -> dict:
        """Check a table and refuse unknown keys, suggesting the closest known one (typos are common)."""
        if not isinstance(value, dict):
            raise self.fail(key, what, value)
        for k in value:
            if k not in known:
                bare = str(k) if re.fullmatch(r"[A-Za-z0-9_-]+", str(k)) else _show(str(k))
                where = f"{key}.{bare}" if key else bare
                close = difflib.get_close_matches(str(k), known, n=1, cutoff=0.6)
                hint = f'did you mean "{close[0]}"? ' if close else ""
                raise SceneError(f"{self.source}: {where}: unknown key; {hint}"
                                 f"expected one of: {', '.join(known)}")
        return value

    # ------------------------------------------------------------------------------- scalar readers

    def number(self, value: Any, key: str, unit: str = "", *, minimum: float | None = None,
               positive: bool = False, allow_inf: bool = False) -> float:
        """A finite real (TOML's nan/inf refused, bools are not numbers), optionally ≥ minimum or > 0."""
        unit = f" ({unit})" if unit else ""
        if positive:
            expected = f"a positive number{unit}"
        elif minimum is not None:
            expected = f"a number ≥ {minimum:g}{unit}"
        elif allow_inf:
            expected = f"a number{unit} or inf"
        else:
            expected = f"a finite number{unit}"
        if value is _MISSING:
            raise self.fail(key, expected)
        if not _is_number(value):
            raise self.fail(key, expected, value)
        try:
            x = float(value)
        except OverflowError:
            raise self.fail(key, expected, value) from None
        if math.isnan(x) or (math.isinf(x) and not (allow_inf and x > 0)):
            raise self.fail(key, expected, value)
        if (positive and not x > 0) or (minimum is not None and not x >= minimum):
            raise self.fail(key, expected, value)
        return x

    def vector(self, value: Any, key: str, n: int, unit: str = "", *, minimum: float | None = None
               ) -> tuple[float, ...]:
        unit_txt = f" ({unit})" if unit else ""
        bound = f" ≥ {minimum:g}" if minimum is not None else ""
        expected = f"a list of {n} numbers{bound}{unit_txt}"
        if not isinstance(value, list | tuple) or len(value) != n:
            raise self.fail(key, expected, value)
        return tuple(self.number(v, f"{key}[{i + 1}]", unit, minimum=minimum) for i, v in enumerate(value))

    def string(self, value: Any, key: str, choices: tuple[str, ...] | None = None) -> str:
        expected = ("one of " + ", ".join(f'"{c}"' for c in choices)) if choices else "a string"
        if not isinstance(value, str) or (choices is not None and value not in choices):
            raise self.fail(key, expected, value)
        return value

    def name(self, value: Any, key: str) -> str:
        expected = "a name usable in FMU variable names (letters, digits, _; not starting with a digit)"
        if not isinstance(value, str) or not _NAME_RE.fullmatch(value):
            raise self.fail(key, expected, value)
        if value in RESERVED_NAMES:
            raise self.fail(key, f"a name other than {', '.join(RESERVED_NAMES)} (used by FMU outputs)",
                            value)
        return value

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(key, "true or false", value)
        return value

    # ----------------------------------------------------------------------------------- structure

    def scene(self, data: Any, path: str | None) -> Scene:
        top = self.table(data, "", _TOP_KEYS, "a TOML document (a table at the top level)")
        if "name" not in top:
            raise self.fail("name", "a string (the FMU modelName)")
        name = top["name"]
        if not isinstance(name, str) or not name.strip():
            raise self.fail("name", "a non-empty string (the FMU modelName)", name)
        gravity = (0.0, 0.0, 0.0)
        if "gravity" in top:
            gravity = self.vector(top["gravity"], "gravity", 3, "m/s²")

        joint_data = self.array_of_tables(top, "joint")
        link_data = self.array_of_tables(top, "link")
        if len(joint_data) != len(link_data):
            raise SceneError(
                f"{self.source}: joint, link: expected as many [[joint]] as [[link]] (link i is driven by "
                f"joint i), got {len(joint_data)} [[joint]] and {len(link_data)} [[link]]")
        joints = tuple(self.joint(d, f"joint[{i + 1}]") for i, d in enumerate(joint_data))
        links = tuple(self.link(d, f"link[{i + 1}]") for i, d in enumerate(link_data))

        seen: dict[str, str] = {}
        for kind, items in (("joint", joints), ("link", links)):
            for i, item in enumerate(items):
                key = f"{kind}[{i + 1}].name"
                if item.name in seen:
                    raise self.fail(key, f"a name not already used (by {seen[item.name]})", item.name)
                seen[item.name] = key.removesuffix(".name")

        fmu = self.fmu(top.get("fmu", {}), joints, links)
        return Scene(name=name, model_identifier=sanitise_identifier(name), gravity=gravity,
                     joints=joints, links=links, fmu=fmu, path=path)

    def array_of_tables(self, top: dict, key: str) -> list[dict]:
        expected = f"at least one [[{key}]] table"
        if key not in top:
            raise self.fail(key, expected)
        value = top[key]
        if not isinstance(value, list) or not value:
            raise self.fail(key, expected, value)
        for i, item in enumerate(value):
            if not isinstance(item, dict):
                raise self.fail(f"{key}[{i + 1}]", f"a [[{key}]] table", item)
        return value

    def joint(self, data: dict, key: str) -> Joint:
        t = self.table(data, key, _JOINT_KEYS)
        name = self.name(t.get("name", _MISSING), f"{key}.name")
        axis = (0.0, 0.0, 1.0)
        if "axis" in t:
            raw = self.vector(t["axis"], f"{key}.axis", 3)
            norm = math.hypot(*raw)
            if not norm > 0 or not math.isfinite(norm):
                raise self.fail(f"{key}.axis", "a non-zero finite vector", t["axis"])
            axis = tuple(c / norm for c in raw)
            if abs(axis[0]) > AXIS_TOLERANCE:
                raise self.fail(f"{key}.axis", "a vector normal to the link's x axis [1, 0, 0] "
                                "(x component 0)", t["axis"])
            axis = (0.0, axis[1], axis[2])
        inertia = self.number(t.get("inertia", 0.0), f"{key}.inertia", "kg m²", minimum=0)
        damping = self.number(t.get("damping", 0.0), f"{key}.damping", "N m s/rad", minimum=0)
        drive = self.string(t.get("drive", "torque"), f"{key}.drive", DRIVES)
        stiffness = self.number(t.get("stiffness", 0.0), f"{key}.stiffness", "N m/rad", minimum=0)
        initial_angle = self.number(t.get("initial_angle", 0.0), f"{key}.initial_angle", "rad")
        initial_rate = self.number(t.get("initial_rate", 0.0), f"{key}.initial_rate", "rad/s")
        trajectory = None
        if "trajectory" in t:
            if drive != "position":
                raise SceneError(f'{self.source}: {key}.trajectory: expected only with drive = "position", '
                                 f'got drive = "{drive}"')
            trajectory = self.trajectory(t["trajectory"], f"{key}.trajectory")
        return Joint(name=name, axis=axis, inertia=inertia, damping=damping, drive=drive, stiffness=stiffness,
                     initial_angle=initial_angle, initial_rate=initial_rate, trajectory=trajectory)

    def trajectory(self, data: Any, key: str) -> Trajectory:
        t = self.table(data, key, _TRAJECTORY_KEYS, "a table with segments = [{until, poly, cos}, ...]")
        raw = t.get("segments", _MISSING)
        expected = "a non-empty list of tables {until = …, poly = […], cos = [[amp, rad_per_s, phase], …]}"
        if not isinstance(raw, list) or not raw:
            raise self.fail(f"{key}.segments", expected, raw)
        segments: list[Segment] = []
        for i, item in enumerate(raw):
            skey = f"{key}.segments[{i + 1}]"
            s = self.table(item, skey, _SEGMENT_KEYS, expected)
            until = self.number(s.get("until", math.inf), f"{skey}.until", "s", allow_inf=True)
            if segments and not until > segments[-1].until:
                raise self.fail(f"{skey}.until", f"a time after the previous segment's until = "
                                f"{_show(segments[-1].until)} (strictly increasing)", until)
            poly_raw = s.get("poly", [])
            if not isinstance(poly_raw, list):
                raise self.fail(f"{skey}.poly", "a list of numbers (coefficients of t^0, t^1, …, rad)",
                                poly_raw)
            poly = tuple(self.number(c, f"{skey}.poly[{k + 1}]", "rad") for k, c in enumerate(poly_raw))
            cos_raw = s.get("cos", [])
            if not isinstance(cos_raw, list):
                raise self.fail(f"{skey}.cos", "a list of [amp, rad_per_s, phase] triples", cos_raw)
            cos = tuple(self.vector(c, f"{skey}.cos[{k + 1}]", 3) for k, c in enumerate(cos_raw))
            segments.append(Segment(until=until, poly=poly, cos=cos))
        return Trajectory(tuple(segments))

    def link(self, data: dict, key: str) -> Link:
        shapes_raw = data.get("shapes") if isinstance(data, dict) else None
        if isinstance(shapes_raw, dict) and shapes_raw.get("kind") == "shell":
            return self.shell_link(data, key)
        t = self.table(data, key, _LINK_KEYS)
        for k in ("E", "poisson"):
            if k in t:
                raise self.fail(f"{key}.{k}", 'no value: E and poisson are for shell links (shapes.kind = "shell"); '
                                "a beam takes EI", t[k])
        name = self.name(t.get("name", _MISSING), f"{key}.name")
        length = self.number(t.get("length", _MISSING), f"{key}.length", "m", positive=True)
        linear_density = self.linear_density(t, key)
        EI = self.number(t.get("EI", _MISSING), f"{key}.EI", "N m²", positive=True)
        optional = {}
        for k, unit, positive in (("EI_out", "N m²", True), ("GJ", "N m²", True),
                                  ("polar_inertia", "kg m", False)):
            if k in t:
                optional[k] = self.number(t[k], f"{key}.{k}", unit, positive=positive,
                                          minimum=None if positive else 0)
        kelvin_voigt = self.number(t.get("kelvin_voigt", 0.0), f"{key}.kelvin_voigt", "s", minimum=0)
        deformation = self.deformation(t.get("deformation", ["v"]), f"{key}.deformation")
        if "w" in deformation and "EI_out" not in optional:
            raise self.fail(f"{key}.EI_out", 'a positive number (N m²) because deformation includes "w"')
        if "alpha" in deformation:
            for k, what in (("GJ", "a positive number (N m²)"), ("polar_inertia", "a number ≥ 0 (kg m)")):
                if k not in optional:
                    raise self.fail(f"{key}.{k}", f'{what} because deformation includes "alpha"')
        shapes = self.shapes(t.get("shapes", {}), f"{key}.shapes")
        kinematics = self.string(t.get("kinematics", "second-order"), f"{key}.kinematics", KINEMATICS)
        payload = self.payload(t.get("payload", {}), f"{key}.payload")
        initial_deformation = self.string(t.get("initial_deformation", "undeformed"),
                                          f"{key}.initial_deformation", INITIAL_DEFORMATIONS)
        return Link(name=name, length=length, linear_density=linear_density, EI=EI,
                    EI_out=optional.get("EI_out"), GJ=optional.get("GJ"),
                    polar_inertia=optional.get("polar_inertia"), kelvin_voigt=kelvin_voigt,
                    deformation=deformation, shapes=shapes, kinematics=kinematics, payload=payload,
                    initial_deformation=initial_deformation)

    def shell_link(self, data: dict, key: str) -> Link:
        """A plate or box-section link of DKT + CST shell elements (seed 001 part 5): material, not section
        properties, since the mesh integrates them."""
        t = self.table(data, key, _SHELL_LINK_KEYS, "a table")
        name = self.name(t.get("name", _MISSING), f"{key}.name")
        length = self.number(t.get("length", _MISSING), f"{key}.length", "m", positive=True)
        density = self.number(t.get("density", _MISSING), f"{key}.density", "kg/m³", positive=True)
        E = self.number(t.get("E", _MISSING), f"{key}.E", "Pa", positive=True)
        poisson = self.number(t.get("poisson", _MISSING), f"{key}.poisson")
        if not -1.0 < poisson < 0.5:
            raise self.fail(f"{key}.poisson", "a number in (-1, 0.5) (Poisson's ratio)", poisson)
        kelvin_voigt = self.number(t.get("kelvin_voigt", 0.0), f"{key}.kelvin_voigt", "s", minimum=0)
        shapes = self.shell_shapes(t["shapes"], f"{key}.shapes")
        kinematics = self.string(t.get("kinematics", "first-order"), f"{key}.kinematics", SHELL_KINEMATICS)
        payload = self.payload(t.get("payload", {}), f"{key}.payload")
        initial_deformation = self.string(t.get("initial_deformation", "undeformed"),
                                          f"{key}.initial_deformation", INITIAL_DEFORMATIONS)
        return Link(name=name, length=length, linear_density=density * shapes.section_area, EI=None,
                    kelvin_voigt=kelvin_voigt, deformation=("v", "w", "alpha"), shapes=shapes,
                    kinematics=kinematics, payload=payload, initial_deformation=initial_deformation,
                    density=density, E=E, poisson=poisson)

    def shell_shapes(self, value: Any, key: str) -> Shapes:
        t = self.table(value, key, _SHELL_SHAPES_KEYS, 'a table {kind = "shell", section = "plate", …}')
        section = self.string(t.get("section", _MISSING), f"{key}.section", SHELL_SECTIONS)
        width = self.number(t.get("width", _MISSING), f"{key}.width", "m", positive=True)
        height = None
        if section == "box":
            height = self.number(t.get("height", _MISSING), f"{key}.height", "m", positive=True)
        elif "height" in t:
            raise self.fail(f"{key}.height", 'no value: a plate has no height (section = "box" has)', t["height"])
        thickness = self.number(t.get("thickness", _MISSING), f"{key}.thickness", "m", positive=True)
        if not thickness < min(width, height or width) / 2:
            raise self.fail(f"{key}.thickness", "a thickness below half the width and height (a thin wall)",
                            thickness)
        n_mesh = 3 if section == "box" else 2
        what = "[nx, nw, nh]" if section == "box" else "[nx, nw]"
        raw = t.get("mesh", _MISSING)
        expected = f"a list {what} of integers ≥ 1 (elements along the length, across the width" + (
            ", across the height)" if section == "box" else ")")
        if raw is _MISSING or not isinstance(raw, list) or len(raw) != n_mesh or not all(
                isinstance(m, int) and not isinstance(m, bool) and m >= 1 for m in raw):
            raise self.fail(f"{key}.mesh", expected, raw)
        pattern = self.string(t.get("pattern", "symmetric"), f"{key}.pattern", MESH_PATTERNS)
        if pattern == "symmetric" and any(m % 2 for m in raw[1:]):
            raise self.fail(f"{key}.mesh", f"{what} with even counts across (the symmetric pattern mirrors the "
                            'diagonals about the mid-line), or pattern = "A" or "B"', raw)
        modes = self.modes(t, key)
        nx, nw = raw[0], raw[1]
        with_mass = 3 * nx * (2 * (nw + raw[2]) if section == "box" else nw + 1)   # translations off the root
        if modes is not None and modes > with_mass:
            raise self.fail(f"{key}.modes", f"at most {with_mass} (the mesh's translational degrees of freedom "
                            "off the root)", modes)
        return Shapes(kind="shell", count=int(raw[0]), modes=modes, section=section, width=width, height=height,
                      thickness=thickness, mesh=tuple(int(m) for m in raw), pattern=pattern)

    def modes(self, t: dict, key: str) -> int | None:
        if "modes" not in t:
            return None
        m = t["modes"]
        if not isinstance(m, int) or isinstance(m, bool) or m < 1:
            raise self.fail(f"{key}.modes", "an integer ≥ 1 (modes kept, joint held)", m)
        return m

    def linear_density(self, t: dict, key: str) -> float:
        """Exactly one way to give the mass per length, so that the two can never disagree."""
        has_lin = "linear_density" in t
        has_vol = "density" in t or "area" in t
        if has_lin and has_vol:
            extra = "density" if "density" in t else "area"
            raise self.fail(f"{key}.{extra}", "either linear_density (kg/m) or density and area, not both",
                            t[extra])
        if has_lin:
            return self.number(t["linear_density"], f"{key}.linear_density", "kg/m", positive=True)
        if not has_vol:
            raise self.fail(f"{key}.linear_density", "a positive number (kg/m), or density (kg/m³) and "
                            "area (m²)")
        density = self.number(t.get("density", _MISSING), f"{key}.density", "kg/m³", positive=True)
        area = self.number(t.get("area", _MISSING), f"{key}.area", "m²", positive=True)
        rho_a = density * area
        if not (rho_a > 0 and math.isfinite(rho_a)):
            raise self.fail(f"{key}.area", "density·area to be a positive finite number (kg/m)", t["area"])
        return rho_a

    def deformation(self, value: Any, key: str) -> tuple[str, ...]:
        expected = 'a list of distinct fields from "v", "w", "alpha"'
        if not isinstance(value, list):
            raise self.fail(key, expected, value)
        for i, d in enumerate(value):
            if not isinstance(d, str) or d not in DEFORMATIONS:
                raise self.fail(f"{key}[{i + 1}]", 'one of "v", "w", "alpha"', d)
            if d in value[:i]:
                raise self.fail(f"{key}[{i + 1}]", f"{expected} (no duplicates)", d)
        return tuple(d for d in DEFORMATIONS if d in value)  # canonical order v, w, alpha

    def shapes(self, value: Any, key: str) -> Shapes:
        t = self.table(value, key, _SHAPES_KEYS, 'a table {kind = "clamped-free", count = 3}')
        kind = self.string(t.get("kind", "clamped-free"), f"{key}.kind", SHAPE_KINDS)
        count = t.get("count", 3)
        if not isinstance(count, int) or isinstance(count, bool) or count < 1:
            what = "number of elements" if kind == "fe" else "number of shape functions"
            raise self.fail(f"{key}.count", f"an integer ≥ 1 ({what})", count)
        modes = self.modes(t, key)
        if modes is not None and kind != "fe":
            raise self.fail(f"{key}.modes", 'no value: only finite-element links (kind = "fe" or "shell") are '
                            "reduced to modes", modes)
        if modes is not None and modes > 2 * count:
            raise self.fail(f"{key}.modes", f"at most {2 * count} (2 coordinates per element)", modes)
        return Shapes(kind=kind, count=count, modes=modes)

    def payload(self, value: Any, key: str) -> Payload:
        t = self.table(value, key, _PAYLOAD_KEYS, "a table {mass = …, inertia = …, offset = [x, y, z]}")
        mass = self.number(t.get("mass", 0.0), f"{key}.mass", "kg", minimum=0)
        raw = t.get("inertia", 0.0)
        inertia: float | tuple[float, ...]
        if isinstance(raw, list):
            inertia = self.vector(raw, f"{key}.inertia", 3, "kg m²", minimum=0)
        elif _is_number(raw):
            inertia = self.number(raw, f"{key}.inertia", "kg m²", minimum=0)
        else:
            raise self.fail(f"{key}.inertia", "a number ≥ 0 or a list [Jxx, Jyy, Jzz] of numbers ≥ 0 (kg m²)",
                            raw)
        offset = self.vector(t.get("offset", [0.0, 0.0, 0.0]), f"{key}.offset", 3, "m")
        return Payload(mass=mass, inertia=inertia, offset=offset)

    def fmu(self, value: Any, joints: tuple[Joint, ...], links: tuple[Link, ...]) -> FmuSettings:
        t = self.table(value, "fmu", _FMU_KEYS, "an [fmu] table")
        step = self.number(t.get("step", 1e-3), "fmu.step", "s", positive=True)
        integrator = self.string(t.get("integrator", "ss22"), "fmu.integrator", INTEGRATORS)
        expected = "[Θ1, Θ2] with 0.5 ≤ Θ1 ≤ Θ2 ≤ 1 (unconditional stability of SS22)"
        raw = t.get("theta", [0.5, 0.5])
        if not isinstance(raw, list) or len(raw) != 2:
            raise self.fail("fmu.theta", expected, raw)
        th1, th2 = (self.number(v, f"fmu.theta[{i + 1}]") for i, v in enumerate(raw))
        if not 0.5 <= th1 <= th2 <= 1.0:
            raise self.fail("fmu.theta", expected, raw)
        tolerance = self.number(t.get("tolerance", 1e-10), "fmu.tolerance", positive=True)
        tunable = self.tunable(t.get("tunable", []), joints, links)
        tip_load_inputs = self.boolean(t.get("tip_load_inputs", False), "fmu.tip_load_inputs")
        return FmuSettings(step=step, integrator=integrator, theta=(th1, th2), tolerance=tolerance,
                           tunable=tunable, tip_load_inputs=tip_load_inputs)

    def tunable(self, value: Any, joints: tuple[Joint, ...], links: tuple[Link, ...]) -> tuple[str, ...]:
        allowed = ["gravity"]
        allowed += [f"{link.name}.{p}" for link in links for p in LINK_TUNABLE]
        allowed += [f"{joint.name}.{p}" for joint in joints for p in JOINT_TUNABLE]
        forms = ("<link>.kelvin_voigt, <link>.payload.mass, <link>.payload.inertia, <joint>.stiffness, "
                 "<joint>.damping or gravity")
        if not isinstance(value, list):
            raise self.fail("fmu.tunable", f"a list of FMU parameter names ({forms})", value)
        out: list[str] = []
        for i, item in enumerate(value):
            key = f"fmu.tunable[{i + 1}]"
            if not isinstance(item, str) or item not in allowed:
                close = difflib.get_close_matches(item, allowed, n=1) if isinstance(item, str) else []
                hint = f' (did you mean "{close[0]}"?)' if close else ""
                raise self.fail(key, f"a parameter name of this scene: {forms}{hint}", item)
            if item in out:
                raise self.fail(key, "a parameter not already listed", item)
            out.append(item)
        return tuple(out)
