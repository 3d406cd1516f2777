"""Running a flexlink FMU through fmpy: input files, start values, results as CSV and plots."""

from __future__ import annotations

import csv
import itertools
import os
import re
from pathlib import Path

import numpy as np

from flexlink.errors import FlexlinkError


def read_input_csv(path: str | os.PathLike, input_names: list[str]) -> np.ndarray:
    """A CSV with a header: first column time, then one column per FMU input name."""
    path = Path(path)
    try:
        with path.open(newline="") as f:
            rows = list(csv.reader(f))
    except OSError as e:
        raise FlexlinkError(f"{path}: cannot read the input file ({e.strerror})") from None
    if len(rows) < 2:
        raise FlexlinkError(f"{path}: expected a header line and at least one row of values")
    header = [h.strip() for h in rows[0]]
    unknown = [h for h in header[1:] if h not in input_names]
    if unknown:
        raise FlexlinkError(f"{path}: column(s) {unknown} are not inputs of the FMU; its inputs are {input_names}")
    if len(set(header)) != len(header):
        raise FlexlinkError(f"{path}: duplicate column names in the header")
    dtype = [("time", np.float64)] + [(h, np.float64) for h in header[1:]]
    data = []
    for k, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != len(header):
            raise FlexlinkError(f"{path}: line {k}: expected {len(header)} values, got {len(row)}")
        try:
            values = tuple(float(x) for x in row)
        except ValueError:
            raise FlexlinkError(f"{path}: line {k}: expected numbers, got {row}") from None
        if not all(np.isfinite(values)):
            raise FlexlinkError(f"{path}: line {k}: NaN or infinite value")
        data.append(values)
    arr = np.array(data, dtype=dtype)
    if np.any(np.diff(arr["time"]) < 0):
        raise FlexlinkError(f"{path}: the time column must not decrease")
    return arr


INTERPOLATIONS = ("linear", "hold")


def hold_inputs(table: np.ndarray) -> np.ndarray:
    """The input table as a staircase: each value held until the next row's time, where it jumps.

    fmpy interpolates a real input linearly between the rows of its table and treats two rows at the same
    time as a jump (an input event it steps to exactly); so a row (t_k, u_{k-1}) inserted before each
    (t_k, u_k) turns linear interpolation into a zero-order hold without touching fmpy."""
    if len(table) < 2:
        return table
    later = np.flatnonzero(np.diff(table["time"]) > 0) + 1          # rows whose time is past the previous one
    held = table[later - 1].copy()
    held["time"] = table["time"][later]
    return np.insert(table, later, held)


def parse_assignments(items: list[str]) -> dict[str, float]:
    """``NAME=VALUE`` pairs from the command line."""
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise FlexlinkError(f"--set {item!r}: expected NAME=VALUE")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise FlexlinkError(f"--set {item!r}: {value!r} is not a number") from None
    return out


def set_start_values(instance, variables, values) -> None:
    """Set start values through an fmpy instance with the setter of each variable's type: ``setInteger`` for
    an Integer (``solver.order``), ``setReal`` otherwise.  ``variables``: the model description's variables
    (any iterable of fmpy ScalarVariables)."""
    by_name = {v.name: v for v in variables}
    for name, value in (values or {}).items():
        v = by_name[name]
        if v.type in ("Integer", "Enumeration"):
            instance.setInteger([v.valueReference], [int(value)])
        else:
            instance.setReal([v.valueReference], [float(value)])


def check_integer_values(variables, values, option: str = "--set") -> None:
    """An Integer variable (``solver.order``) takes whole numbers only: ``4.5`` is refused here, before fmpy
    would truncate it to 4."""
    by_name = {v.name: v for v in variables}
    for name, value in (values or {}).items():
        v = by_name.get(name)
        if v is not None and v.type in ("Integer", "Enumeration") and float(value) != int(float(value)):
            raise FlexlinkError(f"{option} {name}={value:g}: {name} is an Integer; give a whole number")


MAX_POINTS = 1_000_000   # communication points of one run: fmpy keeps them all (100 MB for a dozen outputs)


