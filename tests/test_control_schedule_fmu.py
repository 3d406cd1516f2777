"""The gain schedule in the exported controller FMU (``flexlink control --schedule N --export-fmu``).

On the scheduled manoeuvre of tests/test_control_schedule.py (two-link arm, elbow −20° → 90°, three design
points): the plant FMU in closed loop with the scheduled controller FMU (C: its matrices interpolated along
the path from t alone) against the plant FMU with the Python law (controllers.schedule.ScheduledLQGLaw):
every recorded series equal to 1e-9 of its scale; the law's matrices do change along the path (the fixed
design's FMU gives another loop).  fmpy validates the FMU, ``flexlink check`` passes it, and the command
writes it in one line.

The SSP package carries the schedule too (``--schedule N --export-ssp``): its controller FMU (the schedule,
the manoeuvre built in, predictive for a Jacobi master's one sample of delay) run by libcosim from the
package (its own SSP parser and master), and the same controller FMU extracted from the package stepped by
fmpy beside the plant FMU as a Jacobi master steps it, both equal to 1e-9 the plant FMU with the Python law
(``JacobiDelay(ScheduledPredictiveLQGLaw)``: the schedule's matrices at each sample, the next sample's gain
for the torque it outputs).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import assert_runs_equal
from fmpy.ssp.ssd import read_ssd
from fmpy.validation import validate_fmu
from test_control_schedule import DURATION, LIMIT, POINTS, SCENE, TARGETS

from controllers.cosim import FmuLoop
from controllers.export import FmuLaw, export_controller_fmu
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, inverse_dynamics_reference, plan
from controllers.schedule import ScheduledLQGLaw, design_schedule
from controllers.ssp import CONTROLLER, PLANT, JacobiDelay, ScheduledPredictiveLQGLaw, write_ssp
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.importers import libcosim_available, run_libcosim_ssp

SETTLE = 0.3
RECORD = ["upper.tip.v", "fore.tip.v"]


@pytest.fixture(scope="module")
def scheduled(tmp_path_factory):
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=1e-3)
    pl = plan(d.plant, TARGETS)
    schedule = design_schedule(d, pl, POINTS)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, DURATION, SETTLE)
    fmu = export_controller_fmu(d, tmp_path_factory.mktemp("sched") / "ctrl.fmu", schedule=schedule,
                                duration=DURATION)
    return d, schedule, ref, fmu


def test_fmu_closed_loop_equals_the_python_scheduled_loop(scheduled, example_fmu):
    d, schedule, ref, fmu = scheduled
    limits = [LIMIT, LIMIT]
    law = ScheduledLQGLaw(schedule, limits, ref)
    ctrl = FmuLaw(fmu, law.W)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=["upper.tip.v", "fore.tip.v"]) as loop:
            a = loop.run(law, ref)
            b = loop.run(ctrl, ref)
            fixed = loop.run(MimoLQGLaw(d, limits, ref), ref)
    finally:
        ctrl.close()
    worst = assert_runs_equal(a, b)
    print(f"\nlargest difference FMU - Python: {worst}")
    # the schedule is exercised: the fixed design's loop differs by far more than that
    assert np.max(np.abs(fixed["elbow.tau"] - a["elbow.tau"])) > 1.0


def test_fmpy_validate_and_flexlink_check(scheduled, tmp_path):
    from flexlink.cli import main

    _, _, _, fmu = scheduled
    assert validate_fmu(str(fmu)) == []
    assert main(["check", str(fmu), "--report", str(tmp_path / "check")]) == 0


def test_cli(tmp_path, capsys):
    from flexlink.cli import main

    out = tmp_path / "sched.fmu"
    args = ["control", str(SCENE), "--target", "60,90", "--duration", str(DURATION), "--settle", "0.2",
            "--torque-limit", str(LIMIT), "--schedule", "2", "--json", "--export-fmu", str(out)]
    assert main(args) == 0
    cap = capsys.readouterr()
    assert f"wrote {out}: sampled LQG scheduled at 2 poses" in cap.err and validate_fmu(str(out)) == []
    assert "scheduled" in json.loads(cap.out)
    assert main([*args[:-2], "--export-ssp", str(tmp_path / "s.ssp")]) == 0
    err = capsys.readouterr().err
    assert f"wrote {tmp_path / 's.ssp'}" in err and "scheduled at 2 poses" in err
    read_ssd(str(tmp_path / "s.ssp"), validate=True)


@pytest.fixture(scope="module")
def package(scheduled, example_fmu, tmp_path_factory):
    d, schedule, ref, _ = scheduled
    plant = example_fmu("two_link_payload")
    path = write_ssp(d, plant, tmp_path_factory.mktemp("ssp") / "system.ssp", ref, schedule=schedule)
    law = ScheduledPredictiveLQGLaw(schedule, [LIMIT, LIMIT], ref)
    with FmuLoop(plant, record=RECORD) as loop:
        py = loop.run(JacobiDelay(law, law.initial()), ref)
    return d, ref, plant, path, py


def assert_equal_to_python(py, values: dict, sensors: list[str], torques: list[str]) -> dict:
    """Plant outputs after step k (t_1 … t_n) and the torques output after step k against the Python run."""
    worst = {}
    for name in sensors + RECORD:
        x = np.asarray(values[name])
        scale = max(1.0, float(np.max(np.abs(py[name]))))
        worst[name] = float(np.max(np.abs(x - py[name][1:])))
        assert worst[name] <= 1e-9 * scale, name
    for u in torques:                                          # applied over [t_k+1, t_k+2]
        x = np.asarray(values[u])
        worst[u] = float(np.max(np.abs(x[:-1] - py[u][1:-1])))
        assert worst[u] <= 1e-9 * LIMIT, u
    return worst


def test_the_python_predictive_schedule_is_exercised(scheduled, package):
    """The package's law follows the manoeuvre, and its schedule matters: the predictive law without it
    (the start design throughout) gives another loop."""
    from controllers.cosim import FmuLoopError
    from controllers.ssp import PredictiveLQGLaw

    d, ref, plant, _, py = package
    assert abs(np.degrees(py["elbow.theta"][-1] - TARGETS[1])) < 1e-2
    fixed = PredictiveLQGLaw(d, [LIMIT, LIMIT], ref)
    with FmuLoop(plant, record=RECORD) as loop:
        try:
            other = loop.run(JacobiDelay(fixed, fixed.initial()), ref)
            assert np.max(np.abs(other["elbow.tau"] - py["elbow.tau"])) > 1.0
        except FmuLoopError as e:                             # the fixed design may leave the model's validity
            assert "validity" in str(e)


@pytest.mark.skipif(not libcosim_available(), reason="libcosimpy is not installed")
def test_libcosim_runs_the_scheduled_package_as_python(package):
    d, ref, _, path, py = package
    sensors, torques = list(d.kalman.sensors), list(d.lqr.inputs)
    run = run_libcosim_ssp(path, len(ref.time) - 1, {PLANT: sensors + RECORD, CONTROLLER: torques})
    assert run.ok, run.why + run.log[-2000:]
    values = {n.split(":", 1)[1]: v for n, v in run.values.items()}
    print(f"\nlibcosim - Python: {assert_equal_to_python(py, values, sensors, torques)}")


def test_fmpy_steps_the_packages_controller_as_python(package, tmp_path):
    """The controller FMU inside the package, stepped by fmpy beside the plant FMU as a Jacobi master does:
    every recorded series (plant outputs, the torques applied) equal to the Python run's."""
    import zipfile

    d, ref, plant, path, py = package
    with zipfile.ZipFile(path) as z:
        z.extract(f"resources/{CONTROLLER}.fmu", tmp_path)
    ctrl = FmuLaw(tmp_path / "resources" / f"{CONTROLLER}.fmu", builtin=True)
    try:
        with FmuLoop(plant, record=RECORD) as loop:
            b = loop.run(JacobiDelay(ctrl, [py[u][0] for u in d.lqr.inputs]), ref)
    finally:
        ctrl.close()
    worst = {}
    for name, x in py.series.items():
        scale = max(1.0, float(np.max(np.abs(x))))
        worst[name] = float(np.max(np.abs(b[name] - x)))
        assert worst[name] <= 1e-9 * scale, name
    print(f"\nfmpy - Python: {worst}")
