"""Multi-joint (MIMO) LQR / Kalman design on a two-link arm, its loop-at-a-time margins, and the refusals.

The arm: two aluminium links (1 m, 0.7 kg/m, EI 2204 N m², two clamped-free modes each), rotors 0.1 and
0.05 kg m², a 1.5 kg payload, both joints torque-driven, no gravity (12 states), linearised at rest — no FMU.
The margins are checked against python-control applied here to loops built here from the plant's matrices
and the design's gains (not through controllers.robustness).
"""

from __future__ import annotations

import json
import math
import warnings

import control as ct
import numpy as np
import pytest

from controllers.closedloop import margins
from controllers.design import DesignError, bryson_weights, design_kalman, design_lqr
from controllers.manoeuvre import design
from flexlink.mechanics.model import build_model
from flexlink.run.linearize import linear_plant
from flexlink.scene.loader import load_scene, parse_scene

DT = 1e-3
LIMIT = 20.0


def two_link(elbow_drive: str = "torque") -> dict:
    def link(name, **kw):
        return {"name": name, "length": 1.0, "linear_density": 0.7, "EI": 2204.0, "deformation": ["v"],
                "shapes": {"kind": "clamped-free", "count": 2}, "kinematics": "second-order", **kw}

    return {"name": "two_link", "gravity": [0.0, 0.0, 0.0],
            "joint": [{"name": "shoulder", "axis": [0.0, 0.0, 1.0], "drive": "torque", "inertia": 0.1},
                      {"name": "elbow", "axis": [0.0, 0.0, 1.0], "drive": elbow_drive, "inertia": 0.05}],
            "link": [link("upper"), link("fore", payload={"mass": 1.5, "inertia": 0.0})]}


@pytest.fixture(scope="module")
def arm():
    return design(build_model(parse_scene(two_link())), torque_limit=LIMIT, dt=DT)


