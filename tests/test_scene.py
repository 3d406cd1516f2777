"""flexlink.scene.loader: the SCENE.md contract — defaults, units, and one clear SceneError for every mistake."""

from __future__ import annotations

import copy
import dataclasses
import math
import random
from pathlib import Path

import pytest

from flexlink.errors import SceneError
from flexlink.scene.loader import (
    FmuSettings,
    Payload,
    Scene,
    Segment,
    Shapes,
    Tool,
    Trajectory,
    load_scene,
    parse_scene,
    sanitise_identifier,
)
from flexlink.scene.schema import (
    KEYS,
    NUMBER_BOUNDS,
    OPTIONAL,
    REQUIRED,
    SECTIONS,
    Joint,
    Link,
    section_keys,
)
from flexlink.scene.solver import SolverSettings

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SOURCE = "scenes/bad.toml"
PI = math.pi


def base() -> dict:
    """A small valid scene exercising most keys, to be broken one key at a time."""
    return {
        "name": "robot",
        "gravity": [0.0, -9.81, 0.0],
        "joint": [
            {"name": "hub", "axis": [0.0, 0.0, 1.0], "inertia": 0.1, "drive": "torque"},
            {"name": "elbow", "drive": "position",
             "trajectory": {"segments": [{"until": 1.0, "poly": [0.0, 1.0]}, {"until": math.inf,
                                                                               "poly": [1.0]}]}},
        ],
        "link": [
            {"name": "arm", "length": 2.2, "linear_density": 0.349, "EI": 93.72,
             "payload": {"mass": 0.5, "inertia": 1e-3}},
            {"name": "forearm", "length": 1.0, "density": 2700.0, "area": 1e-4, "EI": 50.0, "EI_out": 40.0,
             "GJ": 30.0, "polar_inertia": 1e-5, "deformation": ["v", "w", "alpha"],
             "shapes": {"kind": "fe", "count": 4}},
        ],
        "fmu": {"step": 1e-3, "theta": [0.5, 0.5], "tunable": ["arm.kelvin_voigt"]},
    }


def minimal() -> dict:
    return {"name": "m", "joint": [{"name": "j"}],
            "link": [{"name": "l", "length": 1.0, "linear_density": 1.0, "EI": 1.0}]}


# ------------------------------------------------------------------------------------------- examples


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.toml")), ids=lambda p: p.name)
def test_every_example_loads(path: Path) -> None:
    scene = load_scene(path)
    assert isinstance(scene, Scene)
    assert scene.path == str(path)
    assert scene.model_identifier == path.stem
    assert path.read_text(encoding="utf-8").startswith("#"), "each example starts with a comment header"


def test_expected_examples_exist() -> None:
    names = {p.stem for p in EXAMPLES.glob("*.toml")}
    assert {"rotating_link", "rotating_link_linear", "rotating_link_payload", "steel_beam_gravity",
            "steel_beam_raise", "flexible_pendulum", "aluminium_arm_payload"} <= names


def test_rotating_link_values() -> None:
    s = load_scene(EXAMPLES / "rotating_link.toml")
    (j,), (link,) = s.joints, s.links
    assert link.EI == pytest.approx(71e9 * 1.32e-9)
    assert (link.length, link.linear_density, link.kinematics) == (2.2, 0.349, "second-order")
    assert link.shapes == Shapes("clamped-free", 3)
    assert (j.drive, j.inertia) == ("torque", 0.1)
    assert not s.has_gravity and not link.payload.is_present
    assert load_scene(EXAMPLES / "rotating_link_linear.toml").links[0].kinematics == "linear"
    payload = load_scene(EXAMPLES / "rotating_link_payload.toml").links[0].payload
    assert payload == Payload(0.5, 1e-3, (0.0, 0.0, 0.0)) and payload.is_present


def test_steel_beam_examples() -> None:
    g = load_scene(EXAMPLES / "steel_beam_gravity.toml")
    beam = g.links[0]
    assert beam.linear_density == pytest.approx(7800 * 1.2e-3)
    assert beam.EI == pytest.approx(2.1e11 * 4.1666e-7)
    assert beam.shapes == Shapes("fe", 5) and beam.initial_deformation == "undeformed"
    assert g.gravity == (0.0, -9.81, 0.0) and g.has_gravity
    assert g.joints[0].trajectory.evaluate(0.3) == (0.0, 0.0, 0.0)
    r = load_scene(EXAMPLES / "steel_beam_raise.toml")
    assert r.links[0].initial_deformation == "static"
    assert r.joints[0].trajectory.evaluate(0.0) == pytest.approx((0.0, 0.0, PI**3 / 4))
    assert r.joints[0].trajectory.evaluate(2.0) == pytest.approx((PI / 2, 0.0, 0.0))


