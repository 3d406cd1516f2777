"""How tight SS22's Newton iteration must be: its error against the step's own truncation error (issue 22).

    python benchmarks/newton_tolerance.py [SCENE.toml ...] [--tolerances 1e-6 1e-8 ...] [--stop T]
        [--step scene|recommended] [--json]

Each scene runs its bench manoeuvre (``flexlink.tools.bench.default_case``: ±τ on the first joint, or its
own law) at its own ``solver.step`` h, or with ``--step recommended`` at the step ``flexlink explain``
recommends (20 steps a period of the highest mode: issue 22 counts iterations and factorisations there), once
per ``solver.tolerance``.  Two errors are compared, both as the
largest difference over the outputs and the communication points, relative to each output's peak:

* the **Newton error** of a tolerance: the run against the same run at tolerance 1e-13 (the same
  discretisation with the iteration converged to rounding);
* the **truncation error** of the step: the run at 1e-13 against the run at h/2, times 4/3 (SS22 is second
  order: Richardson's estimate of the error of the h run).

A tolerance is loose enough when its Newton error is a small fraction of the truncation error; the counters
(Newton iterations and factorisations per SS22 step) say what it costs.  No CVODES reference is needed.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["rotating_link.toml", "fast_two_link.toml", "planar_chain_5.toml", "six_axis_arm.toml",
           "steel_beam_two_links.toml"]
TIGHT = 1e-13


def difference(names: list[str], a: dict, b: dict) -> float:
    """Largest |a − b| over the outputs ``names`` and the times, relative to each output's peak in b."""
    worst = 0.0
    for name in names:
        peak = max(float(np.max(np.abs(b[name]))), 1e-300)
        worst = max(worst, float(np.max(np.abs(a[name] - b[name]))) / peak)
    return worst


def study(scene_path: Path, tolerances: list[float], stop: float, step: str = "scene") -> list[dict]:
    """Rows of (tolerance, Newton error, truncation error, iterations and factorisations per step)."""
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.run.simulate import SlaveRunner
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case
    from flexlink.tools.fidelity import recommended_step

    scene = load_scene(scene_path)
    model = build_model(scene)
    case = default_case(model, stop=stop)
    fmu = cached_fmu(scene, model=model)
    with SlaveRunner(fmu) as runner:
        h = (recommended_step(model)[0] if step == "recommended" else
             next(float(v.start) for v in runner.model_description.modelVariables if v.name == "solver.step"))
        names = [n for n in case.outputs if n in runner.vr]      # the bench's outputs the FMU has

        def run(tol: float, step: float) -> tuple[dict, dict]:
            res = runner.run(case.stop, 0.01, inputs=case.inputs_at, outputs=names,
                             start={"solver.tolerance": tol, "solver.step": step})
            return res, runner.solver_statistics()

        tight, _ = run(TIGHT, h)
        half, _ = run(TIGHT, h / 2)
        truncation = difference(names, tight, half) * 4.0 / 3.0
        rows = []
        for tol in tolerances:
            res, stats = run(tol, h)
            steps = max(stats.get("steps", 0), 1)
            rows.append({"scene": scene_path.stem, "step": h, "tolerance": tol,
                         "newton_error": difference(names, res, tight), "truncation_error": truncation,
                         "iterations_per_step": stats.get("newton_iterations", 0) / steps,
                         "factorisations_per_step": stats.get("factorisations", 0) / steps})
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scenes", nargs="*", help="scene files (default: five examples)")
    parser.add_argument("--tolerances", nargs="+", type=float, default=[1e-4, 1e-6, 1e-8, 1e-10, 1e-12])
    parser.add_argument("--stop", type=float, default=2.0, help="end of the manoeuvre, s (default 2)")
    parser.add_argument("--step", choices=["scene", "recommended"], default="scene",
                        help="SS22 step: the scene's solver.step (default) or the recommended one")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    scenes = [Path(s) for s in args.scenes] or [ROOT / "examples" / s for s in DEFAULT]
    rows = [row for scene in scenes for row in study(scene, args.tolerances, args.stop, args.step)]
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print("| scene | h | tolerance | Newton error | truncation error | ratio | iterations/step | LU/step |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['scene']} | {r['step']:g} | {r['tolerance']:g} | {r['newton_error']:.2e} | "
              f"{r['truncation_error']:.2e} | {r['newton_error'] / r['truncation_error']:.1e} | "
              f"{r['iterations_per_step']:.2f} | {r['factorisations_per_step']:.3f} |")


if __name__ == "__main__":
    main()
