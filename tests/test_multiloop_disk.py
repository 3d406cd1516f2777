"""The multi-loop (simultaneous) balanced disk margin at the plant input (issue 16,
``controllers.diskmargin``), against references that do not come from it:

* μ itself: for 2 and 3 scalar complex blocks μ is the maximum of ρ(M Q) over diagonal unitary Q; a brute
  force over Q's phases (a dense grid, then scipy's polish) gives it, and the D-scaled bound equals it;
* one actuator: the margin is the loop-at-a-time one, 1/max_ω|S − ½| from S's closed form for
  L = k/(s(s + 1)) (Seiler, Packard and Gahinet, IEEE Control Systems 2020), and python-control's
  ``control.disk_margins`` on the rotating link's sampled LQG (a dense grid around the peak);
* a decoupled diagonal plant: the smallest of its loops' closed-form margins;
* the destabilising perturbation, checked by eigenvalues: with the Δ returned at the reported frequency the
  perturbed closed loop (complex actuator factors f_i = (1 + δ_i/2)/(1 − δ_i/2), state matrix built here) has
  a pole on the unit circle / imaginary axis at that frequency, to 1e-6; every Δ 10 % smaller — that one
  scaled, and random ones with all |δ_i| = 0.9 α — leaves it stable;
* on the two-link arm: the simultaneous margin is at most every loop-at-a-time margin.
"""

from __future__ import annotations

import math
import warnings

import control as ct
import numpy as np
import pytest
from scipy.optimize import minimize, minimize_scalar
from test_control_mimo import DT, LIMIT, two_link

from controllers.design import torque_inputs
from controllers.diskmargin import disk_gain_phase, mu_lower, mu_upper
from controllers.manoeuvre import design
from controllers.robustness import loop_at_a_time, lqg_compensator, lqg_plant
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene


def analytic_alpha(k: float) -> float:
    """1/max_ω |S(jω) − ½| of L = k/(s(s + 1)), S = (s² + s)/(s² + s + k), maximised by scipy."""
    def dist(w):
        s = 1j * w
        return abs((s * s + s) / (s * s + s + k) - 0.5)

    ws = np.logspace(-3, 2, 20001)
    w0 = ws[np.argmax([dist(w) for w in ws])]
    best = minimize_scalar(lambda w: -dist(w), bracket=(w0 / 1.001, w0, w0 * 1.001), tol=1e-12)
    return 1.0 / dist(best.x)


def brute_mu(M: np.ndarray, n: int) -> float:
    """max over Q = diag(1, e^{jθ_1}, …) of ρ(M Q): a grid of n points per phase, then Nelder–Mead."""
    m = M.shape[0]
    grids = np.meshgrid(*[np.linspace(0, 2 * np.pi, n, endpoint=False)] * (m - 1), indexing="ij")
    th = np.stack([g.ravel() for g in grids], axis=-1)
    q = np.concatenate([np.ones((len(th), 1)), np.exp(1j * th)], axis=1)
    rho = np.max(np.abs(np.linalg.eigvals(M[None] * q[:, None, :])), axis=-1)
    k = int(np.argmax(rho))

    def neg(t):
        return -np.max(np.abs(np.linalg.eigvals(M * np.concatenate([[1.0], np.exp(1j * t)])[None, :])))

    return -minimize(neg, th[k], method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-15}).fun


@pytest.mark.parametrize("m,n", [(2, 20000), (3, 400)])
def test_mu_against_brute_force(m, n):
    rng = np.random.default_rng(m)
    for _ in range(5):
        M = rng.standard_normal((m, m)) + 1j * rng.standard_normal((m, m))
        mu = brute_mu(M, n)
        up, d = mu_upper(M)
        lo, delta = mu_lower(M)
        assert up == pytest.approx(mu, rel=1e-8)
        assert lo == pytest.approx(mu, rel=1e-8)
        # the bound is what its scaling gives, and the perturbation is singular at its size
        assert np.linalg.norm(d[:, None] * M / d[None, :], 2) == pytest.approx(up, rel=1e-12)
        assert abs(np.linalg.det(np.eye(m) - M @ np.diag(delta))) < 1e-10
        assert np.allclose(np.abs(delta), 1.0 / lo, rtol=1e-12)


