"""Which examples an importer's Model Exchange solver can run (issue 21, "Model exchange that importers can
run"), and how well: every example FMU's ME interface under fmpy's CVode (BDF, what most FMI hosts run) and
under fmpy's explicit Euler (the simplest fixed-step importer), against the converged CVODES reference of the
same equations (``flexlink.tools.bench.reference_outputs`` at ``REFERENCE_RTOL``), beside the FMU's own SS22
Co-Simulation at the scene's step.

    python benchmarks/me_importers.py                   # every example, writes me_importers.{md,json}
    python benchmarks/me_importers.py --quick SCENE...  # CI size: the given scenes, 1 s manoeuvres

Each scene runs in a child process, and each importer run under fmpy's wall-clock limit (``--timeout``,
default 120 s): a solver that stalls or a crash is a row that says so, not a hung benchmark.  The manoeuvre
is ``flexlink bench``'s (a torque pulse on the first joint, or the built-in laws), 2 s long.  The Euler step
is the scene's SS22 step (rounded down to a divisor of the 10 ms output interval, as fmpy requires) and a
tenth of it.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))


def _scene(scene_path: str, stop: float, timeout: float) -> dict:
    """Every method on one scene in this process: relative RMS error against the reference and CPU s per
    simulated s, or the reason a method gave none."""
    import time

    import numpy as np

    from flexlink.errors import FlexlinkError
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.run.simulate import SlaveRunner
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case, reference_outputs, relative_error, run_model_exchange

    scene = load_scene(scene_path)
    model = build_model(scene)
    try:
        case = default_case(model, stop=stop)
    except FlexlinkError as exc:              # no torque on the first joint and no built-in law to follow
        return {m: {"na": str(exc)} for m in METHODS}
    fmu = cached_fmu(scene, model=model)
    ref = reference_outputs(case, rtol=REFERENCE_RTOL)
    sample = float(case.times[1] - case.times[0])
    h = sample / math.ceil(sample / scene.fmu.solver.step - 1e-9)   # the scene's step, a divisor of the output interval

    def ss22():
        t0 = time.process_time()
        with SlaveRunner(fmu) as runner:
            res = runner.run(case.stop, sample, inputs=case.inputs_at, outputs=case.outputs)
        return {n: np.interp(case.times, res["time"], res[n]) for n in case.outputs}, time.process_time() - t0

    runs = {"ss22": ss22,
            "cvode": lambda: run_model_exchange(case, fmu, relative_tolerance=1e-6, timeout=timeout),
            "euler": lambda: run_model_exchange(case, fmu, solver="Euler", step_size=h, timeout=timeout),
            "euler10": lambda: run_model_exchange(case, fmu, solver="Euler", step_size=h / 10, timeout=timeout)}
    row = {}
    for method, run in runs.items():
        try:
            y, cpu = run()
        except Exception as exc:             # the importer's own error or the FMU's refusal, as a row
            row[method] = {"failure": f"{type(exc).__name__}: {exc}"[:200]}
            continue
        error = relative_error(case, y, ref)
        row[method] = {"error": error if math.isfinite(error) else None, "cpu_s_per_s": cpu / case.stop}
    return row


#: The reference's tolerance: 1e-9 is three orders below the errors compared (CVode at rtol 1e-6 lands near
#: 1e-4) and affordable on the stiff examples, where CVODES at 1e-12 takes minutes per simulated second.
REFERENCE_RTOL = 1e-9

METHODS = {"ss22": "SS22 (CS, scene step)", "cvode": "fmpy CVode (ME, rtol 1e-6)",
           "euler": "fmpy Euler (ME, scene step)", "euler10": "fmpy Euler (ME, step/10)"}


def measure(scene: Path, stop: float, timeout: float) -> dict:
    """``_scene`` in a child process (a crash or a stall ends one row, not the benchmark)."""
    limit = 4 * timeout + 600                 # the reference and the build come first
    try:
        out = subprocess.run([sys.executable, __file__, "--one", str(scene), "--stop", str(stop),
                              "--timeout", str(timeout)], capture_output=True, text=True, timeout=limit,
                             check=False)
    except subprocess.TimeoutExpired:
        return {m: {"failure": f"no result within {limit:g} s"} for m in METHODS}
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or [f"exit status {out.returncode}"])[-1]
        return {m: {"failure": last[:200]} for m in METHODS}
    return json.loads(out.stdout.strip().splitlines()[-1])


def cell(r: dict) -> str:
    if "na" in r:
        return "–"
    if "failure" in r:
        return "fails"
    if r["error"] is None or r["error"] > 0.5:
        return "diverges" if r["error"] is None or r["error"] > 10 else f"{r['error']:.2g} (wrong)"
    return f"{r['error']:.1e} / {r['cpu_s_per_s']:.2g} s"


def markdown(rows: list[dict], command: str) -> str:
    lines = [f"Measured with `{command}`: relative RMS error of the manoeuvre's outputs against CVODES at rtol "
             f"{REFERENCE_RTOL:g} on the same equations / CPU seconds per simulated second (fmpy's Python loop "
             "included for ME). \"fails\": the importer stopped with an error (the reasons are in "
             "me_importers.json); \"–\": no manoeuvre (the first joint is not torque-driven and the scene has "
             "no built-in law).", "",
             "| scene | " + " | ".join(METHODS.values()) + " |", "| --- |" + " --- |" * len(METHODS)]
    for row in rows:
        lines.append(f"| {row['scene']} | " + " | ".join(cell(row[m]) for m in METHODS) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", type=Path)
    ap.add_argument("--quick", action="store_true", help="1 s manoeuvres, no files written")
    ap.add_argument("--stop", type=float, default=None)
    ap.add_argument("--timeout", type=float, default=120.0, help="wall-clock seconds per importer run")
    ap.add_argument("--one", metavar="SCENE", help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    args = ap.parse_args()
    stop = args.stop or (1.0 if args.quick else 2.0)
    if args.one:
        print(json.dumps(_scene(args.one, stop, args.timeout)))
        return
    rows = []
    for scene in args.scenes or EXAMPLES:
        row = {"scene": scene.stem, **measure(scene, stop, args.timeout)}
        print(json.dumps(row), flush=True)
        rows.append(row)
    if not args.quick:
        command = " ".join(["python benchmarks/me_importers.py", *map(str, args.scenes),
                            *(["--stop", f"{args.stop:g}"] if args.stop else []),
                            *(["--timeout", f"{args.timeout:g}"] if args.timeout != 120.0 else [])])
        (args.out / "me_importers.json").write_text(json.dumps(rows, indent=1))
        (args.out / "me_importers.md").write_text(markdown(rows, command))


if __name__ == "__main__":
    with tempfile.TemporaryDirectory():
        main()
