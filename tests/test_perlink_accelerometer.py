"""Per-link tip accelerometers (issue 16): the scene's ``sensors = ["accelerometer"]`` on a link adds the outputs
``<link>.tip.sx``, ``.sy``, ``.sz`` — the specific force (acceleration less gravity) at the link's tip, in its tip
frame, exact in the model (feedthrough from the torques).

* Scene: the key is read and refused as every key is (one SceneError naming it); without it the model has no
  such outputs (they cost generated code), with it they follow the link's own outputs.
* Analytic: a planar arm of two rigid uniform rods under gravity, moving, with torques: the FMU's accelerometers
  at the elbow (``upper.tip.s*``) and at the tip (``tip.s*``) against the textbook two-link dynamics (Spong,
  Hutchinson & Vidyasagar, *Robot Modeling and Control*, §7.4.2: M(q), Coriolis, gravity written out), the
  tip accelerations from the joint accelerations by hand.
* Flexible: the two-link payload arm, deflected by gravity (``initial_deformation = "static"``), moving, with
  torques: the FMU's elbow accelerometer at t = 0 against the second time-derivative of the model's elbow
  position along a trajectory integrated by CasADi's cvodes (central differences at four steps, converging as
  h², the extrapolated value to 1e-6 of the reading).
"""

from __future__ import annotations

import math
import re
import tomllib

import casadi as ca
import numpy as np
import pytest
from conftest import EXAMPLES

from flexlink.errors import SceneError
from flexlink.export.cache import cached_fmu
from flexlink.mechanics.assembly import ChainAssembly
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene

G0 = 9.81


def payload_arm(**changes) -> dict:
    """examples/two_link_payload.toml as a dict, its upper link carrying a tip accelerometer (at the elbow)."""
    data = tomllib.loads((EXAMPLES / "two_link_payload.toml").read_text())
    data["link"][0]["sensors"] = ["accelerometer"]
    data.update(changes)
    return data


def fmu_values(fmu, names: list[str], start: dict[str, float]) -> dict[str, float]:
    """The FMU's outputs right after initialisation (t = 0), its start values and inputs set (fmpy)."""
    import fmpy

    res = fmpy.simulate_fmu(str(fmu), stop_time=1e-3, output_interval=1e-3, start_values=start, output=names)
    return {n: float(res[n][0]) for n in names}


def test_sensors_key_is_read_and_refused_like_every_key():
    data = payload_arm()
    scene = parse_scene(data)
    assert [lk.sensors for lk in scene.links] == [("accelerometer",), ()]
    names = [s.name for s in build_model(scene).outputs]
    plain = [s.name for s in build_model(parse_scene(tomllib.loads((EXAMPLES / "two_link_payload.toml")
                                                                   .read_text()))).outputs]
    added = [n for n in names if n not in plain]
    assert added == ["upper.tip.sx", "upper.tip.sy", "upper.tip.sz"]
    # right after the upper link's own outputs, before the elbow's: value references by link
    assert names.index("upper.tip.sx") == names.index("upper.eta[2]") + 1
    assert names.index("upper.tip.sz") + 1 == names.index("elbow.theta")
    for bad, where in ((["gyroscope"], "link[1].sensors[1]"), ("accelerometer", "link[1].sensors"),
                       (["accelerometer", "accelerometer"], "link[1].sensors[2]")):
        data["link"][0]["sensors"] = bad
        with pytest.raises(SceneError, match=re.escape(where) + ": expected"):
            parse_scene(data)
    # a rigid link carries one too
    rigid = rigid_arm()
    assert parse_scene(rigid).links[0].sensors == ("accelerometer",)


# ------------------------------------------------------------------------------------------------ analytic

L1, L2, RHO1, RHO2 = 0.8, 0.6, 2.0, 1.5       # m, kg/m: uniform rods


def rigid_arm() -> dict:
    """Two rigid uniform rods, torque-driven about z, gravity −y; no rotor inertia (the textbook arm)."""
    joint = {"axis": [0.0, 0.0, 1.0], "drive": "torque"}
    return {"name": "rigid_two_link", "gravity": [0.0, -G0, 0.0],
            "joint": [dict(joint, name="shoulder"), dict(joint, name="elbow")],
            "link": [{"name": "upper", "length": L1, "linear_density": RHO1, "deformation": [],
                      "sensors": ["accelerometer"]},
                     {"name": "fore", "length": L2, "linear_density": RHO2, "deformation": []}]}


