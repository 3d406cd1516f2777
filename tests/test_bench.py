"""``flexlink bench`` (CI size): the work–precision rows are what they claim to be.

The SS22 rows converge at order 2 against the reference (so the "error" column measures integration
error, not a modelling difference), the reference is far more accurate than any row, and tighter
tolerances make CVODES more accurate.  Below: issue 6's report generator (benchmarks/report.py) at CI size,
structural facts only (the marked README block, the integrator's counters, convergence of the rows)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.bench import run_bench

FULL = os.environ.get("FLEXLINK_FULL") == "1"


@pytest.fixture(scope="module")
def quick_bench():
    # over 2.5 s, as before --quick timed its horizon (which gives 1 s here, or 0.5 s on a slower run)
    return run_bench("examples/rotating_link_linear.toml", quick=True, repeats=1, stop=2.5)


def test_rows_and_reference(quick_bench):
    rows, info = quick_bench
    assert info["reference_error"] < 1e-6          # rtol 1e-10 against 1e-9 (a full run's 1e-12 against 1e-13: 1e-10)
    assert info["stop_time"] == 2.5 and info["reference"] == "CVODES rtol 1e-10"
    assert {r.method for r in rows} >= {"ss22 (FMU)", "fmpy CVODE (ME)", "cvodes", "idas", "scipy Radau"}
    # order 4 is refused (a failed row) exactly beyond its stability bound ω_max Δt <= 0.3 (fmu_src/richardson.c)
    f_max = max(natural_frequencies(build_model(load_scene("examples/rotating_link_linear.toml"))).frequencies_hz)
    for r in rows:
        if r.method.startswith("ss22 order 4"):
            h = float(r.setting.split("=")[1])
            assert (r.failure is not None) == (2 * np.pi * f_max * h > 0.3), (r.setting, r.failure)
        if r.failure is not None:
            assert "unstable" in r.failure
            continue
        assert np.isfinite(r.error) and r.cpu_s_per_simulated_s > 0
        if r.method == "ss22 (FMU)":
            assert r.error > 10 * info["reference_error"]


def test_ss22_rows_converge_at_order_two(quick_bench):
    rows, _ = quick_bench
    errors = [r.error for r in rows if r.method == "ss22 (FMU)"]        # steps halve from row to row
    orders = [np.log2(a / b) for a, b in zip(errors[:-1], errors[1:], strict=True)]
    assert all(abs(p - 2.0) < 0.5 for p in orders[1:]), orders


def test_cvodes_tighter_tolerance_is_more_accurate(quick_bench):
    rows, _ = quick_bench
    errors = [r.error for r in rows if r.method == "cvodes"]
    assert errors[1] < errors[0] / 10


def test_cli_json(tmp_path):
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "bench", "examples/rotating_link_linear.toml",
                          "--quick", "--repeats", "1", "--json", "--report", str(tmp_path / "r.md")],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    rows = json.loads(out.stdout)
    assert set(rows[0]) == {"method", "setting", "cpu_s_per_simulated_s", "error", "lu_per_step",
                            "iterations_per_step", "failure", "below_reference_error"}
    assert (tmp_path / "r.md").read_text().startswith("# Speed against error")


# --------------------------------------------------------------- issue 22: --quick on a stiff scene, --stop
# steel_beam_raise (5 FE, 23 kHz highest mode): its reference takes about a minute a simulated second at rtol 1e-10.
# At CI size the whole quick study runs over 2 ms (--stop); with FLEXLINK_FULL=1 over the rule's horizon.

@pytest.fixture(scope="module")
def stiff_quick():
    return run_bench("examples/steel_beam_raise.toml", quick=True, repeats=1, stop=None if FULL else 0.002)


def test_a_stiff_scene_gets_a_short_quick_horizon_whose_reference_converges():
    """--quick shortens the horizon of a scene whose reference is expensive, and the error it states for its
    reference (CVODES at rtol 1e-10, its difference from rtol 1e-9) holds: against an independent CVODES run
    (flexlink.mechanics.reference, its own ODE, at rtol 1e-12) the reference is off by no more than the stated
    error, and by more than a thousandth of it (the statement is not vacuous either)."""
    from flexlink.tools.bench import QUICK_STOP, bench_case, reference_outputs, reference_pair, relative_error

    model = build_model(load_scene("examples/steel_beam_raise.toml"))
    case, horizon = bench_case(model, quick=True)
    assert horizon.stop < QUICK_STOP and (horizon.rtol, horizon.check_rtol) == (1e-10, 1e-9)
    assert "shortened" in horizon.why and len(case.times) == 51      # sampled every fiftieth of the horizon
    ref, check = reference_pair(case, horizon.rtol, horizon.check_rtol)
    stated = relative_error(case, ref, check)
    actual = relative_error(case, ref, reference_outputs(case, 1e-12))
    assert 1e-3 * stated < actual <= stated, (actual, stated)


def test_every_quick_row_is_above_the_reference_error_or_flagged(stiff_quick):
    """No row is judged below the reference: its error is above the reference's own, or the report and the JSON
    flag it.  Order 4 beyond its stability bound is a failed row with the FMU's reason (fmi2Discard)."""
    from flexlink.tools.bench import report_markdown, rows_json

    rows, info = stiff_quick
    report = report_markdown(rows, info)
    flags = rows_json(rows, info)
    assert info["stop_time"] < 2.5 and info["reference"] == "CVODES rtol 1e-10"
    assert {r.method for r in rows} >= {"ss22 (FMU)", "fmpy CVODE (ME)", "cvodes", "idas", "scipy Radau"}
    for r, j in zip(rows, flags, strict=True):
        if r.failure is not None:
            assert r.method.startswith("ss22 order 4") and "unstable" in r.failure
            assert f"failed: {r.failure}" in report
            continue
        assert np.isfinite(r.error) and r.cpu_s_per_simulated_s > 0
        assert (r.error > info["reference_error"]) != j["below_reference_error"]
        assert (f"{r.error:.2e} (≤ reference)" in report) == j["below_reference_error"]
    assert any(r.failure for r in rows)
    ss22 = [r.error for r in rows if r.method == "ss22 (FMU)"]
    assert min(ss22) > 10 * info["reference_error"]


