"""Multi-joint closed loop through the FMU (issue 16, part 2) on examples/two_link_payload.toml: both joints
torque-driven, two clamped-free modes per link, 1.5 kg payload, no gravity.

* the feedforward is the model's inverse dynamics: applied open loop to the FMU it moves the joints along
  the quintic written here and the modal coordinates along the reference's;
* the MIMO LQG and the joint PD in closed loop: the figures the comparison reports hold on the recorded
  series (settling time, residual vibration, the PD's peak torque within the LQG's);
* the margins meet the FMU: with the gain of one actuator scaled below the gain margin that
  ``controllers.robustness`` reports the FMU's closed loop decays, above it it grows — the same verdicts as
  the closed-loop poles built here from the plant's matrices (python-control not involved in the FMU runs).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import EXAMPLES

from controllers.cosim import FmuLoop
from controllers.design import DesignError
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, compare, inverse_dynamics_reference, plan
from controllers.trajectory import Reference
from flexlink.errors import FlexlinkError
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SCENE = EXAMPLES / "two_link_payload.toml"
TARGETS = [math.radians(60.0), math.radians(20.0)]     # shoulder 0 → 60°, elbow −20° → 20°
DURATION, SETTLE, LIMIT = 1.5, 1.5, 60.0
PULSE = 1e-3                                           # N m, 5 ms: the unstable loop stays small (linear)


@pytest.fixture(scope="module")
def rig(example_fmu):
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=1e-3)
    with FmuLoop(example_fmu("two_link_payload")) as loop:
        yield d, loop


class OpenLoop:
    """Applies the feedforward alone (no feedback)."""

    kind = "open"

    def __init__(self, d, sensors):
        self.dt, self.sensors, self.inputs, self.u0 = d.dt, sensors, list(d.lqr.inputs), d.plant.u0.copy()

    def reset(self):
        pass

    def step(self, y, x_ref, u_ff):
        return self.u0 + u_ff


def test_feedforward_is_the_inverse_dynamics(rig):
    """Open loop through the FMU (SS22 in C, not the cvodes integration that made u_ff): the joints follow
    θ₀ + Δ(10τ³ − 15τ⁴ + 6τ⁵) and the modal coordinates the reference's, over the manoeuvre."""
    d, loop = rig
    pl = plan(d.plant, TARGETS)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, DURATION, 0.1)
    n_move = int(round(DURATION / d.dt))
    etas = ["upper.eta[1]", "upper.eta[2]", "fore.eta[1]", "fore.eta[2]"]
    res = loop.run(OpenLoop(d, ["shoulder.theta", "elbow.theta", *etas]), ref)
    t = res.time[: n_move + 1]
    tau = t / DURATION
    for k, (j, start) in enumerate((("shoulder", 0.0), ("elbow", -math.radians(20.0)))):
        quintic = start + (TARGETS[k] - start) * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
        assert np.max(np.abs(res[f"{j}.theta"][: n_move + 1] - quintic)) < 2e-4 * abs(TARGETS[k] - start)
    coords = d.plant.model.coordinates
    for e in etas:
        want = ref.x[: n_move + 1, coords.index(e)]
        assert np.max(np.abs(res[e][: n_move + 1] - want)) < 2e-3 * np.max(np.abs(want))
    assert np.all(ref.u_ff[n_move + 1:] == 0)       # no gravity: nothing to hold at rest


def test_lqg_against_joint_pd(rig):
    d, loop = rig
    runs = compare(d, loop, TARGETS, DURATION, SETTLE)
    lqg, pd = runs["lqr"], runs["pd"]
    for res in (lqg, pd):
        m, s = res.metrics, res.series
        t = s["time"]
        band = np.zeros(len(t), dtype=bool)
        for k, j in enumerate(("shoulder", "elbow")):
            err = s[f"{j}.theta"] - TARGETS[k]
            assert m["joints"][j]["final_error_deg"] == pytest.approx(math.degrees(err[-1]))
            band |= np.abs(err) > math.radians(0.1)
        after = t >= DURATION - 1e-12
        for lk in ("upper", "fore"):
            tip = s[f"{lk}.tip.v"]                  # no gravity: the static deflection at the target is 0
            assert m["links"][lk]["residual_vibration_rms_m"] == pytest.approx(np.sqrt(np.mean(tip[after] ** 2)))
            band |= np.abs(tip) > 1e-3
        ts = m["settling_time_s"]
        assert ts is not None and not np.any(band[t >= ts]) and band[t < ts][-1]
    # the PD never used more torque than the LQG did, joint by joint
    for j in ("shoulder", "elbow"):
        assert np.max(np.abs(pd[f"{j}.tau"])) <= np.max(np.abs(lqg[f"{j}.tau"])) + 1e-12
        assert np.max(np.abs(lqg[f"{j}.tau"])) <= LIMIT + 1e-12
        assert abs(lqg.metrics["joints"][j]["final_error_deg"]) < 1e-3
    assert lqg.metrics["settling_time_s"] < pd.metrics["settling_time_s"]
    print(f"\nsettling LQG {lqg.metrics['settling_time_s']:.3f} s, PD {pd.metrics['settling_time_s']:.3f} s; "
          f"residual RMS LQG {lqg.metrics['residual_vibration_rms_m']:.3e} m, PD "
          f"{pd.metrics['residual_vibration_rms_m']:.3e} m")


