"""Integral action in the scheduled LQG (controllers.integral, issue 16) on examples/two_link_payload.toml:
shoulder 0 → 60°, elbow −20° → 90° in 1.5 s, the LQG scheduled at three poses along the path.

* at each design point the augmented gains (K_x, K_ξ) are python-control's ``dlqr`` on the plant linearised
  there from a scene *built* with the joints' ``initial_angle`` at that pose, sampled by python-control's
  ``sample_system`` and augmented here with the integrals of its joint-angle outputs, with Bryson's weights
  written here; between points the law's gains are the linear interpolation of those in σ;
* through the FMU, with a constant torque the model lacks (2 N m at the shoulder, −1 N m at the elbow)
  through the manoeuvre and a 6 s settle: the scheduled LQG ends with the steady joint error that
  python-control's DC gain of its closed loop at the target pose predicts; the scheduled LQG with integral
  action ends below 20 ρ^N of it (ρ the slowest pole of that loop with the integrators, N the settle's
  samples), settled;
* the frozen-pose margins along the path of the integral loops against python-control's;
* the controller FMU of the scheduled integral law equals the Python law in closed loop with the plant FMU;
* ``flexlink control --integral TI --schedule N``: the run and ``--design-only``, ``--json``, ``--export-fmu``
  (``--export-ssp`` refused).
"""

from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES, BiasedLaw, assert_margins_are_python_controls, assert_runs_equal, two_link_plant_at

from controllers.cosim import FmuLoop
from controllers.integral import ScheduledIntegralLQGLaw, design_scheduled_integral, sampled_integral_compensator
from controllers.manoeuvre import design
from controllers.multijoint import inverse_dynamics_reference, plan, run
from controllers.schedule import ScheduledLQGLaw, along_path, design_schedule, path_fraction
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SCENE = EXAMPLES / "two_link_payload.toml"
TARGETS = [math.radians(60.0), math.radians(90.0)]
JOINTS = ("shoulder", "elbow")
SENSORS = ("shoulder.theta", "elbow.theta", "upper.root.moment", "fore.root.moment")
DT, DURATION, LIMIT, POINTS, TI = 1e-3, 1.5, 60.0, 3, 0.5
BIAS = np.array([2.0, -1.0])                     # N m the model lacks, added between the law and the plant


@pytest.fixture(scope="module")
def sched():
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=DT)
    pl = plan(d.plant, TARGETS)
    s = design_schedule(d, pl, POINTS)
    return d, pl, s, design_scheduled_integral(s, TI)


def built_at(pose: dict):
    """The example's scene with its joints' initial_angle at ``pose``, built and linearised afresh."""
    return two_link_plant_at(tuple(pose[j] for j in JOINTS))


def sampled(p):
    """python-control's ZOH-sampled plant from the two torques to the Kalman sensors."""
    cols = [p.inputs.index(f"{j}.tau") for j in JOINTS]
    C = p.sys.C[[p.output_row(s) for s in SENSORS]]
    return ct.sample_system(ct.ss(p.sys.A, p.sys.B[:, cols], C, 0), DT, method="zoh")


def augmented_dlqr(p, limits: dict) -> np.ndarray:
    """python-control's dlqr on the sampled plant with the integrals of the joint angles appended."""
    Pd = sampled(p)
    Ad, Bd = np.asarray(Pd.A), np.asarray(Pd.B)
    n = Ad.shape[0]
    Ce = p.sys.C[[p.output_row(f"{j}.theta") for j in JOINTS]]
    Aa = np.block([[Ad, np.zeros((n, 2))], [DT * Ce, np.eye(2)]])
    Ba = np.vstack([Bd, np.zeros((2, 2))])
    # Bryson's rule with the design's declared limits (0.5° per joint, 5 mm per tip, 6 N m per root) and
    # 1/(e_max T_i)² on each joint's error integral
    Cz = p.sys.C[[p.output_row(z) for z in limits]]
    Q = Cz.T @ np.diag([1 / v**2 for v in limits.values()]) @ Cz
    Qa = np.zeros((n + 2, n + 2))
    Qa[:n, :n] = 0.5 * (Q + Q.T)
    Qa[n:, n:] = np.eye(2) / (math.radians(0.5) * TI) ** 2
    K, _, _ = ct.dlqr(Aa, Ba, Qa, np.eye(2) / LIMIT**2)
    return np.asarray(K)


