"""Cost of one SS22 internal step against its floor, measured in the same process (issue 6, item 1).

    python benchmarks/step_floor.py [SCENE.toml ...] [--step H] [--order 2|4] [--repeats N] [--json]

The floor is one evaluation of the generated residual (the forces: M a + h) and of the generated Newton
matrix (the mass matrix plus the step terms) and one dense LU of the same size.  ``benchmarks/step_floor.c``
is compiled together with the C sources shipped in the FMU (``sources/``: the generated model and the
generic ``fmu_src``), runs issue 6's manoeuvre (+τ for 1 s, −τ for 1 s, then free, 5 s) through
``fmi2DoStep`` (one call per input segment: no host loop charged) and times, in the same process, the
floor and its parts at the end state of the run.  The integrator's counters (steps, Newton iterations,
factorisations, residual evaluations) come from the instance itself.  Times are CPU seconds, medians of
``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DRIVER = Path(__file__).resolve().parent / "step_floor.c"
DEFAULT = ["rotating_link_linear.toml", "rotating_link.toml"]


def compile_driver(fmu: str | Path, workdir: str | Path, driver: Path = DRIVER, defines: tuple[str, ...] = (),
                   name: str | None = None) -> Path:
    """Extract the FMU's ``sources/`` into ``workdir`` and compile ``driver`` (a C file, by default this
    benchmark's) with them (an executable, ``name`` or the driver's stem; ``defines``: ``-D`` flags)."""
    from flexlink.errors import BuildError
    from flexlink.export.cbuild import compiler

    workdir = Path(workdir)
    src = workdir / "sources"
    with zipfile.ZipFile(fmu) as z:
        for member in z.namelist():
            if member.startswith("sources/") and not member.endswith("/"):
                z.extract(member, workdir)
    import xml.etree.ElementTree as ET

    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    # the files the FMU lists (model.c includes the CasADi file with its own warning settings)
    files = [f.get("name") for f in root.findall("CoSimulation/SourceFiles/File")]
    exe = workdir / (name or Path(driver).stem)
    command = [*compiler(), "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", *(f"-D{x}" for x in defines),
               f"-I{src}", f"-I{Path(driver).parent}",
               *(str(src / f) for f in files), str(driver), "-o", str(exe), "-lm"]
    res = subprocess.run(command, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise BuildError(f"compiling {Path(driver).name} failed:\n{res.stderr.strip()}")
    return exe


def manoeuvre_tokens(fmu: str | Path, case, start: dict[str, float]) -> list[str]:
    """Command-line tokens of the driver: ``set`` the start values, then one ``seg`` per input piece."""
    import fmpy

    md = fmpy.read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    tokens: list[str] = []
    for name, value in start.items():
        tokens += ["set", str(vr[name]), repr(float(value))]
    bounds = [0.0, *case.switches, case.stop]
    if not case.pieces:                          # built-in laws only: one segment, no input
        return [*tokens, "seg", repr(float(case.stop)), "-", "0"]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        u = case.inputs_at(lo)
        if len(u) != 1:
            raise ValueError("the driver holds one input per segment")
        (name, value), = u.items()
        tokens += ["seg", repr(float(hi)), str(vr[name]), repr(float(value))]
    return tokens


def measure(exe: Path, fmu: str | Path, case, *, step: float, order: int = 2, repeats: int = 11) -> dict:
    """Run the compiled driver on ``case`` (a flexlink.tools.bench.BenchCase) and return its figures, with
    ``per_step_over_floor`` = CPU time per internal step / floor."""
    import fmpy

    guid = fmpy.read_model_description(str(fmu)).guid
    tokens = manoeuvre_tokens(fmu, case, {"solver.step": step, "solver.order": order})
    out = subprocess.run([str(exe), guid, str(repeats), *tokens], capture_output=True, text=True, check=True)
    res = json.loads(out.stdout)
    res["step"] = step
    res["per_step_over_floor"] = res["step_s"] / res["floor_s"]
    return res


def measure_scene(scene_path: str | Path, *, step: float | None = None, orders=(2,), repeats: int = 11,
                  stop: float = 5.0, fmu: str | Path | None = None) -> list[dict]:
    """Build the scene's FMU (unless given), compile the driver and measure each order."""
    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case

    scene = load_scene(scene_path)
    model = build_model(scene)
    case = default_case(model, stop=stop)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if fmu is None:
            fmu = build_fmu(scene, Path(tmp) / "floor.fmu", model=model).fmu
        exe = compile_driver(fmu, tmp)
        for order in orders:
            r = measure(exe, fmu, case, step=step or scene.fmu.solver.step, order=order, repeats=repeats)
            r["scene"] = Path(scene_path).stem
            rows.append(r)
    return rows


def format_rows(rows: list[dict]) -> str:
    head = (f"{'scene':22s} {'ord':>3s} {'n_q':>3s} {'step':>7s} {'us/step':>8s} {'floor us':>8s} {'ratio':>6s} "
            f"{'resid us':>8s} {'Jac us':>7s} {'LU us':>6s} {'solve us':>8s} {'steps':>6s} {'newton':>6s} "
            f"{'factor':>6s} {'resid':>6s}")
    lines = [head]
    for r in rows:
        lines.append(f"{r['scene']:22s} {r['order']:3d} {r['n_q']:3d} {r['step']:7.1e} {1e6 * r['step_s']:8.3f} "
                     f"{1e6 * r['floor_s']:8.3f} {r['per_step_over_floor']:6.2f} {1e6 * r['residual_s']:8.3f} "
                     f"{1e6 * r['newton_matrix_s']:7.3f} {1e6 * r['lu_factor_s']:6.3f} {1e6 * r['lu_solve_s']:8.3f} "
                     f"{r['ss22_steps']:6d} {r['newton_iterations']:6d} {r['factorisations']:6d} "
                     f"{r['residual_evaluations']:6d}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--step", type=float, help="SS22 step (default: the scene's)")
    ap.add_argument("--order", type=int, action="append", choices=(2, 4), help="repeatable; default 2")
    ap.add_argument("--repeats", type=int, default=11)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    scenes = args.scenes or [str(ROOT / "examples" / s) for s in DEFAULT]
    rows = []
    for path in scenes:
        rows += measure_scene(path, step=args.step, orders=args.order or (2,), repeats=args.repeats)
    print(json.dumps(rows) if args.json else format_rows(rows))


if __name__ == "__main__":
    main()
