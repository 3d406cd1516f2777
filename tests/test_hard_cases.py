"""Hard cases (benchmarks/hard_cases/ and the examples), at a size CI affords; FLEXLINK_FULL=1 runs the
long variants.  Each states what must hold and checks it against the model's own analysis or the
CVODES reference."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np
import pytest

from flexlink.export.cache import cached_fmu
from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.run.simulate import SlaveRunner
from flexlink.scene.loader import load_scene, parse_scene
from flexlink.tools.bench import default_case, reference_outputs

HARD = Path(__file__).resolve().parent.parent / "benchmarks" / "hard_cases"
FULL = os.environ.get("FLEXLINK_FULL") == "1"


def _fmu(scene, tmp_path):
    model = build_model(scene)
    return model, cached_fmu(scene, model=model)


def test_many_modes_low_frequency_error_at_a_step_resolving_only_the_low_modes(tmp_path):
    """20 clamped modes (frequency ratio 350, stiffness ratio 1.2e5): Δt = 2 ms resolves only the modes below
    about 25 Hz (20 steps a period); the hub angle, a low-frequency signal, stays within 1e-3 of CVODES."""
    model, fmu = _fmu(load_scene(HARD / "many_modes.toml"), tmp_path)
    f = natural_frequencies(model).frequencies_hz
    assert (f[-1] / f[0]) ** 2 > 1e4
    case = default_case(model, stop=5.0 if FULL else 1.5)
    ref = reference_outputs(case, 1e-12 if FULL else 1e-9)
    with SlaveRunner(fmu) as runner:
        res = runner.run(case.stop, 0.01, inputs=case.inputs_at, start={"solver.step": 2e-3}, outputs=case.outputs)
    theta = case.outputs[0]
    err = np.sqrt(np.mean((res[theta] - ref[theta]) ** 2)) / np.sqrt(np.mean(ref[theta] ** 2))
    assert err < 1e-3


@pytest.mark.parametrize("name", ["quasi_static_twist", "massless_motor"])
def test_singular_mass_directions(tmp_path, name):
    """Twist without polar inertia, an elastic joint without motor inertia: M is singular, so q'' = M⁻¹(…) has no
    explicit form and CVODES on it fails; SS22's step matrix M + Θ₁ΔtC + Θ₂Δt²/2 K is regular."""
    scene = load_scene(HARD / f"{name}.toml")
    model, fmu = _fmu(scene, tmp_path)
    q, _ = model.start_state()
    M = np.asarray(model.mass_matrix_function()(q, model.default_inputs(0.0), model.p0))
    assert np.linalg.matrix_rank(M) < model.n_q          # no explicit ODE form for CVODES or solve_ivp
    with SlaveRunner(fmu) as runner:
        res = runner.run(2.0, 0.01, inputs=lambda t: {"hub.tau": 0.2}, outputs=["hub.theta", "arm.tip.v"])
    assert np.all(np.isfinite(res["hub.theta"])) and np.all(np.isfinite(res["arm.tip.v"]))
    # the rigid-body motion is right: θ ≈ τ t²/(2 J) with J the rigid inertia about the axis
    J = scene.joints[0].inertia + scene.links[0].linear_density * scene.links[0].length ** 3 / 3
    pay = scene.links[0].payload
    J += pay.mass * (scene.links[0].length ** 2 + sum(x * x for x in pay.offset))
    assert res["hub.theta"][-1] == pytest.approx(0.2 * 2.0**2 / (2 * J), rel=0.05)


def _tip_until_refused(fmu, rate: float) -> tuple[np.ndarray, list[str]]:
    """|arm.tip.v| at each 5 ms communication point of a 1 s run spinning at ``rate`` after a 0.5 N m pulse,
    up to the step the FMU refuses (if any), and its log."""
    with SlaveRunner(fmu, logging=True) as runner:
        s, vr = runner.slave, runner.vr
        s.setReal([vr["hub.initial_rate"]], [rate])
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.exitInitializationMode()
        tips, t = [], 0.0
        while t < 1.0 - 1e-9:
            s.setReal([vr["hub.tau"]], [0.5 if t < 0.02 else 0.0])
            tips.append(abs(s.getReal([vr["arm.tip.v"]])[0]))
            try:
                s.doStep(currentCommunicationPoint=t, communicationStepSize=0.005)
            except Exception:            # fmpy raises on fmi2Discard
                break
            t += 0.005
        return np.array(tips), list(runner.messages)


def test_first_order_model_diverges_past_its_critical_rate_and_second_order_does_not(tmp_path):
    """Seed 000 fig. 3.2, in the time domain: spinning at 1.5× the first-order model's critical rate (free hub,
    where flexlink modes reports the divergence), a small torque pulse grows without bound in the first-order
    model and stays small in the second-order model.  The first-order FMU does not return the runaway past the
    beam model's validity: its guard refuses the step where the deflection passes 20 % of the link's length."""
    data = tomllib.loads(Path("examples/rotating_link.toml").read_text())
    w = 20.0
    tips = {}
    for kin in ("first-order", "second-order"):
        data["link"][0]["kinematics"] = kin
        scene = parse_scene(data)
        model, fmu = _fmu(scene, tmp_path)
        assert bool(natural_frequencies(model, rate=w).unstable_hz) == (kin == "first-order")
        tips[kin], log = _tip_until_refused(fmu, w)
        refused = [m for m in log if "validity" in m]
        assert bool(refused) == (kin == "first-order"), log[-3:]
    length = data["link"][0]["length"]
    # the second-order deflection stays a few centimetres for the whole second; the first-order one runs
    # away, tens of times larger, up to the validity limit (0.2 L) where it is refused
    assert len(tips["second-order"]) == 200 and tips["second-order"].max() < 0.05
    assert tips["first-order"].max() > 10 * tips["second-order"].max()
    assert tips["first-order"].max() <= 0.2 * length


@pytest.mark.parametrize(("theta", "conserved"), [((0.5, 0.5), True), ((0.6, 0.6), False)])
def test_long_undamped_run_energy(tmp_path, theta, conserved):
    """Undamped linear link, 100 s (1000 s with FLEXLINK_FULL=1) after a torque pulse: Θ = ½ keeps the energy to
    round-off (SS22 is then the trapezoidal rule, which conserves the energy of a linear system), Θ > ½
    dissipates it, the more the higher the mode."""
    model, fmu = _fmu(load_scene("examples/rotating_link_linear.toml"), tmp_path)
    stop = 1000.0 if FULL else 100.0
    with SlaveRunner(fmu) as runner:
        res = runner.run(stop, 0.5, inputs=lambda t: {"hub.tau": 0.2 if t < 0.5 else 0.0},
                         start={"solver.theta1": theta[0], "solver.theta2": theta[1]},
                         outputs=["energy.kinetic", "energy.potential", "arm.tip.v"])
    E = (res["energy.kinetic"] + res["energy.potential"])[1:]          # free from t = 0.5 s on
    drift = abs(E[-1] - E[0]) / E[0]
    print(f"Θ = {theta}: relative energy drift over {stop:g} s: {drift:.2e}")
    if conserved:
        assert drift < 1e-9
    else:
        assert E[-1] < E[0]
