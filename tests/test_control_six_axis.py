"""The six-axis arm controlled on every joint (issue 16): examples/six_axis_arm_torque.toml, the robot-scale
issue's arm with its six joints torque-driven (elastic elbow, two flexible tubes, spherical wrist, payload,
gravity).

* the sampled LQG's margins at each of the six actuators and its closed-loop poles against python-control's
  own functions (``sample_system``, ``feedback``, ``stability_margins``) on the loop built here;
* the FMU's closed loop about the start pose (a small torque pulse on every joint, then hold) decays, as
  those poles say, and the decay is no faster than the slowest pole allows;
* the rest-to-rest manoeuvre of all six joints: the LQG reaches every target (the elastic elbow's link side
  too) and holds it with the torques that hold the arm against gravity there.
"""

from __future__ import annotations

import math
import warnings

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES

from controllers.cosim import FmuLoop
from controllers.design import torque_inputs
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, compare, plan
from controllers.trajectory import Reference
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SCENE = EXAMPLES / "six_axis_arm_torque.toml"
LIMITS = {"base": 20.0, "shoulder": 100.0, "elbow": 50.0, "wrist_roll": 4.0, "wrist_pitch": 8.0, "flange": 1.0}
DT = 1e-3
PULSE = 1e-3                 # N m on every joint for 5 ms: the loop stays linear


@pytest.fixture(scope="module")
def rig(example_fmu):
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMITS, dt=DT)
    with FmuLoop(example_fmu("six_axis_arm_torque")) as loop:
        yield d, loop


def _sampled_loop(d):
    """python-control's sampled plant (ZOH) from the actuated torques to the Kalman sensors, the sensors'
    rows C, and the matrices of the current estimator (F = I − M C, the LQR's A_d − B_d K_d)."""
    p, kf = d.plant, d.kalman
    C = np.asarray(p.sys.C)[[p.output_row(s) for s in kf.sensors]]
    plant = ct.ss(p.sys.A, np.asarray(p.sys.B)[:, [p.inputs.index(u) for u in d.lqr.inputs]], C, 0)
    Pd = ct.sample_system(plant, DT, method="zoh")
    return Pd, C, np.eye(p.sys.nstates) - kf.Md @ C, np.asarray(Pd.A) - np.asarray(Pd.B) @ d.lqr.Kd


def _compensator(d, C, F, Acl):
    """u = −K_d x̂, x̂ = F z + M y, z⁺ = (A_d − B_d K_d) x̂: a discrete state space from y to u."""
    M, K = d.kalman.Md, d.lqr.Kd
    return ct.ss(Acl @ F, Acl @ M, -K @ F, -K @ M, DT)


def test_margins_and_poles_against_python_control(rig):
    """The loop broken at each actuator with the other five closed, built here from python-control's
    sampled plant and the gains (state: plant x, estimator z): ``stability_margins`` gives the gain and
    phase margins that controllers.robustness reports; all loops closed, the poles of python-control's
    ``feedback`` of plant and compensator are the reported ones, inside the unit circle."""
    d, _ = rig
    rob = d.robustness()["lqg"]
    Pd, C, F, Acl = _sampled_loop(d)
    Ad, Bd, M, K = np.asarray(Pd.A), np.asarray(Pd.B), d.kalman.Md, d.lqr.Kd
    n, m = Ad.shape[0], len(d.lqr.inputs)
    assert d.actuated_joints == list(LIMITS) and m == 6
    w = np.logspace(-2, np.log10(np.pi / DT), 800)[:-1]
    for i, fig in enumerate(rob["actuators"]):
        o = [k for k in range(m) if k != i]
        Ai = np.block([[Ad - Bd[:, o] @ K[o] @ M @ C, -Bd[:, o] @ K[o] @ F], [Acl @ M @ C, Acl @ F]])
        L = ct.ss(Ai, np.vstack([Bd[:, [i]], np.zeros((n, 1))]), np.hstack([K[[i]] @ M @ C, K[[i]] @ F]), 0, DT)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gm, pm, sm, wpc, wgc, wms = ct.stability_margins(ct.frd(L, w, smooth=True), returnall=True)
        up = gm[gm > 1]
        if fig["gain_margin_db"] is None or not math.isfinite(fig["gain_margin_db"]):
            assert len(up) == 0
        else:
            assert fig["gain_margin_db"] == pytest.approx(20 * np.log10(np.min(up)), abs=1e-3)
        assert fig["phase_margin_deg"] == pytest.approx(np.min(np.abs(pm)), abs=1e-3)
        assert fig["phase_margin_deg"] > 0
    poles = ct.feedback(Pd, _compensator(d, C, F, Acl), sign=+1).poles()
    assert rob["stable"] and np.max(np.abs(poles)) < 1
    np.testing.assert_allclose(np.sort(np.abs(rob["closed_loop_poles"])), np.sort(np.abs(poles)), atol=1e-8)


