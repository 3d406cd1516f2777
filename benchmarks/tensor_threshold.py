"""Where the foreshortening's tensors stop paying: the whole model's cost with tensors and with point sums.

    python benchmarks/tensor_threshold.py [--modes 4 6 7 8 10] [--builds 1] [--repeats 3]

A second-order link of 16 Hermite elements reduced to n modes (``benchmarks/scaling.py``'s modes family) is
built twice per n, once with its foreshortening sums from :class:`ForeshorteningTensors` (n⁴ terms) and once
from the 96 points (the equations in Kane's form), by setting ``kinematics.TENSOR_MAX_SHAPES`` above or below n;
the two builds of each n follow each other in the same session.  For each: build time (median of
``--builds``), bytes of generated C, the operations of every generated function (what ``flexlink explain``
lists) and µs per SS22 step (``benchmarks/step_floor.py``'s driver, median of ``--repeats``).  The rule in
``flexlink/mechanics/kinematics.py`` (TENSOR_MAX_SHAPES) is chosen on these figures (docs/performance.md).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def main(argv: list[str] | None = None) -> None:
    from scaling import measure, modes_scene

    from flexlink.export.codegen import generated_functions
    from flexlink.mechanics import kinematics
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import parse_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", type=int, nargs="+", default=[4, 6, 7, 8, 10])
    ap.add_argument("--builds", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    kept = kinematics.TENSOR_MAX_SHAPES
    print(f"load average {os.getloadavg()[0]:.1f} at the start")
    print("| modes | form | build [s] | C [MB] | µs per step | residual µs | operations: residual / mass matrix / "
          "outputs |\n| --- | --- | --- | --- | --- | --- | --- |")
    try:
        for n in args.modes:
            for form, threshold in (("tensors", n), ("points", n - 1)):
                kinematics.TENSOR_MAX_SHAPES = threshold
                scene = parse_scene(modes_scene(n))
                ops = {k: v[1] for k, v in generated_functions(build_model(scene)).items()}
                r = measure(scene, builds=args.builds, repeats=args.repeats)
                print(f"| {n} | {form} | {r['build_s']:.1f} | {r['generated_bytes'] / 1e6:.2f} | {r['step_us']:.1f} | "
                      f"{r['residual_us']:.2f} | {ops['residual']} / {ops['mass_matrix']} / {ops['outputs']} |",
                      flush=True)
    finally:
        kinematics.TENSOR_MAX_SHAPES = kept
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
