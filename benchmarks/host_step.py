"""What a host pays stepping an FMU at the solver's own step: the consistent acceleration kept or not.

    python benchmarks/host_step.py [SCENE.toml ...] [--modes 32] [--host H] [--rounds N] [--repeats N]
                                   [--min-cost C] [--json]

A host that calls ``fmi2DoStep`` at ``solver.step`` and reads every output after it makes the FMU find the
consistent acceleration M(q) a = −r(q, v, 0, u, p) after every internal step: the outputs and the energy
balance stand on it.  ``fmu_src/consistent.c`` keeps a factorised M across calls and iterates on the residual
where a new M costs more than a few residuals (``CONSISTENT_REFRESH_COST``); this benchmark times it against
the direct solve every time (the same sources compiled with ``-DCONSISTENT_KEEP_MIN_COST=1e300``).

For each scene (default: ``examples/planar_chain_5.toml``, ``examples/six_axis_arm.toml`` and the 32-mode
second-order link of ``benchmarks/scaling.py``) the FMU is built once and ``benchmarks/step_floor.c`` is
compiled twice with its sources.  Each runs the bench manoeuvre (``flexlink.tools.bench.default_case``, 2 s) as
a host stepping at ``--host`` (default: the scene's ``solver.step``), reading every output after each step,
alternately for ``--rounds`` rounds of ``--repeats`` runs, so that the load falls on both alike.  Reported:
the median CPU µs per communication step of each, their ratio, the long-step figure (one ``fmi2DoStep`` per
input segment, µs per internal step) and the kept form's counters per communication step: mass matrices
formed and residuals iterated.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import step_floor  # noqa: E402

DIRECT = ("CONSISTENT_KEEP_MIN_COST=1e300",)      # never kept: M and its LU at every call, as before
DEFAULT = [str(ROOT / "examples" / "planar_chain_5.toml"), str(ROOT / "examples" / "six_axis_arm.toml")]


def _scene(spec: str, modes: int):
    """A scene file, or the 32-mode (``--modes``) second-order link of the scaling benchmark for ``modes``."""
    from flexlink.scene.loader import load_scene, parse_scene

    if spec == "modes":
        from scaling import modes_scene

        return parse_scene(modes_scene(modes)), f"one link, {modes} modes"
    return load_scene(spec), Path(spec).stem


def compare(spec: str, *, modes: int, host: float | None, rounds: int, repeats: int,
            min_cost: float | None = None) -> dict:
    """Median µs per communication step, kept and direct, with the kept form's counters."""
    import fmpy

    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.tools.bench import default_case

    scene, label = _scene(spec, modes)
    model = build_model(scene)
    fmu = Path(cached_fmu(scene, model=model))
    md = fmpy.read_model_description(str(fmu))
    outputs = [str(v.valueReference) for v in md.modelVariables if v.causality == "output"]
    step = host or scene.fmu.solver.step
    case = default_case(model, stop=2.0)
    base = step_floor.manoeuvre_tokens(fmu, case, {"solver.step": scene.fmu.solver.step})
    hosted = [*base, "host", repr(step), *(t for vr in outputs for t in ("out", vr))]
    with tempfile.TemporaryDirectory() as tmp:
        kept = () if min_cost is None else (f"CONSISTENT_KEEP_MIN_COST={min_cost!r}",)
        exes = {"kept": step_floor.compile_driver(fmu, tmp, defines=kept, name="kept"),
                "direct": step_floor.compile_driver(fmu, tmp, defines=DIRECT, name="direct")}
        times: dict[str, list[float]] = {k: [] for k in exes}
        counts: dict[str, dict] = {}
        for _ in range(rounds):
            for key, exe in exes.items():
                out = subprocess.run([str(exe), md.guid, str(repeats), *hosted], capture_output=True, text=True,
                                     check=True)
                res = json.loads(out.stdout)
                n = max(res["communication_steps"], 1)
                times[key].append(res["run_cpu_s"] / n)
                counts[key] = {"refreshes": res["mass_refreshes"] / n, "iterations": res["mass_iterations"] / n,
                               "residual_us": res["residual_s"] * 1e6, "communication_steps": n}
        long = json.loads(subprocess.run([str(exes["kept"]), md.guid, str(repeats), *base], capture_output=True,
                                         text=True, check=True).stdout)
    med = {k: statistics.median(v) * 1e6 for k, v in times.items()}
    return {"scene": label, "n_q": model.n_q, "host_step": step, "us_per_communication_step": med,
            "speed-up": med["direct"] / med["kept"], "long_step_us": long["step_s"] * 1e6, "counts": counts}


def report(rows: list[dict]) -> str:
    lines = ["| scene | n_q | host step | direct µs/step | kept µs/step | speed-up | M formed / step | "
             "residuals iterated / step | long step µs |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        us, kept = r["us_per_communication_step"], r["counts"]["kept"]
        lines.append(f"| {r['scene']} | {r['n_q']} | {r['host_step']:g} s | {us['direct']:.1f} | {us['kept']:.1f} | "
                     f"{r['speed-up']:.2f}× | {kept['refreshes']:.3f} | {kept['iterations']:.2f} | "
                     f"{r['long_step_us']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", help="scene files; 'modes' is the scaling benchmark's link")
    parser.add_argument("--modes", type=int, default=32, help="modes of the 'modes' link (default 32)")
    parser.add_argument("--host", type=float, help="the host's step (default: each scene's solver.step)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--min-cost", type=float, help="the kept form's CONSISTENT_KEEP_MIN_COST (default: "
                        "fmu_src/consistent.c's): where a new M costs fewer residuals, the direct solve")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    for name, value in (("--modes", args.modes), ("--rounds", args.rounds), ("--repeats", args.repeats)):
        if value < 1:
            parser.error(f"{name} must be at least 1")
    if args.host is not None and not args.host > 0:
        parser.error("--host must be > 0")
    rows = [compare(s, modes=args.modes, host=args.host, rounds=args.rounds, repeats=args.repeats,
                    min_cost=args.min_cost)
            for s in (args.scenes or [*DEFAULT, "modes"])]
    print(json.dumps(rows, indent=1) if args.json else report(rows))


if __name__ == "__main__":
    main()
