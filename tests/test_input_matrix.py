"""The input matrix B = ∂r/∂u where it is a constant (mechanics.assembly.structure): the FMU's energy guard
takes the inputs' generalized forces as −B u instead of the residual difference r(u = 0) − r(u) (two
residuals at every communication point, fmu_src/guards.c)."""

import numpy as np
import pytest

from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene, parse_scene


def test_a_joint_torque_is_a_unit_generalized_force_on_its_own_joint():
    """Virtual work: a torque τ between the two sides of a revolute joint does τ δθ on its relative angle and
    nothing on any other coordinate, whatever the pose and the links' bending; at an elastic joint the motor
    turns the motor side, whose angle is the motor's (the spring carries it on).  On the six-axis arm
    (flexible links, an elastic elbow, gravity, six torques) −B u is that, and it equals the residual
    difference the guard took before at random states."""
    model = build_model(load_scene("examples/six_axis_arm_torque.toml"))
    B = model.input_matrix
    assert B is not None and B.shape == (model.n_q, len(model.inputs))
    for k, signal in enumerate(model.inputs):
        joint = signal.name.removesuffix(".tau")
        column = np.zeros(model.n_q)
        driven = f"{joint}.motor_theta" if f"{joint}.motor_theta" in model.coordinates else f"{joint}.theta"
        column[model.coordinates.index(driven)] = -1.0
        assert B[:, k] == pytest.approx(column, abs=0.0)
    rng = np.random.default_rng(3)
    zero = np.zeros(model.n_q)
    for _ in range(5):
        q, v = rng.normal(scale=0.3, size=model.n_q), rng.normal(scale=0.5, size=model.n_q)
        u = rng.normal(scale=20.0, size=len(model.inputs))
        free = np.asarray(model.residual(q, v, zero, np.zeros_like(u), model.p0)).ravel()
        forced = np.asarray(model.residual(q, v, zero, u, model.p0)).ravel()
        assert -B @ u == pytest.approx(free - forced, rel=1e-12, abs=1e-12 * np.max(np.abs(free)))


def test_a_force_whose_generalized_force_turns_with_the_arm_keeps_the_residual_differences():
    """A tip force given in the inertial frame acts on the hub angle through the arm's pose (its moment is
    r × F): B depends on the coordinates, so there is no constant matrix and the guard keeps its
    differences.  A kinematic law's slots are an angle, a rate and an acceleration, not forces: none either."""
    data = {"name": "tip_load", "fmu": {"tip_load_inputs": True},
            "joint": [{"name": "hub", "inertia": 0.1}],
            "link": [{"name": "arm", "length": 1.5, "linear_density": 2.0, "EI": 300.0,
                      "shapes": {"kind": "clamped-free", "count": 2}}]}
    assert build_model(parse_scene(data)).input_matrix is None
    assert build_model(load_scene("examples/aluminium_arm_smooth.toml")).input_matrix is None


def test_explain_says_how_the_energy_guard_takes_the_inputs_forces(tmp_path):
    """`flexlink explain` says which of the two ways a model's inputs take in the guard: the demo arm's hub
    torque is a constant matrix times the input, a tip force in the inertial frame is not."""
    from flexlink.tools.explain import explain, format_explanation

    text = format_explanation(explain("examples/rotating_link.toml"))
    assert "the force inputs' generalized forces: a constant matrix times the inputs" in text
    scene = tmp_path / "tip_load.toml"
    scene.write_text('name = "tip_load"\n[fmu]\ntip_load_inputs = true\n'
                     '[[joint]]\nname = "hub"\ninertia = 0.1\n'
                     '[[link]]\nname = "arm"\nlength = 1.5\nlinear_density = 2.0\nEI = 300.0\n'
                     'shapes = { kind = "clamped-free", count = 2 }\n')
    text = format_explanation(explain(str(scene)))
    assert "the force inputs' generalized forces: residual differences in the energy guard" in text