def check_run(stop_time: float, step: float | None, stop_option: str = "--stop-time",
              step_option: str = "--step") -> None:
    """Refuse a run that cannot end or cannot be stored before it starts: a stop time or step that is not a
    positive number, or so many communication steps (``--stop-time 0.01 --step 1e-12``: 10¹⁰) that the run
    would outlast the user and its results the memory. Without ``step``, fmpy keeps about 1000 points."""
    if not (np.isfinite(stop_time) and stop_time > 0):
        raise FlexlinkError(f"{stop_option} must be a positive number, got {stop_time}")
    if step is None:
        return
    if not (np.isfinite(step) and step > 0):
        raise FlexlinkError(f"{step_option} must be a positive number, got {step}")
    if stop_time / step > MAX_POINTS:
        raise FlexlinkError(f"{step_option} {step:g}: {stop_time / step:.3g} communication steps to {stop_time:g} s, "
                            f"more than {MAX_POINTS:,} (give a larger {step_option} or a shorter {stop_option})")


def simulate(fmu: str | os.PathLike, stop_time: float, *, step: float | None = None, inputs: np.ndarray | None = None,
             start_values: dict[str, float] | None = None, outputs: list[str] | None = None,
             interpolation: str = "linear", step_finished=None):
    """Co-simulate the FMU with fmpy (communication step ``step``) and return fmpy's structured result.

    ``interpolation`` of the ``inputs`` table between its rows: ``"linear"`` (fmpy's own) or ``"hold"``
    (:func:`hold_inputs`); either way the FMU receives the value at each communication point and holds it
    over the step (it does not interpolate inputs). ``step_finished(time, recorder)`` is called after every
    step (a progress bar)."""
    import fmpy
    from fmpy.fmi1 import FMICallException

    md = fmpy.read_model_description(str(fmu))
    names = {v.name: v for v in md.modelVariables}
    for name in start_values or {}:
        if name not in names:
            raise FlexlinkError(f"--set {name}: the FMU has no variable of that name")
        if names[name].causality not in ("parameter", "input"):
            raise FlexlinkError(f"--set {name}: only parameters and inputs can be set "
                                f"(it is an {names[name].causality})")
    check_integer_values(md.modelVariables, start_values)
    check_run(stop_time, step)
    if interpolation not in INTERPOLATIONS:
        raise FlexlinkError(f"--interpolation {interpolation}: expected one of {', '.join(INTERPOLATIONS)}")
    if inputs is not None and interpolation == "hold":
        inputs = hold_inputs(inputs)
    messages: list[str] = []
    refusals: list[str] = []

    def logger(component, instance, status, category, message):
        text = message.decode(errors="replace") if isinstance(message, bytes) else str(message)
        messages.append(text)
        if status >= 2:                     # fmi2Discard, fmi2Error, fmi2Fatal
            refusals.append(text)

    try:
        result = fmpy.simulate_fmu(str(fmu), stop_time=stop_time, output_interval=step, fmi_type="CoSimulation",
                                   start_values=start_values or {}, input=inputs, output=outputs,
                                   logger=logger, debug_logging=False, step_finished=step_finished)
        if refusals:                        # a discarded step ends fmpy's loop early, without an exception
            raise FlexlinkError(f"the FMU refused: {refusals[-1]}")
        return result
    except FMICallException as e:
        detail = messages[-1] if messages else str(e)
        raise FlexlinkError(f"the FMU refused: {detail}") from None
    finally:
        _install_router()


def write_csv(result: np.ndarray, path: str | os.PathLike, names: list[str] | None = None) -> None:
    """Time and ``names`` (every column of ``result`` for ``None``), every row, at full precision; ``path`` "-"
    is standard output."""
    import contextlib
    import sys

    names = ["time", *names] if names else result.dtype.names
    stdout = str(path) == "-"
    with contextlib.nullcontext(sys.stdout) if stdout else open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n") if stdout else csv.writer(f)
        w.writerow(names)
        for row in result:
            w.writerow([repr(float(row[n])) for n in names])


