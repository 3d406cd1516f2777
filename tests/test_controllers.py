"""controllers: LQR / Kalman / PD design on the linearised model, the references, the sampled laws and their
python-control closed loops (no FMU here; the FMU-in-the-loop runs are in test_control_fmu.py)."""

from __future__ import annotations

import math
from pathlib import Path

import control as ct
import numpy as np
import pytest
from conftest import make_link_scene

from controllers.closedloop import closed_loop, loop_transfer, margins, predict, sampled_plant
from controllers.design import bryson_weights, design_kalman, design_pd, rigid_pair, sensor_set
from controllers.laws import measurement_schedule
from controllers.manoeuvre import default_torque_limit, design, reference, rest_to_rest
from controllers.trajectory import min_jerk_feedforward, min_jerk_reference, quintic
from flexlink.errors import FlexlinkError
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DT = 1e-3
TARGET, DURATION, SETTLE = math.pi / 2, 1.5, 1.5


@pytest.fixture(scope="module")
def link():
    """The seed-000 link: design at 8.5 N m (1.5 x the rigid quintic's 5.4 N m peak)."""
    return design(build_model(load_scene(EXAMPLES / "rotating_link.toml")), torque_limit=8.5, dt=DT)


@pytest.fixture(scope="module")
def payload():
    return design(build_model(load_scene(EXAMPLES / "rotating_link_payload.toml")), torque_limit=23.0, dt=DT)


def test_default_torque_limit(link, payload):
    """Rigid inertias 0.1 + ρL³/3 = 1.339 and + m L² + J_p = 3.760 kg m²; the quintic's peak acceleration
    is 10/√3 · Δ/T² = 4.03 rad/s² for 90° in 1.5 s: 5.40 and 15.2 N m, × 1.5 rounded up to 0.5 N m."""
    assert link.pd.inertia == pytest.approx(0.1 + 0.349 * 2.2**3 / 3, rel=1e-12)
    assert payload.pd.inertia == pytest.approx(0.1 + 0.349 * 2.2**3 / 3 + 0.5 * 2.2**2 + 1e-3, rel=1e-12)
    assert default_torque_limit(link.plant, TARGET, DURATION) == 8.5
    assert default_torque_limit(payload.plant, TARGET, DURATION) == 23.0


def test_bryson_weights(link):
    limits = {"hub.theta": 0.01, "arm.tip.v": 0.005}
    Q, R = bryson_weights(link.plant, limits, 8.0)
    assert R[0, 0] == pytest.approx(1 / 64)
    x = np.zeros(8)
    x[0] = 0.01                               # the hub at its max error costs 1
    assert x @ Q @ x == pytest.approx(1.0)
    x = np.zeros(8)
    x[1] = 0.005 / link.plant.sys.C[link.plant.output_row("arm.tip.v"), 1]   # tip at its max deflection
    assert x @ Q @ x == pytest.approx(1.0)
    with pytest.raises(FlexlinkError, match="feedthrough"):
        bryson_weights(link.plant, {"tip.sy": 1.0}, 8.0)


def test_lqr_continuous_and_sampled(link):
    lqr = link.lqr
    assert lqr.K.shape == (1, 8) and lqr.Kd.shape == (1, 8)
    assert np.all(lqr.poles.real < 0) and np.all(np.abs(lqr.poles_d) < 1)
    np.testing.assert_allclose(np.linalg.eigvals(link.plant.sys.A - link.plant.sys.B @ lqr.K), lqr.poles, rtol=1e-8)
    # the sampled design is close to the continuous one at 1 ms for the slow poles
    s_d = np.log(lqr.poles_d.astype(complex)) / DT
    for p in sorted(lqr.poles, key=abs)[:4]:
        assert np.min(np.abs(s_d - p)) < 0.02 * abs(p)
    assert lqr.plant_d.dt == DT and isinstance(lqr.plant_d.sys, ct.StateSpace)   # python-control's on request
    wn, zeta = lqr.rigid_pair
    assert 1.0 < wn < 20.0 and 0.4 < zeta < 0.9


