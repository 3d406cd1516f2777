"""``flexlink check OUT.fmu``: a compliance harness for any FMU flexlink builds.

Like fmpy's validation it collects problems instead of stopping at the first one; every check gives a
row in the style of the FMI cross-check results (input, reference, result, status):

a. ``model-description``: fmpy's schema and semantic validation, plus what it does not notice: every
   value reference of the XML read back through the binary, every output in ``<Outputs>``, every
   ``derivative=`` state in ``<Derivatives>``.
b. ``me-vs-cs``: the FMU run by fmpy in both interfaces — Model Exchange with CVODE at tight
   tolerances, Co-Simulation with a small SS22 step — and the trajectories compared.
c. ``fuzz``: seeded random legal call sequences (each must succeed) and a catalogue of illegal calls
   (each must return fmi2Error and leave an instance that ``fmi2Reset`` revives), in a child process
   so that a crash is reported, not fatal.
d. ``fmu-state``: get/set/serialize round trips (bit for bit) and reset, in both interfaces.
e. ``directional-derivatives``: ``fmi2GetDirectionalDerivative`` against central finite differences
   (Model Exchange: derivatives and outputs w.r.t. states and inputs; Co-Simulation: outputs w.r.t.
   inputs).
f. ``libcosim``, ``fmutool``: the independent importers of :mod:`flexlink.tools.importers`.

The fuzz size is small by default (CI); the full-size run is ``flexlink check OUT.fmu --fuzz 5000``.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["CI_FUZZ", "CheckResult", "check_fmu", "write_report"]

CI_FUZZ = 60          # random legal sequences per interface by default
ME_VS_CS_TOLERANCE = 3e-2   # max deviation / peak of each output
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
FD_TOLERANCE = 1e-5         # directional derivative vs central differences, relative to the column

OK, WARNING, DISCARD, ERROR, FATAL = range(5)


@dataclass
class CheckResult:
    name: str
    input: str
    reference: str
    result: str
    status: str                    # pass | fail | skip
    seconds: float = 0.0
    details: list[str] = field(default_factory=list)


# ====================================================================== the FMU through fmpy

class _Fmu:
    """The unzipped FMU, its model description and value references by name."""

    def __init__(self, path: str | os.PathLike):
        import fmpy

        self.path = os.fspath(path)
        self.dir = tempfile.mkdtemp(prefix="flexlink-check-")
        fmpy.extract(self.path, self.dir)
        self.md = fmpy.read_model_description(self.path, validate=False)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.outputs = [v.name for v in self.md.modelVariables if v.causality == "output"]
        self.inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]
        self.tunable = [v.name for v in self.md.modelVariables if v.causality == "parameter"
                        and v.variability == "tunable"]
        self.states = [u.variable.derivative.name for u in self.md.derivatives]
        self.derivatives = [u.variable.name for u in self.md.derivatives]
        self.nx = len(self.derivatives)
        self.identifier = (self.md.coSimulation or self.md.modelExchange).modelIdentifier

    def close(self):
        shutil.rmtree(self.dir, ignore_errors=True)

    def instance(self, kind: str, name: str = "check"):
        from fmpy.fmi2 import FMU2Model, FMU2Slave

        cls = FMU2Model if kind == "ME" else FMU2Slave
        ident = (self.md.modelExchange if kind == "ME" else self.md.coSimulation).modelIdentifier
        return cls(guid=self.md.guid, unzipDirectory=self.dir, modelIdentifier=ident, instanceName=name)


def _quiet_callbacks():
    """fmi2 callbacks that drop the FMU's messages (the checks read statuses, not log lines), through
    flexlink's one logger router: fmpy's native logger proxy is process-wide, and a logger of our own
    registered there would be called after it is freed by whichever FMU logs next (a segfault)."""
    from flexlink.run.simulate import logging_callbacks

    return logging_callbacks(lambda *message: None)


def _call(fn, *args):
    """Status of an fmpy call (fmpy raises on error and discard)."""
    from fmpy.fmi1 import FMICallException

    try:
        fn(*args)
        return OK
    except FMICallException as e:
        return int(e.status)


def _start(inst, kind: str, start: dict[str, float] | None = None, stop: float | None = None):
    inst.instantiate(callbacks=_quiet_callbacks())
    for name, value in (start or {}).items():
        inst.setReal([inst_vr(inst, name)], [value])
    inst.setupExperiment(startTime=0.0, stopTime=stop)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    if kind == "ME":
        inst.newDiscreteStates()
        inst.enterContinuousTimeMode()


def inst_vr(inst, name: str) -> int:
    return inst._vr[name]


def _instance(f: _Fmu, kind: str, name: str = "check"):
    inst = f.instance(kind, name)
    inst._vr = f.vr
    return inst


def _free(inst):
    """Free the instance but keep the library loaded (fmpy's freeInstance also unloads it)."""
    inst.fmi2FreeInstance(inst.component)
    inst.component = None


# ================================================================== a. model description

def check_model_description(f: _Fmu) -> CheckResult:
    from fmpy.validation import validate_fmu

    t0 = time.perf_counter()
    problems = list(validate_fmu(f.path))
    root = ET.parse(os.path.join(f.dir, "modelDescription.xml")).getroot()
    variables = root.find("ModelVariables").findall("ScalarVariable")
    structure = root.find("ModelStructure")
    listed = {int(u.get("index")) for u in structure.find("Outputs") or []}
    for i, v in enumerate(variables, 1):
        if v.get("causality") == "output" and i not in listed:
            problems.append(f"output {v.get('name')} (index {i}) is missing from <ModelStructure><Outputs>")
    ders = structure.find("Derivatives")
    listed_d = {int(u.get("index")) for u in (ders if ders is not None else [])}
    for i, v in enumerate(variables, 1):
        real = v.find("Real")
        if real is not None and real.get("derivative") and i not in listed_d:
            problems.append(f"derivative {v.get('name')} (index {i}) is missing from <ModelStructure><Derivatives>")
    # every value reference through the binary, in both interfaces
    for kind in ("CS", "ME"):
        try:
            inst = _instance(f, kind)
            inst.instantiate(callbacks=_quiet_callbacks())
            inst.setupExperiment(startTime=0.0)
            inst.enterInitializationMode()
            inst.exitInitializationMode()
            for name, v in f.vars.items():
                if v.type != "Real":
                    continue
                if _call(inst.getReal, [v.valueReference]) > WARNING:
                    problems.append(f"{kind}: value reference {v.valueReference} of {name} is refused by the binary")
            _free(inst)
        except Exception as e:    # a library that does not load, a GUID that differs, ...
            problems.append(f"{kind}: {type(e).__name__}: {e}")
    return CheckResult("model-description", "modelDescription.xml", "fmpy validation; value references, "
                       "ModelStructure", f"{len(problems)} problem(s)", "fail" if problems else "pass",
                       time.perf_counter() - t0, problems)


# ======================================================================== b. ME vs CS

def _excitation(f: _Fmu) -> dict[str, float]:
    """A constant excitation of the inputs (prescribed-law inputs stay at their start)."""
    return {n: 0.1 for n in f.inputs if not n.endswith(("_ref",))}


def _smooth_excitation(f: _Fmu, stop: float, interval: float) -> tuple[dict[str, float], np.ndarray | None]:
    """The inputs of ``_excitation`` reached by a smooth step s(t/stop) = τ³(10 − 15τ + 6τ²), sampled at the
    output points, instead of at once: a step at t = 0 rings every mode of the link, up to the top of its
    shape functions (16 kHz for examples/fast_two_link.toml), undamped by SS22 at Θ = ½, and two
    integrators sample that ringing at different phases after thousands of periods; the smooth step
    leaves those modes still, so the comparison is about the motion both resolve.  Returns the start values
    (inputs at 0) and fmpy's input table (None without inputs).  An FMU without inputs (a pendulum hanging at
    rest) would compare rounding noise: its joints start at 0.5 rad/s instead."""
    target = _excitation(f)
    if not target:              # nothing to drive: the joints start turning instead of resting in equilibrium
        return {n: 0.5 for n in f.vars if n.endswith(".initial_rate")}, None
    t = np.arange(0.0, stop + 0.5 * interval, interval)
    tau = np.clip(t / stop, 0.0, 1.0)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    table = np.zeros(len(t), dtype=[("time", float)] + [(n, float) for n in target])
    table["time"] = t
    for n, v in target.items():
        table[n] = v * s
    return {n: 0.0 for n in target}, table


def check_me_vs_cs(f: _Fmu, stop_time: float | None = None, cs_step: float = 2e-6,
                   rtol: float = 1e-9) -> CheckResult:
    import fmpy
    import fmpy.sundials as sundials

    t0 = time.perf_counter()
    stop = stop_time or min(0.5, float(f.md.defaultExperiment.stopTime or 0.5) if f.md.defaultExperiment else 0.5)
    # with inputs, a finer grid: fmpy moves them at these points only and holds them between
    interval = stop / (2000 if _excitation(f) else 500)
    start, ramp = _smooth_excitation(f, stop, interval)
    original = sundials.CVodeSolver

    class _CVode(original):                    # fmpy caps CVODE at 500 steps per output interval
        def __init__(self, *args, **kwargs):
            kwargs["maxNumSteps"] = 10**7
            super().__init__(*args, **kwargs)

    details: list[str] = []
    inp = (", ".join(f"{k} 0 → {v}" for k, v in _excitation(f).items()) + " (smooth step over the run)"
           if ramp is not None else ", ".join(f"{k} = {v}" for k, v in start.items()) or "no inputs")
    desc = f"0 .. {stop} s, {inp}"
    ref = f"ME: CVODE rtol {rtol}; CS: SS22 step {cs_step} s"
    try:
        sundials.CVodeSolver = _CVode
        me = fmpy.simulate_fmu(f.dir, fmi_type="ModelExchange", solver="CVode", relative_tolerance=rtol,
                               stop_time=stop, output_interval=interval, start_values=start, input=ramp,
                               model_description=f.md, record_events=False)
        cs = fmpy.simulate_fmu(f.dir, fmi_type="CoSimulation", stop_time=stop, output_interval=interval,
                               start_values={**start, "solver.step": cs_step}, input=ramp,
                               model_description=f.md)
    except Exception as e:
        return CheckResult("me-vs-cs", desc, ref, f"{type(e).__name__}: {e}", "fail", time.perf_counter() - t0)
    finally:
        sundials.CVodeSolver = original
    worst, worst_name, bad = 0.0, "", []
    n = min(len(me), len(cs))

    def unit_of(name):
        return f.vars[name].unit or (f.vars[name].declaredType.unit if f.vars[name].declaredType else "")

    # A signal far below the others of its unit (the out-of-plane reaction of a planar motion, a barely
    # excited high mode) is judged against a thousandth of its kind's peak: otherwise the integrators'
    # absolute tolerances (CVODE's atol) would be read as relative errors of a signal that is round-off.
    peaks = {name: max(float(np.max(np.abs(np.asarray(me[name][:n], float)))),
                       float(np.max(np.abs(np.asarray(cs[name][:n], float))))) for name in f.outputs}
    family: dict[str, float] = {}
    for name, peak in peaks.items():
        if np.isfinite(peak):
            family[unit_of(name)] = max(family.get(unit_of(name), 0.0), peak)
    for name in f.outputs:
        a, b = np.asarray(me[name][:n], float), np.asarray(cs[name][:n], float)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            bad.append(f"{name}: NaN or infinite values")
            continue
        unit = unit_of(name)
        if unit in ACCELERATION_UNITS:
            window = np.ones(ACCELERATION_AVERAGE) / ACCELERATION_AVERAGE
            a, b = np.convolve(a, window, mode="valid"), np.convolve(b, window, mode="valid")
        scale = max(peaks[name], SMALL_SIGNAL * family.get(unit, 0.0), 1e-12)
        err = float(np.max(np.abs(a - b))) / scale
        details.append(f"{name}: max |ME - CS| / peak = {err:.2e}")
        if err > worst:
            worst, worst_name = err, name
        tol = ME_VS_CS_ACCELERATION_TOLERANCE if unit in ACCELERATION_UNITS else ME_VS_CS_TOLERANCE
        if err > tol:
            bad.append(f"{name}: ME and CS differ by {err:.2e} of the peak (tolerance {tol})")
    if not np.allclose(me["time"][:n], cs["time"][:n], rtol=0, atol=1e-9 * max(1.0, stop)):
        bad.append("time grids differ")
    result = f"worst {worst_name}: {worst:.2e} of the peak" + (f"; {len(bad)} failure(s)" if bad else "")
    return CheckResult("me-vs-cs", desc, ref, result, "fail" if bad else "pass", time.perf_counter() - t0,
                       bad + details)


# ===================================================================== c. fuzzing (child)

def _fuzz(path: str, n: int, seed: int) -> dict:
    """Random legal sequences and the illegal catalogue, in this process (the child's job)."""
    fuzzer = _Fuzzer(_Fmu(path), seed)
    try:
        for k in range(n):
            fuzzer.legal_sequence("CS" if k % 2 == 0 else "ME")
        n_illegal = fuzzer.illegal_calls()
        fuzzer.wrong_guid()
    finally:
        fuzzer.f.close()
    failures = fuzzer.failures
    return {"sequences": n, "illegal": n_illegal + 1, "calls": fuzzer.calls, "failures": failures[:50],
            "n_failures": len(failures)}


class _Fuzzer:
    """One CS and one ME instance of the FMU, re-instantiated for each sequence; every call's status is
    checked against what the standard allows and the surprises are collected in ``failures``."""

    LEGAL = (OK, WARNING)

    def __init__(self, f: _Fmu, seed: int):
        self.f = f
        self.rng = np.random.default_rng(seed)
        self.failures: list[str] = []
        self.calls = 0
        self.outputs = [f.vr[n] for n in f.outputs]
        self.inputs = [f.vr[n] for n in f.inputs]
        self.tunable = [f.vr[n] for n in f.tunable]
        self.tunable_start = [float(f.vars[n].start) for n in f.tunable]
        # an array parameter (name[1], name[2], ...) is scaled as a whole: relations between its entries,
        # which an FMU may enforce (an inertia tensor must stay a body's), survive a common factor
        groups: dict[str, list[int]] = {}
        for k, n in enumerate(f.tunable):
            groups.setdefault(n.split("[", 1)[0], []).append(k)
        self.tunable_groups = list(groups.values())
        self.states = [f.vr[n] for n in f.states]
        self.ders = [f.vr[n] for n in f.derivatives]
        self.insts = {k: _instance(f, k, f"fuzz{k}") for k in ("CS", "ME")}

    def expect(self, ok_statuses, status, what: str) -> None:
        self.calls += 1
        if status not in ok_statuses:
            self.failures.append(f"{what}: status {status}")

    def fresh(self, kind: str):
        inst = self.insts[kind]
        inst.instantiate(callbacks=_quiet_callbacks())
        return inst

    def init(self, inst, kind: str) -> None:
        legal = self.LEGAL
        self.expect(legal, _call(inst.setupExperiment, None, 0.0, None), "setupExperiment")
        self.expect(legal, _call(inst.enterInitializationMode), "enterInitializationMode")
        self.expect(legal, _call(inst.exitInitializationMode), "exitInitializationMode")
        if kind == "ME":
            self.expect(legal, _call(inst.newDiscreteStates), "newDiscreteStates")
            self.expect(legal, _call(inst.enterContinuousTimeMode), "enterContinuousTimeMode")

    def _scaled_tunable(self, inst, what: str) -> None:
        group = self.tunable_groups[int(self.rng.integers(len(self.tunable_groups)))]
        factor = self.rng.uniform(0.8, 1.25)
        self.expect(self.LEGAL, _call(inst.setReal, [self.tunable[j] for j in group],
                                      [self.tunable_start[j] * factor for j in group]), what)

    def legal_sequence(self, kind: str) -> None:
        """Instantiate, maybe change a parameter, initialise, 3 to 14 random legal operations, maybe reset,
        terminate, free."""
        inst = self.fresh(kind)
        if self.tunable and self.rng.random() < 0.5:
            self._scaled_tunable(inst, "setReal(parameter) before init")
        self.init(inst, kind)
        t = 0.0
        for _ in range(int(self.rng.integers(3, 15))):
            t = self._random_operation(inst, kind, t)
        if self.rng.random() < 0.2:
            self.expect(self.LEGAL, _call(inst.reset), "reset")
            self.init(inst, kind)
        self.expect(self.LEGAL, _call(inst.terminate), "terminate")
        _free(inst)

    def _random_operation(self, inst, kind: str, t: float) -> float:
        """One legal operation chosen at random; returns the time reached."""
        legal, rng = self.LEGAL, self.rng
        op = rng.integers(7)
        if op == 0 and kind == "CS":
            h = float(rng.uniform(1e-4, 2e-2))
            status = _call(inst.doStep, t, h)
            self.expect(legal + (DISCARD,), status, f"doStep({t}, {h})")
            return t + h if status == OK else t
        if op == 0:
            return self._model_exchange_step(inst, t + float(rng.uniform(1e-4, 2e-2)))
        if op == 1:
            n = min(len(self.outputs), int(rng.integers(1, 6)))
            sel = list(rng.choice(self.outputs, size=n, replace=False))
            self.expect(legal, _call(inst.getReal, [int(s) for s in sel]), "getReal(outputs)")
        elif op == 2 and self.inputs:
            self.expect(legal, _call(inst.setReal, [self.inputs[0]], [float(rng.uniform(-1, 1))]), "setReal(input)")
        elif op == 3 and self.tunable and kind == "CS":
            self._scaled_tunable(inst, "setReal(tunable)")
        elif op == 4:
            self._state_round_trip(inst)
        elif op == 5:
            known = (self.states if kind == "ME" else []) + self.inputs
            if known:
                unknown = [int(u) for u in (self.ders if kind == "ME" else []) + self.outputs]
                kv = [int(known[int(rng.integers(len(known)))])]
                self.expect(legal, _call(inst.getDirectionalDerivative, unknown, kv, [1.0]),
                            "getDirectionalDerivative")
        elif op == 6 and kind == "ME":
            self.expect(legal, _call(inst.enterEventMode), "enterEventMode")
            self.expect(legal, _call(inst.newDiscreteStates), "newDiscreteStates")
            self.expect(legal, _call(inst.enterContinuousTimeMode), "enterContinuousTimeMode")
        return t

    def _model_exchange_step(self, inst, t: float) -> float:
        """What an integrator does: time, states slightly moved, derivatives, step completed (which may
        discard a state outside the model's validity)."""
        nx, legal = self.f.nx, self.LEGAL
        self.expect(legal, _call(inst.setTime, t), "setTime")
        x = np.zeros(nx)
        self.expect(legal, _call(inst.getContinuousStates, _c_doubles(x), nx), "getContinuousStates")
        x += 1e-4 * self.rng.standard_normal(nx)
        self.expect(legal, _call(inst.setContinuousStates, _c_doubles(x), nx), "setContinuousStates")
        dx = np.zeros(nx)
        self.expect(legal, _call(inst.getDerivatives, _c_doubles(dx), nx), "getDerivatives")
        self.expect(legal + (DISCARD,), _call(inst.completedIntegratorStep), "completedIntegratorStep")
        return t

    def _state_round_trip(self, inst) -> None:
        try:
            s = inst.getFMUstate()
            data = inst.serializeFMUstate(s)
            s2 = inst.deSerializeFMUstate(data)
            inst.setFMUstate(s2)
            inst.freeFMUstate(s)
            inst.freeFMUstate(s2)
            self.calls += 6
        except Exception as e:
            self.failures.append(f"FMU state round trip: {e}")

    def illegal_calls(self) -> int:
        """Each call of the catalogue on a fresh instance: fmi2Error expected, then fmi2Reset must work."""
        catalogue = _illegal_catalogue(self.f, self.outputs, self.inputs, self.tunable, self.states, self.ders)
        for name, kind, setup, call in catalogue:
            inst = self.fresh(kind)
            if setup == "init":
                self.init(inst, kind)
            status = _call(call, inst)
            self.calls += 1
            if status != ERROR:
                self.failures.append(f"illegal call '{name}' ({kind}): expected fmi2Error (3), got {status}")
            # the instance is now in the error state: only reset brings it back
            if _call(inst.reset) != OK:
                self.failures.append(f"after '{name}' ({kind}): fmi2Reset failed")
            else:
                self.init(inst, kind)
            _free(inst)
        return len(catalogue)

    def wrong_guid(self) -> None:
        """An instance with a wrong GUID is refused."""
        from fmpy.fmi2 import FMU2Slave

        wrong = FMU2Slave(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=self.f.dir,
                          modelIdentifier=self.f.identifier, instanceName="wrong")
        try:
            wrong.instantiate(callbacks=_quiet_callbacks())
            self.failures.append("an instance with a wrong GUID was created")
        except Exception:
            pass


def _c_doubles(x: np.ndarray):
    return x.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _illegal_catalogue(f: _Fmu, outputs, inputs, tunable, states, ders) -> list[tuple]:
    """(name, interface, "init" or None, call): calls the standard forbids here, each of which must give
    fmi2Error."""
    bad_vr = 10**6
    catalogue = []

    def illegal(name, kind, setup, call):
        catalogue.append((name, kind, setup, call))

    nan = float("nan")
    c_arr = ctypes.c_double * max(f.nx, 1)
    illegal("doStep before initialization", "CS", None, lambda i: i.doStep(0.0, 0.01))
    illegal("exitInitializationMode without enter", "CS", None, lambda i: i.exitInitializationMode())
    illegal("getReal of an unknown value reference", "CS", "init", lambda i: i.getReal([bad_vr]))
    illegal("setReal of an unknown value reference", "CS", "init", lambda i: i.setReal([bad_vr], [1.0]))
    illegal("setReal of an output", "CS", "init", lambda i: i.setReal([outputs[0]], [1.0]))
    if inputs:
        illegal("setReal(input) = NaN", "CS", "init", lambda i: i.setReal([inputs[0]], [nan]))
        illegal("setReal(input) = inf", "ME", "init", lambda i: i.setReal([inputs[0]], [math.inf]))
    if tunable:
        illegal("setReal(parameter) = NaN", "CS", None, lambda i: i.setReal([tunable[0]], [nan]))
        lows = [n_ for n_ in f.tunable if f.vars[n_].min is not None and float(f.vars[n_].min) >= 0]
        if lows:
            illegal(f"setReal({lows[0]}) negative", "CS", None, lambda i: i.setReal([f.vr[lows[0]]], [-1.0]))
            illegal(f"setReal({lows[0]}) in continuous-time mode", "ME", "init",
                    lambda i: i.setReal([f.vr[lows[0]]], [float(f.vars[lows[0]].start)]))
    illegal("solver.step = 0", "CS", None, lambda i: i.setReal([f.vr["solver.step"]], [0.0]))
    illegal("solver.theta1 out of range", "CS", None, lambda i: i.setReal([f.vr["solver.theta1"]], [1.5]))
    illegal("fixed parameter set after initialization", "CS", "init",
            lambda i: i.setReal([f.vr["solver.step"]], [1e-3]))
    illegal("doStep with a zero step", "CS", "init", lambda i: i.doStep(0.0, 0.0))
    illegal("doStep with a negative step", "CS", "init", lambda i: i.doStep(0.0, -0.01))
    illegal("doStep with a NaN step", "CS", "init", lambda i: i.doStep(0.0, nan))
    illegal("doStep at the wrong communication point", "CS", "init", lambda i: i.doStep(1.0, 0.01))
    illegal("getDirectionalDerivative w.r.t. an output", "CS", "init",
            lambda i: i.getDirectionalDerivative([outputs[0]], [outputs[0]], [1.0]))
    illegal("getDirectionalDerivative with a NaN seed", "ME", "init",
            lambda i: i.getDirectionalDerivative([ders[0]], [states[0]], [nan]))
    illegal("Model Exchange function on a Co-Simulation instance", "CS", "init",
            lambda i: _raw(i, "fmi2SetTime", [ctypes.c_double], 0.1))
    illegal("setContinuousStates with NaN", "ME", "init",
            lambda i: i.setContinuousStates(c_arr(*([nan] * f.nx)), f.nx))
    illegal("setContinuousStates with the wrong nx", "ME", "init",
            lambda i: i.setContinuousStates(c_arr(*([0.0] * f.nx)), f.nx + 1))
    illegal("getDerivatives before initialization", "ME", None,
            lambda i: i.getDerivatives(c_arr(*([0.0] * f.nx)), f.nx))
    illegal("setTime NaN", "ME", "init", lambda i: i.setTime(nan))
    illegal("newDiscreteStates in continuous-time mode", "ME", "init", lambda i: i.newDiscreteStates())
    illegal("enterContinuousTimeMode in continuous-time mode", "ME", "init", lambda i: i.enterContinuousTimeMode())
    illegal("doStep on a Model Exchange instance", "ME", "init",
            lambda i: _raw(i, "fmi2DoStep", [ctypes.c_double, ctypes.c_double, ctypes.c_int], 0.0, 0.01, 1))
    illegal("deserialize garbage", "CS", "init", lambda i: i.deSerializeFMUstate(bytes(64)))
    illegal("terminate before initialization", "ME", None, lambda i: i.terminate())
    return catalogue


def _raw(inst, function: str, argtypes: list, *args) -> None:
    """Call an FMI function that fmpy does not bind for this interface; raise on a bad status."""
    from fmpy.fmi1 import FMICallException

    fn = getattr(inst.dll, function)
    fn.argtypes = [ctypes.c_void_p, *argtypes]
    fn.restype = ctypes.c_int
    status = fn(inst.component, *args)
    if status != OK:
        raise FMICallException(function, status)


def check_fuzz(f: _Fmu, n: int = CI_FUZZ, seed: int = 0, timeout: float = 1800) -> CheckResult:
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "flexlink.tools.check", "--fuzz-child", f.path, str(n), str(seed)]
    inp = f"{n} random legal sequences (seed {seed}) + the illegal catalogue, in a child process"
    ref = "legal: fmi2OK/fmi2Warning (doStep may discard); illegal: fmi2Error, then fmi2Reset works"
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return CheckResult("fuzz", inp, ref, f"timed out after {timeout} s", "fail", time.perf_counter() - t0)
    line = [x for x in p.stdout.splitlines() if x.startswith("FUZZ ")]
    if p.returncode != 0 or not line:
        why = f"signal {-p.returncode}" if p.returncode < 0 else f"exit status {p.returncode}"
        return CheckResult("fuzz", inp, ref, f"the child process crashed ({why})", "fail", time.perf_counter() - t0,
                           (p.stdout + p.stderr).splitlines()[-20:])
    data = json.loads(line[-1][5:])
    res = (f"{data['sequences']} sequences, {data['illegal']} illegal calls, {data['calls']} calls, "
           f"{data['n_failures']} failure(s), no crash")
    return CheckResult("fuzz", inp, ref, res, "fail" if data["n_failures"] else "pass", time.perf_counter() - t0,
                       data["failures"])


