"""TOML scene → validated, typed, SI objects (the contract of docs/scene.md).

Everything downstream trusts these objects, so every check happens here, once, and every mistake is
reported as one :class:`SceneError` of the form ``FILE: KEY: expected WHAT, got VALUE`` (or ``FILE: KEY:
missing; expected WHAT``, ``FILE: KEY: unknown key; did you mean …``). Keys are dotted
paths with 1-based indices into the arrays of tables, e.g. ``link[1].EI``, ``joint[2].trajectory.segments[1].
until``, ``fmu.theta``, because the index exists even when the name is missing or wrong.

A link is a beam, a shell (``shapes.kind = "shell"``) or rigid (``deformation = []``); each has its reader.
The keys each table accepts, their defaults, units and bounds come from :data:`~flexlink.scene.schema.KEYS`;
the checks that relate several keys are in :mod:`flexlink.scene.checks`. The data classes live in
:mod:`flexlink.scene.schema` and are re-exported here.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import sys
import tomllib
from typing import Any

from flexlink.errors import SceneError
from flexlink.scene import checks
from flexlink.scene.checks import MISSING, is_number, show
from flexlink.scene.schema import (
    DEFORMATIONS,
    LINK_SENSORS,
    OPTIONAL,
    REQUIRED,
    RESERVED_NAMES,
    FmuSettings,
    Joint,
    Link,
    Payload,
    Scene,
    Segment,
    Shapes,
    Tool,
    Trajectory,
    Vec3,
    key_spec,
    section_keys,
)
from flexlink.scene.solver import THETA_RULE, SolverSettings, theta_valid

__all__ = [
    "FmuSettings",
    "Joint",
    "Link",
    "Payload",
    "Scene",
    "SceneError",
    "Segment",
    "Shapes",
    "Tool",
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
# A beam link knows the shell-only keys, to answer "E and poisson are for shell links" rather than "unknown".
_SHELL_ONLY = tuple(k for k in section_keys("shell_link") if k not in section_keys("link"))
_BOUNDS: dict[str, dict[str, Any]] = {"": {}, "> 0": {"positive": True}, "≥ 0": {"minimum": 0}}
_RIGID_BODY = ("mass", "center_of_mass", "inertia")     # a rigid link's mass properties given as a body


# ------------------------------------------------------------------------------------------ public API


def sanitise_identifier(name: str) -> str:
    """The scene's name made a C identifier, for use as the FMU's modelIdentifier.

    The modelIdentifier names the FMU's files and prefixes its C symbols, so it must be a C identifier and not a
    C keyword: other characters become ``_``, a leading digit or an empty name gets a leading ``_``, and a
    keyword a trailing one.
    """
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


def parse_scene(data: dict[str, Any], source: str = "<scene>", *, _path: str | None = None) -> Scene:
    """Validate an already-parsed TOML document (tests, programmatic scenes) into a :class:`Scene`.

    Parameters
    ----------
    data : dict
        The document as :func:`tomllib.loads` returns it.
    source : str
        The name the messages give the document (a file name, or ``<scene>``).

    Raises
    ------
    SceneError
        The first mistake in reading order, in one line naming its key.
    """
    return _Parser(source).scene(data, _path)


# ------------------------------------------------------------------------------------------ values


class _Values:
    """Reads single values: each returns the value in SI units, or raises the one SceneError naming its key."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, expected: str, value: Any = MISSING) -> SceneError:
        return checks.error(self.source, key, expected, value)

    def table(self, value: Any, key: str, section: str, what: str = "a table", *, also: tuple[str, ...] = ()
              ) -> dict:
        """Check a table and refuse keys its section of KEYS lacks, suggesting the closest (typos are common)."""
        known = section_keys(section) + also
        if not isinstance(value, dict):
            raise self.fail(key, what, value)
        for k in value:
            if k not in known:
                bare = str(k) if re.fullmatch(r"[A-Za-z0-9_-]+", str(k)) else show(str(k))
                where = f"{key}.{bare}" if key else bare
                close = difflib.get_close_matches(str(k), known, n=1, cutoff=0.6)
                hint = f'did you mean "{close[0]}"? ' if close else ""
                raise SceneError(f"{self.source}: {where}: unknown key; {hint}"
                                 f"expected one of: {', '.join(known)}")
        return value

    def get(self, t: dict, section: str, name: str) -> Any:
        """The key's value, else its default from KEYS (MISSING for a required or optional key)."""
        spec = key_spec(section, name)
        if name in t:
            return t[name]
        return MISSING if spec.default is REQUIRED or spec.default is OPTIONAL else spec.toml_default()

    def number_key(self, t: dict, section: str, name: str, prefix: str, **bounds: Any) -> float:
        """A number key with the unit, default and bounds of its row of KEYS.

        The row's bounds the loader reads itself are "> 0" and "≥ 0" (the part of the row's bounds before a
        semicolon); ``bounds`` given here replace those; other bounds are checked by the caller.
        """
        spec = key_spec(section, name)
        table_bounds = _BOUNDS.get(spec.bounds.split(";")[0].strip(), {})
        return self.number(self.get(t, section, name), f"{prefix}.{name}", spec.unit, **{**table_bounds, **bounds})

    def choice_key(self, t: dict, section: str, name: str, prefix: str) -> str:
        return self.string(self.get(t, section, name), f"{prefix}.{name}", key_spec(section, name).choices or None)

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
        if value is MISSING:
            raise self.fail(key, expected)
        if not is_number(value):
            raise self.fail(key, expected, value)
        try:
            x = float(value)
        except OverflowError:
            raise self.fail(key, expected, value) from None
        if math.isnan(x) or (math.isinf(x) and not (allow_inf and x > 0)):
            raise self.fail(key, expected, value)
        if (positive and not x > 0) or (minimum is not None and not x >= minimum):
            raise self.fail(key, expected, value)
        if x != 0.0 and abs(x) < sys.float_info.min:     # subnormal: its products underflow, its quotients blow up
            raise self.fail(key, f"{expected}, not subnormal (|x| ≥ {sys.float_info.min:.4g} or 0)", value)
        return x + 0.0                                    # -0.0 is 0.0

    def vector(self, value: Any, key: str, n: int, unit: str = "", *, minimum: float | None = None
               ) -> tuple[float, ...]:
        unit_txt = f" ({unit})" if unit else ""
        bound = f" ≥ {minimum:g}" if minimum is not None else ""
        expected = f"a list of {n} numbers{bound}{unit_txt}"
        if not isinstance(value, list | tuple) or len(value) != n:
            raise self.fail(key, expected, value)
        return tuple(self.number(v, f"{key}[{i + 1}]", unit, minimum=minimum) for i, v in enumerate(value))

    def vector3(self, value: Any, key: str, unit: str = "", *, minimum: float | None = None) -> Vec3:
        """A list of 3 numbers, as the (x, y, z) triple the scene's classes hold."""
        x, y, z = self.vector(value, key, 3, unit, minimum=minimum)
        return (x, y, z)

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


