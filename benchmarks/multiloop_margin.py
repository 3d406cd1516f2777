"""The simultaneous (multi-loop) disk margin against the loop-at-a-time ones, and its time (issue 16).

    python benchmarks/multiloop_margin.py [--repeats N] [--json]

On the two-link arm (examples/two_link_payload.toml, 60 N m) and the six-axis arm
(examples/six_axis_arm_torque.toml, 20,100,50,4,8,1 N m), 1 ms, the design made once (not timed); for each of
the four loops of ``flexlink control --design-only`` (continuous LQR, sampled LQG, the predictive LQG with one
sample of delay, the LQG unaware of it): the simultaneous balanced disk margin at the plant input
(``controllers.diskmargin``: its guaranteed value from μ's upper bound, the size of the destabilising
perturbation from μ's lower bound, whether they agree), the smallest loop-at-a-time disk margin, and the
median over ``--repeats`` of the time of ``multiloop_disk_margin`` alone (T's response on the 4000-point
grid given) and of the whole ``loop_at_a_time`` (whose classical margins it joins), with the median of the
per-repeat ratios (``share``: the part of ``loop_at_a_time``'s time the simultaneous margin takes).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import control as ct
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENES = {"two_link_payload": [60.0, 60.0], "six_axis_arm_torque": [20.0, 100.0, 50.0, 4.0, 8.0, 1.0]}


def measure(name: str, limits: list[float], repeats: int) -> dict:
    """The figures of one arm's four loops (module docstring)."""
    from margins import loops

    from controllers.design import actuated_joints
    from controllers.diskmargin import multiloop_disk_margin
    from controllers.manoeuvre import design
    from controllers.robustness import _grid, loop_at_a_time, response
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant
    from flexlink.scene.loader import load_scene

    model = build_model(load_scene(ROOT / "examples" / f"{name}.toml"))
    plant = linear_plant(model, outputs=[f"{model.scene.joints[0].name}.theta"])
    d = design(model, torque_limit=dict(zip(actuated_joints(plant), limits, strict=True)), dt=1e-3)
    out = {}
    for loop, (P, K) in loops(d).items():
        Kc = K if isinstance(K, ct.StateSpace) else ct.ss([], [], [], np.atleast_2d(K), P.dt)
        T = ct.series(P, Kc)
        w = _grid(T, 4000)
        Tw = response(T, w)
        T_inf = np.asarray(T.D, dtype=float) if T.isctime() else None
        t_multi, t_all = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            multiloop_disk_margin(Tw, w, lambda x, T=T: response(T, x), T_inf)
            t1 = time.perf_counter()
            r = loop_at_a_time(P, K)
            t_all.append(time.perf_counter() - t1)
            t_multi.append(t1 - t0)
        # the figures as loop_at_a_time reports them (0 for an unstable loop)
        out[loop] = {"multiloop": r["multiloop"], "stable": r["stable"],
                     "loop_at_a_time_min": min(a["disk_margin"] for a in r["actuators"]),
                     "loop_at_a_time": [a["disk_margin"] for a in r["actuators"]],
                     "multiloop_s": statistics.median(t_multi), "loop_at_a_time_s": statistics.median(t_all),
                     "share": statistics.median(a / b for a, b in zip(t_multi, t_all, strict=True))}
    return out


def main() -> None:
    """Measure both arms and print (or ``--json``) the table."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    doc = {name: measure(name, limits, args.repeats) for name, limits in SCENES.items()}
    if args.json:
        print(json.dumps(doc))
        return
    print(f"{'arm / loop':<40}{'simultaneous':>14}{'(upper)':>10}{'exact':>7}{'loop-at-a-time':>36}"
          f"{'multi s':>9}{'whole s':>9}{'share':>7}")
    for name, loops_ in doc.items():
        for loop, f in loops_.items():
            ml = f["multiloop"]
            lat = ", ".join(f"{v:.3f}" for v in f["loop_at_a_time"])
            label = f"{name} / {loop}" + ("" if f["stable"] else " (unstable)")
            print(f"{label:<40}{ml['disk_margin']:>14.4f}{ml['disk_margin_upper']:>10.4f}"
                  f"{'yes' if ml['exact'] else 'no':>7}{lat:>44}{f['multiloop_s']:>9.3f}{f['loop_at_a_time_s']:>9.3f}"
                  f"{f['share']:>7.2f}")
    print(f"(median of {args.repeats} repeats; times wall-clock in seconds)")


if __name__ == "__main__":
    main()