# =================================================================== d. FMU state

def check_fmu_state(f: _Fmu) -> CheckResult:
    t0 = time.perf_counter()
    problems: list[str] = []
    outs = [f.vr[n] for n in f.outputs]
    start = _excitation(f)
    try:
        # Co-Simulation: get at t1, run, set back, run again: bit for bit; serialized likewise
        inst = _instance(f, "CS")
        _start(inst, "CS", start)
        h, t = 1e-3, 0.0
        for _ in range(5):
            inst.doStep(t, h)
            t += h
        s = inst.getFMUstate()
        data = inst.serializeFMUstate(s)

        def run(t):
            for _ in range(10):
                inst.doStep(t, h)
                t += h
            return np.array(inst.getReal(outs))

        y1 = run(t)
        inst.setFMUstate(s)
        y2 = run(t)
        s2 = inst.deSerializeFMUstate(data)
        inst.setFMUstate(s2)
        y3 = run(t)
        if not np.array_equal(y1, y2):
            problems.append("CS: get/set FMU state does not reproduce the run bit for bit")
        if not np.array_equal(y1, y3):
            problems.append("CS: serialize/deserialize does not reproduce the run bit for bit")
        inst.freeFMUstate(s)
        inst.freeFMUstate(s2)
        inst.reset()
        for name, value in start.items():
            inst.setReal([f.vr[name]], [value])
        inst.setupExperiment(startTime=0.0)
        inst.enterInitializationMode()
        inst.exitInitializationMode()
        y_reset = np.array(inst.getReal(outs))
        fresh = _instance(f, "CS", "fresh")
        _start(fresh, "CS", start)
        y_fresh = np.array(fresh.getReal(outs))
        if not np.array_equal(y_reset, y_fresh):
            problems.append("CS: after fmi2Reset the outputs differ from a fresh instance's")
        _free(fresh)
        _free(inst)
        # Model Exchange: states survive a round trip through a serialized FMU state
        me = _instance(f, "ME")
        _start(me, "ME", start)
        x = np.zeros(f.nx)
        ptr = x.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        me.getContinuousStates(ptr, f.nx)
        x0 = x.copy()
        s = me.getFMUstate()
        data = me.serializeFMUstate(s)
        me.setTime(0.01)
        me.setContinuousStates((x0 + 1e-3).ctypes.data_as(ctypes.POINTER(ctypes.c_double)), f.nx)
        s2 = me.deSerializeFMUstate(data)
        me.setFMUstate(s2)
        me.getContinuousStates(ptr, f.nx)
        if not np.array_equal(x, x0):
            problems.append("ME: serialized FMU state does not restore the continuous states")
        me.freeFMUstate(s)
        me.freeFMUstate(s2)
        _free(me)
    except Exception as e:
        problems.append(f"{type(e).__name__}: {e}")
    return CheckResult("fmu-state", "get/set/serialize after 5 steps of 1 ms; reset", "bit-for-bit equal runs",
                       "ok" if not problems else f"{len(problems)} problem(s)", "fail" if problems else "pass",
                       time.perf_counter() - t0, problems)


