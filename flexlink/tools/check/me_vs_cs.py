"""Check ``me-vs-cs``: the FMU run by fmpy in both interfaces and the trajectories compared.

The Model Exchange run is fmpy's: CVODE root-finds a sign change of the event indicators, then fmpy enters
Event Mode and iterates fmi2NewDiscreteStates before going back to Continuous-Time Mode (state events), and
stops at the time events the FMU announces.  The times of the state events located are reported.

The tolerance comes from what the FMU says about its Co-Simulation solver.  A flexlink FMU's CS is SS22
with a step the check sets (``solver.step``), so its own tolerances below apply.  Any other FMU says
nothing of its CS solver in FMI 2.0 (the Reference FMUs step with fixed explicit Euler), so its difference
is measured and reported, not judged, unless the user gives ``--tolerance`` (which applies to any FMU).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from flexlink.tools.check.findings import CheckResult, Finding, skipped
from flexlink.tools.check.fmu import Fmu

ME_VS_CS_TOLERANCE = 3e-2   # flexlink FMUs: max deviation / peak of each output
# Accelerations and the forces they make (units m/s2, rad/s2, N: tip accelerations, accelerometer,
# joint reaction forces) carry the undamped highest modes of FE beams, which neither integrator resolves
# at these settings: for a beam released under gravity (steel_beam_gravity) the tip accelerations differ
# by 28 % of the peak at a 2 µs SS22 step and 15 % at 0.5 µs, the reaction force by 17 % (positions,
# moments, torques: at most 1 %).
# They are compared after a moving average over ACCELERATION_AVERAGE output points (both runs alike): in ME
# they are read at CVODE's interpolated states, whose rounding-level error times the stiffness of the top
# modes is noise from one sample to the next (examples/fast_two_link.toml, smooth-step inputs: the shoulder's
# 2.8 mN transverse reaction jumps by 0.3 mN between samples in ME, is smooth in CS, 33 % of its peak
# apart unaveraged).
ME_VS_CS_ACCELERATION_TOLERANCE = 0.35
ACCELERATION_AVERAGE = 9
ACCELERATION_UNITS = ("m/s2", "rad/s2", "N")
SMALL_SIGNAL = 1e-3         # a signal's peak is taken as at least this fraction of the largest of its unit
FOREIGN_STOP = 10.0         # other FMUs: their default stop time, at most this


def _smooth_excitation(f: Fmu, stop: float, interval: float) -> tuple[dict, np.ndarray | None]:
    """The excitation of the runs: start values and fmpy's input table.

    flexlink FMUs: the inputs of ``Fmu.excitation`` reached by a smooth step s(t/stop) = τ³(10 − 15τ + 6τ²),
    sampled at the output points, instead of at once: a step at t = 0 rings every mode of the link, up to
    the top of its shape functions (16 kHz for examples/fast_two_link.toml), undamped by SS22 at Θ = ½, and
    two integrators sample that ringing at different phases after thousands of periods; the smooth step
    leaves those modes still.  Returns the start values (inputs at 0) and fmpy's input table (None without
    inputs).  An FMU without inputs (a pendulum hanging at rest) would compare rounding noise: its joints
    start at 0.5 rad/s instead.  Other FMUs: their excitation as constant start values, no table.
    """
    target = f.excitation()
    if not f.is_flexlink:
        return target, None
    if not target:
        return {n: 0.5 for n in f.vars if n.endswith(".initial_rate")}, None
    t = np.arange(0.0, stop + 0.5 * interval, interval)
    tau = np.clip(t / stop, 0.0, 1.0)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    table = np.zeros(len(t), dtype=[("time", float)] + [(n, float) for n in target])
    table["time"] = t
    for n, v in f.real_excitation().items():       # a flexlink FMU's excitation is all Real
        table[n] = v * s
    return {n: 0.0 for n in target}, table


def _simulate(f: Fmu, stop: float, interval: float, start: dict, ramp, cs_step: float, rtol: float,
              logs: dict[str, list[str]] | None = None):
    """The ME (fmpy's CVODE) and CS runs; what the FMU logs with a status above warning goes to ``logs``."""
    logs = {"ME": [], "CS": []} if logs is None else logs
    import fmpy
    import fmpy.sundials as sundials

    original: Any = sundials.CVodeSolver
    events: list[float] = []

    class _CVode(original):
        """fmpy's CVODE without its cap of 500 steps per output interval, noting the state events it locates.

        CVODE root-finds on the event indicators (the event iteration with fmi2NewDiscreteStates is fmpy's
        simulateME); the time of each state event it locates is noted.
        """

        def __init__(self, *args, **kwargs):
            kwargs["maxNumSteps"] = 10**7
            super().__init__(*args, **kwargs)

        def step(self, t, t_next):
            state_event, roots, t_reached = super().step(t, t_next)
            if state_event and np.any(roots != 0):
                events.append(float(t_reached))
            return state_event, roots, t_reached

    cs_start = {**start, "solver.step": cs_step} if f.is_flexlink else start

    def logger_of(interface):
        def logger(component, instance, status, category, message):
            if status > 1:                          # what the FMU said with fmi2Discard, fmi2Error, fmi2Fatal
                logs[interface].append(message.decode(errors="replace") if isinstance(message, bytes)
                                       else str(message))
        return logger

    def run(kind: str, fmi_type: str, **options):
        """The run of one interface by fmpy.

        FMI 2: on an instance whose messages reach ``logs`` through flexlink's logger router (fmpy's own
        ``logger=`` would register a process-wide callback that is freed after the run, and the next FMU to
        log would call it: a crash in a later check).
        """
        if f.fmi3:
            return fmpy.simulate_fmu(f.dir, fmi_type=fmi_type, model_description=f.md, **options)
        from flexlink.run.simulate import logging_callbacks, release_logging_callbacks

        inst = f.instance(kind, name="me-vs-cs")
        callbacks = logging_callbacks(logger_of(kind))
        try:
            inst.instantiate(callbacks=callbacks)
            return fmpy.simulate_fmu(f.dir, fmi_type=fmi_type, model_description=f.md, fmu_instance=inst,
                                     **options)
        finally:
            inst.freeInstance()
            release_logging_callbacks(callbacks)

    try:
        sundials.CVodeSolver = _CVode
        me = run("ME", "ModelExchange", solver="CVode", relative_tolerance=rtol, stop_time=stop,
                 output_interval=interval, start_values=start, input=ramp, record_events=False)
        cs = run("CS", "CoSimulation", stop_time=stop, output_interval=interval, start_values=cs_start,
                 input=ramp)
    finally:
        sundials.CVodeSolver = original
    return me, cs, events


def _last_said(f: Fmu, logs: list[str]) -> str:
    """What the FMU last logged with a status above warning (FMI 3 FMUs' messages are not collected)."""
    if logs:
        return logs[-1]
    return "its messages are not collected for FMI 3 FMUs" if f.fmi3 else "nothing logged"


def _ended_early(f: Fmu, runs: dict, logs: dict[str, list[str]], stop: float, interval: float) -> list[str]:
    """A line for each run that stopped before ``stop``, with the last thing the FMU said.

    fmpy ends a run quietly when the FMU discards a step: the reason is the finding, not the differing time
    grids it leaves.
    """
    lines = []
    for interface, run in runs.items():
        end = float(run["time"][-1]) if len(run) else 0.0
        if end < stop - 0.5 * interval:
            lines.append(f"the {interface} run ended at t = {end:.9g} of {stop:.9g} s; the FMU: "
                         f"{_last_said(f, logs[interface])}")
    return lines


def _compare(f: Fmu, me, cs, tolerance: float | None) -> tuple[list[Finding], list[str], float, str]:
    """Each numeric output's max |ME − CS| over its peak (see SMALL_SIGNAL), and the findings.

    A finding for each output beyond the tolerance (flexlink's own when ``tolerance`` is None on a flexlink
    FMU; none for other FMUs without one).
    """
    n = min(len(me), len(cs))
    names = [v.name for v in f.typed_outputs if v.type != "String"]

    def unit_of(name):
        v = f.vars[name]
        return v.unit or (v.declaredType.unit if v.declaredType is not None else "") or ""

    def column(r, name):
        return np.asarray(r[name][:n], float)

    peaks = {m: max(float(np.max(np.abs(column(me, m)), initial=0.0)), float(np.max(np.abs(column(cs, m)),
                                                                                      initial=0.0))) for m in names}
    family: dict[str, float] = {}
    for m, peak in peaks.items():
        if np.isfinite(peak):
            family[unit_of(m)] = max(family.get(unit_of(m), 0.0), peak)
    found, details, worst, worst_name = [], [], 0.0, "-"
    for m in names:
        a, b = column(me, m), column(cs, m)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            found.append(Finding("finite", f"{m}: NaN or infinite values"))
            continue
        unit = unit_of(m)
        averaged = f.is_flexlink and unit in ACCELERATION_UNITS
        if averaged:
            window = np.ones(ACCELERATION_AVERAGE) / ACCELERATION_AVERAGE
            a, b = np.convolve(a, window, mode="valid"), np.convolve(b, window, mode="valid")
        scale = max(peaks[m], SMALL_SIGNAL * family.get(unit, 0.0), 1e-12)
        err = float(np.max(np.abs(a - b), initial=0.0)) / scale
        details.append(f"{m}: max |ME - CS| / peak = {err:.2e}")
        if err > worst:
            worst, worst_name = err, m
        tol = tolerance
        if tol is None and f.is_flexlink:
            tol = ME_VS_CS_ACCELERATION_TOLERANCE if averaged else ME_VS_CS_TOLERANCE
        if tol is not None and err > tol:
            found.append(Finding("me-vs-cs", f"{m}: ME and CS differ by {err:.2e} of the peak (tolerance {tol})"))
    if not np.allclose(me["time"][:n], cs["time"][:n], rtol=0, atol=1e-9 * max(1.0, float(me["time"][-1]))):
        found.append(Finding("me-vs-cs", "time grids differ"))
    return found, details, worst, worst_name


def check_me_vs_cs(f: Fmu, stop_time: float | None = None, tolerance: float | None = None,
                   cs_step: float = 2e-6, rtol: float = 1e-9) -> CheckResult:
    """The check: both interfaces run by fmpy and compared (see docs/check.md, ME against CS)."""
    if not {"CS", "ME"} <= set(f.interfaces):
        return skipped("me-vs-cs", "needs both interfaces (declared or selected: " + (", ".join(f.interfaces)
                                                                                      or "none") + ")")
    t0 = time.perf_counter()
    default = float(f.md.defaultExperiment.stopTime or 0) if f.md.defaultExperiment else 0.0
    if f.is_flexlink:
        stop = stop_time or min(0.5, default or 0.5)
        # with inputs, a finer grid: fmpy moves them at these points only and holds them between
        interval = stop / (2000 if f.excitation() else 500)
    else:
        stop = stop_time or min(FOREIGN_STOP, default or 1.0)
        interval = stop / 500
        step = f.md.defaultExperiment.stepSize if f.md.defaultExperiment else None
        if step and not f.can("CS", "canHandleVariableCommunicationStepSize"):
            interval = float(step)            # fmpy's communication step is the output interval
    start, ramp = _smooth_excitation(f, stop, interval)
    inp = (", ".join(f"{k} 0 → {v}" for k, v in f.excitation().items()) + " (smooth step over the run)"
           if ramp is not None else ", ".join(f"{k} = {v}" for k, v in start.items()) or "no inputs")
    desc = f"0 .. {stop} s, {inp}"
    judged = (f"tolerance {tolerance} (--tolerance)" if tolerance is not None else
              "flexlink tolerances" if f.is_flexlink else "not judged: the FMU does not describe its CS solver")
    ref = (f"ME: CVODE rtol {rtol}; CS: " + (f"SS22 step {cs_step} s" if f.is_flexlink else "its own solver")
           + f"; {judged}")
    logs: dict[str, list[str]] = {"ME": [], "CS": []}
    try:
        me, cs, events = _simulate(f, stop, interval, start, ramp, cs_step, rtol, logs)
    except Exception as e:
        from flexlink.tools.check import isolation

        said = "; ".join(f"{k}: {_last_said(f, v)}" for k, v in logs.items() if v)
        why = f"{type(e).__name__}: {e}" + (f" (the FMU: {said})" if said else "")
        return CheckResult("me-vs-cs", desc, ref, why, seconds=time.perf_counter() - t0,
                           findings=[Finding("legal-call", f"a simulation failed: {why}",
                                             sequence=isolation.recent())])
    found, details, worst, worst_name = _compare(f, me, cs, tolerance)
    details[:0] = _ended_early(f, {"ME": me, "CS": cs}, logs, stop, interval)
    result = f"worst {worst_name}: {worst:.2e} of the peak" + (f"; {len(found)} failure(s)" if found else "")
    if f.nz:
        result += f"; ME: {len(events)} state event(s)"
        details.insert(0, f"ME: {len(events)} state event(s) located on {f.nz} event indicator(s)"
                          + (": t = " + ", ".join(f"{t:.9g}" for t in events[:20]) if events else ""))
    return CheckResult("me-vs-cs", desc, ref, result, seconds=time.perf_counter() - t0,
                       details=[x.message for x in found] + details, findings=found)
