"""Delay-aware design: the controller FMU's one sample of computation delay (a Jacobi master such as
libcosim applies the torque one sample late) in the design's figures, on examples/two_link_payload.toml.

* the predictive LQG (``DELAY 1``, controllers.ssp.PredictiveLQGLaw) with the delay is the undelayed LQG:
  the closed-loop poles of the delayed loop, built here (plant augmented with the torque being applied,
  the predictive law's state space written out), are the sampled LQG's poles plus poles at the origin;
  without the prediction the delayed loop is unstable (python-control's ``feedback`` poles);
* the delayed loop's margins that controllers.robustness reports are python-control's ``stability_margins``
  of the loop broken at each actuator, built here;
* the reported gain margin holds on the FMU: the plant FMU with the Python predictive law delayed one
  sample (controllers.ssp.JacobiDelay), the shoulder's torque scaled by 0.95 and 1.05 × the critical gain,
  dies out and grows.
"""

from __future__ import annotations

import math
import warnings

import control as ct
import numpy as np
import pytest
from test_control_multijoint import LIMIT, SCENE

from controllers.cosim import FmuLoop
from controllers.manoeuvre import design
from controllers.robustness import delayed_robustness, lqg_compensator
from controllers.ssp import JacobiDelay, PredictiveLQGLaw
from controllers.trajectory import Reference
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene


@pytest.fixture(scope="module")
def arm():
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=1e-3)
    return d, delayed_robustness(d.lqr, d.kalman)


def _loop(d):
    """(plant with one sample of input delay, predictive compensator), written out here."""
    p, kf = d.plant, d.kalman
    Pc = ct.ss(p.sys.A, np.asarray(p.sys.B)[:, [p.inputs.index(u) for u in d.lqr.inputs]],
               np.asarray(p.sys.C)[[p.output_row(s) for s in kf.sensors]], 0)
    Pd = ct.sample_system(Pc, d.dt, method="zoh")
    A, B, C = np.asarray(Pd.A), np.asarray(Pd.B), np.asarray(Pd.C)
    n, m = B.shape
    # x⁺ = A x + B v, v⁺ = u (the torque applied a sample late)
    P = ct.ss(np.block([[A, B], [np.zeros((m, n + m))]]), np.vstack([np.zeros((n, m)), np.eye(m)]),
              np.hstack([C, np.zeros((len(C), m))]), 0, d.dt)
    # x̂ = z + M (y − C z); z⁺ = A x̂ + B w; u = −K z⁺; w⁺ = u   (state z, w)
    M, K = kf.Md, d.lqr.Kd
    Ahat = np.hstack([A @ (np.eye(n) - M @ C), B])
    Kc = ct.ss(np.vstack([Ahat, -K @ Ahat]), np.vstack([A @ M, -K @ A @ M]), -K @ Ahat, -K @ A @ M, d.dt)
    return P, Kc


def test_predictive_law_with_the_delay_is_the_undelayed_lqg(arm):
    d, rob = arm
    P, Kc = _loop(d)
    delayed = ct.feedback(P, Kc, sign=1).poles()
    p = d.plant
    Pd = ct.sample_system(ct.ss(p.sys.A, np.asarray(p.sys.B)[:, [p.inputs.index(u) for u in d.lqr.inputs]],
                                np.asarray(p.sys.C)[[p.output_row(s) for s in d.kalman.sensors]], 0), d.dt, "zoh")
    undelayed = ct.feedback(Pd, lqg_compensator(d.lqr, d.kalman), sign=1).poles()
    for q in undelayed:
        assert np.min(np.abs(delayed - q)) < 1e-8
    extra = np.sort(np.abs(delayed))[: len(delayed) - len(undelayed)]
    assert np.all(extra < 1e-8)                      # the delay's own poles, at the origin
    assert rob["lqg_delay1"]["stable"] and np.max(np.abs(delayed)) < 1
    np.testing.assert_allclose(np.sort(np.abs(rob["lqg_delay1"]["closed_loop_poles"])), np.sort(np.abs(delayed)),
                               atol=1e-8)
    unaware = ct.feedback(P, lqg_compensator(d.lqr, d.kalman), sign=1).poles()
    assert not rob["lqg_delay1_unaware"]["stable"] and np.max(np.abs(unaware)) > 1


def test_delayed_margins_against_python_control(arm):
    d, rob = arm
    P, Kc = _loop(d)
    T = ct.series(P, Kc)
    w = np.logspace(-3, np.log10(np.pi / d.dt), 4000)[:-1]
    for i, fig in enumerate(rob["lqg_delay1"]["actuators"]):
        E = np.diag([0.0 if j == i else 1.0 for j in range(2)])
        L = -ct.feedback(T, E, sign=1)[i, i]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gm, pm, *_ = ct.stability_margins(ct.frd(L, w, smooth=True), returnall=True)
        assert fig["gain_margin_db"] == pytest.approx(20 * np.log10(np.min(gm[gm > 1])), abs=1e-3)
        # python-control's signed figure: its magnitude is the phase change that destabilises, its sign the sense
        k = np.argmin(np.abs(pm))
        assert fig["phase_margin_deg"] == pytest.approx(abs(pm[k]), abs=1e-3)
        assert fig["phase_margin_sense"] == ("lag" if pm[k] > 0 else "lead")


class ScaledShoulder:
    """The delayed predictive law with the shoulder's torque deviation scaled by g on its way to the plant."""

    kind = "lqr"

    def __init__(self, law, g):
        self.law, self.g = law, g
        self.dt, self.sensors, self.inputs = law.dt, law.sensors, law.inputs
        self.u0 = law.law.u0

    def reset(self):
        self.law.reset()

    def step(self, y, x_ref, u_ff):
        u = self.law.step(y, x_ref, u_ff).copy()
        u[0] = self.u0[0] + self.g * (u[0] - self.u0[0])
        return u


def test_delayed_gain_margin_on_the_fmu(arm, example_fmu):
    d, rob = arm
    gm = rob["lqg_delay1"]["actuators"][0]["gain_margin_db"]
    crit = 10 ** (gm / 20)
    n = d.plant.sys.nstates
    N = 3000
    with FmuLoop(example_fmu("two_link_payload")) as loop:
        for g, stable in ((0.95 * crit, True), (1.05 * crit, False)):
            u_ff = np.zeros((N + 1, 2))
            u_ff[:5] = 1e-3
            ref = Reference("pulse", d.dt, 0.0, np.arange(N + 1) * d.dt, np.zeros((N + 1, n)), u_ff, 0)
            law = PredictiveLQGLaw(d, [1e6, 1e6], ref)
            try:
                res = loop.run(ScaledShoulder(JacobiDelay(law, law.initial()), g), ref,
                               parameters={"solver.step": 1e-4})
                u = np.abs(res["shoulder.tau"] - d.plant.u0[0])
                early, late = np.max(u[6:26]), np.max(u[-20:])
                grew = late > 10 * early
            except Exception as e:                    # grown out of the beam model's validity: grown
                assert "validity" in str(e), e
                early, late, grew = math.nan, math.inf, True
            print(f"\nshoulder gain x {g:.3f} (critical {crit:.3f}): |tau| {early:.3g} -> {late:.3g}")
            assert grew != stable
            if stable:
                assert late < 0.1 * early
