"""The optimisation level of the small complex-step twins: build time against a directional derivative's cost.

    python benchmarks/twin_level.py [--levels O2,O1] [--builds 3] [--repeats 5] [scene.toml ...]

A generated unit's complex twin (the directional derivatives by the complex step, docs/fmi.md) below
``COMPLEX_STEP_OPTIMISE_MAX_OPERATIONS`` compiles at ``COMPLEX_STEP_SMALL_LEVEL``
(``flexlink/export/codegen.py``).  For each scene and level: the whole build (median of ``--builds``, the
levels alternated) and one fmi2GetDirectionalDerivative of every state derivative and output in one state's
direction (medians of ``--repeats`` runs of 2000 calls, the levels alternated; ``benchmarks/directional_cost.py``'s
timing).  Prints one line per scene.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

DEFAULT = ["examples/rotating_link.toml", "examples/two_link_payload.toml"]


def main(argv: list[str] | None = None) -> int:
    import directional_cost

    from flexlink.export import codegen

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=DEFAULT)
    ap.add_argument("--levels", default="O2,O1")
    ap.add_argument("--builds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    levels = args.levels.split(",")
    kept = codegen.COMPLEX_STEP_SMALL_LEVEL
    print(f"load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scenes:
            builds: dict[str, list[float]] = {lvl: [] for lvl in levels}
            fmus = {}
            try:
                for k in range(args.builds):
                    for lvl in levels:
                        codegen.COMPLEX_STEP_SMALL_LEVEL = lvl
                        t0 = time.perf_counter()
                        fmus[lvl] = directional_cost._build(Path(scene), Path(tmp) / f"{lvl}_{k}.fmu", True).fmu
                        builds[lvl].append(time.perf_counter() - t0)
            finally:
                codegen.COMPLEX_STEP_SMALL_LEVEL = kept
            instances = {lvl: directional_cost._Instance(f) for lvl, f in fmus.items()}
            calls: dict[str, list[float]] = {lvl: [] for lvl in levels}
            for _ in range(args.repeats):
                for lvl, inst in instances.items():
                    calls[lvl].append(1e6 * inst.directional(2000))
            for inst in instances.values():
                inst.close()
            print(f"{Path(scene).stem}: " + "; ".join(
                f"-{lvl} build {statistics.median(builds[lvl]):.2f} s, directional derivative "
                f"{statistics.median(calls[lvl]):.2f} us" for lvl in levels))
    print(f"load average {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