def test_the_tip_is_the_last_link_that_bends():
    """six_axis_arm ends in a rigid tool (no tip deflection): the bench's tip output is the last link whose
    deformation has v in the scene file (the bench used to ask for tool.tip.v: a KeyError)."""
    import tomllib

    from flexlink.tools.bench import default_case

    path = "examples/six_axis_arm.toml"
    with open(path, "rb") as f:
        links = tomllib.load(f)["link"]
    bending = [k["name"] for k in links if "v" in k.get("deformation", ["v"])]
    assert links[-1]["name"] not in bending
    case = default_case(build_model(load_scene(path)), stop=0.05)
    assert f"{bending[-1]}.tip.v" in case.outputs


def test_cli_stop_sets_the_horizon(tmp_path):
    """--stop 0.2 with --quick: the rows are over 0.2 s (sampled every 4 ms, a fiftieth), the reference at rtol
    1e-10 as for any quick run, and the report says so."""
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "bench", "examples/rotating_link_linear.toml",
                          "--quick", "--stop", "0.2", "--repeats", "1", "--report", str(tmp_path / "r.md")],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    report = (tmp_path / "r.md").read_text()
    assert "over 0.2 s (--stop), sampled every 0.004 s; reference CVODES rtol 1e-10" in report


def test_a_scene_the_manoeuvre_leaves_at_rest_is_refused():
    """spatial_cantilever's hub is held and nothing else loads it (no gravity, no input): the link stays
    exactly at rest, so every method's error against the reference would be 0/0.  One line, exit status 2,
    naming the outputs, before any FMU is built or timed."""
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "bench", "examples/spatial_cantilever.toml",
                          "--quick", "--stop", "0.01", "--repeats", "1"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and out.stdout == ""
    (line,) = out.stderr.strip().splitlines()
    assert "leaves arm.tip.v and hub.tau at exactly 0" in line