def _margins_of(L, w):
    """python-control's margins of a SISO loop from its frequency response on the grid w."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ct.stability_margins(ct.frd(L, w, smooth=True), returnall=True)


def test_lqr_and_kalman_on_every_joint(arm):
    p, lqr, kf = arm.plant, arm.lqr, arm.kalman
    assert arm.actuated_joints == ["shoulder", "elbow"] and lqr.inputs == ["shoulder.tau", "elbow.tau"]
    assert lqr.K.shape == lqr.Kd.shape == (2, 12)
    np.testing.assert_array_equal(lqr.R, np.diag([1 / LIMIT**2] * 2))
    assert lqr.limits == {"shoulder.theta": math.radians(0.5), "elbow.theta": math.radians(0.5),
                          "upper.tip.v": 5e-3, "upper.root.moment": 0.1 * LIMIT,
                          "fore.tip.v": 5e-3, "fore.root.moment": 0.1 * LIMIT}
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(p.sys.A - p.sys.B @ lqr.K)),
                               np.sort_complex(lqr.poles), rtol=1e-8)
    assert np.all(lqr.poles.real < 0) and np.all(np.abs(lqr.poles_d) < 1)
    assert kf.sensors == ["shoulder.theta", "elbow.theta", "upper.root.moment", "fore.root.moment"]
    assert kf.G.shape[1] == 2 + 4 and kf.Md.shape == (12, 4)      # two torques + four elastic coordinates
    assert np.all(kf.poles.real < 0) and np.all(np.abs(kf.poles_d) < 1)
    np.testing.assert_allclose(lqr.plant_d.A @ kf.Md, kf.Ld, rtol=1e-8, atol=1e-10)
    assert arm.pd is None
    with pytest.raises(Exception, match="one joint so far"):
        arm.law("lqr")
    # per joint and per link limits: R from the torque limits by joint, Q from the named outputs
    Q, R = bryson_weights(p, {"elbow.theta": 0.01, "fore.eta[1]": 0.002}, {"shoulder": 30.0, "elbow.tau": 10.0})
    np.testing.assert_array_equal(R, np.diag([1 / 900, 1 / 100]))
    x = np.zeros(12)
    x[p.state_index("elbow.theta")] = 0.01
    assert x @ Q @ x == pytest.approx(1.0)
    d2 = design_lqr(p, DT, {"shoulder": 30.0, "elbow": 10.0}, hub_error={"shoulder": 0.01, "elbow": 0.02},
                    tip_deflection={"fore": 1e-3}, root_moment={"upper": 5.0})
    assert d2.limits == {"shoulder.theta": 0.01, "elbow.theta": 0.02, "fore.tip.v": 1e-3, "upper.root.moment": 5.0}
    assert d2.torque_limits == {"shoulder": 30.0, "elbow": 10.0}


def test_lqr_margins_against_python_control(arm):
    """Loop broken at actuator i, the other closed: L_i = K_i (sI − A + B_o K_o)⁻¹ B_i, built here."""
    p, lqr = arm.plant, arm.lqr
    rob = arm.robustness()["lqr"]
    A, B, K = p.sys.A, p.sys.B, lqr.K
    w = np.logspace(-3, np.log10(10 * np.max(np.abs(lqr.poles))), 4000)
    for i, fig in enumerate(rob["actuators"]):
        o = [1 - i]
        L = ct.ss(A - B[:, o] @ K[o], B[:, [i]], K[[i]], 0)
        gm, pm, sm, wpc, wgc, wms = _margins_of(L, w)
        assert fig["phase_margin_deg"] == pytest.approx(np.min(np.abs(pm)), abs=1e-6)
        # at the reported crossover python-control's own L has |L| = 1 and the reported phase
        Lc = complex(np.squeeze(L(1j * 2 * np.pi * fig["gain_crossover_hz"])))
        assert abs(Lc) == pytest.approx(1.0, abs=1e-4)
        assert 180 + np.degrees(np.angle(Lc)) == pytest.approx(fig["phase_margin_deg"], abs=1e-3)
        # LQR's guarantees: ≥ 60° phase margin, no gain increase destabilises, |1 + L| ≥ 1 (to the grid)
        assert fig["phase_margin_deg"] >= 60 and fig["gain_margin_db"] == math.inf
        assert np.min(np.abs(1 + L(1j * w))) > 1 - 1e-9
        # the least |1 + L|: stability_margins' interior minima, or |1 + L(j∞)| = 1 (strictly proper)
        d_min = min(np.min(sm, initial=np.inf), 1.0)
        assert fig["peak_sensitivity"] == pytest.approx(1 / d_min, rel=1e-9)
    assert rob["stable"]
    np.testing.assert_allclose(np.sort_complex(rob["closed_loop_poles"]), np.sort_complex(lqr.poles), rtol=1e-6)


def test_lqg_margins_against_python_control(arm):
    """The sampled LQG loop built here from A, B (ZOH-sampled here), the sensors' C and the gains K_d, M_d
    (current estimator): margins at each actuator and closed-loop poles agree with controllers.robustness;
    the margins say stable and the closed-loop poles are inside the unit circle."""
    p, lqr, kf = arm.plant, arm.lqr, arm.kalman
    rob = arm.robustness()["lqg"]
    sd = ct.sample_system(ct.ss(p.sys.A, p.sys.B, np.eye(12), 0), DT, method="zoh")
    Ad, Bd = sd.A, sd.B
    C = p.sys.C[[p.output_row(s) for s in kf.sensors]]
    assert np.all(p.sys.D[[p.output_row(s) for s in kf.sensors]] == 0)      # encoders and strain gauges
    Kd, M = lqr.Kd, kf.Md
    F = np.eye(12) - M @ C
    Acl = Ad - Bd @ Kd
    w = np.logspace(-3, np.log10(np.pi / DT), 4000)[:-1]
    for i, fig in enumerate(rob["actuators"]):
        o = [1 - i]
        Ai = np.block([[Ad - Bd[:, o] @ Kd[o] @ M @ C, -Bd[:, o] @ Kd[o] @ F], [Acl @ M @ C, Acl @ F]])
        Bi = np.vstack([Bd[:, [i]], np.zeros((12, 1))])
        Ci = np.hstack([Kd[[i]] @ M @ C, Kd[[i]] @ F])
        L = ct.ss(Ai, Bi, Ci, 0, DT)
        gm, pm, sm, wpc, wgc, wms = _margins_of(L, w)
        up = gm[gm > 1]
        assert fig["gain_margin_db"] == pytest.approx(20 * np.log10(np.min(up)), abs=1e-6)
        assert fig["phase_margin_deg"] == pytest.approx(np.min(np.abs(pm)), abs=1e-6)
        z = np.exp(1j * 2 * np.pi * fig["phase_crossover_hz"] * DT)
        Lz = complex(np.squeeze(L(z)))
        assert abs(Lz.imag) < 1e-3 * abs(Lz) and Lz.real < 0
        assert -20 * np.log10(abs(Lz)) == pytest.approx(fig["gain_margin_db"], abs=1e-3)
        assert fig["gain_margin_db"] > 0 and fig["phase_margin_deg"] > 0
    # both loops closed, built here: x⁺ = A_d x − B_d K_d x̂, z⁺ = (A_d − B_d K_d) x̂, x̂ = F z + M C x
    Afull = np.block([[Ad - Bd @ Kd @ M @ C, -Bd @ Kd @ F], [Acl @ M @ C, Acl @ F]])
    poles = np.linalg.eigvals(Afull)
    assert rob["stable"] and np.max(np.abs(poles)) < 1
    np.testing.assert_allclose(np.sort_complex(rob["closed_loop_poles"]), np.sort_complex(poles), atol=1e-8)
    # separation principle: the LQR's and the estimator's poles
    got = np.asarray(rob["closed_loop_poles"])
    for q in np.concatenate([lqr.poles_d, kf.poles_d]):
        assert np.min(np.abs(got - q)) < 1e-6
    # peak sensitivity at the plant input, all loops: σ̄((I + K_c P)⁻¹) on the grid, from the same matrices
    Kc = ct.ss(Acl @ F, Acl @ M, -Kd @ F, -Kd @ M, DT)
    T = np.moveaxis(np.asarray(ct.series(ct.ss(Ad, Bd, C, 0, DT), Kc).frequency_response(w).complex), -1, 0)
    peak = np.max(np.linalg.svd(np.linalg.inv(np.eye(2) - T), compute_uv=False)[:, 0])
    assert rob["peak_sensitivity"] == pytest.approx(peak, rel=1e-3)


def test_single_joint_margins_are_the_laws(tmp_path):
    """On the one-joint link the MIMO machinery gives the SISO law's margins (controllers.closedloop)."""
    from conftest import EXAMPLES

    d = design(build_model(load_scene(EXAMPLES / "rotating_link.toml")), torque_limit=8.5, dt=DT)
    fig = d.robustness()["lqg"]["actuators"][0]
    ref = margins(d.plant, d.law("lqr"))
    assert fig["gain_margin_db"] == pytest.approx(ref["gain_margin_db"], abs=1e-3)
    assert fig["phase_margin_deg"] == pytest.approx(ref["phase_margin_deg"], abs=1e-3)
    assert fig["peak_sensitivity"] == pytest.approx(1 / ref["stability_margin"], rel=1e-3)