@pytest.mark.parametrize("k", [0.5, 4.0, 20.0])
def test_one_actuator_is_the_loop_at_a_time_margin(k):
    r = loop_at_a_time(ct.tf2ss([1.0], [1.0, 1.0, 0.0]), [[-k]], ["u"])
    ml = r["multiloop"]
    assert ml["disk_margin"] == pytest.approx(analytic_alpha(k), rel=1e-9)
    assert ml["exact"] and ml["disk_margin_upper"] == pytest.approx(ml["disk_margin"], rel=1e-9)
    gm, pm = disk_gain_phase(ml["disk_margin"])
    assert (ml["disk_gain_margin_db"], ml["disk_phase_margin_deg"]) == (gm, pm)
    assert ml["disk_margin"] <= r["actuators"][0]["disk_margin"] * (1 + 1e-12)


def test_one_actuator_against_python_control():
    """The rotating link's sampled LQG (one joint): ``control.disk_margins`` on 2001 points between the grid
    neighbours of the reported frequency."""
    from conftest import EXAMPLES

    from flexlink.scene.loader import load_scene

    d = design(build_model(load_scene(EXAMPLES / "rotating_link.toml")), torque_limit=2.0, dt=1e-3)
    P, K = lqg_plant(d.lqr, d.kalman), lqg_compensator(d.lqr, d.kalman)
    r = loop_at_a_time(P, K)
    ml = r["multiloop"]
    f = ml["disk_margin_hz"] * 2 * np.pi
    w = np.linspace(f * 0.995, min(f * 1.005, np.pi / d.dt), 2001)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dm, dgm, dpm = ct.disk_margins(-ct.series(P, K), w, skew=0.0)
    assert ml["disk_margin"] == pytest.approx(dm, rel=1e-6)
    assert ml["disk_gain_margin_db"] == pytest.approx(dgm, rel=1e-6)
    assert ml["disk_phase_margin_deg"] == pytest.approx(dpm, rel=1e-6)


def test_decoupled_plant_is_its_smallest_loop():
    P = ct.append(ct.tf2ss([1.0], [1.0, 1.0, 0.0]), ct.tf2ss([1.0], [1.0, 1.0, 0.0]),
                  ct.tf2ss([1.0], [1.0, 1.0, 0.0]))
    ks = [0.5, 20.0, 4.0]
    ml = loop_at_a_time(P, -np.diag(ks))["multiloop"]
    assert ml["disk_margin"] == pytest.approx(min(analytic_alpha(k) for k in ks), rel=1e-9)
    assert ml["exact"]


def perturbed_radius(T: ct.StateSpace, delta: np.ndarray) -> np.ndarray:
    """The eigenvalues of the loop u = T u_p, u_p = F u, F = diag((1 + δ/2)/(1 − δ/2)) (complex)."""
    A, B, C, D = (np.asarray(X, dtype=float) for X in (T.A, T.B, T.C, T.D))
    F = np.diag((1 + delta / 2) / (1 - delta / 2))
    return np.linalg.eigvals(A + B @ np.linalg.solve(np.eye(len(delta)) - F @ D, F @ C))


@pytest.fixture(scope="module")
def arm():
    return design(build_model(parse_scene(two_link())), torque_limit=LIMIT, dt=DT)


