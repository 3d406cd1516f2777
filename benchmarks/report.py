"""Issue 6's measurements in one command: writes report.md, report.json and report.png, and the block of
docs/performance.md between ``<!-- perf:begin -->`` and ``<!-- perf:end -->`` (its figure copied to docs/img/).

    python benchmarks/report.py                  # full size (about 15 min on the 2-core machine)
    python benchmarks/report.py --quick --out DIR [--page PAGE_COPY.md]   # CI size

Runs, on the one-link 3-mode seed-000 link (``examples/rotating_link_linear.toml``) and its second-order
version (``examples/rotating_link.toml``):

1. cost per internal SS22 step against its floor, in the same process (``benchmarks/step_floor.py``);
2. the co-simulation loop at 1 ms through fmpy: the FMU, CVODES restarted at every step, a PythonFMU FMU
   (``benchmarks/cosim_loop.py``);
3. the stiff case, 20 clamped modes (``benchmarks/stiff_case.py``);
4. ``flexlink bench`` at full size on both scenes;
5. the build time of the one-link FMU and of the largest example.

Every figure is a median of repeated runs, and every comparison a ratio measured in the same run.  The
figures of ``benchmarks/fmu_speed.py --large`` and ``benchmarks/closed_loop.py`` are kept apart
(docs/performance.md, above the generated block).  ``--quick`` runs everything at CI size (short runs, one
repeat, few settings, no largest-example build) and touches no page unless ``--page`` is given.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
# factorisations ss22.c keeps (its SS22_CACHE): more than that in a run means the cache is being thrashed
SS22_CACHE = int(next(line.split()[2] for line in (ROOT / "fmu_src" / "ss22.h").read_text().splitlines()
                      if line.startswith("#define SS22_CACHE")))
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

import cosim_loop  # noqa: E402
import step_floor  # noqa: E402
import stiff_case  # noqa: E402

SCENES = {"linear": ROOT / "examples" / "rotating_link_linear.toml",
          "second-order": ROOT / "examples" / "rotating_link.toml"}
BEGIN, END = "<!-- perf:begin -->", "<!-- perf:end -->"
LEVELS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7)
TARGETS = {"floor": 3.0, "cvodes_per_step": 4.0, "python_fmu": 2.5, "stiff_error": 1e-3, "stiff_speedup": 10.0,
           "build_s": 5.0}


# ------------------------------------------------------------------------------------------- measuring

def build_times(quick: bool, tmp: Path) -> dict:
    """Build time of the one-link FMUs (median of 3; 1 in quick) and of the largest example (by coordinates)."""
    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene

    out: dict = {"fmus": {}, "builds": []}
    for key, path in SCENES.items():
        reps = [build_fmu(path, tmp / f"{key}-{k}.fmu") for k in range(1 if quick else 3)]
        out["fmus"][key] = str(reps[-1].fmu)
        out["builds"].append({"scene": path.stem, "n_q": reps[-1].n_coordinates,
                              "build_s": statistics.median(sum(r.seconds.values()) for r in reps),
                              "generated_c_kib": reps[-1].generated_c_bytes / 1024})
    if not quick:
        sizes = {p: build_model(load_scene(p)).n_q for p in sorted((ROOT / "examples").glob("*.toml"))}
        largest = max(sizes, key=lambda p: (sizes[p], p.name))
        reps = [build_fmu(largest, tmp / f"largest-{k}.fmu") for k in range(3)]
        out["builds"].append({"scene": largest.stem, "n_q": reps[-1].n_coordinates, "largest_example": True,
                              "build_s": statistics.median(sum(r.seconds.values()) for r in reps),
                              "generated_c_kib": reps[-1].generated_c_bytes / 1024})
    return out


def measure_all(quick: bool, repeats: int | None) -> dict:
    from flexlink.tools.bench import run_bench

    data: dict = {"quick": quick, "machine": f"{platform.machine()}, {platform.python_implementation()} "
                  f"{platform.python_version()}", "date": time.strftime("%Y-%m-%d")}
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        builds = build_times(quick, tmp)
        data["builds"] = builds["builds"]
        data["floor"] = []
        for key, path in SCENES.items():
            data["floor"] += step_floor.measure_scene(path, orders=(2, 4), repeats=repeats or (3 if quick else 11),
                                                      stop=1.0 if quick else 5.0, fmu=builds["fmus"][key])
        data["cosim"] = {}
        for key, path in SCENES.items():
            rows, info = cosim_loop.run_cosim(path, quick=quick, repeats=repeats, fmu=builds["fmus"][key])
            data["cosim"][key] = {"rows": rows, "info": info}
    rows, info = stiff_case.run_stiff(quick=quick, repeats=repeats)
    data["stiff"] = {"rows": rows, "info": info}
    data["bench"] = {}
    if not quick:
        for key, path in SCENES.items():
            rows, info = run_bench(path, repeats=repeats)
            data["bench"][key] = {"rows": [r.as_dict() for r in rows], "info": info}
    data["wall_s"] = time.perf_counter() - t_start
    data["verdicts"] = verdicts(data)
    return data


# --------------------------------------------------------------------------------------------- judging

def _figures(row: dict) -> list[str]:
    """A bench row's cost and error, or the FMU's refusal of that setting (a failed row has no figures)."""
    if row["error"] is None or row["cpu_s_per_simulated_s"] is None:
        return ["refused", str(row.get("failure") or "no result")[:80]]
    return [f"{row['cpu_s_per_simulated_s']:.3g}", f"{row['error']:.2e}"]


def _cheapest(rows: list[dict], method: str, error: float) -> dict | None:
    ok = [r for r in rows if r["method"] == method and r["error"] is not None and r["error"] <= error]
    return min(ok, key=lambda r: r["cpu_s_per_simulated_s"]) if ok else None


def verdicts(data: dict) -> list[dict]:
    """Each target of issue 6 with the measured figure and whether it is met."""
    out = []
    for r in data["floor"]:
        per_ss22 = r["ss22_step_s"] / r["floor_s"]
        out.append({"target": f"{r['scene']}, order {r['order']}: SS22 step <= 3x floor",
                    "measured": f"{per_ss22:.2f}x per SS22 step" + (f" ({r['per_step_over_floor']:.2f}x per "
                                                                   "Richardson step of 3)" if r["order"] == 4 else ""),
                    "met": per_ss22 <= TARGETS["floor"]})
        if r["linear_in_state"] and r["order"] == 2:
            out.append({"target": f"{r['scene']}: no Newton iteration, no refactorisation (factorisations bounded "
                                  f"by the {SS22_CACHE}-entry cache, not growing with the steps)",
                        "measured": f"{r['newton_iterations']} iterations, {r['factorisations']} factorisations, "
                                    f"{r['residual_evaluations']} residuals in {r['ss22_steps']} steps",
                        "met": r["newton_iterations"] == 0 and r["factorisations"] <= SS22_CACHE
                        and r["residual_evaluations"] == r["ss22_steps"]})
    for key, c in data["cosim"].items():
        table = [e for e in c["info"]["equal_error"]]
        for other, name, target in (("cvodes", "CVODES per step", TARGETS["cvodes_per_step"]),
                                    ("python_fmu", "Python FMU", TARGETS["python_fmu"])):
            ratios = [e[f"{other}_ratio"] for e in table if e[f"{other}_ratio"] is not None]
            unmatched = [e["setting"] for e in table if e[f"{other}_ratio"] is None]
            measured = (f"{min(ratios):.1f}x to {max(ratios):.1f}x over {len(ratios)} error levels"
                        if ratios else "no common error level")
            if unmatched:
                measured += f"; {name} never reaches the error of {', '.join(unmatched)}"
            out.append({"target": f"{key}, 1 ms co-simulation: >= {target:g}x faster than {name} at equal error",
                        "measured": measured, "met": bool(ratios) and min(ratios) >= target})
    rows = data["stiff"]["rows"]
    ss22 = [r for r in rows if r["method"] == "ss22 (FMU)"]
    at_50 = [r for r in ss22 if r["step"] * 20 * stiff_case.CUTOFF_HZ <= 1 + 1e-9]
    if at_50:
        r = max(at_50, key=lambda r: r["step"])
        out.append({"target": f"stiff case: hub angle error < 1e-3 at the step resolving modes < 50 Hz "
                              f"({r['step']:g} s, 20 steps a period)",
                    "measured": f"{r['hub_angle']:.1e}", "met": r["hub_angle"] < TARGETS["stiff_error"]})
        out.append({"target": f"stiff case: tip deflection (modes < 50 Hz) error < 1e-3 at {r['step']:g} s",
                    "measured": f"{r['tip_low_modes']:.1e}", "met": r["tip_low_modes"] < TARGETS["stiff_error"]})
    good = [r for r in ss22 if r["error"] < TARGETS["stiff_error"]]
    if good:
        r = max(good, key=lambda r: r["step"])
        s = next(s for s in data["stiff"]["info"]["speedups"] if s["setting"] == r["setting"])
        out.append({"target": f"stiff case: >= 10x faster than CVODES at the same low-frequency error "
                              f"(largest step with both errors < 1e-3: {r['step']:g} s)",
                    "measured": (f"{s['ratio']:.0f}x (CVODES {s['cvodes_setting']})" if s["ratio"]
                                 else "CVODES does not reach it"),
                    "met": s["ratio"] is None or s["ratio"] >= TARGETS["stiff_speedup"]})
    for b in data["builds"]:
        if b["n_q"] <= 4 or b.get("largest_example"):
            out.append({"target": f"build {b['scene']} ({b['n_q']} coordinates)"
                                  + (" < 5 s" if b["n_q"] <= 4 else " (largest example)"),
                        "measured": f"{b['build_s']:.2f} s",
                        "met": b["build_s"] < TARGETS["build_s"] if b["n_q"] <= 4 else None})
    return out


def not_ahead(data: dict) -> list[str]:
    """Where flexlink is not ahead, or only narrowly, read off the measurements (no figure is written by hand)."""
    notes = []
    for key, b in data["bench"].items():
        rows = [r for r in b["rows"] if r.get("failure") is None]     # a refused setting has no figures
        plain = [r for r in rows if r["method"] == "ss22 (FMU)"]
        others = [m for m in dict.fromkeys(r["method"] for r in rows) if not m.startswith("ss22")]
        if plain:
            best = min(plain, key=lambda r: r["error"])
            notes.append(f"`flexlink bench` {key}: plain SS22 (order 2) reaches {best['error']:.1e} at its smallest "
                         f"step ({best['setting']}); below that only the order-4 option is there")
        for level in LEVELS:
            ours = [x for x in (_cheapest(rows, m, level) for m in dict.fromkeys(r["method"] for r in rows)
                                if m.startswith("ss22")) if x]
            if not ours:
                notes.append(f"`flexlink bench` {key}: no SS22 row reaches {level:g}")
                continue
            mine = min(ours, key=lambda r: r["cpu_s_per_simulated_s"])
            for m in others:
                o = _cheapest(rows, m, level)
                if o and o["cpu_s_per_simulated_s"] < 2 * mine["cpu_s_per_simulated_s"]:
                    notes.append(f"`flexlink bench` {key}, error ≤ {level:g}: {m} ({o['setting']}, "
                                 f"{o['cpu_s_per_simulated_s']:.2g} s/s) is within 2× of the best SS22 row "
                                 f"({mine['method']}, {mine['setting']}, {mine['cpu_s_per_simulated_s']:.2g} s/s)")
        if plain:
            for level in LEVELS:
                mine = _cheapest(rows, "ss22 (FMU)", level)
                if mine is None:
                    break
                for m in others:
                    o = _cheapest(rows, m, level)
                    if o and o["cpu_s_per_simulated_s"] < 2 * mine["cpu_s_per_simulated_s"]:
                        notes.append(f"`flexlink bench` {key}, error ≤ {level:g}: plain SS22 ({mine['setting']}, "
                                     f"{mine['cpu_s_per_simulated_s']:.2g} s/s) is only "
                                     f"{o['cpu_s_per_simulated_s'] / mine['cpu_s_per_simulated_s']:.1f}× cheaper "
                                     f"than {m} ({o['setting']})")
    # full evaluations only: a mass update (fmu_src/mass_update.c) refactorises an entry in place
    thrash = [r for r in data["floor"]
              if r["order"] == 4 and r["factorisations"] - r.get("mass_updates", 0) > SS22_CACHE]
    if thrash:
        notes.append("order 4: " + ", ".join(f"{r['scene']} {r['factorisations']} factorisations in {r['ss22_steps']} "
                                             f"SS22 steps ({r['per_step_over_floor']:.1f}× the floor per Richardson "
                                             "step)" for r in thrash)
                     + f" — the {SS22_CACHE}-entry factorisation cache of ss22.c alternates between Δt, Δt/2 and "
                       "rounding variants of Δt (cheap at 4 coordinates, an n³ LU each time on larger models)")
    for key, c in data["cosim"].items():
        for e in c["info"]["equal_error"]:
            for other, name in (("cvodes", "CVODES per step"), ("python_fmu", "the Python FMU")):
                if e[f"{other}_ratio"] is not None and e[f"{other}_ratio"] < 1:
                    notes.append(f"1 ms loop, {key}, ours {e['setting']}: {name} is cheaper at equal error")
        pyrows = [r for r in c["rows"] if r["method"] == cosim_loop.PYFMU]
        plain = [r for r in c["rows"] if r["method"] == cosim_loop.OURS and "order 4" not in r["setting"]]
        if pyrows and plain:
            best_py = min(pyrows, key=lambda r: r["error"])
            if not [r for r in plain if r["error"] <= best_py["error"]]:
                notes.append(f"1 ms loop, {key}: plain SS22 reaches {min(r['error'] for r in plain):.1e} at its "
                             f"smallest step, the RK4 Python FMU {best_py['error']:.1e} (at "
                             f"{best_py['us_per_comm_step']:.0f} µs a step): at tight errors only the order-4 "
                             "option keeps flexlink ahead")
    stiff = [r for r in data["stiff"]["rows"] if r["method"] == "ss22 (FMU)"]
    bad = [r for r in stiff if r["tip_low_modes"] >= TARGETS["stiff_error"]]
    if bad:
        same = {}
        for b in data["bench"].values():
            for r in b["rows"]:
                if r["method"] == "ss22 (FMU)" and "theta" not in r["setting"] and r["error"] is not None:
                    same.setdefault(r["setting"], r["error"])
        cmp = [f"{r['tip_low_modes']:.1e} at {r['step']:g} s" + (f" (3-mode link: {same[r['setting']]:.1e})"
                                                                  if r["setting"] in same else "") for r in bad]
        notes.append("stiff case: the tip deflection of the modes below 50 Hz is off by " + ", ".join(cmp)
                     + f" over {data['stiff']['info']['stop_time']:g} s — as large as for the 3-mode link at the same "
                       "step, so the second-order method's phase error in the resolved first modes, not an effect of "
                       "the unresolved ones; < 1e-3 needs "
                     + (f"{max(r['step'] for r in stiff if r['tip_low_modes'] < 1e-3):g} s"
                        if any(r["tip_low_modes"] < 1e-3 for r in stiff) else "a smaller step than measured"))
    sp = [s for s in data["stiff"]["info"]["speedups"] if s["ratio"]]
    if len(sp) > 1:
        cv = [r["cpu_s_per_simulated_s"] for r in data["stiff"]["rows"] if r["method"] == "cvodes"]
        notes.append(f"stiff case: CVODES's cost hardly depends on its tolerance ({min(cv):.2g} … {max(cv):.2g} s/s "
                     "over the tolerances measured) while SS22's doubles with every halving of the step: the margin "
                     f"falls from {sp[0]['ratio']:.0f}× ({sp[0]['setting']}) to {sp[-1]['ratio']:.0f}× "
                     f"({sp[-1]['setting']})")
    return notes


# ------------------------------------------------------------------------------------------- reporting

def _md_table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |",
            *["| " + " | ".join(r) + " |" for r in rows]]


def _g(x: float | None, fmt: str = ".2g") -> str:
    return "—" if x is None else format(x, fmt)


def floor_table(data: dict) -> list[str]:
    rows = []
    for r in data["floor"]:
        n = r["ss22_steps"]
        rows.append([r["scene"], str(r["order"]), f"{r['step']:g}", f"{1e6 * r['step_s']:.3f}",
                     f"{1e6 * r['floor_s']:.3f}", f"**{r['per_step_over_floor']:.2f}**",
                     f"{r['ss22_step_s'] / r['floor_s']:.2f}",
                     f"{1e6 * r['residual_s']:.3f} / {1e6 * r['newton_matrix_s']:.3f} / {1e6 * r['lu_factor_s']:.3f}"
                     f" / {1e6 * r['lu_solve_s']:.3f}",
                     f"{r['newton_iterations'] / n:.2f}", f"{r['residual_evaluations'] / n:.2f}",
                     f"{r['factorisations']}"])
    return _md_table(["scene", "order", "step (s)", "µs / internal step", "floor µs", "step / floor",
                      "per SS22 step / floor", "residual / Newton matrix / LU / solve µs",
                      "Newton it. / step", "residuals / step", "factorisations / run"], rows)


def cosim_table(data: dict, key: str, full: bool) -> list[str]:
    c = data["cosim"][key]
    if full:
        rows = [[r["method"], r["setting"], f"{r['us_per_comm_step']:.1f}", f"{r['error']:.2e}"] for r in c["rows"]]
        return _md_table(["method", "setting", "CPU µs per 1 ms step", "error"], rows)
    rows = []
    def cell(e, k):
        return "not reached" if e[f"{k}_ratio"] is None else f"{e[f'{k}_ratio']:.1f}× ({e[f'{k}_setting']})"

    for e in c["info"]["equal_error"]:
        rows.append([e["setting"], f"{e['error']:.1e}", f"{1e6 * e['ours'] * c['info']['comm_step']:.1f}",
                     cell(e, "cvodes"), cell(e, "python_fmu")])
    return _md_table(["flexlink FMU", "error", "CPU µs / step", "CVODES per step at ≤ this error",
                      "Python FMU at ≤ this error"], rows)


def stiff_table(data: dict) -> list[str]:
    rows = []
    speed = {s["setting"]: s for s in data["stiff"]["info"]["speedups"]}
    for r in data["stiff"]["rows"]:
        s = speed.get(r["setting"]) if r["method"] == "ss22 (FMU)" else None
        rows.append([r["method"], r["setting"], f"{r['cpu_s_per_simulated_s']:.3g}", f"{r['hub_angle']:.1e}",
                     f"{r['tip_low_modes']:.1e}", f"{r['tip_all_modes']:.1e}",
                     "" if s is None else ("CVODES never as accurate" if s["ratio"] is None
                                           else f"{s['ratio']:.0f}× ({s['cvodes_setting']})")])
    return _md_table(["method", "setting", "CPU s / sim. s", "hub angle", "tip, modes < 50 Hz", "tip, all modes",
                      "CVODES at ≤ this error"], rows)


def bench_summary(data: dict, key: str) -> list[str]:
    rows = data["bench"][key]["rows"]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    out = []
    for m in methods:
        cells = [m]
        for level in LEVELS:
            r = _cheapest(rows, m, level)
            cells.append(_g(r["cpu_s_per_simulated_s"]) if r else "—")
        out.append(cells)
    return _md_table(["method (CPU s / sim. s, cheapest row reaching)", *[f"≤ {v:g}" for v in LEVELS]], out)


def build_table(data: dict) -> list[str]:
    return _md_table(["scene", "coordinates", "build (s)", "generated C (KiB)"],
                     [[b["scene"] + (" (largest example)" if b.get("largest_example") else ""), str(b["n_q"]),
                       f"{b['build_s']:.2f}", f"{b['generated_c_kib']:.0f}"] for b in data["builds"]])


def verdict_table(data: dict) -> list[str]:
    mark = {True: "met", False: "**not met**", None: "(reported)"}
    return _md_table(["target (issue 6)", "measured", ""],
                     [[v["target"], v["measured"], mark[v["met"]]] for v in data["verdicts"]])


def command(data: dict) -> str:
    return "python benchmarks/report.py" + (" --quick" if data["quick"] else "")


def report_markdown(data: dict) -> str:
    lines = [f"# Performance report (issue 6){' — QUICK (CI size, not for quoting)' if data['quick'] else ''}", "",
             f"`{command(data)}`, {data['date']}, {data['machine']}, {data['wall_s']:.0f} s. "
             "2 shared cores: absolute times are noisy; every comparison is a ratio of medians measured in the "
             "same run.  Errors are relative RMS deviations from CVODES at rtol 1e-12 (hub angle and tip "
             "deflection, 10 ms samples) unless stated.", "", "## Targets", "", *verdict_table(data), "",
             "## Where flexlink is not ahead", ""]
    lines += [f"* {n}" for n in not_ahead(data)] or ["* nothing found in these measurements"]
    lines += ["", "## Build time", "", *build_table(data), "",
              "## Cost per internal step against its floor (`benchmarks/step_floor.py`)", "",
              "Floor = one generated residual + one generated Newton matrix + one LU of the same size, at the end "
              "state of the run, timed in the same process as the run (C driver compiled with the FMU's "
              "`sources/`); the run is issue 6's manoeuvre through `fmi2DoStep` (one call per input segment), "
              "per internal step (order 4: one internal step is 3 SS22 steps). Counters from the instance.", "",
              *floor_table(data), ""]
    for key in data["cosim"]:
        info = data["cosim"][key]["info"]
        lines += [f"## Co-simulation at 1 ms through fmpy: {key} (`benchmarks/cosim_loop.py`)", "",
                  f"{info['stop_time']:g} s, setReal / doStep / getReal every {info['comm_step'] * 1e3:g} ms; CVODES "
                  "restarted at every step from Python; Python FMU: PythonFMU 0.7, RK4 in one CasADi call per step.",
                  "", *cosim_table(data, key, True), "", "At equal error (cheapest row at least as accurate; ratio = "
                  "its cost / ours):", "", *cosim_table(data, key, False), ""]
    info = data["stiff"]["info"]
    lines += ["## Stiff case: 20 clamped modes (`benchmarks/stiff_case.py`)", "",
              f"`{Path(info['scene']).relative_to(ROOT) if Path(info['scene']).is_absolute() else info['scene']}`: "
              f"{info['n_q']} coordinates, modes {info['frequencies_hz'][0]:.3g} … {info['frequencies_hz'][-1]:.4g} Hz "
              f"({info['modes_below_cutoff']} below {info['cutoff_hz']:g} Hz), {info['stop_time']:g} s; reference "
              f"{info['reference']} (own error {info['reference_error']:.0e}). Low-frequency error = the larger of "
              "the hub angle's and the tip deflection's restricted to the rigid mode and the modes below 50 Hz "
              "(exact modal projection Φ_low Φ_lowᵀ M q of the linear model). CVODES with the parameters "
              "substituted (its best case), restarted at the input switches.", "", *stiff_table(data), ""]
    for key, b in data["bench"].items():
        info = b["info"]
        lines += [f"## `flexlink bench {Path(info['scene']).relative_to(ROOT)}` (full size): {key}", "",
                  f"Reference error {info['reference_error']:.1e}.", "", *bench_summary(data, key), "",
                  "<details><summary>all rows</summary>", "",
                  *_md_table(["method", "setting", "CPU s / sim. s", "error"],
                             [[r["method"], r["setting"], *_figures(r)] for r in b["rows"]]), "", "</details>", ""]
    lines += ["Not in this report: `python benchmarks/fmu_speed.py --large` (build, size and per-step cost of the "
              "larger examples and the 81-coordinate FE link) and `python benchmarks/closed_loop.py` (LQR/PD closed "
              "loop); their figures are in docs/performance.md.", ""]
    return "\n".join(lines)


def readme_block(data: dict, png: str) -> str:
    by = {(r["scene"], r["order"]): r for r in data["floor"]}
    lin, sec = by.get(("rotating_link_linear", 2)), by.get(("rotating_link", 2))
    lines = [BEGIN, f"<!-- generated by `{command(data)}` on {data['date']}: edit benchmarks/report.py, "
             "not this block -->", "",
             f"**Issue 6's measurements** (`{command(data)}`, {data['wall_s'] / 60:.0f} min; every table in "
             "`benchmarks/report.md`, plot `benchmarks/report.png`). Medians; each comparison a ratio from the same "
             "run.", "", *verdict_table(data), ""]
    if lin and sec:
        lines += [f"Per internal step (1 ms, issue 6's manoeuvre through `fmi2DoStep`, C driver "
                  f"`benchmarks/step_floor.c`): linear {1e6 * lin['step_s']:.3f} µs = "
                  f"{lin['per_step_over_floor']:.2f}× its floor ({1e6 * lin['floor_s']:.3f} µs = residual + Newton "
                  f"matrix + LU), one residual and one LU solve a step, {lin['newton_iterations']} Newton iterations "
                  f"and {lin['factorisations']} factorisations in {lin['ss22_steps']} steps; second-order "
                  f"{1e6 * sec['step_s']:.3f} µs = {sec['per_step_over_floor']:.2f}× its floor, "
                  f"{sec['newton_iterations'] / sec['ss22_steps']:.1f} simplified-Newton iterations a step on "
                  f"{sec['factorisations']} factorisations.", ""]
    rows = []
    for key, c in data["cosim"].items():
        pick = [e for e in c["info"]["equal_error"]
                if e["setting"] in ("step=0.001", "step=0.00025", "step=0.001, order 4")]
        for e in pick:
            rows.append([key, e["setting"], f"{e['error']:.1e}", f"{1e6 * e['ours'] * c['info']['comm_step']:.1f}",
                         *[("not reached" if e[f"{k}_ratio"] is None
                            else f"{e[f'{k}_ratio']:.1f}× ({e[f'{k}_setting']})") for k in ("cvodes", "python_fmu")]])
    if rows:
        lines += ["1 ms co-simulation through fmpy (`benchmarks/cosim_loop.py`; CPU µs per communication step, "
                  "setReal + doStep + getReal; the others at their cheapest setting at least as accurate):", "",
                  *_md_table(["scene", "flexlink FMU", "error", "µs / step", "CVODES restarted per step",
                              "PythonFMU (RK4 in CasADi)"], rows), ""]
    st = data["stiff"]
    speed = {s["setting"]: s for s in st["info"]["speedups"]}
    rows = [[r["setting"], f"{r['cpu_s_per_simulated_s']:.2g}", f"{r['hub_angle']:.1e}", f"{r['tip_low_modes']:.1e}",
             "—" if speed[r["setting"]]["ratio"] is None else f"{speed[r['setting']]['ratio']:.0f}×"]
            for r in st["rows"] if r["method"] == "ss22 (FMU)"]
    cv = [r for r in st["rows"] if r["method"] == "cvodes"]
    if cv:
        lo, hi = min(cv, key=lambda r: r["cpu_s_per_simulated_s"]), max(cv, key=lambda r: r["cpu_s_per_simulated_s"])
        rows.append([f"CVODES rtol {cv[0]['setting'][5:]} … {cv[-1]['setting'][5:]}",
                     f"{lo['cpu_s_per_simulated_s']:.2g} … {hi['cpu_s_per_simulated_s']:.2g}",
                     f"{max(r['hub_angle'] for r in cv):.0e} … {min(r['hub_angle'] for r in cv):.0e}",
                     f"{max(r['tip_low_modes'] for r in cv):.0e} … {min(r['tip_low_modes'] for r in cv):.0e}", ""])
    lines += [f"Stiff case (`benchmarks/stiff_case.py`: `many_modes.toml`, {st['info']['n_q']} coordinates, modes "
              f"{st['info']['frequencies_hz'][0]:.2g} Hz … {st['info']['frequencies_hz'][-1] / 1e3:.1f} kHz, "
              f"{st['info']['stop_time']:g} s; low modes = rigid + below 50 Hz, by exact modal projection):", "",
              *_md_table(["SS22 step (s)", "CPU s / sim. s", "hub angle error", "tip error, modes < 50 Hz",
                          "CVODES at ≤ both errors"], rows), ""]
    notes = not_ahead(data)
    if notes:
        lines += ["Where flexlink is not ahead, or only narrowly (from these measurements):", "",
                  *[f"* {n}" for n in notes], ""]
    lines += [f"![issue 6 measurements]({png})", "", END]
    return "\n".join(lines)


PAGE = ROOT / "docs" / "performance.md"      # the page whose marked blocks these scripts write


def rewrite_readme(path: Path, block: str, begin: str = BEGIN, end: str = END) -> None:
    """Replace a page's text from ``begin`` to ``end`` (markers included) by ``block``: the measured figures
    live in their generated block and nowhere else, so a new run cannot leave stale copies (the name is from
    the days the block sat in the README; the default page is now docs/performance.md)."""
    text = path.read_text()
    if begin not in text or end not in text or text.index(begin) > text.index(end):
        raise SystemExit(f"{path}: no {begin} ... {end} block to rewrite")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    path.write_text(head + block + tail)


def publish_figure(png: Path, page: Path) -> str:
    """The link from ``page`` to ``png``: a copy in the page's ``img/`` folder when the page is in docs/
    (MkDocs serves, and its strict build checks, only the files below docs/), else the relative path."""
    page = Path(page).resolve()
    if page.parent == PAGE.parent:
        target = page.parent / "img" / png.name
        target.parent.mkdir(exist_ok=True)
        if Path(png).resolve() != target:
            target.write_bytes(Path(png).read_bytes())
        return f"img/{png.name}"
    try:
        return str(Path(png).resolve().relative_to(page.parent))
    except ValueError:
        return str(Path(png).resolve())


def plot(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    ax = axes[0, 0]
    for key, style in zip(data["cosim"], ("-", "--"), strict=False):
        rows = data["cosim"][key]["rows"]
        for method, colour in ((cosim_loop.OURS, "C0"), (cosim_loop.PYFMU, "C1"), (cosim_loop.CVODES, "C2")):
            for sub, marker in (("order 4", "s"), ("", "o")):
                pts = sorted((r["error"], r["us_per_comm_step"]) for r in rows if r["method"] == method
                             and ((sub in r["setting"]) if sub else "order 4" not in r["setting"]))
                if pts:
                    label = f"{method}{' ' + sub if sub else ''} ({key})"
                    ax.loglog([p[0] for p in pts], [p[1] for p in pts], marker + style, color=colour,
                              mfc="none" if sub else colour, label=label)
    ax.set_title("1 ms co-simulation through fmpy", fontsize=10)
    ax.set_xlabel("relative RMS error")
    ax.set_ylabel("CPU µs per communication step")
    ax.legend(fontsize=6)
    ax = axes[0, 1]
    rows = data["stiff"]["rows"]
    for method, colour in (("ss22 (FMU)", "C0"), ("cvodes", "C2")):
        for field, marker in (("hub_angle", "o-"), ("tip_low_modes", "s--")):
            pts = sorted((r[field], r["cpu_s_per_simulated_s"]) for r in rows if r["method"] == method)
            ax.loglog([p[0] for p in pts], [p[1] for p in pts], marker, color=colour,
                      label=f"{method}: {field.replace('_', ' ')}")
    ax.axvline(TARGETS["stiff_error"], color="gray", ls=":", lw=1)
    ax.set_title("stiff case: 20 clamped modes", fontsize=10)
    ax.set_xlabel("relative RMS error (low-frequency)")
    ax.set_ylabel("CPU s per simulated s")
    ax.legend(fontsize=7)
    ax = axes[1, 0]
    labels = [f"{r['scene'].replace('rotating_link', 'rl')}\norder {r['order']}" for r in data["floor"]]
    x = range(len(labels))
    ax.bar([i - 0.2 for i in x], [1e6 * r["step_s"] for r in data["floor"]], 0.4, label="per internal step")
    ax.bar([i + 0.2 for i in x], [1e6 * r["floor_s"] for r in data["floor"]], 0.4, label="floor")
    ax.set_xticks(list(x), labels, fontsize=8)
    ax.set_ylabel("CPU µs")
    ax.set_title("SS22 step against its floor (same process)", fontsize=10)
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    if data["bench"]:
        key = next(iter(data["bench"]))
        rows = data["bench"][key]["rows"]
        series = dict.fromkeys((r["method"], r["setting"].partition(", ")[2]) for r in rows)
        for method, variant in series:       # e.g. SS22 with theta = 0.6 apart from theta = 0.5
            # a setting the FMU refused is a row without figures (flexlink bench's failed rows)
            pts = sorted((r["error"], r["cpu_s_per_simulated_s"]) for r in rows
                         if r["method"] == method and r["setting"].partition(", ")[2] == variant
                         and r["error"] is not None and r["cpu_s_per_simulated_s"] is not None)
            ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", ms=3,
                      label=method + (f" ({variant})" if variant else ""))
        ax.set_title(f"flexlink bench, {key} (full size)", fontsize=10)
        ax.set_xlabel("relative RMS error")
        ax.set_ylabel("CPU s per simulated s")
        ax.legend(fontsize=6)
    else:
        ax.text(0.5, 0.5, "flexlink bench rows: full run only", ha="center", va="center")
        ax.set_axis_off()
    for a in axes.flat:
        a.grid(alpha=0.3, which="both")
    fig.suptitle(f"flexlink, issue 6 ({command(data)}, {data['date']})", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="CI size; writes to --out only")
    ap.add_argument("--out", help="folder of report.md, report.json, report.png (default benchmarks/; "
                    "required with --quick)")
    ap.add_argument("--page", "--readme", dest="page", help="page to rewrite between the perf markers "
                    "(default docs/performance.md, none with --quick)")
    ap.add_argument("--no-page", "--no-readme", dest="no_page", action="store_true")
    ap.add_argument("--repeats", type=int, help="timed runs per setting (default: each benchmark's own)")
    ap.add_argument("--from-json", help="re-render from a report.json instead of measuring")
    args = ap.parse_args(argv)
    if args.quick and not args.out:
        ap.error("--quick needs --out (CI-size figures must not overwrite benchmarks/report.md)")
    out = Path(args.out) if args.out else HERE
    out.mkdir(parents=True, exist_ok=True)
    data = json.loads(Path(args.from_json).read_text()) if args.from_json else measure_all(args.quick, args.repeats)
    data["verdicts"] = verdicts(data)
    (out / "report.json").write_text(json.dumps(data, indent=1, default=float))
    plot(data, out / "report.png")
    (out / "report.md").write_text(report_markdown(data))
    page = None if args.no_page else (args.page or (None if args.quick else str(PAGE)))
    if page:
        rewrite_readme(Path(page), readme_block(data, publish_figure(out / "report.png", Path(page))))
    print(f"wrote {out / 'report.md'}, report.json, report.png" + (f"; rewrote {page}" if page else ""))
    for v in data["verdicts"]:
        mark = {True: "met", False: "NOT MET", None: ""}[v["met"]]
        print(f"  {mark:7s} {v['target']}: {v['measured']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