def test_pd_places_the_rigid_pair_exactly(link, payload):
    for d in (link, payload):
        wn, _ = d.lqr.rigid_pair
        target = wn * (-0.7 + 1j * math.sqrt(1 - 0.49))
        assert np.min(np.abs(d.pd.poles - target)) < 1e-8 * wn
        # rigid-link values kp = J ω², kd = 2ζωJ within the flexibility's correction
        assert d.pd.kp == pytest.approx(d.pd.inertia * wn**2, rel=0.3)
        assert d.pd.kd == pytest.approx(2 * 0.7 * wn * d.pd.inertia, rel=0.3)
        assert np.all(d.pd.poles.real < 0)
    with pytest.raises(FlexlinkError, match="non-positive gains"):
        design_pd(link.plant, 20.0)      # just above the first clamped mode (11.9 rad/s): no positive PD


def test_kalman_from_realistic_sensors(link):
    assert link.kalman.sensors == ["hub.theta", "arm.root.moment"]
    assert sensor_set(link.plant, "accelerometer") == ["hub.theta", "tip.sx", "tip.sy"]
    k = design_kalman(link.plant, DT, "accelerometer", torque_noise=0.4, elastic_noise=0.4)
    for kf in (link.kalman, k):
        assert np.all(kf.poles.real < 0) and np.all(np.abs(kf.poles_d) < 1)
        # current-estimator gain and predictor gain: L_d = A_d M_d
        np.testing.assert_allclose(link.lqr.plant_d.A @ kf.Md, kf.Ld, rtol=1e-8, atol=1e-10)
    assert k.noise["tip.sy"] == 0.05 and link.kalman.noise["hub.theta"] == pytest.approx(2 * math.pi / 16384 / 12**0.5)
    with pytest.raises(FlexlinkError, match="strain"):
        design_kalman(link.plant, DT, "sonar")


def test_quintic_and_min_jerk_feedforward():
    th, thd, thdd = quintic(np.array([0.0, 0.75, 1.5, 2.0]), 2.0, 1.5)
    np.testing.assert_allclose(th, [0, 1, 2, 2])
    np.testing.assert_allclose(thd, [0, 2 * 1.875 / 1.5, 0, 0], atol=1e-15)
    # on a rigid body J s², the minimum-jerk torque is the quintic's J θ̈ (to O(dt))
    J = 2.0
    rigid = ct.sample_system(ct.ss([[0, 1], [0, 0]], [[0], [1 / J]], np.eye(2), 0), DT)
    u = min_jerk_feedforward(rigid, [1.0, 0.0], 1500)
    t = (np.arange(1500) + 0.5) * DT
    assert np.max(np.abs(u - J * quintic(t, 1.0, 1.5)[2])) < 5e-3 * np.max(np.abs(u))


def test_min_jerk_reference_is_rest_to_rest(link, payload):
    for d in (link, payload):
        ref = min_jerk_reference(d.lqr.plant_d, 0, TARGET, DURATION, DURATION + SETTLE)
        n_move = round(DURATION / DT)
        x = np.zeros(8)
        for k in range(n_move):
            x = d.lqr.plant_d.A @ x + d.lqr.plant_d.B[:, 0] * ref.u_ff[k]
        expected = np.zeros(8)
        expected[0] = TARGET
        np.testing.assert_allclose(x, expected, atol=1e-9)
        assert abs(ref.u_ff[0]) < 1e-12 and abs(ref.u_ff[n_move - 1]) < 1e-12 and np.all(ref.u_ff[n_move:] == 0)
        # its peak torque is that of the rigid quintic within 2 %: the flexible modes cost almost nothing
        quintic_peak = d.pd.inertia * 10 / math.sqrt(3) * TARGET / DURATION**2
        assert np.max(np.abs(ref.u_ff)) == pytest.approx(quintic_peak, rel=0.02)