# ------------------------------------------------------------------------------------------ sections


class _Parser(_Values):
    """One method per table of the scene file, reading its keys in a fixed order (the first mistake wins)."""

    def scene(self, data: Any, path: str | None) -> Scene:
        top = self.table(data, "", "scene", "a TOML document (a table at the top level)")
        if "name" not in top:
            raise self.fail("name", "a string (the FMU modelName)")
        name = top["name"]
        if not isinstance(name, str) or not name.strip():
            raise self.fail("name", "a non-empty string (the FMU modelName)", name)
        gravity = self.vector3(self.get(top, "scene", "gravity"), "gravity", key_spec("scene", "gravity").unit)
        joint_data = self.array_of_tables(top, "joint")
        link_data = self.array_of_tables(top, "link")
        checks.same_count(self.source, len(joint_data), len(link_data))
        joints = tuple(self.joint(d, f"joint[{i + 1}]") for i, d in enumerate(joint_data))
        links = tuple(self.link(d, f"link[{i + 1}]") for i, d in enumerate(link_data))
        joints = checks.joint_axes(self.source, joint_data, joints, links)
        checks.unique_names(self.source, joints, links)
        tool = self.tool(self.get(top, "scene", "tool"))
        fmu = self.fmu(self.get(top, "scene", "fmu"), joints, links)
        return Scene(name=name, model_identifier=sanitise_identifier(name), gravity=gravity,
                     joints=joints, links=links, fmu=fmu, path=path, tool=tool)

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

    # ---------------------------------------------------------------------------------------- joints

    def joint(self, data: dict, key: str) -> Joint:
        t = self.table(data, key, "joint")
        name = self.name(self.get(t, "joint", "name"), f"{key}.name")
        axis = self.axis(t, key)
        origin = self.vector_key(t, "joint", "origin", key)
        rpy = self.vector_key(t, "joint", "rpy", key)
        inertia = self.number_key(t, "joint", "inertia", key)
        damping = self.number_key(t, "joint", "damping", key)
        drive = self.choice_key(t, "joint", "drive", key)
        stiffness = self.number_key(t, "joint", "stiffness", key)
        initial_angle = self.number_key(t, "joint", "initial_angle", key)
        initial_rate = self.number_key(t, "joint", "initial_rate", key)
        trajectory = None
        if "trajectory" in t:
            checks.trajectory_needs_position(self.source, key, drive)
            trajectory = self.trajectory(t["trajectory"], f"{key}.trajectory")
        return Joint(name=name, axis=axis, inertia=inertia, damping=damping, drive=drive, stiffness=stiffness,
                     initial_angle=initial_angle, initial_rate=initial_rate, trajectory=trajectory,
                     origin=origin, rpy=rpy)

    def axis(self, t: dict, key: str) -> tuple[float, float, float]:
        """A unit vector (a non-zero vector, normalised).

        Whether it must be normal to the link's x axis depends on the link, checked once the links are read
        (:func:`checks.joint_axes`).
        """
        value = self.get(t, "joint", "axis")
        raw = self.vector3(value, f"{key}.axis", key_spec("joint", "axis").unit)
        norm = math.hypot(*raw)
        if not norm > 0 or not math.isfinite(norm):
            raise self.fail(f"{key}.axis", "a non-zero finite vector", value)
        return (raw[0] / norm + 0.0, raw[1] / norm + 0.0, raw[2] / norm + 0.0)

    def vector_key(self, t: dict, section: str, name: str, prefix: str) -> tuple[float, float, float]:
        """A 3-vector key with the unit and default of its row of KEYS."""
        spec = key_spec(section, name)
        return self.vector3(self.get(t, section, name), f"{prefix}.{name}", spec.unit)

    def trajectory(self, data: Any, key: str) -> Trajectory:
        t = self.table(data, key, "joint.trajectory", "a table with segments = [{until, poly, cos}, ...]")
        raw = self.get(t, "joint.trajectory", "segments")
        expected = "a non-empty list of tables {until = …, poly = […], cos = [[amp, rad_per_s, phase], …]}"
        if not isinstance(raw, list) or not raw:
            raise self.fail(f"{key}.segments", expected, raw)
        segments: list[Segment] = []
        for i, item in enumerate(raw):
            previous = segments[-1].until if segments else None
            segments.append(self.segment(item, f"{key}.segments[{i + 1}]", expected, previous))
        return Trajectory(tuple(segments))

    def segment(self, item: Any, key: str, expected: str, previous: float | None) -> Segment:
        section = "joint.trajectory.segments"
        s = self.table(item, key, section, expected)
        until = self.number_key(s, section, "until", key, allow_inf=True)
        if previous is not None and not until > previous:
            raise self.fail(f"{key}.until", f"a time after the previous segment's until = "
                            f"{show(previous)} (strictly increasing)", until)
        poly_raw = self.get(s, section, "poly")
        if not isinstance(poly_raw, list):
            raise self.fail(f"{key}.poly", "a list of numbers (coefficients of t^0, t^1, …, rad)", poly_raw)
        unit = key_spec(section, "poly").unit
        poly = tuple(self.number(c, f"{key}.poly[{k + 1}]", unit) for k, c in enumerate(poly_raw))
        cos_raw = self.get(s, section, "cos")
        if not isinstance(cos_raw, list):
            raise self.fail(f"{key}.cos", "a list of [amp, rad_per_s, phase] triples", cos_raw)
        cos = tuple(self.vector3(c, f"{key}.cos[{k + 1}]") for k, c in enumerate(cos_raw))
        return Segment(until=until, poly=poly, cos=cos)

    # ----------------------------------------------------------------------------------------- links

    def link(self, data: dict, key: str) -> Link:
        shapes_raw = data.get("shapes") if isinstance(data, dict) else None
        if isinstance(shapes_raw, dict) and shapes_raw.get("kind") == "shell":
            return self.shell_link(data, key)
        t = self.table(data, key, "link", also=_SHELL_ONLY)
        checks.no_shell_material(self.source, key, t)
        if isinstance(t.get("deformation"), list) and not t["deformation"]:
            return self.rigid_link(t, key)
        name = self.name(self.get(t, "link", "name"), f"{key}.name")
        checks.only_for_rigid(self.source, key, t, _RIGID_BODY)
        length = self.number_key(t, "link", "length", key)
        linear_density = self.linear_density(t, key)
        if "EI" not in t:
            raise self.fail(f"{key}.EI", "a positive number (N m²), required for a flexible link (a rigid link "
                            "has deformation = [])")
        EI = self.number_key(t, "link", "EI", key)
        given = {k: self.number_key(t, "link", k, key) for k in ("EI_out", "GJ", "polar_inertia") if k in t}
        kelvin_voigt = self.number_key(t, "link", "kelvin_voigt", key)
        deformation = self.deformation(self.get(t, "link", "deformation"), f"{key}.deformation")
        checks.deformation_data(self.source, key, deformation, given)
        shapes = self.shapes(self.get(t, "link", "shapes"), f"{key}.shapes")
        kinematics = self.choice_key(t, "link", "kinematics", key)
        payload = self.payload(self.get(t, "link", "payload"), f"{key}.payload")
        initial_deformation = self.choice_key(t, "link", "initial_deformation", key)
        return Link(name=name, length=length, linear_density=linear_density, EI=EI,
                    EI_out=given.get("EI_out"), GJ=given.get("GJ"),
                    polar_inertia=given.get("polar_inertia"), kelvin_voigt=kelvin_voigt,
                    deformation=deformation, shapes=shapes, kinematics=kinematics, payload=payload,
                    initial_deformation=initial_deformation, sensors=self.sensors(t, "link", key))

    def rigid_link(self, t: dict, key: str) -> Link:
        """A rigid link (deformation = []), as a uniform rod or as a body.

        A uniform slender rod takes linear_density (or density and area) and polar_inertia; a body takes mass,
        center_of_mass and inertia.  Its length may be 0.
        """
        name = self.name(self.get(t, "link", "name"), f"{key}.name")
        checks.not_for_rigid(self.source, key, t)
        length = self.number_key(t, "link", "length", key, positive=False, minimum=0)
        mass: float | None
        com: Vec3 | None
        inertia: tuple[float, ...] | None
        if checks.rigid_mass_form(self.source, key, t, _RIGID_BODY):
            checks.no_polar_inertia_with_body(self.source, key, t)
            mass = self.number_key(t, "link", "mass", key)
            com = (0.0, 0.0, 0.0)
            if "center_of_mass" in t:
                com = self.vector_key(t, "link", "center_of_mass", key)
            inertia = self.rigid_inertia(t, key)
            linear_density, polar_inertia = 0.0, None
        else:
            mass, com, inertia = None, None, None
            linear_density = self.linear_density(t, key)
            polar_inertia = self.number_key(t, "link", "polar_inertia", key) if "polar_inertia" in t else None
        payload = self.payload(self.get(t, "link", "payload"), f"{key}.payload")
        initial_deformation = self.choice_key(t, "link", "initial_deformation", key)
        return Link(name=name, length=length, linear_density=linear_density, EI=None, polar_inertia=polar_inertia,
                    deformation=(), payload=payload, initial_deformation=initial_deformation,
                    mass=mass, center_of_mass=com, inertia=inertia, sensors=self.sensors(t, "link", key))

    def rigid_inertia(self, t: dict, key: str) -> tuple[float, ...]:
        """A rigid body's inertia about its centre of mass (kg m²), always as 6 values.

        Given as [Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]; the moments ≥ 0 and the tensor physical
        (:func:`checks.physical_inertia`).
        """
        if "inertia" not in t:
            return (0.0,) * 6
        raw = t["inertia"]
        unit = key_spec("link", "inertia").unit
        if not isinstance(raw, list) or len(raw) not in (3, 6):
            raise self.fail(f"{key}.inertia", f"[Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] ({unit}) about "
                            "the centre of mass", raw)
        values = tuple(self.number(v, f"{key}.inertia[{i + 1}]", unit, minimum=0 if i < 3 else None)
                       for i, v in enumerate(raw))
        values += (0.0,) * (6 - len(values))
        checks.physical_inertia(self.source, f"{key}.inertia", raw, values)
        return values

    def linear_density(self, t: dict, key: str) -> float:
        """linear_density, or density × area."""
        if checks.mass_per_length_given_once(self.source, key, t):
            return self.number_key(t, "link", "linear_density", key)
        density = self.number_key(t, "link", "density", key)
        area = self.number_key(t, "link", "area", key)
        return checks.density_times_area(self.source, key, t, density, area)

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

    def sensors(self, t: dict, section: str, key: str) -> tuple[str, ...]:
        """The link's declared sensors (:data:`LINK_SENSORS`): distinct names, in the table's order."""
        value, where = self.get(t, section, "sensors"), f"{key}.sensors"
        choices = ", ".join(f'"{c}"' for c in LINK_SENSORS)
        if not isinstance(value, list):
            raise self.fail(where, f"a list of distinct sensors from {choices}", value)
        for i, s in enumerate(value):
            if not isinstance(s, str) or s not in LINK_SENSORS:
                raise self.fail(f"{where}[{i + 1}]", f"one of {choices}", s)
            if s in value[:i]:
                raise self.fail(f"{where}[{i + 1}]", f"a sensor not already listed ({choices})", s)
        return tuple(s for s in LINK_SENSORS if s in value)

    def shapes(self, value: Any, key: str) -> Shapes:
        t = self.table(value, key, "link.shapes", 'a table {kind = "clamped-free", count = 3}')
        kind = self.choice_key(t, "link.shapes", "kind", key)
        count = self.get(t, "link.shapes", "count")
        if not isinstance(count, int) or isinstance(count, bool) or count < 1:
            what = "number of elements" if kind == "fe" else "number of shape functions"
            raise self.fail(f"{key}.count", f"an integer ≥ 1 ({what})", count)
        modes = self.modes(t, key)
        checks.beam_modes(self.source, key, kind, count, modes)
        return Shapes(kind=kind, count=count, modes=modes)

    def modes(self, t: dict, key: str) -> int | None:
        if "modes" not in t:
            return None
        m = t["modes"]
        if not isinstance(m, int) or isinstance(m, bool) or m < 1:
            raise self.fail(f"{key}.modes", "an integer ≥ 1 (modes kept, joint held)", m)
        return m

    def payload(self, value: Any, key: str) -> Payload:
        section = "link.payload"
        t = self.table(value, key, section, "a table {mass = …, inertia = …, offset = [x, y, z]}")
        mass = self.number_key(t, section, "mass", key)
        raw = self.get(t, section, "inertia")
        inertia: float | Vec3
        if isinstance(raw, list):
            inertia = self.vector3(raw, f"{key}.inertia", key_spec(section, "inertia").unit, minimum=0)
        elif is_number(raw):
            inertia = self.number_key(t, section, "inertia", key)
        else:
            raise self.fail(f"{key}.inertia", "a number ≥ 0 or a list [Jxx, Jyy, Jzz] of numbers ≥ 0 (kg m²)",
                            raw)
        offset = self.vector3(self.get(t, section, "offset"), f"{key}.offset", key_spec(section, "offset").unit)
        return Payload(mass=mass, inertia=inertia, offset=offset)

    # ------------------------------------------------------------------------------------ shell links

    def shell_link(self, data: dict, key: str) -> Link:
        """A plate or box-section link of DKT + CST shell elements (seed 001 part 5).

        It takes material properties, not section properties, since the mesh integrates them.
        """
        section = "shell_link"
        t = self.table(data, key, section, "a table")
        name = self.name(self.get(t, section, "name"), f"{key}.name")
        length = self.number_key(t, section, "length", key)
        density = self.number_key(t, section, "density", key)
        E = self.number_key(t, section, "E", key)
        poisson = self.number_key(t, section, "poisson", key)
        if not -1.0 < poisson < 0.5:
            raise self.fail(f"{key}.poisson", "a number in (-1, 0.5) (Poisson's ratio)", poisson)
        kelvin_voigt = self.number_key(t, section, "kelvin_voigt", key)
        shapes = self.shell_shapes(self.get(t, section, "shapes"), f"{key}.shapes")
        kinematics = self.choice_key(t, section, "kinematics", key)
        payload = self.payload(self.get(t, section, "payload"), f"{key}.payload")
        initial_deformation = self.choice_key(t, section, "initial_deformation", key)
        return Link(name=name, length=length, linear_density=density * shapes.section_area, EI=None,
                    kelvin_voigt=kelvin_voigt, deformation=("v", "w", "alpha"), shapes=shapes,
                    kinematics=kinematics, payload=payload, initial_deformation=initial_deformation,
                    density=density, E=E, poisson=poisson, sensors=self.sensors(t, section, key))

    def shell_shapes(self, value: Any, key: str) -> Shapes:
        section = "shell_link.shapes"
        t = self.table(value, key, section, 'a table {kind = "shell", section = "plate", …}')
        box = self.choice_key(t, section, "section", key) == "box"
        width = self.number_key(t, section, "width", key)
        height = None
        if box:
            height = self.number_key(t, section, "height", key)
        else:
            checks.plate_has_no_height(self.source, key, t)
        thickness = self.number_key(t, section, "thickness", key)
        checks.thin_wall(self.source, key, thickness, width, height)
        mesh, what = self.mesh(self.get(t, section, "mesh"), key, box)
        pattern = self.choice_key(t, section, "pattern", key)
        checks.symmetric_mesh(self.source, key, what, mesh, pattern)
        modes = self.modes(t, key)
        checks.shell_modes(self.source, key, "box" if box else "plate", mesh, modes)
        return Shapes(kind="shell", count=int(mesh[0]), modes=modes, section="box" if box else "plate",
                      width=width, height=height, thickness=thickness, mesh=tuple(int(m) for m in mesh),
                      pattern=pattern)

    def mesh(self, raw: Any, key: str, box: bool) -> tuple[list[int], str]:
        """Element counts [nx, nw] (plate) or [nx, nw, nh] (box), and how the message spells them."""
        what = "[nx, nw, nh]" if box else "[nx, nw]"
        expected = f"a list {what} of integers ≥ 1 (elements along the length, across the width" + (
            ", across the height)" if box else ")")
        if raw is MISSING or not isinstance(raw, list) or len(raw) != (3 if box else 2) or not all(
                isinstance(m, int) and not isinstance(m, bool) and m >= 1 for m in raw):
            raise self.fail(f"{key}.mesh", expected, raw)
        return raw, what

    # ------------------------------------------------------------------------------------------ tool

    def tool(self, value: Any) -> Tool:
        t = self.table(value, "tool", "tool", "a [tool] table {origin = [x, y, z], rpy = [roll, pitch, yaw]}")
        return Tool(origin=self.vector_key(t, "tool", "origin", "tool"), rpy=self.vector_key(t, "tool", "rpy", "tool"))

    # ------------------------------------------------------------------------------------------- fmu

    def fmu(self, value: Any, joints: tuple[Joint, ...], links: tuple[Link, ...]) -> FmuSettings:
        t = self.table(value, "fmu", "fmu", "an [fmu] table")
        step = self.number_key(t, "fmu", "step", "fmu")
        integrator = self.choice_key(t, "fmu", "integrator", "fmu")
        expected = f"[Θ1, Θ2] with {THETA_RULE} (unconditional stability of SS22)"
        raw = self.get(t, "fmu", "theta")
        if not isinstance(raw, list) or len(raw) != 2:
            raise self.fail("fmu.theta", expected, raw)
        th1, th2 = (self.number(v, f"fmu.theta[{i + 1}]") for i, v in enumerate(raw))
        if not theta_valid(th1, th2):
            raise self.fail("fmu.theta", expected, raw)
        tolerance = self.number_key(t, "fmu", "tolerance", "fmu")
        tunable = checks.tunable_names(self.source, self.get(t, "fmu", "tunable"), joints, links)
        tip_load_inputs = self.boolean(self.get(t, "fmu", "tip_load_inputs"), "fmu.tip_load_inputs")
        newton_matrix = self.choice_key(t, "fmu", "newton_matrix", "fmu")
        directional = self.boolean(self.get(t, "fmu", "directional_derivatives"), "fmu.directional_derivatives")
        solver = SolverSettings(step=step, theta=(th1, th2), tolerance=tolerance)
        return FmuSettings(solver=solver, integrator=integrator, tunable=tunable, tip_load_inputs=tip_load_inputs,
                           newton_matrix=newton_matrix, directional_derivatives=directional)