def test_aluminium_arm_law_is_barraco() -> None:
    """Seed 001 §6.2 in degrees: continuity of θ and θ̇ at t = 1, 90° at rest at t = 5, θ̈(0) = −3.316."""
    s = load_scene(EXAMPLES / "aluminium_arm_payload.toml")
    assert s.links[0].payload.mass == 10.0
    law = s.joints[0].trajectory
    deg = PI / 180
    for t in (0.0, 0.25, 0.5, 0.999):
        assert law.evaluate(t)[0] == pytest.approx((70 * t - 95 * t**2 + 55 * t**3) * deg, abs=1e-12)
    for t in (1.0, 2.0, 3.7, 4.999):
        tp = (t - 1) / 4
        ref = (30 + 180 * tp - 180 * tp**2 + 60 * tp**3) * deg
        assert law.evaluate(t)[0] == pytest.approx(ref, abs=1e-12)
    assert law.segments[0].evaluate(1.0)[:2] == pytest.approx(law.segments[1].evaluate(1.0)[:2], abs=1e-12)
    assert law.segments[1].evaluate(5.0)[:2] == pytest.approx((PI / 2, 0.0), abs=1e-12)
    assert law.evaluate(0.0)[2] == pytest.approx(-3.316, abs=1e-3)
    assert law.evaluate(7.0) == (PI / 2, 0.0, 0.0)


def test_flexible_pendulum_hangs() -> None:
    s = load_scene(EXAMPLES / "flexible_pendulum.toml")
    j, link = s.joints[0], s.links[0]
    assert j.drive == "free" and j.initial_angle == pytest.approx(-PI / 2)
    assert link.linear_density == pytest.approx(0.117) and link.EI == pytest.approx(0.315)
    assert link.payload.mass == 0.031 and link.length == 0.835


# ------------------------------------------------------------------------------------------- defaults


def test_defaults_follow_scene_md() -> None:
    s = parse_scene(minimal())
    assert s.gravity == (0.0, 0.0, 0.0) and not s.has_gravity and s.path is None
    (j,), (link,) = s.joints, s.links
    assert j.axis == (0.0, 0.0, 1.0)
    assert (j.inertia, j.damping, j.drive, j.stiffness) == (0.0, 0.0, "torque", 0.0)
    assert (j.initial_angle, j.initial_rate, j.trajectory) == (0.0, 0.0, None)
    assert (link.EI_out, link.GJ, link.polar_inertia, link.kelvin_voigt) == (None, None, None, 0.0)
    assert link.deformation == ("v",)
    assert link.shapes == Shapes("clamped-free", 3)
    assert link.kinematics == "second-order" and link.initial_deformation == "undeformed"
    assert link.payload == Payload(0.0, 0.0, (0.0, 0.0, 0.0)) and not link.payload.is_present
    assert s.fmu == FmuSettings(SolverSettings(1e-3, (0.5, 0.5), 1e-10), "ss22", (), False)
    assert (j.origin, j.rpy) == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)) and s.tool == Tool()
    assert not link.is_rigid and (link.mass, link.center_of_mass, link.inertia) == (None, None, None)


def test_values_are_floats_and_partial_tables_get_defaults() -> None:
    d = minimal()
    d["link"][0].update(length=2, shapes={"kind": "polynomial"}, payload={"inertia": [1, 2, 3]})
    d["joint"][0].update(axis=[0, 2, 0], initial_angle=1)
    s = parse_scene(d)
    link, j = s.links[0], s.joints[0]
    assert isinstance(link.length, float) and link.shapes == Shapes("polynomial", 3)
    assert link.payload.inertia == (1.0, 2.0, 3.0) and link.payload.is_present
    assert j.axis == (0.0, 1.0, 0.0) and isinstance(j.initial_angle, float)


def test_density_times_area() -> None:
    s = parse_scene(base())
    assert s.links[1].linear_density == pytest.approx(2700.0 * 1e-4)


def test_full_scene() -> None:
    s = parse_scene(base(), SOURCE)
    assert s.links[1].deformation == ("v", "w", "alpha")
    assert (s.links[1].EI_out, s.links[1].GJ, s.links[1].polar_inertia) == (40.0, 30.0, 1e-5)
    assert s.fmu.tunable == ("arm.kelvin_voigt",)


def test_deformation_order_is_canonical_and_polar_inertia_may_be_zero() -> None:
    d = base()
    d["link"][1].update(deformation=["alpha", "v"], polar_inertia=0.0)
    assert parse_scene(d).links[1].deformation == ("v", "alpha")


def test_tunable_names() -> None:
    d = base()
    d["fmu"]["tunable"] = ["gravity", "arm.kelvin_voigt", "forearm.payload.mass", "arm.payload.inertia",
                           "hub.stiffness", "elbow.damping"]
    assert len(parse_scene(d).fmu.tunable) == 6


@pytest.mark.parametrize(("name", "ident"), [("rotating_link", "rotating_link"), ("my robot-2", "my_robot_2"),
                                             ("2link", "_2link"), ("bras é", "bras__"), ("int", "int_")])
def test_model_identifier(name: str, ident: str) -> None:
    assert sanitise_identifier(name) == ident
    d = minimal()
    d["name"] = name
    assert parse_scene(d).model_identifier == ident
    assert parse_scene(d).name == name


