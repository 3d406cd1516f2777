"""Running a flexlink FMU through fmpy: input files, start values, results as CSV and plots."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.run import INTERPOLATIONS
from flexlink.run.host import (  # noqa: F401  (logging_callbacks, set_start_values, ...: importable here)
    FmuHost,
    install_router,
    logging_callbacks,
    release_logging_callbacks,
    set_start_values,
)


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


def hold_inputs(table: np.ndarray) -> np.ndarray:
    """The input table as a staircase: each value held until the next row's time, where it jumps.

    fmpy interpolates a real input linearly between the rows of its table and treats two rows at the same
    time as a jump (an input event it steps to exactly); so a row (t_k, u_{k-1}) inserted before each
    (t_k, u_k) turns linear interpolation into a zero-order hold without touching fmpy.
    """
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


def check_integer_values(variables, values, option: str = "--set") -> None:
    """Refuse a value that is not whole for an Integer variable (``solver.order``).

    ``4.5`` is refused here, before fmpy would truncate it to 4.
    """
    by_name = {v.name: v for v in variables}
    for name, value in (values or {}).items():
        v = by_name.get(name)
        if v is not None and v.type in ("Integer", "Enumeration") and float(value) != int(float(value)):
            raise FlexlinkError(f"{option} {name}={value:g}: {name} is an Integer; give a whole number")


MAX_POINTS = 1_000_000   # communication points of one run: fmpy keeps them all (100 MB for a dozen outputs)


def check_run(stop_time: float, step: float | None, stop_option: str = "--stop-time",
              step_option: str = "--step") -> None:
    """Refuse a run that cannot end or cannot be stored before it starts.

    A stop time or step that is not a positive number, or so many communication steps (``--stop-time 0.01
    --step 1e-12``: 10¹⁰) that the run would outlast the user and its results the memory. Without ``step``,
    fmpy keeps about 1000 points.
    """
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
    step (a progress bar).
    """
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
        install_router()


def write_csv(result: np.ndarray, path: str | os.PathLike, names: list[str] | None = None) -> None:
    """Write time and ``names`` (every column of ``result`` for ``None``), every row, at full precision.

    ``path`` "-" is standard output.
    """
    import contextlib
    import sys

    columns = ["time", *names] if names else list(result.dtype.names or ())
    stdout = str(path) == "-"
    with contextlib.nullcontext(sys.stdout) if stdout else open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n") if stdout else csv.writer(f)
        w.writerow(columns)
        for row in result:
            w.writerow([repr(float(row[n])) for n in columns])


def variable_units(model_description) -> dict[str, str]:
    """Each variable's unit as the model description declares it (its own, else its type's; "" if none)."""
    units = {}
    for v in model_description.modelVariables:
        declared = getattr(v, "declaredType", None)
        units[v.name] = v.unit or (declared.unit if declared is not None and declared.unit else "") or ""
    return units


def choose_outputs(model_description, names: list[str] | None, option: str = "--output") -> list[str]:
    """The FMU's outputs (or inputs) named by the user (every output for ``None``), in the user's order.

    An unknown name is one error naming the closest outputs, so that a typo costs no run.
    """
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
    """A plot's y label: the signal's name over its unit, or a note that the FMU gives none."""
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
    """One panel per signal against time, each y axis labelled with its unit.

    ``units``: from :func:`variable_units`; without ``names``, the first six columns.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = names or [n for n in result.dtype.names or () if n != "time"][:6]
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


class SlaveRunner(FmuHost):
    """A step-by-step co-simulation loop on one :class:`~flexlink.run.host.FmuHost` (Co-Simulation).

    The FMU is instantiated once and reset between runs.

    ``run(stop, comm_step, inputs=lambda t: {...}, start={...}, outputs=[...])`` sets the inputs at each
    communication point from ``inputs(t)`` and records the outputs; it returns ``{name: array}`` with
    ``"time"``.  A refused call raises :class:`~flexlink.run.host.FmuCallError` with the FMU's reason.
    """

    def __init__(self, fmu: str | os.PathLike, instance_name: str = "flexlink", logging: bool = False):
        super().__init__(fmu, interface="CoSimulation", instance_name=instance_name, logging=logging)

    @property
    def slave(self):
        """The fmpy ``FMU2Slave`` (for loops that call it directly)."""
        return self.instance

    def run(self, stop: float, comm_step: float, *, inputs=None, start: dict[str, float] | None = None,
            outputs: list[str] | None = None) -> dict[str, np.ndarray]:
        """Initialise with ``start`` and step to ``stop``; the outputs at every communication point."""
        s = self.instance
        self.initialize(start)
        outputs = outputs or [v.name for v in self.model_description.modelVariables if v.causality == "output"]
        out_vr = [self.value_reference(n) for n in outputs]
        n = int(round(stop / comm_step))
        rec = np.empty((n + 1, len(outputs)))
        times = np.arange(n + 1) * comm_step
        for k in range(n + 1):
            if inputs is not None:
                u = inputs(times[k])
                if u:
                    self.call("fmi2SetReal", s.setReal, [self.value_reference(name) for name in u],
                              [float(x) for x in u.values()])
            rec[k] = self.call("fmi2GetReal", s.getReal, out_vr)
            if k < n:
                self.call("fmi2DoStep", s.doStep, times[k], comm_step)
        result = {"time": times}
        result.update({name: rec[:, i] for i, name in enumerate(outputs)})
        return result
