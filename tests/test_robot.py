"""Robots of rigid and flexible links (issue 15) against Pinocchio, an independent rigid-body library.

The scene of ``examples/six_axis_arm.toml`` is translated here, from the scene's own data, into a Pinocchio
model: joint placements (the previous link's tip at (L, 0, 0), then the joint's origin and rpy), revolute
joints about their axes, each link's inertia (a rigid link's ten parameters; a flexible link's rigid limit,
the uniform rod with its sections' polar inertia), each rotor as an inertia I·a aᵀ turning with its link,
the tip payload.  flexlink's mass matrix, bias forces and forward dynamics must equal Pinocchio's CRBA,
RNEA and ABA at random states: for the arm made wholly rigid, and for the flexible arm at zero deflection
(where a beam link's inertia is its rod's).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene

pin = pytest.importorskip("pinocchio")

ROOT = Path(__file__).resolve().parent.parent
ARM = ROOT / "examples" / "six_axis_arm.toml"
CHAIN = ROOT / "examples" / "planar_chain_5.toml"
FLEXIBLE_ONLY = ("EI", "EI_out", "GJ", "kelvin_voigt", "deformation", "shapes", "kinematics", "initial_deformation")


def _torque_driven(data: dict, rigid: bool) -> dict:
    """The arm with every joint torque-driven and stiff (its coordinates are the six joint angles), rotor
    inertias on every joint, and, if ``rigid``, every flexible link replaced by its rigid limit."""
    for i, joint in enumerate(data["joint"]):
        for key in ("trajectory", "stiffness", "damping"):
            joint.pop(key, None)
        joint["drive"] = "torque"
        joint["inertia"] = 0.01 * (i + 1)
    if rigid:
        for link in data["link"]:
            if link.get("deformation", ["v"]):
                for key in FLEXIBLE_ONLY:
                    link.pop(key, None)
                link["deformation"] = []
    return data


def _arm(rigid: bool, path: Path = ARM):
    data = _torque_driven(tomllib.loads(path.read_text()), rigid)
    return parse_scene(data, f"{path.stem} (torque-driven)")


def _inertia(mass: float, centre, inertia) -> pin.Inertia:
    return pin.Inertia(float(mass), np.asarray(centre, float), np.asarray(inertia, float))


def _link_inertia(link) -> pin.Inertia:
    """A rigid link's ten parameters, or a beam link's rigid limit: the uniform rod along x."""
    if link.is_rigid:
        mass, centre, inertia = link.rigid_body()
        return _inertia(mass, centre, inertia)
    rho, L = link.linear_density, link.length
    polar = (link.polar_inertia or 0.0) * L if "alpha" in link.deformation else 0.0
    return _inertia(rho * L, (L / 2, 0, 0), np.diag([polar, rho * L**3 / 12, rho * L**3 / 12]))


def _link_frame(joint, link) -> np.ndarray:
    """A link's frame in its joint's frame (docs/scene.md): a beam's is (x, a × x, a), so that it bends
    in the plane normal to its axis a; a rigid link's is the joint frame itself."""
    if link.is_rigid:
        return np.eye(3)
    a = np.asarray(joint.axis, float)
    return np.column_stack([[1.0, 0.0, 0.0], np.cross(a, [1.0, 0.0, 0.0]), a])


