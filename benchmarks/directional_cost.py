"""What a directional derivative costs: the complex step against CasADi's forward-mode functions.

For each scene, two FMUs from the same scene: the default build (the forward derivatives by the complex step
on the residual and outputs, docs/fmi.md) and one with CasADi's forward-mode functions
(``flexlink.export.codegen.COMPLEX_STEP = False``).  For each: the generated operations and C bytes, and the
time of one fmi2GetDirectionalDerivative call in Model Exchange (every state derivative and output, in one
state's direction), timed from C through ctypes over many calls, medians of several runs alternating the two
FMUs, and, for scale, one evaluation of the state derivatives (fmi2SetContinuousStates + fmi2GetDerivatives).

    python benchmarks/directional_cost.py [--repeats 5] [--calls 2000] [--write] [scene.toml ...]

``--write`` puts the table into docs/performance.md between ``<!-- directional-cost:begin -->`` and
``<!-- directional-cost:end -->``.
"""

from __future__ import annotations

import argparse
import ctypes
import datetime
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Model

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ["examples/six_axis_arm.toml", "examples/planar_chain_5.toml", "examples/flexible_pendulum.toml"]
BEGIN, END = "<!-- directional-cost:begin -->", "<!-- directional-cost:end -->"


def _build(scene: Path, folder: Path, complex_step: bool):
    from flexlink.export import codegen
    from flexlink.export.fmu import build_fmu

    codegen.COMPLEX_STEP = complex_step
    try:
        return build_fmu(scene, folder)
    finally:
        codegen.COMPLEX_STEP = True


class _Instance:
    """One Model Exchange instance, initialised, with the value references a Jacobian column needs."""

    def __init__(self, fmu: Path):
        md = read_model_description(str(fmu))
        self.inst = FMU2Model(guid=md.guid, unzipDirectory=extract(str(fmu)),
                              modelIdentifier=md.modelExchange.modelIdentifier, instanceName="cost")
        self.inst.instantiate()
        self.inst.setupExperiment(startTime=0.0)
        self.inst.enterInitializationMode()
        self.inst.exitInitializationMode()
        self.inst.enterContinuousTimeMode()
        unknown = [d.variable.valueReference for d in md.derivatives] + [o.variable.valueReference
                                                                          for o in md.outputs]
        self.n_x = len(md.derivatives)
        self.unknown = (ctypes.c_uint * len(unknown))(*unknown)
        self.known = (ctypes.c_uint * 1)(md.derivatives[0].variable.derivative.valueReference)
        self.seed = (ctypes.c_double * 1)(1.0)
        self.out = (ctypes.c_double * len(unknown))()
        self.dx = (ctypes.c_double * self.n_x)()
        self.x = (ctypes.c_double * self.n_x)()

    def directional(self, calls: int) -> float:
        f, c = self.inst.fmi2GetDirectionalDerivative, self.inst.component
        n = len(self.unknown)
        t = time.perf_counter()
        for _ in range(calls):
            f(c, self.unknown, n, self.known, 1, self.seed, self.out)
        return (time.perf_counter() - t) / calls

    def derivatives(self, calls: int) -> float:
        """One fmi2SetContinuousStates + fmi2GetDerivatives: the state derivatives evaluated afresh (a set state
        drops the instance's evaluated point), for the scale of one model evaluation."""
        f, c, s = self.inst.fmi2GetDerivatives, self.inst.component, self.inst.fmi2SetContinuousStates
        self.inst.fmi2GetContinuousStates(c, self.x, self.n_x)
        t = time.perf_counter()
        for _ in range(calls):
            s(c, self.x, self.n_x)
            f(c, self.dx, self.n_x)
        return (time.perf_counter() - t) / calls

    def close(self) -> None:
        self.inst.terminate()
        self.inst.freeInstance()


def _measure(scene: Path, tmp: Path, repeats: int, calls: int) -> list[str]:
    """The table rows of one scene: both forms built, then timed alternately (the same load for both)."""
    builds = {form: _build(scene, tmp / f"{scene.stem}_{form}", form == "complex step")
              for form in ("complex step", "forward mode")}
    instances = {form: _Instance(b.fmu) for form, b in builds.items()}
    times: dict[str, tuple[list[float], list[float]]] = {form: ([], []) for form in builds}
    for _ in range(repeats):
        for form, inst in instances.items():
            times[form][0].append(inst.directional(calls))
            times[form][1].append(inst.derivatives(calls))
    rows = []
    for form, b in builds.items():
        d, g = (statistics.median(x) * 1e6 for x in times[form])
        rows.append(f"| {scene.stem} | {form} | {b.operations} | {b.generated_c_bytes / 1e6:.2f} | {d:.1f} | "
                    f"{g:.1f} |")
    for inst in instances.values():
        inst.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=DEFAULT)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--write", action="store_true", help="write the table into docs/performance.md")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0]
    lines = ["| scene | form | operations | C [MB] | µs a directional derivative "
             "| µs to evaluate the state derivatives |",
             "| --- | --- | --- | --- | --- | --- |"]
    print("\n".join(lines), flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scenes:
            rows = _measure(ROOT / scene, Path(tmp), args.repeats, args.calls)
            print("\n".join(rows), flush=True)
            lines += rows
    if args.write:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from report import PAGE, rewrite_readme  # the block rewriter of benchmarks/report.py

        head = (f"Measured {datetime.date.today()} on {platform.machine()} (`python benchmarks/directional_cost.py "
                f"--repeats {args.repeats} --write`): medians of {args.repeats} runs of {args.calls} calls, the "
                f"two forms alternated; load average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end.")
        rewrite_readme(PAGE, "\n".join([BEGIN, "<!-- generated by `python benchmarks/directional_cost.py --write`: "
                                         "edit it, not this block -->", "", head, "", *lines, END]), BEGIN, END)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
