"""The multi-joint LQG with the tip accelerometer (issue 16) through the FMU, on examples/two_link_payload.toml
(both joints torque-driven, 1.5 kg payload, no gravity): shoulder 0 → 60°, elbow −20° → 20° in 1.5 s.

* Open-loop replay of the feedforward: what the law expects to read at each sample along the reference
  (the model's outputs at the reference state, acceleration and the held feedforward torque) equals what
  the FMU outputs, to far below the accelerometer's noise; and the one-sample response of the FMU's
  accelerometer to a torque step equals the law's linearisation along the reference ``C_k B_k + D_k``
  (finite difference through the FMU, an SS22 step in C, not the CasADi Jacobians of the law).
* Closed loop, zero sensor noise: the Kalman innovation stays below the sensors' noise levels
  (``SENSOR_NOISE``) over the whole run, the joints reach their targets and the arm settles; the same
  manoeuvre with the strain-gauge LQG for comparison (both print their figures).
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest
from conftest import EXAMPLES

from controllers.cosim import FmuLoop
from controllers.design import SENSOR_NOISE, DesignError, sensor_kind
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, check_multijoint, inverse_dynamics_reference, plan, run
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SCENE = EXAMPLES / "two_link_payload.toml"
TARGETS = [math.radians(60.0), math.radians(20.0)]
DURATION, SETTLE, LIMIT = 1.5, 1.5, 60.0


@pytest.fixture(scope="module")
def rig(example_fmu):
    model = build_model(load_scene(SCENE))
    designs = {s: design(model, torque_limit=LIMIT, dt=1e-3, sensors=s) for s in ("accelerometer", "strain")}
    with FmuLoop(example_fmu("two_link_payload")) as loop:
        yield designs, loop


class Feedforward:
    """The feedforward torque alone, plus ``delta`` at sample ``at``; the law's innovation logged."""

    kind = "open"

    def __init__(self, law: MimoLQGLaw, delta=(0.0, 0.0), at: int = -1):
        self.law, self.delta, self.at = law, np.asarray(delta, dtype=float), at
        self.dt, self.sensors, self.inputs = law.dt, law.sensors, law.inputs
        self.k = 0

    def reset(self):
        self.k = 0

    def step(self, y, x_ref, u_ff):
        u = self.law.u0 + u_ff + (self.delta if self.k == self.at else 0.0)
        self.k += 1
        return u


def test_predicted_accelerometer_equals_the_fmu_along_the_reference(rig):
    designs, loop = rig
    d = designs["accelerometer"]
    assert d.kalman.sensors[-2:] == ["tip.sx", "tip.sy"]
    pl = plan(d.plant, TARGETS)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, DURATION, 0.0)
    law = MimoLQGLaw(d, [LIMIT, LIMIT], ref)
    sc = law.schedule
    assert sc is not None and sc.D.shape == (len(ref.time), 4, 2)
    base = loop.run(Feedforward(law), ref)
    sigma = np.array([SENSOR_NOISE[sensor_kind(s)] for s in law.sensors])
    for i, s in enumerate(law.sensors):
        err = np.max(np.abs(base[s] - sc.y_ref[:, i]))
        span = np.max(np.abs(base[s]))
        print(f"\n{s}: |FMU − h(x_ref, u_ff)| ≤ {err:.2e} over the manoeuvre (values up to {span:.3g})")
        # the open loop drifts from the reference by the feedforward's integration error only (cvodes vs SS22)
        assert err < 0.05 * sigma[i]
    assert np.max(np.abs(sc.y_ref[:, -1])) > 100 * sigma[-1]      # the reference's tip.sy is far from 0
    # one sample's response to a torque step at 0.64 s, where the rest pose's B_d mispredicts it (the rates
    # at the reference's speed feed the centripetal tip.sx): FMU finite difference against C_k B + D_k
    k0, h = 640, 0.05
    fmu, along, rest = (np.zeros((len(law.sensors), 2)) for _ in range(3))
    for j in range(2):
        delta = np.zeros(2)
        delta[j] = h
        kicked = loop.run(Feedforward(law, delta, k0), ref)
        fmu[:, j] = [(kicked[s][k0 + 1] - base[s][k0 + 1]) / h for s in law.sensors]
        along[:, j] = sc.C[k0 + 1] @ law.along.B[k0][:, j] + sc.D[k0 + 1][:, j]
        rest[:, j] = sc.C[k0 + 1] @ law.Bd[:, j] + sc.D[k0 + 1][:, j]
    e_along, e_rest = np.linalg.norm(fmu - along), np.linalg.norm(fmu - rest)
    print(f"one-sample response ∂y/∂τ (rows {law.sensors}, columns shoulder, elbow):\n"
          f" FMU {np.round(fmu, 4).tolist()}\n"
          f" along the reference {np.round(along, 4).tolist()} (error {e_along:.3g})\n"
          f" rest-pose A_d, B_d {np.round(rest, 4).tolist()} (error {e_rest:.3g})")
    assert e_along < 0.2 * e_rest and e_along < 0.06 * np.linalg.norm(fmu)


