"""Realtime factor of the closed loop through fmpy (issue: controllers), at 1 ms sample time by default.

    python benchmarks/closed_loop.py [SCENE.toml ...] [--sample-time S] [--repeats N] [--json]

For each scene: the FMU is built (cached, not timed), the controllers designed (not timed), then a 90°
rest-to-rest manoeuvre in 1.5 s plus 1.5 s settle is run ``--repeats`` times on one instance (``fmi2Reset``
between runs) with the LQR + Kalman law and with the PD.  The realtime factor is simulated seconds per
wall-clock second of the loop (reset, initialisation and every sample's getReal / law / setReal / doStep);
each figure is the median over the repeats.  The per-sample split separates the FMU calls from the law:
the FMU alone is the same loop with a constant torque and no law.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["rotating_link.toml", "rotating_link_payload.toml"]


def fmu_only(loop, names: list[str], n_steps: int, dt: float, repeats: int) -> float:
    """Median wall time per sample of getReal + setReal + doStep alone (constant torque, no law)."""
    s = loop.slave
    vr_out = (ctypes.c_uint * len(names))(*[loop.vr(n) for n in names])
    val_out = (ctypes.c_double * len(names))()
    vr_in = (ctypes.c_uint * 1)(loop.vr("hub.tau"))
    val_in = (ctypes.c_double * 1)(0.1)
    walls = []
    for _ in range(repeats):
        s.reset()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.exitInitializationMode()
        t0 = time.perf_counter()
        for k in range(n_steps):
            s.fmi2GetReal(s.component, vr_out, len(names), val_out)
            s.fmi2SetReal(s.component, vr_in, 1, val_in)
            s.fmi2DoStep(s.component, k * dt, dt, 1)
        walls.append((time.perf_counter() - t0) / n_steps)
        s.terminate()
    loop._fresh = False
    return statistics.median(walls)


def law_only(law, reference, p: int, repeats: int) -> float:
    """Median wall time per sample of the law alone (fixed measurements)."""
    y = np.zeros(p) + law.y0
    walls = []
    for _ in range(repeats):
        law.reset()
        t0 = time.perf_counter()
        for k in range(len(reference.time)):
            law.step(y, reference.x[k], reference.u_ff[k])
        walls.append((time.perf_counter() - t0) / len(reference.time))
    return statistics.median(walls)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--sample-time", type=float, default=1e-3)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    from controllers.cosim import FmuLoop
    from controllers.manoeuvre import default_torque_limit, design, reference, rest_to_rest
    from flexlink.export.fmu import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant
    from flexlink.scene.loader import load_scene

    scenes = args.scenes or [str(ROOT / "examples" / s) for s in DEFAULT]
    dt, target, duration, settle = args.sample_time, math.pi / 2, 1.5, 1.5
    rows = []
    for path in scenes:
        model = build_model(load_scene(path))
        fmu = cached_fmu(path)
        limit = default_torque_limit(linear_plant(model), target, duration)
        d = design(model, torque_limit=limit, dt=dt)
        with FmuLoop(fmu) as loop:
            for controller in ("lqr", "pd"):
                rtf = [rest_to_rest(d, loop, target, duration, settle, controller).metrics["realtime_factor"]
                       for _ in range(args.repeats)]
                law = d.law(controller)
                ref = reference(d, controller, target, duration, settle)
                law.follow(ref)
                n_steps = len(ref.time) - 1
                per_law = law_only(law, ref, len(law.sensors), args.repeats)
                per_fmu = fmu_only(loop, list(dict.fromkeys([*law.sensors, *loop.record])), n_steps, dt,
                                   args.repeats)
                rows.append({"scene": Path(path).stem, "controller": controller, "sample_time_s": dt,
                             "simulated_s": duration + settle, "realtime_factor": statistics.median(rtf),
                             "realtime_factor_min": min(rtf), "us_per_sample_fmu": 1e6 * per_fmu,
                             "us_per_sample_law": 1e6 * per_law})
    if args.json:
        print(json.dumps(rows))
        return
    print(f"closed loop through fmpy, sample time {dt * 1e3:g} ms, {duration + settle:g} s simulated, "
          f"median of {args.repeats}")
    print(f"{'scene':28s} {'ctrl':>5s} {'realtime x':>11s} {'(min)':>7s} {'us/sample FMU':>14s} "
          f"{'us/sample law':>14s}")
    for r in rows:
        print(f"{r['scene']:28s} {r['controller']:>5s} {r['realtime_factor']:11.1f} {r['realtime_factor_min']:7.1f} "
              f"{r['us_per_sample_fmu']:14.1f} {r['us_per_sample_law']:14.1f}")


if __name__ == "__main__":
    main()