# ======================================================= e. directional derivatives vs FD

def directional_jacobian(inst, unknown: list[int], known: list[int]) -> np.ndarray:
    """∂unknown/∂known by one fmi2GetDirectionalDerivative call per known."""
    J = np.zeros((len(unknown), len(known)))
    for j, k in enumerate(known):
        J[:, j] = inst.getDirectionalDerivative(unknown, [k], [1.0])
    return J


class _InputProbe:
    """Unknowns read with one input offset by d from its value u0 (restored afterwards)."""

    def __init__(self, inst, vr: int, u0: float, read):
        self.inst, self.vr, self.u0, self.read = inst, vr, u0, read
        self.step = 1e-5 * max(abs(u0), 1.0)

    def __call__(self, d: float) -> np.ndarray:
        self.inst.setReal([self.vr], [self.u0 + d])
        try:
            return self.read()
        finally:
            self.inst.setReal([self.vr], [self.u0])


# Central differences are taken with the knowns' steps × each factor: an analytic unknown agrees with its
# directional derivative at one of them at least, where neither truncation (∝ h²) nor rounding (∝ 1/h, large
# for an unknown that is a small difference of large terms, e.g. a reaction about a free joint's axis) dominates.
FD_STEP_FACTORS = (1.0, 10.0, 100.0)


