"""flexlink.scene for real robots (issue 15, loader side): rigid links (a uniform rod or a body), joint frames
placed by origin and rpy, a joint axis free for a rigid link, a [tool] frame; each mistake one SceneError."""

from __future__ import annotations

import copy
import dataclasses
import math
import random
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_scene import _del, _paths, _set, one_clear_message

from flexlink import cli
from flexlink.errors import SceneError
from flexlink.scene.loader import Tool, load_scene, parse_scene
from flexlink.scene.schema import KEYS, Shapes, rpy_rotation, section_keys

ROOT = Path(__file__).resolve().parents[1]
# The scenes that existed before rigid links, joint placements and [tool] (newer examples use them).
SCENES_BEFORE = [ROOT / "examples" / f"{n}.toml" for n in (
    "aluminium_arm_payload", "aluminium_arm_smooth", "elastic_joint", "fast_two_link", "flexible_pendulum",
    "plate_raise", "rotating_link", "rotating_link_linear", "rotating_link_payload", "spatial_cantilever",
    "steel_beam_gravity", "steel_beam_raise", "steel_beam_two_links")] + [
    ROOT / "benchmarks" / f"{n}.toml" for n in (
        "hard_cases/fast_heavy_gravity", "hard_cases/fast_spatial_arm", "hard_cases/heavy_payload",
        "hard_cases/many_modes", "hard_cases/massless_motor", "hard_cases/quasi_static_twist",
        "scenes/fe40_second_order")]
SOURCE = "scenes/robot.toml"
PI = math.pi


def robot() -> dict:
    """A six-axis arm: a rigid column (a body), flexible upper arm and forearm, a spherical wrist of two
    zero-length rigid links and a rigid flange (a rod), a tool frame."""
    return {
        "name": "six_axis",
        "gravity": [0.0, 0.0, -9.81],
        "joint": [
            {"name": "base", "axis": [0.0, 0.0, 1.0]},
            {"name": "shoulder", "origin": [0.0, 0.0, 0.1], "rpy": [PI / 2, 0.0, 0.0]},
            {"name": "elbow", "axis": [0.0, 1.0, 0.0]},
            {"name": "wrist1", "axis": [1.0, 0.0, 0.0]},
            {"name": "wrist2", "axis": [0.0, 1.0, 0.0], "rpy": [0.0, 0.0, 0.3]},
            {"name": "wrist3", "axis": [1.0, 0.0, 0.0]},
        ],
        "link": [
            {"name": "column", "length": 0.4, "deformation": [], "mass": 12.0,
             "center_of_mass": [0.2, 0.0, 0.01], "inertia": [0.05, 0.2, 0.2]},
            {"name": "upper", "length": 0.6, "linear_density": 3.0, "EI": 2e3, "EI_out": 2e3, "GJ": 1e3,
             "polar_inertia": 1e-3, "deformation": ["v", "w", "alpha"], "kinematics": "second-order"},
            {"name": "forearm", "length": 0.5, "linear_density": 2.0, "EI": 1e3, "kinematics": "first-order"},
            {"name": "wrist_a", "length": 0.0, "deformation": [], "mass": 0.0, "inertia": [1e-4, 1e-4, 1e-4]},
            {"name": "wrist_b", "length": 0.0, "deformation": [], "linear_density": 1.0},
            {"name": "flange", "length": 0.08, "deformation": [], "density": 2700.0, "area": 1e-3,
             "polar_inertia": 2e-5, "payload": {"mass": 1.5, "offset": [0.02, 0.0, 0.0]},
             "initial_deformation": "undeformed"},
        ],
        "tool": {"origin": [0.0, 0.0, 0.05], "rpy": [0.0, PI / 2, 0.0]},
        "fmu": {"tunable": ["flange.payload.mass", "upper.kelvin_voigt"]},
    }


# ----------------------------------------------------------------------------------------- values in SI