def pinocchio_model(scene) -> pin.Model:
    """The scene's chain as a Pinocchio model, built from the scene's data alone, with a frame "tool"."""
    model = pin.Model()
    model.gravity = pin.Motion(np.asarray(scene.gravity, float), np.zeros(3))
    parent, tip = 0, pin.SE3.Identity()           # the parent's tip frame in the parent joint's frame
    for joint, link in zip(scene.joints, scene.links, strict=True):
        placement = tip * pin.SE3(joint.placement_rotation(), np.asarray(joint.origin, float))
        axis = np.asarray(joint.axis, float) / np.linalg.norm(joint.axis)
        parent = model.addJoint(parent, pin.JointModelRevoluteUnaligned(axis), placement, joint.name)
        B = _link_frame(joint, link)
        model.appendBodyToJoint(parent, _link_inertia(link), pin.SE3(B, np.zeros(3)))
        model.appendBodyToJoint(parent, _inertia(0.0, np.zeros(3), joint.inertia * np.outer(axis, axis)),
                                pin.SE3.Identity())
        tip = pin.SE3(B, B @ np.array([link.length, 0.0, 0.0]))
        pay = link.payload
        if pay.is_present:
            e = B.T @ axis                                  # a scalar payload inertia is about the joint axis
            J = np.diag(pay.inertia) if isinstance(pay.inertia, tuple) else pay.inertia * np.outer(e, e)
            model.appendBodyToJoint(parent, _inertia(pay.mass, np.zeros(3), J),
                                    tip * pin.SE3(np.eye(3), np.asarray(pay.offset, float)))
    tool = tip * pin.SE3(scene.tool.placement_rotation(), np.asarray(scene.tool.origin, float))
    model.addFrame(pin.Frame("tool", parent, 0, tool, pin.FrameType.OP_FRAME))
    return model


def _states(model, rng, n: int = 5):
    """Random joint angles (all of them, large), rates and torques; elastic coordinates at zero."""
    joints = [k for k, kind in enumerate(model.coordinate_kinds) if kind == "joint"]
    for _ in range(n):
        q = np.zeros(model.n_q)
        v = np.zeros(model.n_q)
        q[joints] = rng.uniform(-np.pi, np.pi, len(joints))
        v[joints] = rng.normal(0.0, 2.0, len(joints))
        tau = rng.normal(0.0, 20.0, len(model.inputs))
        yield q, v, tau, joints


def _compare(scene, flexlink_model) -> tuple[float, float, float]:
    """Largest relative differences of M, h and the joint accelerations against Pinocchio."""
    pmodel = pinocchio_model(scene)
    data = pmodel.createData()
    m = flexlink_model
    rng = np.random.default_rng(15)
    worst = np.zeros(3)
    for q, v, tau, joints in _states(m, rng):
        qj, vj = q[joints], v[joints]
        M = np.asarray(m.mass_matrix_function()(q, tau, m.p0))[np.ix_(joints, joints)]
        M_pin = pin.crba(pmodel, data, qj)
        M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
        h = np.asarray(m.residual(q, v, np.zeros(m.n_q), np.zeros(len(tau)), m.p0)).ravel()[joints]
        h_pin = pin.rnea(pmodel, data, qj, vj, np.zeros(len(joints)))
        a_pin = pin.aba(pmodel, data, qj, vj, tau)
        a = np.linalg.solve(M, tau - h)
        worst = np.maximum(worst, [np.max(np.abs(M - M_pin)) / np.max(np.abs(M_pin)),
                                   np.max(np.abs(h - h_pin)) / np.max(np.abs(h_pin)),
                                   np.max(np.abs(a - a_pin)) / np.max(np.abs(a_pin))])
    return tuple(worst)


def test_rigid_arm_equals_pinocchio():
    """Every link rigid: M (CRBA), bias forces h = C v + g (RNEA at zero acceleration) and forward dynamics
    (ABA) at five random states of the six joints, to 1e-12 (both sides are exact to rounding)."""
    scene = _arm(rigid=True)
    model = build_model(scene)
    assert model.n_q == 6
    assert max(_compare(scene, model)) < 1e-12


@pytest.mark.parametrize("path, n_q", [(ARM, 6 + 12), (CHAIN, 5 + 15)], ids=["six_axis_arm", "planar_chain_5"])
def test_flexible_robot_at_zero_deflection_equals_its_rigid_limit_in_pinocchio(path, n_q):
    """The flexible robot at η = 0, η̇ = 0: the joints' block of M and of the bias forces is the rigid
    limit's (each beam a uniform rod with its sections' polar inertia)."""
    scene = _arm(rigid=False, path=path)
    model = build_model(scene)
    assert model.n_q == n_q
    assert max(_compare(scene, model)) < 1e-12


def test_pinocchio_translation_is_not_vacuous():
    """The comparison can fail: a 1 % heavier tool is seen in M, h and the accelerations."""
    scene = _arm(rigid=True)
    data = _torque_driven(tomllib.loads(ARM.read_text()), rigid=True)
    data["link"][-1]["mass"] *= 1.01
    heavier = build_model(parse_scene(data, "heavier tool"))
    M_err, h_err, a_err = _compare(scene, heavier)
    assert M_err > 1e-4 and h_err > 1e-4 and a_err > 1e-4


