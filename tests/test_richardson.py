"""The order-4 option (Richardson extrapolation of the symmetric SS22) is used only where it is stable.

The scheme's amplification on an undamped mode is computed here from its own equations (independent of the
C code): plain SS22 at Θ = ½ keeps every mode's amplitude for any ωΔt, the extrapolation does not, and its
excess radius decides the bound RICHARDSON_MAX_OMEGA_STEP = 0.3 of fmu_src/richardson.c.  The FMU's highest
frequency, found in C by power iteration, is checked against flexlink.mechanics.analysis (scipy's eigenvalues
of the linearised model), and the FMU refuses exactly the steps beyond the bound."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from flexlink.errors import FlexlinkError
from flexlink.export.cache import cached_fmu
from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.run.simulate import SlaveRunner, simulate
from flexlink.scene.loader import load_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
BOUND = 0.3                   # fmu_src/internal.h RICHARDSON_MAX_OMEGA_STEP
MAX_STEPS = 1e6               # fmu_src/cs_step.c: internal steps one fmi2DoStep may take


def ss22_map(h: float, omega: float) -> np.ndarray:
    """One SS22 step (Θ1 = Θ2 = ½) on q'' + ω² q = 0 as a linear map of (q, v, α): the end-of-step
    acceleration α solves α + ω² (q + Θ1 h v + Θ2 h²/2 α) = 0; then q += h v + h²/2 α, v += h α."""
    cv, cq = 0.5 * h, 0.25 * h * h
    a_q, a_v = -omega**2 / (1 + omega**2 * cq), -omega**2 * cv / (1 + omega**2 * cq)
    return np.array([[1 + 0.5 * h * h * a_q, h + 0.5 * h * h * a_v, 0.0],
                     [h * a_q, 1 + h * a_v, 0.0],
                     [a_q, a_v, 0.0]])


def richardson_map(h: float, omega: float) -> np.ndarray:
    """q, v ← fine + (fine − coarse)/3 with fine = two steps of h/2, coarse = one of h (fmu_src/cs_step.c)."""
    coarse, fine = ss22_map(h, omega), ss22_map(h / 2, omega) @ ss22_map(h / 2, omega)
    out = fine.copy()
    out[:2] = fine[:2] + (fine[:2] - coarse[:2]) / 3
    return out


def radius(m: np.ndarray) -> float:
    return float(max(abs(np.linalg.eigvals(m))))


def test_plain_ss22_keeps_every_undamped_mode_and_richardson_does_not():
    for x in (0.01, 0.3, 1.0, 10.0, 1e3):
        assert radius(ss22_map(x, 1.0)) == pytest.approx(1.0, abs=1e-12)
    excess = [radius(richardson_map(x, 1.0)) - 1 for x in (0.1, 0.2, 0.4)]
    assert all(e > 0 for e in excess)
    assert np.log2(excess[1] / excess[0]) == pytest.approx(6.0, abs=0.3)     # grows like (ωΔt)^6
    assert radius(richardson_map(1e4, 1.0)) == pytest.approx(5 / 3, rel=1e-3)   # unresolved: |4·1 − (−1)|/3


def test_the_bound_keeps_an_unexcited_mode_within_a_factor_two_over_a_do_step():
    assert radius(richardson_map(BOUND, 1.0)) ** MAX_STEPS <= 2.0
    assert radius(richardson_map(1.5 * BOUND, 1.0)) ** MAX_STEPS > 2.0       # the bound is not slack


def _highest_frequency_in_message(messages: list[str]) -> float:
    found = re.search(r"highest natural frequency, ([0-9.e+]+) Hz", messages[-1])
    assert found, messages[-1]
    return float(found.group(1))


@pytest.mark.parametrize("name", ["rotating_link", "plate_raise"])
def test_order_four_is_refused_beyond_the_bound_with_the_scenes_highest_frequency(name):
    scene = load_scene(EXAMPLES / f"{name}.toml")
    f_max = max(natural_frequencies(build_model(scene)).frequencies_hz)
    limit = BOUND / (2 * np.pi * f_max)
    with SlaveRunner(cached_fmu(scene)) as runner:
        runner.run(0.02, 0.01, start={"solver.order": 4, "solver.step": 0.95 * limit})   # within: runs
        with pytest.raises(FMICallException, match="discard"):
            runner.run(0.02, 0.01, start={"solver.order": 4, "solver.step": 1.05 * limit})
        assert "solver.order = 4" in runner.messages[-1] and "use order 2" in runner.messages[-1]
        assert _highest_frequency_in_message(runner.messages) == pytest.approx(f_max, rel=1e-3)


def test_a_stiffer_arm_set_during_the_run_is_checked_again():
    """Four times EI doubles every frequency: a step that was within the bound is no longer."""
    scene = load_scene(EXAMPLES / "rotating_link.toml")
    f_max = max(natural_frequencies(build_model(scene)).frequencies_hz)
    h = 0.7 * BOUND / (2 * np.pi * f_max)
    with SlaveRunner(cached_fmu(scene)) as runner:
        runner.run(0.01, 0.01, start={"solver.order": 4, "solver.step": h})
        s, vr = runner.slave, runner.vr
        s.setReal([vr["arm.EI"]], [4 * s.getReal([vr["arm.EI"]])[0]])
        with pytest.raises(FMICallException, match="discard"):
            s.doStep(currentCommunicationPoint=0.01, communicationStepSize=0.01)
        assert _highest_frequency_in_message(runner.messages) == pytest.approx(2 * f_max, rel=1e-3)


def test_simulate_turns_the_refusal_into_one_error():
    with pytest.raises(FlexlinkError, match="order = 4"):
        simulate(cached_fmu(EXAMPLES / "plate_raise.toml"), 0.05, step=0.01, start_values={"solver.order": 4})


def _step_floor():
    """benchmarks/step_floor.py: the C driver compiled with an FMU's own sources, its SS22 counters."""
    import importlib
    import sys

    bench = str(Path(__file__).resolve().parents[1] / "benchmarks")
    sys.path.insert(0, bench)
    try:
        return importlib.import_module("step_floor")
    finally:
        sys.path.remove(bench)


