"""The margins of a scheduled LQG along its path (``controllers.schedule.along_path``, issue 16) on
examples/two_link_payload.toml: shoulder 0 → 60°, elbow −20° → 90° in 1.5 s, three design points, the laws
frozen at nine poses (the design points and three between each two).

* the reported worst case is the worst of the points, at the σ it names;
* at the scheduled law's worst pose the margins at each actuator are python-control's own
  (``sample_system``, ``feedback``, ``stability_margins``) on the loop built here, with the plant linearised
  from a scene *built* with the joints' ``initial_angle`` at that pose; where the report says the fixed law
  is unstable, python-control's closed-loop poles say so too;
* through the FMU, started at that pose (its ``initial_angle`` parameters) and held there by the law frozen
  at that σ after a small torque pulse: the loop dies out at the nominal gain and at 0.95 × the critical
  gain 10^(GM/20) of the reported worst gain margin, and grows at 1.05 × it; the fixed law, reported
  unstable at the target pose, grows there at the nominal gain.  A margin that says stable is stable in the
  FMU;
* ``flexlink control --schedule 3`` reports them (``--json``, the plot, ``--design-only``'s printout).
"""

from __future__ import annotations

import functools
import json
import math
import tomllib

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES, assert_margins_are_python_controls

from controllers.cosim import FmuLoop
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, plan
from controllers.schedule import along_path, design_schedule, redesign
from controllers.trajectory import Reference
from flexlink.errors import FlexlinkError
from flexlink.mechanics.model import build_model
from flexlink.run.linearize import linear_plant
from flexlink.scene.loader import load_scene, parse_scene

SCENE = EXAMPLES / "two_link_payload.toml"
TARGETS = [math.radians(60.0), math.radians(90.0)]
LIMIT, POINTS, DT = 60.0, 3, 1e-3
SIGMA = np.linspace(0.0, 1.0, 4 * POINTS - 3)
SENSORS = ("shoulder.theta", "elbow.theta", "upper.root.moment", "fore.root.moment")
PULSE = 1e-3                                           # N m, 5 ms: an unstable loop stays small (linear)


@pytest.fixture(scope="module")
def path():
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=DT)
    pl = plan(d.plant, TARGETS)
    sch = design_schedule(d, pl, POINTS)
    return d, pl, sch, along_path(d, sch, pl, SIGMA.tolist())


@functools.cache
def built_at(shoulder: float, elbow: float):
    """The example's scene with its joints' initial_angle at the pose, built and linearised afresh."""
    data = tomllib.loads(SCENE.read_text())
    for j, a in zip(data["joint"], (shoulder, elbow), strict=True):
        j["initial_angle"] = a
    return linear_plant(build_model(parse_scene(data)))


def pose_of(point) -> tuple[float, float]:
    return tuple(round(math.radians(point["pose_deg"][j]), 12) for j in ("shoulder", "elbow"))


def sampled(p):
    """python-control's ZOH-sampled plant from the two torques to the Kalman sensors."""
    cols = [p.inputs.index(f"{j}.tau") for j in ("shoulder", "elbow")]
    C = p.sys.C[[p.output_row(s) for s in SENSORS]]
    return ct.sample_system(ct.ss(p.sys.A, p.sys.B[:, cols], C, 0), DT, method="zoh")


def loop(p, law, gain=(1.0, 1.0)) -> ct.StateSpace:
    """The sampled loop of plant p and the law's matrices (M, C, K, A_d, B_d; current estimator), the torques
    scaled by ``gain`` between law and plant, with inputs and outputs at the torques (broken loops below):
    ``x̂ = (I − M C) z + M y``, ``u = −K x̂``, ``z⁺ = (A_d − B_d K) x̂``."""
    M, C, K, Ad, Bd = law
    F, Acl = np.eye(len(Ad)) - M @ C, Ad - Bd @ K
    Kc = ct.ss(Acl @ F, Acl @ M, -K @ F, -K @ M, DT)
    return ct.series(sampled(p), Kc, np.diag(gain))            # torques asked for, from the torques applied


def worst_gain_margin(along: dict):
    """The actuator and the entry of the smallest gain margin of the scheduled law along the path."""
    acts = along["scheduled"]["worst"]["actuators"]
    i = min(range(len(acts)), key=lambda k: acts[k]["gain_margin_db"]["value"])
    return i, acts[i]["gain_margin_db"]


