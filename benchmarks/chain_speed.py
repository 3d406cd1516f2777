"""Issue 22's chain comparison: SS22 in the FMU against the best of CVODES and IDAS at equal error, and where
each one's time goes.

    python benchmarks/chain_speed.py [SCENE.toml] [--stop T] [--sample S] [--repeats N] [--reference-rtol R]
        [--halvings K] [--order4-floor H] [--order4-tolerance T,...] [--tolerances R,...] [--split-steps H,...]
        [--bdf2] [--json]

Default scene: ``benchmarks/scenes/planar_chain_3.toml`` (3 flexible links, 3 modes each, second-order
kinematics), over ``flexlink bench``'s manoeuvre (``flexlink.tools.bench``: the same equations, the same
error measure, CPU seconds per simulated second, medians of ``--repeats`` runs, every method timed in the same
process).  The reference is CVODES at ``--reference-rtol`` (default 1e-10, not the bench's 1e-12: on this chain
CVODES at 1e-12 takes minutes a simulated second), its own error stated against the run at a tenth of it.
For each error level 1e-3, 1e-4, 1e-5 each method's cost is read off
its own cost-against-error curve (log-log interpolation between its settings; a level beyond a method's
settings is not reported), and the ratio is CVODES's or IDAS's, whichever is cheaper, over SS22's.

A scene driven by a built-in law (``examples/steel_beam_two_links.toml``) is measured over its law from
t = 0 to ``--stop``: CVODES and IDAS then integrate the same equations with the law's (θ, θ̇, θ̈) as functions
of time, as the FMU evaluates it (``flexlink.tools.bench.casadi_integrators``).  ``--halvings`` sets how
many times SS22's step is halved from 1 ms, ``--order4-floor`` the smallest order-4 step tried (a stiff
scene's stability bound lies below order 2's finest step), ``--sample`` the output samples the error is
measured at (the bench's 10 ms is too coarse for a window of a few hundredths of a second).

Where the time goes: the FMU's sources compiled with ``benchmarks/step_floor.c`` time one residual, one Newton
matrix, one LU and one solve at a state of the run, and count the Newton iterations and factorisations a
step; CasADi's own statistics count CVODES's steps, right-hand sides and Jacobians over the run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import step_floor  # noqa: E402

DEFAULT = HERE / "scenes" / "planar_chain_3.toml"
LEVELS = (1e-3, 1e-4, 1e-5)
HALVINGS = 10                                           # 1 ms … 2 µs
TOLERANCES = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
ORDER4 = "ss22 order 4 (FMU, Richardson)"
ORDER4_LOOSE = "ss22 order 4, solver.tolerance"


def with_tolerance(case, tolerance: float):
    """``case`` whose scene asks for ``solver.tolerance`` = ``tolerance`` (the bench sets the scene's solver)."""
    import copy
    import dataclasses

    scene = case.model.scene
    model = copy.copy(case.model)
    model.scene = dataclasses.replace(scene, fmu=dataclasses.replace(
        scene.fmu, solver=dataclasses.replace(scene.fmu.solver, tolerance=tolerance)))
    return dataclasses.replace(case, model=model)


def cost_at(rows: list[dict], level: float) -> float | None:
    """A method's CPU s/s at error ``level``: log-log interpolation between the two settings whose errors bracket
    it along the method's settings ordered by error; else (a level beyond them, or a curve that is not monotone
    there) its cheapest setting whose error is at most ``level``, as ``benchmarks/report.py`` judges."""
    pts = sorted((r["error"], r["cpu_s_per_simulated_s"]) for r in rows if r["error"] is not None)
    for (e0, c0), (e1, c1) in zip(pts[:-1], pts[1:], strict=True):
        if e0 <= level <= e1 and e1 > e0 and c1 <= c0:
            w = np.log(level / e0) / np.log(e1 / e0)
            return float(np.exp(np.log(c0) + w * np.log(c1 / c0)))
    ok = [c for e, c in pts if e <= level]
    return min(ok) if ok else None


def levels(rows: list[dict]) -> list[dict]:
    """SS22's (order 2 and order 4) and the best of CVODES/IDAS's cost at each error level, and their ratios."""
    out = []
    for level in LEVELS:
        ss22 = cost_at([r for r in rows if r["method"] == "ss22 (FMU)"], level)
        order4 = cost_at([r for r in rows if r["method"] == ORDER4], level)
        # each looser tolerance is its own curve of settings; the cheapest of them at this level
        curves = sorted({r["method"] for r in rows if r["method"].startswith(ORDER4_LOOSE)})
        costs = [(c, m) for c, m in ((cost_at([r for r in rows if r["method"] == m], level), m) for m in curves)
                 if c is not None]
        loose, loose_method = min(costs) if costs else (None, "")
        sundials = sorted({r["method"] for r in rows if r["method"].split()[0] in ("cvodes", "idas")})
        best = [c for c in (cost_at([r for r in rows if r["method"] == m], level) for m in sundials)
                if c is not None]
        sundials = min(best) if best else None
        out.append({"error": level, "ss22_cpu": ss22, "order4_cpu": order4, "sundials_cpu": sundials,
                    "ratio": sundials / ss22 if sundials and ss22 else None,
                    "ratio_order4": sundials / order4 if sundials and order4 else None,
                    "order4_loose_cpu": loose, "ratio_order4_loose": sundials / loose if sundials and loose else None,
                    "order4_loose_tolerance": loose_method.removeprefix(ORDER4_LOOSE).strip()})
    return out


def sundials_counts(case, plugin: str, tol: float, max_order: int | None = None) -> dict:
    """One run of CasADi's CVODES or IDAS over ``case`` as ``flexlink bench`` runs it: steps, right-hand
    sides, Jacobians and Newton iterations summed over the input pieces."""
    from flexlink.tools.bench import casadi_integrators, start_state

    xk = np.concatenate(start_state(case))
    total = {"nsteps": 0, "nfevals": 0, "nlinsetups": 0, "nniters": 0}
    for F, pk, _grid in casadi_integrators(case, plugin, tol, max_order=max_order):
        xk = np.asarray(F(x0=xk, p=pk)["xf"])[:, -1]
        stats = F.stats()
        for k in total:
            total[k] += int(stats.get(k, 0))
    return total


def measure(scene_path: Path, stop: float, repeats: int, reference_rtol: float,
            order4_tolerances=(), *, sample: float = 0.01, halvings: int = HALVINGS,
            order4_floor: float | None = None, tolerances=TOLERANCES, split_steps=None,
            max_orders=(None,)) -> dict:
    """Every row, the ratios at the error levels and the per-step split.

    ``order4_tolerances``: order 4 again at each of these ``solver.tolerance``s, a curve each;
    ``order4_floor``: the smallest order-4 step (default order 2's finest); ``split_steps``: the SS22 steps
    the per-step split is measured at (default the four coarsest).
    """
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.analysis import natural_frequencies
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import bench_casadi, bench_ss22, default_case, reference_outputs, relative_error

    scene = load_scene(scene_path)
    model = build_model(scene)
    case = default_case(model, stop=stop, sample=sample)
    steps = tuple(1e-3 / 2**k for k in range(halvings))
    ref = reference_outputs(case, reference_rtol)
    reference_error = relative_error(case, ref, reference_outputs(case, reference_rtol / 10))
    fmu = cached_fmu(scene, model=model)
    rows = [r.as_dict() for r in bench_ss22(case, fmu, steps, [(0.5, 0.5)], ref, repeats)]
    # order 4 (Richardson) only where it is stable, ω_max Δt ≤ 0.3 (the FMU refuses larger steps): at its bound,
    # two thirds of it, then the halvings below; by default none below order 2's finest step (a stiff scene's
    # bound, the 40-element FE beam's 0.3 µs, would take hours over seconds: --order4-floor for a short window)
    omega_max = 2 * np.pi * max(natural_frequencies(model).frequencies_hz)
    floor = steps[-1] if order4_floor is None else order4_floor
    order4 = [h for h in (0.299 / omega_max, 0.2 / omega_max, *[h for h in steps if omega_max * h <= 0.2][:6])
              if h >= floor]
    rows += [r.as_dict() for r in bench_ss22(case, fmu, order4, [(0.5, 0.5)], ref, repeats, order=4)]
    for tolerance in order4_tolerances:
        # the same steps with the Newton iteration stopped far looser than the scene's 1e-10: a setting like
        # CVODES's rtol, each error level reading the cheapest (docs/performance.md, "How tight the Newton
        # iteration must be"); the error measured says whether the Newton error stays below the step's own
        for r in bench_ss22(with_tolerance(case, tolerance), fmu, order4, [(0.5, 0.5)], ref, repeats, order=4):
            rows.append(r.as_dict() | {"method": f"{ORDER4_LOOSE} {tolerance:g}"})
    for plugin in ("cvodes", "idas"):
        for max_order in max_orders:
            for r in bench_casadi(case, plugin, tolerances, ref, repeats, max_order):
                d = r.as_dict()
                d.update(sundials_counts(case, plugin, float(d["setting"].split("=")[1]), max_order))
                rows.append(d)
    with tempfile.TemporaryDirectory() as tmp:
        exe = step_floor.compile_driver(fmu, tmp)
        split = [step_floor.measure(exe, fmu, case, step=h, repeats=repeats) for h in split_steps or steps[:4]]
    return {"scene": scene_path.stem, "n_q": model.n_q, "stop": stop, "sample": sample, "repeats": repeats,
            "rows": rows, "driven_by_law": bool(model.laws),
            "order4_tolerances": list(order4_tolerances),
            "split": split, "omega_max_hz": omega_max / (2 * np.pi), "load": os.getloadavg(),
            "reference_rtol": reference_rtol, "reference_error": reference_error}


def markdown(data: dict) -> str:
    """The rows, the ratios and the split as Markdown."""
    what = (f"its built-in law from 0 to {data['stop']:g} s, outputs sampled every {data['sample']:g} s"
            if data.get("driven_by_law") else f"{data['stop']:g} s of the bench manoeuvre")
    out = [f"{data['scene']} ({data['n_q']} coordinates), {what}, medians of "
           f"{data['repeats']} runs (reference: CVODES rtol {data['reference_rtol']:g}, its error "
           f"{data['reference_error']:.1e}; load average during the run {fmt_load(data)})", "",
           "| method | setting | CPU s/s | error | iterations/step | LU/step | steps | rhs | Jacobians |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in data["rows"]:
        if r["error"] is None:
            out.append(f"| {r['method']} | {r['setting']} | refused | {str(r['failure'])[:60]} | | | | | |")
            continue
        it = "" if r["iterations_per_step"] is None else f"{r['iterations_per_step']:.2f}"
        lu = "" if r["lu_per_step"] is None else f"{r['lu_per_step']:.3f}"
        out.append(f"| {r['method']} | {r['setting']} | {r['cpu_s_per_simulated_s']:.3g} | {r['error']:.2e} | {it} | "
                   f"{lu} | {r.get('nsteps', '')} | {r.get('nfevals', '')} | {r.get('nlinsetups', '')} |")
    tolerances = data.get("order4_tolerances") or ([data["order4_tolerance"]] if data.get("order4_tolerance") else [])
    loose = f"order 4, tolerance {' or '.join(f'{t:g}' for t in tolerances)}" if tolerances else "–"
    out += ["", "| error | SS22 CPU s/s | SS22 order 4 CPU s/s | best of CVODES/IDAS CPU s/s | ratio | "
            f"ratio, order 4 | {loose} CPU s/s | ratio, {loose} |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for lv in levels(data["rows"]):
        cells = [f"{x:.3g}" if x is not None else "–"
                 for x in (lv["ss22_cpu"], lv["order4_cpu"], lv["sundials_cpu"], lv["ratio"], lv["ratio_order4"],
                           lv.get("order4_loose_cpu"), lv.get("ratio_order4_loose"))]
        if len(tolerances) > 1 and lv.get("order4_loose_tolerance"):          # which curve it read
            cells[5] += f" (at {lv['order4_loose_tolerance']})"
        out.append(f"| {lv['error']:g} | " + " | ".join(cells) + " |")
    out += ["", "| SS22 step | µs/step | residual µs | Newton matrix µs | LU µs | solve µs | iterations/step | "
            "LU/step | (it × (residual + solve) + LU/step × (matrix + LU)) / step |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for s in data["split"]:
        it = s["newton_iterations"] / max(s["ss22_steps"], 1)
        lu = s["factorisations"] / max(s["ss22_steps"], 1)
        model_cost = it * (s["residual_s"] + s["lu_solve_s"]) + lu * (s["newton_matrix_s"] + s["lu_factor_s"])
        out.append(f"| {s['step']:g} | {s['step_s'] * 1e6:.2f} | {s['residual_s'] * 1e6:.2f} | "
                   f"{s['newton_matrix_s'] * 1e6:.2f} | {s['lu_factor_s'] * 1e6:.2f} | {s['lu_solve_s'] * 1e6:.3f} | "
                   f"{it:.2f} | {lu:.3f} | {model_cost / s['step_s']:.2f} |")
    if data.get("note"):
        out += ["", f"Note: {data['note']}."]
    return "\n".join(out)


def fmt_load(data: dict) -> str:
    """The 1-, 5- and 15-minute load averages at the end of the run, or "not recorded"."""
    return "/".join(f"{x:.1f}" for x in data["load"]) if data.get("load") else "not recorded"


def floats(text: str) -> tuple[float, ...]:
    """A comma-separated list of positive numbers (an option's value)."""
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None
    if not all(v > 0 and math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"every number must be > 0: {text!r}")
    return values


def positive(kind):
    """An argparse type: ``kind`` (float or int) and > 0."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not (value > 0 and math.isfinite(value)):
            raise argparse.ArgumentTypeError(f"must be > 0: {text!r}")
        return value
    return parse


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", nargs="?", default=str(DEFAULT))
    parser.add_argument("--stop", type=positive(float), default=2.0, help="end of the manoeuvre, s (default 2: ±τ)")
    parser.add_argument("--repeats", type=positive(int), default=5)
    parser.add_argument("--reference-rtol", type=positive(float), default=1e-10)
    parser.add_argument("--order4-tolerance", type=lambda x: () if x == "0" else floats(x), default=(1e-4, 1e-6),
                        help="also run order 4 at these solver.tolerances, comma-separated (0: not; default "
                             "1e-4,1e-6)")
    parser.add_argument("--sample", type=positive(float), default=0.01,
                        help="output samples the error is measured at, s")
    parser.add_argument("--halvings", type=positive(int), default=HALVINGS,
                        help="how many SS22 steps: 1 ms and its halvings (default 10: 1 ms … 2 µs)")
    parser.add_argument("--order4-floor", type=positive(float),
                        help="smallest order-4 step, s (default order 2's finest)")
    parser.add_argument("--tolerances", type=floats, default=TOLERANCES, help="CVODES/IDAS rtols, comma-separated")
    parser.add_argument("--split-steps", type=floats, help="SS22 steps of the per-step split (default the 4 coarsest)")
    parser.add_argument("--bdf2", action="store_true",
                        help="CVODES and IDAS also with their BDF order capped at 2 (A-stable), in the best of")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--from-json", help="render a --json output again instead of measuring")
    args = parser.parse_args(argv)
    if args.from_json:
        data = json.loads(Path(args.from_json).read_text())
    else:
        data = measure(Path(args.scene), args.stop, args.repeats, args.reference_rtol, args.order4_tolerance,
                       sample=args.sample, halvings=args.halvings, order4_floor=args.order4_floor,
                       tolerances=args.tolerances, split_steps=args.split_steps,
                       max_orders=(None, 2) if args.bdf2 else (None,))
    print(json.dumps(data, indent=1) if args.json else markdown(data))


if __name__ == "__main__":
    main()
