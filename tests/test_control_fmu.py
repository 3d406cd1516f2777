"""Closed loop through the FMU (fmpy FMU2Slave): LQR + Kalman against the joint PD baseline, agreement
with python-control's linear prediction, robustness to the payload mass, resets, the CLI and the demo.

Figures asserted here (90° rest-to-rest in 1.5 s, 1.5 s settle window, 1 ms sample time; torque limit
1.5 × the rigid quintic's peak: 8.5 N m for the seed-000 link, 23 N m with the 0.5 kg payload):

* LQR + Kalman (encoder + root strain gauge): |final error| < 0.01°, residual vibration ≥ 5× (in fact
  several hundred ×) smaller than the PD's;
* a 2° manoeuvre through the FMU matches the linear closed-loop prediction within 1e-3 of its amplitude;
* payload mass ±30 % (FMU parameter, no re-export): stable, margins ≥ 6 dB / 30°, target reached.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import control as ct
import numpy as np
import pytest

from controllers.closedloop import closed_loop
from controllers.cosim import FmuLoop, FmuLoopError
from controllers.manoeuvre import design, predict_manoeuvre, reference, rest_to_rest, stability_report
from flexlink.errors import FlexlinkError
from flexlink.export.cache import cached_fmu
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TARGET, DURATION, SETTLE, DT = math.pi / 2, 1.5, 1.5, 1e-3
CASES = {"rotating_link": 8.5, "rotating_link_payload": 23.0}


@pytest.fixture(scope="module")
def rigs():
    """Per scene: the design (scene values) and one FMU instance reused by every run (fmi2Reset)."""
    out = {}
    for name, limit in CASES.items():
        scene = load_scene(EXAMPLES / f"{name}.toml")
        model = build_model(scene)
        fmu = cached_fmu(scene, model=model)
        out[name] = (design(model, torque_limit=limit, dt=DT), FmuLoop(fmu), fmu)
    yield out
    for _, loop, _ in out.values():
        loop.close()


def _figures(res) -> str:
    m = res.metrics
    return (f"{res.controller}: final error {m['final_error_deg']:.2e} deg, residual RMS "
            f"{m['residual_vibration_rms_m']:.2e} m, peak torque {m['peak_torque_nm']:.2f} N m, "
            f"realtime x{m['realtime_factor']:.0f}")


@pytest.mark.parametrize("name", CASES)
def test_lqr_with_estimator_beats_pd(rigs, name):
    d, loop, _ = rigs[name]
    lqr = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr")
    pd = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "pd")
    print(f"\n{name}: {_figures(lqr)}\n{name}: {_figures(pd)}")
    assert abs(lqr.metrics["final_error_deg"]) < 0.01
    assert abs(pd.metrics["final_error_deg"]) < 1.0
    for r in (lqr, pd):
        assert r.metrics["peak_torque_nm"] <= d.torque_limit
    assert lqr.metrics["saturated_fraction"] == 0.0
    assert lqr.metrics["residual_vibration_rms_m"] * 5 <= pd.metrics["residual_vibration_rms_m"]
    assert lqr.metrics["residual_vibration_rms_m"] < 1e-3
    # the same torque limit, and a manoeuvre that needs most of it
    assert lqr.metrics["torque_limit_nm"] == pd.metrics["torque_limit_nm"] == CASES[name]
    assert lqr.metrics["peak_torque_nm"] > 0.5 * CASES[name]


def test_lqr_with_tip_accelerometer_and_sensor_noise(rigs):
    """Hub encoder + tip accelerometer (specific force in the tip frame), noisy sensors."""
    d0, loop, _ = rigs["rotating_link_payload"]
    d = design(d0.plant.model, torque_limit=d0.torque_limit, dt=DT, sensors="accelerometer")
    pd = rest_to_rest(d0, loop, TARGET, DURATION, SETTLE, "pd")
    for noise in (False, True):
        r = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr", noise=noise)
        print(f"\naccelerometer, noise {noise}: {_figures(r)}")
        assert abs(r.metrics["final_error_deg"]) < 0.05
        assert r.metrics["saturated_fraction"] == 0.0
        assert r.metrics["residual_vibration_rms_m"] * 5 <= pd.metrics["residual_vibration_rms_m"]
    r = rest_to_rest(d0, loop, TARGET, DURATION, SETTLE, "lqr", noise=True, seed=3)
    assert abs(r.metrics["final_error_deg"]) < 0.01
    assert r.metrics["residual_vibration_rms_m"] * 5 <= pd.metrics["residual_vibration_rms_m"]


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("controller", ["lqr", "pd"])
def test_small_manoeuvre_matches_linear_prediction(rigs, name, controller):
    """2°: the FMU in the loop and python-control's forced_response of the sampled closed loop agree
    within 1e-3 of the amplitude (hub angle, tip deflection) and 2e-3 (torque)."""
    d, loop, _ = rigs[name]
    target = math.radians(2.0)
    res = rest_to_rest(d, loop, target, DURATION, SETTLE, controller)
    pred = predict_manoeuvre(d, target, DURATION, SETTLE, controller)
    tip = np.max(np.abs(pred[f"{d.link}.tip.v"]))
    assert np.max(np.abs(res[f"{d.joint}.theta"] - pred[f"{d.joint}.theta"])) < 1e-3 * target
    assert np.max(np.abs(res[f"{d.link}.tip.v"] - pred[f"{d.link}.tip.v"])) < 1e-3 * tip
    assert np.max(np.abs(res["hub.tau"] - pred["hub.tau"])) < 2e-3 * np.max(np.abs(pred["hub.tau"]))


@pytest.mark.parametrize("name", CASES)
def test_closed_loop_poles_through_the_fmu(rigs, name):
    """Start the FMU 1 mrad off (parameter hub.initial_angle; small enough not to saturate the LQR) with the
    controller at rest at 0: the FMU's response is the closed loop's free response, i.e. python-control's
    initial_response from the same state — a sum of the modes of the poles python-control reports.

    The LQR's free response is a fast transient that excites the 34 Hz mode, where SS22 (Θ = ½, second
    order) at the default 1 ms step is off by a few 1e-3; four internal steps per sample (solver.step =
    0.25 ms) bring the FMU within 1e-3 of python-control for both controllers (16× closer: second order)."""
    d, loop, _ = rigs[name]
    offset = 1e-3
    for controller in ("lqr", "pd"):
        errors = []
        for step in (None, 2.5e-4):
            params = {"hub.initial_angle": offset, **({"solver.step": step} if step else {})}
            res = rest_to_rest(d, loop, 0.0, DURATION, SETTLE, controller, parameters=params)
            assert res.metrics["saturated_fraction"] == 0.0
            cl = closed_loop(d.plant, d.law(controller), [f"{d.joint}.theta", f"{d.link}.tip.v"])
            assert cl.state_labels[0] == f"plant_{d.joint}.theta" and np.all(np.abs(cl.poles()) < 1)
            x0 = np.zeros(cl.nstates)
            x0[0] = offset
            theta, tip, tau = np.asarray(ct.initial_response(cl, T=res["time"], X0=x0).outputs)[:3]
            errors.append(max(np.max(np.abs(res[f"{d.joint}.theta"] - theta)) / offset,
                              np.max(np.abs(res[f"{d.link}.tip.v"] - tip)) / np.max(np.abs(tip)),
                              np.max(np.abs(res["hub.tau"] - tau)) / np.max(np.abs(tau))))
        print(f"\n{name} {controller}: FMU vs python-control free response, max relative deviation "
              f"{errors[0]:.1e} (1 ms SS22 step), {errors[1]:.1e} (0.25 ms)")
        assert errors[0] < 1e-2 and errors[1] < 1e-3
        assert errors[1] < errors[0] / 10


@pytest.mark.parametrize("mass", [0.35, 0.65])
def test_payload_mass_plus_minus_30_percent(rigs, mass):
    """The nominal design (0.5 kg) on the FMU with arm.payload.mass changed, without re-export."""
    d, loop, _ = rigs["rotating_link_payload"]
    nominal = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr")
    res = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr", parameters={"arm.payload.mass": mass})
    pd = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "pd", parameters={"arm.payload.mass": mass})
    m = stability_report(d, "lqr", {"arm.payload.mass": mass})
    print(f"\npayload {mass} kg: {_figures(res)}; PD {pd.metrics['residual_vibration_rms_m']:.2e} m; margins "
          f"GM {m['gain_margin_db']:.1f} dB, PM {m['phase_margin_deg']:.1f} deg, min|1+L| {m['stability_margin']:.2f}")
    assert m["stable"] and m["gain_margin_db"] > 6 and m["phase_margin_deg"] > 30
    # the parameter reached the FMU: the run differs from the nominal one
    assert abs(res.metrics["max_tip_deflection_m"] / nominal.metrics["max_tip_deflection_m"] - 1) > 0.03
    assert abs(res.metrics["final_error_deg"]) < 0.5
    assert res.metrics["residual_vibration_rms_m"] < pd.metrics["residual_vibration_rms_m"]
    # stable in the FMU too: the deflection decays over the settle window
    t, tip = res["time"], res["arm.tip.v"]
    early, late = (t >= DURATION) & (t < DURATION + 0.5), t >= DURATION + SETTLE - 0.5
    assert np.sqrt(np.mean(tip[late] ** 2)) < 0.5 * np.sqrt(np.mean(tip[early] ** 2))


def test_reset_between_runs(rigs):
    d, loop, _ = rigs["rotating_link_payload"]
    a = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr")
    rest_to_rest(d, loop, -TARGET, DURATION, SETTLE, "pd", parameters={"arm.payload.mass": 0.65})
    c = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr")
    for name in ("hub.theta", "arm.tip.v", "hub.tau"):
        np.testing.assert_array_equal(a[name], c[name])


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("controller", ["lqr", "pd"])
def test_fast_loop_is_the_stepped_loop(rigs, name, controller):
    """The fast loop (the law's affine form, raw ctypes calls) gives the reference loop's run (``law.step``
    per sample through fmpy's functions) up to rounding, the saturated stretch of the manoeuvre included.

    Rounding is relative to the largest numbers the law adds: the LQR's ``K x_ref`` reaches 3 500 N m on the
    payload arm for a torque of 15 N m, so the torques agree to 1e-12 of that (measured: 2e-14 of it), the
    outputs to 1e-12 of their own size."""
    d, loop, _ = rigs[name]
    law = d.law(controller)
    ref = reference(d, controller, TARGET, DURATION, SETTLE)
    law.follow(ref)
    assert law.affine(ref) is not None
    slow, fast = loop.run(law, ref, fast=False), loop.run(law, ref, fast=True)
    assert slow.series.keys() == fast.series.keys()
    law_scale = np.max(np.abs(slow[law.input])) + np.max(np.abs(ref.x @ law.K[0]))
    for key, v in slow.series.items():
        scale = law_scale if key == law.input else max(1.0, np.max(np.abs(v)))
        np.testing.assert_allclose(fast[key], v, rtol=0, atol=1e-12 * scale, err_msg=key)
    # a saturating law: the clipped torque feeds the estimator the same way in both loops
    tight = d.law(controller)
    tight.torque_limit = 0.6 * np.max(np.abs(slow[tight.input]))
    tight.follow(ref)
    a, b = loop.run(tight, ref, fast=False), loop.run(tight, ref, fast=True)
    assert np.mean(np.abs(a[tight.input]) >= tight.torque_limit) > 0.01
    np.testing.assert_allclose(b[tight.input], a[tight.input], rtol=0, atol=1e-12 * law_scale)
    np.testing.assert_allclose(b["hub.theta"], a["hub.theta"], rtol=0, atol=1e-12 * 2)


@pytest.mark.parametrize("fast", [True, False])
def test_step_errors_are_reported_by_both_loops(rigs, fast):
    d, loop, _ = rigs["rotating_link"]
    ref = reference(d, "pd", TARGET, DURATION, SETTLE)
    with pytest.raises(FmuLoopError, match=r"step 0 \(t = 0 s\) failed \(fmi2DoStep failed with status 2"):
        loop.run(d.law("pd"), ref, parameters={"solver.step": 1e-12}, fast=fast)


def test_fmu_errors_are_reported(rigs):
    d, loop, _ = rigs["rotating_link"]
    with pytest.raises(FlexlinkError, match="not a parameter"):
        rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr", parameters={"arm.payload.mass": 0.6})
    with pytest.raises(FmuLoopError, match="solver.step|step"):
        loop.run(d.law("pd"), reference(d, "pd", TARGET, DURATION, SETTLE), parameters={"solver.step": -1.0})
    # and the instance is still usable afterwards
    r = rest_to_rest(d, loop, TARGET, DURATION, SETTLE, "lqr")
    assert abs(r.metrics["final_error_deg"]) < 0.01


def test_cli_control(tmp_path, monkeypatch, capsys):
    import argparse

    from controllers.cli import add_control_parsers

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    parser = argparse.ArgumentParser()
    add_control_parsers(parser.add_subparsers(dest="command"))
    scene = str(EXAMPLES / "rotating_link.toml")
    args = parser.parse_args(["control", scene, "--target", "90", "--duration", "1.5", "--json"])
    assert args.func(args) == 0
    m = json.loads(capsys.readouterr().out)
    assert {"final_error_deg", "residual_vibration_rms_m", "peak_torque_nm", "realtime_factor"} <= set(m)
    assert abs(m["final_error_deg"]) < 0.01 and m["torque_limit_nm"] == 8.5 and m["realtime_factor"] > 1
    png = tmp_path / "pd.png"
    args = parser.parse_args(["control", scene, "--target", "90", "--duration", "1.5", "--controller", "pd",
                              "--torque-limit", "8", "--settle", "1", "--plot", str(png)])
    assert args.func(args) == 0
    assert "residual vibration" in capsys.readouterr().out and png.stat().st_size > 10_000
    args = parser.parse_args(["control", scene, "--target", "90", "--duration", "1.5", "--settle", "0"])
    with pytest.raises(FlexlinkError, match="--settle"):
        args.func(args)


def test_demo(tmp_path, capsys):
    from controllers.demo import run_control_demo

    figures = run_control_demo(tmp_path)
    out = capsys.readouterr().out
    assert "LQR" in out and (tmp_path / "rotating_link_control.png").exists()
    assert figures["lqr"]["residual_vibration_rms_m"] * 5 <= figures["pd"]["residual_vibration_rms_m"]


@pytest.mark.parametrize("name, count", [("two_link_payload", 2), ("steel_beam_two_links", 0)])
def test_demo_on_a_scene_without_one_torque_joint_is_one_clear_error(tmp_path, name, count):
    """The demo compares LQR with the single-joint PD baseline: on a scene with two torque-driven joints (or
    none) it says so before building; two_link_payload used to be built, designed and then fail with an
    AttributeError on the missing PD design (found by mypy: ``ControlDesign.pd`` is None with several actuated
    joints)."""
    from controllers.demo import run_control_demo

    with pytest.raises(FlexlinkError, match=f"one torque-driven joint; this scene has {count} "):
        run_control_demo(tmp_path / "out", scene=EXAMPLES / f"{name}.toml")
    assert not (tmp_path / "out").exists()
