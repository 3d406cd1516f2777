"""Realtime factor of the closed loop through fmpy (issue 22), at 1 ms sample time by default.

    python benchmarks/closed_loop.py [SCENE.toml ...] [--sample-time S] [--repeats N] [--rounds R] [--json]
                                     [--write [PAGE]]
    python benchmarks/closed_loop.py --startup N [SCENE.toml]

For each scene: the FMU is built (cached, not timed), the controllers designed (not timed), then a 90°
rest-to-rest manoeuvre in 1.5 s plus 1.5 s settle is run ``--repeats`` times on one instance (``fmi2Reset``
between runs) with the LQR + Kalman law and with the PD, each time by both loops of
:class:`controllers.cosim.FmuLoop` in turn: the fast one (``fast=True``: the law's affine form, raw cffi
calls) and the reference loop (``fast=False``: ``law.step`` per sample), whose runs must agree to 1e-9 of
the torque's scale (the tests hold them to 1e-12 relative).  The realtime factor is simulated seconds per
wall-clock second of the loop (reset, initialisation and every sample's getReal / law / setReal / doStep);
each figure is the median over the repeats, the speed-up the median of the per-repeat ratios.  "CPU" is the
same factor on the process's CPU time: on a loaded machine the wall clock also counts the time the loop
waited for a core.  The per-sample split gives the FMU alone: the same three calls through cffi with a
constant torque and no law; and "from C": ``benchmarks/sample_cost.c``, compiled with the FMU's own sources,
replays the fast loop's recorded torques through the same three calls without Python.  ``--write`` puts the
table into docs/performance.md between ``<!-- closed-loop:begin -->`` and ``<!-- closed-loop:end -->`` (or
into PAGE), with the load average at the start and the end: the figures there come from this command, never
typed.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["rotating_link.toml", "rotating_link_payload.toml"]
PAGE = ROOT / "docs" / "performance.md"
BEGIN, END = "<!-- closed-loop:begin -->", "<!-- closed-loop:end -->"
SAMPLE_DRIVER = Path(__file__).resolve().parent / "sample_cost.c"


def fmu_in_c(fmu, names: list[str], torque_name: str, torques: np.ndarray, dt: float, repeats: int) -> dict:
    """Microseconds per sample of getReal + setReal + doStep called from C on the recorded ``torques`` (and of
    doStep alone): benchmarks/sample_cost.c compiled with the FMU's sources, medians of ``repeats`` runs."""
    import fmpy

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from step_floor import compile_driver

    md = fmpy.read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    with tempfile.TemporaryDirectory() as tmp:
        exe = compile_driver(fmu, tmp, SAMPLE_DRIVER)
        path = Path(tmp) / "torques.bin"
        np.ascontiguousarray(torques, dtype=np.float64).tofile(path)
        out = subprocess.run([str(exe), md.guid, str(path), repr(dt), str(repeats), str(vr[torque_name]),
                              *(str(vr[n]) for n in names)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def fmu_only(loop, names: list[str], torque: str, n_steps: int, dt: float, repeats: int) -> tuple[float, float]:
    """Median wall and CPU time per sample of getReal + setReal + doStep alone (constant torque, no law),
    called as the fast loop calls them (the host's raw functions through cffi, pointers made once)."""
    from flexlink.run.host import pointer

    s = loop.slave
    get_real, set_real, do_step = (loop.host.raw(f) for f in ("fmi2GetReal", "fmi2SetReal", "fmi2DoStep"))
    vr_out = (ctypes.c_uint * len(names))(*[loop.vr(n) for n in names])
    val_out = (ctypes.c_double * len(names))()
    vr_in = (ctypes.c_uint * 1)(loop.vr(torque))
    val_in = (ctypes.c_double * 1)(0.1)
    a_out, a_in = pointer(ctypes.addressof(val_out), "double"), pointer(ctypes.addressof(val_in), "double")
    a_vr_out, a_vr_in = (pointer(ctypes.addressof(x), "unsigned int") for x in (vr_out, vr_in))
    walls, cpus = [], []
    for _ in range(repeats):
        loop.host.initialize()
        comp = pointer(s.component, "void")
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(n_steps):
            get_real(comp, a_vr_out, len(names), a_out)
            set_real(comp, a_vr_in, 1, a_in)
            if do_step(comp, k * dt, dt, 1) > 1:
                raise RuntimeError(f"fmi2DoStep failed at step {k}")
        walls.append((time.perf_counter() - t0) / n_steps)
        cpus.append((time.process_time() - c0) / n_steps)
        s.terminate()
    return statistics.median(walls), statistics.median(cpus)


_FIRST_CALL = """
import sys, time
import controllers.cosim as cosim
init = cosim.FmuLoop.__init__
def first(self, *a, **k):
    print("FIRST_FMU_CALL", flush=True, file=sys.stderr)
    cosim.FmuLoop.__init__ = init
    init(self, *a, **k)
cosim.FmuLoop.__init__ = first
from flexlink.cli import main
sys.exit(main(sys.argv[1:]))
"""


def startup(scene: str, n: int) -> dict:
    """Seconds from process start to the first FMU call of ``flexlink control`` (median of ``n`` fresh
    processes) with the design cache off (``FLEXLINK_DESIGN_CACHE=0``: imports, linearisation, design) and
    on (a repeated command), alternated in the same run; the heaviest imports of one cached and one uncached
    run (``-X importtime``, cumulative seconds)."""
    import os
    import subprocess
    import sys

    argv = [sys.executable, "-c", _FIRST_CALL, "control", scene, "--target", "90", "--duration", "1.5"]
    subprocess.run(argv, check=True, capture_output=True)     # the FMU and design caches filled, not timed
    envs = {"uncached": {**os.environ, "FLEXLINK_DESIGN_CACHE": "0"}, "cached": dict(os.environ)}
    envs["cached"].pop("FLEXLINK_DESIGN_CACHE", None)
    times = {k: [] for k in envs}
    for _ in range(n):
        for k, env in envs.items():
            t0 = time.perf_counter()
            proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
            for line in proc.stderr:
                if line.startswith("FIRST_FMU_CALL"):
                    times[k].append(time.perf_counter() - t0)
            proc.wait()
    heavy = ("control", "scipy.signal", "scipy.stats", "matplotlib.pyplot", "scipy.optimize", "casadi",
             "flexlink.mechanics.model", "flexlink.run.linearize", "controllers.manoeuvre", "fmpy", "numpy")
    out = {}
    for k, env in envs.items():
        err = subprocess.run([argv[0], "-X", "importtime", *argv[1:]], capture_output=True, text=True,
                             env=env).stderr
        cumulative = {}
        for line in err.splitlines():
            parts = line.split("|")
            if line.startswith("import time:") and parts[1].strip().isdigit():
                name = parts[2].strip()
                cumulative[name] = max(cumulative.get(name, 0.0), int(parts[1]) * 1e-6)
        ts = times[k]
        out[k] = {"median_s": statistics.median(ts), "min_s": min(ts), "max_s": max(ts), "runs": len(ts),
                  "imports_s": {m: cumulative[m] for m in heavy if m in cumulative}}
    out["ratio"] = statistics.median(u / c for u, c in zip(times["uncached"], times["cached"], strict=True))
    return out


def compare_loops(loop, law, ref, repeats: int) -> dict:
    """The fast loop against the reference loop, alternated, ``repeats`` times each: median realtime factors
    (wall and CPU), median speed-up, and the largest torque difference between the two."""
    fast, slow, ratios, diff = [], [], [], 0.0
    b = None
    for _ in range(repeats):
        a = loop.run(law, ref, fast=False)
        b = loop.run(law, ref, fast=True)
        fast.append(b)
        slow.append(a.realtime_factor)
        ratios.append(a.wall_time / b.wall_time)
        diff = max(diff, float(np.max(np.abs(a[law.input] - b[law.input]))))
        scale = float(np.max(np.abs(a[law.input])))
        if diff > 1e-9 * scale:
            raise RuntimeError(f"the fast loop differs from the reference loop by {diff:g} N m")
    span = float(ref.time[-1] - ref.time[0])
    return {"realtime_factor": statistics.median(r.realtime_factor for r in fast),
            "realtime_factor_min": min(r.realtime_factor for r in fast),
            "realtime_factor_cpu": statistics.median(span / r.cpu_time for r in fast),
            "realtime_factor_reference_loop": statistics.median(slow),
            "speed_up": statistics.median(ratios), "max_torque_difference_nm": diff,
            "torques": b[law.input][:-1]}


def measure(scenes: list[str], args) -> list[dict]:
    """One round: every scene's LQR and PD rows (the loops alternated, the FMU alone, the FMU from C)."""
    from controllers.cosim import FmuLoop
    from controllers.manoeuvre import default_torque_limit, design, reference
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant
    from flexlink.scene.loader import load_scene

    dt, target, duration, settle = args.sample_time, math.pi / 2, 1.5, 1.5
    rows = []
    for path in scenes:
        model = build_model(load_scene(path))
        fmu = cached_fmu(path)
        limit = default_torque_limit(linear_plant(model), target, duration)
        d = design(model, torque_limit=limit, dt=dt)
        with FmuLoop(fmu, record=[f"{d.joint}.theta", f"{d.link}.tip.v"]) as loop:
            for controller in ("lqr", "pd"):
                law = d.law(controller)
                ref = reference(d, controller, target, duration, settle)
                law.follow(ref)
                n_steps = len(ref.time) - 1
                row = compare_loops(loop, law, ref, args.repeats)
                names = list(dict.fromkeys([*law.sensors, *loop.record]))
                per_fmu = fmu_only(loop, names, law.input, n_steps, dt, args.repeats)
                in_c = fmu_in_c(fmu, names, law.input, row.pop("torques"), dt, args.repeats)
                rows.append({"scene": Path(path).stem, "controller": controller, "sample_time_s": dt,
                             "simulated_s": duration + settle, **row,
                             "us_per_sample": 1e6 * (duration + settle) / n_steps / row["realtime_factor"],
                             "us_per_sample_cpu": 1e6 * (duration + settle) / n_steps / row["realtime_factor_cpu"],
                             "us_per_sample_fmu": 1e6 * per_fmu[0], "us_per_sample_fmu_cpu": 1e6 * per_fmu[1],
                             "us_per_sample_fmu_c": in_c["us_per_sample"],
                             "us_per_sample_fmu_c_cpu": in_c["us_per_sample_cpu"]})
    return rows


def combine(rounds: list[list[dict]]) -> list[dict]:
    """Each row's figures as the median over the rounds, with the realtime factors of every round.

    The rounds run one after the other over minutes: on a shared machine whose speed drifts between phases
    that long, the median of several rounds says what one round's median cannot.
    """
    rows = []
    for same in zip(*rounds, strict=True):
        row = {k: (statistics.median(r[k] for r in same) if isinstance(v, float) else v)
               for k, v in same[0].items()}
        row["max_torque_difference_nm"] = max(r["max_torque_difference_nm"] for r in same)
        row["realtime_factor_min"] = min(r["realtime_factor_min"] for r in same)
        row["realtime_factor_rounds"] = [r["realtime_factor"] for r in same]
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--sample-time", type=float, default=1e-3)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=1,
                    help="measure the whole table N times in a row and report each figure's median over them")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--startup", type=int, metavar="N", help="measure the start-up of flexlink control instead")
    ap.add_argument("--write", nargs="?", const=str(PAGE), metavar="PAGE",
                    help="write the table into PAGE (default docs/performance.md) between its closed-loop markers")
    args = ap.parse_args()
    if args.startup:
        scene = args.scenes[0] if args.scenes else str(ROOT / "examples" / DEFAULT[0])
        res = startup(scene, args.startup)
        if args.json:
            print(json.dumps(res))
            return
        print(f"flexlink control {Path(scene).name} --target 90: process start to first FMU call, median of "
              f"{res['cached']['runs']} (alternated in this run)")
        for k in ("uncached", "cached"):
            r = res[k]
            print(f"  {k:9s} {r['median_s']:.2f} s ({r['min_s']:.2f}-{r['max_s']:.2f} s); heaviest imports "
                  "(cumulative, one run, -X importtime): "
                  + ", ".join(f"{m} {v:.2f} s" for m, v in r["imports_s"].items()))
        print(f"  uncached / cached (median of the per-run ratios): {res['ratio']:.2f}")
        return

    scenes = args.scenes or [str(ROOT / "examples" / s) for s in DEFAULT]
    load0 = os.getloadavg()[0]
    rounds = [measure(scenes, args) for _ in range(args.rounds)]
    rows = combine(rounds)
    info = {"date": time.strftime("%Y-%m-%d"), "machine": platform.machine(), "repeats": args.repeats,
            "rounds": args.rounds, "sample_time_s": args.sample_time, "simulated_s": rows[0]["simulated_s"],
            "load_start": load0,
            "load_end": os.getloadavg()[0]}
    if args.json:
        print(json.dumps({"info": info, "rows": rows}))
        return
    block = markdown(rows, info)
    print(block)
    if args.write:
        from report import rewrite_readme  # the block rewriter of benchmarks/report.py

        rewrite_readme(Path(args.write), block, BEGIN, END)


def markdown(rows: list[dict], info: dict) -> str:
    """The closed-loop table between the page's markers, with how and when it was measured."""
    n = info.get("rounds", 1)
    rounds_flag = f" --rounds {n}" if n > 1 else ""
    rounds_text = (f"; the whole table measured {n} times in a row, each figure the median of the {n} "
                   "(the realtime factor's range over them in brackets: the machine's speed drifts over minutes)"
                   if n > 1 else "")
    lines = [BEGIN, "<!-- generated by `python benchmarks/closed_loop.py --write`: edit it, not this block -->", "",
             f"Measured {info['date']} on {info['machine']} (`python benchmarks/closed_loop.py --repeats "
             f"{info['repeats']}{rounds_flag}`): a 90° rest-to-rest manoeuvre in 1.5 s + 1.5 s settle, sample time "
             f"{info['sample_time_s'] * 1e3:g} ms, through fmpy on one instance (`fmi2Reset` between runs); medians "
             f"of {info['repeats']} runs, the fast loop and the reference loop (`law.step` per sample) alternated in "
             f"the same run{rounds_text}; load average {info['load_start']:.1f} at the start, "
             f"{info['load_end']:.1f} at the end (2 cores: on CPU time, the waits for a core are left out).", "",
             "Times per 1 ms sample in µs, wall (CPU): the whole loop; the FMU's three calls through cffi with a "
             "constant torque and no law; the same three calls from C on the loop's recorded torques.", "",
             "| scene | law | × real time (target ≥ 150) | × on CPU time | reference loop × | speed-up | "
             "loop µs | FMU via cffi µs | FMU from C µs |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        spread = r.get("realtime_factor_rounds", [])
        factor = f"{r['realtime_factor']:.0f}" + (f" ({min(spread):.0f}–{max(spread):.0f})" if len(spread) > 1 else "")
        lines.append(f"| {r['scene']} | {r['controller'].upper()} | {factor} | "
                     f"{r['realtime_factor_cpu']:.0f} | {r['realtime_factor_reference_loop']:.0f} | "
                     f"{r['speed_up']:.2f} | {r['us_per_sample']:.1f} ({r['us_per_sample_cpu']:.1f}) | "
                     f"{r['us_per_sample_fmu']:.1f} ({r['us_per_sample_fmu_cpu']:.1f}) | "
                     f"{r['us_per_sample_fmu_c']:.2f} ({r['us_per_sample_fmu_c_cpu']:.2f}) |")
    lines.append(END)
    return "\n".join(lines)


if __name__ == "__main__":
    main()
