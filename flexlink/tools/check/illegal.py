"""Check ``illegal-calls``: a catalogue of calls the state machine or the argument rules forbid.

Each is made on a fresh instance; each should give fmi2Error, after which ``fmi2Reset`` must revive the
instance.

FMI 2.0 makes a legal calling sequence the importer's duty, so for FMUs in general a forbidden call that is
accepted is a *warning* (rule ``illegal-call``, a robustness recommendation); for flexlink FMUs it is an
error (flexlink's own contract, with the catalogue of its parameter checks added).  FMI 3.0 makes it the
FMU's: "When detecting illegal arguments or a function call not allowed in the current state according to
the respective state machine, the FMU must return fmi3Error" (§2.2.4), so on an FMI 3.0 FMU an accepted
call out of sequence or with an illegal argument (an unknown value reference, a step not > 0, a first step
away from the start time) is an error (rule ``state-machine``).  A non-finite *value* (a NaN input, state,
time or seed) is not named illegal by either version: a warning in both.  The catalogue is the same for
both versions, under FMI 3's function names (``fmu.Fmi3AsFmi2``); FMI 3's further states (Configuration
Mode, Clock activation, Scheduled Execution) are not exercised.  A forbidden call that
hangs or crashes is an error for every FMU: the catalogue marks its progress item by item, so the harness
(:mod:`flexlink.tools.check.isolation`) reports that item and resumes after it.
"""

from __future__ import annotations

import ctypes
import math
import time
from typing import Any

from flexlink.tools.check import isolation
from flexlink.tools.check.findings import CheckResult, Finding, skipped
from flexlink.tools.check.fmu import ERROR, OK, Fmi3AsFmi2, Fmu, call, free, quiet_callbacks

BAD_VR = 10**6 + 7
NAN = float("nan")


def _raw(inst, function: str, argtypes: list, *args) -> None:
    """Call an FMI function that fmpy does not bind for this interface; raise on a bad status."""
    from fmpy.fmi1 import FMICallException

    try:
        fn = getattr(inst.dll, function)
    except AttributeError:                 # not exported: the call cannot be made, so it is not accepted
        raise FMICallException(function, ERROR) from None
    fn.argtypes = [ctypes.c_void_p, *argtypes]
    fn.restype = ctypes.c_int
    isolation._enter(f"{function}{args}")
    try:
        status = fn(inst.component, *args)
    finally:
        isolation._leave()
    if status != OK:
        raise FMICallException(function, status)


def _set_time(f: Fmu, inst, t: float) -> None:
    _raw(inst, "fmi3SetTime" if f.fmi3 else "fmi2SetTime", [ctypes.c_double], t)


def _do_step(f: Fmu, inst, t: float, h: float) -> None:
    if not f.fmi3:
        _raw(inst, "fmi2DoStep", [ctypes.c_double, ctypes.c_double, ctypes.c_int], t, h, 1)
        return
    flags = [ctypes.c_bool() for _ in range(3)]
    last = ctypes.c_double()
    _raw(inst, "fmi3DoStep", [ctypes.c_double, ctypes.c_double, ctypes.c_bool] + [ctypes.c_void_p] * 4, t, h, True,
         *(ctypes.addressof(x) for x in flags), ctypes.addressof(last))


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
        illegal("setReal(input) = NaN", "init", lambda i: i.setReal([inputs[0]], [NAN]), value=True)
    illegal("doStep with a zero step", "init", lambda i: i.doStep(0.0, 0.0))
    illegal("doStep with a negative step", "init", lambda i: i.doStep(0.0, -0.01))
    illegal("doStep with a NaN step", "init", lambda i: i.doStep(0.0, NAN))
    illegal("doStep at the wrong communication point", "init", lambda i: i.doStep(1.0, 0.01))
    if f.can("CS", "providesDirectionalDerivative") and outputs:
        illegal("getDirectionalDerivative w.r.t. an output", "init",
                lambda i: i.getDirectionalDerivative([outputs[0]], [outputs[0]], [1.0]))
    illegal("Model Exchange function on a Co-Simulation instance", "init", lambda i: _set_time(f, i, 0.1))
    if f.can("CS", "canSerializeFMUstate"):
        illegal("deserialize garbage", "init", lambda i: i.deSerializeFMUstate(bytes(64)))


def _model_exchange(f: Fmu, illegal) -> None:
    inputs = [f.vr[n] for n in f.inputs]
    states, ders, nx = [f.vr[n] for n in f.states], [f.vr[n] for n in f.derivatives], f.nx
    c_arr = ctypes.c_double * max(nx, 1)
    if inputs:
        illegal("setReal(input) = inf", "init", lambda i: i.setReal([inputs[0]], [math.inf]), value=True)
    if f.can("ME", "providesDirectionalDerivative") and nx:
        illegal("getDirectionalDerivative with a NaN seed", "init",
                lambda i: i.getDirectionalDerivative([ders[0]], [states[0]], [NAN]), value=True)
    if nx:
        illegal("setContinuousStates with NaN", "init", lambda i: i.setContinuousStates(c_arr(*([NAN] * nx)), nx),
                value=True)
        illegal("getDerivatives before initialization", None, lambda i: i.getDerivatives(c_arr(*([0.0] * nx)), nx))
    illegal("setContinuousStates with the wrong nx", "init",
            lambda i: i.setContinuousStates(c_arr(*([0.0] * max(nx, 1))), nx + 1))
    illegal("setTime NaN", "init", lambda i: i.setTime(NAN), value=True)
    illegal("newDiscreteStates in continuous-time mode", "init", lambda i: i.newDiscreteStates())
    illegal("enterContinuousTimeMode in continuous-time mode", "init", lambda i: i.enterContinuousTimeMode())
    illegal("doStep on a Model Exchange instance", "init", lambda i: _do_step(f, i, 0.0, 0.01))
    illegal("terminate before initialization", None, lambda i: i.terminate())


