"""Reduced against full finite-element shell link (issue 9): frequencies, response and cost.

    python benchmarks/shell_reduction.py [SCENE.toml] [--modes 1 3 6] [--step 2e-5] [--stop-time 0.3]

Every model is the scene's shell link with ``shapes.modes`` changed; "full" keeps every mode, which is the
FE model itself (the massless rotations condensed exactly).  Each is built into an FMU and run through the
same manoeuvre at the same (small) SS22 step; the response error is the relative RMS deviation of the tip
deflection and the joint torque from the full model's, the cost the CPU time of the run (median of 3).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.analysis import natural_frequencies
    from flexlink.mechanics.model import build_model
    from flexlink.run.simulate import SlaveRunner
    from flexlink.scene.loader import load_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "examples" / "plate_raise.toml"))
    ap.add_argument("--modes", type=int, nargs="+", default=[1, 3, 6])
    ap.add_argument("--step", type=float, default=2e-5)
    ap.add_argument("--stop-time", type=float, default=0.3)
    args = ap.parse_args()
    scene = load_scene(args.scene)
    link = scene.links[0]
    joint = scene.joints[0].name
    outputs = [f"{link.name}.tip.v", f"{joint}.tau" if scene.joints[0].drive == "position" else f"{joint}.theta"]
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for modes in [None, *args.modes]:
            variant = dataclasses.replace(scene, links=(dataclasses.replace(
                link, shapes=dataclasses.replace(link.shapes, modes=modes)),))
            model = build_model(variant)
            freqs = natural_frequencies(model).frequencies_hz
            t0 = time.perf_counter()
            fmu = build_fmu(variant, Path(tmp) / f"m{modes}.fmu", model=model).fmu
            build = time.perf_counter() - t0
            cpu = []
            with SlaveRunner(fmu) as runner:
                for _ in range(3):
                    t0 = time.process_time()
                    res = runner.run(args.stop_time, 1e-3, start={"solver.step": args.step}, outputs=outputs)
                    cpu.append(time.process_time() - t0)
            rows[modes] = dict(n=model.n_q, freqs=freqs, build=build, cpu=statistics.median(cpu), res=res)
    full = rows[None]
    print(f"{args.scene}: {args.stop_time} s at SS22 step {args.step:g} s; errors against the full FE model "
          f"({full['n']} coordinates)")
    print("| model | coordinates | first frequencies (Hz) | max rel. frequency difference | error "
          + " / ".join(outputs) + " | build s | CPU s | cost / full |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for modes, r in rows.items():
        k = len(r["freqs"]) if modes is not None else 3
        diff = np.max(np.abs(np.array(r["freqs"][:k]) / np.array(full["freqs"][:k]) - 1))
        errs = [np.sqrt(np.mean((r["res"][n] - full["res"][n]) ** 2)) / np.sqrt(np.mean(full["res"][n] ** 2))
                for n in outputs]
        print(f"| {'full' if modes is None else f'{modes} modes'} | {r['n']} | "
              + ", ".join(f"{f:.2f}" for f in r["freqs"][:3]) + f" | {diff:.1e} | "
              + " / ".join(f"{e:.1e}" for e in errs) + f" | {r['build']:.1f} | {r['cpu']:.3f} | "
              f"{r['cpu'] / full['cpu']:.3f} |")


if __name__ == "__main__":
    main()