def textbook_acceleration(q, qd, tau) -> np.ndarray:
    """q̈ of the planar two-link arm, Spong et al. §7.4.2 (masses m_i, centres lc_i = L_i/2, I_i = m_i L_i²/12)."""
    m1, m2 = RHO1 * L1, RHO2 * L2
    lc1, lc2, I1, I2 = L1 / 2, L2 / 2, m1 * L1**2 / 12, m2 * L2**2 / 12
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    m12 = m2 * (lc2**2 + L1 * lc2 * c2) + I2
    M = np.array([[m1 * lc1**2 + m2 * (L1**2 + lc2**2 + 2 * L1 * lc2 * c2) + I1 + I2, m12],
                  [m12, m2 * lc2**2 + I2]])
    h = -m2 * L1 * lc2 * s2
    coriolis = np.array([h * (2 * qd[0] * qd[1] + qd[1] ** 2), -h * qd[0] ** 2])
    c1, c12 = math.cos(q[0]), math.cos(q[0] + q[1])
    gravity = np.array([(m1 * lc1 + m2 * L1) * G0 * c1 + m2 * lc2 * G0 * c12, m2 * lc2 * G0 * c12])
    return np.linalg.solve(M, np.asarray(tau) - coriolis - gravity)


def specific_force(angle: float, a_world: np.ndarray) -> np.ndarray:
    """What an accelerometer turned by ``angle`` about z reads: Rᵀ (a − g)."""
    c, s = math.cos(angle), math.sin(angle)
    f = a_world - np.array([0.0, -G0])
    return np.array([c * f[0] + s * f[1], -s * f[0] + c * f[1]])


def test_rigid_two_link_accelerometers_equal_the_textbook_dynamics():
    fmu = cached_fmu(parse_scene(rigid_arm()))
    names = ["upper.tip.sx", "upper.tip.sy", "upper.tip.sz", "tip.sx", "tip.sy", "tip.sz"]
    for q, qd, tau in (((0.0, 0.0), (0.0, 0.0), (0.0, 0.0)),           # at rest: gravity alone, +g upwards
                       ((0.4, -0.9), (1.5, -2.0), (6.0, -1.5)),
                       ((-1.2, 2.1), (-3.0, 4.0), (-2.0, 3.0))):
        start = {"shoulder.initial_angle": q[0], "elbow.initial_angle": q[1], "shoulder.initial_rate": qd[0],
                 "elbow.initial_rate": qd[1], "shoulder.tau": tau[0], "elbow.tau": tau[1]}
        got = fmu_values(fmu, names, start)
        qdd = textbook_acceleration(q, qd, tau)
        e1, n1 = np.array([math.cos(q[0]), math.sin(q[0])]), np.array([-math.sin(q[0]), math.cos(q[0])])
        q12, w12, a12 = q[0] + q[1], qd[0] + qd[1], qdd[0] + qdd[1]
        e12, n12 = np.array([math.cos(q12), math.sin(q12)]), np.array([-math.sin(q12), math.cos(q12)])
        elbow = L1 * (qdd[0] * n1 - qd[0] ** 2 * e1)
        tip = elbow + L2 * (a12 * n12 - w12**2 * e12)
        for prefix, angle, a in (("upper.tip", q[0], elbow), ("tip", q12, tip)):
            expected = specific_force(angle, a)
            measured = np.array([got[f"{prefix}.sx"], got[f"{prefix}.sy"]])
            print(f"\nq {q}, q̇ {qd}, τ {tau}: {prefix}.s(x, y) FMU {measured.round(6)}, textbook {expected.round(6)}")
            assert measured == pytest.approx(expected, abs=1e-9 * max(1.0, np.max(np.abs(expected))))
            assert got[f"{prefix}.sz"] == pytest.approx(0.0, abs=1e-12)


# ------------------------------------------------------------------------------------------------ flexible