def _flexlink(f: Fmu, illegal) -> None:
    """The catalogue of flexlink's parameter checks (flexlink FMUs only: see fmu.py for how they are recognised)."""
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
    if order is not None and order.type in ("Integer", "Int32"):     # an Integer since issue 17: 2 or 4
        illegal("solver.order = 3", None, lambda i: i.setInteger([order.valueReference], [3]), "CS")
        illegal("solver.order = 2.5 set as a Real", None, lambda i: i.setReal([order.valueReference], [2.5]), "CS")


def catalogue(f: Fmu) -> list[tuple[str, str, str | None, object, bool]]:
    """The catalogue for the FMU's declared interfaces.

    Each item is (name, interface, "init" or None, call, whether only a value is wrong).
    """
    items: list[tuple] = []

    def add(name, setup, fn, kind, value=False):
        if kind in f.interfaces:
            items.append((name, kind, setup, fn, value))

    for kind, add_items in (("CS", _co_simulation), ("ME", _model_exchange)):
        add_items(f, lambda name, setup, fn, value=False, k=kind: add(name, setup, fn, k, value))
    if f.is_flexlink:
        _flexlink(f, add)
    return items


def _init(inst, kind: str) -> None:
    inst.setupExperiment(startTime=0.0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    if kind == "ME":
        inst.newDiscreteStates()
        inst.enterContinuousTimeMode()


def _rule(f: Fmu, value: bool) -> str:
    """The rule an accepted forbidden call breaks.

    flexlink's contract on flexlink FMUs; FMI 3.0's "must return fmi3Error" for a call out of sequence or
    with an illegal argument; a robustness recommendation otherwise (see the module docstring).
    """
    if f.is_flexlink:
        return "flexlink-contract"
    return "state-machine" if f.fmi3 and not value else "illegal-call"


def _one(f: Fmu, inst, name: str, kind: str, setup, fn, value: bool) -> list[Finding]:
    rule = _rule(f, value)
    inst.instantiate(callbacks=quiet_callbacks())
    found = []
    try:
        if setup == "init":
            _init(inst, kind)
    except Exception as e:
        return [Finding("legal-call", f"setting up '{name}' ({kind}): {e}", sequence=isolation.recent())]
    status = call(fn, inst)
    if status != ERROR:
        expected = "fmi3Error" if f.fmi3 else "fmi2Error"
        found.append(Finding(rule, f"illegal call '{name}' ({kind}): expected {expected} (3), got {status}",
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
    """An instance with a wrong GUID (FMI 3.0: instantiation token) is refused."""
    if f.fmi3:
        from fmpy.fmi3 import FMU3Model as Model
        from fmpy.fmi3 import FMU3Slave as Slave
    else:
        from fmpy.fmi2 import FMU2Model as Model
        from fmpy.fmi2 import FMU2Slave as Slave

    kind = f.interfaces[0]
    wrong = (Slave if kind == "CS" else Model)(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=f.dir,
                                               modelIdentifier=f.identifier, instanceName="wrong")
    inst = Fmi3AsFmi2(wrong) if f.fmi3 else wrong
    try:
        inst.instantiate(callbacks=quiet_callbacks())
    except Exception:
        return []
    free(inst)          # an importer frees what it made: none left for the process's exit to meet
    what = "instantiation token" if f.fmi3 else "GUID"
    return [Finding("flexlink-contract" if f.is_flexlink else "wrong-guid",
                    f"{kind}: an instance with a wrong {what} was created", sequence=isolation.recent(1))]


def check_illegal_calls(f: Fmu, first: int = 0) -> CheckResult:
    """The catalogue from item ``first`` (the harness resumes after an item that hangs or crashes)."""
    if not f.interfaces:
        return skipped("illegal-calls", "no interface")
    t0 = time.perf_counter()
    items = catalogue(f)
    insts: dict[str, Any] = {k: f.instance(k, f"illegal{k}") for k in f.interfaces}
    found: list[Finding] = []
    for k in range(first, len(items)):
        isolation.progress(k)
        name, kind, setup, fn, value = items[k]
        new = _one(f, insts[kind], name, kind, setup, fn, value)
        isolation.emit(new)
        found += new
    isolation.progress(len(items))
    found += _wrong_guid(f)
    inp = f"{len(items)} forbidden calls on {', '.join(f.interfaces)}" + (f" (from item {first})" if first else "")
    ref = "each gives fmi2Error, then fmi2Reset works; a wrong GUID is refused"
    return CheckResult("illegal-calls", inp, ref, f"{len(items) - first} calls, {len(found)} finding(s)",
                       seconds=time.perf_counter() - t0, details=[x.message for x in found], findings=found)
