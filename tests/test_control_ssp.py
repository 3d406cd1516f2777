"""``flexlink control --export-ssp``: the plant FMU and the controller FMU as an SSP 1.0 package.

* the ``.ssd`` passes the normative SSP 1.0 schema (fmpy's copy, through its own reader), and names what it
  should: two components, each sensor and torque connected, the sample time as libcosim's base step;
* libcosim (an independent importer: its own SSP parser, its own Jacobi master, in a child process) runs
  the package, and its plant outputs and torques equal, to 1e-9, the plant FMU stepped by fmpy with the
  Python law applied as a Jacobi master applies it (``JacobiDelay(PredictiveLQGLaw)``);
* why the package's controller compensates the delay: python-control's closed-loop poles of the sampled
  LQG with one sample of input delay lie outside the unit circle, those without inside;
* the command writes the package, and refuses without a manoeuvre or with another suffix (one line, exit 2).
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from fmpy.ssp.ssd import read_ssd
from test_control_multijoint import LIMIT, SCENE, TARGETS

from controllers.cosim import FmuLoop
from controllers.design import torque_inputs
from controllers.manoeuvre import design
from controllers.multijoint import inverse_dynamics_reference, plan
from controllers.robustness import lqg_compensator, lqg_plant
from controllers.ssp import CONTROLLER, PLANT, JacobiDelay, PredictiveLQGLaw, write_ssp
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.importers import libcosim_available, run_libcosim_ssp

DURATION, SETTLE = 1.5, 0.5
RECORD = ["upper.tip.v", "fore.tip.v"]


@pytest.fixture(scope="module")
def package(tmp_path_factory, example_fmu):
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=1e-3)
    ref = inverse_dynamics_reference(d.plant, plan(d.plant, TARGETS), d.dt, DURATION, SETTLE)
    plant = example_fmu("two_link_payload")
    return d, ref, plant, write_ssp(d, plant, tmp_path_factory.mktemp("ssp") / "system.ssp", ref)


def test_ssd_against_the_ssp_schema(package):
    import zipfile

    from lxml import etree

    d, ref, _, path = package
    ssd = read_ssd(str(path), validate=True)             # raises on a schema violation
    assert sorted(c.name for c in ssd.system.elements) == [CONTROLLER, PLANT]
    want = {(PLANT, s, CONTROLLER, s) for s in d.kalman.sensors} | {(CONTROLLER, u, PLANT, u) for u in d.lqr.inputs}
    got = {(c.startElement, c.startConnector, c.endElement, c.endConnector) for c in ssd.system.connections}
    assert got == want
    with zipfile.ZipFile(path) as z:
        root = etree.fromstring(z.read("SystemStructure.ssd"))
        assert {"resources/plant.fmu", "resources/controller.fmu"} <= set(z.namelist())
    ns = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
          "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations"}
    exp = root.find("ssd:DefaultExperiment", ns)
    assert float(exp.get("stopTime")) == pytest.approx(DURATION + SETTLE)
    assert float(exp.find(".//osp:FixedStepAlgorithm", ns).get("baseStepSize")) == d.dt


@pytest.mark.skipif(not libcosim_available(), reason="libcosimpy is not installed")
def test_libcosim_runs_the_package_as_fmpy_and_python(package):
    d, ref, plant, path = package
    n = len(ref.time) - 1
    sensors = list(d.kalman.sensors)
    run = run_libcosim_ssp(path, n, {PLANT: sensors + RECORD, CONTROLLER: list(d.lqr.inputs)})
    assert run.ok, run.why + run.log[-2000:]
    law = PredictiveLQGLaw(d, [LIMIT, LIMIT], ref)
    with FmuLoop(plant, record=RECORD) as loop:
        py = loop.run(JacobiDelay(law, law.initial()), ref)
    for name in sensors + RECORD:
        x = np.asarray(run.values[f"{PLANT}:{name}"])          # after step k: t_1 … t_n
        scale = max(1.0, float(np.max(np.abs(py[name]))))
        assert np.max(np.abs(x - py[name][1:])) <= 1e-9 * scale, name
    for u in d.lqr.inputs:                                     # output after step k: applied over [t_k, t_k+1]
        x = np.asarray(run.values[f"{CONTROLLER}:{u}"])
        assert np.max(np.abs(x[:-1] - py[u][1:-1])) <= 1e-9 * LIMIT, u
    assert np.max(np.abs(py["shoulder.tau"])) == LIMIT         # the saturation is exercised
    assert abs(math.degrees(py["elbow.theta"][-1] - TARGETS[1])) < 1e-3


def test_the_delay_the_package_compensates(package):
    """python-control: the sampled LQG as designed, with the one sample of delay a Jacobi master adds at the
    torque inputs, is unstable on this arm; without it, stable."""
    d = package[0]
    P = lqg_plant(d.lqr, d.kalman)
    K = lqg_compensator(d.lqr, d.kalman)
    m = len(torque_inputs(d.plant))
    delay = ct.ss(np.zeros((m, m)), np.eye(m), np.eye(m), np.zeros((m, m)), d.dt)
    undelayed = ct.feedback(P, K, sign=1)
    delayed = ct.feedback(ct.series(delay, P), K, sign=1)
    assert np.max(np.abs(undelayed.poles())) < 1 < np.max(np.abs(delayed.poles()))


def test_cli_export_ssp(tmp_path, capsys):
    from flexlink.cli import main

    out = tmp_path / "system.ssp"
    base = ["control", str(SCENE), "--design-only", "--torque-limit", str(LIMIT)]
    assert main([*base, "--target", "60,20", "--duration", "1.5", "--settle", "0.2", "--export-ssp", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().err
    read_ssd(str(out), validate=True)
    for extra, msg in (([], "--target and --duration"),
                       (["--target", "60,20", "--duration", "1.5", "--export-ssp", str(tmp_path / "s.zip")], ".ssp")):
        args = [*base, *extra] if extra else [*base, "--export-ssp", str(tmp_path / "t.ssp")]
        assert main(args) == 2
        err = capsys.readouterr().err
        assert msg in err and err.count("\n") == 1