def test_fmu_settings_read() -> None:
    d = minimal()
    d["fmu"] = {"step": 2e-4, "theta": [0.6, 0.9], "tolerance": 1e-8, "tip_load_inputs": True}
    assert parse_scene(d).fmu == FmuSettings(SolverSettings(2e-4, (0.6, 0.9), 1e-8), "ss22", (), True)


# ----------------------------------------------------------------------------------------- trajectory


def test_raise_law_against_its_analytic_derivatives() -> None:
    law = Trajectory((Segment(1.0, (PI / 4,), ((-PI / 4, PI, 0.0),)), Segment(math.inf, (PI / 2,))))
    for t in (0.0, 0.1, 0.37, 0.5, 0.9, 0.999):
        th, om, al = law.evaluate(t)
        assert th == pytest.approx(PI / 4 * (1 - math.cos(PI * t)), abs=1e-15)
        assert om == pytest.approx(PI**2 / 4 * math.sin(PI * t), abs=1e-14)
        assert al == pytest.approx(PI**3 / 4 * math.cos(PI * t), abs=1e-13)
    assert law.evaluate(1.0) == (PI / 2, 0.0, 0.0)  # t == until belongs to the next segment
    assert law.evaluate(50.0) == (PI / 2, 0.0, 0.0)


def test_polynomial_and_phase_derivatives() -> None:
    seg = Segment(math.inf, (0.3, -1.0, 0.5, 2.0, -0.25), ((0.7, 3.0, 0.4), (-0.1, 11.0, -1.0)))
    for t in (-1.3, 0.0, 0.8, 2.5):
        th, om, al = seg.evaluate(t)
        ref = (0.3 - t + 0.5 * t**2 + 2 * t**3 - 0.25 * t**4
               + 0.7 * math.cos(3 * t + 0.4) - 0.1 * math.cos(11 * t - 1))
        dref = (-1 + t + 6 * t**2 - t**3 - 2.1 * math.sin(3 * t + 0.4) + 1.1 * math.sin(11 * t - 1))
        ddref = 1 + 12 * t - 3 * t**2 - 6.3 * math.cos(3 * t + 0.4) + 12.1 * math.cos(11 * t - 1)
        assert (th, om, al) == pytest.approx((ref, dref, ddref), rel=1e-12, abs=1e-12)


def test_last_segment_extends_beyond_its_end() -> None:
    law = Trajectory((Segment(1.0, (1.0,)), Segment(2.0, (0.0, 1.0))))
    assert law.evaluate(0.5)[0] == 1.0 and law.evaluate(3.0) == (3.0, 1.0, 0.0)


def test_trajectory_from_toml(tmp_path: Path) -> None:
    f = tmp_path / "law.toml"
    f.write_text("""name = "law"
[[joint]]
name = "j"
drive = "position"
[joint.trajectory]
segments = [
    { until = 1.0, poly = [0.7853981633974483], cos = [[-0.7853981633974483, 3.141592653589793, 0.0]] },
    { until = inf, poly = [1.5707963267948966] },
]
[[link]]
name = "l"
length = 1.0
linear_density = 1.0
EI = 1.0
""", encoding="utf-8")
    law = load_scene(f).joints[0].trajectory
    assert law.segments[-1].until == math.inf
    assert law.evaluate(0.5) == pytest.approx((PI / 4, PI**2 / 4, 0.0), abs=1e-14)


# ------------------------------------------------------------------------------------- bad input paths


def _set(*path_and_value):
    *path, value = path_and_value

    def mutate(d: dict) -> None:
        node = d
        for p in path[:-1]:
            node = node[p]
        node[path[-1]] = value
    return mutate


def _del(*path):
    def mutate(d: dict) -> None:
        node = d
        for p in path[:-1]:
            node = node[p]
        del node[path[-1]]
    return mutate


def _pop_list(key: str):
    return lambda d: d[key].pop()