def _central_differences(g, steps: list[float]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per factor of FD_STEP_FACTORS: the quotients (g(j, h) − g(j, −h)) / 2h, one column per known j, with
    h = factor × steps[j], and the same with 2h (their difference is the reference's own error estimate)."""
    pairs = []
    for factor in FD_STEP_FACTORS:
        hs = [factor * h for h in steps]
        F = [(g(j, h) - g(j, -h)) / (2 * h) for j, h in enumerate(hs)]
        F2 = [(g(j, 2 * h) - g(j, -2 * h)) / (4 * h) for j, h in enumerate(hs)]
        pairs.append((np.array(F).T, np.array(F2).T))
    return pairs


def check_directional_derivatives(f: _Fmu, seed: int = 1) -> CheckResult:
    t0 = time.perf_counter()
    problems: list[str] = []
    details: list[str] = []
    rng = np.random.default_rng(seed)
    outs = [f.vr[n] for n in f.outputs]
    ders = [f.vr[n] for n in f.derivatives]
    ins = [f.vr[n] for n in f.inputs]
    worst = 0.0

    def compare(label, J, pairs, scale):
        """Columns scaled by the knowns' nominal values, then each row by its largest entry: the error
        relative to the size of that unknown's sensitivity.  An entry fails only if at every step of
        ``pairs`` (see FD_STEP_FACTORS) it is off by more than FD_TOLERANCE and by more than 4 |F − F2|, the
        differences' own error estimate there."""
        nonlocal worst
        Js = J * scale
        rows = np.max(np.abs(Js), axis=1)
        for F, _ in pairs:
            rows = np.maximum(rows, np.max(np.abs(F * scale), axis=1))
        rows = np.where(rows > 0, rows, 1.0)[:, None]
        errs = np.array([np.abs(Js - F * scale) / rows for F, _ in pairs])
        owns = np.array([4.0 * np.abs(F - F2) * scale / rows for F, F2 in pairs])
        excess = np.min(errs - np.maximum(owns, FD_TOLERANCE), axis=0)       # > 0: off at every step
        best = np.argmin(errs, axis=0)
        err = np.take_along_axis(errs, best[None], axis=0)[0]
        unexplained = np.maximum(np.min(errs - owns, axis=0), 0.0)
        worst = max(worst, float(unexplained.max(initial=0.0)))
        for j in range(J.shape[1]):
            if excess[:, j].max(initial=-1.0) > 0.0:
                i = int(np.argmax(excess[:, j]))
                F = pairs[best[i, j]][0]
                problems.append(f"{label}: column {j}, row {i}: relative error {err[i, j]:.2e} at the best "
                                f"step, beyond the differences' own error (directional {J[i, j]:.6g}, "
                                f"differences {F[i, j]:.6g})")
        details.append(f"{label}: {J.shape[0]} x {J.shape[1]}, worst {float(unexplained.max(initial=0.0)):.2e} "
                       f"beyond the differences' own error ({float(err.max(initial=0.0)):.2e} in all)")

    try:
        me = _instance(f, "ME")
        _start(me, "ME", _excitation(f))
        nominal = np.zeros(f.nx)
        me.getNominalsOfContinuousStates(nominal.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), f.nx)
        x = np.zeros(f.nx)
        me.getContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), f.nx)
        x = x + 0.05 * nominal * rng.standard_normal(f.nx)      # away from the (symmetric) start
        me.setTime(0.05)

        def evaluate(xx):
            me.setContinuousStates(np.ascontiguousarray(xx).ctypes.data_as(ctypes.POINTER(ctypes.c_double)), f.nx)
            dx = np.zeros(f.nx)
            me.getDerivatives(dx.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), f.nx)
            return np.concatenate([dx, np.asarray(me.getReal(outs), float)])

        evaluate(x)
        J = directional_jacobian(me, ders + outs, [f.vr[n] for n in f.states] + ins)
        steps = [1e-5 * max(abs(x[j]), nominal[j]) for j in range(f.nx)]
        pairs = _central_differences(lambda j, d: evaluate(x + d * np.eye(f.nx)[j]), steps)
        evaluate(x)
        inputs = [_InputProbe(me, vr, _excitation(f).get(n, float(f.vars[n].start or 0.0)), lambda: evaluate(x))
                  for n, vr in zip(f.inputs, ins, strict=True)]
        if inputs:
            pairs_u = _central_differences(lambda k, d: inputs[k](d), [p.step for p in inputs])
            pairs = [(np.hstack([F, Fu]), np.hstack([F2, F2u])) for (F, F2), (Fu, F2u) in zip(pairs, pairs_u,
                                                                                         strict=True)]
        compare("ME d(der, outputs)/d(states, inputs)", J, pairs, np.concatenate([nominal, np.ones(len(ins))]))
        _free(me)
        if ins:
            cs = _instance(f, "CS")
            start = _excitation(f)
            _start(cs, "CS", start)
            cs.doStep(0.0, 0.01)
            J = directional_jacobian(cs, outs, ins)
            probes = [_InputProbe(cs, vr, start.get(n, float(f.vars[n].start or 0.0)),
                                  lambda: np.asarray(cs.getReal(outs), float))
                      for n, vr in zip(f.inputs, ins, strict=True)]
            pairs = _central_differences(lambda k, d: probes[k](d), [p.step for p in probes])
            compare("CS d(outputs)/d(inputs)", J, pairs, np.ones(len(ins)))
            _free(cs)
    except Exception as e:
        problems.append(f"{type(e).__name__}: {e}")
    res = (f"worst column error {worst:.2e} beyond the differences' own error"
           + (f"; {len(problems)} failure(s)" if problems else ""))
    return CheckResult("directional-derivatives", "random state about the start, t = 0.05 s",
                       f"central differences, tolerance {FD_TOLERANCE}", res, "fail" if problems else "pass",
                       time.perf_counter() - t0, problems + details)