def test_accelerometer_lqg_reaches_the_targets_and_settles(rig):
    designs, loop = rig
    runs, innov = {}, {}
    for sensors, d in designs.items():
        check_multijoint(d)
        pl = plan(d.plant, TARGETS)
        ref = inverse_dynamics_reference(d.plant, pl, d.dt, DURATION, SETTLE)
        law = MimoLQGLaw(d, [d.lqr.torque_limits[j] for j in pl.joints], ref)
        log: list[np.ndarray] = []
        step = law.step

        def logged(y, x_ref, u_ff, law=law, step=step, log=log):
            M, C = law.matrices(law.k)[:2]
            log.append(np.asarray(y) - law.predicted(x_ref, C))
            return step(y, x_ref, u_ff)

        law.step = logged
        runs[sensors] = run(d, loop, pl, ref, law)
        sigma = np.array([SENSOR_NOISE[sensor_kind(s)] for s in law.sensors])
        ratio = np.abs(np.array(log)) / sigma
        n_move = int(round(DURATION / d.dt))
        innov[sensors] = {"move": ratio[: n_move + 1].max(axis=0), "p99": np.percentile(ratio, 99, axis=0),
                          "max": ratio.max(axis=0)}
    for sensors, res in runs.items():
        m = res.metrics
        ts = m["settling_time_s"]
        errors = [round(m["joints"][j]["final_error_deg"], 6) for j in ("shoulder", "elbow")]
        print(f"\n{sensors}: final errors {errors} deg, settling {ts} s, residual RMS "
              f"{m['residual_vibration_rms_m']:.3e} m, peak torques "
              f"{[round(m['joints'][j]['peak_torque_nm'], 2) for j in ('shoulder', 'elbow')]} N m; "
              f"|innovation| / noise σ per sensor ({', '.join(designs[sensors].kalman.sensors)}): max over the "
              f"manoeuvre {np.round(innov[sensors]['move'], 3)}, 99th percentile over the run "
              f"{np.round(innov[sensors]['p99'], 3)}, max {np.round(innov[sensors]['max'], 3)}")
        for j in ("shoulder", "elbow"):
            assert abs(m["joints"][j]["final_error_deg"]) < 1e-3
        assert ts is not None and ts < DURATION + SETTLE - 0.5
    # noise-free sensors: along the manoeuvre the accelerometer LQG expects what the FMU outputs, within the
    # sensors' noise; the reference's jump to rest at the manoeuvre's end (not a plant trajectory) is a few
    # samples' transient
    acc = innov["accelerometer"]
    assert np.all(acc["move"] < 1.0) and np.all(acc["p99"] < 1.0)
    # the same manoeuvre, the same final errors and settling as the strain-gauge LQG (noise-free: both estimate
    # the state; the torques differ only by the estimates' errors)
    a, s = runs["accelerometer"].metrics, runs["strain"].metrics
    assert a["settling_time_s"] == pytest.approx(s["settling_time_s"], abs=0.05)
    for j in ("shoulder", "elbow"):
        tau_a, tau_s = runs["accelerometer"][f"{j}.tau"], runs["strain"][f"{j}.tau"]
        print(f"{j}: max |τ_accelerometer − τ_strain| {np.max(np.abs(tau_a - tau_s)):.3g} N m")


def test_cli_runs_the_accelerometer_lqg_and_refuses_other_sensors(rig, capsys, tmp_path):
    """``flexlink control … --sensors accelerometer`` through the FMU; a sensor the run cannot read yet (a tip
    deflection) is refused with one message before anything runs (the controller FMU and SSP package with the
    accelerometer: tests/test_control_export_accel.py)."""
    from controllers.cli import add_control_parsers

    parser = argparse.ArgumentParser()
    add_control_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["control", str(SCENE), "--target", "60,20", "--duration", str(DURATION), "--torque-limit",
                              str(LIMIT), "--sensors", "accelerometer", "--json"])
    assert args.func(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["sensors"] == ["shoulder.theta", "elbow.theta", "tip.sx", "tip.sy"]
    assert doc["lqg"]["settling_time_s"] is not None and doc["robustness"]["lqg"]["stable"]
    designs, _ = rig
    d = design(designs["strain"].plant.model, torque_limit=LIMIT, dt=1e-3,
               sensors=["shoulder.theta", "elbow.theta", "fore.tip.v"])
    with pytest.raises(DesignError, match=r"sensors \['fore.tip.v'\]: the multi-joint run reads"):
        check_multijoint(d)


def test_scheduled_lqg_with_the_accelerometer(rig):
    """``--schedule``: the LQR gain scheduled over the path, the accelerometer read along the reference, on the
    larger travel that the fixed LQG cannot hold (elbow −20° → 90°, docs/control.md): both joints reach their
    targets and the arm settles."""
    from controllers.schedule import ScheduledLQGLaw, design_schedule

    designs, loop = rig
    d = designs["accelerometer"]
    targets = [math.radians(60.0), math.radians(90.0)]
    pl = plan(d.plant, targets)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, DURATION, SETTLE)
    law = ScheduledLQGLaw(design_schedule(d, pl, 3), [LIMIT, LIMIT], ref)
    assert law.along is not None
    m = run(d, loop, pl, ref, law).metrics
    errors = [m["joints"][j]["final_error_deg"] for j in ("shoulder", "elbow")]
    print(f"\nscheduled, accelerometer: final errors {errors} deg, settling {m['settling_time_s']} s")
    for j in ("shoulder", "elbow"):
        assert abs(m["joints"][j]["final_error_deg"]) < 1e-3
    assert m["settling_time_s"] is not None and m["settling_time_s"] < DURATION + SETTLE - 0.5
