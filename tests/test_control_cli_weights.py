"""The LQR's weights from the command line (``--joint-error``, ``--tip-deflection``, ``--root-moment``,
``--mode-limit``, ``--torque-limit`` by name; docs/control.md).

The gains ``flexlink control --design-only --json`` reports are checked against python-control's own
``sample_system`` and ``dlqr`` on the plant linearised here, with Q and R built here by Bryson's rule from the
limits the options say (Q = C_zᵀ diag(1/z_max²) C_z over the named outputs, R = diag(1/u_max²)).  A heavier
joint-error weight must make the rigid-body poles faster, as LQR theory says for a double integrator:
ω_n = (q / r)^¼ / √J, so dividing the joint-error limit by 5 (q × 25) multiplies ω_n by about √5.  Bad names and
values are one line and exit status 2.
"""

from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES

from flexlink.cli import main
from flexlink.mechanics.model import build_model
from flexlink.run.linearize import linear_plant
from flexlink.scene.loader import load_scene

SCENE = str(EXAMPLES / "two_link_payload.toml")
DT = 1e-3


def design_json(capsys, *options: str) -> dict:
    assert main(["control", SCENE, "--design-only", "--json", *options]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def plant():
    return linear_plant(build_model(load_scene(SCENE)))


def bryson(plant, limits: dict[str, float], torque: list[float]):
    """Bryson's rule, written here from the plant's output rows (not controllers.design)."""
    rows = [plant.outputs.index(name) for name in limits]
    Cz = np.asarray(plant.C)[rows]
    Q = Cz.T @ np.diag([1.0 / v**2 for v in limits.values()]) @ Cz
    Q = 0.5 * (Q + Q.T)                    # symmetric up to rounding; python-control checks it exactly
    return Q, np.diag([1.0 / u**2 for u in torque])


def sampled(plant):
    """python-control's zero-order-hold sampling of the plant, the joint torques its inputs."""
    cols = [plant.inputs.index(n) for n in ("shoulder.tau", "elbow.tau")]
    return ct.sample_system(ct.ss(plant.A, np.asarray(plant.B)[:, cols], plant.C, np.asarray(plant.D)[:, cols]), DT)


def python_control_dlqr(plant, Q, R):
    sysd = sampled(plant)
    K, _, _ = ct.dlqr(sysd.A, sysd.B, Q, R)
    return np.asarray(K), sysd


def test_named_weights_give_python_controls_dlqr(capsys, plant):
    doc = design_json(capsys, "--torque-limit", "shoulder=60,elbow=40", "--joint-error", "shoulder=0.2",
                      "--tip-deflection", "fore=2", "--root-moment", "60,30", "--mode-limit", "upper.eta[1]=2e-3")
    limits = {"shoulder.theta": math.radians(0.2), "elbow.theta": math.radians(0.5),     # elbow: the default
              "upper.tip.v": 5e-3, "upper.root.moment": 60.0, "fore.tip.v": 2e-3, "fore.root.moment": 30.0,
              "upper.eta[1]": 2e-3}
    assert doc["bryson_limits"] == pytest.approx(limits, rel=1e-15)
    assert doc["torque_limits_nm"] == {"shoulder": 60.0, "elbow": 40.0}
    Q, R = bryson(plant, limits, [60.0, 40.0])
    np.testing.assert_allclose(doc["lqr_weights"]["Q"], Q, rtol=1e-12, atol=1e-12 * np.abs(Q).max())
    np.testing.assert_allclose(doc["lqr_weights"]["R"], R, rtol=1e-15)
    K, _ = python_control_dlqr(plant, Q, R)
    np.testing.assert_allclose(doc["Kd"], K, rtol=0, atol=1e-9 * np.abs(K).max())


def test_a_mode_limit_changes_the_gains_as_python_control_says(capsys, plant):
    base = design_json(capsys, "--torque-limit", "60")
    moded = design_json(capsys, "--torque-limit", "60", "--mode-limit", "fore=1e-4")
    limits = dict(base["bryson_limits"], **{"fore.eta[1]": 1e-4, "fore.eta[2]": 1e-4})
    assert moded["bryson_limits"] == pytest.approx(limits, rel=1e-15)
    K, _ = python_control_dlqr(plant, *bryson(plant, limits, [60.0, 60.0]))
    np.testing.assert_allclose(moded["Kd"], K, rtol=0, atol=1e-9 * np.abs(K).max())
    assert np.abs(np.asarray(moded["Kd"]) - base["Kd"]).max() > 1e-3 * np.abs(K).max()    # the weight acts


def rigid_pair(plant, Kd) -> float:
    """ω_n (rad/s) of the slowest closed-loop pair of the sampled LQR, from its z-plane poles (ln z / dt)."""
    sysd = sampled(plant)
    z = np.linalg.eigvals(sysd.A - sysd.B @ np.asarray(Kd))
    s = np.log(z.astype(complex)) / DT
    return float(np.sort(np.abs(s))[0])


def test_heavier_joint_error_weight_gives_faster_joint_poles(capsys, plant):
    base = design_json(capsys, "--torque-limit", "60")
    heavy = design_json(capsys, "--torque-limit", "60", "--joint-error", "0.1")
    w0, w1 = rigid_pair(plant, base["Kd"]), rigid_pair(plant, heavy["Kd"])
    print(f"\nslowest closed-loop pair: {w0:.4g} rad/s (0.5 deg), {w1:.4g} rad/s (0.1 deg), ratio {w1 / w0:.3f} "
          f"(double integrator: {math.sqrt(5):.3f})")
    assert w1 / w0 == pytest.approx(math.sqrt(5.0), rel=0.25)


@pytest.mark.parametrize("options, words", [
    (["--joint-error", "wrist=0.2"], "'wrist' is not a joint of the scene"),
    (["--tip-deflection", "lower=1"], "'lower' is not a link of the scene"),
    (["--mode-limit", "upper.eta[3]=1e-3"], "'upper.eta[3]' is not a mode of the model"),
    (["--joint-error", "0.1,0.2,0.3"], "one per item of the joints with an encoder"),
    (["--torque-limit", "shoulder=60"], "no limit for the torque-driven joint(s) elbow"),
    (["--torque-limit", "60", "--root-moment", "upper=0"], "expected a positive number"),
    (["--torque-limit", "60", "--joint-error", "shoulder=-1"], "expected a positive number"),
    (["--torque-limit", "60", "--mode-limit", "nan"], "expected a finite number"),
])
def test_bad_weights_are_one_line_and_status_2(capsys, options, words):
    opts = options if "--torque-limit" in options else ["--torque-limit", "60", *options]
    try:
        status = main(["control", SCENE, "--design-only", *opts])
    except SystemExit as e:                     # argparse's usage error: its own exit, status 2
        status = e.code
    assert status == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and len(err.strip().splitlines()) <= 2