# ========================================================================= f. importers

def check_importers(f: _Fmu) -> list[CheckResult]:
    from flexlink.tools.importers import fmutool_check, libcosim_available, run_libcosim

    out = []
    t0 = time.perf_counter()
    if libcosim_available():
        stop = 0.05
        run = run_libcosim(f.path, stop, 1e-3, f.outputs[:3], _excitation(f))
        ok = run.ok and all(np.isfinite(v) for v in run.values.values())
        out.append(CheckResult("libcosim", f"0 .. {stop} s, step 1 ms", "runs without error or warning",
                               ", ".join(f"{k} = {v:.6g}" for k, v in run.values.items()) or "no result",
                               "pass" if ok else "fail", time.perf_counter() - t0,
                               [] if ok else run.log.splitlines()[-20:]))
    else:
        out.append(CheckResult("libcosim", "-", "-", "libcosimpy is not installed", "skip"))
    t0 = time.perf_counter()
    run = fmutool_check(f.path)
    skip = "not installed" in run.log
    out.append(CheckResult("fmutool", "fmutool -check", "no errors", "not installed" if skip else
                           ("no errors" if run.ok else "errors"), "skip" if skip else ("pass" if run.ok else "fail"),
                           time.perf_counter() - t0, [] if run.ok else run.log.splitlines()[-20:]))
    return out


