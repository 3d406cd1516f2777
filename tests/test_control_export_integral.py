"""Integral action on the joint positions in the controller FMU and the SSP package (``--integral TI`` with
``--export-fmu`` / ``--export-ssp``; ``ctrl_fmu.c`` with ``INTEGRAL 1``) on examples/two_link_payload.toml.

* fmpy validates the FMU and ``flexlink check`` passes it;
* the plant FMU stepped by fmpy with the controller FMU equals, to 1e-9 of every series' scale, the plant FMU
  with the Python law (``controllers.integral.IntegralLQGLaw``): on the 60°/20° manoeuvre, which saturates
  the shoulder (the anti-windup is exercised), and holding the start pose against a constant torque the model
  lacks, which only the integrators remove (the FMU's loop ends on its targets, the LQG without them off);
* the SSP package with integral action run by libcosim (its own SSP parser and Jacobi master) equals, to 1e-9,
  the plant FMU stepped by fmpy with the Python predictive law (``controllers.ssp.PredictiveIntegralLQGLaw``)
  applied one sample late, as that master applies it;
* ``flexlink control --integral`` writes both, with ``--schedule`` too (that package run by libcosim:
  tests/test_control_schedule_integral.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from fmpy.validation import validate_fmu
from test_control_multijoint import LIMIT, SCENE, TARGETS

from controllers.cosim import FmuLoop
from controllers.export import FmuLaw, export_controller_fmu
from controllers.integral import IntegralLQGLaw, design_integral
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, inverse_dynamics_reference, plan
from controllers.ssp import CONTROLLER, PLANT, JacobiDelay, PredictiveIntegralLQGLaw, write_ssp
from controllers.trajectory import Reference
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.importers import libcosim_available, run_libcosim_ssp

TI, DURATION, SETTLE = 0.5, 1.5, 0.5
RECORD = ["upper.tip.v", "fore.tip.v"]
BIAS = np.array([2.0, -1.0])                     # N m the model lacks, added between the law and the plant


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=1e-3)
    integ = design_integral(d, TI)
    fmu = export_controller_fmu(d, tmp_path_factory.mktemp("ctrl") / "ctrl.fmu", integral=integ)
    ref = inverse_dynamics_reference(d.plant, plan(d.plant, TARGETS), d.dt, DURATION, SETTLE)
    return d, integ, fmu, ref


def assert_series_equal(a, b, names, what: str) -> None:
    for name in names:
        scale = max(1.0, float(np.max(np.abs(a[name]))))
        diff = float(np.max(np.abs(b[name] - a[name])))
        print(f"  {what}: {name} differs by {diff:.2g} (scale {scale:.3g})")
        assert diff <= 1e-9 * scale, name


class Biased:
    """A law's torques plus a constant torque the model lacks."""

    def __init__(self, law):
        self.law, self.dt, self.sensors, self.inputs, self.kind = law, law.dt, law.sensors, law.inputs, "biased"

    def reset(self):
        self.law.reset()

    def step(self, y, x_ref, u_ff):
        return self.law.step(y, x_ref, u_ff) + BIAS


def test_fmpy_validate_and_flexlink_check(rig, tmp_path):
    from flexlink.cli import main

    fmu = rig[2]
    assert validate_fmu(str(fmu)) == []
    assert main(["check", str(fmu), "--report", str(tmp_path / "check")]) == 0


def test_fmu_closed_loop_equals_the_python_integral_law(rig, example_fmu):
    d, integ, fmu, ref = rig
    law = IntegralLQGLaw(integ, [LIMIT, LIMIT], ref)
    ctrl = FmuLaw(fmu, law.W)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=RECORD) as loop:
            a = loop.run(law, ref)
            b = loop.run(ctrl, ref)
    finally:
        ctrl.close()
    assert np.max(np.abs(a["shoulder.tau"])) == LIMIT          # the saturation (and the anti-windup) is exercised
    assert np.any(law.xi != 0)
    assert_series_equal(a, b, list(a.series), "manoeuvre")
    assert abs(math.degrees(b["elbow.theta"][-1] - TARGETS[1])) < 0.1       # the settle band (a slow integral tail)