def _flow(model, u: np.ndarray, p: np.ndarray, backwards: bool) -> ca.Function:
    """cvodes on the model's own equations r(q, q̇, q̈, u) = 0, q̈ eliminated through the mass matrix."""
    n = model.n_q
    res = model.residual.expand()
    q, v, a = ca.SX.sym("q", n), ca.SX.sym("v", n), ca.SX.sym("a", n)
    r = res(q, v, a, u, p)
    zero = ca.SX.zeros(n)
    acc = -ca.solve(ca.substitute(ca.jacobian(r, a), a, zero), ca.substitute(r, a, zero))
    x, f = ca.vertcat(q, v), ca.vertcat(v, acc)
    return ca.integrator("flow", "cvodes", {"x": x, "ode": -f if backwards else f}, 0.0, sorted(STEPS),
                         {"abstol": 1e-14, "reltol": 1e-13})


STEPS = np.array([4e-4, 2e-4, 1e-4, 5e-5])      # s: well below the period of the highest mode (2nd bending, 5 ms)


def test_flexible_elbow_accelerometer_is_the_second_derivative_of_the_elbow():
    data = payload_arm(gravity=[0.0, -G0, 0.0])
    for link in data["link"]:
        link["initial_deformation"] = "static"
    scene = parse_scene(data)
    model = build_model(scene)
    start = {"shoulder.initial_angle": 0.3, "shoulder.initial_rate": 1.2, "elbow.initial_rate": -2.0,
             "shoulder.tau": 25.0, "elbow.tau": -6.0}
    coords = list(model.coordinates)
    fmu = cached_fmu(scene)
    got = fmu_values(fmu, coords + ["upper.tip.sx", "upper.tip.sy", "upper.tip.sz"], start)
    # the reading depends on the torques directly: the FMU says so to an importer (algebraic loops)
    import fmpy

    structure = {o.variable.name: {v.name for v in o.dependencies} for o in fmpy.read_model_description(fmu).outputs}
    assert {"shoulder.tau", "elbow.tau"} <= structure["upper.tip.sy"]
    q0 = np.array([got[c] for c in coords])
    assert abs(got["upper.eta[1]"]) > 1e-4                  # deflected by gravity: the tip frame is turned
    v0 = np.zeros(model.n_q)
    v0[coords.index("shoulder.theta")], v0[coords.index("elbow.theta")] = 1.2, -2.0
    u = np.array([25.0, -6.0])
    p = np.array([par.value for par in model.parameters])
    # the elbow point and its frame as functions of the coordinates (the model's own position kinematics)
    chain = ChainAssembly(scene)
    chain.assemble_kinematics()
    frame = chain.frames[0]
    assert chain.coordinates == coords                       # every coordinate free: q is the chain's own
    pose = ca.Function("elbow", [chain.qa, chain.p], [ca.vertcat(frame.tip_origin, ca.vec(frame.tip_rotation))])

    def elbow(x):
        return np.asarray(pose(x[: model.n_q], p), dtype=float).ravel()

    x0 = np.concatenate([q0, v0])
    fwd = np.asarray(_flow(model, u, p, False)(x0=x0)["xf"], dtype=float).T[::-1]     # in STEPS order
    bwd = np.asarray(_flow(model, u, p, True)(x0=x0)["xf"], dtype=float).T[::-1]
    centre = elbow(x0)
    R = centre[3:].reshape(3, 3, order="F")                  # ca.vec stacks columns
    g = np.array([0.0, -G0, 0.0])
    measured = np.array([got["upper.tip.sx"], got["upper.tip.sy"], got["upper.tip.sz"]])
    estimates = []
    for k, h in enumerate(STEPS):
        a = (elbow(fwd[k])[:3] - 2 * centre[:3] + elbow(bwd[k])[:3]) / h**2
        estimates.append(R.T @ (a - g))
    errors = [float(np.linalg.norm(e - measured)) for e in estimates]
    extrapolated = (4 * estimates[-1] - estimates[-2]) / 3  # Richardson: the h² term removed
    scale = float(np.linalg.norm(measured))
    print(f"\nupper.tip.s(x, y, z) FMU {measured.round(6)}; central differences at h = {STEPS.tolist()}: errors "
          f"{[f'{e:.3g}' for e in errors]}, ratios {[round(errors[i] / errors[i + 1], 2) for i in range(3)]}; "
          f"extrapolated {extrapolated.round(6)} (error {np.linalg.norm(extrapolated - measured):.2g})")
    for i in range(3):                                       # second order: each halving divides the error by 4
        assert 3.5 < errors[i] / errors[i + 1] < 4.5
    assert np.linalg.norm(extrapolated - measured) < 1e-6 * scale
    assert scale > 5.0                                       # a reading far from the rest value's g
