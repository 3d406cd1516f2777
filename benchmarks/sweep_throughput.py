"""Throughput of ``flexlink sweep`` on a local Dask cluster against the same closed-loop runs in a plain loop.

    python benchmarks/sweep_throughput.py                      # 300 LQR rest-to-rest runs (90 deg in 1.5 s)
    python benchmarks/sweep_throughput.py --cases 40 --duration 0.4 --settle 0.2 --target 5    # CI-sized

The cases are a grid of ``arm.payload.mass`` x ``arm.EI`` on ``examples/rotating_link_payload.toml``.  The
plain loop is what a user would write: one ``FmuLoop``, ``controllers.manoeuvre.rest_to_rest`` per case.
The sweep is ``controllers.sweep.run_sweep`` on a ``LocalCluster`` of ``--workers`` processes; it is timed
warm (cluster started, workers' imports and FMU instance done by a first small sweep) and the cluster's
start-up is reported apart.  Both give the same numbers (checked: the largest difference is printed).
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "rotating_link_payload.toml"
EXACT = ("final_error_deg", "residual_vibration_rms_m", "peak_torque_nm", "max_tip_deflection_m")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=300, help="about this many cases (a 2-D grid), default 300")
    ap.add_argument("--target", type=float, default=90.0, help="deg (default 90)")
    ap.add_argument("--duration", type=float, default=1.5, help="s (default 1.5)")
    ap.add_argument("--settle", type=float, default=1.5, help="s (default 1.5)")
    ap.add_argument("--controller", default="lqr", choices=("lqr", "pd"))
    ap.add_argument("--workers", type=int, default=2, help="local Dask worker processes (default 2)")
    args = ap.parse_args()

    from dask.distributed import Client, LocalCluster

    from controllers.cosim import FmuLoop
    from controllers.manoeuvre import rest_to_rest
    from controllers.sweep import SweepSpec, make_cases, run_sweep
    from flexlink.export.cache import cached_fmu

    n_ei = max(1, int(round(math.sqrt(args.cases / 1.5))))
    n_m = max(1, int(round(args.cases / n_ei)))
    grid = {"arm.payload.mass": f"0.3:1.0:{n_m}", "arm.EI": f"85:100:{n_ei}"}
    _, cases = make_cases(grid)
    manoeuvre = {"controller": args.controller, "target_deg": args.target, "duration": args.duration,
                 "settle": args.settle}
    fmu = cached_fmu(SCENE)
    simulated = args.duration + args.settle
    print(f"{len(cases)} closed-loop cases ({args.controller.upper()}, {args.target:g} deg in {args.duration:g} s "
          f"+ {args.settle:g} s settle, 1 ms samples: {simulated:g} simulated s each) of {SCENE.name}")

    # the design run_sweep uses (its in-process cache), so that both sides run the very same controller
    probe = run_sweep(SweepSpec(SCENE, {"arm.payload.mass": 0.5}, scheduler="serial", fmu=fmu, **manoeuvre))
    from controllers.sweep import _DESIGNS

    design = next(iter(_DESIGNS.values()))[0]
    assert design.torque_limit == probe.attrs["settings"]["torque_limit"]

    t0 = time.perf_counter()
    plain = []
    loop = FmuLoop(fmu)
    for c in cases:
        try:
            res = rest_to_rest(design, loop, math.radians(args.target), args.duration, args.settle, args.controller,
                               parameters=c)
            plain.append(res.metrics)
        except Exception as e:  # noqa: BLE001
            plain.append({"error": str(e)})
            loop.close()
            loop = FmuLoop(fmu)
    loop.close()
    t_plain = time.perf_counter() - t0

    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=logging.ERROR)
    client = Client(cluster)
    client.wait_for_workers(args.workers)
    t_start = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        warm_up = SweepSpec(SCENE, {"arm.payload.mass": f"0.3:1.0:{2 * args.workers}"}, fmu=fmu, batch_size=1,
                            **manoeuvre)
        run_sweep(warm_up, client=client)                                  # imports, FMU instances
        t_warm = time.perf_counter() - t0
        t0 = time.perf_counter()
        df = run_sweep(SweepSpec(SCENE, grid, fmu=fmu, **manoeuvre), client=client)
        t_dask = time.perf_counter() - t0
    finally:
        client.close()
        cluster.close()

    n = len(cases)
    diff = 0.0
    for m in EXACT:
        a = np.array([r.get(m, np.nan) for r in plain])
        b = df[m].to_numpy()
        assert np.array_equal(np.isnan(a), np.isnan(b)), m
        ok = ~np.isnan(a)
        diff = max(diff, float(np.max(np.abs(a[ok] - b[ok]), initial=0.0)))
    failed = int(df["failed"].sum())
    print(f"  plain loop (1 process)        {t_plain:7.2f} s   {n / t_plain:7.1f} runs/s")
    print(f"  Dask, {args.workers} workers (warm)        {t_dask:7.2f} s   {n / t_dask:7.1f} runs/s   "
          f"x{t_plain / t_dask:.2f} vs the plain loop")
    print(f"  Dask incl. cluster start ({t_start:.1f} s) and warm-up ({t_warm:.1f} s): "
          f"{n / (t_dask + t_start + t_warm):.1f} runs/s")
    print(f"  failed cases {failed}; largest difference to the plain loop over {', '.join(EXACT)}: {diff:.3g}")


if __name__ == "__main__":
    main()
