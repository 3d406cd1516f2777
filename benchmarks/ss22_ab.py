"""SS22 of a git revision against the working tree's, timed in the same run (before/after of an integrator change).

    python benchmarks/ss22_ab.py REV [SCENE.toml ...] [--rounds N] [--repeats N] [--tolerance TOL]
                                 [--order 4 --omega-step W]

For each scene (default: the four examples of ``benchmarks/newton_tolerance.py`` that iterate), the FMU's
sources (``sources/``, the generated model and the generic ``fmu_src``) are compiled twice with
``benchmarks/step_floor.c``: as they are, and with ``fmu_src/ss22.c``, ``ss22.h``, ``predictor.c``,
``predictor.h``, ``fmu_state.c``, ``cs_step.c``, ``cosimulation.h`` and ``instance.c`` (the FMU's state, with
order 4's starts) taken from git revision REV (a file REV does not have
compiles to nothing).  Both run the scene's bench manoeuvre
(``flexlink.tools.bench.default_case``, 2 s) at the scene's step (with ``--order 4``: the order-4 option at the
step where ω_max Δt = ``--omega-step``, ω_max the highest natural frequency at the start), alternately for
``--rounds`` rounds of ``--repeats`` runs each, so that the machine's load
falls on both alike; the report gives the median CPU µs per SS22 step of each, their ratio and the counters
(Newton iterations and factorisations per step: counts, the same in every run).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import statistics
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import step_floor  # noqa: E402

SWAPPED = ("ss22.c", "ss22.h", "predictor.c", "predictor.h", "fmu_state.c", "cs_step.c", "cosimulation.h", "instance.c",
           "variables.c", "logging.c", "mass_update.c", "mass_update.h")
DEFAULT = ["fast_two_link.toml", "planar_chain_5.toml", "six_axis_arm.toml", "rotating_link.toml"]


def fmu_with_sources_of(fmu: Path, rev: str, out: Path) -> Path:
    """A copy of ``fmu`` whose ``sources/`` hold the SWAPPED files of git revision ``rev``."""
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(out, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            name = item.filename.removeprefix("sources/")
            if item.filename.startswith("sources/") and name in SWAPPED:
                shown = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:fmu_src/{name}"],
                                       capture_output=True, check=False)
                # a file the revision did not have yet (predictor.c before 2026-11-28) compiles to nothing
                data = shown.stdout if shown.returncode == 0 else b"/* not in this revision */\n"
            zout.writestr(item, data)
    return out


def compare(scene_path: Path, rev: str, rounds: int, repeats: int, tolerance: float | None,
            order: int = 2, omega_step: float = 0.299) -> dict:
    """Median µs per SS22 step and counters per step of REV's integrator and the working tree's."""
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.analysis import natural_frequencies
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case

    scene = load_scene(scene_path)
    model = build_model(scene)
    case = default_case(model, stop=2.0)
    fmu = Path(cached_fmu(scene, model=model))
    start = {"solver.step": scene.fmu.solver.step}
    if order == 4:
        omega_max = 2 * math.pi * max(natural_frequencies(model).frequencies_hz)   # as chain_speed.py
        start = {"solver.step": omega_step / omega_max, "solver.order": 4}
    if tolerance is not None:
        start["solver.tolerance"] = tolerance
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        exes = {"now": step_floor.compile_driver(fmu, tmp / "now"),
                rev: step_floor.compile_driver(fmu_with_sources_of(fmu, rev, tmp / "rev.fmu"), tmp / "rev")}
        import fmpy

        guid = fmpy.read_model_description(str(fmu)).guid
        tokens = step_floor.manoeuvre_tokens(fmu, case, start)
        times: dict[str, list[float]] = {k: [] for k in exes}
        counts: dict[str, dict] = {}
        for _ in range(rounds):
            for key, exe in exes.items():
                out = subprocess.run([str(exe), guid, str(repeats), *tokens], capture_output=True, text=True,
                                     check=True)
                res = json.loads(out.stdout)
                times[key].append(res["ss22_step_s"])
                steps = max(res["ss22_steps"], 1)
                counts[key] = {"iterations": res["newton_iterations"] / steps,
                               "factorisations": res["factorisations"] / steps,
                               "residual_us": res["residual_s"] * 1e6, "newton_matrix_us": res["newton_matrix_s"] * 1e6,
                               "lu_us": res["lu_factor_s"] * 1e6, "solve_us": res["lu_solve_s"] * 1e6}
        shutil.rmtree(tmp, ignore_errors=True)
    med = {k: statistics.median(v) * 1e6 for k, v in times.items()}
    return {"scene": scene_path.stem, "rev": rev, "us_per_step": med, "ratio": med[rev] / med["now"], "counts": counts}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("rev", help="git revision whose fmu_src/ss22.[ch] and fmu_state.c are the 'before'")
    parser.add_argument("scenes", nargs="*")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--tolerance", type=float, help="solver.tolerance (default: the scene's)")
    parser.add_argument("--order", type=int, choices=(2, 4), default=2)
    parser.add_argument("--omega-step", type=float, default=0.299,
                        help="with --order 4: ω_max Δt of the step (the FMU refuses above 0.3)")
    args = parser.parse_args(argv)
    scenes = [Path(s) for s in args.scenes] or [ROOT / "examples" / s for s in DEFAULT]
    print(f"| scene | µs/step {args.rev} | µs/step now | {args.rev} / now | iterations/step {args.rev} → now | "
          "LU/step → now | residual, Newton matrix, LU, solve µs |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for scene in scenes:
        r = compare(scene, args.rev, args.rounds, args.repeats, args.tolerance, args.order, args.omega_step)
        a, b = r["counts"][args.rev], r["counts"]["now"]
        us = r["us_per_step"]
        print(f"| {r['scene']} | {us[args.rev]:.2f} | {us['now']:.2f} | {r['ratio']:.2f} | "
              f"{a['iterations']:.2f} → {b['iterations']:.2f} | "
              f"{a['factorisations']:.3f} → {b['factorisations']:.3f} | "
              f"{b['residual_us']:.2f}, {b['newton_matrix_us']:.2f}, {b['lu_us']:.2f}, {b['solve_us']:.3f} |")


if __name__ == "__main__":
    main()