NAN, INF = math.nan, math.inf
BAD = [
    # unknown keys (with a suggestion)
    ("unknown-top", _set("gravty", [0, 0, 0]), "gravty", 'did you mean "gravity"'),
    ("unknown-link", _set("link", 0, "lenght", 1.0), "link[1].lenght", 'did you mean "length"'),
    ("unknown-joint", _set("joint", 0, "dampng", 1.0), "joint[1].dampng", 'did you mean "damping"'),
    ("unknown-shapes", _set("link", 1, "shapes", "knd", "fe"), "link[2].shapes.knd", 'did you mean "kind"'),
    ("unknown-payload", _set("link", 0, "payload", "mas", 1.0), "link[1].payload.mas", 'did you mean "mass"'),
    ("unknown-fmu", _set("fmu", "stepp", 1.0), "fmu.stepp", 'did you mean "step"'),
    ("unknown-segment", _set("joint", 1, "trajectory", "segments", 0, "unti", 1.0),
     "joint[2].trajectory.segments[1].unti", 'did you mean "until"'),
    ("unknown-quoted", _set("link", 0, "a\nb", 1.0), 'link[1]."a\\nb"', "unknown key; expected one of"),
    ("unknown-far", _set("link", 0, "zzz", 1.0), "link[1].zzz", "expected one of: name, length"),
    # missing values
    ("missing-name", _del("name"), "name", "missing; expected a string"),
    ("empty-name", _set("name", "  "), "name", "a non-empty string"),
    ("missing-length", _del("link", 0, "length"), "link[1].length",
     "missing; expected a positive number (m)"),
    ("missing-EI", _del("link", 0, "EI"), "link[1].EI", "missing; expected a positive number (N m²)"),
    ("missing-joint-name", _del("joint", 0, "name"), "joint[1].name", "missing; expected a name"),
    ("missing-density", _del("link", 0, "linear_density"), "link[1].linear_density",
     "or density (kg/m³) and area (m²)"),
    ("missing-area", _del("link", 1, "area"), "link[2].area", "missing; expected a positive number (m²)"),
    ("missing-segments", _set("joint", 1, "trajectory", {}), "joint[2].trajectory.segments",
     "non-empty list"),
    ("missing-joints", _del("joint"), "joint", "at least one [[joint]]"),
    ("missing-links", _set("link", []), "link", "at least one [[link]]"),
    # wrong types (bool is not a number)
    ("str-length", _set("link", 0, "length", "2.2"), "link[1].length", 'positive number (m), got "2.2"'),
    ("bool-inertia", _set("joint", 0, "inertia", True), "joint[1].inertia", "number ≥ 0 (kg m²), got true"),
    ("bool-EI", _set("link", 0, "EI", False), "link[1].EI", "positive number (N m²), got false"),
    ("list-step", _set("fmu", "step", [1e-3]), "fmu.step", "positive number (s)"),
    ("str-gravity", _set("gravity", "down"), "gravity", "a list of 3 numbers (m/s²)"),
    ("short-gravity", _set("gravity", [0, -9.81]), "gravity", "a list of 3 numbers"),
    ("str-gravity-item", _set("gravity", [0, "g", 0]), "gravity[2]", "finite number"),
    ("table-joint", _set("joint", {"name": "hub"}), "joint", "at least one [[joint]]"),
    ("str-joint-item", _set("joint", 0, "x"), "joint[1]", "a [[joint]] table"),
    ("str-shapes", _set("link", 0, "shapes", "fe"), "link[1].shapes", "a table"),
    ("str-payload", _set("link", 0, "payload", 1.0), "link[1].payload", "a table"),
    ("str-fmu", _set("fmu", 3), "fmu", "an [fmu] table"),
    ("bool-tip-load", _set("fmu", "tip_load_inputs", "yes"), "fmu.tip_load_inputs", "true or false"),
    ("int-name", _set("name", 3), "name", "a non-empty string"),
    # non-positive geometry and material
    ("neg-length", _set("link", 0, "length", -2.2), "link[1].length", "positive number (m), got -2.2"),
    ("zero-length", _set("link", 0, "length", 0), "link[1].length", "positive number (m), got 0"),
    ("neg-lin-density", _set("link", 0, "linear_density", -1.0), "link[1].linear_density",
     "positive number (kg/m)"),
    ("zero-EI", _set("link", 0, "EI", 0.0), "link[1].EI", "positive number (N m²), got 0.0"),
    ("neg-density", _set("link", 1, "density", -7800.0), "link[2].density", "positive number (kg/m³)"),
    ("zero-area", _set("link", 1, "area", 0.0), "link[2].area", "positive number (m²)"),
    ("neg-EI_out", _set("link", 1, "EI_out", -1.0), "link[2].EI_out", "positive number (N m²)"),
    ("zero-GJ", _set("link", 1, "GJ", 0.0), "link[2].GJ", "positive number (N m²)"),
    ("both-densities", _set("link", 1, "linear_density", 0.27), "link[2].density",
     "either linear_density (kg/m) or density and area, not both"),
    # NaN and inf
    ("nan-EI", _set("link", 0, "EI", NAN), "link[1].EI", "got nan"),
    ("inf-length", _set("link", 0, "length", INF), "link[1].length", "got inf"),
    ("nan-gravity", _set("gravity", [0.0, NAN, 0.0]), "gravity[2]", "finite number (m/s²), got nan"),
    ("inf-angle", _set("joint", 0, "initial_angle", INF), "joint[1].initial_angle", "finite number (rad)"),
    ("ninf-rate", _set("joint", 0, "initial_rate", -INF), "joint[1].initial_rate", "got -inf"),
    ("nan-poly", _set("joint", 1, "trajectory", "segments", 0, "poly", [0.0, NAN]),
     "joint[2].trajectory.segments[1].poly[2]", "finite number (rad), got nan"),
    ("nan-until", _set("joint", 1, "trajectory", "segments", 0, "until", NAN),
     "joint[2].trajectory.segments[1].until", "expected a number (s) or inf, got nan"),
    ("ninf-until", _set("joint", 1, "trajectory", "segments", 0, "until", -INF),
     "joint[2].trajectory.segments[1].until", "got -inf"),
    ("inf-cos", _set("joint", 1, "trajectory", "segments", 0, "cos", [[1.0, INF, 0.0]]),
     "joint[2].trajectory.segments[1].cos[1][2]", "finite number"),
    ("inf-offset", _set("link", 0, "payload", "offset", [INF, 0, 0]), "link[1].payload.offset[1]",
     "finite number (m)"),
    ("inf-step", _set("fmu", "step", INF), "fmu.step", "positive number (s), got inf"),
    ("nan-density", _set("link", 1, "density", NAN), "link[2].density", "got nan"),
    ("nan-kv", _set("link", 0, "kelvin_voigt", NAN), "link[1].kelvin_voigt", "got nan"),
    ("huge-int", _set("link", 0, "length", 10**400), "link[1].length", "positive number (m)"),
    ("overflow-rho-A", lambda d: d["link"][1].update(density=1e300, area=1e10), "link[2].area",
     "density·area"),
    # negative inertia, damping, stiffness, kelvin_voigt, payload
    ("neg-inertia", _set("joint", 0, "inertia", -0.1), "joint[1].inertia", "number ≥ 0 (kg m²), got -0.1"),
    ("neg-damping", _set("joint", 0, "damping", -1), "joint[1].damping", "number ≥ 0 (N m s/rad)"),
    ("neg-stiffness", _set("joint", 0, "stiffness", -5.0), "joint[1].stiffness", "number ≥ 0 (N m/rad)"),
    ("neg-kv", _set("link", 0, "kelvin_voigt", -1e-3), "link[1].kelvin_voigt", "number ≥ 0 (s)"),
    ("neg-mass", _set("link", 0, "payload", "mass", -0.5), "link[1].payload.mass", "number ≥ 0 (kg)"),
    ("neg-pinertia", _set("link", 0, "payload", "inertia", -1e-3), "link[1].payload.inertia",
     "number ≥ 0 (kg m²)"),
    ("neg-pinertia-3", _set("link", 0, "payload", "inertia", [1e-3, -1e-3, 0.0]),
     "link[1].payload.inertia[2]", "number ≥ 0 (kg m²)"),
    ("str-pinertia", _set("link", 0, "payload", "inertia", "big"), "link[1].payload.inertia",
     "a number ≥ 0 or a list [Jxx, Jyy, Jzz]"),
    ("short-pinertia", _set("link", 0, "payload", "inertia", [1.0, 1.0]), "link[1].payload.inertia",
     "a list of 3 numbers ≥ 0 (kg m²)"),
    ("neg-polar", _set("link", 1, "polar_inertia", -1e-5), "link[2].polar_inertia", "number ≥ 0 (kg m)"),
    # deformation fields and their data
    ("w-without-EI_out", _del("link", 1, "EI_out"), "link[2].EI_out", 'because deformation includes "w"'),
    ("alpha-without-GJ", _del("link", 1, "GJ"), "link[2].GJ", 'because deformation includes "alpha"'),
    ("alpha-without-polar", _del("link", 1, "polar_inertia"), "link[2].polar_inertia",
     'a number ≥ 0 (kg m) because deformation includes "alpha"'),
    ("deformation-unknown", _set("link", 0, "deformation", ["v", "u"]), "link[1].deformation[2]",
     'one of "v", "w", "alpha"'),
    ("deformation-dup", _set("link", 0, "deformation", ["v", "v"]), "link[1].deformation[2]",
     "no duplicates"),
    ("deformation-str", _set("link", 0, "deformation", "v"), "link[1].deformation", "a list of distinct"),
    # shapes
    ("shape-kind", _set("link", 1, "shapes", "kind", "spline"), "link[2].shapes.kind",
     'one of "clamped-free", "polynomial", "fe", "shell", got "spline"'),
    ("shape-count-0", _set("link", 1, "shapes", "count", 0), "link[2].shapes.count",
     "an integer ≥ 1 (number of elements), got 0"),
    ("shape-count-float", _set("link", 0, "shapes", {"count": 2.5}), "link[1].shapes.count",
     "an integer ≥ 1 (number of shape functions), got 2.5"),
    ("shape-count-bool", _set("link", 0, "shapes", {"count": True}), "link[1].shapes.count", "got true"),
    # keywords with a fixed set of values
    ("kinematics", _set("link", 0, "kinematics", "third-order"), "link[1].kinematics",
     'one of "linear", "first-order", "second-order"'),
    ("drive", _set("joint", 0, "drive", "velocity"), "joint[1].drive", 'one of "torque", "position", "free"'),
    ("initial-deformation", _set("link", 0, "initial_deformation", "sagged"), "link[1].initial_deformation",
     'one of "undeformed", "static"'),
    ("integrator", _set("fmu", "integrator", "radau"), "fmu.integrator", 'one of "ss22"'),
    # joint axis
    ("axis-zero", _set("joint", 0, "axis", [0, 0, 0]), "joint[1].axis", "a non-zero finite vector"),
    ("axis-along-x", _set("joint", 0, "axis", [1, 0, 0]), "joint[1].axis", "normal to the link's x axis"),
    ("axis-oblique", _set("joint", 0, "axis", [1e-6, 0, 1]), "joint[1].axis", "normal to the link's x axis"),
    ("axis-length", _set("joint", 0, "axis", [0, 1]), "joint[1].axis", "a list of 3 numbers"),
    # chain structure
    ("count-mismatch", _pop_list("joint"), "joint, link", "as many [[joint]] as [[link]]"),
    ("duplicate-link", _set("link", 1, "name", "arm"), "link[2].name", "not already used (by link[1])"),
    ("duplicate-joint", _set("joint", 1, "name", "hub"), "joint[2].name", "not already used (by joint[1])"),
    ("duplicate-joint-link", _set("link", 0, "name", "hub"), "link[1].name",
     "not already used (by joint[1])"),
    ("name-digit", _set("link", 0, "name", "2arm"), "link[1].name", "usable in FMU variable names"),
    ("name-dash", _set("joint", 0, "name", "hub-1"), "joint[1].name", "usable in FMU variable names"),
    ("name-dot", _set("link", 0, "name", "arm.x"), "link[1].name", "usable in FMU variable names"),
    ("name-newline", _set("link", 0, "name", "arm\n"), "link[1].name", "usable in FMU variable names"),
    ("name-reserved", _set("link", 0, "name", "tip"), "link[1].name", "a name other than tip"),
    # trajectories
    ("trajectory-on-torque", _set("joint", 0, "trajectory", {"segments": [{"poly": [0.0]}]}),
     "joint[1].trajectory", 'only with drive = "position", got drive = "torque"'),
    ("trajectory-on-free", lambda d: d["joint"][1].update(drive="free"), "joint[2].trajectory",
     'only with drive = "position"'),
    ("until-decreasing", _set("joint", 1, "trajectory", "segments", 1, "until", 0.5),
     "joint[2].trajectory.segments[2].until", "strictly increasing"),
    ("until-equal", _set("joint", 1, "trajectory", "segments", 1, "until", 1.0),
     "joint[2].trajectory.segments[2].until", "strictly increasing"),
    ("inf-before-last", _set("joint", 1, "trajectory", "segments", 0, "until", INF),
     "joint[2].trajectory.segments[2].until", "strictly increasing"),
    ("segments-empty", _set("joint", 1, "trajectory", "segments", []), "joint[2].trajectory.segments",
     "non-empty list"),
    ("poly-number", _set("joint", 1, "trajectory", "segments", 0, "poly", 1.0),
     "joint[2].trajectory.segments[1].poly", "a list of numbers"),
    ("cos-pair", _set("joint", 1, "trajectory", "segments", 0, "cos", [[1.0, 2.0]]),
     "joint[2].trajectory.segments[1].cos[1]", "a list of 3 numbers"),
    # [fmu]
    ("step-zero", _set("fmu", "step", 0.0), "fmu.step", "positive number (s), got 0.0"),
    ("theta1-low", _set("fmu", "theta", [0.4, 0.5]), "fmu.theta", "0.5 ≤ Θ1 ≤ Θ2 ≤ 1"),
    ("theta2-below-theta1", _set("fmu", "theta", [0.8, 0.6]), "fmu.theta", "0.5 ≤ Θ1 ≤ Θ2 ≤ 1"),
    ("theta2-high", _set("fmu", "theta", [0.5, 1.1]), "fmu.theta", "0.5 ≤ Θ1 ≤ Θ2 ≤ 1"),
    ("theta-three", _set("fmu", "theta", [0.5, 0.5, 0.5]), "fmu.theta", "[Θ1, Θ2]"),
    ("theta-nan", _set("fmu", "theta", [0.5, NAN]), "fmu.theta[2]", "got nan"),
    ("tolerance-zero", _set("fmu", "tolerance", 0), "fmu.tolerance", "a positive number"),
    ("tunable-unknown-link", _set("fmu", "tunable", ["ghost.kelvin_voigt"]), "fmu.tunable[1]",
     "a parameter name of this scene"),
    ("tunable-typo", _set("fmu", "tunable", ["arm.kelvin_voight"]), "fmu.tunable[1]",
     'did you mean "arm.kelvin_voigt"'),
    ("tunable-joint-on-link", _set("fmu", "tunable", ["arm.stiffness"]), "fmu.tunable[1]",
     "<joint>.stiffness"),
    ("tunable-dup", _set("fmu", "tunable", ["gravity", "gravity"]), "fmu.tunable[2]", "not already listed"),
    ("tunable-str", _set("fmu", "tunable", "gravity"), "fmu.tunable", "a list of FMU parameter names"),
    ("tunable-int", _set("fmu", "tunable", [3]), "fmu.tunable[1]", "a parameter name"),
    # subnormal numbers (issue 21: EI = 5e-324 ended in LinAlgError)
    ("subnormal-EI", _set("link", 0, "EI", 5e-324), "link[1].EI", "not subnormal"),
    ("subnormal-gravity", _set("gravity", [0.0, -1e-310, 0.0]), "gravity[2]", "not subnormal"),
]