JOINTS = ("base", "shoulder", "elbow", "wrist_roll", "wrist_pitch", "flange")


def test_six_axis_arm_manoeuvre_ends_at_pinocchio_gravity_torques(example_fmu):
    """The example itself through fmpy (Co-Simulation, Θ = ½): 3 s of cycloidal moves on all six joints under
    gravity, then 2 s of hold.  At the end the torques the laws need are the static gravity torques of the
    final pose, which Pinocchio gives for the rigid arm (RNEA at zero rate and acceleration; the elbow at its
    link-side angle, its motor torque being the spring's).  The flexible arm's geometry differs from the
    rigid one by its deflections, so they agree to a few times tip deflection / length (that ratio is read
    from the run itself)."""
    import fmpy

    links = {"upper_arm": 0.6, "forearm": 0.5}
    outputs = [f"{j}.tau" for j in JOINTS] + ["elbow.theta"] + [f"{k}.tip.{c}" for k in links for c in "vw"]
    res = fmpy.simulate_fmu(str(example_fmu("six_axis_arm")), fmi_type="CoSimulation", stop_time=5.0,
                            output_interval=0.01, output=outputs)
    scene = _arm(rigid=False)
    pm = pinocchio_model(scene)
    q = np.array([1.2, -0.6, res["elbow.theta"][-1], 0.8, -0.7, 1.5])     # the laws' end values
    g = pin.rnea(pm, pm.createData(), q, np.zeros(6), np.zeros(6))
    tau = np.array([res[f"{j}.tau"][-1] for j in JOINTS])
    deflection = max(abs(res[f"{k}.tip.{c}"][-1]) / length for k, length in links.items() for c in "vw")
    assert 1e-5 < deflection < 1e-2                          # the arm sags, a little
    assert np.max(np.abs(tau - g)) < 3 * deflection * np.max(np.abs(g))


# ------------------------------------------------------------------ a rigid link's inertia set through the FMU


def _rigid_pendulum(inertia=(0.01, 0.02, 0.025, 0.0, 0.0, 0.0)) -> dict:
    return dict(name="rigid_pendulum", gravity=[0.0, -9.81, 0.0],
                joint=[dict(name="hub", axis=[0.0, 0.0, 1.0], drive="torque")],
                link=[dict(name="body", deformation=[], length=0.5, mass=2.0, center_of_mass=[0.3, 0.0, 0.0],
                           inertia=list(inertia))])


def test_inertia_relations_agree_with_the_scene_loader():
    """The model's parameter check (principal minors of ½tr(J)1 − J, generated into the FMU) accepts exactly
    the tensors the scene loader accepts (its own test: eigenvalues and the triangle inequalities), on
    random tensors around the boundary."""
    from flexlink.errors import SceneError

    model = build_model(parse_scene(_rigid_pendulum()))
    k = [model.parameter_index(f"body.inertia[{i + 1}]") for i in range(6)]
    rng = np.random.default_rng(3)
    decided = {True: 0, False: 0}
    for _ in range(400):
        A = rng.normal(size=(3, 3))
        second = A @ A.T                                    # a body's ∫ρ r rᵀ, then a perturbation
        J = np.trace(second) * np.eye(3) - second + rng.normal(0.0, 0.1 * np.trace(second), (3, 3))
        J = 0.5 * (J + J.T)
        tensor = np.array([J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]])
        if np.any(tensor[:3] < 0):                          # a negative moment is the variable's own bound
            continue
        p = model.p0.copy()
        p[k] = tensor
        accepted_by_model = bool(np.all(np.asarray(model.parameter_check(p)) >= -1e-12))
        try:
            parse_scene(_rigid_pendulum(tuple(tensor)))
            accepted_by_loader = True
        except SceneError:
            accepted_by_loader = False
        assert accepted_by_model == accepted_by_loader, tensor
        decided[accepted_by_model] += 1
    assert min(decided.values()) > 40          # both sides of the boundary were tried