def test_worst_is_the_worst_of_the_points(path):
    *_, along = path
    for name in ("scheduled", "fixed"):
        pts, worst = along[name]["points"], along[name]["worst"]
        assert [p["sigma"] for p in pts] == pytest.approx(SIGMA.tolist())
        stable = [p for p in pts if p["stable"]]
        assert worst["stable"] == (len(stable) == len(pts))
        assert worst["unstable_sigma"] == [p["sigma"] for p in pts if not p["stable"]]
        for p in pts:                                     # stable ⇔ every frozen pole inside the unit circle
            assert p["stable"] == (p["spectral_radius"] < 1)
        for i, act in enumerate(worst["actuators"]):
            gm = [(p["actuators"][i]["gain_margin_db"], p["sigma"]) for p in stable
                  if p["actuators"][i]["gain_margin_db"] is not None]
            assert (act["gain_margin_db"]["value"], act["gain_margin_db"]["sigma"]) == min(gm)
            dm = [(p["actuators"][i]["disk_margin"], p["sigma"]) for p in stable]
            assert (act["disk_margin"]["value"], act["disk_margin"]["sigma"]) == min(dm)
    assert along["scheduled"]["worst"]["stable"]
    assert not along["fixed"]["worst"]["stable"]          # why the example schedules (tests/test_control_schedule.py)


def test_margins_against_python_control(path):
    """At the scheduled law's worst pose, the loop broken at each torque with the other closed
    (``feedback``), plant and gains as built here: ``stability_margins`` gives the reported margins.  At the
    fixed law's unstable poses, python-control's closed-loop poles leave the unit circle."""
    d, _, sch, along = path
    _, entry = worst_gain_margin(along)
    point = next(p for p in along["scheduled"]["points"] if p["sigma"] == entry["sigma"])
    T = loop(built_at(*pose_of(point)), sch.matrices(point["sigma"]))
    assert_margins_are_python_controls(point["actuators"], T, DT, f"σ {point['sigma']}: ")
    fixed = (d.kalman.Md, d.kalman.C, d.lqr.Kd, np.asarray(d.lqr.plant_d.A), np.asarray(d.lqr.plant_d.B))
    for p in along["fixed"]["points"]:
        if p["sigma"] in (0.0, 0.5, 1.0):
            poles = ct.feedback(loop(built_at(*pose_of(p)), fixed), np.eye(2), sign=1).poles()
            assert p["stable"] == bool(np.max(np.abs(poles)) < 1)
            assert p["spectral_radius"] == pytest.approx(float(np.max(np.abs(poles))), abs=1e-8)


class Frozen(MimoLQGLaw):
    """The multi-joint LQG about a pose (its operating point: the design there), with the matrices of a law
    frozen at one point of the path and actuator i's torque deviation scaled by g on its way to the plant."""

    def __init__(self, here, law, ref, i=0, g=1.0):
        super().__init__(here, [1e6, 1e6], ref)
        self.law, self.i, self.g = law, i, g

    def matrices(self, k):
        return self.law

    def step(self, y, x_ref, u_ff):
        u = super().step(y, x_ref, u_ff).copy()
        u[self.i] = self.u0[self.i] + self.g * (u[self.i] - self.u0[self.i])
        return u


def hold(d, fmu, point, law, i=0, g=1.0) -> tuple[float, float, float]:
    """The FMU started at the point's pose, a 5 ms pulse on both torques, then the frozen law: the torque
    deviation at actuator i just after the pulse and at the end, and the loop's spectral radius (built here).
    The run lasts until that radius has decayed the loop a hundredfold or grown it a thousandfold."""
    p = built_at(*pose_of(point))
    gain = [1.0, 1.0]
    gain[i] = g
    r = float(np.max(np.abs(ct.feedback(loop(p, law, gain), np.eye(2), sign=1).poles())))
    N = 16 + math.ceil(math.log(1e-2 if r < 1 else 1e3) / math.log(r))
    n = p.sys.nstates
    u_ff = np.zeros((N + 1, 2))
    u_ff[:5] = PULSE
    ref = Reference("pulse", DT, 0.0, np.arange(N + 1) * DT, np.zeros((N + 1, n)), u_ff, 0)
    shoulder, elbow = pose_of(point)
    with FmuLoop(fmu) as fl:
        res = fl.run(Frozen(redesign(d, p), law, ref, i, g), ref,
                     parameters={"shoulder.initial_angle": shoulder, "elbow.initial_angle": elbow,
                                 "solver.step": 1e-4})
    j = d.actuated_joints[i]
    u = np.abs(res[f"{j}.tau"])
    return float(np.max(u[6:16])), float(np.max(u[-20:])), r