def test_fmu_removes_a_constant_disturbance_as_the_python_law(rig, example_fmu):
    """Hold the start pose 3 s against BIAS: the controller FMU's loop equals the Python integral law's and
    ends on the start pose; the LQG without integral action stays off it (the disturbance over its stiffness)."""
    d, integ, fmu, _ = rig
    n = 3000
    nx = d.plant.sys.nstates
    hold = Reference("hold", d.dt, 0.0, np.arange(n + 1) * d.dt, np.zeros((n + 1, nx)), np.zeros((n + 1, 2)), 0)
    law = IntegralLQGLaw(integ, [LIMIT, LIMIT], hold)
    ctrl = FmuLaw(fmu, law.W)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=RECORD) as loop:
            a = loop.run(Biased(law), hold)
            b = loop.run(Biased(ctrl), hold)
            c = loop.run(Biased(MimoLQGLaw(d, [LIMIT, LIMIT], hold)), hold)
    finally:
        ctrl.close()
    assert_series_equal(a, b, list(a.series), "hold")
    start = {j: d.plant.x0[d.plant.states.index(f"{j}.theta")] for j in ("shoulder", "elbow")}
    err = {j: math.degrees(b[f"{j}.theta"][-1] - start[j]) for j in start}
    off = {j: math.degrees(c[f"{j}.theta"][-1] - start[j]) for j in start}
    print(f"  final joint errors: integral FMU {err}, LQG {off}")
    assert max(abs(v) for v in err.values()) < 0.05 * max(abs(v) for v in off.values())


@pytest.mark.skipif(not libcosim_available(), reason="libcosimpy is not installed")
def test_libcosim_runs_the_integral_package_as_fmpy_and_python(rig, example_fmu, tmp_path):
    d, integ, _, ref = rig
    plant = example_fmu("two_link_payload")
    path = write_ssp(d, plant, tmp_path / "system.ssp", ref, integral=integ)
    sensors = list(d.kalman.sensors)
    run = run_libcosim_ssp(path, len(ref.time) - 1, {PLANT: sensors + RECORD, CONTROLLER: list(d.lqr.inputs)})
    assert run.ok, run.why + run.log[-2000:]
    law = PredictiveIntegralLQGLaw(integ, [LIMIT, LIMIT], ref)
    with FmuLoop(plant, record=RECORD) as loop:
        py = loop.run(JacobiDelay(law, law.initial()), ref)
    assert np.any(law.xi != 0)
    for name in sensors + RECORD:
        x = np.asarray(run.values[f"{PLANT}:{name}"])          # after step k: t_1 … t_n
        scale = max(1.0, float(np.max(np.abs(py[name]))))
        print(f"  libcosim: {name} differs by {np.max(np.abs(x - py[name][1:])):.2g} (scale {scale:.3g})")
        assert np.max(np.abs(x - py[name][1:])) <= 1e-9 * scale, name
    for u in d.lqr.inputs:                                     # output after step k: applied over [t_k, t_k+1]
        x = np.asarray(run.values[f"{CONTROLLER}:{u}"])
        print(f"  libcosim: {u} differs by {np.max(np.abs(x[:-1] - py[u][1:-1])):.2g} N m")
        assert np.max(np.abs(x[:-1] - py[u][1:-1])) <= 1e-9 * LIMIT, u
    assert np.max(np.abs(py["shoulder.tau"])) == LIMIT
    assert abs(math.degrees(py["elbow.theta"][-1] - TARGETS[1])) < 0.1


def test_cli_writes_both_and_a_scheduled_package(tmp_path, capsys):
    from flexlink.cli import main

    base = ["control", str(SCENE), "--design-only", "--torque-limit", str(LIMIT), "--integral", str(TI),
            "--target", "60,20", "--duration", "1.5", "--settle", "0.2"]
    fmu, ssp = tmp_path / "ctrl.fmu", tmp_path / "system.ssp"
    assert main([*base, "--export-fmu", str(fmu), "--export-ssp", str(ssp)]) == 0
    err = capsys.readouterr().err
    assert f"wrote {fmu}" in err and f"wrote {ssp}" in err and "integral action (integral time 0.5 s)" in err
    assert validate_fmu(str(fmu)) == []
    # with a schedule too (tests/test_control_schedule_integral.py runs that package in libcosim)
    assert main([*base, "--schedule", "3", "--export-ssp", str(ssp)]) == 0
    assert "scheduled at 3 poses with integral action" in capsys.readouterr().err
