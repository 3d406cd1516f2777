"""Joint reactions (seed 001 §2.10): Newton–Euler on the subtree beyond a joint, checked against the balance
laws they must satisfy independently of flexlink's kinematics."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from flexlink.mechanics.analysis import operating_point, static_deflection
from flexlink.mechanics.model import build_model
from flexlink.mechanics.reference import simulate_reference
from flexlink.scene.loader import load_scene, parse_scene


def test_static_reaction_carries_the_weight_and_its_moment():
    """Seed 001 §4.8 beam held horizontal: the joint carries ρAL g upwards and ρAL g L/2 about its axis."""
    model = build_model(load_scene("examples/steel_beam_gravity.toml"))
    op = operating_point(model)
    y = np.asarray(model.outputs_function(op.q, op.v, np.zeros(model.n_q), op.u, op.p)).ravel()
    weight = 7800 * 1.2e-3 * 1.0 * 9.81
    assert y[model.output_index("base.reaction.fy")] == pytest.approx(weight, rel=1e-12)
    assert y[model.output_index("base.reaction.fx")] == pytest.approx(0.0, abs=1e-9)
    # the sagged beam's centre of mass is a little inside L/2: the moment is ρA g ∫(x + u) dx, to O(η²)
    assert y[model.output_index("base.reaction.mz")] == pytest.approx(weight * 0.5, rel=1e-6)
    assert y[model.output_index("base.reaction.mz")] == pytest.approx(y[model.output_index("base.tau")], rel=1e-6)


@pytest.mark.parametrize("kinematics", ["linear", "first-order"])
def test_axial_moment_equals_the_motor_torque(kinematics):
    """Free hub (no damping, no gravity): everything beyond the joint is the subtree, so the moment the joint
    transmits about its axis is the motor torque itself, at every instant of a manoeuvre."""
    data = tomllib.loads(Path("examples/rotating_link_payload.toml").read_text())
    data["link"][0]["kinematics"] = kinematics
    model = build_model(parse_scene(data))
    times = np.linspace(0.0, 2.0, 41)
    ref = simulate_reference(model, times, inputs=[(0.0, {"hub.tau": 0.2}), (1.0, {"hub.tau": -0.5})])
    expected = np.where(times < 1.0, 0.2, -0.5)
    if kinematics == "linear":
        # the linear model's T is linearised: its momentum balance holds to first order only
        assert ref.output(model, "hub.reaction.mz") == pytest.approx(expected, rel=2e-2, abs=2e-3)
    else:
        assert ref.output(model, "hub.reaction.mz") == pytest.approx(expected, abs=1e-8)
    for c in ("fz", "mx", "my"):                  # planar motion: nothing out of the plane
        assert np.max(np.abs(ref.output(model, f"hub.reaction.{c}"))) < 1e-9


def test_reaction_force_is_the_rate_of_momentum():
    """First-order model, free hub: the joint force equals the rate of change of the total momentum, which an
    independent finite difference of the tip and beam positions does not give directly — so check the in-plane
    force against m a_G computed from the reference's tip acceleration of a payload-dominated link."""
    data = tomllib.loads(Path("examples/rotating_link_payload.toml").read_text())
    data["link"][0]["kinematics"] = "first-order"
    data["link"][0]["linear_density"] = 1e-4            # nearly massless beam: the payload is the mass
    data["link"][0]["payload"] = {"mass": 2.0, "inertia": 0.0}
    model = build_model(parse_scene(data))
    times = np.linspace(0.0, 1.0, 11)
    ref = simulate_reference(model, times, inputs=[(0.0, {"hub.tau": 0.5})])
    theta = ref.output(model, "hub.theta")
    a_tip = np.column_stack([ref.output(model, "tip.ax"), ref.output(model, "tip.ay")])
    f = np.column_stack([ref.output(model, "hub.reaction.fx"), ref.output(model, "hub.reaction.fy")])
    # joint frame = base rotated by θ: world force = R(θ) f
    c, s = np.cos(theta), np.sin(theta)
    f_world = np.column_stack([c * f[:, 0] - s * f[:, 1], s * f[:, 0] + c * f[:, 1]])
    beam_mass = 1e-4 * 2.2
    assert f_world == pytest.approx(2.0 * a_tip, abs=5 * beam_mass * np.max(np.abs(a_tip)) + 1e-9)


def test_tip_load_inputs_bend_the_link_and_load_the_joint():
    """[fmu] tip_load_inputs: a static tip force F across the link (hub held) deflects the tip by FL³/3EI
    (FE: nodally exact) and the joint reacts with −F and the moment F·L; a tip moment M bends it by ML²/2EI."""
    data = {"name": "tip_load", "fmu": {"tip_load_inputs": True},
            "joint": [{"name": "hub", "drive": "position",
                       "trajectory": {"segments": [{"until": float("inf"), "poly": [0.0]}]}}],
            "link": [{"name": "arm", "length": 1.5, "linear_density": 2.0, "EI": 300.0,
                      "shapes": {"kind": "fe", "count": 4}, "kinematics": "first-order"}]}
    model = build_model(parse_scene(data))
    names = [s.name for s in model.inputs]
    for load, expected in (("tip.fy", 2.0 * 1.5**3 / (3 * 300.0)), ("tip.mz", 2.0 * 1.5**2 / (2 * 300.0))):
        op = operating_point(model)
        u = op.u.copy()
        u[names.index(load)] = 2.0
        q = static_deflection(model, op.q, op.v, u, op.p, list(range(model.n_q)))
        y = np.asarray(model.outputs_function(q, op.v, np.zeros(model.n_q), u, op.p)).ravel()
        assert y[model.output_index("arm.tip.v")] == pytest.approx(expected, rel=1e-9)
        if load == "tip.fy":
            assert y[model.output_index("hub.reaction.fy")] == pytest.approx(-2.0, rel=1e-6)
            assert y[model.output_index("hub.reaction.mz")] == pytest.approx(-2.0 * 1.5, rel=1e-3)
