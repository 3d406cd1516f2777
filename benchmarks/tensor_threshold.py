"""Where the foreshortening's tensors stop paying: the whole model's cost with tensors and with point sums.

    python benchmarks/tensor_threshold.py [--modes 4 6 7 8 10] [--builds 1] [--repeats 3]
    python benchmarks/tensor_threshold.py --kane 32 [--rounds 2]   # Kane's form against the AD form

A second-order link of 16 Hermite elements reduced to n modes (``benchmarks/scaling.py``'s modes family) is
built twice per n, once with its foreshortening sums from :class:`ForeshorteningTensors` (n⁴ terms) and once
from the 96 points (the equations in Kane's form), by setting ``kinematics.TENSOR_MAX_SHAPES`` above or below n;
the two builds of each n follow each other in the same session.  For each: build time (median of
``--builds``), bytes of generated C, the operations of every generated function (what ``flexlink explain``
lists) and µs per SS22 step (``benchmarks/step_floor.py``'s driver, median of ``--repeats``).  The rule in
``flexlink/mechanics/kinematics.py`` (TENSOR_MAX_SHAPES) is chosen on these figures (docs/performance.md).

With ``--kane N`` the N-mode link is built instead with its foreshortening's equations in Kane's form and with
CasADi's Lagrange derivative through the point sums (``assembly.KANE_FORESHORTENING``), the two builds
alternated ``--rounds`` times in the same session: the same figures, for a same-run ratio.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def _measured(modes: int, builds: int, repeats: int) -> tuple[dict, dict[str, int]]:
    """The n-mode link as the module's switches now build it: scaling.py's figures and each function's operations."""
    from scaling import measure, modes_scene

    from flexlink.export.codegen import generated_functions
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import parse_scene

    scene = parse_scene(modes_scene(modes))
    ops = {name: v[1] for name, v in generated_functions(build_model(scene)).items()}
    return measure(scene, builds=builds, repeats=repeats), ops


def main(argv: list[str] | None = None) -> None:
    from flexlink.mechanics import kinematics

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", type=int, nargs="+", default=[4, 6, 7, 8, 10])
    ap.add_argument("--builds", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--kane", type=int, default=None, metavar="N", help="Kane against Lagrange on N modes")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    if args.kane is not None:
        kane_against_lagrange(args.kane, args.rounds, args.builds, args.repeats)
        return
    kept = kinematics.TENSOR_MAX_SHAPES
    print(f"load average {os.getloadavg()[0]:.1f} at the start")
    print("| modes | form | build [s] | C [MB] | µs per step | residual µs | operations: residual / mass matrix / "
          "outputs |\n| --- | --- | --- | --- | --- | --- | --- |")
    try:
        for n in args.modes:
            for form, threshold in (("tensors", n), ("points", n - 1)):
                kinematics.TENSOR_MAX_SHAPES = threshold
                r, ops = _measured(n, args.builds, args.repeats)
                print(f"| {n} | {form} | {r['build_s']:.1f} | {r['generated_bytes'] / 1e6:.2f} | {r['step_us']:.1f} | "
                      f"{r['residual_us']:.2f} | {ops['residual']} / {ops.get('mass_matrix', '-')} "
                      f"/ {ops['outputs']} |",
                      flush=True)
    finally:
        kinematics.TENSOR_MAX_SHAPES = kept
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


def kane_against_lagrange(modes: int, rounds: int, builds: int, repeats: int) -> None:
    """The n-mode link with the foreshortening's equations in Kane's form and by AD, alternated."""
    from flexlink.mechanics import assembly

    kept = assembly.KANE_FORESHORTENING
    print(f"load average {os.getloadavg()[0]:.1f} at the start")
    print("| round | form | build [s] | C [MB] | µs per step | residual µs | operations: residual / outputs |\n"
          "| --- | --- | --- | --- | --- | --- | --- |")
    try:
        for k in range(rounds):
            for form, kane in (("Kane", True), ("Lagrange (AD)", False)):
                assembly.KANE_FORESHORTENING = kane
                r, ops = _measured(modes, builds, repeats)
                print(f"| {k + 1} | {form} | {r['build_s']:.1f} | {r['generated_bytes'] / 1e6:.2f} | "
                      f"{r['step_us']:.1f} | {r['residual_us']:.2f} | {ops['residual']} / {ops['outputs']} |",
                      flush=True)
    finally:
        assembly.KANE_FORESHORTENING = kept
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