def test_refusals():
    free = linear_plant(parse_scene(two_link("free")))
    with pytest.raises(DesignError, match=r'torques of shoulder: the rigid-body mode \(0 Hz\), mostly elbow.theta — '
                                          r'joint "elbow" is not torque-driven \(drive = "free"\): it has no actuator'):
        design_lqr(free, DT, LIMIT)
    with pytest.raises(DesignError, match='joint "elbow" is not torque-driven'):
        design_lqr(free, DT, {"shoulder": 20.0, "elbow": 5.0})
    with pytest.raises(DesignError, match="'wrist' is not a joint"):
        design_lqr(free, DT, {"shoulder": 20.0, "wrist": 5.0})
    p = linear_plant(parse_scene(two_link()))
    with pytest.raises(DesignError, match=r"do not weigh the rigid-body mode \(0 Hz\), mostly elbow.theta"):
        design_lqr(p, DT, LIMIT, hub_error={"shoulder": 0.01})
    with pytest.raises(DesignError, match="no sensors"):
        design_kalman(p, DT, [])
    with pytest.raises(DesignError, match=r"sensors \(shoulder.theta\) do not see the rigid-body mode \(0 Hz\), "
                                          "mostly elbow.theta"):
        design_kalman(p, DT, ["shoulder.theta"])


def _toml(scene: dict) -> str:
    """The two-link scene dict as TOML (flat values, inline tables)."""

    def val(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + " }"
        return json.dumps(v)

    lines = [f"{k} = {val(v)}" for k, v in scene.items() if not isinstance(v, list) or k == "gravity"]
    for key in ("joint", "link"):
        for t in scene[key]:
            lines += [f"[[{key}]]"] + [f"{k} = {val(v)}" for k, v in t.items()]
    return "\n".join(lines) + "\n"


def test_cli(tmp_path, capsys):
    from flexlink.cli import main

    scene = tmp_path / "two_link.toml"
    scene.write_text(_toml(two_link()))
    assert main(["control", str(scene), "--design-only", "--torque-limit", str(LIMIT), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["actuated_joints"] == ["shoulder", "elbow"] and np.asarray(out["Kd"]).shape == (2, 12)
    for loop in ("lqr", "lqg"):
        r = out["robustness"][loop]
        assert [a["input"] for a in r["actuators"]] == ["shoulder.tau", "elbow.tau"] and r["stable"]
        assert len(r["closed_loop_poles"]) == (12 if loop == "lqr" else 24)
    assert out["robustness"]["lqr"]["actuators"][0]["gain_margin_db"] is None        # infinite
    # a run of a two-joint arm with one target, a passive joint: one line, exit status 2, before any FMU is built
    assert main(["control", str(scene), "--target", "30", "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "one angle per torque-driven joint (shoulder, elbow), got 1" in err and "Traceback" not in err
    assert err.count("\n") == 1
    scene.write_text(_toml(two_link("free")))
    assert main(["control", str(scene), "--design-only", "--torque-limit", "20"]) == 2
    err = capsys.readouterr().err
    assert 'joint "elbow" is not torque-driven' in err and "fewer modes" not in err and err.count("\n") == 1