def test_law_statespace_is_the_stepped_law(link):
    """The python-control closed loop (interconnect + forced_response) and the law stepped sample by sample
    against the sampled plant give the same run, for both controllers."""
    outs = ["hub.theta", "arm.tip.v", "arm.root.moment"]
    P = sampled_plant(link.plant, DT, outs)
    for controller in ("lqr", "pd"):
        law = link.law(controller)
        law.torque_limit = 1e9                      # the python-control loop has no saturation
        ref = reference(link, controller, TARGET, DURATION, 0.5)
        pred = predict(link.plant, law, ref, outs)
        law.reset()
        x = np.zeros(P.nstates)
        th, us = [], []
        for k in range(len(ref.time)):
            y = np.asarray(link.plant.sys.C)[[link.plant.output_row(s) for s in law.sensors]] @ x[:8]
            u = law.step(y + law.y0, ref.x[k], ref.u_ff[k])
            th.append((P.C @ x)[0])
            us.append(u)
            x = P.A @ x + P.B[:, 0] * u
        np.testing.assert_allclose(th, pred["hub.theta"], atol=1e-10)
        np.testing.assert_allclose(us, pred["hub.tau"], atol=1e-8)


def test_closed_loop_poles_separation_principle(link):
    """python-control's closed-loop poles = LQR poles ∪ estimator poles (dlqr, dlqe)."""
    law = link.law("lqr")
    cl = closed_loop(link.plant, law, ["hub.theta"])
    assert isinstance(cl, ct.StateSpace) and cl.dt == DT
    expected = np.concatenate([link.lqr.poles_d, link.kalman.poles_d])
    got = cl.poles()
    assert len(got) == len(expected)
    for p in expected:
        assert np.min(np.abs(got - p)) < 1e-8


def test_accelerometer_feedthrough_is_sampled_with_the_previous_torque(link, payload):
    """With D ≠ 0 the plant seen by the master carries u_{k−1}: one extra state in the closed loop."""
    d = design(payload.plant.model, torque_limit=23.0, dt=DT, sensors="accelerometer")
    law = d.law("lqr")
    assert law.has_feedthrough
    P = sampled_plant(d.plant, DT, law.sensors)
    assert P.nstates == 9 and np.all(P.D == 0)
    cl = closed_loop(d.plant, law, ["hub.theta"])
    assert np.all(np.abs(cl.poles()) < 1)
    # At rest a torque gives the tip no instantaneous acceleration along the link (ż × r is normal to it):
    # D of tip.sx is 0.  Deflected, the tip frame is turned by the slope and the tip is off the link's
    # axis, so tip.sx picks up a feedthrough of the order of tip.sy's: the schedule must follow it.
    i, j = law.sensors.index("tip.sy"), law.sensors.index("tip.sx")
    assert law.D[j] == 0.0 and law.D[i] != 0.0
    ref = reference(d, "lqr", TARGET, DURATION, SETTLE)
    sc = measurement_schedule(d.plant, law.sensors, ref)
    assert np.max(np.abs(sc.D[:, j])) > 0.1 * abs(law.D[i])
    # ... and at the most deflected sample the schedule's (C, D) are the central differences of the
    # sensors computed independently: accelerations from a numerical solve of the residual, no AD
    k = int(np.argmax(np.abs(ref.x[:, 1])))
    x = d.plant.x0 + ref.x[k]
    u = d.plant.u0[0] + (ref.u_ff[k - 1] if k > 0 else 0.0)       # the torque held while y_k is sampled
    assert sc.u_ff_prev[k] == (ref.u_ff[k - 1] if k > 0 else 0.0)
    h = 1e-4
    fd_D = (_sensors_by_solve(d.plant, law.sensors, x, u + h) - _sensors_by_solve(d.plant, law.sensors, x, u - h))
    np.testing.assert_allclose(sc.D[k], fd_D / (2 * h), rtol=1e-6, atol=1e-9)
    e = np.eye(len(x))[1] * 1e-6
    fd_C = _sensors_by_solve(d.plant, law.sensors, x + e, u) - _sensors_by_solve(d.plant, law.sensors, x - e, u)
    np.testing.assert_allclose(sc.C[k][:, 1], fd_C / 2e-6, rtol=1e-5, atol=1e-6)
    assert measurement_schedule(link.plant, link.kalman.sensors, ref) is None   # encoder + strain: linear