def test_fmu_closed_loop_decays(rig):
    """Hold the start pose after a 5 ms pulse of every torque: through the FMU (its own SS22 step in C, the
    nonlinear spatial model) the torques' deviation dies out, as the poles of python-control's closed loop
    (inside the unit circle) say it must."""
    d, loop = rig
    Pd, C, F, Acl = _sampled_loop(d)
    radius = float(np.max(np.abs(ct.feedback(Pd, _compensator(d, C, F, Acl), sign=+1).poles())))
    assert radius < 1
    n, m = d.plant.sys.nstates, 6
    N = 2000
    u_ff = np.zeros((N + 1, m))
    u_ff[:5] = PULSE
    ref = Reference("pulse", DT, 0.0, np.arange(N + 1) * DT, np.zeros((N + 1, n)), u_ff, 0)
    law = MimoLQGLaw(d, [1e6] * m, ref)
    res = loop.run(law, ref)
    u0 = d.plant.u0[torque_inputs(d.plant)]
    dev = np.max(np.abs(np.column_stack([res[f"{j}.tau"] for j in d.actuated_joints]) - u0), axis=1)
    early, late = np.max(dev[6:50]), np.max(dev[-50:])
    print(f"\n|tau - tau0| after the pulse {early:.3g}, at {N} steps {late:.3g} N m; slowest pole {radius:.5f}")
    assert late < 0.01 * early


def test_rest_to_rest_of_all_six_joints(rig):
    """The manoeuvre of docs/control.md through the FMU: the LQG settles within 0.1° of every target (link
    side of the elastic elbow, whose motor ends ahead by the spring's static lag) and its final torques are
    the holding torques of the plan; the joint PD never uses more torque than the LQG did."""
    d, loop = rig
    targets = [math.radians(v) for v in (30, -20, 20, 30, -10, 45)]
    pl = plan(d.plant, targets)
    elbow = d.actuated_joints.index("elbow")
    assert d.plant.model.coordinates[pl.index[elbow]] == "elbow.motor_theta"
    assert abs(pl.drive_target[elbow] - targets[elbow]) > 1e-4          # gravity's torque through the spring
    runs = compare(d, loop, targets, 1.0, 1.0, pl=pl)
    lqg, pd = runs["lqr"].metrics, runs["pd"].metrics
    assert lqg["settling_time_s"] is not None and lqg["settling_time_s"] < 2.0
    for k, j in enumerate(d.actuated_joints):
        assert abs(lqg["joints"][j]["final_error_deg"]) < 1e-3
        assert runs["lqr"].series[f"{j}.tau"][-1] == pytest.approx(pl.u_end[k], abs=1e-3 * max(1, abs(pl.u_end[k])))
        assert pd["joints"][j]["peak_torque_nm"] <= lqg["joints"][j]["peak_torque_nm"] * (1 + 1e-9)