# ============================================================================ driver

def check_fmu(path: str | os.PathLike, *, fuzz: int = CI_FUZZ, seed: int = 0, importers: bool = True,
              stop_time: float | None = None) -> list[CheckResult]:
    """Run every check on the FMU at ``path``; see the module docstring."""
    # fmpy changes into the binary's folder to load it and does not come back when the load fails (an
    # unresolved symbol): the caller's working directory is restored whatever happens
    cwd = os.getcwd()
    try:
        f = _Fmu(path)
    except Exception as e:      # fmpy's parse errors have no common class; the FMU is unusable whichever it is
        from flexlink.errors import FlexlinkError

        os.chdir(cwd)
        raise FlexlinkError(f"{os.fspath(path)}: modelDescription.xml cannot be read "
                            f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})") from None
    try:
        results = [check_model_description(f)]
        results.append(check_me_vs_cs(f, stop_time))
        results.append(check_fuzz(f, fuzz, seed))
        results.append(check_fmu_state(f))
        results.append(check_directional_derivatives(f))
        if importers:
            results += check_importers(f)
    finally:
        f.close()
        os.chdir(cwd)
    return results


def write_report(results: list[CheckResult], directory: str | os.PathLike, fmu: str) -> tuple[Path, Path]:
    """``report.json`` and ``report.md`` (a cross-check style table: input, reference, result, status)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    passed = all(r.status != "fail" for r in results)
    data = {"fmu": os.fspath(fmu), "passed": passed, "checks": [asdict(r) for r in results]}
    j = d / "report.json"
    j.write_text(json.dumps(data, indent=2) + "\n")
    lines = [f"# flexlink check: {os.path.basename(fmu)}", "",
             f"Overall: **{'passed' if passed else 'FAILED'}**", "",
             "| check | input | reference | result | status | time (s) |", "| --- | --- | --- | --- | --- | --- |"]
    for r in results:
        cells = [r.name, r.input, r.reference, r.result, r.status.upper() if r.status == "fail" else r.status,
                 f"{r.seconds:.2f}"]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    for r in results:
        if r.details and r.status == "fail":
            lines += ["", f"## {r.name}", ""] + [f"- {x}" for x in r.details]
    m = d / "report.md"
    m.write_text("\n".join(lines) + "\n")
    return j, m


def _require_fmu(path: str) -> None:
    """Refuse, in one line, what is not an FMU at all (a missing file, a folder, not a zip archive, a zip
    without modelDescription.xml): the harness is for FMUs that may be wrong, not for arbitrary files."""
    import zipfile

    from flexlink.errors import FlexlinkError

    if not os.path.exists(path):
        raise FlexlinkError(f"{path}: no such file")
    if not os.path.isfile(path):
        raise FlexlinkError(f"{path}: is not a file; expected an FMU (.fmu)")
    if not zipfile.is_zipfile(path):
        raise FlexlinkError(f"{path}: not an FMU (an FMU is a zip archive; this file is not one)")
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
    except (zipfile.BadZipFile, OSError) as e:
        raise FlexlinkError(f"{path}: not an FMU (unreadable zip archive: {e})") from None
    if "modelDescription.xml" not in names:
        raise FlexlinkError(f"{path}: not an FMU (no modelDescription.xml in the archive)")


def run_check(args) -> int:
    """``flexlink check`` (cli.py): exit status 1 if anything fails."""
    _require_fmu(args.fmu)
    if args.me_vs_cs_stop is not None and not (0.0 < args.me_vs_cs_stop < math.inf):
        from flexlink.errors import FlexlinkError

        raise FlexlinkError(f"--me-vs-cs-stop {args.me_vs_cs_stop}: must be a positive number of seconds")
    results = check_fmu(args.fmu, fuzz=args.fuzz, seed=args.seed, importers=not args.no_importers,
                        stop_time=args.me_vs_cs_stop)
    for r in results:
        print(f"{r.status.upper():5s} {r.name:24s} {r.result}  ({r.seconds:.1f} s)")
        if r.status == "fail":
            for line in r.details[:10]:
                print(f"      {line}")
    if args.report:
        j, m = write_report(results, args.report, args.fmu)
        print(f"report: {m}, {j}")
    return 1 if any(r.status == "fail" for r in results) else 0


def add_parser(sub) -> None:
    p = sub.add_parser("check", help="compliance harness: validation, ME vs CS, fuzzing, FMU state, "
                                     "directional derivatives, independent importers")
    p.add_argument("fmu", metavar="FMU", help="the FMU file to check")
    p.add_argument("--report", metavar="DIR", help="write report.md and report.json to DIR")
    p.add_argument("--fuzz", type=int, default=CI_FUZZ, metavar="N",
                   help=f"random legal call sequences (default {CI_FUZZ}; full size: 5000)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the fuzzing (default 0)")
    p.add_argument("--me-vs-cs-stop", type=float, metavar="SECONDS",
                   help="length of the ME vs CS comparison (default: the FMU's stop time, at most 0.5 s)")
    p.add_argument("--no-importers", action="store_true", help="skip libcosim and fmutool")
    p.set_defaults(func=run_check)


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--fuzz-child":
        out = _fuzz(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
        print("FUZZ " + json.dumps(out), flush=True)
        sys.exit(0)
    ap = argparse.ArgumentParser(prog="python -m flexlink.tools.check")
    add_parser(ap.add_subparsers(dest="command", required=True))
    a = ap.parse_args(["check", *sys.argv[1:]])
    sys.exit(a.func(a))
