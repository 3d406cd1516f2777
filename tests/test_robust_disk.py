"""Disk margins (issue 16): the balanced (skew 0) loop-at-a-time disk margin at each actuator that
``controllers.robustness.loop_at_a_time`` reports.

* an analytic loop built here, L(s) = k/(s(s + 1)): α = 1/max_ω |S(jω) − ½| from S's closed form (Seiler,
  Packard and Gahinet, "An introduction to disk margins", IEEE Control Systems 2020: the balanced disk
  margin is α = 1/‖(S − T)/2‖∞), maximised here with scipy; the disk's gain and phase margins from α alone,
  gains within [(2 − α)/(2 + α), (2 + α)/(2 − α)] and phases within ±2·atan(α/2);
* the two-link arm of tests/test_control_mimo.py: ``control.disk_margins`` called here on the sampled LQG
  loop broken at each actuator, built here from the plant's matrices and the gains.
"""

from __future__ import annotations

import math
import warnings

import control as ct
import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from test_control_mimo import DT, LIMIT, two_link

from controllers.manoeuvre import design
from controllers.robustness import DISK_SKEW, loop_at_a_time
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene


@pytest.mark.parametrize("k", [0.5, 4.0, 20.0])
def test_analytic_loop(k):
    """L = k/(s(s+1)) closed by u = −k y around P = 1/(s(s+1)): S = (s² + s)/(s² + s + k)."""
    def dist(w):                                           # |S(jω) − ½|, closed form
        s = 1j * w
        return abs((s * s + s) / (s * s + s + k) - 0.5)

    ws = np.logspace(-3, 1, 2001)
    w0 = ws[np.argmax([dist(w) for w in ws])]
    best = minimize_scalar(lambda w: -dist(w), bracket=(w0 / 1.01, w0, w0 * 1.01), tol=1e-12)
    alpha = 1.0 / dist(best.x)
    a = loop_at_a_time(ct.tf2ss([1.0], [1.0, 1.0, 0.0]), [[-k]], ["u"])["actuators"][0]
    assert DISK_SKEW == 0.0
    # the grid's minimum (4000 points from 1e-3 to 10x the largest pole, 10 rad/s), from the closed form
    grid = np.logspace(-3, 1, 4000)[:-1]
    on_grid = 1.0 / max(dist(w) for w in grid)
    assert a["disk_margin"] == pytest.approx(on_grid, rel=1e-9)
    # and the true one: the grid's minimum is above it by its resolution only (steps of 0.23 % in ω, the
    # peak of |S − ½| at k = 20 is a resonance of damping 0.11: 3e-5 relative)
    assert alpha <= a["disk_margin"] <= alpha * (1 + 1e-4)
    assert a["disk_margin_hz"] == pytest.approx(best.x / (2 * math.pi), rel=3e-3)
    alpha = a["disk_margin"]
    assert a["disk_gain_margin_db"] == pytest.approx(20 * math.log10((2 + alpha) / (2 - alpha)), rel=1e-9)
    assert a["disk_phase_margin_deg"] == pytest.approx(math.degrees(2 * math.atan(alpha / 2)), rel=1e-9)
    # the disk lies inside the classical margins: its gain margin below the (here infinite) gain margin,
    # its phase margin below the phase margin
    assert a["disk_phase_margin_deg"] <= a["phase_margin_deg"] + 1e-9


def test_two_link_against_python_control():
    """The sampled LQG of the two-link arm broken at each actuator, the other closed (as in
    tests/test_control_mimo.py), through ``control.disk_margins`` on the 4000-point grid up to Nyquist."""
    d = design(build_model(parse_scene(two_link())), torque_limit=LIMIT, dt=DT)
    p, lqr, kf = d.plant, d.lqr, d.kalman
    rob = d.robustness()["lqg"]
    sd = ct.sample_system(ct.ss(p.sys.A, p.sys.B, np.eye(12), 0), DT, method="zoh")
    Ad, Bd = sd.A, sd.B
    C = p.sys.C[[p.output_row(s) for s in kf.sensors]]
    Kd, M = lqr.Kd, kf.Md
    F = np.eye(12) - M @ C
    Acl = Ad - Bd @ Kd
    w = np.logspace(-3, np.log10(np.pi / DT), 4000)[:-1]
    assert rob["disk_skew"] == 0.0
    for i, fig in enumerate(rob["actuators"]):
        o = [1 - i]
        Ai = np.block([[Ad - Bd[:, o] @ Kd[o] @ M @ C, -Bd[:, o] @ Kd[o] @ F], [Acl @ M @ C, Acl @ F]])
        L = ct.ss(Ai, np.vstack([Bd[:, [i]], np.zeros((12, 1))]), np.hstack([Kd[[i]] @ M @ C, Kd[[i]] @ F]), 0, DT)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dm, dgm, dpm = ct.disk_margins(L, w, skew=0.0)
        assert fig["disk_margin"] == pytest.approx(dm, rel=1e-6)
        assert fig["disk_gain_margin_db"] == pytest.approx(dgm, rel=1e-6)
        assert fig["disk_phase_margin_deg"] == pytest.approx(dpm, rel=1e-6)
        # a disk margin is a guarantee for simultaneous gain and phase variations: never more than the
        # classical margins of the same loop
        assert 0 < fig["disk_gain_margin_db"] <= fig["gain_margin_db"] + 1e-9
        assert 0 < fig["disk_phase_margin_deg"] <= fig["phase_margin_deg"] + 1e-9