def test_robot_loads_with_its_values() -> None:
    s = parse_scene(robot(), SOURCE)
    base, shoulder, _elbow, wrist1, wrist2, _wrist3 = s.joints
    column, upper, forearm, wrist_a, wrist_b, flange = s.links
    assert [link.is_rigid for link in s.links] == [True, False, False, True, True, True]
    assert shoulder.origin == (0.0, 0.0, 0.1) and shoulder.rpy == (PI / 2, 0.0, 0.0)
    assert base.origin == (0.0, 0.0, 0.0) and base.rpy == (0.0, 0.0, 0.0)
    assert wrist2.rpy == (0.0, 0.0, 0.3)
    assert all(isinstance(c, float) for j in s.joints for c in (*j.origin, *j.rpy, *j.axis))
    assert wrist1.axis == (1.0, 0.0, 0.0)                       # a rigid link turns about its x axis
    assert (upper.kinematics, forearm.kinematics) == ("second-order", "first-order")   # per link
    assert column.deformation == () and column.EI is None
    assert (column.mass, column.center_of_mass, column.inertia) == (12.0, (0.2, 0.0, 0.01),
                                                                   (0.05, 0.2, 0.2, 0.0, 0.0, 0.0))
    assert (wrist_a.length, wrist_a.mass, wrist_a.center_of_mass) == (0.0, 0.0, (0.0, 0.0, 0.0))
    assert (wrist_b.length, wrist_b.linear_density, wrist_b.mass, wrist_b.inertia) == (0.0, 1.0, None, None)
    assert flange.linear_density == pytest.approx(2.7) and flange.polar_inertia == 2e-5
    assert flange.payload.mass == 1.5 and flange.initial_deformation == "undeformed"
    assert s.tool == Tool((0.0, 0.0, 0.05), (0.0, PI / 2, 0.0))
    assert s.fmu.tunable == ("flange.payload.mass", "upper.kelvin_voigt")


def test_values_are_si_floats_from_integers() -> None:
    d = robot()
    d["joint"][1].update(origin=[0, 0, 1], rpy=[0, 1, 0])
    d["link"][0].update(mass=3, center_of_mass=[1, 0, 0], inertia=[3, 2, 2, 0, 0, 1])
    d["tool"] = {"origin": [1, 2, 3]}
    s = parse_scene(d, SOURCE)
    values = (*s.joints[1].origin, *s.joints[1].rpy, s.links[0].mass, *s.links[0].center_of_mass,
              *s.links[0].inertia, *s.tool.origin, *s.tool.rpy)
    assert all(type(v) is float for v in values)
    assert s.links[0].inertia == (3.0, 2.0, 2.0, 0.0, 0.0, 1.0)
    assert s.tool == Tool((1.0, 2.0, 3.0), (0.0, 0.0, 0.0))


def test_rigid_axis_is_normalised_with_all_its_components() -> None:
    d = robot()
    d["joint"][3]["axis"] = [1.0, -2.0, 2.0]
    assert parse_scene(d, SOURCE).joints[3].axis == pytest.approx((1 / 3, -2 / 3, 2 / 3), abs=1e-16)


def test_flexible_axis_keeps_the_rule_and_x_exactly_zero() -> None:
    d = robot()
    d["joint"][2]["axis"] = [1e-12, 0.0, 2.0]                  # within the tolerance: x set to 0
    assert parse_scene(d, SOURCE).joints[2].axis == (0.0, 0.0, 1.0)


def test_body_form_defaults_centre_and_inertia_to_zero() -> None:
    d = robot()
    d["link"][0] = {"name": "column", "length": 0.4, "deformation": [], "mass": 2.0}
    link = parse_scene(d, SOURCE).links[0]
    assert (link.mass, link.center_of_mass, link.inertia) == (2.0, (0.0, 0.0, 0.0), (0.0,) * 6)
    assert link.linear_density == 0.0 and link.polar_inertia is None