@pytest.mark.parametrize(("mutate", "key", "expected"), [c[1:] for c in BAD], ids=[c[0] for c in BAD])
def test_bad_input_is_one_clear_message(mutate, key: str, expected: str) -> None:
    one_clear_message(base(), mutate, key, expected)


def one_clear_message(data: dict, mutate, key: str, expected: str, source: str = SOURCE) -> SceneError:
    """``mutate(data)`` makes the scene fail with one SceneError: one line, naming ``key``, saying ``expected``."""
    mutate(data)
    with pytest.raises(SceneError) as info:
        parse_scene(data, source)
    msg = str(info.value)
    assert msg.startswith(f"{source}: {key}: "), msg
    assert expected in msg, msg
    assert "expected" in msg, msg
    assert "\n" not in msg
    return info.value


def test_base_scene_is_valid() -> None:
    """Guards the table above: each case must fail because of its own mutation."""
    parse_scene(base(), SOURCE)


def test_data_not_a_table() -> None:
    with pytest.raises(SceneError, match="a TOML document"):
        parse_scene([1, 2], SOURCE)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------------------- file errors


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(SceneError, match=r"nope\.toml: file not found; expected a TOML scene file"):
        load_scene(path)


def test_directory(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match="is a directory"):
        load_scene(tmp_path)


