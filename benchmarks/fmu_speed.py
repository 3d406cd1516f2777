"""FMU build time, size, and cost per SS22 step / per simulated second (issue 3's figures).

    python benchmarks/fmu_speed.py [SCENE.toml ...] [--repeats N] [--sim-time T] [--large]

The FMU is timed with one long communication step (fmi2DoStep over the whole run) so that no Python
loop is charged; each figure is the median of ``--repeats`` runs (the machine is shared and noisy).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["rotating_link_linear.toml", "rotating_link.toml", "steel_beam_raise.toml", "flexible_pendulum.toml"]
LARGE = ROOT / "benchmarks" / "scenes" / "fe40_second_order.toml"


def time_fmu(fmu: Path, sim_time: float, step: float, repeats: int) -> list[float]:
    """Wall seconds of one ``fmi2DoStep`` over ``sim_time`` (a fresh instance each repeat, through FmuHost)."""
    from flexlink.run.host import FmuHost

    walls = []
    with FmuHost(fmu, instance_name="bench") as host:
        for _ in range(repeats):
            host.initialize({"solver.step": step})     # resets the instance after the first run
            if "hub.tau" in host.vr:
                host.set_values({"hub.tau": 0.2})
            t0 = time.perf_counter()
            host.call("fmi2DoStep", host.instance.doStep, 0.0, sim_time)
            walls.append(time.perf_counter() - t0)
    return walls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sim-time", type=float, default=10.0)
    ap.add_argument("--large", action="store_true", help="also the 81-coordinate FE model (about 10 s to build)")
    args = ap.parse_args()
    from flexlink.export.fmu import build_fmu
    from flexlink.scene.loader import load_scene

    scenes = args.scenes or [str(ROOT / "examples" / s) for s in DEFAULT]
    if args.large:
        scenes.append(str(LARGE))
    print(f"{'scene':28s} {'n_q':>4s} {'build s':>8s} {'FMU KiB':>8s} {'C KiB':>7s} {'step s':>8s} "
          f"{'us/step':>8s} {'ms/sim s':>9s}")
    with tempfile.TemporaryDirectory() as tmp:
        for path in scenes:
            scene = load_scene(path)
            builds = []
            for k in range(max(1, min(3, args.repeats))):
                rep = build_fmu(scene, Path(tmp) / f"{scene.model_identifier}-{k}.fmu")
                builds.append(sum(rep.seconds.values()))
            step = scene.fmu.solver.step
            sim_time = min(args.sim_time, 2000 * step)        # at most 2000 steps of the large models
            walls = time_fmu(rep.fmu, sim_time, step, args.repeats)
            wall = statistics.median(walls)
            n_steps = round(sim_time / step)
            print(f"{Path(path).stem:28s} {rep.n_coordinates:4d} {statistics.median(builds):8.2f} "
                  f"{rep.fmu_bytes / 1024:8.0f} {rep.generated_c_bytes / 1024:7.0f} {step:8.1e} "
                  f"{wall / n_steps * 1e6:8.3f} {wall / sim_time * 1e3:9.3f}")


if __name__ == "__main__":
    main()