def test_rigid_link_may_be_the_first_or_every_link() -> None:
    d = robot()
    for link in d["link"][1:3]:
        for k in ("EI", "EI_out", "GJ", "kinematics"):
            link.pop(k, None)
        link.update(deformation=[], polar_inertia=1e-3)
    d["fmu"]["tunable"] = []
    assert all(link.is_rigid for link in parse_scene(d, SOURCE).links)


def test_rigid_tunable_payload_but_not_kelvin_voigt() -> None:
    d = robot()
    d["fmu"]["tunable"] = ["column.payload.mass", "wrist_a.payload.inertia"]
    assert parse_scene(d, SOURCE).fmu.tunable == ("column.payload.mass", "wrist_a.payload.inertia")


@pytest.mark.parametrize("inertia", [[0, 0, 0], [0, 1, 1], [1, 1, 2], [1, 1, 2 * (1 + 1e-13)], [2, 1, 1],
                                     [1, 1.25, 1.25, 0, 0, 0.25], [1, 1, 1, 0.5, 0, 0]],
                         ids=["point", "rod", "disk", "disk-rounding", "disk-x", "rotated", "products"])
# "rotated": diag [1, 1, 1.5] turned 45° about x
def test_physical_limits_are_accepted(inertia) -> None:
    d = robot()
    d["link"][0]["inertia"] = inertia
    parse_scene(d, SOURCE)


def test_pure_rotor_mass_zero_inertia_non_zero() -> None:
    d = robot()
    d["link"][0].update(mass=0.0, inertia=[0.1, 0.1, 0.2])
    assert parse_scene(d, SOURCE).links[0].rigid_body()[0] == 0.0


# -------------------------------------------------------------------------------------------- rigid_body


def test_rigid_body_of_a_rod_is_the_analytic_rod() -> None:
    rho, length, mu = 2.0, 0.9, 3e-3
    d = robot()
    d["link"][4].update(length=length, linear_density=rho, polar_inertia=mu)
    m, c, inertia = parse_scene(d, SOURCE).links[4].rigid_body()
    assert m == pytest.approx(rho * length, rel=1e-15)
    np.testing.assert_allclose(c, [length / 2, 0.0, 0.0], rtol=1e-15)
    np.testing.assert_allclose(inertia, np.diag([mu * length, rho * length**3 / 12, rho * length**3 / 12]),
                               rtol=1e-15, atol=0)
    # without polar_inertia: no inertia about the rod's axis
    d["link"][4].pop("polar_inertia")
    _, _, inertia = parse_scene(d, SOURCE).links[4].rigid_body()
    assert inertia[0, 0] == 0.0 and inertia[1, 1] == pytest.approx(rho * length**3 / 12, rel=1e-15)
    # density·area is the mass per length; a zero-length rod is a point without mass
    m, c, inertia = parse_scene(robot(), SOURCE).links[5].rigid_body()
    rho_f, length_f = 2700.0 * 1e-3, 0.08
    assert m == pytest.approx(rho_f * length_f, rel=1e-14) and c.tolist() == [length_f / 2, 0.0, 0.0]
    np.testing.assert_allclose(np.diag(inertia), [2e-5 * length_f, rho_f * length_f**3 / 12,
                                                  rho_f * length_f**3 / 12], rtol=1e-14)
    m, c, inertia = parse_scene(robot(), SOURCE).links[4].rigid_body()
    assert m == 0.0 and not c.any() and not inertia.any()