def test_fmu_refuses_an_inertia_that_is_no_body_and_keeps_the_old_one(tmp_path):
    """fmi2SetReal of Ixx = 0.05 > Iyy + Izz = 0.045: fmi2Error naming the relation, and nothing changed
    (the other value of the same call, a torque input, included); after the reset fmi2Error asks for, a
    physical change is taken; a product of inertia beyond its 2×2 minor is refused too."""
    import fmpy
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    from flexlink.export.fmu import build_fmu
    from flexlink.run.simulate import logging_callbacks

    path = build_fmu(parse_scene(_rigid_pendulum()), tmp_path / "rigid.fmu").fmu
    md = fmpy.read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(path)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="rigid")
    messages = []
    callbacks = logging_callbacks(lambda *args: messages.append(args[-1].decode(errors="replace")))
    slave.instantiate(loggingOn=False, callbacks=callbacks)
    with pytest.raises(FMICallException):
        slave.setReal([vr["body.inertia[1]"], vr["hub.tau"]], [0.05, 1.0])
    assert "body.inertia: second moment xx >= 0" in messages[-1] and "nothing was set" in messages[-1]
    assert slave.getReal([vr["body.inertia[1]"], vr["hub.tau"]]) == [0.01, 0.0]
    slave.reset()                                              # fmi2Error: the instance wants a reset
    slave.setReal([vr["body.inertia[1]"]], [0.04])            # ≤ 0.045: a body
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    assert slave.getReal([vr["body.inertia[1]"]]) == [0.04]
    slave.setReal([vr["body.inertia[1]"]], [0.01])
    with pytest.raises(FMICallException):                      # a product beyond the minor: 0.012² > 0.0175·0.0075
        slave.setReal([vr["body.inertia[4]"]], [0.012])
    assert "second moments xy minor" in messages[-1]
    assert slave.getReal([vr["body.inertia[4]"]]) == [0.0]
    slave.reset()
    slave.setReal([vr["body.inertia[4]"]], [0.011])           # within the minor: 0.011² < 0.0175·0.0075
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    assert slave.getReal([vr["body.inertia[4]"]]) == [0.011]
    slave.freeInstance()
    _KEEP_ALIVE.append(callbacks)          # fmpy's logger proxy may still call it


_KEEP_ALIVE: list = []


# ------------------------------------------------------- frames, tool, reactions and tip loads of a general chain


def _general_chain() -> dict:
    """Placements on every joint, axes that are not coordinate axes, a beam about y between rigid links, a
    payload with a scalar inertia, a [tool] frame, tip-load inputs and a tilted gravity."""
    def joint(name, **kw):
        return dict(name=name, drive="torque", inertia=0.03, **kw)

    def body(name, **kw):
        return dict(name=name, deformation=[], length=0.3, mass=1.5, center_of_mass=[0.1, 0.02, -0.03],
                    inertia=[0.02, 0.03, 0.025, 0.001, -0.002, 0.0015], **kw)

    beam = dict(name="beam", length=0.5, linear_density=1.2, EI=80.0, EI_out=60.0, deformation=["v", "w"],
                shapes={"kind": "clamped-free", "count": 2}, payload={"mass": 0.4, "inertia": 0.002})
    return dict(name="general", gravity=[0.3, -2.0, -9.81],
                joint=[joint("j0", origin=[0.1, 0.2, 0.3], rpy=[0.3, -0.4, 0.5], axis=[1.0, 2.0, 3.0]),
                       joint("j1", axis=[0.0, 1.0, 0.0], rpy=[0.2, 0.0, 0.1]),
                       joint("j2", origin=[0.0, 0.05, 0.1], axis=[0.3, -1.0, 0.2])],
                link=[body("l0"), beam, body("l2", payload={"mass": 0.3, "inertia": 0.001, "offset": [0.02, 0, 0]})],
                tool=dict(origin=[0.05, 0.01, 0.02], rpy=[0.1, 0.2, 0.3]), fmu=dict(tip_load_inputs=True))