def test_toml_syntax_error_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text('name = "x"\n\n[[joint]]\nname = "j\n', encoding="utf-8")
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: TOML syntax error") and "line 4" in msg
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes('name = "bras é"\n'.encode("latin-1"))
    with pytest.raises(SceneError, match="not UTF-8"):
        load_scene(path)


def test_error_from_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "x.toml"
    text = (EXAMPLES / "rotating_link.toml").read_text(encoding="utf-8")
    text = text.replace("length = 2.2", "length = -2.2")
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value) == f"{path}: link[1].length: expected a positive number (m), got -2.2"


def test_toml_nan_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "nan.toml"
    text = (EXAMPLES / "rotating_link.toml").read_text(encoding="utf-8").replace("EI = 93.72", "EI = nan")
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SceneError, match=r"link\[1\]\.EI: expected a positive number \(N m²\), got nan"):
        load_scene(path)


# -------------------------------------------------------------------------------------------------- fuzz


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*prefix, i))


_JUNK = [None, "x", "", True, False, NAN, INF, -INF, -1.0, -1, 0, 0.0, 1e308, 10**30, [], {}, [1, 2],
         [NAN, 0, 1], {"x": 1}, [{}], ["v"], object()]


def test_fuzz_only_scene_error_escapes() -> None:
    rng = random.Random(20240601)
    for _ in range(3000):
        data = base()
        for _ in range(rng.randint(1, 3)):
            paths = [p for p in _paths(data) if p]
            path = rng.choice(paths)
            parent = data
            for p in path[:-1]:
                parent = parent[p]
            action = rng.random()
            if action < 0.2:
                del parent[path[-1]]
            elif action < 0.25 and isinstance(parent, dict):
                parent[rng.choice(["extra", "Name", "EI_Out", "lenght"])] = 1.0
            else:
                parent[path[-1]] = copy.copy(rng.choice(_JUNK))
        try:
            parse_scene(data, SOURCE)
        except SceneError as e:
            assert str(e).startswith(f"{SOURCE}: ") and "\n" not in str(e), str(e)