def test_rigid_body_full_tensor_is_the_hand_computed_one() -> None:
    """Point masses: I = Σ m (|r|² 1 − r rᵀ) about their centre, the products Ixy = −Σ m x y (URDF) given as
    [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]; rigid_body() returns that tensor, its mass and centre."""
    rng = np.random.default_rng(15)
    masses = rng.uniform(0.1, 2.0, 7)
    points = rng.normal(size=(7, 3)) * [0.3, 0.1, 0.05]
    mass = masses.sum()
    centre = masses @ points / mass
    r = points - centre
    tensor = sum(m * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for m, ri in zip(masses, r, strict=True))
    x, y, z = r.T
    six = [float(v) for v in (masses @ (y**2 + z**2), masses @ (x**2 + z**2), masses @ (x**2 + y**2),
                              -masses @ (x * y), -masses @ (x * z), -masses @ (y * z))]
    d = robot()
    d["link"][0].update(mass=float(mass), center_of_mass=[float(c) for c in centre], inertia=six)
    m, c, inertia = parse_scene(d, SOURCE).links[0].rigid_body()
    assert m == float(mass)
    np.testing.assert_array_equal(c, centre)
    np.testing.assert_allclose(inertia, tensor, rtol=1e-13, atol=1e-16)
    assert inertia[0, 1] == six[3] and inertia[1, 0] == six[3] and inertia[1, 2] == six[5]


def test_rigid_body_hand_example() -> None:
    d = robot()
    d["link"][0].update(mass=2.0, center_of_mass=[0.1, -0.2, 0.3], inertia=[2.0, 3.0, 4.0, 0.1, -0.2, 0.3])
    m, c, inertia = parse_scene(d, SOURCE).links[0].rigid_body()
    assert m == 2.0 and c.tolist() == [0.1, -0.2, 0.3]
    assert inertia.tolist() == [[2.0, 0.1, -0.2], [0.1, 3.0, 0.3], [-0.2, 0.3, 4.0]]


def test_rigid_body_of_a_flexible_link_is_a_value_error() -> None:
    with pytest.raises(ValueError, match='link "upper" is flexible'):
        parse_scene(robot(), SOURCE).links[1].rigid_body()


def test_rigid_body_built_by_hand_without_its_inertia_is_a_value_error() -> None:
    """A Link made in code (not by the loader) with a mass but no inertia is refused in words, not by a
    TypeError from unpacking None (found by mypy)."""
    link = dataclasses.replace(parse_scene(robot(), SOURCE).links[0], mass=2.0, center_of_mass=(0.1, 0.0, 0.0),
                               inertia=None)
    with pytest.raises(ValueError, match="needs center_of_mass and inertia"):
        link.rigid_body()


def test_section_area_of_a_beam_basis_is_a_value_error() -> None:
    """A beam basis has no shell section: asked for its area it says so, not TypeError on None (found by mypy);
    a box's area is its mid-surface perimeter times the thickness."""
    with pytest.raises(ValueError, match='section_area is for a shell basis .*not "clamped-free"'):
        _ = Shapes().section_area
    box = Shapes(kind="shell", section="box", width=0.04, height=0.02, thickness=0.002)
    assert box.section_area == pytest.approx(2 * (0.04 + 0.02) * 0.002, rel=1e-15)
    assert dataclasses.replace(box, section="plate").section_area == pytest.approx(0.04 * 0.002, rel=1e-15)


# ------------------------------------------------------------------------------------------------- rpy


def test_rpy_rotation_is_scipy_extrinsic_xyz() -> None:
    rng = random.Random(15)
    for _ in range(200):
        rpy = (rng.uniform(-PI, PI), rng.uniform(-PI / 2, PI / 2), rng.uniform(-PI, PI))
        np.testing.assert_allclose(rpy_rotation(rpy), Rotation.from_euler("xyz", rpy).as_matrix(),
                                   rtol=0, atol=1e-15)