def test_augmented_gains_at_each_point_are_python_controls_dlqr(sched):
    d, pl, s, si = sched
    assert set(d.lqr.limits) >= {"shoulder.theta", "elbow.theta"}
    gains = []
    for pose, integ in zip(s.poses, si.designs, strict=True):
        K = augmented_dlqr(built_at(pose), d.lqr.limits)
        n = K.shape[1] - 2
        scale = np.max(np.abs(K))
        np.testing.assert_allclose(integ.Kx, K[:, :n], atol=1e-6 * scale)
        np.testing.assert_allclose(integ.Ki, K[:, n:], atol=1e-6 * scale)
        gains.append(K)
    # the law between the first two points: the gains interpolated linearly in the path parameter
    ref = inverse_dynamics_reference(d.plant, pl, DT, DURATION, 0.5)
    law = ScheduledIntegralLQGLaw(si, [LIMIT, LIMIT], ref)
    sigma = path_fraction(ref)
    k = int(np.argmin(np.abs(sigma - 0.2)))
    lam = sigma[k] / s.sigma[1]
    K = (1 - lam) * gains[0] + lam * gains[1]
    n = K.shape[1] - 2
    scale = np.max(np.abs(K))
    np.testing.assert_allclose(law.matrices(k)[2], K[:, :n], atol=1e-6 * scale)
    np.testing.assert_allclose(law.integral_gain(k), K[:, n:], atol=1e-6 * scale)


def Biased(law):
    return BiasedLaw(law, BIAS)


def test_constant_disturbance_through_the_fmu(sched, example_fmu):
    """The manoeuvre with ``BIAS`` throughout and a 6 s settle.  The scheduled LQG (the target design's
    matrices from the manoeuvre's end) ends with python-control's DC-gain error of its closed loop with the
    plant built at the target pose; with integral action the error falls below 20 ρ^N of that, and the run
    settles (joints within 0.1°, tips within 1 mm)."""
    d, pl, s, si = sched
    settle = 6.0
    p = built_at(s.poses[-1])
    M, C, K, Ad, Bd = s.matrices(1.0)
    n = Ad.shape[0]
    F, Acl = np.eye(n) - M @ C, Ad - Bd @ K
    lqg = ct.ss(Acl @ F, Acl @ M, -K @ F, -K @ M, DT)
    expected = np.degrees((np.asarray(ct.dcgain(ct.feedback(sampled(p), lqg, sign=1))) @ BIAS)[:2])
    T = ct.series(sampled(p), sampled_integral_compensator(si.matrices(1.0), si.designs[-1].rows, DT))
    rho = float(np.max(np.abs(ct.feedback(T, np.eye(2), sign=1).poles())))
    N = int(round(settle / DT))
    ref = inverse_dynamics_reference(d.plant, pl, DT, DURATION, settle)
    laws = {"lqg": ScheduledLQGLaw(s, [LIMIT, LIMIT], ref),
            "integral": ScheduledIntegralLQGLaw(si, [LIMIT, LIMIT], ref)}
    errors, metrics = {}, {}
    with FmuLoop(example_fmu("two_link_payload")) as fl:
        for name, law in laws.items():
            res = run(d, fl, pl, ref, Biased(law))
            errors[name] = np.degrees([res.series[f"{j}.theta"][-1] - t for j, t in zip(JOINTS, TARGETS, strict=True)])
            metrics[name] = res.metrics
    print(f"\nsteady errors (deg): scheduled LQG {errors['lqg']}, python-control {expected}; with integral action "
          f"{errors['integral']} (slowest pole {rho:.5f}, 20 rho^N = {20 * rho ** N:.2e}); settling "
          f"{metrics['integral']['settling_time_s']} s")
    assert errors["lqg"] == pytest.approx(expected, rel=2e-3)
    assert np.all(np.abs(errors["integral"]) < 20 * rho**N * np.abs(expected))
    assert metrics["integral"]["settling_time_s"] is not None


