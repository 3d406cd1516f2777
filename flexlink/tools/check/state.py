"""Check ``fmu-state``: FMU state round trips and ``fmi2Reset``.

Get/set/serialize round trips must reproduce a run bit for bit, and ``fmi2Reset`` must give what a fresh
instance gives.

Round trips only where declared (``canGetAndSetFMUstate``, ``canSerializeFMUstate``, per interface);
the reset comparison always (fmi2Reset is mandatory).  Outputs of every type are compared.
"""

from __future__ import annotations

import time

import numpy as np

from flexlink.tools.check import isolation
from flexlink.tools.check.findings import CheckResult, Finding, skipped
from flexlink.tools.check.fmu import Fmu, c_doubles, free, get_values, set_value, start


def _steps(f: Fmu) -> float:
    """flexlink: 1 ms; others: their default step if they cannot vary it, else 1 ms."""
    step = f.md.defaultExperiment.stepSize if f.md.defaultExperiment else None
    if not f.is_flexlink and step and not f.can("CS", "canHandleVariableCommunicationStepSize"):
        return float(step)
    return 1e-3


def _co_simulation(f: Fmu, found: list[Finding]) -> None:
    outs = f.typed_outputs
    values = f.excitation()
    inst = f.instance("CS")
    start(f, inst, "CS", values)
    h, t = _steps(f), 0.0
    for _ in range(5):
        inst.doStep(t, h)
        t += h

    def run(t):
        for _ in range(10):
            inst.doStep(t, h)
            t += h
        return get_values(inst, outs)

    if f.can("CS", "canGetAndSetFMUstate"):
        s = inst.getFMUstate()
        data = inst.serializeFMUstate(s) if f.can("CS", "canSerializeFMUstate") else None
        y1 = run(t)
        inst.setFMUstate(s)
        y2 = run(t)
        if y1 != y2:
            found.append(Finding("fmu-state", "CS: get/set FMU state does not reproduce the run bit for bit",
                                 sequence=["fmi2GetFMUstate", "10 x fmi2DoStep", "fmi2SetFMUstate",
                                           "10 x fmi2DoStep"], reproduce=f"{y1} != {y2}"))
        if data is not None:
            s2 = inst.deSerializeFMUstate(data)
            inst.setFMUstate(s2)
            y3 = run(t)
            if y1 != y3:
                found.append(Finding("fmu-state", "CS: serialize/deserialize does not reproduce the run bit for "
                                                  "bit", reproduce=f"{y1} != {y3}"))
            inst.freeFMUstate(s2)
        inst.freeFMUstate(s)
    inst.reset()
    for name, value in values.items():
        set_value(inst, f.vars[name], value)
    inst.setupExperiment(startTime=0.0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    y_reset = get_values(inst, outs)
    fresh = f.instance("CS", "fresh")
    start(f, fresh, "CS", values)
    y_fresh = get_values(fresh, outs)
    if y_reset != y_fresh:
        found.append(Finding("reset", "CS: after fmi2Reset the outputs differ from a fresh instance's",
                             reproduce=f"{y_reset} != {y_fresh}"))
    free(fresh)
    free(inst)


def _model_exchange(f: Fmu, found: list[Finding]) -> None:
    """States and outputs survive a round trip through an FMU state (serialized where declared)."""
    me = f.instance("ME")
    start(f, me, "ME", f.excitation())
    x = np.zeros(f.nx)
    me.getContinuousStates(c_doubles(x), f.nx)
    x0, y0 = x.copy(), get_values(me, f.typed_outputs)
    s = me.getFMUstate()
    serialize = f.can("ME", "canSerializeFMUstate")
    data = me.serializeFMUstate(s) if serialize else None
    me.setTime(0.01)
    me.setContinuousStates(c_doubles(x0 + 1e-3), f.nx)
    s2 = me.deSerializeFMUstate(data) if serialize else None
    me.setFMUstate(s2 or s)
    me.getContinuousStates(c_doubles(x), f.nx)
    y = get_values(me, f.typed_outputs)
    if not np.array_equal(x, x0) or y != y0:
        how = "serialized " if serialize else ""
        found.append(Finding("fmu-state", f"ME: a {how}FMU state does not restore the continuous states and "
                                          "outputs", sequence=isolation.recent(),
                             reproduce=f"states {list(x0)} -> {list(x)}"))
    me.freeFMUstate(s)
    if s2 is not None:
        me.freeFMUstate(s2)
    free(me)


def check_fmu_state(f: Fmu) -> CheckResult:
    """The check, in each declared interface."""
    if not f.interfaces:
        return skipped("fmu-state", "no interface")
    t0 = time.perf_counter()
    found: list[Finding] = []
    try:
        if "CS" in f.interfaces:
            _co_simulation(f, found)
        if "ME" in f.interfaces and f.can("ME", "canGetAndSetFMUstate"):
            _model_exchange(f, found)
    except Exception as e:
        found.append(Finding("legal-call", f"{type(e).__name__}: {e}", sequence=isolation.recent()))
    declared = [k for k in f.interfaces if f.can(k, "canGetAndSetFMUstate")]
    inp = ("get/set" + ("/serialize" if any(f.can(k, "canSerializeFMUstate") for k in declared) else "")
           + f" on {', '.join(declared) or 'no interface (not declared)'}; reset")
    return CheckResult("fmu-state", inp, "bit-for-bit equal runs", "ok" if not found else f"{len(found)} problem(s)",
                       seconds=time.perf_counter() - t0, details=[x.message for x in found], findings=found)
