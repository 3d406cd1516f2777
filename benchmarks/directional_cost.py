"""What a directional derivative costs: the complex step against CasADi's forward-mode functions.

For each scene, two FMUs from the same scene: the default build (the forward derivatives by the complex step
on the residual and outputs, docs/fmi.md) and one with CasADi's forward-mode functions
(``flexlink.export.codegen.COMPLEX_STEP = False``).  For each: the generated operations and C bytes, and the
time of one fmi2GetDirectionalDerivative call in Model Exchange (every state derivative and output, in one
state's direction), timed from C through ctypes over many calls, medians of several runs alternating the two
FMUs, and the time of one fmi2GetDerivatives call for scale.

    python benchmarks/directional_cost.py [--repeats 5] [--calls 2000] [scene.toml ...]
"""

from __future__ import annotations

import argparse
import ctypes
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

    def directional(self, calls: int) -> float:
        f, c = self.inst.fmi2GetDirectionalDerivative, self.inst.component
        n = len(self.unknown)
        t = time.perf_counter()
        for _ in range(calls):
            f(c, self.unknown, n, self.known, 1, self.seed, self.out)
        return (time.perf_counter() - t) / calls

    def derivatives(self, calls: int) -> float:
        f, c = self.inst.fmi2GetDerivatives, self.inst.component
        t = time.perf_counter()
        for _ in range(calls):
            f(c, self.dx, self.n_x)
        return (time.perf_counter() - t) / calls

    def close(self) -> None:
        self.inst.terminate()
        self.inst.freeInstance()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=DEFAULT)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--calls", type=int, default=2000)
    args = ap.parse_args(argv)
    print("| scene | form | operations | C [MB] | µs a directional derivative | µs a fmi2GetDerivatives |")
    print("| --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scenes:
            path = ROOT / scene
            builds = {form: _build(path, Path(tmp) / f"{path.stem}_{form}", form == "complex step")
                      for form in ("complex step", "forward mode")}
            instances = {form: _Instance(b.fmu) for form, b in builds.items()}
            times = {form: ([], []) for form in builds}
            for _ in range(args.repeats):           # alternated, so that both see the same load
                for form, inst in instances.items():
                    times[form][0].append(inst.directional(args.calls))
                    times[form][1].append(inst.derivatives(args.calls))
            for form, b in builds.items():
                d, g = (statistics.median(x) * 1e6 for x in times[form])
                print(f"| {path.stem} | {form} | {b.operations} | {b.generated_c_bytes / 1e6:.2f} | {d:.1f} | "
                      f"{g:.1f} |", flush=True)
            for inst in instances.values():
                inst.close()
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