def test_worst_margin_against_the_fmu(path, example_fmu):
    d, _, sch, along = path
    fmu = example_fmu("two_link_payload")
    i, entry = worst_gain_margin(along)
    point = next(p for p in along["scheduled"]["points"] if p["sigma"] == entry["sigma"])
    crit = 10 ** (entry["value"] / 20)
    law = sch.matrices(point["sigma"])
    for g, stable in ((1.0, True), (0.95 * crit, True), (1.05 * crit, False)):
        early, late, r = hold(d, fmu, point, law, i, g)
        print(f"\nscheduled at σ {point['sigma']}, {d.actuated_joints[i]} gain x {g:.4f} (critical {crit:.4f}, "
              f"radius {r:.5f}): |tau| after the pulse {early:.3g}, at the end {late:.3g} N m")
        assert (r < 1) == stable
        assert (late < 0.1 * early) if stable else (late > 10 * early)
    fixed = (d.kalman.Md, d.kalman.C, d.lqr.Kd, np.asarray(d.lqr.plant_d.A), np.asarray(d.lqr.plant_d.B))
    end = along["fixed"]["points"][-1]
    assert not end["stable"]
    early, late, r = hold(d, fmu, end, fixed)
    print(f"fixed at the target pose (radius {r:.4f}): |tau| after the pulse {early:.3g}, at the end {late:.3g} N m")
    assert late > 10 * early


def test_cli_reports_the_margins_along_the_path(path, tmp_path, capsys):
    """``flexlink control --schedule 3 --json --plot``: the margins along the path under
    ``robustness_along_path`` (the points' σ, the worst case and where), the frozen spectral radius at the same
    poses, the plot written; ``--design-only`` prints the worst margins with their σ; without the path,
    ``--schedule`` is refused in one message."""
    import argparse

    from controllers.cli import add_control_parsers

    *_, along = path
    parser = argparse.ArgumentParser()
    add_control_parsers(parser.add_subparsers(dest="command"))
    png = tmp_path / "sched.png"
    common = ["control", str(SCENE), "--target", "60,90", "--duration", "1.5", "--settle", "0.5", "--torque-limit",
              "60", "--schedule", str(POINTS)]
    args = parser.parse_args([*common, "--json", "--plot", str(png)])
    assert args.func(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert png.stat().st_size > 10_000
    rob = doc["robustness_along_path"]
    assert [p["sigma"] for p in rob["scheduled"]["points"]] == pytest.approx(SIGMA.tolist())
    assert [r["scheduled"] for r in doc["frozen_spectral_radius"]] == pytest.approx(
        [p["spectral_radius"] for p in along["scheduled"]["points"]], rel=1e-9)
    i, entry = worst_gain_margin(along)
    got = rob["scheduled"]["worst"]["actuators"][i]["gain_margin_db"]
    assert got["sigma"] == entry["sigma"] and got["value"] == pytest.approx(entry["value"], rel=1e-9)
    assert rob["fixed"]["worst"]["unstable_sigma"] == along["fixed"]["worst"]["unstable_sigma"]
    args = parser.parse_args([*common, "--design-only"])                  # the margins without a run
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert f"gain margin {entry['value']:.3g} dB (σ {entry['sigma']:.3g})" in out
    assert "fixed LQG: UNSTABLE at σ = 0.5" in out
    for bad in (["--design-only"], ["--design-only", "--target", "60,90"]):    # no path: refused before the design
        args = parser.parse_args(["control", str(SCENE), "--torque-limit", "60", "--schedule", "3", *bad])
        with pytest.raises(FlexlinkError, match="needs the path"):
            args.func(args)


def test_accelerometer_loops_are_marked_not_the_runs(path):
    """With the accelerometers the run's estimator follows the reference (controllers.multijoint), so the
    frozen-pose loops with the designs' stationary estimators are marked as not the run's; not so with the
    strain gauges."""
    *_, along = path
    assert along["scheduled"]["note"] is None and along["fixed"]["note"] is None
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=DT, sensors="accelerometer")
    pl = plan(d.plant, TARGETS)
    acc = along_path(d, design_schedule(d, pl, 2), pl, [0.0])
    assert "not the run's" in acc["scheduled"]["note"] and "not the run's" in acc["fixed"]["note"]
    from controllers.plots import path_margins_text

    assert "note: the sensors read the torques" in path_margins_text(acc)