# --------------------------------------------------------------------------- issue 6: benchmarks/report.py
# One CI-size run of the report generator (about 35 s); the tests below read its report.json.  Timings are
# never asserted (a shared 2-core machine), only what the code's structure and the numerics guarantee.

REPO = Path(__file__).resolve().parent.parent
MARKED = "# Title\n\nbefore the block\n\n<!-- perf:begin -->\nold figures\n<!-- perf:end -->\n\nafter the block\n"


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    readme = out / "README.md"
    readme.write_text(MARKED)
    res = subprocess.run([sys.executable, str(REPO / "benchmarks" / "report.py"), "--quick", "--repeats", "1",
                          "--out", str(out), "--readme", str(readme)], capture_output=True, text=True, timeout=600,
                         cwd=REPO)
    assert res.returncode == 0, res.stderr
    return out, json.loads((out / "report.json").read_text())


def test_report_writes_the_marked_section_only(quick_report):
    out, data = quick_report
    text = (out / "README.md").read_text()
    assert text.count("<!-- perf:begin -->") == 1 and text.count("<!-- perf:end -->") == 1
    assert text.startswith("# Title\n\nbefore the block\n\n<!-- perf:begin -->")
    assert text.endswith("<!-- perf:end -->\n\nafter the block\n")
    assert "old figures" not in text and "| target (issue 6) |" in text
    assert (out / "report.md").read_text().startswith("# Performance report (issue 6)")
    assert (out / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert {"floor", "cosim", "stiff", "builds", "verdicts"} <= set(data)
    # re-rendering from the JSON rewrites the same block in place (one pair of markers, surroundings kept)
    again = subprocess.run([sys.executable, str(REPO / "benchmarks" / "report.py"), "--from-json",
                            str(out / "report.json"), "--out", str(out), "--readme", str(out / "README.md")],
                           capture_output=True, text=True, timeout=120, cwd=REPO)
    assert again.returncode == 0, again.stderr
    assert (out / "README.md").read_text() == text


def test_report_refuses_a_readme_without_markers(tmp_path):
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import report
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    readme = tmp_path / "README.md"
    readme.write_text("# no markers\n")
    with pytest.raises(SystemExit):
        report.rewrite_readme(readme, "<!-- perf:begin -->\nx\n<!-- perf:end -->")
    assert readme.read_text() == "# no markers\n"


def test_floor_driver_counters(quick_report):
    """What ss22.c and cs_step.c guarantee: equal internal steps (stop / step of them, 3 SS22 steps each
    for order 4); the linear model without gravity takes one residual and no Newton iteration a step and
    factorises its constant matrix at most once per cached step size; the Newton model evaluates one
    residual per iteration and iterates at least once a step."""
    _, data = quick_report
    rows = {(r["scene"], r["order"]): r for r in data["floor"]}
    assert set(rows) == {(s, o) for s in ("rotating_link_linear", "rotating_link") for o in (2, 4)}
    for (_, order), r in rows.items():
        assert r["ss22_steps"] == (3 if order == 4 else 1) * round(r["simulated_s"] / r["step"])
        assert r["floor_s"] > 0 and r["step_s"] > 0 and np.isfinite(r["per_step_over_floor"])
    lin = rows[("rotating_link_linear", 2)]
    assert lin["linear_in_state"] == 1 and lin["jacobian_constant"] == 1
    assert lin["newton_iterations"] == 0 and lin["residual_evaluations"] == lin["ss22_steps"]
    assert 1 <= lin["factorisations"] <= 2
    nonlin = rows[("rotating_link", 2)]
    assert nonlin["linear_in_state"] == 0
    assert nonlin["newton_iterations"] >= nonlin["ss22_steps"]
    assert nonlin["residual_evaluations"] == nonlin["newton_iterations"]


def test_cosim_loop_rows_are_finite_and_cvodes_per_step_converges(quick_report):
    _, data = quick_report
    for key in ("linear", "second-order"):
        rows = data["cosim"][key]["rows"]
        ref_error = data["cosim"][key]["info"]["reference_error"]
        assert {r["method"] for r in rows} == {"flexlink FMU", "python FMU (RK4)", "cvodes per step"}
        for r in rows:
            assert np.isfinite(r["error"]) and r["error"] > 10 * ref_error and r["cpu_s_per_simulated_s"] > 0
        cv = [r["error"] for r in rows if r["method"] == "cvodes per step"]          # rtol 1e-4, then 1e-7
        assert cv[1] < cv[0] / 10
        ours = [r["error"] for r in rows if r["method"] == "flexlink FMU"]           # step h, then h/4: order 2
        assert 16 / 2 < ours[0] / ours[1] < 16 * 2


def test_python_fmu_agrees_with_the_reference(quick_report):
    """The PythonFMU FMU integrates the same equations by RK4: at 1 ms its error against CVODES is within the
    RK4 estimate (ω h ≤ 0.25 for the fastest mode, 34 Hz: global error well below 1e-4), and halving its
    step divides the error by about 2⁴."""
    _, data = quick_report
    for key in ("linear", "second-order"):
        py = [r for r in data["cosim"][key]["rows"] if r["method"] == "python FMU (RK4)"]
        assert [r["setting"] for r in py] == ["RK4 step=0.001", "RK4 step=0.0005"]
        assert py[0]["error"] < 1e-4
        assert 16 / 2 < py[0]["error"] / py[1]["error"] < 16 * 2


def test_stiff_case_modal_split_matches_the_model_analysis():
    """The low-frequency measure of benchmarks/stiff_case.py: its modes are flexlink.mechanics.analysis's natural
    frequencies, and Φ_low Φ_lowᵀ M is a projection that keeps the low modes and removes the others."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import stiff_case
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    from flexlink.mechanics.analysis import natural_frequencies
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene

    model = build_model(load_scene(stiff_case.SCENE))
    freq, P, c = stiff_case.modal_projection(model)
    expected = natural_frequencies(model).frequencies_hz
    assert np.allclose(freq[freq > 1e-3], expected, rtol=1e-6)
    assert np.allclose(P @ P, P, atol=1e-9 * np.abs(P).max())
    assert np.linalg.matrix_rank(P, tol=1e-9 * np.abs(P).max()) == 1 + int(np.sum(np.array(expected) < 50.0))
    assert np.count_nonzero(c[1:]) == model.n_q - 1 and c[0] == 0.0      # tip deflection: the elastic coordinates


# ------------------------------------------------------------------ the integrator's counters (logStatistics)

def test_statistics_count_what_the_integrator_does(example_fmu):
    """The logStatistics counters against what the run must take: 0.2 s in 10 ms communication steps of ten
    1 ms SS22 steps is exactly 200 steps; a model linear in its state solves once a step without Newton
    iterations and factorises its constant matrix once; a nonlinear one evaluates one residual per Newton
    iteration (fmu_src/ss22.c)."""
    from flexlink.run.simulate import SlaveRunner

    for name, linear in (("rotating_link_linear", True), ("rotating_link", False)):
        with SlaveRunner(example_fmu(name)) as runner:
            runner.run(0.2, 0.01, start={"solver.step": 1e-3}, inputs=lambda t: {"hub.tau": 0.2})
            first = runner.solver_statistics()
            runner.run(0.1, 0.01, start={"solver.step": 1e-3}, inputs=lambda t: {"hub.tau": 0.2})
            second = runner.solver_statistics()           # counted from initialisation: the reset run alone
        assert first["steps"] == 200 and second["steps"] == 100
        if linear:
            assert first["newton_iterations"] == 0 and first["factorisations"] == 1
            assert first["residual_evaluations"] == first["steps"]
        else:
            assert first["newton_iterations"] == first["residual_evaluations"] >= first["steps"]


def test_simplified_newton_keeps_its_matrix_on_the_six_axis_arm(example_fmu):
    """Issue 22's target for chains: at most 0.1 factorisations per SS22 step at the scene's step.  The six-axis
    arm's Newton matrix changes slowly, so simplified Newton must keep reusing the newest factorisation (it
    once picked an older matrix of the same step size from the cache and refreshed 1.7 times a step)."""
    from flexlink.run.simulate import SlaveRunner

    with SlaveRunner(example_fmu("six_axis_arm")) as runner:
        runner.run(0.3, 0.01)
        stats = runner.solver_statistics()
    assert stats["steps"] == 600
    assert stats["factorisations"] <= 0.1 * stats["steps"], stats


def test_a_refused_setting_is_a_failed_row(example_fmu):
    """bench_ss22 records a setting the FMU refuses as a failed row with the FMU's reason and goes on."""
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import bench_ss22, default_case, report_markdown

    model = build_model(load_scene("examples/rotating_link_linear.toml"))
    case = default_case(model, stop=0.2)
    ref = {n: np.zeros(len(case.times)) + 1.0 for n in case.outputs}
    rows = bench_ss22(case, example_fmu("rotating_link_linear"), [1e-300, 1e-3], [(0.5, 0.5)], ref, repeats=1)
    assert rows[0].failure is not None and "internal steps" in rows[0].failure
    assert rows[0].as_dict()["error"] is None
    assert rows[1].failure is None and rows[1].lu_per_step == pytest.approx(1 / 200)
    assert rows[1].iterations_per_step == 0
    assert "failed: " in report_markdown(rows, {"scene": "x", "outputs": case.outputs, "stop_time": 0.2,
                                                "reference": "-", "reference_error": 0.0})


