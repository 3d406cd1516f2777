"""``flexlink control --export-fmu``: the sampled MIMO LQG as a pure-C FMI 2.0 Co-Simulation FMU.

fmpy's own validation of the FMU; the closed loop of the plant FMU with the controller FMU (both stepped by
fmpy here) against the closed loop of the plant FMU with the Python law (controllers.multijoint.MimoLQGLaw)
on the two-link arm's manoeuvre, which saturates the shoulder: every recorded series equal to 1e-9; the
FMU's refusals (another step size, another GUID, a file name without .fmu).
"""

from __future__ import annotations

import math

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from test_control_multijoint import LIMIT, SCENE, TARGETS

from controllers.cosim import FmuLoop
from controllers.design import DesignError
from controllers.export import FmuLaw, export_controller_fmu
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, inverse_dynamics_reference, plan
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=1e-3)
    return d, export_controller_fmu(d, tmp_path_factory.mktemp("ctrl") / "ctrl.fmu")


def test_fmpy_validates_it(exported):
    d, fmu = exported
    assert validate_fmu(str(fmu)) == []
    md = fmpy.read_model_description(str(fmu))
    assert md.coSimulation is not None and md.modelExchange is None
    assert float(md.defaultExperiment.stepSize) == d.dt
    assert md.coSimulation.canHandleVariableCommunicationStepSize is False
    names = [v.name for v in md.modelVariables]
    assert names[:4] == d.kalman.sensors and names[-2:] == ["shoulder.tau", "elbow.tau"]
    assert len(names) == 4 + 12 + 2 + 12 + 2


def test_closed_loop_equals_the_python_law(exported, example_fmu):
    d, fmu = exported
    pl = plan(d.plant, TARGETS)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, 1.5, 0.5)
    law = MimoLQGLaw(d, [LIMIT, LIMIT], ref)
    ctrl = FmuLaw(fmu, law.W)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=["upper.tip.v", "fore.tip.v"]) as loop:
            a = loop.run(law, ref)
            b = loop.run(ctrl, ref)
            c = loop.run(ctrl, ref)                  # the controller FMU reset (fmi2Reset) between runs
    finally:
        ctrl.close()
    assert np.max(np.abs(a["shoulder.tau"])) == LIMIT          # the saturation is exercised
    for name, x in a.series.items():
        scale = max(1.0, float(np.max(np.abs(x))))
        assert np.max(np.abs(b[name] - x)) <= 1e-9 * scale, name
        np.testing.assert_array_equal(c[name], b[name])
    assert abs(math.degrees(b["elbow.theta"][-1] - TARGETS[1])) < 1e-3


def test_refusals(exported, tmp_path):
    d, fmu = exported
    from fmpy.fmi2 import FMU2Slave

    md = fmpy.read_model_description(str(fmu))
    unzip = fmpy.extract(str(fmu))
    s = FMU2Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=md.coSimulation.modelIdentifier)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    with pytest.raises(FMICallException):
        s.doStep(0.0, 2 * d.dt)
    with pytest.raises(FMICallException):
        s.setReal([0], [math.nan])
    s.doStep(0.0, d.dt)
    s.terminate()
    s.freeInstance()
    wrong = FMU2Slave(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=unzip,
                      modelIdentifier=md.coSimulation.modelIdentifier)
    with pytest.raises(Exception, match="instantiate|NULL|Failed"):
        wrong.instantiate()
    with pytest.raises(DesignError, match="ending in .fmu"):
        export_controller_fmu(d, tmp_path / "ctrl.zip")


def test_cli_export(tmp_path, capsys):
    from flexlink.cli import main

    out = tmp_path / "ctrl.fmu"
    assert main(["control", str(SCENE), "--design-only", "--torque-limit", str(LIMIT), "--export-fmu", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().err and validate_fmu(str(out)) == []
    assert main(["control", str(SCENE), "--design-only", "--torque-limit", str(LIMIT), "--sensors", "accelerometer",
                 "--export-fmu", str(tmp_path / "acc.fmu")]) == 2          # tests/test_control_export_accel.py
    err = capsys.readouterr().err
    assert "give --target and --duration" in err and err.count("\n") == 1 and not (tmp_path / "acc.fmu").exists()
