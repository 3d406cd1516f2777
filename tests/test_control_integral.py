"""Integral action on the joint positions (controllers.integral, issue 16) on examples/two_link_payload.toml.

* the augmented gains are python-control's ``dlqr`` on the plant sampled by ``sample_system`` and augmented
  here with the integrators of the joints' angle outputs (the plant's output rows, not the Kalman design's);
* the loop-at-a-time margins of the loop with the integrators against python-control's
  ``stability_margins`` of the loop broken at each torque built here;
* through the FMU, holding the start pose against a constant torque the model lacks (2 N m at the shoulder,
  −1 N m at the elbow): the LQG without integral action keeps the steady joint error that python-control's
  DC gain of its closed loop predicts; with it the error dies out as its slowest closed-loop pole allows;
* the rest-to-rest manoeuvre with the integral law settles on its targets; on the six-axis arm run with a
  heavier payload than designed for, the LQG ends off its targets and the integral LQG on them;
* ``flexlink control --integral`` and its refusals.
"""

from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES, BiasedLaw, assert_margins_are_python_controls

from controllers.cosim import FmuLoop
from controllers.design import DesignError
from controllers.integral import IntegralLQGLaw, design_integral, integral_compensator, integral_robustness
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, inverse_dynamics_reference, plan, run
from controllers.trajectory import Reference
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SCENE = EXAMPLES / "two_link_payload.toml"
DT, LIMIT, TI = 1e-3, 60.0, 0.5
JOINTS = ("shoulder", "elbow")
SENSORS = ("shoulder.theta", "elbow.theta", "upper.root.moment", "fore.root.moment")
BIAS = np.array([2.0, -1.0])                     # N m the model lacks, added between the law and the plant


@pytest.fixture(scope="module")
def rig():
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=DT)
    return d, design_integral(d, TI)


def sampled(p):
    """python-control's ZOH-sampled plant from the two torques to the Kalman sensors."""
    cols = [p.inputs.index(f"{j}.tau") for j in JOINTS]
    C = p.sys.C[[p.output_row(s) for s in SENSORS]]
    return ct.sample_system(ct.ss(p.sys.A, p.sys.B[:, cols], C, 0), DT, method="zoh")


def test_gains_are_python_controls_dlqr_on_the_augmented_plant(rig):
    d, integ = rig
    p = d.plant
    Pd = sampled(p)
    Ad, Bd = np.asarray(Pd.A), np.asarray(Pd.B)
    n = Ad.shape[0]
    Ce = p.sys.C[[p.output_row(f"{j}.theta") for j in JOINTS]]
    Aa = np.block([[Ad, np.zeros((n, 2))], [DT * Ce, np.eye(2)]])
    Ba = np.vstack([Bd, np.zeros((2, 2))])
    e_max = np.radians(0.5)                                     # the design's Bryson joint error
    Qa = np.zeros((n + 2, n + 2))
    Qa[:n, :n] = d.lqr.Q
    Qa[n:, n:] = np.eye(2) / (e_max * TI) ** 2
    K, _, E = ct.dlqr(Aa, Ba, Qa, d.lqr.R)
    scale = np.max(np.abs(K))
    assert np.max(np.abs(np.hstack([integ.Kx, integ.Ki]) - K)) < 1e-7 * scale
    assert np.max(np.abs(E)) < 1


def loop(d, Kc):
    """Torques applied → torques asked for: python-control's sampled plant then the compensator."""
    return ct.series(sampled(d.plant), Kc)


def test_margins_against_python_control(rig):
    d, integ = rig
    rob = integral_robustness(integ)
    T = loop(d, integral_compensator(integ))
    assert rob["stable"] and np.max(np.abs(ct.feedback(T, np.eye(2), sign=1).poles())) < 1
    assert_margins_are_python_controls(rob["actuators"], T, DT)


def Biased(law):
    return BiasedLaw(law, BIAS)


def test_constant_disturbance_through_the_fmu(rig, example_fmu):
    """Hold the start pose for 4 s against ``BIAS``.  Without integral action the final joint errors are the
    DC gain of python-control's closed loop (sampled plant with the bias at its input, the LQG compensator)
    times the bias; with it they fall below 20 ρ^N of that error (ρ the loop's slowest pole, N samples)."""
    d, integ = rig
    n, N = d.plant.sys.nstates, 4000
    ref = Reference("hold", DT, 0.0, np.arange(N + 1) * DT, np.zeros((N + 1, n)), np.zeros((N + 1, 2)), 0)
    M, C, K = d.kalman.Md, d.kalman.C, d.lqr.Kd
    Ad, Bd = np.asarray(d.lqr.plant_d.A), np.asarray(d.lqr.plant_d.B)
    F, Acl = np.eye(n) - M @ C, Ad - Bd @ K
    lqg = ct.ss(Acl @ F, Acl @ M, -K @ F, -K @ M, DT)
    # bias in → encoders out: the plant's input is the law's torque plus the bias
    closed = ct.feedback(sampled(d.plant), lqg, sign=1)
    expected = np.degrees((np.asarray(ct.dcgain(closed)) @ BIAS)[:2])
    T = loop(d, integral_compensator(integ))
    rho = float(np.max(np.abs(ct.feedback(T, np.eye(2), sign=1).poles())))
    start = np.array([d.plant.x0[d.plant.states.index(f"{j}.theta")] for j in JOINTS])
    with FmuLoop(example_fmu("two_link_payload")) as fl:
        errors = {}
        laws = {"lqg": MimoLQGLaw(d, [LIMIT, LIMIT], ref), "integral": IntegralLQGLaw(integ, [LIMIT, LIMIT], ref)}
        for name, law in laws.items():
            res = fl.run(Biased(law), ref)
            errors[name] = np.degrees(np.array([res[f"{j}.theta"][-1] for j in JOINTS]) - start)
    print(f"\nsteady errors (deg): LQG {errors['lqg']}, python-control {expected}; with integral action "
          f"{errors['integral']} (slowest pole {rho:.5f}, 20 rho^N = {20 * rho ** N:.2e})")
    assert errors["lqg"] == pytest.approx(expected, rel=2e-3)
    assert np.all(np.abs(errors["integral"]) < 20 * rho**N * np.abs(expected))


