"""The fixed accelerometer LQG in the SSP package: why it diverged on some moves, and its refusal.

The SSP package's controller is predictive for the Jacobi master's sample of delay
(``controllers.ssp.PredictiveLQGLaw``).  With the accelerometers and the fixed LQR (no ``--schedule``) it
diverged on 10°/10° in 1 s and on 60°/20° in 1.5 s of examples/two_link_payload.toml, and held 60°/−30°.  What
this file shows:

* the cause is the fixed LQR itself: python-control's ZOH sampling of the plant linearised at the straight arm
  (a scene *built* with the joints' ``initial_angle`` there), closed with the design's K_d, has a pole outside
  the unit circle (≈ 1.19); at the bent poses of the 60°/−30° path it has none;
* the delayed loop diverges at that rate: the alternating part of the elbow torque (its second difference)
  grows per sample as the largest frozen spectral radius of A_k − B_k K_d along the reference says, to 10 %;
  the move that stays bent is not refused;
* so ``write_ssp`` / ``--export-ssp`` refuse the fixed accelerometer LQG on a path where that radius exceeds 1,
  in one line that names where and says to schedule it (``--schedule``) — a refusal, not a package that fails.
"""

from __future__ import annotations

import math
import tomllib

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES

from controllers.design import DesignError
from controllers.export import along_law, frozen_radius_along
from controllers.manoeuvre import design
from controllers.multijoint import inverse_dynamics_reference, plan
from controllers.ssp import JacobiDelay, JacobiLoop, PredictiveLQGLaw, write_ssp
from flexlink.errors import FlexlinkError
from flexlink.mechanics.model import build_model
from flexlink.run.linearize import linear_plant
from flexlink.scene.loader import load_scene, parse_scene

SCENE = EXAMPLES / "two_link_payload.toml"
LIMIT, DT = 60.0, 1e-3


@pytest.fixture(scope="module")
def accel():
    return design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=DT, sensors="accelerometer")


def frozen_radius(d, shoulder_deg: float, elbow_deg: float) -> float:
    """python-control: the spectral radius of the sampled plant at rest at that pose closed with K_d."""
    data = tomllib.loads(SCENE.read_text())
    for j, a in zip(data["joint"], (shoulder_deg, elbow_deg), strict=True):
        j["initial_angle"] = math.radians(a)
    p = linear_plant(build_model(parse_scene(data)))
    cols = [p.inputs.index(f"{j}.tau") for j in ("shoulder", "elbow")]
    sysd = ct.sample_system(ct.ss(p.A, np.asarray(p.B)[:, cols], np.eye(len(p.A)), 0), DT)
    return float(np.max(np.abs(ct.ss(sysd.A - sysd.B @ d.lqr.Kd, sysd.B, sysd.C, 0, DT).poles())))


def test_the_fixed_lqr_is_unstable_at_the_straight_arm(accel):
    straight, bent = frozen_radius(accel, 6.7, 0.0), frozen_radius(accel, 30.0, -30.0)
    print(f"\nfrozen spectral radius of the fixed LQR: straight arm {straight:.4f}, elbow -30 deg {bent:.4f}")
    assert straight > 1.1 and bent < 1.0


def alternating(u: np.ndarray) -> np.ndarray:
    """|u_k − 2 u_k−1 + u_k−2| / 4: the amplitude of a sample-to-sample (z = −1) oscillation."""
    return np.abs(u[2:] - 2 * u[1:-1] + u[:-2]) / 4


def test_the_delayed_loop_diverges_at_the_frozen_rate(accel, example_fmu, tmp_path):
    d = accel
    targets = [math.radians(10.0), math.radians(10.0)]
    ref = inverse_dynamics_reference(d.plant, plan(d.plant, targets), d.dt, 1.0, 0.5)
    radius, k_max = frozen_radius_along(d, along_law(d, ref, [LIMIT, LIMIT]))
    law = PredictiveLQGLaw(d, [LIMIT, LIMIT], ref)
    torques: list[np.ndarray] = []
    delayed = JacobiDelay(law, law.initial())
    step = delayed.step

    def recorded(y, x_ref, u_ff):
        u = step(y, x_ref, u_ff)
        torques.append(u)
        return u

    delayed.step = recorded                                     # type: ignore[method-assign]
    with JacobiLoop(example_fmu("two_link_payload")) as loop, pytest.raises(FlexlinkError, match="diverged"):
        loop.run(delayed, ref)
    a = alternating(np.asarray(torques)[:, 1])
    window = np.flatnonzero((a > 1e-3) & (a < 1.0))             # from above the noise floor to before saturation
    window = window[window > k_max - 200]
    rate = math.exp(np.polyfit(window, np.log(a[window]), 1)[0])
    print(f"\nlargest frozen radius along the path {radius:.4f} at t = {k_max * DT:.3f} s; the delayed loop's "
          f"alternating elbow torque grows {rate:.4f} per sample over samples {window[0]}-{window[-1]}")
    assert radius > 1.1 and rate == pytest.approx(radius, rel=0.1)
    with pytest.raises(DesignError, match=r"unstable along this path .*\(--schedule N\)"):
        write_ssp(d, example_fmu("two_link_payload"), tmp_path / "s.ssp", ref)


def test_cli_refuses_in_one_line(tmp_path, capsys):
    from flexlink.cli import main

    args = ["control", str(SCENE), "--design-only", "--torque-limit", "60", "--sensors", "accelerometer",
            "--target", "10,10", "--duration", "1", "--settle", "0.2", "--export-ssp", str(tmp_path / "s.ssp")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "the fixed LQR is unstable along this path" in err and "--schedule" in err and err.count("\n") == 1
    assert not (tmp_path / "s.ssp").exists()
