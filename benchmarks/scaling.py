"""Build time, generated C and cost per SS22 step against the size of the robot (issue 15's figures).

    python benchmarks/scaling.py                  # full size: 1-8 links, 1-32 modes, 3 builds each; rewrites
                                                  # docs/performance.md between the scaling markers
    python benchmarks/scaling.py --quick --out DIR   # CI size: a few sizes, one build each, docs untouched
    python benchmarks/scaling.py --table-only     # the issue's table again; the families kept from the last
                                                  # full run's scaling.json (the report says which run is which)
    python benchmarks/scaling.py --out DIR        # the same into DIR; the README and docs/performance.md untouched

Two families of scenes, generated here (second-order kinematics, gravity, torque-driven joints):

* **bodies**: planar chains of 1 ... 8 flexible links, 3 clamped-free modes each (what issue 15 measured:
  build n^3.4, code n^2.8 before the builder was made to scale);
* **modes**: one link of 16 Hermite elements reduced to its first 1 ... 32 modes (``shapes.modes``).

and the issue's table: ``examples/six_axis_arm.toml``, ``examples/planar_chain_5.toml`` and the 32-mode link.
The two families are built with ``newton_matrix = "auto"``, the Newton matrix from the mass matrix and
differences of the residual at every size (the form whose code grows like the residual's; "auto" used to switch
from the dense Jacobian at 12 coordinates, and the families were built with "columns" then).

For every scene: the build time (``build_fmu``: model, code generation, gcc, packaging; median of
``--builds``), the bytes of generated C, and the CPU time per internal SS22 step at the scene's step, from
``benchmarks/step_floor.py``'s driver (compiled with the FMU's own sources, run in one process over issue 6's
manoeuvre: +τ, −τ, free; median of ``--repeats``; the table's rows are timed in turns, one run of each a
round, so that a burst of outside load falls on all of them alike: :func:`retime_interleaved`).  Growth is
reported as the exponent of a least-squares fit of log(figure) against log(size).  Writes ``scaling.md``,
``scaling.json`` and ``scaling.png`` into ``--out`` (default: ``benchmarks/``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

TABLE = [("six-axis arm (examples/six_axis_arm.toml)", ROOT / "examples" / "six_axis_arm.toml", (20.0, 1.0, 20.0)),
         ("planar chain of 5 flexible links, 3 modes (examples/planar_chain_5.toml)",
          ROOT / "examples" / "planar_chain_5.toml", (10.0, 1.0, 10.0)),
         ("one link, 32 modes, second-order kinematics", 32, (10.0, 1.0, 5.0)),
         # the issue names no kinematics for this row: both are measured (docs/chains.md says what each keeps)
         ("one link, 32 modes, first-order kinematics", ("first-order", 32), (10.0, 1.0, 5.0))]
OLD_32_LABEL = "one link, 32 modes"     # its label in scaling.json before 2026-11-26 (--keep-32)
# the table's scenes measured again without the directional derivatives ([fmu] directional_derivatives = false).
# None since 2026-11-27: the derivatives are the complex step on the residual and outputs, which generates no
# code, and "auto" builds the same Newton matrix with or without them, so those rows measured the same build.
LEAN = " with directional_derivatives = false"
LEAN_ROWS: tuple[str, ...] = ()
# issue 15's targets for the growth exponents: build and code, step
GOAL_LINEAR, GOAL_STEP = 1.2, 2.0
BEGIN, END = "<!-- scaling:begin -->", "<!-- scaling:end -->"
# the table alone, in the README (issue 15 asks for it there), written by the same run
README_BEGIN, README_END = "<!-- robot-scale:begin -->", "<!-- robot-scale:end -->"


def _avx_twins() -> str:
    """Which of the Newton iteration's units the steps ran: their AVX twins where the processor has AVX."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "(processor's AVX unknown)"
    return "in their AVX twins" if " avx " in flags.replace("\n", " ") else "without AVX (the baseline units)"