def test_each_order_four_start_adds_its_last_miss_and_saves_newton_iterations(tmp_path):
    """fmu_src/cs_step.c, richardson_step: the full step's start (the line through the last half steps) and the
    half steps' (from the full step's acceleration) miss in the same direction from one internal step to the next,
    so each adds its own last miss where a vote says that helps.  The same FMU sources compiled with and without
    (RICHARDSON_FEEDBACK=0) on the bench manoeuvre of the rotating link at order 4 (1 ms, w_max dt = 0.21): fewer
    Newton iterations for the same steps (measured 2.23 -> 2.09 a step).  That every step still meets its Newton
    tolerance is the stops' business: a start with a miss added is judged on its own first ratios and ends a
    step on its first increment only within a third of the tolerance (tests/c/predictor_check.c, section 9;
    docs/integrator.md, "Order 4's starts")."""
    from flexlink.tools.bench import default_case

    floor = _step_floor()
    scene = EXAMPLES / "rotating_link.toml"
    fmu = cached_fmu(scene)
    case = default_case(build_model(load_scene(scene)), stop=1.0)
    runs = {}
    for feedback in (0, 1):
        exe = floor.compile_driver(fmu, tmp_path / f"fb{feedback}", defines=(f"RICHARDSON_FEEDBACK={feedback}",))
        runs[feedback] = floor.measure(exe, fmu, case, step=1e-3, order=4, repeats=1)
    base, fed = runs[0], runs[1]
    assert fed["ss22_steps"] == base["ss22_steps"] == 3000
    assert fed["newton_iterations"] < 0.97 * base["newton_iterations"], (fed["newton_iterations"],
                                                                         base["newton_iterations"])