def test_joint_and_tool_placement_rotations() -> None:
    d = robot()
    d["joint"][0]["rpy"] = [0.3, -0.7, 1.9]
    d["tool"]["rpy"] = [0.3, -0.7, 1.9]
    s = parse_scene(d, SOURCE)
    ref = Rotation.from_euler("xyz", [0.3, -0.7, 1.9]).as_matrix()
    np.testing.assert_allclose(s.joints[0].placement_rotation(), ref, atol=1e-15)
    np.testing.assert_array_equal(s.tool.placement_rotation(), s.joints[0].placement_rotation())
    # yaw π/2 turns x onto y; roll π/2 turns y onto z (columns: the placed frame's axes in the parent)
    np.testing.assert_allclose(rpy_rotation((0.0, 0.0, PI / 2)) @ [1, 0, 0], [0, 1, 0], atol=1e-16)
    np.testing.assert_allclose(rpy_rotation((PI / 2, 0.0, 0.0)) @ [0, 1, 0], [0, 0, 1], atol=1e-16)
    np.testing.assert_array_equal(parse_scene(robot(), SOURCE).joints[0].placement_rotation(), np.eye(3))
    assert Tool().placement_rotation().tolist() == np.eye(3).tolist()


# ------------------------------------------------------------------------------------------- bad input


NOT_USED = "not used by a rigid link (deformation = []); remove it"
ONLY_RIGID = "only for a rigid link (deformation = [])"
AXIS = ("expected a vector normal to the link's x axis [1, 0, 0] (x component 0) — link \"forearm\" is "
        "flexible; a rigid link turns about any axis, or orient the joint frame with rpy, got [1, 0, 0]")