def test_manoeuvre_settles(rig, example_fmu):
    """The rest-to-rest manoeuvre of tests/test_control_multijoint.py (0 → 60°, −20° → 20° in 1.5 s, the
    shoulder saturating at 60 N m: the integrators hold) with the integral law: it settles (joints within
    0.1°, tips within 1 mm) and ends within 0.01° of its targets (the integrals of the manoeuvre's errors
    decay with T_i = 0.5 s: 3e-3° left after the 1.5 s settle)."""
    d, integ = rig
    targets = [math.radians(60.0), math.radians(20.0)]
    pl = plan(d.plant, targets)
    ref = inverse_dynamics_reference(d.plant, pl, DT, 1.5, 1.5)
    with FmuLoop(example_fmu("two_link_payload")) as fl:
        res = run(d, fl, pl, ref, IntegralLQGLaw(integ, [LIMIT, LIMIT], ref))
    m = res.metrics
    print(f"\nintegral LQG: settles at {m['settling_time_s']} s, final errors "
          f"{[m['joints'][j]['final_error_deg'] for j in JOINTS]} deg, residual "
          f"{m['links']['upper']['residual_vibration_rms_m']:.3e} m")
    assert m["settling_time_s"] is not None
    for j, t in zip(JOINTS, targets, strict=True):
        assert abs(res.series[f"{j}.theta"][-1] - t) < math.radians(1e-2)


def test_refusals(rig):
    d, _ = rig
    with pytest.raises(DesignError, match="integral time must be positive"):
        design_integral(d, 0.0)
    acc = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=DT, sensors="accelerometer")
    with pytest.raises(DesignError, match="accelerometers"):
        design_integral(acc)


SIX = EXAMPLES / "six_axis_arm_torque.toml"
SIX_LIMITS = {"base": 20.0, "shoulder": 100.0, "elbow": 50.0, "wrist_roll": 4.0, "wrist_pitch": 8.0, "flange": 1.0}


def test_six_axis_heavier_payload(example_fmu):
    """The six-axis arm (gravity) designed with its 2 kg payload and run with 3 kg (``tool.payload.mass``, an FMU
    parameter): the LQG ends off its targets (the payload's extra weight over the loop's stiffness), the LQG
    with integral action on them (a constant disturbance leaves no steady error under integral action)."""
    d = design(build_model(load_scene(SIX)), torque_limit=SIX_LIMITS, dt=DT)
    targets = [math.radians(v) for v in (30.0, -20.0, 20.0, 30.0, -10.0, 45.0)]
    pl = plan(d.plant, targets)
    ref = inverse_dynamics_reference(d.plant, pl, DT, 1.0, 1.5)
    limits = [SIX_LIMITS[j] for j in pl.joints]
    laws = {"lqg": MimoLQGLaw(d, limits, ref), "integral": IntegralLQGLaw(design_integral(d, TI), limits, ref)}
    final = {}
    with FmuLoop(example_fmu("six_axis_arm_torque")) as fl:
        for name, law in laws.items():
            m = run(d, fl, pl, ref, law, parameters={"tool.payload.mass": 3.0}).metrics
            final[name] = {j: m["joints"][j]["final_error_deg"] for j in pl.joints}
            print(f"\n{name}: settling {m['settling_time_s']} s, final errors (deg) "
                  + ", ".join(f"{j} {v:.3g}" for j, v in final[name].items()))
    assert max(abs(v) for v in final["lqg"].values()) > 0.1              # outside the settle band
    assert max(abs(v) for v in final["integral"].values()) < 0.01


def test_cli(tmp_path, capsys):
    """``flexlink control --integral TI``: the run (its LQG with integral action settles; ``--json`` carries
    the integral loop's margins as ``lqg_integral``, stable) and the refusals, each one message."""
    import argparse

    from controllers.cli import add_control_parsers
    from flexlink.errors import FlexlinkError

    parser = argparse.ArgumentParser()
    add_control_parsers(parser.add_subparsers(dest="command"))
    base = ["control", str(SCENE), "--target", "60,20", "--duration", "1.5", "--torque-limit", "60"]
    args = parser.parse_args([*base, "--integral", "0.5", "--json"])
    assert args.func(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["integral_time_s"] == 0.5 and doc["lqg"]["settling_time_s"] is not None
    assert doc["robustness"]["lqg_integral"]["stable"]
    assert len(doc["robustness"]["lqg_integral"]["actuators"]) == 2
    for bad, msg in ((["--integral", "0"], "must be a positive"),
                     (["--integral", "0.5", "--sensors", "accelerometer"], "accelerometers")):
        args = parser.parse_args([*base, *bad])
        with pytest.raises((FlexlinkError, DesignError), match=msg):
            args.func(args)
    one = ["control", str(EXAMPLES / "rotating_link.toml"), "--target", "30", "--duration", "1", "--integral", "0.5"]
    with pytest.raises(FlexlinkError, match="several torque-driven joints"):
        (args := parser.parse_args(one)).func(args)
