"""Time of the robustness figures of ``flexlink control --design-only`` on the six-axis arm (issue 16).

    python benchmarks/margins.py [--repeats N] [--json]

The design of examples/six_axis_arm_torque.toml (torque limits 20,100,50,4,8,1 N m, 1 ms) is made once (not
timed); then, ``--repeats`` times each and alternated, the four loops' loop-at-a-time margins (continuous
LQR, sampled LQG, the predictive LQG with one sample of delay and the LQG unaware of it):

* ``before``: each broken loop as its own state space (``control.feedback``), its response through
  ``control.frd`` (python-control's evaluation, one LU solve per frequency) and ``control.stability_margins``
  on it, python-control's FRD evaluated one frequency per ``splev`` call: the code before this benchmark;
* ``after``: ``controllers.robustness`` as it is: T's response once per loop in batched numpy, the broken
  loops by algebra at each frequency, the crossovers bracketed on the grid as python-control does and refined
  on the loop's exact response (:func:`controllers.crossovers.loop_margins`), and the disk margins too.

It prints the median CPU and wall time of each, the median of the per-repeat ratios, and the largest
relative difference between the two's classical margins (python-control's phase margin by its magnitude):
what python-control's refinement on the table's spline leaves, which the exact refinement removes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
import warnings
from pathlib import Path

import control as ct
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
LIMITS = [20.0, 100.0, 50.0, 4.0, 8.0, 1.0]


def loops(d):
    """The four loops (P, K_c) of ``flexlink control --design-only`` (controllers.cli._robustness_json)."""
    from controllers import robustness as r
    from controllers.design import torque_inputs

    B = np.asarray(d.lqr.plant.sys.B)[:, torque_inputs(d.lqr.plant)]
    sys = ct.ss(np.asarray(d.lqr.plant.sys.A), B, np.eye(d.lqr.plant.sys.nstates), 0)
    Pd1 = r.delayed_plant(d.lqr, d.kalman)
    return {"lqr": (sys, -np.asarray(d.lqr.K)),
            "lqg": (r.lqg_plant(d.lqr, d.kalman), r.lqg_compensator(d.lqr, d.kalman)),
            "lqg_delay1": (Pd1, r.predictive_compensator(d.lqr, d.kalman)),
            "lqg_delay1_unaware": (Pd1, r.lqg_compensator(d.lqr, d.kalman))}


def before(P, Kc, n_points: int = 4000) -> list[dict]:
    """The margins at each actuator as computed before (python-control on each broken loop's state space)."""
    from controllers.closedloop import margin_entries
    from controllers.robustness import _grid

    if not isinstance(Kc, ct.StateSpace):
        Kc = ct.ss([], [], [], np.atleast_2d(Kc), P.dt)
    T = ct.series(P, Kc)
    m = T.ninputs
    w = _grid(T, n_points)
    out = []
    for i in range(m):
        E = np.diag([0.0 if j == i else 1.0 for j in range(m)])
        L = -ct.feedback(T, E, sign=1)[i, i]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gm, pm, sm, wpc, wgc, _ = ct.stability_margins(ct.frd(L, w, smooth=True), returnall=True)
        out.append(margin_entries(gm, pm, np.asarray(wpc, dtype=float), np.asarray(wgc, dtype=float)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    from controllers.design import actuated_joints
    from controllers.manoeuvre import design
    from controllers.robustness import loop_at_a_time
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant
    from flexlink.scene.loader import load_scene

    model = build_model(load_scene(ROOT / "examples" / "six_axis_arm_torque.toml"))
    plant = linear_plant(model, outputs=[f"{model.scene.joints[0].name}.theta"])
    d = design(model, torque_limit=dict(zip(actuated_joints(plant), LIMITS, strict=True)), dt=1e-3)
    cases = loops(d)
    times = {"before": [], "after": []}
    worst = 0.0
    for _ in range(args.repeats):
        for name, fn in (("before", before), ("after", loop_at_a_time)):
            c0, w0 = time.process_time(), time.perf_counter()
            res = {k: fn(P, K) for k, (P, K) in cases.items()}
            times[name].append((time.process_time() - c0, time.perf_counter() - w0))
            if name == "before":
                old = res
        for k in cases:
            for a, b in zip(old[k], res[k]["actuators"], strict=True):
                for key, v in a.items():
                    u = abs(v) if key == "phase_margin_deg" else v       # python-control's signed figure
                    if np.isfinite(u) or np.isfinite(b[key]):
                        worst = max(worst, abs(u - b[key]) / abs(u))
    med = {n: {"cpu_s": statistics.median(t[0] for t in ts), "wall_s": statistics.median(t[1] for t in ts)}
           for n, ts in times.items()}
    ratio = statistics.median(b[0] / a[0] for b, a in zip(times["before"], times["after"], strict=True))
    doc = {"repeats": args.repeats, "median": med, "cpu_speedup_median": ratio, "max_rel_difference": worst}
    if args.json:
        print(json.dumps(doc))
        return
    for n, v in med.items():
        print(f"{n:>6}: {v['cpu_s']:6.2f} s CPU, {v['wall_s']:6.2f} s wall (median of {args.repeats})")
    print(f"speed-up (CPU, median of the per-repeat ratios): {ratio:.1f}x; classical margins' largest relative "
          f"difference {worst:.2e}")


if __name__ == "__main__":
    main()
