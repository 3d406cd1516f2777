"""The gain schedule in the exported controller FMU (``flexlink control --schedule N --export-fmu``).

On the scheduled manoeuvre of tests/test_control_schedule.py (two-link arm, elbow −20° → 90°, three design
points): the plant FMU in closed loop with the scheduled controller FMU (C: its matrices interpolated along
the path from t alone) against the plant FMU with the Python law (controllers.schedule.ScheduledLQGLaw):
every recorded series equal to 1e-9 of its scale; the law's matrices do change along the path (the fixed
design's FMU gives another loop).  fmpy validates the FMU, ``flexlink check`` passes it, and the command
writes it in one line (the SSP package refuses a schedule in one line).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from fmpy.validation import validate_fmu
from test_control_schedule import DURATION, LIMIT, POINTS, SCENE, TARGETS

from controllers.cosim import FmuLoop
from controllers.export import FmuLaw, export_controller_fmu
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, inverse_dynamics_reference, plan
from controllers.schedule import ScheduledLQGLaw, design_schedule
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SETTLE = 0.3


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
    worst = {}
    for name, x in a.series.items():
        scale = max(1.0, float(np.max(np.abs(x))))
        worst[name] = float(np.max(np.abs(b[name] - x)))
        assert worst[name] <= 1e-9 * scale, name
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
    assert main([*args[:-2], "--export-ssp", str(tmp_path / "s.ssp")]) == 2
    err = capsys.readouterr().err
    assert "--export-ssp" in err and err.count("\n") == 1 and not (tmp_path / "s.ssp").exists()
