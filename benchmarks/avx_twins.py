"""The AVX twins of the Newton iteration's units (fmu_src/avx.h) against the baseline units, in the same run.

    python benchmarks/avx_twins.py [SCENE.toml ...] [--rounds 3] [--repeats 3] [--stop 3]

Each scene's FMU is built once; ``benchmarks/step_floor.c`` is compiled twice with its sources, as shipped
and with ``-DFLEXLINK_NO_AVX`` (the twins empty, model.c calling the baseline units), and the two drivers run
issue 6's manoeuvre alternately, ``--rounds`` times each (medians of ``--repeats`` runs inside each).  The
report: the residual's time and the SS22 step's, the medians of the rounds, and their ratio; the counts of
Newton iterations must be the same in both (the same bits), which is checked.  Needs a processor with AVX.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from step_floor import compile_driver, measure  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["planar_chain_5.toml", "six_axis_arm.toml", "fast_two_link.toml", "two_link_payload.toml",
           "rotating_link.toml", "spatial_cantilever.toml"]


def compare(scene_path: Path, rounds: int, repeats: int, stop: float) -> dict:
    """The medians over ``rounds`` alternated rounds of each build's residual and step times."""
    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case

    scene = load_scene(scene_path)
    model = build_model(scene)
    case = default_case(model, stop=stop)
    times: dict[str, dict[str, list[float]]] = {k: {"residual_s": [], "step_s": []} for k in ("avx", "baseline")}
    iterations = set()
    with tempfile.TemporaryDirectory() as tmp:
        fmu = build_fmu(scene, Path(tmp) / "twins.fmu", model=model).fmu
        exes = {"avx": compile_driver(fmu, Path(tmp) / "avx"),
                "baseline": compile_driver(fmu, Path(tmp) / "baseline", defines=("FLEXLINK_NO_AVX",))}
        for _ in range(rounds):
            for kind, exe in exes.items():
                r = measure(exe, fmu, case, step=scene.fmu.solver.step, repeats=repeats)
                iterations.add(r["newton_iterations"])
                for key in times[kind]:
                    times[kind][key].append(r[key])
    if len(iterations) != 1:
        raise SystemExit(f"{scene_path.name}: the two builds iterated differently ({sorted(iterations)})")
    med = {k: {key: statistics.median(v) for key, v in t.items()} for k, t in times.items()}
    return {"scene": scene_path.stem, **{f"{k}_{key}": v for k, t in med.items() for key, v in t.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stop", type=float, default=3.0, help="manoeuvre length [s] (default 3)")
    args = ap.parse_args()
    paths = [Path(s) for s in args.scenes] or [ROOT / "examples" / s for s in DEFAULT]
    print(f"{'scene':22s} {'residual us (base → AVX)':>26s} {'step us (base → AVX)':>22s} {'speed-up':>8s}")
    for path in paths:
        r = compare(path, args.rounds, args.repeats, args.stop)
        print(f"{r['scene']:22s} {1e6 * r['baseline_residual_s']:12.2f} → {1e6 * r['avx_residual_s']:<11.2f} "
              f"{1e6 * r['baseline_step_s']:9.2f} → {1e6 * r['avx_step_s']:<9.2f} "
              f"{r['baseline_step_s'] / r['avx_step_s']:7.2f}×", flush=True)


if __name__ == "__main__":
    main()
