"""Check ``illegal-calls``: a catalogue of calls the state machine or the argument rules forbid, each on a
fresh instance; each should give fmi2Error, after which ``fmi2Reset`` must revive the instance.

FMI 2.0 makes a legal calling sequence the importer's duty, so for FMUs in general a forbidden call that is
accepted is a *warning* (rule ``illegal-call``, a robustness recommendation); for flexlink FMUs it is an
error (flexlink's own contract, with the catalogue of its parameter checks added).  A forbidden call that
hangs or crashes is an error for every FMU: the catalogue marks its progress item by item, so the harness
(:mod:`flexlink.tools.check.isolation`) reports that item and resumes after it.
"""

from __future__ import annotations

import ctypes
import math
import time

from flexlink.tools.check import isolation
from flexlink.tools.check.findings import CheckResult, Finding, skipped
from flexlink.tools.check.fmu import ERROR, OK, Fmu, call, free, quiet_callbacks

BAD_VR = 10**6 + 7
NAN = float("nan")


def _raw(inst, function: str, argtypes: list, *args) -> None:
    """Call an FMI function that fmpy does not bind for this interface; raise on a bad status."""
    from fmpy.fmi1 import FMICallException

    fn = getattr(inst.dll, function)
    fn.argtypes = [ctypes.c_void_p, *argtypes]
    fn.restype = ctypes.c_int
    isolation._enter(f"{function}{args}")
    try:
        status = fn(inst.component, *args)
    finally:
        isolation._leave()
    if status != OK:
        raise FMICallException(function, status)


def _co_simulation(f: Fmu, illegal) -> None:
    outputs = [f.vr[n] for n in f.outputs]
    inputs = [f.vr[n] for n in f.inputs]
    illegal("doStep before initialization", None, lambda i: i.doStep(0.0, 0.01))
    illegal("exitInitializationMode without enter", None, lambda i: i.exitInitializationMode())
    illegal("getReal of an unknown value reference", "init", lambda i: i.getReal([BAD_VR]))
    illegal("setReal of an unknown value reference", "init", lambda i: i.setReal([BAD_VR], [1.0]))
    if outputs:
        illegal("setReal of an output", "init", lambda i: i.setReal([outputs[0]], [1.0]))
    if inputs:
        illegal("setReal(input) = NaN", "init", lambda i: i.setReal([inputs[0]], [NAN]))
    illegal("doStep with a zero step", "init", lambda i: i.doStep(0.0, 0.0))
    illegal("doStep with a negative step", "init", lambda i: i.doStep(0.0, -0.01))
    illegal("doStep with a NaN step", "init", lambda i: i.doStep(0.0, NAN))
    illegal("doStep at the wrong communication point", "init", lambda i: i.doStep(1.0, 0.01))
    if f.can("CS", "providesDirectionalDerivative") and outputs:
        illegal("getDirectionalDerivative w.r.t. an output", "init",
                lambda i: i.getDirectionalDerivative([outputs[0]], [outputs[0]], [1.0]))
    illegal("Model Exchange function on a Co-Simulation instance", "init",
            lambda i: _raw(i, "fmi2SetTime", [ctypes.c_double], 0.1))
    if f.can("CS", "canSerializeFMUstate"):
        illegal("deserialize garbage", "init", lambda i: i.deSerializeFMUstate(bytes(64)))


def _model_exchange(f: Fmu, illegal) -> None:
    inputs = [f.vr[n] for n in f.inputs]
    states, ders, nx = [f.vr[n] for n in f.states], [f.vr[n] for n in f.derivatives], f.nx
    c_arr = ctypes.c_double * max(nx, 1)
    if inputs:
        illegal("setReal(input) = inf", "init", lambda i: i.setReal([inputs[0]], [math.inf]))
    if f.can("ME", "providesDirectionalDerivative") and nx:
        illegal("getDirectionalDerivative with a NaN seed", "init",
                lambda i: i.getDirectionalDerivative([ders[0]], [states[0]], [NAN]))
    if nx:
        illegal("setContinuousStates with NaN", "init", lambda i: i.setContinuousStates(c_arr(*([NAN] * nx)), nx))
        illegal("getDerivatives before initialization", None, lambda i: i.getDerivatives(c_arr(*([0.0] * nx)), nx))
    illegal("setContinuousStates with the wrong nx", "init",
            lambda i: i.setContinuousStates(c_arr(*([0.0] * max(nx, 1))), nx + 1))
    illegal("setTime NaN", "init", lambda i: i.setTime(NAN))
    illegal("newDiscreteStates in continuous-time mode", "init", lambda i: i.newDiscreteStates())
    illegal("enterContinuousTimeMode in continuous-time mode", "init", lambda i: i.enterContinuousTimeMode())
    illegal("doStep on a Model Exchange instance", "init",
            lambda i: _raw(i, "fmi2DoStep", [ctypes.c_double, ctypes.c_double, ctypes.c_int], 0.0, 0.01, 1))
    illegal("terminate before initialization", None, lambda i: i.terminate())