NAN, INF = math.nan, math.inf
BAD = [
    # joint frames
    ("origin-short", _set("joint", 1, "origin", [0.0, 0.1]), "joint[2].origin", "a list of 3 numbers (m)"),
    ("origin-nan", _set("joint", 1, "origin", [0.0, 0.0, NAN]), "joint[2].origin[3]", "finite number (m), got nan"),
    ("origin-str", _set("joint", 0, "origin", "up"), "joint[1].origin", "a list of 3 numbers (m)"),
    ("rpy-inf", _set("joint", 1, "rpy", [INF, 0, 0]), "joint[2].rpy[1]", "finite number (rad), got inf"),
    ("rpy-table", _set("joint", 1, "rpy", {"roll": 1.0}), "joint[2].rpy", "a list of 3 numbers (rad)"),
    ("rpy-typo", _set("joint", 1, "rpy_", [0, 0, 0]), "joint[2].rpy_", 'did you mean "rpy"'),
    ("rpy-subnormal", _set("joint", 1, "rpy", [0, 1e-310, 0]), "joint[2].rpy[2]", "not subnormal"),
    # the axis rule (checks.joint_axes)
    ("axis-flexible", _set("joint", 2, "axis", [1, 0, 0]), "joint[3].axis", AXIS),
    ("axis-flexible-oblique", _set("joint", 1, "axis", [1e-6, 0, 1]), "joint[2].axis", 'link "upper" is flexible'),
    ("axis-rigid-zero", _set("joint", 3, "axis", [0, 0, 0]), "joint[4].axis", "a non-zero finite vector"),
    # [tool]
    ("tool-number", _set("tool", 1.0), "tool", "a [tool] table"),
    ("tool-typo", _set("tool", "orign", [0, 0, 0]), "tool.orign", 'did you mean "origin"'),
    ("tool-origin-short", _set("tool", "origin", [0.0]), "tool.origin", "a list of 3 numbers (m)"),
    ("tool-rpy-nan", _set("tool", "rpy", [0.0, NAN, 0.0]), "tool.rpy[2]", "finite number (rad), got nan"),
    # keys a rigid link does not use
    ("rigid-EI", _set("link", 0, "EI", 1e3), "link[1].EI", NOT_USED),
    ("rigid-EI_out", _set("link", 3, "EI_out", 1e3), "link[4].EI_out", NOT_USED),
    ("rigid-GJ", _set("link", 4, "GJ", 1e3), "link[5].GJ", NOT_USED),
    ("rigid-kv", _set("link", 5, "kelvin_voigt", 0.0), "link[6].kelvin_voigt", NOT_USED),
    ("rigid-shapes", _set("link", 0, "shapes", {}), "link[1].shapes", NOT_USED),
    ("rigid-kinematics", _set("link", 0, "kinematics", "linear"), "link[1].kinematics", NOT_USED),
    ("rigid-static", _set("link", 5, "initial_deformation", "static"), "link[6].initial_deformation", NOT_USED),
    ("rigid-initial-bad", _set("link", 5, "initial_deformation", "bent"), "link[6].initial_deformation",
     'one of "undeformed", "static"'),
    ("rigid-E", _set("link", 0, "E", 7e10), "link[1].E", "E and poisson are for shell links"),
    # keys only a rigid link uses
    ("flexible-mass", _set("link", 1, "mass", 2.0), "link[2].mass", ONLY_RIGID),
    ("flexible-com", _set("link", 2, "center_of_mass", [0, 0, 0]), "link[3].center_of_mass", ONLY_RIGID),
    ("flexible-inertia", _set("link", 2, "inertia", [1, 1, 1]), "link[3].inertia", ONLY_RIGID),
    ("flexible-no-EI", _del("link", 2, "EI"), "link[3].EI", "missing; expected a positive number (N m²), "
     "required for a flexible link"),
    ("flexible-zero-length", _set("link", 2, "length", 0.0), "link[3].length", "a positive number (m), got 0.0"),
    # the two forms of a rigid link's mass
    ("rigid-both-forms", _set("link", 0, "linear_density", 3.0), "link[1].mass", "not both"),
    ("rigid-both-forms-area", _set("link", 3, "area", 1e-3), "link[4].mass", "not both"),
    ("rigid-both-forms-inertia", _set("link", 5, "inertia", [1, 1, 1]), "link[6].inertia", "not both"),
    ("rigid-no-mass", lambda d: d["link"][4].pop("linear_density"), "link[5].mass",
     "missing; expected a number ≥ 0 (kg), with center_of_mass and inertia, or linear_density"),
    ("rigid-inertia-without-mass", _del("link", 0, "mass"), "link[1].mass", "because center_of_mass is given"),
    ("rigid-neg-mass", _set("link", 0, "mass", -1.0), "link[1].mass", "a number ≥ 0 (kg), got -1.0"),
    ("rigid-bool-mass", _set("link", 0, "mass", True), "link[1].mass", "got true"),
    ("rigid-neg-length", _set("link", 3, "length", -0.1), "link[4].length", "a number ≥ 0 (m), got -0.1"),
    ("rigid-zero-density", _set("link", 4, "linear_density", 0.0), "link[5].linear_density",
     "a positive number (kg/m)"),
    ("rigid-polar-with-body", _set("link", 0, "polar_inertia", 1e-3), "link[1].polar_inertia",
     "a rigid body given by mass takes inertia"),
    ("rigid-neg-polar", _set("link", 4, "polar_inertia", -1.0), "link[5].polar_inertia", "a number ≥ 0 (kg m)"),
    ("rigid-com-short", _set("link", 0, "center_of_mass", [0.2, 0.0]), "link[1].center_of_mass",
     "a list of 3 numbers (m)"),
    ("rigid-com-inf", _set("link", 0, "center_of_mass", [0.2, 0.0, -INF]), "link[1].center_of_mass[3]",
     "got -inf"),
    # the inertia tensor
    ("inertia-4", _set("link", 0, "inertia", [1, 1, 1, 0]), "link[1].inertia",
     "[Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (kg m²)"),
    ("inertia-number", _set("link", 0, "inertia", 0.1), "link[1].inertia", "[Ixx, Iyy, Izz] or"),
    ("inertia-neg-moment", _set("link", 0, "inertia", [0.1, -0.2, 0.2]), "link[1].inertia[2]",
     "a number ≥ 0 (kg m²), got -0.2"),
    ("inertia-nan-product", _set("link", 0, "inertia", [1, 1, 1, 0, NAN, 0]), "link[1].inertia[5]", "got nan"),
    ("inertia-triangle", _set("link", 0, "inertia", [0.05, 0.2, 0.1]), "link[1].inertia", "Iyy ≤ Ixx + Izz"),
    ("inertia-triangle-tolerance", _set("link", 0, "inertia", [1, 1, 2 * (1 + 1e-9)]), "link[1].inertia",
     "Izz ≤ Ixx + Iyy"),
    ("inertia-not-psd", _set("link", 0, "inertia", [1, 1, 1, 0, 0, 2]), "link[1].inertia",
     "a positive semi-definite inertia tensor (principal moments -1, 1, 3 kg m²)"),
    # diag [1, 1, 2.5] turned 45° about x: each diagonal entry passes, the principal moments do not
    ("inertia-principal-triangle", _set("link", 0, "inertia", [1, 1.75, 1.75, 0, 0, 0.75]), "link[1].inertia",
     "its principal moments (here"),
    ("inertia-huge-product", _set("link", 0, "inertia", [1, 1, 1, 0, 0, 1e308]), "link[1].inertia",
     "positive semi-definite"),
    ("rigid-deformation-str", _set("link", 0, "deformation", "none"), "link[1].mass", ONLY_RIGID),
    # [fmu] tunable
    ("tunable-rigid-kv", _set("fmu", "tunable", ["column.kelvin_voigt"]), "fmu.tunable[1]",
     "a parameter name of this scene"),
]