def chain_scene(n_links: int, modes: int = 3) -> dict:
    """A planar chain hanging along x under gravity (so that it swings, not falls), joints damped."""
    joints = [dict(name=f"j{i + 1}", axis=[0.0, 0.0, 1.0], inertia=1e-3, damping=0.01) for i in range(n_links)]
    links = [dict(name=f"l{i + 1}", length=0.4, linear_density=1.5, EI=40.0, deformation=["v"],
                  shapes=dict(kind="clamped-free", count=modes), kinematics="second-order")
             for i in range(n_links)]
    return dict(name=f"chain_{n_links}", gravity=[9.81, 0.0, 0.0], joint=joints, link=links,
                fmu=dict(step=1e-3, newton_matrix="auto"))


def modes_scene(modes: int, kinematics: str = "second-order") -> dict:
    """One link of 16 Hermite elements reduced to its first ``modes`` modes (second-order kinematics by default)."""
    joint = dict(name="hub", axis=[0.0, 0.0, 1.0], inertia=1e-2)
    link = dict(name="arm", length=1.0, linear_density=2.0, EI=100.0, deformation=["v"],
                shapes=dict(kind="fe", count=16, modes=modes), kinematics=kinematics)
    return dict(name=f"modes_{modes}", gravity=[0.0, 0.0, 0.0], joint=[joint], link=[link],
                fmu=dict(step=1e-4, newton_matrix="auto"))


