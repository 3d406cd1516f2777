"""Checks ``libcosim`` and ``fmutool``: the independent importers of :mod:`flexlink.tools.importers`.

A run is judged by its outcome, not by every line it logs.  The rule:

* the run **failed** (an error, rule ``importer``) if the importer's process crashed or exited non-zero,
  printed no result, reported the simulation as not completed, or gave a non-finite output;
* a log line of ``KNOWN_NOISE`` (a documented parser bug or chatter of the importer itself, not a fault of
  the FMU) is shown in the details and changes nothing;
* any other ``[error]``/``[warning]`` line of a run that completed is a warning (``importer-warning``), and
  an error on a flexlink FMU (flexlink's own FMUs must run clean).

Co-Simulation only (libcosim); fmutool checks the model description.
"""

from __future__ import annotations

import math
import re
import time

from flexlink.tools.check.findings import CheckResult, Finding, skipped
from flexlink.tools.check.fmu import Fmu

# (pattern, why it is not the FMU's fault, a condition on the FMU under which that holds)
KNOWN_NOISE = [
    (re.compile(r"Start attribute is required for this causality, variability and initial combination"),
     "FMI Library's parser asks for a start value on the independent variable (`time`), which FMI 2.0 §2.2.7 "
     "forbids; known noise only when that variable is declared and every other variable that needs a start "
     "has one",
     lambda f: _has_independent(f) and not _missing_starts(f)),
    (re.compile(r"Enumeration variable type not supported"),
     "libcosim ignores Enumeration variables (a limitation of the importer, not of the FMU)",
     lambda f: True),
]


def _has_independent(f: Fmu) -> bool:
    return any(v.causality == "independent" for v in f.md.modelVariables)


def _missing_starts(f: Fmu) -> list[str]:
    """Variables that FMI 2.0 §2.2.7 requires a start value of but that have none.

    Those are inputs, parameters, constants, and variables of initial = exact or approx.
    """
    out = []
    for v in f.md.modelVariables:
        needs = (v.causality in ("input", "parameter") or v.variability == "constant"
                 or v.initial in ("exact", "approx"))
        if needs and v.start is None:
            out.append(v.name)
    return out


def _classify(f: Fmu, log: str) -> tuple[list[str], list[str]]:
    """The log's [error]/[warning] lines split into (known noise, the rest)."""
    noise: list[str] = []
    other: list[str] = []
    for line in log.splitlines():
        if "[error]" not in line.lower() and "[warning]" not in line.lower():
            continue
        why = next((w for p, w, holds in KNOWN_NOISE if p.search(line) and holds(f)), None)
        (noise if why else other).append(line.strip() + (f"  (known: {why})" if why else ""))
    return noise, other


def check_libcosim(f: Fmu) -> CheckResult:
    """The FMU's Co-Simulation run by libcosim for 0.05 s (see the module docstring for the judgement)."""
    from flexlink.tools.importers import libcosim_available, run_libcosim

    if "CS" not in f.interfaces:
        return skipped("libcosim", "Co-Simulation only (not declared or not selected)")
    if not libcosim_available():
        return skipped("libcosim", "libcosimpy is not installed")
    t0 = time.perf_counter()
    stop = 0.05
    step = f.md.defaultExperiment.stepSize if f.md.defaultExperiment else None
    step = 1e-3 if f.is_flexlink or not step else min(float(step), stop)
    run = run_libcosim(f.path, stop, step, f.outputs[:3], f.real_excitation())
    noise, other = _classify(f, run.log)
    found = []
    if not run.completed:
        tail = run.log.strip().splitlines()[-1:] or ["no output"]
        found.append(Finding("importer", f"libcosim: the run did not complete ({run.why}): {tail[0]}"))
    elif not all(math.isfinite(v) for v in run.values.values()):
        found.append(Finding("importer", f"libcosim: non-finite outputs {run.values}"))
    found += [Finding("importer" if f.is_flexlink else "importer-warning", f"libcosim: {line}") for line in other]
    result = ", ".join(f"{k} = {v:.6g}" for k, v in run.values.items()) or ("completed" if run.completed
                                                                              else "no result")
    return CheckResult("libcosim", f"0 .. {stop} s, step {step} s", "completes; no error or warning but known "
                       "noise", result, seconds=time.perf_counter() - t0,
                       details=[x.message for x in found] + noise + run.log.splitlines()[-10:] * bool(found),
                       findings=found)


def check_fmutool(f: Fmu) -> CheckResult:
    """fmu-manipulation-toolbox's ``fmutool -check`` on the FMU."""
    from flexlink.tools.importers import fmutool_check

    t0 = time.perf_counter()
    run = fmutool_check(f.path)
    if "not installed" in run.log:
        return skipped("fmutool", "fmu-manipulation-toolbox is not installed")
    found = [] if run.ok else [Finding("importer", "fmutool -check reports errors")]
    return CheckResult("fmutool", "fmutool -check", "no errors", "no errors" if run.ok else "errors",
                       seconds=time.perf_counter() - t0, details=[] if run.ok else run.log.splitlines()[-20:],
                       findings=found)