@pytest.mark.parametrize(("mutate", "key", "expected"), [c[1:] for c in BAD], ids=[c[0] for c in BAD])
def test_bad_input_is_one_clear_message(mutate, key: str, expected: str) -> None:
    assert one_clear_message(robot(), mutate, key, expected, SOURCE).__cause__ is None


def test_robot_scene_is_valid() -> None:
    """Guards the table above: each case must fail because of its own mutation."""
    parse_scene(robot(), SOURCE)


def test_axis_message_exactly() -> None:
    data = robot()
    data["joint"][2]["axis"] = [1, 0, 0]
    with pytest.raises(SceneError) as info:
        parse_scene(data, SOURCE)
    assert str(info.value) == f"{SOURCE}: joint[3].axis: {AXIS}"


def test_shell_link_keeps_the_axis_rule() -> None:
    d = robot()
    d["link"][2] = {"name": "forearm", "length": 0.5, "density": 2700.0, "E": 7e10, "poisson": 0.3,
                    "shapes": {"kind": "shell", "section": "plate", "width": 0.05, "thickness": 0.002,
                               "mesh": [4, 2]}}
    parse_scene(d, SOURCE)
    d["joint"][2]["axis"] = [1, 0, 0]
    with pytest.raises(SceneError, match=r"joint\[3\]\.axis: .*link \"forearm\" is flexible"):
        parse_scene(d, SOURCE)