def variable_units(model_description) -> dict[str, str]:
    """Each variable's unit as the model description declares it (its own, else its type's; "" if none)."""
    units = {}
    for v in model_description.modelVariables:
        declared = getattr(v, "declaredType", None)
        units[v.name] = v.unit or (declared.unit if declared is not None and declared.unit else "") or ""
    return units


def choose_outputs(model_description, names: list[str] | None, option: str = "--output") -> list[str]:
    """The FMU's outputs (or inputs) named by the user (every output for ``None``), in the user's order; an
    unknown name is one error naming the closest outputs, so that a typo costs no run."""
    import difflib

    outputs = [v.name for v in model_description.modelVariables if v.causality == "output"]
    if not names:
        return outputs
    inputs = {v.name for v in model_description.modelVariables if v.causality == "input"}
    for name in names:
        if name not in outputs and name not in inputs:
            close = difflib.get_close_matches(name, outputs, n=4, cutoff=0.5)
            hint = f"did you mean {', '.join(close)}?" if close else f"its outputs are {', '.join(outputs[:12])}" + (
                ", …" if len(outputs) > 12 else "")
            raise FlexlinkError(f"{option} {name}: the FMU has no output of that name; {hint}")
    return list(dict.fromkeys(names))


def axis_label(name: str, units: dict[str, str]) -> str:
    unit = units.get(name, "")
    return f"{name}\n({unit})" if unit else f"{name}\n(no unit given)"