class ActuatorGain:
    """The LQG with actuator i's torque (deviation) scaled by g between the controller and the plant: the
    loop broken at that input, as the gain margin is defined; the estimator still sees the commanded torque."""

    kind = "lqr"

    def __init__(self, law, i, g):
        self.law, self.i, self.g = law, i, g
        self.dt, self.sensors, self.inputs = law.dt, law.sensors, law.inputs

    def reset(self):
        self.law.reset()

    def step(self, y, x_ref, u_ff):
        u = self.law.step(y, x_ref, u_ff).copy()
        u[self.i] = self.law.u0[self.i] + self.g * (u[self.i] - self.law.u0[self.i])
        return u


def _closed_loop_radius(d, i, g) -> float:
    """Spectral radius of the sampled LQG loop with input i scaled by g, built from A, B (ZOH here), the
    sensors' C and the gains K_d, M_d: x⁺ = A_d x + B_d G u, u = −K_d x̂, x̂ = (I − M C) z + M C x,
    z⁺ = (A_d − B_d K_d) x̂."""
    import scipy.linalg

    p, kf = d.plant, d.kalman
    n = p.sys.nstates
    Md_ = scipy.linalg.expm(np.block([[p.sys.A, p.sys.B], [np.zeros((2, n + 2))]]) * d.dt)
    Ad, Bd = Md_[:n, :n], Md_[:n, n:]
    C = p.sys.C[[p.output_row(s) for s in kf.sensors]]
    G = np.eye(2)
    G[i, i] = g
    F, M, K = np.eye(n) - kf.Md @ C, kf.Md, d.lqr.Kd
    A = np.block([[Ad - Bd @ G @ K @ M @ C, -Bd @ G @ K @ F], [(Ad - Bd @ K) @ M @ C, (Ad - Bd @ K) @ F]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


@pytest.mark.parametrize("i", [0, 1])
def test_gain_margin_against_the_fmu(rig, i):
    """Hold the start pose after a small 5 ms torque pulse on both joints, actuator i's gain scaled by g = 1,
    0.95 and 1.05 x the critical gain 10^(GM/20) that controllers.robustness reports (±0.45 dB about the
    margin): the FMU's torque at that actuator dies out (below a tenth of its size just after the pulse) or
    grows (tenfold).  A growing
    run lasts as long as the poles built here take to grow a thousandfold (the FMU leaves the beam model's
    validity beyond)."""
    d, loop = rig
    gm = d.robustness()["lqg"]["actuators"][i]["gain_margin_db"]
    assert math.isfinite(gm) and gm > 0
    crit = 10 ** (gm / 20)
    n = d.plant.sys.nstates
    j = d.actuated_joints[i]
    for g, stable in ((1.0, True), (0.95 * crit, True), (1.05 * crit, False)):
        r = _closed_loop_radius(d, i, g)
        assert (r < 1) == stable                      # the reported margin, against the poles built here
        N = 1500 if stable else 16 + math.ceil(math.log(1e3) / math.log(r))
        u_ff = np.zeros((N + 1, 2))
        u_ff[:5] = PULSE
        ref = Reference("pulse", d.dt, 0.0, np.arange(N + 1) * d.dt, np.zeros((N + 1, n)), u_ff, 0)
        law = ActuatorGain(MimoLQGLaw(d, [1e6, 1e6], ref), i, g)
        res = loop.run(law, ref, parameters={"solver.step": 1e-4})
        u = np.abs(res[f"{j}.tau"] - d.plant.u0[i])
        early, late = np.max(u[6:16]), np.max(u[-20:])
        print(f"\n{j} gain x {g:.3f} (critical {crit:.3f}, radius {r:.4f}): |tau| after the pulse {early:.3g}, "
              f"at the end ({N} steps) {late:.3g} N m")
        assert (late < 0.1 * early) if stable else (late > 10 * early)


def test_cli_multijoint(tmp_path, capsys):
    import argparse

    from controllers.cli import add_control_parsers

    parser = argparse.ArgumentParser()
    add_control_parsers(parser.add_subparsers(dest="command"))
    png = tmp_path / "mj.png"
    args = parser.parse_args(["control", str(SCENE), "--target", "60,20", "--duration", "1.5", "--torque-limit", "60",
                              "--json", "--plot", str(png)])
    assert args.func(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["joints"] == ["shoulder", "elbow"] and png.stat().st_size > 10_000
    for c in ("lqg", "pd"):
        assert {"settling_time_s", "residual_vibration_rms_m", "joints", "links"} <= set(doc[c])
    assert doc["robustness"]["lqg"]["stable"] and len(doc["robustness"]["pd"]["actuators"]) == 2
    assert doc["torque_limits_nm"] == {"shoulder": 60.0, "elbow": 60.0}          # the weights the run used
    assert doc["bryson_limits"]["elbow.theta"] == pytest.approx(math.radians(0.5), rel=1e-15)
    for bad, msg in ((["--target", "60"], "one angle per torque-driven joint"),
                     (["--target", "60,20", "--controller", "pd"], "--controller"),
                     (["--target", "60,20", "--torque-limit", "60,20,5"], "one per torque-driven joint")):
        args = parser.parse_args(["control", str(SCENE), "--duration", "1.5", "--torque-limit", "60", *bad])
        with pytest.raises((FlexlinkError, DesignError), match=msg):
            args.func(args)
    with pytest.raises(SystemExit):              # a non-positive limit: argparse's usage error (exit 2, one line)
        parser.parse_args(["control", str(SCENE), "--target", "60,20", "--torque-limit", "60,-1"])
    assert "--torque-limit: expected a positive number, got '-1'" in capsys.readouterr().err
