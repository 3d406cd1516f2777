"""flexlink.run.linearize: the scene's model as a python-control StateSpace with named signals."""

from __future__ import annotations

import json
import math
from pathlib import Path

import control as ct
import numpy as np
import pytest

from flexlink.errors import FlexlinkError
from flexlink.mechanics.analysis import linearise, natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.run.linearize import explicit_functions, linear_plant, linearize, operating_point_at, signal_name
from flexlink.scene.loader import load_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
OUTPUTS = ["hub.theta", "hub.omega", "arm.tip.v", "arm.root.moment", "tip.sx", "tip.sy", "tip.ay"]


@pytest.fixture(scope="module")
def model():
    return build_model(load_scene(EXAMPLES / "rotating_link.toml"))


@pytest.fixture(scope="module")
def payload_model():
    return build_model(load_scene(EXAMPLES / "rotating_link_payload.toml"))


def test_names_follow_the_fmu(model):
    sys = linearize(model, outputs=OUTPUTS)
    assert isinstance(sys, ct.StateSpace) and sys.isctime()
    assert list(sys.state_labels) == ["hub.theta", "arm.eta[1]", "arm.eta[2]", "arm.eta[3]", "der(hub.theta)",
                                      "der(arm.eta[1])", "der(arm.eta[2])", "der(arm.eta[3])"]
    # python-control 0.10 reserves "." in input/output names: "_" stands for it
    assert list(sys.input_labels) == ["hub_tau"]
    assert list(sys.output_labels) == [signal_name(o) for o in OUTPUTS]
    assert signal_name("arm.eta[2]") == "arm_eta[2]"
    plant = linear_plant(model)
    assert plant.outputs == [s.name for s in model.outputs] and plant.inputs == ["hub.tau"]
    # python-control reads arm_eta[k] as a vector signal
    assert plant.sys.find_outputs("arm_eta") == [plant.output_row(f"arm.eta[{k}]") for k in (1, 2, 3)]