def test_timing_splits_a_run_longer_than_one_dostep_may_integrate(example_fmu):
    """time_slave times one fmi2DoStep per input switch, but one fmi2DoStep takes at most 10⁶ internal steps
    (fmu_src/cs_step.c refuses more): 0.3 s without a switch at a 0.25 µs step is 1.2 × 10⁶ of them (a law-driven
    scene at ``explain --error-target``'s halved steps once ended in a traceback there).  It is timed in
    pieces, and the pieces integrate the same run: the end state equals a 10 ms communication-step run's."""
    from flexlink.mechanics.model import build_model
    from flexlink.run.simulate import SlaveRunner
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case, time_slave

    case = default_case(build_model(load_scene("examples/rotating_link_linear.toml")), stop=0.3)
    assert not case.switches                             # one interval of 0.3 s
    start = {"solver.step": 2.5e-7, "hub.tau": 0.2}
    with SlaveRunner(example_fmu("rotating_link_linear")) as runner:
        cost = time_slave(runner, case, start, repeats=1)
        timed = runner.get_real(case.outputs)
        reference = runner.run(0.3, 0.01, start=start, outputs=case.outputs)
    assert 0 < cost < float("inf")
    assert abs(timed[0]) > 1e-3                          # the hub turned: the run was integrated
    assert timed == pytest.approx([reference[n][-1] for n in case.outputs], rel=1e-9, abs=1e-12)


def test_a_stop_between_samples_ends_the_samples_before_it():
    """stop = 0.05 s sampled every 3 ms: the samples end at 48 ms, inside every method's run (rounding the count
    put one at 51 ms, past the CasADi runs' last point, and the comparison ended in a StopIteration); CVODES's
    states come back at every sample, finite; a sample time of 0 is one FlexlinkError."""
    from flexlink.errors import FlexlinkError
    from flexlink.tools.bench import casadi_states, default_case

    model = build_model(load_scene("examples/rotating_link_linear.toml"))
    case = default_case(model, stop=0.05, sample=0.003)
    assert case.times[-1] == pytest.approx(0.048) and case.times.max() <= case.stop
    _, X = casadi_states(case, "cvodes", 1e-8, repeats=1)
    assert X.shape == (len(case.times), 2 * model.n_q) and np.all(np.isfinite(X))
    with pytest.raises(FlexlinkError, match="must be > 0"):
        default_case(model, stop=0.05, sample=0.0)