def test_bad_rigid_file_is_one_line_from_the_cli(tmp_path: Path, capsys) -> None:
    path = tmp_path / "bad_rigid.toml"
    path.write_text('name = "r"\n[[joint]]\nname = "j"\n[[link]]\nname = "l"\nlength = 0.3\ndeformation = []\n'
                    "mass = 1.0\nEI = 5.0\n", encoding="utf-8")
    assert cli.main(["modes", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == f"flexlink: error: {path}: link[1].EI: expected no value: {NOT_USED}, got 5.0\n"


# --------------------------------------------------------------------------------- the key table, rigid


def _rigid_table_for(name: str) -> dict:
    """A rigid link in the form in which ``name`` means something: a rod for its mass per length, else a body."""
    if name in ("linear_density", "polar_inertia"):
        return {"name": "rod", "length": 0.3, "deformation": [], "linear_density": 1.0}
    if name in ("density", "area"):
        return {"name": "rod", "length": 0.3, "deformation": [], "density": 1.0, "area": 1.0}
    return {"name": "body", "length": 0.3, "deformation": [], "mass": 1.0}


@pytest.mark.parametrize("name", [n for n in section_keys("link") if n != "deformation"])
def test_rigid_link_reads_or_refuses_every_link_key(name: str) -> None:
    """A value no reader takes, at any key of [[link]] in a rigid link, is refused at that key."""
    d = robot()
    d["link"][3] = _rigid_table_for(name)
    parse_scene(d, SOURCE)
    d["link"][3][name] = object()
    with pytest.raises(SceneError) as info:
        parse_scene(d, SOURCE)
    assert str(info.value).startswith(f"{SOURCE}: link[4].{name}: "), str(info.value)


def test_rigid_link_accepts_the_keys_of_the_link_section() -> None:
    d = robot()
    d["link"][0]["not_a_key"] = 1.0
    known = (*section_keys("link"), "E", "poisson")
    with pytest.raises(SceneError) as info:
        parse_scene(d, SOURCE)
    assert str(info.value) == f"{SOURCE}: link[1].not_a_key: unknown key; expected one of: {', '.join(known)}"


def test_new_rows_of_the_key_table() -> None:
    rows = {(k.section, k.name): k for k in KEYS}
    for section, name, unit in [("joint", "origin", "m"), ("joint", "rpy", "rad"), ("tool", "origin", "m"),
                                ("tool", "rpy", "rad"), ("link", "mass", "kg"), ("link", "center_of_mass", "m"),
                                ("link", "inertia", "kg m²")]:
        assert rows[(section, name)].unit == unit
    assert "required for a flexible link" in rows[("link", "EI")].bounds
    assert "rigid" in rows[("link", "length")].bounds and "rigid" in rows[("joint", "axis")].bounds
    assert section_keys("tool") == ("origin", "rpy") and "tool" in section_keys("scene")


# ----------------------------------------------------------------------------------- existing scenes


@pytest.mark.parametrize("path", SCENES_BEFORE, ids=lambda p: str(p.relative_to(ROOT)))
def test_existing_scenes_keep_their_meaning(path: Path) -> None:
    """No existing scene has a rigid link, a placed joint frame or a tool: every joint frame sits at its parent's
    tip, axes normal to x as before, the tool at the last tip."""
    s = load_scene(path)
    assert s.tool == Tool()
    for joint, link in zip(s.joints, s.links, strict=True):
        assert joint.origin == (0.0, 0.0, 0.0) and joint.rpy == (0.0, 0.0, 0.0)
        assert joint.axis[0] == 0.0 and not link.is_rigid
        assert (link.mass, link.center_of_mass, link.inertia) == (None, None, None)


# ----------------------------------------------------------------------------------------------- fuzz


_JUNK = [None, "x", "", True, NAN, INF, -1.0, 0, 0.0, 1e308, [], {}, [1, 2], [1, 2, 3], [1, 1, 1, 0, 0, 5],
         [0, 0, 0], [NAN, 0, 1], {"x": 1}, ["v"], "static", object()]


def test_fuzz_only_scene_error_escapes() -> None:
    rng = random.Random(15)
    for _ in range(2000):
        data = robot()
        for _ in range(rng.randint(1, 3)):
            path = rng.choice([p for p in _paths(data) if p])
            parent = data
            for p in path[:-1]:
                parent = parent[p]
            action = rng.random()
            if action < 0.2:
                del parent[path[-1]]
            elif action < 0.3 and isinstance(parent, dict):
                parent[rng.choice(["mass", "inertia", "center_of_mass", "EI", "origin", "rpy", "tool"])] = \
                    copy.copy(rng.choice(_JUNK))
            else:
                parent[path[-1]] = copy.copy(rng.choice(_JUNK))
        try:
            parse_scene(data, SOURCE)
        except SceneError as e:
            assert str(e).startswith(f"{SOURCE}: ") and "\n" not in str(e), str(e)