def _flexlink(f: Fmu, illegal) -> None:
    """flexlink's parameter checks (flexlink FMUs only: see fmu.py for how they are recognised)."""
    tunable = [f.vr[n] for n in f.tunable]
    if tunable:
        illegal("setReal(parameter) = NaN", None, lambda i: i.setReal([tunable[0]], [NAN]), "CS")
        lows = [n for n in f.tunable if f.vars[n].min is not None and float(f.vars[n].min) >= 0]
        if lows:
            illegal(f"setReal({lows[0]}) negative", None, lambda i: i.setReal([f.vr[lows[0]]], [-1.0]), "CS")
            illegal(f"setReal({lows[0]}) in continuous-time mode", "init",
                    lambda i: i.setReal([f.vr[lows[0]]], [float(f.vars[lows[0]].start)]), "ME")
    illegal("solver.step = 0", None, lambda i: i.setReal([f.vr["solver.step"]], [0.0]), "CS")
    illegal("solver.theta1 out of range", None, lambda i: i.setReal([f.vr["solver.theta1"]], [1.5]), "CS")
    illegal("fixed parameter set after initialization", "init",
            lambda i: i.setReal([f.vr["solver.step"]], [1e-3]), "CS")
    order = f.vars.get("solver.order")
    if order is not None and order.type == "Integer":       # an Integer since issue 17: 2 or 4
        illegal("solver.order = 3", None, lambda i: i.setInteger([order.valueReference], [3]), "CS")
        illegal("solver.order = 2.5 set as a Real", None, lambda i: i.setReal([order.valueReference], [2.5]), "CS")


def catalogue(f: Fmu) -> list[tuple[str, str, str | None, object]]:
    """(name, interface, "init" or None, call) for the FMU's declared interfaces."""
    items: list[tuple] = []
    for kind, add in (("CS", _co_simulation), ("ME", _model_exchange)):
        if kind in f.interfaces:
            add(f, lambda name, setup, fn, k=kind: items.append((name, k, setup, fn)))
    if f.is_flexlink:
        _flexlink(f, lambda name, setup, fn, k: items.append((name, k, setup, fn)) if k in f.interfaces else None)
    return items


def _init(inst, kind: str) -> None:
    inst.setupExperiment(startTime=0.0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    if kind == "ME":
        inst.newDiscreteStates()
        inst.enterContinuousTimeMode()


def _one(f: Fmu, inst, name: str, kind: str, setup, fn) -> list[Finding]:
    rule = "flexlink-contract" if f.is_flexlink else "illegal-call"
    inst.instantiate(callbacks=quiet_callbacks())
    found = []
    try:
        if setup == "init":
            _init(inst, kind)
    except Exception as e:
        return [Finding("legal-call", f"setting up '{name}' ({kind}): {e}", sequence=isolation.recent())]
    status = call(fn, inst)
    if status != ERROR:
        found.append(Finding(rule, f"illegal call '{name}' ({kind}): expected fmi2Error (3), got {status}",
                             sequence=isolation.recent(), reproduce=f"on a fresh {kind} instance: "
                             + " ; ".join(isolation.recent())))
    try:
        inst.reset()
        _init(inst, kind)
    except Exception as e:
        found.append(Finding("reset", f"after '{name}' ({kind}): fmi2Reset and initialisation failed: {e}",
                             sequence=isolation.recent()))
    free(inst)
    return found


def _wrong_guid(f: Fmu) -> list[Finding]:
    """An instance with a wrong GUID is refused."""
    from fmpy.fmi2 import FMU2Model, FMU2Slave

    kind = f.interfaces[0]
    cls = FMU2Slave if kind == "CS" else FMU2Model
    wrong = cls(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=f.dir,
                modelIdentifier=f.identifier, instanceName="wrong")
    try:
        wrong.instantiate(callbacks=quiet_callbacks())
    except Exception:
        return []
    return [Finding("flexlink-contract" if f.is_flexlink else "wrong-guid",
                    f"{kind}: an instance with a wrong GUID was created", sequence=isolation.recent(1))]


def check_illegal_calls(f: Fmu, first: int = 0) -> CheckResult:
    if not f.interfaces:
        return skipped("illegal-calls", "no interface")
    t0 = time.perf_counter()
    items = catalogue(f)
    insts = {k: f.instance(k, f"illegal{k}") for k in f.interfaces}
    found: list[Finding] = []
    for k in range(first, len(items)):
        isolation.progress(k)
        name, kind, setup, fn = items[k]
        new = _one(f, insts[kind], name, kind, setup, fn)
        isolation.emit(new)
        found += new
    isolation.progress(len(items))
    found += _wrong_guid(f)
    inp = f"{len(items)} forbidden calls on {', '.join(f.interfaces)}" + (f" (from item {first})" if first else "")
    ref = "each gives fmi2Error, then fmi2Reset works; a wrong GUID is refused"
    return CheckResult("illegal-calls", inp, ref, f"{len(items) - first} calls, {len(found)} finding(s)",
                       seconds=time.perf_counter() - t0, details=[x.message for x in found], findings=found)