def test_tool_frame_reactions_and_tip_loads_equal_pinocchio():
    """At zero deflection, random joint angles, rates and accelerations and a random tip load: the tool frame's
    position, absolute acceleration and accelerometer (Pinocchio's frame kinematics), every joint's reaction
    (the spatial force Pinocchio's RNEA transmits through the joint, with the load as an external force on the
    last body) and the joint equations (RNEA's torques minus the load's) agree to rounding."""
    scene = parse_scene(_general_chain(), "general chain")
    model = build_model(scene)
    pm = pinocchio_model(scene)
    pd = pm.createData()
    tool = pm.getFrameId("tool")
    joints = [k for k, kind in enumerate(model.coordinate_kinds) if kind == "joint"]
    names = [s.name for s in model.outputs]
    k0 = [s.name for s in model.inputs].index("tip.fx")
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(4):
        q, v, a = np.zeros(model.n_q), np.zeros(model.n_q), np.zeros(model.n_q)
        q[joints], v[joints], a[joints] = rng.uniform(-3, 3, 3), rng.normal(0, 2, 3), rng.normal(0, 2, 3)
        u = np.zeros(len(model.inputs))
        load = rng.normal(0.0, 5.0, 6)
        u[k0:k0 + 6] = load
        y = dict(zip(names, np.asarray(model.outputs_function(q, v, a, u, model.p0)).ravel(), strict=True))
        r = np.asarray(model.residual(q, v, a, u, model.p0)).ravel()[joints]
        qj, vj, aj = q[joints], v[joints], a[joints]
        pin.forwardKinematics(pm, pd, qj, vj, aj)
        pin.updateFramePlacements(pm, pd)
        frame = pd.oMf[tool]
        acc = pin.getFrameClassicalAcceleration(pm, pd, tool, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).linear
        last = pd.oMi[3]
        force = [pin.Force.Zero() for _ in range(pm.njoints)]
        force[3] = pin.Force(last.rotation.T @ load[:3],
                             last.rotation.T @ (np.cross(frame.translation - last.translation, load[:3]) + load[3:]))
        tau = pin.rnea(pm, pd, qj, vj, aj, force)
        ours = np.concatenate([[y[f"tip.{c}"] for c in "xyz"], [y[f"tip.a{c}"] for c in "xyz"],
                               [y[f"tip.s{c}"] for c in "xyz"],
                               *[[y[f"{j}.reaction.{c}"] for c in ("fx", "fy", "fz", "mx", "my", "mz")]
                                 for j in ("j0", "j1", "j2")], r])
        theirs = np.concatenate([frame.translation, acc, frame.rotation.T @ (acc - np.asarray(scene.gravity)),
                                 *[pd.f[i].vector for i in (1, 2, 3)], tau])
        worst = max(worst, np.max(np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1.0)))
    assert worst < 1e-12


def test_a_chain_with_nothing_to_integrate_is_refused():
    """Every joint position-driven, every link rigid (inverse dynamics only): one clear error, no C build."""
    from flexlink.errors import FlexlinkError

    data = _torque_driven(tomllib.loads(ARM.read_text()), rigid=True)
    for joint in data["joint"]:
        joint["drive"] = "position"
    with pytest.raises(FlexlinkError, match="no free coordinate"):
        build_model(parse_scene(data, "all prescribed"))


def test_a_turntable_builds(tmp_path):
    """One joint turning a rigid disc of zero length: its tip acceleration is structurally zero, and the
    generated outputs are still dense (the FMU builds and runs one step)."""
    import fmpy

    from flexlink.export.fmu import build_fmu

    data = dict(name="turntable", joint=[dict(name="spin", drive="torque", inertia=0.01)],
                link=[dict(name="disc", deformation=[], length=0.0, mass=3.0, inertia=[0.02, 0.02, 0.04])])
    path = build_fmu(parse_scene(data), tmp_path / "turntable.fmu").fmu
    res = fmpy.simulate_fmu(str(path), stop_time=0.01, output=["spin.omega", "tip.ax"],
                            input=np.array([(0.0, 1.0)], dtype=[("time", float), ("spin.tau", float)]))
    assert res["spin.omega"][-1] == pytest.approx(0.01 / (0.04 + 0.01), rel=1e-9)   # τ t / (J_disc + J_rotor)
    assert np.all(res["tip.ax"] == 0.0)