def measure(scene, *, builds: int, repeats: int, keep: Path | None = None) -> dict:
    """Build ``builds`` times (median), then time the SS22 step with the step-floor driver.

    ``keep``: a directory where the FMU and the driver stay, with the driver's command line as ``"timing"``
    (:func:`retime_interleaved` times the table's rows again, in turns)."""
    from step_floor import compile_driver, manoeuvre_tokens
    from step_floor import measure as measure_step

    from flexlink.export.codegen import OPTIMISE_ENV
    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.tools.bench import default_case

    walls, report, timing = [], None, None
    with tempfile.TemporaryDirectory() as scratch:
        tmp = Path(keep or scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        for _ in range(builds):
            t0 = time.perf_counter()
            report = build_fmu(scene, tmp / "scaling.fmu")
            walls.append(time.perf_counter() - t0)
        model = build_model(scene)
        exe = compile_driver(report.fmu, tmp)
        case = default_case(model, stop=3.0)
        step = measure_step(exe, report.fmu, case, step=scene.fmu.solver.step, repeats=repeats)
        if keep is not None:
            import fmpy

            tokens = manoeuvre_tokens(report.fmu, case, {"solver.step": scene.fmu.solver.step, "solver.order": 2})
            timing = [str(exe), fmpy.read_model_description(str(report.fmu)).guid, "1", *tokens]
    return {"scene": scene.name, "n_q": model.n_q, "bodies": len(scene.links), "timing": timing,
            "build_s": statistics.median(walls), "build_parts_s": report.seconds,
            "generated_bytes": report.generated_c_bytes, "operations": report.operations,
            "step_us": 1e6 * step["step_s"], "residual_us": 1e6 * step["residual_s"],
            "optimise": os.environ.get(OPTIMISE_ENV) or "-O2, -Og above 5 000 operations",
            "newton_matrix_us": 1e6 * step["newton_matrix_s"], "factorisations": step["factorisations"],
            "steps": step["ss22_steps"], "iterations_per_step": step["newton_iterations"] / step["ss22_steps"]}


def retime_interleaved(rows: list[dict], rounds: int) -> None:
    """The table's steps timed again in turns: ``rounds`` rounds of one run of each row's driver, the median of
    each row's runs in place of its own.

    The machine is shared, and outside load comes in bursts of seconds: one row's runs, taken one after the
    other, can all fall in one (planar_chain_5 measured 8.6 µs in three runs of 2026-11-29 and 11.1 and 12.1 in
    two others, with its driver varying 9 to 16 µs between alternated runs).  In turns, a burst costs each row
    one or two of its runs, and the median keeps none of them."""
    runs: dict[int, list[dict]] = {k: [] for k, r in enumerate(rows) if r.get("timing")}
    for _ in range(rounds):
        for k in runs:
            out = subprocess.run(rows[k]["timing"], capture_output=True, text=True, check=True)
            runs[k].append(json.loads(out.stdout))
    for k, results in runs.items():
        rows[k]["step_us"] = 1e6 * statistics.median(r["step_s"] for r in results)
        rows[k]["residual_us"] = 1e6 * statistics.median(r["residual_s"] for r in results)
        rows[k]["interleaved_runs"] = rounds


def exponent(sizes, values) -> float:
    """Slope of the least-squares line through (log size, log value)."""
    return float(np.polyfit(np.log(np.asarray(sizes, float)), np.log(np.asarray(values, float)), 1)[0])


def family(rows: list[dict], size_key: str) -> dict:
    sizes = [r[size_key] for r in rows]
    return {k: exponent(sizes, [r[k] for r in rows]) for k in ("build_s", "generated_bytes", "step_us")}


def plot(bodies: list[dict], modes: list[dict], fits: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
    for row, (rows, key, label) in enumerate(((bodies, "bodies", "flexible links (3 modes each)"),
                                             (modes, "modes", "modes of one link"))):
        x = [r[key] for r in rows]
        for col, (fig_key, unit, scale) in enumerate((("build_s", "build [s]", 1.0),
                                                      ("generated_bytes", "generated C [MB]", 1e-6),
                                                      ("step_us", "SS22 step [µs]", 1.0))):
            ax = axes[row, col]
            ax.loglog(x, [r[fig_key] * scale for r in rows], "o-")
            ax.set_xlabel(label)
            ax.set_ylabel(unit)
            ax.set_title(f"fitted exponent {fits[key][fig_key]:.2f}")
            ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("flexlink: cost against robot size (second-order kinematics)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def target_table(table: list[dict], info: dict) -> list[str]:
    """The issue's table: each scene's build, generated C and step against its targets, with how it was measured."""
    lines = [f"Measured {info['date']} on {info['machine']} (`{info['command']}`, generated C at "
             f"{info['optimise']}); builds: median of {info['builds']}, steps: median of {info['repeats']} runs"
             + (", the rows timed in turns" if any(r.get("interleaved_runs") for r in table) else "")
             + (f"; load average {info['load'][0]:.1f} at the start, {info['load'][1]:.1f} at the end (2 cores: "
                "above 2, the wall-clock build times grow with it)" if "load" in info else "") + ".", "",
             "| scene | n_q | build [s] (target) | generated C [MB] (target) | µs per SS22 step (target) |",
             "| --- | --- | --- | --- | --- |"]
    for r in table:
        b, c, s = r["targets"]
        kept = (f" (kept from {r['kept_from']}, generated C at {r.get('optimise', '-O2, -O1 above 5 000 operations')})"
                if "kept_from" in r else "")
        lines.append(f"| {r['label']}{kept} | {r['n_q']} | {r['build_s']:.1f} (≤ {b:g}) | "
                     f"{r['generated_bytes'] / 1e6:.2f} (≤ {c:g}) | {r['step_us']:.1f} (≤ {s:g}) |")
    return lines


def markdown(table: list[dict], bodies: list[dict], modes: list[dict], fits: dict, info: dict) -> str:
    lines = target_table(table, info)
    if "families_from" in info:
        f = info["families_from"]
        lines += ["", f"The families below are from an earlier run: {f['date']}, `{f['command']}` (builds: median of "
                      f"{f['builds']}, steps: median of {f['repeats']} runs)."]
    lines += ["", "| family | sizes | build exponent | code exponent | step exponent (goals: ≤ 1.2, ≤ 1.2, ≤ 2) |",
              "| --- | --- | --- | --- | --- |"]
    for key, rows in (("bodies", bodies), ("modes", modes)):
        f = fits[key]
        lines.append(f"| {key} | {', '.join(str(r[key]) for r in rows)} | {f['build_s']:.2f} | "
                     f"{f['generated_bytes']:.2f} | {f['step_us']:.2f} |")
    lines += ["", "| scene | n_q | build [s] | model / codegen / gcc [s] | C [MB] | operations | µs/step | "
              "residual µs | Newton matrix µs | iterations / step | factorisations |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in [*bodies, *modes]:
        p = r["build_parts_s"]
        lines.append(f"| {r['scene']} | {r['n_q']} | {r['build_s']:.1f} | {p['model']:.1f} / {p['codegen']:.1f} / "
                     f"{p['compile']:.1f} | {r['generated_bytes'] / 1e6:.2f} | {r['operations']} | "
                     f"{r['step_us']:.1f} | {r['residual_us']:.2f} | {r['newton_matrix_us']:.1f} | "
                     f"{r['iterations_per_step']:.2f} | {r['factorisations']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    from flexlink.scene.loader import load_scene, parse_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="CI size: 1-3 links, 2 and 4 modes; no table")
    ap.add_argument("--builds", type=int, default=None, help="builds per scene (median; default 3, quick 1)")
    ap.add_argument("--repeats", type=int, default=None, help="step-timing runs (median; default 7, quick 3)")
    ap.add_argument("--max-modes", type=int, default=32,
                    help="largest mode count of the modes family (the 32-mode link takes minutes per build; the "
                         "table measures it once anyway)")
    ap.add_argument("--table-only", action="store_true",
                    help="measure only the issue's table; keep the families of --out/scaling.json")
    ap.add_argument("--keep-32", action="store_true",
                    help="with --table-only: keep the second-order 32-mode link's row of --out/scaling.json (minutes "
                         "per build); the first-order 32-mode rows are measured again")
    ap.add_argument("--out", type=Path, default=HERE,
                    help="where scaling.md, .json and .png go (default benchmarks/); only the default also rewrites "
                         "the README's and docs/performance.md's tables")
    args = ap.parse_args(argv)
    if args.table_only and not (args.out / "scaling.json").is_file():
        ap.exit(2, f"scaling.py: --table-only keeps the families of {args.out / 'scaling.json'}, which does not exist "
                   "(run once without --table-only, or point --out at a directory that has one)\n")
    builds = args.builds or (1 if args.quick else 3)
    repeats = args.repeats or (3 if args.quick else 7)
    link_counts = (1, 2, 3) if args.quick else (1, 2, 3, 4, 5, 6, 8)
    mode_counts = (2, 4) if args.quick else tuple(m for m in (1, 2, 4, 8, 16, 32) if m <= args.max_modes)
    bodies, modes, table = [], [], []
    timing_dir = Path(tempfile.mkdtemp(prefix="flexlink-scaling-"))      # the table's drivers, timed in turns
    load_at_start = os.getloadavg()[0]          # the machine is shared: the report says how busy it was
    families_from = None
    kept_rows: dict[str, dict] = {}
    if args.table_only:                                # a table row re-measured after a change of the code
        kept = json.loads((args.out / "scaling.json").read_text())
        bodies, modes, families_from = kept["bodies"], kept["modes"], kept["info"].get("families_from", kept["info"])
        link_counts, mode_counts = (), ()
        if args.keep_32:
            for r in kept["table"]:
                if r["label"] in (TABLE[2][0], OLD_32_LABEL):
                    kept_rows[TABLE[2][0]] = {**r, "label": TABLE[2][0],
                                              "kept_from": r.get("kept_from", kept["info"]["date"])}
    for n in link_counts:
        bodies.append(measure(parse_scene(chain_scene(n)), builds=builds, repeats=repeats))
        print(f"bodies {n}: {bodies[-1]}", flush=True)
    for m in mode_counts:
        in_table = not args.quick and m == TABLE[2][1]             # the table's row too: timed in turns there
        row = measure(parse_scene(modes_scene(m)), builds=builds, repeats=repeats,
                      keep=timing_dir / f"modes{m}" if in_table else None)
        modes.append({**row, "modes": m})
        print(f"modes {m}: {row}", flush=True)
    for label, source, targets in ([] if args.quick else TABLE):
        measured = [r for r in modes if isinstance(source, int) and r["modes"] == source and not args.table_only]
        if label in kept_rows:
            table.append(kept_rows[label])
            continue
        if measured:                                   # the same scene as a row of the family
            row = measured[0]
        else:
            if isinstance(source, tuple):
                scene = parse_scene(modes_scene(source[1], kinematics=source[0]))
            else:
                scene = parse_scene(modes_scene(source)) if isinstance(source, int) else load_scene(source)
            row = measure(scene, builds=builds, repeats=repeats, keep=timing_dir / f"row{len(table)}")
        table.append({**row, "label": label, "targets": targets})
        print(f"table {label}: {table[-1]}", flush=True)
        if label in LEAN_ROWS:
            lean = dataclasses.replace(scene, fmu=dataclasses.replace(scene.fmu, directional_derivatives=False))
            table.append({**measure(lean, builds=builds, repeats=repeats), "label": label + LEAN,
                          "targets": targets})
            print(f"table {label + LEAN}: {table[-1]}", flush=True)
    retime_interleaved(table, repeats)
    for row in [*table, *bodies, *modes]:
        row.pop("timing", None)
    shutil.rmtree(timing_dir, ignore_errors=True)
    fits = {"bodies": family(bodies, "bodies"), "modes": family(modes, "modes")}
    from flexlink.export.codegen import OPTIMISE_ENV

    info = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
            "quick": args.quick, "builds": builds, "repeats": repeats,
            "command": " ".join(["python benchmarks/scaling.py", *(argv if argv is not None else sys.argv[1:])]),
            "optimise": os.environ.get(OPTIMISE_ENV) or ("the default levels (-O2, -Og above 5 000 operations "
                                                         "with IRA's priority allocator; their complex-step twins "
                                                         "-O1, -O0 above 5 000; the dense product loop -O2; the "
                                                         f"Newton iteration's units {_avx_twins()})"),
            "load": (load_at_start, os.getloadavg()[0])}
    if families_from is not None:
        info["families_from"] = {k: families_from[k] for k in ("date", "command", "builds", "repeats")}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "scaling.json").write_text(json.dumps({"info": info, "table": table, "bodies": bodies,
                                                       "modes": modes, "fits": fits}, indent=1))
    (args.out / "scaling.md").write_text(markdown(table, bodies, modes, fits, info))
    plot(bodies, modes, fits, args.out / "scaling.png")
    if not args.quick and args.out.resolve() == HERE:      # a run elsewhere leaves the published tables alone
        from report import PAGE, publish_figure, rewrite_readme

        block = (f"{BEGIN}\n<!-- generated by `python benchmarks/scaling.py`: edit it, not this block -->\n\n"
                 + markdown(table, bodies, modes, fits, info)
                 + f"\n![cost against size]({publish_figure(args.out / 'scaling.png', PAGE)})\n\n" + END)
        rewrite_readme(PAGE, block, BEGIN, END)
        readme = (f"{README_BEGIN}\n<!-- generated by `python benchmarks/scaling.py`: edit it, not this block -->\n\n"
                  + "\n".join(target_table(table, info)) + f"\n{README_END}")
        rewrite_readme(ROOT / "README.md", readme, README_BEGIN, README_END)
    print((args.out / "scaling.md").read_text())


if __name__ == "__main__":
    main()
