"""Third-party FMUs for the tests of ``flexlink check``.  PythonFMU 0.7.0 (a test dependency) exports a Python
class as an FMI 2.0 Co-Simulation FMU with its own prebuilt C++ wrapper (``binaries/linux64``), an exporter
independent of flexlink and of tests/c/check_fmu.  ``build(directory, declared=...)`` returns the FMU's path
(tests/pythonfmu/Oscillator.py; ``declared`` False: its variables as PythonFMU declares them by default).
fmu-manipulation-toolbox 2.0 (a test dependency) wraps Co-Simulation FMUs in its FMU Container, whose
runtime is its own prebuilt C: ``container(directory, fmu)``."""

from __future__ import annotations

import os
from pathlib import Path

SLAVE = Path(__file__).resolve().parent / "pythonfmu" / "Oscillator.py"
OSCILLATOR = {"k": 4.0, "c": 0.5, "x0": 1.0, "v0": 0.0}      # as in Oscillator.py


def build(directory: str | os.PathLike, *, declared: bool = True) -> Path:
    """PythonFMU's builder on a copy of the slave (``DECLARED`` set), with FMU state and its serialization
    declared (``--handle-state --serialize-state``: PythonFMU implements both)."""
    from pythonfmu.builder import FmuBuilder

    d = Path(directory) / ("declared" if declared else "defaults")
    d.mkdir(parents=True, exist_ok=True)
    script = d / SLAVE.name
    script.write_text(SLAVE.read_text().replace("DECLARED = True", f"DECLARED = {declared}"))
    return FmuBuilder.build_FMU(script, dest=d, canGetAndSetFMUstate=True, canSerializeFMUstate=True)


def oscillator_x(t: float) -> float:
    """The analytic x(t) of x'' + c x' + k x = 0 from x0, v0 (underdamped)."""
    import math

    k, c, x0, v0 = OSCILLATOR["k"], OSCILLATOR["c"], OSCILLATOR["x0"], OSCILLATOR["v0"]
    a, w = c / 2, math.sqrt(k - c * c / 4)
    return math.exp(-a * t) * (x0 * math.cos(w * t) + (v0 + a * x0) / w * math.sin(w * t))


def container(directory: str | os.PathLike, fmu: str | os.PathLike) -> Path:
    """fmu-manipulation-toolbox's FMU Container (FMI 2.0 Co-Simulation; its prebuilt C runtime
    ``container.so`` steps the embedded FMU) around one Co-Simulation FMU, its inputs, outputs and
    parameters exposed, at a fixed internal step of 0.01 s."""
    import shutil

    from fmu_manipulation_toolbox.assembly import AssemblyNode

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    shutil.copy(fmu, d / Path(fmu).name)
    node = AssemblyNode("container.fmu", step_size=0.01, auto_parameter=True)
    node.add_fmu(Path(fmu).name)
    node.make_fmu(d)
    return d / "container.fmu"
