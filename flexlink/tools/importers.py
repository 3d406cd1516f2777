"""Independent FMI importers from PyPI, run against our FMUs (docs/check.md).

* libcosimpy (Open Simulation Platform's libcosim, on the Modelica Association's FMI Library): it
  aborts or crashes when an FMU returns an error, so it runs in a child process.  ``ok`` is a completed run
  without any ``[error]``/``[warning]`` line (flexlink's own FMUs must be that clean); ``completed`` only
  says the run finished with a result, for callers that judge the log lines themselves
  (:mod:`flexlink.tools.check.importer_checks` tells an importer's known parser bugs from the FMU's faults).
* fmu-manipulation-toolbox's ``fmutool -check`` (schema and semantic checks; exit 7 on errors).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

_LIBCOSIM_CHILD = r'''
import json, sys
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

log_output_level(CosimLogLevel.WARNING)
fmu, stop, step, start, outputs = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), json.loads(sys.argv[4]), \
    json.loads(sys.argv[5])
ex = CosimExecution.from_step_size(step_size=int(round(step * 1e9)))
idx = ex.add_local_slave(CosimLocalSlave(fmu_path=fmu, instance_name="flexlink"))
obs = CosimObserver.create_last_value()
ex.add_observer(obs)
refs = {v.name.decode(): v.reference for v in ex.slave_variables(idx)}
for name, value in start.items():
    ex.real_initial_value(idx, refs[name], value)
ok = ex.simulate_until(target_time=int(round(stop * 1e9)))
values = obs.last_real_values(idx, [refs[n] for n in outputs]) if outputs else []
print("RESULT " + json.dumps({"ok": bool(ok), "values": dict(zip(outputs, values))}))
'''


_LIBCOSIM_SSP_CHILD = r'''
import json, sys
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver

log_output_level(CosimLogLevel.WARNING)
ssp, n_steps, record = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
ex = CosimExecution.from_ssp_file(ssp)
obs = CosimObserver.create_last_value()
ex.add_observer(obs)
idx = {el: ex.slave_index_from_instance_name(el) for el in record}
refs = {el: {v.name.decode(): v.reference for v in ex.slave_variables(i)} for el, i in idx.items()}
rows, ok = [], True
for k in range(n_steps):
    if not ex.step():
        ok = False
        break
    rows.append([v for el, names in record.items()
                 for v in obs.last_real_values(idx[el], [refs[el][n] for n in names])])
print("RESULT " + json.dumps({"ok": ok, "rows": rows}))
'''


Value = TypeVar("Value", float, list[float])   # a last value, or a series (an SSP run)


@dataclass
class ImporterRun(Generic[Value]):
    """What one run of an independent importer showed, whether or not the importer finished.

    The importers abort, crash or hang on a faulty FMU, so a run is a record rather than an exception: the
    caller decides whether a failure is the FMU's or the importer's (:mod:`flexlink.tools.check`).

    Attributes
    ----------
    ok : bool
        The run completed and logged no ``[error]``/``[warning]`` line (the bar flexlink's own FMUs meet).
    values : dict of str to Value
        Variable → its last value (:func:`run_libcosim`), or ``"element:variable"`` → its value after each
        step (:func:`run_libcosim_ssp`); empty when the run gave no result.
    log : str
        The importer's standard output and error, for the caller to judge or show.
    completed : bool
        The run finished and printed its result, whatever it logged.
    why : str
        Why it did not complete (exit status, signal, timeout, a failed step); empty when it did.
    """

    ok: bool
    values: dict[str, Value] = field(default_factory=dict)
    log: str = ""
    completed: bool = False
    why: str = ""


def libcosim_available() -> bool:
    """Whether libcosimpy imports here: the libcosim checks are skipped, not failed, on a machine without it."""
    try:
        import libcosimpy  # noqa: F401
    except Exception:
        return False
    return True


def run_libcosim(fmu: str | os.PathLike, stop_time: float, step: float, outputs: list[str],
                 start_values: dict[str, float] | None = None, timeout: float = 120) -> ImporterRun[float]:
    """Co-simulate the FMU alone in libcosim and return the outputs' last values.

    The run happens in a child process: libcosim aborts the whole process when an FMU returns an error, and
    a refused call is exactly what the callers want to see reported.

    Parameters
    ----------
    fmu : str or os.PathLike
        The FMU file.
    stop_time, step : float
        The end time and the fixed communication step, in seconds (libcosim counts in nanoseconds).
    outputs : list of str
        The variables whose last values are read back.
    start_values : dict of str to float, optional
        Real start values set before initialisation.
    timeout : float
        Seconds before the child is given up.

    Returns
    -------
    ImporterRun
        ``values`` maps each output to its value at ``stop_time``.
    """
    cmd = [sys.executable, "-c", _LIBCOSIM_CHILD, os.fspath(fmu), repr(stop_time), repr(step),
           json.dumps(start_values or {}), json.dumps(outputs)]
    run, data = _child(cmd, timeout)
    if data is not None:
        run.values = data["values"]
    return run


def run_libcosim_ssp(ssp: str | os.PathLike, n_steps: int, record: dict[str, list[str]],
                     timeout: float = 300) -> ImporterRun[list[float]]:
    """Load an SSP package in libcosim and take ``n_steps`` steps of its own master algorithm.

    ``CosimExecution.from_ssp_file`` takes the fixed-step algorithm and the step size from the package, so the
    run checks the package as a user's SSP tool would read it, not as our own loop would.

    Parameters
    ----------
    ssp : str or os.PathLike
        The .ssp file.
    n_steps : int
        The number of communication steps to take.
    record : dict of str to list of str
        Element (instance) name → the variables to record after each step.
    timeout : float
        Seconds before the child process is given up (a hung importer is a failed run, not a hung caller).

    Returns
    -------
    ImporterRun
        ``values`` maps ``"element:variable"`` to its value after each step (times t_1 … t_n); a run that
        stopped early is neither ``ok`` nor ``completed``.
    """
    cmd = [sys.executable, "-c", _LIBCOSIM_SSP_CHILD, os.fspath(ssp), str(int(n_steps)), json.dumps(record)]
    run: ImporterRun[list[float]]
    run, data = _child(cmd, timeout)
    if data is not None:
        names = [f"{el}:{n}" for el, ns in record.items() for n in ns]
        cols: list[tuple[float, ...]] = list(zip(*data["rows"], strict=True)) if data["rows"] else [
            () for _ in names]
        run.values = {n: list(c) for n, c in zip(names, cols, strict=True)}
        if len(data["rows"]) != n_steps:
            run.ok, run.completed, run.why = False, False, f"stopped after {len(data['rows'])} of {n_steps} steps"
    return run


def _child(cmd: list[str], timeout: float) -> tuple[ImporterRun[Value], dict[str, Any] | None]:
    """Run a libcosim child process and read its ``RESULT`` line.

    Returns the run (``ok``: completed without an ``[error]``/``[warning]`` line) and its ``RESULT`` document,
    None when the child printed none (it crashed, timed out or exited with an error).
    """
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as e:
        return ImporterRun(False, {}, str(e.stdout or "") + str(e.stderr or ""),
                           why=f"no result within {timeout} s"), None
    log = p.stdout + p.stderr
    bad = [line for line in log.splitlines() if "[error]" in line.lower() or "[warning]" in line.lower()]
    result = [line for line in p.stdout.splitlines() if line.startswith("RESULT ")]
    if p.returncode != 0 or not result:
        why = f"signal {-p.returncode}" if p.returncode < 0 else f"exit status {p.returncode}"
        return ImporterRun(False, {}, log, why=why if p.returncode else "no result"), None
    data = json.loads(result[-1][len("RESULT "):])
    completed = bool(data["ok"])
    return ImporterRun(completed and not bad, {}, log, completed, "" if completed else
                       "the execution reported a failed step"), data


def fmutool_check(fmu: str | os.PathLike, timeout: float = 120) -> ImporterRun[float]:
    """Run fmu-manipulation-toolbox's ``fmutool -check`` (schema and semantic checks) on an FMU.

    A second reading of the model description by a tool that is not fmpy, so that a fault fmpy tolerates is
    still found.  ``ok`` is exit status 0 and no ``error`` in the log (its "no semantic error" line aside); a
    missing fmutool is a failed run that says so.
    """
    exe = shutil.which("fmutool") or os.path.join(os.path.dirname(sys.executable), "fmutool")
    if not os.path.exists(exe):
        return ImporterRun(False, {}, "fmutool is not installed (pip install fmu-manipulation-toolbox)")
    p = subprocess.run([exe, "-input", os.fspath(fmu), "-check"], capture_output=True, text=True, timeout=timeout)
    log = p.stdout + p.stderr
    ok = p.returncode == 0 and "error" not in log.lower().replace("no semantic error", "")
    return ImporterRun(ok, {}, log)
