"""Gain scheduling over the path (controllers.schedule) on examples/two_link_payload.toml: shoulder 0 → 60°,
elbow −20° → 90° in 1.5 s, the LQG designed at three poses along the path.

* at each design point the scheduled LQR gain is python-control's ``dlqr`` and the Kalman filter gain the
  one from python-control's ``dlqe``, both on the plant linearised there from a scene *built* with the
  joints' ``initial_angle`` at that pose (not from the model whose start values the schedule moves);
* the scheduled law's sampled loop with that independently linearised plant (built here with numpy, no
  python-control) has its poles inside the unit circle at each design point and halfway between; the
  fixed design's loop at the target pose has one outside (why scheduling is needed here);
* through the FMU the scheduled LQG ends the manoeuvre inside the settle band (joints within 0.1°, tips
  within 1 mm, read from the recorded series), the fixed one does not.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES, two_link_plant_at

from controllers.cosim import FmuLoop
from controllers.manoeuvre import design
from controllers.multijoint import inverse_dynamics_reference, plan
from controllers.schedule import compare_schedule, design_schedule
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SCENE = EXAMPLES / "two_link_payload.toml"
TARGETS = [math.radians(60.0), math.radians(90.0)]
DURATION, SETTLE, LIMIT, POINTS = 1.5, 1.5, 60.0, 3


@pytest.fixture(scope="module")
def sched():
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=1e-3)
    pl = plan(d.plant, TARGETS)
    return d, pl, design_schedule(d, pl, POINTS)


def built_at(pose: dict):
    """The example's scene with its joints' initial_angle at ``pose``, built and linearised afresh."""
    return two_link_plant_at(tuple(pose[j] for j in ("shoulder", "elbow")))


def torques(p):
    return [p.inputs.index(f"{j}.tau") for j in ("shoulder", "elbow")]


def sampled(p, dt):
    return ct.sample_system(ct.ss(p.sys.A, p.sys.B[:, torques(p)], np.eye(p.sys.nstates), 0), dt, method="zoh")


def loop_radius(p, dt, law) -> float:
    """The sampled loop of the law (M, C, K, A_d, B_d: current estimator, e = x − x_ref) with plant p,
    state (x, z) — z the law's prior estimate — its spectral radius (numpy eigenvalues)."""
    M, C, K, Ad, Bd = law
    sd = sampled(p, dt)
    Ap, Bp = np.asarray(sd.A), np.asarray(sd.B)
    Cp = p.sys.C[[p.output_row(s) for s in ("shoulder.theta", "elbow.theta", "upper.root.moment",
                                            "fore.root.moment")]]
    n = len(Ap)
    # x̂ = z + M (Cp x − C z);  u = −K x̂;  x⁺ = Ap x + Bp u;  z⁺ = Ad x̂ + Bd u
    Hx, Hz = M @ Cp, np.eye(n) - M @ C
    top = np.hstack([Ap - Bp @ K @ Hx, -Bp @ K @ Hz])
    bot = np.hstack([(Ad - Bd @ K) @ Hx, (Ad - Bd @ K) @ Hz])
    return float(np.max(np.abs(np.linalg.eigvals(np.vstack([top, bot])))))


def test_gains_at_each_point_are_python_controls_design(sched):
    d, pl, s = sched
    for sigma, pose in zip(s.sigma, s.poses, strict=True):
        p = built_at(pose)
        sd = sampled(p, d.dt)
        # Bryson's rule with the design's declared limits (0.5° per joint, 5 mm per tip, 6 N m per root)
        Cz = p.sys.C[[p.output_row(z) for z in d.lqr.limits]]
        Q = Cz.T @ np.diag([1 / v**2 for v in d.lqr.limits.values()]) @ Cz
        Kd, _, _ = ct.dlqr(sd, 0.5 * (Q + Q.T), np.eye(2) / LIMIT**2)
        M, C, K, Ad, Bd = s.matrices(float(sigma))
        np.testing.assert_allclose(K, Kd, rtol=1e-6, atol=1e-9 * np.max(np.abs(Kd)))
        np.testing.assert_allclose(Ad, sd.A, atol=1e-9 * np.max(np.abs(sd.A)))
        # Kalman: 3 N m (5 % of the limit) on each torque and each elastic coordinate's generalised force,
        # the sensors' declared noise; the filter gain P Cᵀ (C P Cᵀ + R)⁻¹ of python-control's dlqe
        n = p.model.n_q
        elastic = [k for k, c in enumerate(p.model.coordinates) if not c.endswith(".theta")]
        Minv = np.linalg.inv(p.mechanics.M)
        G = np.vstack([np.zeros((n, 2 + len(elastic))),
                       np.column_stack([p.sys.B[n:, torques(p)], Minv[:, elastic]])])
        Gd = ct.sample_system(ct.ss(p.sys.A, G, np.zeros((1, 2 * n)), 0), d.dt, method="zoh").B
        W = Gd @ Gd.T * (0.05 * LIMIT) ** 2
        RN = np.diag([d.kalman.noise[x] ** 2 for x in d.kalman.sensors])
        _, P, _ = ct.dlqe(sd.A, np.eye(2 * n), C, 0.5 * (W + W.T), RN)
        Mref = P @ C.T @ np.linalg.inv(C @ P @ C.T + RN)
        np.testing.assert_allclose(M, Mref, rtol=1e-5, atol=1e-7 * np.max(np.abs(Mref)))


def test_scheduled_loop_holds_every_pose_of_the_path(sched):
    d, pl, s = sched
    for sigma in np.linspace(0.0, 1.0, 2 * POINTS - 1):   # the design points and halfway between
        pose = {j: a + sigma * (b - a) for j, a, b in zip(pl.joints, pl.start, pl.target, strict=True)}
        p = built_at(pose)
        assert loop_radius(p, d.dt, s.matrices(float(sigma))) < 1.0, f"scheduled loop unstable at {pose}"
    fixed = (d.kalman.Md, d.kalman.C, d.lqr.Kd, np.asarray(d.lqr.plant_d.A), np.asarray(d.lqr.plant_d.B))
    assert loop_radius(p, d.dt, fixed) > 1.0                 # the start pose's design does not hold the target


def test_scheduled_settles_where_the_fixed_does_not(sched, example_fmu):
    d, pl, s = sched
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, DURATION, SETTLE)
    with FmuLoop(example_fmu("two_link_payload")) as loop:
        runs = compare_schedule(d, s, loop, pl, ref)

    def settled_at_end(res) -> bool:
        if isinstance(res, str):
            return False                                     # it left the beam model's validity
        sr, last = res.series, res.series["time"] >= DURATION + SETTLE - 0.1   # the last 0.1 s
        joints = all(np.all(np.abs(sr[f"{j}.theta"][last] - TARGETS[k]) < math.radians(0.1))
                     for k, j in enumerate(("shoulder", "elbow")))
        return joints and all(np.all(np.abs(sr[f"{lk}.tip.v"][last]) < 1e-3) for lk in ("upper", "fore"))

    assert settled_at_end(runs["scheduled"]) and not settled_at_end(runs["fixed"])
    for j in ("shoulder", "elbow"):
        assert np.max(np.abs(runs["scheduled"][f"{j}.tau"])) <= LIMIT + 1e-12