def test_fuzz_files_only_scene_error_escapes(tmp_path: Path) -> None:
    rng = random.Random(7)
    texts = [p.read_text(encoding="utf-8") for p in sorted(EXAMPLES.glob("*.toml"))]
    alphabet = '=[]{},."\'#\n 0123456789-+.eEinfa_zxtrue'
    path = tmp_path / "fuzz.toml"
    for _ in range(1500):
        text = list(rng.choice(texts))
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(text))
            op = rng.random()
            if op < 0.4:
                del text[i]
            elif op < 0.7:
                text[i] = rng.choice(alphabet)
            else:
                text.insert(i, rng.choice(alphabet))
        path.write_text("".join(text), encoding="utf-8")
        try:
            load_scene(path)
        except SceneError as e:
            assert str(e).startswith(f"{path}: ") and "\n" not in str(e), str(e)


# --------------------------------------------------------------------------------------------- key table


def shell() -> dict:
    """A valid box-section shell link (every shell key has a place), driven by a torque."""
    return {"name": "box", "joint": [{"name": "hub"}],
            "link": [{"name": "tube", "length": 1.0, "density": 2700.0, "E": 7e10, "poisson": 0.3,
                      "shapes": {"kind": "shell", "section": "box", "width": 0.1, "height": 0.05,
                                 "thickness": 0.002, "mesh": [4, 2, 2], "modes": 4}}]}


