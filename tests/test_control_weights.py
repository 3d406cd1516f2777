"""The weights that give the two-link example a real margin at each actuator (docs/control.md): with every
link's root-moment Bryson limit at the torque limit (``--root-moment 60``) the sampled LQG's loop-at-a-time
margins are ≥ 6 dB gain and ≥ 30° phase at both torques; with the default (10 % of it) the elbow's gain
margin is below 6 dB.  The margins are python-control's (``stability_margins`` of the loop broken at one
torque, the other closed with ``feedback``), and agree with what ``flexlink control --design-only`` reports.
"""

from __future__ import annotations

import warnings

import control as ct
import numpy as np
from conftest import EXAMPLES

from controllers.manoeuvre import design
from controllers.robustness import lqg_compensator, lqg_plant
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

LIMIT = 60.0
GAIN_DB, PHASE_DEG = 6.0, 30.0          # the stated targets


def python_control_margins(d) -> list[tuple[float, float]]:
    """(gain margin dB upwards, phase margin deg) at each torque, loop at a time."""
    T = ct.series(lqg_plant(d.lqr, d.kalman), lqg_compensator(d.lqr, d.kalman))
    w = np.logspace(-3, np.log10(np.pi / d.dt), 4000)[:-1]
    out = []
    for i in range(2):
        E = np.diag([0.0 if j == i else 1.0 for j in range(2)])
        L = -ct.feedback(T, E, sign=1)[i, i]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gm, pm, *_ = ct.stability_margins(ct.frd(L, w, smooth=True), returnall=True)
        up = [g for g in np.atleast_1d(gm) if g > 1]
        out.append((20 * np.log10(min(up)) if up else np.inf, float(np.min(np.abs(pm)))))
    return out


def test_root_moment_at_the_torque_limit_meets_the_margin_targets():
    model = build_model(load_scene(EXAMPLES / "two_link_payload.toml"))
    default = design(model, torque_limit=LIMIT, dt=1e-3)
    chosen = design(model, torque_limit=LIMIT, dt=1e-3, root_moment=LIMIT)
    assert python_control_margins(default)[1][0] < GAIN_DB            # the elbow's, with the default weights
    margins = python_control_margins(chosen)
    reported = chosen.robustness()["lqg"]["actuators"]
    for (gm, pm), r in zip(margins, reported, strict=True):
        assert gm >= GAIN_DB and pm >= PHASE_DEG
        assert abs(r["gain_margin_db"] - gm) < 0.05 and abs(r["phase_margin_deg"] - pm) < 0.5
