"""CPU time of flexlink's FMU against Exudyn at equal joint-angle error, on examples/fast_two_link.toml (issue 14).

    python benchmarks/exudyn_two_link.py [--repeats 3] [--stop 2.0] [--json FILE]

(run from the repository root with exudyn installed: ``pip install -e .[test]``).

Both sides simulate the arm over [0, stop] with 1 ms outputs:

* flexlink: the FMU of the scene as given (6 Hermite elements per link, second-order kinematics, 26
  coordinates) through fmpy's FMU2Slave (``flexlink.run.simulate.SlaveRunner``), 1 ms communication steps, the
  torques sampled at the middle of each communication step, internal SS22 steps ``solver.step`` with Θ = ½.
  (``solver.order = 4`` is not usable here: its Richardson extrapolation amplifies unresolved modes by up to
  5/3 a step, docs/fidelity.md, "The order-4 option", and the 6-element chain's top mode, 16.3 kHz, is unresolved at any
  step above ~1e-5 s; it is discarded within 20 ms at every step from 1e-3 to 5e-5 s.)
* Exudyn: ``tests/references/exudyn_arm.py`` (geometrically exact 2D beams, N linear elements per link,
  generalised-α with ρ∞ = 0.9, step h, sparse solver, the torques as Python user functions).

The error is the joint-angle error max over both joints of max_t |θ − θ_ref| / max_t |θ_ref|, against the
finest reference: Exudyn with 64 elements at h = 2.5e-5 s (its own change from 32 elements or from h = 5e-5 s
is below 1e-5). The CPU time is the process time of the run alone (the FMU instantiated and the Exudyn model
assembled beforehand; the one-off FMU build, about 80 s, is not counted), the median of ``--repeats`` runs.
"At equal error": for each error target, the cheapest run of each tool that meets it (the Pareto front), and the
ratio of their CPU times; the same for the tip deflections (max over both links). Takes about 75 s on a 2-core
machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]   # this checkout's flexlink, and the Exudyn model of the tests

from references.exudyn_arm import simulate, torques  # noqa: E402

from flexlink.export.cache import cached_fmu  # noqa: E402
from flexlink.run.simulate import SlaveRunner  # noqa: E402

SCENE = ROOT / "examples" / "fast_two_link.toml"
COMM = 1e-3
ANGLES = ("shoulder.theta", "elbow.theta")
TIPS = ("upper.tip.v", "fore.tip.v")
FLEX_STEPS = (1e-3, 5e-4, 2.5e-4, 1e-4, 5e-5)
EXUDYN_RUNS = [(n, h) for n in (4, 8, 16, 32) for h in (1e-3, 5e-4, 2.5e-4, 1e-4)]
REFERENCE = (64, 2.5e-5)
TARGETS = (1e-4, 3e-5, 1e-5, 5e-6)
TIP_TARGETS = (3e-2, 1e-2, 3e-3, 1e-3)


def midpoint_inputs(t: float) -> dict[str, float]:
    tau1, tau2 = torques(t + 0.5 * COMM)
    return {"shoulder.tau": tau1, "elbow.tau": tau2}


def error(run: dict, ref: dict, keys=ANGLES) -> float:
    return max(float(np.max(np.abs(np.interp(ref["time"], run["time"], run[k]) - ref[k])) / np.max(np.abs(ref[k])))
               for k in keys)


def time_flexlink(runner: SlaveRunner, stop: float, step: float, order: int, repeats: int):
    """(outputs, median CPU seconds), or (None, the FMU's last messages) when a step is discarded."""
    from fmpy.fmi1 import FMICallException

    cpu = []
    for _ in range(repeats):
        t0 = time.process_time()
        try:
            res = runner.run(stop, COMM, inputs=midpoint_inputs, start={"solver.step": step, "solver.order": order},
                             outputs=[*ANGLES, *TIPS])
        except FMICallException as exc:
            return None, f"{exc}: {' | '.join(runner.messages[-2:])}"
        cpu.append(time.process_time() - t0)
    return res, statistics.median(cpu)


def time_exudyn(stop: float, n: int, h: float, repeats: int):
    runs = [simulate(n, h, stop, output_step=COMM) for _ in range(repeats)]
    return runs[-1], statistics.median(r["cpu"] for r in runs)


def front(rows: list[dict], tool: str, target: float, key: str = "angle_error") -> dict | None:
    ok = [r for r in rows if r["tool"] == tool and r[key] <= target]
    return min(ok, key=lambda r: r["cpu"]) if ok else None


def equal_error_table(rows: list[dict], key: str, targets) -> None:
    print(f"{'target':>8s}  {'flexlink':<30s} {'Exudyn':<28s} {'CPU ratio flexlink/Exudyn':>26s}")
    for target in targets:
        f, e = front(rows, "flexlink", target, key), front(rows, "Exudyn", target, key)
        fs = f"{f['config']} {f['cpu']:.3f} s" if f else "- (not reached)"
        es = f"{e['config']} {e['cpu']:.3f} s" if e else "- (not reached)"
        ratio = f"{f['cpu'] / e['cpu']:.2f}" if f and e else "-"
        print(f"{target:8.0e}  {fs:<30s} {es:<28s} {ratio:>26s}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stop", type=float, default=2.0)
    ap.add_argument("--json", type=Path, help="write the rows to this file")
    args = ap.parse_args(argv)

    print(f"reference: Exudyn N = {REFERENCE[0]}, h = {REFERENCE[1]:g} s, 0-{args.stop:g} s", flush=True)
    ref = simulate(*REFERENCE, args.stop, output_step=COMM)
    rows, failures = [], []
    fmu = cached_fmu(SCENE)
    with SlaveRunner(fmu, logging=True) as runner:
        for step in FLEX_STEPS:
            res, cpu = time_flexlink(runner, args.stop, step, 2, args.repeats)
            if res is None:
                print(f"  flexlink step {step:g}: failed, {cpu}", flush=True)
                failures.append(f"flexlink 6 el., step {step:g}: {cpu}")
                continue
            rows.append({"tool": "flexlink", "config": f"6 el., step {step:g}", "cpu": cpu,
                         "angle_error": error(res, ref), "tip_error": error(res, ref, TIPS)})
            print(f"  {rows[-1]}", flush=True)
    for n, h in EXUDYN_RUNS:
        res, cpu = time_exudyn(args.stop, n, h, args.repeats)
        rows.append({"tool": "Exudyn", "config": f"N {n}, h {h:g}", "cpu": cpu,
                     "angle_error": error(res, ref), "tip_error": error(res, ref, TIPS)})
        print(f"  {rows[-1]}", flush=True)

    print(f"\n{'tool':<9s} {'configuration':<28s} {'CPU s':>8s} {'angle err':>10s} {'tip err':>9s}")
    for r in rows:
        print(f"{r['tool']:<9s} {r['config']:<28s} {r['cpu']:8.3f} {r['angle_error']:10.2e} {r['tip_error']:9.2e}")
    print(f"\nat equal joint-angle error (cheapest run meeting the target; medians of {args.repeats} runs):")
    equal_error_table(rows, "angle_error", TARGETS)
    print("\nthe same at equal tip-deflection error (max over both links, relative to the amplitude):")
    equal_error_table(rows, "tip_error", TIP_TARGETS)
    for f in failures:
        print(f"failed: {f}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