def test_margins_along_the_path_against_python_control(sched):
    """At the target pose (σ = 1) and between the first two points, the integral loops' margins that
    along_path reports equal python-control's on the loop built with the plant linearised afresh there.

    On a 20 000-point grid: at σ = 0.25 the elbow's phase crossover is sharp enough that the default 4000
    points report a gain margin 0.013 dB low (1.707 dB against python-control's 1.720 dB on 6000 points)."""
    d, pl, s, si = sched
    along = along_path(d, s, pl, [0.25, 1.0], n_points=20000, integral=si)
    for i, sigma in enumerate((0.25, 1.0)):
        pose = {j: a + sigma * (b - a) for j, a, b in zip(pl.joints, pl.angle_start, pl.target, strict=True)}
        pt = along["scheduled"]["points"][i]
        T = ct.series(sampled(built_at(pose)), sampled_integral_compensator(si.matrices(sigma), si.designs[0].rows, DT))
        rho = float(np.max(np.abs(ct.feedback(T, np.eye(2), sign=1).poles())))
        assert pt["stable"] and pt["spectral_radius"] == pytest.approx(rho, rel=1e-6)
        assert_margins_are_python_controls(pt["actuators"], T, DT, f"sigma {sigma}: ")
    assert along["scheduled"]["worst"]["stable"]


def test_cli(capsys):
    """``flexlink control --integral TI --schedule N``: the run (--json: both laws' figures, the integral
    time, the margins along the path) and ``--design-only``."""
    from flexlink.cli import main

    base = ["control", str(SCENE), "--target", "60,90", "--duration", "1.5", "--torque-limit", "60",
            "--integral", "0.5", "--schedule", "3", "--json"]
    assert main(base) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["integral_time_s"] == 0.5 and doc["schedule"]["points"] == 3
    assert doc["scheduled"]["settling_time_s"] is not None
    for j, t in zip(JOINTS, (60.0, 90.0), strict=True):
        assert abs(doc["scheduled"]["joints"][j]["final_error_deg"]) < 0.1, t
    assert doc["robustness_along_path"]["scheduled"]["worst"]["stable"]
    assert len(doc["robustness_along_path"]["scheduled"]["points"]) == 4 * 3 - 3
    assert main([*base, "--design-only"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["robustness"]["lqg_integral"]["stable"] and doc["robustness_along_path"]["scheduled"]["worst"]["stable"]


def test_controller_fmu_equals_the_python_scheduled_integral_law(sched, example_fmu, tmp_path):
    """The controller FMU of the scheduled integral law (``ctrl_fmu.c``: ``SKD`` = K_x and ``SKI`` = K_ξ per
    design point, interpolated in C) passes fmpy's validation and ``flexlink check``, and with the plant FMU,
    stepped by fmpy, it equals the Python ``ScheduledIntegralLQGLaw`` to 1e-9 of every series' scale, with
    the constant disturbance of the test above (the integrators are exercised)."""
    from fmpy.validation import validate_fmu

    from controllers.export import FmuLaw, export_controller_fmu

    d, pl, s, si = sched
    settle = 1.5
    fmu = export_controller_fmu(d, tmp_path / "ctrl.fmu", schedule=s, duration=DURATION, integral=si)
    from flexlink.cli import main

    assert validate_fmu(str(fmu)) == []
    assert main(["check", str(fmu), "--report", str(tmp_path / "check")]) == 0
    ref = inverse_dynamics_reference(d.plant, pl, DT, DURATION, settle)
    law = ScheduledIntegralLQGLaw(si, [LIMIT, LIMIT], ref)
    ctrl = FmuLaw(fmu, law.W)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=["upper.tip.v", "fore.tip.v"]) as loop:
            a = loop.run(Biased(law), ref)
            b = loop.run(Biased(ctrl), ref)
    finally:
        ctrl.close()
    assert np.max(np.abs(law.xi)) > 1e-4
    worst = assert_runs_equal(a, b)
    print(f"\nlargest difference FMU - Python: {worst}")


def test_cli_exports_the_fmu_and_refuses_the_ssp(tmp_path, capsys):
    from flexlink.cli import main

    base = ["control", str(SCENE), "--design-only", "--torque-limit", "60", "--target", "60,90", "--duration", "1.5",
            "--integral", "0.5", "--schedule", "3"]
    assert main([*base, "--export-fmu", str(tmp_path / "c.fmu")]) == 0
    assert "scheduled at 3 poses with integral action" in capsys.readouterr().err
    assert main([*base, "--export-ssp", str(tmp_path / "s.ssp")]) == 2
    err = capsys.readouterr().err
    assert "SSP package of the scheduled LQG with integral action is not built yet" in err and err.count("\n") == 1
