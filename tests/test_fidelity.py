"""The fidelity ladder (``flexlink.tools.fidelity``, ``flexlink explain --error-target``), CI size.

Checked against properties that hold independently of the measured numbers: the assumed-modes series converges
as modes are added; the linear and first-order kinematic models differ only by terms quadratic in the hub rate;
the recommendation is consistent with the table it comes from; the variants are the arm the scene describes."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene, parse_scene
from flexlink.tools.bench import default_case, reference_outputs, relative_error
from flexlink.tools.fidelity import Level, deformation_levels, levels, recommend, run_ladder, variant

SCENE = "examples/rotating_link.toml"
TARGET = 1e-2


@pytest.fixture(scope="module")
def ladder():
    return run_ladder(SCENE, target=TARGET, quick=True, counts=(1, 2, 3, 4), kinematics=("linear", "second-order"))


def test_variants_are_the_same_arm_modelled_differently():
    scene = load_scene(SCENE)
    for n in (1, 2, 5):
        model = build_model(variant(scene, Level(n, "linear", ("v",))))
        assert model.n_q == 1 + n                    # the hub angle and one coordinate per clamped-free mode
        assert model.p0[model.parameter_index("arm.EI")] == scene.links[0].EI
    fe = variant(load_scene("examples/spatial_cantilever.toml"), Level(2, "second-order", ("v",)))
    assert build_model(fe).n_q == 2 * 2              # two Hermite elements (deflection, slope at two nodes); the
    #                                                  hub is held by its law, so it is not a coordinate
    assert deformation_levels(scene) == [("v",)]     # no EI_out, GJ: nothing spatial to try
    assert deformation_levels(load_scene("examples/spatial_cantilever.toml")) == [
        ("v",), ("v", "w"), ("v", "w", "alpha")]


def test_model_error_decreases_as_modes_are_added(ladder):
    rungs = sorted((r for r in ladder.rungs if r.level.kinematics == "second-order"), key=lambda r: r.level.count)
    errors = [r.model_error for r in rungs]
    assert [r.level.count for r in rungs] == [1, 2, 3, 4]
    assert rungs[-1].truth and errors[-1] == 0.0
    assert all(a > b for a, b in zip(errors[:-1], errors[1:], strict=True)), errors
    assert ladder.reference_error < 1e-3 * min(errors[:-1])     # the truth is far more accurate than any gap


def test_recommendation_is_the_cheapest_rung_meeting_the_target(ladder):
    best = recommend(ladder, TARGET)
    # the truth (model error 0) meets any target above its integration error at 1/32 of its step
    assert best is not None
    assert best.model_error < TARGET and best.error < TARGET
    costs = [r.cpu_s_per_simulated_s for r in ladder.rungs]
    assert costs == sorted(costs) and all(c > 0 for c in costs)
    for r in ladder.rungs[:ladder.rungs.index(best)]:
        assert r.model_error >= TARGET or r.error >= TARGET, r
    # the error a user sees is bounded by its two parts (triangle inequality of RMS norms; the integration error
    # is relative to the level's own RMS, at most 1 + model error times the truth's)
    for r in ladder.rungs:
        assert r.error <= (r.model_error + r.integration_error * (1 + r.model_error)) * (1 + 1e-9), r


def test_planar_motion_leaves_out_of_plane_bending_and_twist_at_rest():
    # the hub turns about z, normal to the link, with no load out of the plane: w and alpha are never excited
    # (symmetry), so the planar levels are exact against the spatial truth up to the reference's own accuracy
    data = tomllib.loads(Path(SCENE).read_text())
    data["link"][0].update({"EI_out": 50.0, "GJ": 20.0, "polar_inertia": 1e-4, "deformation": ["v", "w", "alpha"],
                            "shapes": {"kind": "clamped-free", "count": 1}})
    spatial = run_ladder(parse_scene(data), target=TARGET, quick=True, counts=(1, 2), kinematics=("second-order",))
    by_level = {(r.level.count, r.level.deformation): r for r in spatial.rungs}
    assert set(by_level) == {(n, d) for n in (1, 2) for d in (("v",), ("v", "w"), ("v", "w", "alpha"))}
    for n in (1, 2):
        full = by_level[(n, ("v", "w", "alpha"))].model_error
        for d in (("v",), ("v", "w")):
            assert abs(by_level[(n, d)].model_error - full) < 1e-6
    assert by_level[(2, ("v",))].model_error < 1e-6
    assert by_level[(2, ("v",))].coordinates == 3 and by_level[(2, ("v", "w", "alpha"))].coordinates == 7


def test_linear_and_first_order_kinematics_differ_at_second_order_in_the_hub_rate():
    # the linear model drops the terms of the first-order one that are quadratic in the rates (centrifugal
    # softening, Coriolis): halving the torque halves the rates and quarters the relative difference
    scene = load_scene(SCENE)
    diff = []
    for tau in (0.2, 0.1):
        y = {}
        for kinematics in ("linear", "first-order"):
            case = default_case(build_model(variant(scene, Level(3, kinematics, ("v",)))), stop=2.5, torque=tau)
            y[kinematics] = reference_outputs(case, 1e-10)
        diff.append(relative_error(case, y["linear"], y["first-order"]))
    assert diff[0] > 0
    assert diff[0] / diff[1] == pytest.approx(4.0, rel=0.1), diff


def test_cli_json_fields():
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "explain", SCENE, "--error-target", "1e-2",
                          "--quick", "--json"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert info["coordinates"] == ["hub.theta", "arm.eta[1]", "arm.eta[2]", "arm.eta[3]"]   # explain as before
    fid = info["fidelity"]
    assert set(fid) == {"error_target", "outputs", "stop_time", "reference_error", "ladder", "recommendation",
                        "checks", "notes"}
    assert fid["error_target"] == 1e-2 and fid["outputs"] == ["hub.theta", "arm.tip.v"]
    fields = {"level", "count", "kinematics", "deformation", "coordinates", "highest_hz", "step", "model_error",
              "integration_error", "error", "cpu_s_per_simulated_s", "truth", "scene_level"}
    assert all(set(r) == fields for r in fid["ladder"])
    assert {(r["count"], r["kinematics"]) for r in fid["ladder"]} == {
        (n, k) for n in (1, 2, 3) for k in ("linear", "first-order", "second-order")}
    assert sum(r["truth"] for r in fid["ladder"]) == 1 and sum(r["scene_level"] for r in fid["ladder"]) == 1
    best = fid["recommendation"]
    if best is not None:
        check = best.pop("check")
        assert best.pop("checked_error") == check["error"] < 1e-2 and check["passed"]
        assert check["level"] == best["level"]
        assert best in fid["ladder"] and best["error"] < 1e-2 and best["model_error"] < 1e-2
        assert fid["checks"][-1] == check and not any(c["passed"] for c in fid["checks"][:-1])
    assert all(np.isfinite(r["error"]) and math.isfinite(r["cpu_s_per_simulated_s"]) for r in fid["ladder"])


def test_cli_without_error_target_is_unchanged():
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "explain", SCENE, "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "fidelity" not in json.loads(out.stdout)


@pytest.mark.parametrize("value", ["-1e-3", "0", "nan", "inf", "abc"])
def test_cli_bad_error_target(value):
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "explain", SCENE, f"--error-target={value}"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "--error-target" in lines[0] and "positive" in lines[0], out.stderr
    assert out.stdout == ""


def test_reduced_links_climb_the_ladder_in_modes():
    """A shell (or a reduced FE beam) is varied in its number of modes, not its mesh, and a shell has no
    second-order level: the truth is first-order with the most modes."""
    scene = load_scene("examples/plate_raise.toml")
    ladder = levels(scene, quick=True)
    assert {lv.kinematics for lv in ladder} == {"linear", "first-order"}
    assert max(lv.count for lv in ladder) == scene.links[0].shapes.modes
    for lv in ladder:
        assert build_model(variant(scene, lv)).n_q == lv.count


def test_the_checked_error_is_measured_directly(ladder):
    """The recommended level's check: its FMU run here through fmpy (another path than the check's) at its
    SS22 step over the second manoeuvre (+τ 0.7 s, −τ 0.7 s, free), against the truth's equations integrated
    here by CVODES; the relative RMS error of each output, computed here, is the one the check reports."""
    from flexlink.mechanics.reference import simulate_reference
    from flexlink.run.simulate import simulate
    from flexlink.tools.fidelity import check_level, variant_fmu

    scene = load_scene(SCENE)
    best = recommend(ladder, TARGET)
    check = check_level(scene, best, ladder.truth.level, ladder.stop_time, TARGET)
    times = np.round(np.arange(int(round(ladder.stop_time / 0.01)) + 1) * 0.01, 12)
    pieces = [(0.0, {"hub.tau": 0.2}), (0.7, {"hub.tau": -0.2}), (1.4, {"hub.tau": 0.0})]
    truth = build_model(variant(scene, ladder.truth.level))
    ref = simulate_reference(truth, times, inputs=pieces, rtol=1e-10, atol=1e-13)
    table = np.array([(0.0, 0.2), (0.7, 0.2), (0.7, -0.2), (1.4, -0.2), (1.4, 0.0), (ladder.stop_time, 0.0)],
                     dtype=[("time", float), ("hub.tau", float)])
    fmu = variant_fmu(variant(scene, best.level))
    y = simulate(fmu, ladder.stop_time, step=0.01, inputs=table, start_values={"solver.step": best.step},
                 outputs=["hub.theta", "arm.tip.v"])
    _, last = np.unique(y["time"][::-1], return_index=True)         # fmpy repeats the samples at input jumps
    y = y[len(y) - 1 - last]
    assert np.allclose(y["time"], times)
    for name in ("hub.theta", "arm.tip.v"):
        r = ref.output(truth, name)
        measured = np.sqrt(np.mean((y[name] - r) ** 2)) / np.sqrt(np.mean(r ** 2))
        assert check.errors[name] == pytest.approx(measured, rel=1e-3), name
    assert check.error == max(check.errors.values()) and check.passed == (check.error < TARGET)
    assert check.manoeuvre.startswith("hub.tau = 0.2 for 0.7 s")


def test_a_candidate_whose_direct_check_fails_is_not_recommended():
    """The cheapest candidate whose check passes is recommended; a failing one is passed over (and reported);
    none passing gives no recommendation; at most MAX_CHECKS candidates are run."""
    from flexlink.tools.fidelity import MAX_CHECKS, Check, checked_recommendation

    rungs = [f"level {k}" for k in range(5)]
    verdicts = {"level 0": False, "level 1": True}
    calls = []

    def check(rung):
        calls.append(rung)
        ok = verdicts.get(rung, False)
        return Check(rung, "m", {"y": 0.5 if ok else 2.0}, 0.5 if ok else 2.0, ok)

    best, checks = checked_recommendation(rungs, check)
    assert best == "level 1" and [c.passed for c in checks] == [False, True] and calls == rungs[:2]
    verdicts.clear()
    calls.clear()
    best, checks = checked_recommendation(rungs, check)
    assert best is None and len(checks) == MAX_CHECKS == len(calls)