def plot_result(result: np.ndarray, path: str | os.PathLike, names: list[str] | None = None, title: str = "",
                units: dict[str, str] | None = None) -> None:
    """Write :func:`result_figure` to ``path``."""
    import matplotlib.pyplot as plt

    fig = result_figure(result, names, title, units)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def result_figure(result: np.ndarray, names: list[str] | None = None, title: str = "",
                  units: dict[str, str] | None = None):
    """One panel per signal against time, each y axis labelled with its unit (``units``: from
    :func:`variable_units`); without ``names``, the first six columns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = names or [n for n in result.dtype.names if n != "time"][:6]
    units = units or {}
    fig, axes = plt.subplots(len(names), 1, sharex=True, figsize=(8, 1.8 * len(names) + 0.6), squeeze=False)
    for ax, n in zip(axes[:, 0], names, strict=True):
        ax.plot(result["time"], result[n], lw=1.0)
        ax.set_ylabel(axis_label(n, units), rotation=0, ha="right", va="center", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig


_ROUTES: dict[int, object] = {}     # componentEnvironment key → the Python logger of one instance
_ROUTE_KEYS = itertools.count(1)
_ROUTER = None                        # the one ctypes logger fmpy's native proxy ever calls


def _route(environment, instance, status, category, message):
    logger = _ROUTES.get(environment or 0)
    if logger is not None:
        logger(environment, instance, status, category, message)


def _install_router() -> None:
    """Point fmpy's process-wide logger proxy back at our router (fmpy.simulate_fmu replaces it with a
    logger that dies with the call; a message after that would call freed memory)."""
    global _ROUTER
    from ctypes import byref

    from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

    if _ROUTER is None:
        _ROUTER = fmi2CallbackLoggerTYPE(_route)
    try:
        from fmpy.logging import addLoggerProxy
    except ImportError:   # older fmpy: no proxy, messages arrive unformatted
        return
    holder = fmi2CallbackFunctions()
    holder.logger = _ROUTER
    addLoggerProxy(byref(holder))


def logging_callbacks(logger):
    """fmi2CallbackFunctions whose messages reach ``logger(component, instance, status, category, message)``.

    fmpy's native proxy (which formats the FMU's printf-style messages) keeps a single, process-wide Python
    logger, so every instance is registered with one router that dispatches on ``componentEnvironment``.
    Keep the returned object alive while the instance lives; ``release_logging_callbacks`` ends the route."""
    from ctypes import byref, c_void_p

    from fmpy import calloc, free
    from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions

    _install_router()
    key = next(_ROUTE_KEYS)
    _ROUTES[key] = logger
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _ROUTER
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    callbacks.componentEnvironment = c_void_p(key)
    try:
        from fmpy.logging import addLoggerProxy

        addLoggerProxy(byref(callbacks))
    except ImportError:
        pass
    callbacks.route_key = key
    return callbacks


def release_logging_callbacks(callbacks) -> None:
    _ROUTES.pop(getattr(callbacks, "route_key", None), None)


# fmu_src/logging.c's logStatistics message, and the counters it holds
STATISTICS = re.compile(r"(\d+) SS22 steps, (\d+) Newton iterations, (\d+) factorisations, (\d+) residual")
STATISTICS_KEYS = ("steps", "newton_iterations", "factorisations", "residual_evaluations")


class SlaveRunner:
    """A step-by-step co-simulation loop with fmpy's ``FMU2Slave``, instantiated once (reset between runs).

    ``run(stop, comm_step, inputs=lambda t: {...}, start={...}, outputs=[...])`` sets the inputs at each
    communication point from ``inputs(t)`` and records the outputs; it returns ``{name: array}`` with
    ``"time"``.
    """

    def __init__(self, fmu: str | os.PathLike, instance_name: str = "flexlink", logging: bool = False):
        import fmpy
        from fmpy.fmi2 import FMU2Slave

        self.model_description = fmpy.read_model_description(str(fmu))
        self._unzipdir = fmpy.extract(str(fmu))
        self.vr = {v.name: v.valueReference for v in self.model_description.modelVariables}
        self.messages: list[str] = []

        def logger(component, instance, status, category, message):
            self.messages.append(message.decode(errors="replace") if isinstance(message, bytes) else str(message))

        self.slave = FMU2Slave(guid=self.model_description.guid, unzipDirectory=self._unzipdir,
                               modelIdentifier=self.model_description.coSimulation.modelIdentifier,
                               instanceName=instance_name)
        self._callbacks = logging_callbacks(logger)
        self.slave.instantiate(loggingOn=logging, callbacks=self._callbacks)
        self._fresh = True

    def run(self, stop: float, comm_step: float, *, inputs=None, start: dict[str, float] | None = None,
            outputs: list[str] | None = None) -> dict[str, np.ndarray]:
        s = self.slave
        if not self._fresh:
            s.reset()
        self._fresh = False
        set_start_values(s, self.model_description.modelVariables, start)
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.exitInitializationMode()
        outputs = outputs or [v.name for v in self.model_description.modelVariables if v.causality == "output"]
        out_vr = [self.vr[n] for n in outputs]
        n = int(round(stop / comm_step))
        rec = np.empty((n + 1, len(outputs)))
        times = np.arange(n + 1) * comm_step
        for k in range(n + 1):
            if inputs is not None:
                u = inputs(times[k])
                if u:
                    s.setReal([self.vr[name] for name in u], [float(x) for x in u.values()])
            rec[k] = s.getReal(out_vr)
            if k < n:
                s.doStep(currentCommunicationPoint=times[k], communicationStepSize=comm_step)
        result = {"time": times}
        result.update({name: rec[:, i] for i, name in enumerate(outputs)})
        return result

    def solver_statistics(self) -> dict[str, int]:
        """The integrator's counters of the run just made (SS22 steps, Newton iterations, factorisations,
        residual evaluations), read from the FMU's ``logStatistics`` message at fmi2Terminate; ends the run
        (the next ``run`` resets the instance).  Empty for an FMU without that category."""
        self.messages.clear()
        self.slave.setDebugLogging(True, ["logStatistics"])
        self.slave.terminate()
        self.slave.setDebugLogging(False, [])
        for message in reversed(self.messages):
            found = STATISTICS.search(message)
            if found:
                return {key: int(value) for key, value in zip(STATISTICS_KEYS, found.groups(), strict=True)}
        return {}

    def close(self) -> None:
        try:
            self.slave.terminate()
        except Exception:   # already terminated, or in error: freeing is what matters
            pass
        self.slave.freeInstance()
        release_logging_callbacks(self._callbacks)
        import shutil

        shutil.rmtree(self._unzipdir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