# Where each section of KEYS sits in base() / shell(), and how the loader names it in messages.
PLACES = {
    "scene": (base, (), ""),
    "joint": (base, ("joint", 0), "joint[1]"),
    "joint.trajectory": (base, ("joint", 1, "trajectory"), "joint[2].trajectory"),
    "joint.trajectory.segments": (base, ("joint", 1, "trajectory", "segments", 1),
                                  "joint[2].trajectory.segments[2]"),
    "link": (base, ("link", 0), "link[1]"),
    "link.shapes": (base, ("link", 0, "shapes"), "link[1].shapes"),
    "link.payload": (base, ("link", 0, "payload"), "link[1].payload"),
    "shell_link": (shell, ("link", 0), "link[1]"),
    "shell_link.shapes": (shell, ("link", 0, "shapes"), "link[1].shapes"),
    "tool": (base, ("tool",), "tool"),
    "fmu": (base, ("fmu",), "fmu"),
}
# shapes.kind = "shell" is what makes a link a shell link: another value there reads the link as a beam.
DISCRIMINATORS = {("shell_link", "shapes"), ("shell_link.shapes", "kind")}


def _table_at(section: str) -> tuple[dict, dict, str]:
    make, path, prefix = PLACES[section]
    doc = make()
    node = doc
    for p in path:
        node = node.setdefault(p, {}) if isinstance(node, dict) else node[p]
    return doc, node, prefix


def _outcome(doc: dict) -> str:
    try:
        return repr(parse_scene(doc, SOURCE))
    except SceneError as e:
        return str(e)


def test_key_table_is_well_formed() -> None:
    ids = [s.id for s in SECTIONS]
    assert len(set(ids)) == len(ids) and set(ids) == set(PLACES)
    assert len({(k.section, k.name) for k in KEYS}) == len(KEYS)
    for k in KEYS:
        assert k.section in ids and k.type and k.description, k
        if k.choices:
            given = k.default if isinstance(k.default, tuple) else (k.default,)
            assert k.default is REQUIRED or set(given) <= set(k.choices), k
        head, _, rule = k.bounds.partition(";")
        if k.type == "number" and head not in NUMBER_BOUNDS:     # checked in code: say so in words
            assert len(k.bounds) > 3, k
        if k.type == "number" and head in NUMBER_BOUNDS and rule:    # a bound the loader reads, then words
            assert head and len(rule.strip()) > 3, k
    assert all(section_keys(s) for s in ids)


@pytest.mark.parametrize("section", list(PLACES))
def test_parser_accepts_exactly_the_keys_of_the_table(section: str) -> None:
    """An unknown key is refused with the list of accepted ones: the section's keys in KEYS (a beam link also
    knows the shell-only E and poisson, to refuse them with a better message)."""
    doc, table, prefix = _table_at(section)
    table["not_a_key"] = 1.0
    known = section_keys(section) + (("E", "poisson") if section == "link" else ())
    where = f"{prefix}.not_a_key" if prefix else "not_a_key"
    with pytest.raises(SceneError) as info:
        parse_scene(doc, SOURCE)
    assert str(info.value) == f"{SOURCE}: {where}: unknown key; expected one of: {', '.join(known)}"
    del table["not_a_key"]
    parse_scene(doc, SOURCE)


@pytest.mark.parametrize("spec", [k for k in KEYS if (k.section, k.name) not in DISCRIMINATORS],
                         ids=lambda k: f"{k.section}.{k.name}")
def test_parser_reads_every_key_of_the_table(spec) -> None:
    """A value no reader takes, put at any key of the table, is refused at that key: the parser reads it."""
    doc, table, prefix = _table_at(spec.section)
    table[spec.name] = object()
    where = f"{prefix}.{spec.name}" if prefix else spec.name
    with pytest.raises(SceneError) as info:
        parse_scene(doc, SOURCE)
    assert str(info.value).startswith(f"{SOURCE}: {where}: "), str(info.value)


@pytest.mark.parametrize("spec", [k for k in KEYS if k.default not in (REQUIRED, OPTIONAL)],
                         ids=lambda k: f"{k.section}.{k.name}")
def test_absent_key_means_its_default(spec) -> None:
    doc, table, _ = _table_at(spec.section)
    table.pop(spec.name, None)
    absent = _outcome(doc)
    table[spec.name] = spec.toml_default()
    assert _outcome(doc) == absent
    assert not absent.startswith(SOURCE), absent


@pytest.mark.parametrize(("section", "cls"), [("joint", Joint), ("link", Link), ("link.shapes", Shapes),
                                              ("link.payload", Payload), ("joint.trajectory.segments", Segment),
                                              ("tool", Tool), ("fmu", FmuSettings)])
def test_data_class_defaults_agree_with_the_table(section: str, cls) -> None:
    fields = {f.name: f.default for f in dataclasses.fields(cls) if f.default is not dataclasses.MISSING}
    compared = 0
    for k in KEYS:
        if k.section == section and k.name in fields and k.type != "table" and k.default is not OPTIONAL:
            assert fields[k.name] == k.default, (section, k.name)
            compared += 1
    assert compared >= 2


def test_negative_zero_is_zero() -> None:
    """A payload mass of -0.0 (issue 21) is the number 0, with no sign bit left to leak into the model."""
    data = base()
    data["link"][0]["payload"]["mass"] = -0.0
    mass = parse_scene(data, SOURCE).links[0].payload.mass
    assert mass == 0.0 and math.copysign(1.0, mass) == 1.0