@pytest.mark.parametrize("loop", ["lqg", "lqr"])
def test_the_perturbation_at_the_margin_destabilises(arm, loop):
    if loop == "lqg":
        T = ct.series(lqg_plant(arm.lqr, arm.kalman), lqg_compensator(arm.lqr, arm.kalman))
    else:
        B = np.asarray(arm.lqr.plant.sys.B)[:, torque_inputs(arm.plant)]
        T = ct.ss(arm.lqr.plant.sys.A, B, -np.asarray(arm.lqr.K), 0)
    ml = arm.robustness()[loop]["multiloop_margin"]
    assert ml.exact and ml.alpha == pytest.approx(ml.alpha_upper, rel=1e-9)
    assert np.allclose(np.abs(ml.delta), ml.alpha_upper, rtol=1e-12)
    ev = perturbed_radius(T, ml.delta)
    boundary = np.exp(1j * ml.omega * DT) if loop == "lqg" else 1j * ml.omega
    assert np.min(np.abs(ev - boundary)) < 1e-6 * max(1.0, abs(boundary))
    if loop == "lqg":
        assert np.max(np.abs(ev)) == pytest.approx(1.0, abs=1e-6)
        assert np.max(np.abs(perturbed_radius(T, 0.9 * ml.delta))) < 1.0
    else:
        assert np.max(ev.real) == pytest.approx(0.0, abs=1e-6 * ml.omega)
        assert np.max(perturbed_radius(T, 0.9 * ml.delta).real) < 0.0
    rng = np.random.default_rng(16)
    for _ in range(200):
        delta = 0.9 * ml.alpha * np.exp(2j * np.pi * rng.random(len(ml.delta)))
        ev = perturbed_radius(T, delta)
        assert (np.max(np.abs(ev)) < 1.0) if loop == "lqg" else (np.max(ev.real) < 0.0)


def test_two_link_simultaneous_below_every_loop(arm):
    for loop in ("lqr", "lqg"):
        r = arm.robustness()[loop]
        ml = r["multiloop"]
        assert 0 < ml["disk_margin"] <= min(a["disk_margin"] for a in r["actuators"])
        assert ml["disk_gain_margin_db"] <= min(a["disk_gain_margin_db"] for a in r["actuators"])
    print(f"\ntwo-link arm, sampled LQG: simultaneous {arm.robustness()['lqg']['multiloop']['disk_margin']:.4f}, "
          f"loop at a time {[round(a['disk_margin'], 4) for a in arm.robustness()['lqg']['actuators']]}")
    assert not math.isnan(arm.robustness()["lqg"]["multiloop"]["disk_margin_hz"])


def test_in_the_json_and_the_plot(arm):
    """``robustness_figures`` (the --json values) carries the simultaneous margin, and the plot's margin text
    has its line."""
    import json

    from controllers.plots import margins_text
    from controllers.robustness import robustness_figures

    fig = json.loads(json.dumps(robustness_figures(arm.robustness())))["lqg"]
    ml = arm.robustness()["lqg"]["multiloop_margin"]
    assert fig["multiloop"]["disk_margin"] == ml.alpha and fig["multiloop"]["exact"] is True
    assert fig["multiloop"]["disk_margin_hz"] == pytest.approx(ml.omega / (2 * np.pi), rel=1e-12)
    line = margins_text(fig).splitlines()[-1]
    assert line.startswith("all at once") and f"{ml.alpha:.3g}" in line


def test_an_unstable_loop_has_no_margin():
    """Positive feedback around 1/(s(s + 1)): a closed-loop pole at (−1 + √5)/2 > 0 for k = 1; no perturbation
    is needed, the margin is 0 (not the distance of the unstable loop's S to ½)."""
    r = loop_at_a_time(ct.tf2ss([1.0], [1.0, 1.0, 0.0]), [[1.0]], ["u"])
    assert not r["stable"] and np.max(r["closed_loop_poles"].real) == pytest.approx((math.sqrt(5) - 1) / 2)
    ml = r["multiloop"]
    assert (ml["disk_margin"], ml["disk_gain_margin_db"], ml["disk_phase_margin_deg"]) == (0.0, 0.0, 0.0)