def _sensors_by_solve(plant, sensors, x, tau):
    """The sensors at state x and torque tau: M from residual differences (exact, the residual is affine
    in the accelerations), the accelerations by numpy, then the outputs function."""
    model, p = plant.model, plant.op.p
    n = model.n_q
    u = np.array(plant.op.u, dtype=float).ravel()
    u[[k for k, s in enumerate(model.inputs) if s.fmu_variable][0]] = tau
    q, v = x[:n], x[n:]
    r0 = np.array(model.residual(q, v, np.zeros(n), u, p)).ravel()
    M = np.column_stack([np.array(model.residual(q, v, e, u, p)).ravel() - r0 for e in np.eye(n)])
    y = np.array(model.outputs_function(q, v, np.linalg.solve(M, -r0), u, p)).ravel()
    names = [s.name for s in model.outputs]
    return y[[names.index(s) for s in sensors]]


def test_margins(link, payload):
    for d in (link, payload):
        for controller in ("lqr", "pd"):
            m = margins(d.plant, d.law(controller))
            assert m["stable"]
            assert m["gain_margin_db"] > 6 and m["phase_margin_deg"] > 30 and m["stability_margin"] > 0.4
    L = loop_transfer(link.plant, link.law("lqr"))
    assert isinstance(L, ct.StateSpace) and L.ninputs == 1 and L.noutputs == 1


def test_rigid_pair_helper():
    wn, zeta = rigid_pair([-3 + 4j, -3 - 4j, -100 + 10j, -100 - 10j])
    assert wn == pytest.approx(5.0) and zeta == pytest.approx(0.6)
    wn, zeta = rigid_pair([-1.0, -4.0, -50.0])
    assert wn == pytest.approx(2.0) and zeta == pytest.approx(1.25)


def test_refuses_what_it_cannot_control(tmp_path):
    with pytest.raises(FlexlinkError, match="torque-driven"):
        design(EXAMPLES / "steel_beam_raise.toml", torque_limit=10.0)
    # gravity across the joint axis: the loads change along the manoeuvre (refused before the FMU is opened)
    scene = make_link_scene(drive="torque", hub_inertia=0.1, gravity=(0.0, -9.81, 0.0))
    d = design(build_model(scene), torque_limit=10.0)
    with pytest.raises(FlexlinkError, match="loads change"):
        rest_to_rest(d, tmp_path / "never_opened.fmu", TARGET, DURATION, SETTLE)
    with pytest.raises(FlexlinkError, match="multiple of the sample time"):
        rest_to_rest(d, tmp_path / "never_opened.fmu", TARGET, 1.2345, SETTLE)
    with pytest.raises(FlexlinkError, match="controller"):
        d.law("pid")


def test_lqr_gains_are_python_controls_on_the_plants_matrices(link, payload):
    """The LQR gains, continuous and sampled, are python-control's ``lqr``/``dlqr`` (SciPy's Riccati solvers)
    on a system built here from the plant's matrices: bit for bit, whether or not the plant's own
    python-control system (built on first use) went through anything else first."""
    for d in (link, payload):
        p = d.plant
        sys = ct.ss(p.A, p.B, p.C, p.D)
        K, S, E = ct.lqr(sys, d.lqr.Q, d.lqr.R, method="scipy")
        Kd, Sd, Ed = ct.dlqr(ct.sample_system(sys, DT, method="zoh"), d.lqr.Q, d.lqr.R, method="scipy")
        for ours, theirs in ((d.lqr.K, K), (d.lqr.S, S), (d.lqr.poles, E), (d.lqr.Kd, Kd), (d.lqr.Sd, Sd),
                             (d.lqr.poles_d, Ed)):
            assert np.array_equal(ours, theirs)
