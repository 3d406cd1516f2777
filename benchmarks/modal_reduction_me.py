"""What a modal reduction buys an importer's Model Exchange solver (issue 21, "Model exchange that importers
can run"): the finite-element examples stop fmpy's CVode on ``mxstep`` (their top modes are kHz); the same
links reduced to their first modes (``shapes = { kind = "fe", count = N, modes = M }``) run.  For each
example and mode count: fmpy's CVode at rtol 1e-6 on the full and on the reduced FMU, and the reduction's own
error, the reduced model's CVODES reference against the full model's (both at rtol 1e-9: the full one takes
minutes per simulated second, which is why this is a benchmark and not a test).

    python benchmarks/modal_reduction_me.py [--modes 3] [--stop 1]
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCENES = ("steel_beam_raise", "elastic_joint")


def reduced(name: str, modes: int, directory: Path) -> Path:
    """The example with every finite-element link reduced to its first ``modes`` modes."""
    text = (ROOT / "examples" / f"{name}.toml").read_text()
    text = re.sub(r'shapes = \{ kind = "fe", count = (\d+) \}',
                  lambda m: f'shapes = {{ kind = "fe", count = {m.group(1)}, modes = {modes} }}', text)
    text = text.replace(f'name = "{name}"', f'name = "{name}_{modes}_modes"', 1)
    path = directory / f"{name}_{modes}_modes.toml"
    path.write_text(text)
    return path


def cvode(case, scene, model) -> str:
    from flexlink.export.cache import cached_fmu
    from flexlink.tools.bench import reference_outputs, relative_error, run_model_exchange

    try:
        y, cpu = run_model_exchange(case, cached_fmu(scene, model=model), relative_tolerance=1e-6, timeout=120)
    except Exception as exc:                  # the importer's own stop, as the row's finding
        return f"stops: {str(exc)[:90]}"
    return (f"runs: {relative_error(case, y, reference_outputs(case, rtol=1e-9)):.1e} against its CVODES "
            f"reference, {cpu / case.stop:.2g} CPU s per s")


def main() -> None:
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case, reference_outputs, relative_error

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", type=int, default=3)
    ap.add_argument("--stop", type=float, default=1.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for name in SCENES:
            full = load_scene(ROOT / "examples" / f"{name}.toml")
            small = load_scene(reduced(name, args.modes, Path(tmp)))
            models = build_model(full), build_model(small)
            cases = [default_case(m, stop=args.stop) for m in models]
            print(f"{name}: {models[0].n_q} coordinates; reduced to {args.modes} modes: {models[1].n_q}", flush=True)
            print(f"  fmpy CVode, full:    {cvode(cases[0], full, models[0])}", flush=True)
            print(f"  fmpy CVode, reduced: {cvode(cases[1], small, models[1])}", flush=True)
            t0 = time.perf_counter()
            error = relative_error(cases[0], reference_outputs(cases[1], rtol=1e-9),
                                   reference_outputs(cases[0], rtol=1e-9))
            print(f"  the reduction's error (reduced against full, CVODES rtol 1e-9): {error:.1e} "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