def test_state_matrices_from_the_second_order_form(model):
    """A = [[0, I], [−M⁻¹K, −M⁻¹C]], B = [0; M⁻¹B] from flexlink.mechanics.analysis.linearise, checked against
    the CasADi Jacobian of the explicit form ẋ = f(x, u)."""
    plant = linear_plant(model, outputs=OUTPUTS)
    lin = linearise(model, plant.op)
    n = model.n_q
    Minv = np.linalg.inv(lin.M)
    np.testing.assert_array_equal(plant.sys.A[:n, :n], 0)
    np.testing.assert_array_equal(plant.sys.A[:n, n:], np.eye(n))
    np.testing.assert_allclose(plant.sys.A[n:, :n], -Minv @ lin.K, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(plant.sys.B[n:], Minv @ lin.B, rtol=1e-12)
    f, _ = explicit_functions(model)
    import casadi as ca

    x, u = ca.MX.sym("x", 2 * n), ca.MX.sym("u", 1)
    jac = ca.Function("j", [x, u], [ca.jacobian(f(x, u, plant.op.p), x), ca.jacobian(f(x, u, plant.op.p), u)])
    Aj, Bj = (np.asarray(m) for m in jac(plant.x0, plant.u0))
    np.testing.assert_allclose(plant.sys.A, Aj, rtol=1e-10, atol=1e-8)
    np.testing.assert_allclose(plant.sys.B, Bj, rtol=1e-10, atol=1e-12)


def test_outputs_and_feedthrough(model):
    """C, D: the encoder and strain gauge have no feedthrough; the tip acceleration y-component at rest is
    L θ̈ + v̈(L), so its D is L·(M⁻¹B)_θ + φ(L)ᵀ(M⁻¹B)_η — derived here from the tip.v and hub rows."""
    p = linear_plant(model, outputs=OUTPUTS)
    n = model.n_q
    D = dict(zip(p.outputs, p.sys.D[:, 0], strict=True))
    assert D["hub.theta"] == D["arm.tip.v"] == D["arm.root.moment"] == 0.0
    Bv = p.sys.B[n:, 0]                       # accelerations per unit torque
    C_tip = p.sys.C[p.output_row("arm.tip.v"), :n]
    expected = 2.2 * Bv[0] + C_tip @ Bv
    assert D["tip.ay"] == pytest.approx(expected, rel=1e-10)
    assert D["tip.sy"] == pytest.approx(expected, rel=1e-10)     # no gravity, tip frame = link frame at rest
    assert abs(D["tip.ay"]) > 0.1
    # hub angle row is the state; the root moment is EI φ''(0)ᵀη
    np.testing.assert_array_equal(p.sys.C[p.output_row("hub.theta")], np.eye(2 * n)[0])
    assert np.all(p.sys.C[p.output_row("arm.root.moment"), n:] == 0)


def test_poles_are_the_natural_frequencies(model, payload_model):
    for m, rate in ((model, 0.0), (model, 3.0), (payload_model, 0.0)):
        sys = linearize(m, rate=rate)
        poles = sys.poles()
        w = np.sort(poles.imag[poles.imag > 1e-6])          # one of each conjugate pair
        ref = natural_frequencies(m, rate).frequencies_hz
        np.testing.assert_allclose(w / (2 * math.pi), ref, rtol=1e-8)
    # seed-000 link, hub free (0.1 kg m²): 5.76 Hz; with the 0.5 kg payload: 4.55 Hz (examples' headers)
    assert natural_frequencies(model).frequencies_hz[0] == pytest.approx(5.760, abs=2e-3)


def test_operating_point_angle_and_parameters(payload_model):
    op = operating_point_at(payload_model, angle=1.0, parameters={"arm.payload.mass": 0.65})
    assert op.q[0] == 1.0 and op.p[payload_model.parameter_index("arm.payload.mass")] == 0.65
    heavy = linear_plant(payload_model, parameters={"arm.payload.mass": 0.65})
    light = linear_plant(payload_model, parameters={"arm.payload.mass": 0.35})
    assert np.min(np.abs(heavy.sys.poles().imag[heavy.sys.poles().imag > 0])) < \
        np.min(np.abs(light.sys.poles().imag[light.sys.poles().imag > 0]))
    with pytest.raises(FlexlinkError, match="not a tunable parameter"):
        linear_plant(payload_model, parameters={"arm.nonsense": 1.0})
    with pytest.raises(FlexlinkError, match="not outputs"):
        linear_plant(payload_model, outputs=["tip.nothing"])


def test_cli_linearize_json(capsys, tmp_path):
    import argparse

    from controllers.cli import add_control_parsers

    parser = argparse.ArgumentParser()
    add_control_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["linearize", str(EXAMPLES / "rotating_link.toml"), "--json", "--output", "hub.theta",
                              "--output", "tip.sy"])
    assert args.func(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["inputs"] == ["hub.tau"] and out["outputs"] == ["hub.theta", "tip.sy"]
    assert np.asarray(out["A"]).shape == (8, 8) and np.asarray(out["D"]).shape == (2, 1)
    assert out["states"][4] == "der(hub.theta)"
    saved = tmp_path / "lin.npz"
    args = parser.parse_args(["linearize", str(EXAMPLES / "rotating_link.toml"), "--save", str(saved)])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "der(arm.eta[3])" in text and "hub.tau" in text
    with np.load(saved) as z:
        assert z["A"].shape == (8, 8) and list(z["inputs"]) == ["hub.tau"]
    args = parser.parse_args(["linearize", str(EXAMPLES / "rotating_link.toml"), "--save", str(tmp_path / "x.txt")])
    with pytest.raises(FlexlinkError, match="json or .npz"):
        args.func(args)


def test_the_python_control_system_is_built_on_first_use_from_the_matrices(model):
    """``LinearPlant.sys`` is python-control's system of the plant's own matrices and names, built when first
    asked for (``flexlink linearize`` never asks, and so never imports python-control)."""
    plant = linear_plant(model, outputs=OUTPUTS)
    assert "sys" not in vars(plant)
    sys = plant.sys
    assert plant.sys is sys and isinstance(sys, ct.StateSpace) and sys.isctime()
    for mine, theirs in ((plant.A, sys.A), (plant.B, sys.B), (plant.C, sys.C), (plant.D, sys.D)):
        np.testing.assert_array_equal(theirs, mine)
    assert list(sys.state_labels) == plant.states
    assert list(sys.input_labels) == [signal_name(s) for s in plant.inputs]
    assert list(sys.output_labels) == [signal_name(s) for s in plant.outputs]
    assert sys.name == model.scene.model_identifier


def _cli(argv):
    import argparse

    from controllers.cli import add_control_parsers

    parser = argparse.ArgumentParser()
    add_control_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.mark.parametrize("scene", ["rotating_link.toml", "rotating_link_payload.toml"])
def test_cli_linearize_prints_python_controls_system(capsys, scene):
    """Every number and name ``flexlink linearize`` prints is python-control's: the matrices and labels of
    ``linear_plant(...).sys`` bit for bit, and its poles (``StateSpace.poles``) as the text prints them."""
    args = ["linearize", str(EXAMPLES / scene), "--angle", "20", "--output", "hub.theta", "--output", "arm.tip.v",
            "--output", "tip.ay"]
    sys = linear_plant(EXAMPLES / scene, angle=math.radians(20), outputs=["hub.theta", "arm.tip.v", "tip.ay"]).sys
    assert _cli([*args, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    for k in "ABCD":
        assert np.array_equal(np.asarray(doc[k]), getattr(sys, k)), k
    assert doc["states"] == list(sys.state_labels)
    assert doc["python_control_names"] == {"inputs": list(sys.input_labels), "outputs": list(sys.output_labels)}
    assert _cli(args) == 0
    text = capsys.readouterr().out
    poles = np.sort_complex(sys.poles())
    assert "poles (rad/s): " + ", ".join(f"{p.real:.6g}{p.imag:+.6g}j" for p in poles) + "\n" in text
    assert f"for '.': {', '.join(sys.input_labels)})" in text


@pytest.mark.parametrize(("name", "value"), [("arm.EI", -1.0), ("arm.EI", 0.0), ("arm.linear_density", -2.0),
                                             ("hub.inertia", -5.0), ("arm.EI", math.nan), ("arm.EI", math.inf),
                                             ("arm.EI", 1e-310), ("arm.EI", 1e301), ("hub.inertia", 0.0)])
def test_the_linearisation_refuses_a_parameter_where_the_fmu_does(model, example_fmu, name, value):
    """``linearize --set arm.EI=-1`` printed the matrices of an unstable plant and ``=0`` ended in a traceback
    (a singular static deflection), while the FMU refuses both: the linearisation refuses exactly what the
    FMU's own fmi2SetReal refuses (its C range check, fmu_src/variables.c: finite, not subnormal, within the
    bounds), in its words, and takes what it takes (``hub.inertia = 0``, its inclusive bound)."""
    from flexlink.run.host import FmuCallError, FmuHost

    host = FmuHost(example_fmu("rotating_link"))
    try:
        try:
            host.set_values({name: value})
            refused = None
        except FmuCallError as e:
            refused = e.reason
    finally:
        host.close()
    if refused is None:
        linear_plant(model, parameters={name: value})
        return
    with pytest.raises(FlexlinkError) as ours:
        linear_plant(model, parameters={name: value})
    assert refused.endswith(str(ours.value)), (refused, str(ours.value))
