"""Check ``fuzz``: seeded random *legal* call sequences, each call of which must succeed.

Sequence k draws from its own generator, seeded with (seed, k), so that it is the same whether the run
starts at sequence 0 or at k: the check marks its progress sequence by sequence, and a call that does not
return (or crashes) ends that sequence only; the harness (:mod:`flexlink.tools.check.isolation`) reports it
and resumes at sequence k + 1 in a fresh process.  ``--fuzz k+1 --seed S`` replays up to sequence k.

Only what the FMU declares is called: its interfaces; FMU state round trips with ``canGetAndSetFMUstate``
(serialization with ``canSerializeFMUstate``); directional derivatives with
``providesDirectionalDerivative``; one communication step size per sequence without
``canHandleVariableCommunicationStepSize``.  Inputs get values of their type within their declaration
(discrete ones only where the state machine lets them change: CS between steps, ME at initialisation);
Model Exchange steps stop at the time events the FMU announces and handle them.
"""

from __future__ import annotations

import time

import numpy as np

from flexlink.tools.check import isolation
from flexlink.tools.check.findings import CheckResult, Finding, skipped
from flexlink.tools.check.fmu import (
    DISCARD,
    OK,
    WARNING,
    Fmu,
    c_doubles,
    call,
    excite_value,
    free,
    quiet_callbacks,
    set_value,
)

CI_FUZZ = 60          # random legal sequences per run by default
MAX_FINDINGS = 50


class Fuzzer:
    """One instance per interface, re-instantiated for each sequence; every call's status is checked
    against what the standard allows and the surprises are collected in ``findings``."""

    LEGAL = (OK, WARNING)

    def __init__(self, f: Fmu, seed: int):
        self.f = f
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.sequence = 0
        self.findings: list[Finding] = []
        self.seen: set[str] = set()
        self.calls = 0
        self.outputs = [f.vr[n] for n in f.outputs]
        self.inputs = [v for v in f.typed_inputs if v.type != "String"]
        self.tunable = [f.vars[n] for n in f.tunable]
        # an array parameter (name[1], name[2], ...) is scaled as a whole: relations between its entries,
        # which an FMU may enforce (an inertia tensor must stay a body's), survive a common factor
        groups: dict[str, list[int]] = {}
        for k, n in enumerate(f.tunable):
            groups.setdefault(n.split("[", 1)[0], []).append(k)
        self.tunable_groups = list(groups.values())
        self.states = [f.vr[n] for n in f.states]
        self.ders = [f.vr[n] for n in f.derivatives]
        self.insts = {k: f.instance(k, f"fuzz{k}") for k in f.interfaces}
        self.next_event = {k: None for k in f.interfaces}
        step = f.md.defaultExperiment.stepSize if f.md.defaultExperiment else None
        self.fixed_step = float(step) if step else 1e-2

    def expect(self, ok_statuses, status, what: str) -> None:
        self.calls += 1
        if status not in ok_statuses:
            key = what.split("(")[0] + f" {status}"
            if key not in self.seen and len(self.findings) < MAX_FINDINGS:
                self.seen.add(key)
                self.findings.append(Finding("legal-call", f"sequence {self.sequence}: {what}: status {status}",
                                             sequence=isolation.recent()))

    def init(self, inst, kind: str) -> None:
        legal = self.LEGAL
        self.expect(legal, call(inst.setupExperiment, None, 0.0, None), "setupExperiment")
        self.expect(legal, call(inst.enterInitializationMode), "enterInitializationMode")
        self.expect(legal, call(inst.exitInitializationMode), "exitInitializationMode")
        if kind == "ME":
            self._event_iteration(inst)
            self.expect(legal, call(inst.enterContinuousTimeMode), "enterContinuousTimeMode")

    def _event_iteration(self, inst) -> None:
        """fmi2NewDiscreteStates until no new discrete states are needed; remembers the next time event."""
        for _ in range(100):
            try:
                info = inst.newDiscreteStates()
                self.calls += 1
            except Exception as e:
                self.expect(self.LEGAL, getattr(e, "status", 3), "newDiscreteStates")
                return
            self.next_event["ME"] = info[5] if info[4] else None
            if not info[0]:
                return

    def _scaled_tunable(self, inst, what: str) -> None:
        group = self.tunable_groups[int(self.rng.integers(len(self.tunable_groups)))]
        factor = self.rng.uniform(0.8, 1.25)
        values = []
        for j in group:
            v = self.tunable[j]
            x = float(v.start or 0.0) * factor
            lo = float(v.min) if v.min is not None else -np.inf
            hi = float(v.max) if v.max is not None else np.inf
            values.append(float(np.clip(x, lo, hi)))
        self.expect(self.LEGAL, call(inst.setReal, [self.tunable[j].valueReference for j in group], values), what)

    def legal_sequence(self, k: int) -> None:
        """Sequence k, on interface k mod the number of interfaces, with its own generator: instantiate, maybe
        change a parameter, initialise, 3 to 14 random legal operations, maybe reset, terminate, free."""
        kind = self.f.interfaces[k % len(self.f.interfaces)]
        self.sequence, self.rng = k, np.random.default_rng((self.seed, k))
        inst = self.insts[kind]
        inst.instantiate(callbacks=quiet_callbacks())
        if self.tunable and self.rng.random() < 0.5:
            self._scaled_tunable(inst, "setReal(parameter) before init")
        self.init(inst, kind)
        t = 0.0
        h = self.fixed_step if not self.f.can("CS", "canHandleVariableCommunicationStepSize") else None
        for _ in range(int(self.rng.integers(3, 15))):
            t = self._random_operation(inst, kind, t, h)
        if self.rng.random() < 0.2:
            self.expect(self.LEGAL, call(inst.reset), "reset")
            self.init(inst, kind)
        self.expect(self.LEGAL, call(inst.terminate), "terminate")
        free(inst)

    def _random_operation(self, inst, kind: str, t: float, fixed_h: float | None) -> float:
        """One legal operation chosen at random; returns the time reached."""
        legal, rng, f = self.LEGAL, self.rng, self.f
        op = rng.integers(7)
        if op == 0 and kind == "CS":
            h = fixed_h or float(rng.uniform(1e-4, 2e-2))
            status = call(inst.doStep, t, h)
            self.expect(legal + (DISCARD,), status, f"doStep({t}, {h})")
            return t + h if status == OK else t
        if op == 0:
            return self._model_exchange_step(inst, t + float(rng.uniform(1e-4, 2e-2)))
        if op == 1 and self.outputs:
            n = min(len(self.outputs), int(rng.integers(1, 6)))
            sel = list(rng.choice(self.outputs, size=n, replace=False))
            self.expect(legal, call(inst.getReal, [int(s) for s in sel]), "getReal(outputs)")
        elif op == 2:
            self._set_input(inst, kind)
        elif op == 3 and self.tunable and kind == "CS":
            self._scaled_tunable(inst, "setReal(tunable)")
        elif op == 4 and f.can(kind, "canGetAndSetFMUstate"):
            self._state_round_trip(inst, f.can(kind, "canSerializeFMUstate"))
        elif op == 5 and f.can(kind, "providesDirectionalDerivative"):
            known = (self.states if kind == "ME" else []) + [v.valueReference for v in self.inputs
                                                             if v.type == "Real"]
            unknown = [int(u) for u in (self.ders if kind == "ME" else []) + self.outputs]
            if known and unknown:
                kv = [int(known[int(rng.integers(len(known)))])]
                self.expect(legal, call(inst.getDirectionalDerivative, unknown, kv, [1.0]),
                            "getDirectionalDerivative")
        elif op == 6 and kind == "ME":
            self.expect(legal, call(inst.enterEventMode), "enterEventMode")
            self._event_iteration(inst)
            self.expect(legal, call(inst.enterContinuousTimeMode), "enterContinuousTimeMode")
        return t

    def _set_input(self, inst, kind: str) -> None:
        """An input set to a legal value of its type: CS any input, ME continuous Real inputs only."""
        choices = [v for v in self.inputs if kind == "CS" or (v.type == "Real" and v.variability == "continuous")]
        if not choices:
            return
        v = choices[int(self.rng.integers(len(choices)))]
        if self.f.is_flexlink and v.type == "Real":
            value = float(self.rng.uniform(-1, 1))
        else:
            value = excite_value(v) if self.rng.random() < 0.5 else (v.start if v.start is not None else
                                                                     excite_value(v))
        self.expect(self.LEGAL, call(set_value, inst, v, value), f"set{v.type}({v.name} = {value})")

    def _model_exchange_step(self, inst, t: float) -> float:
        """What an integrator does: time (not past the next time event), states slightly moved, derivatives,
        step completed (which may discard a state outside the model's validity); events handled."""
        nx, legal = self.f.nx, self.LEGAL
        event = self.next_event.get("ME")
        at_event = event is not None and t >= event
        if at_event:
            t = event
        self.expect(legal, call(inst.setTime, t), "setTime")
        x = np.zeros(nx)
        self.expect(legal, call(inst.getContinuousStates, c_doubles(x), nx), "getContinuousStates")
        x += 1e-4 * self.rng.standard_normal(nx)
        self.expect(legal, call(inst.setContinuousStates, c_doubles(x), nx), "setContinuousStates")
        dx = np.zeros(nx)
        self.expect(legal, call(inst.getDerivatives, c_doubles(dx), nx), "getDerivatives")
        try:
            enter, _ = inst.completedIntegratorStep()
            self.calls += 1
        except Exception as e:
            self.expect(legal + (DISCARD,), getattr(e, "status", 3), "completedIntegratorStep")
            enter = False
        if enter or at_event:
            self.expect(legal, call(inst.enterEventMode), "enterEventMode")
            self._event_iteration(inst)
            self.expect(legal, call(inst.enterContinuousTimeMode), "enterContinuousTimeMode")
        return t

    def _state_round_trip(self, inst, serialize: bool) -> None:
        try:
            s = inst.getFMUstate()
            s2 = inst.deSerializeFMUstate(inst.serializeFMUstate(s)) if serialize else None
            inst.setFMUstate(s2 or s)
            inst.freeFMUstate(s)
            if s2 is not None:
                inst.freeFMUstate(s2)
            self.calls += 6 if serialize else 3
        except Exception as e:
            self.findings.append(Finding("fmu-state", f"sequence {self.sequence}: FMU state round trip: {e}",
                                         sequence=isolation.recent()))


def check_fuzz(f: Fmu, n: int = CI_FUZZ, seed: int = 0, first: int = 0) -> CheckResult:
    """Sequences ``first`` .. n - 1 (the harness starts again after one that hangs or crashes)."""
    inp = f"{n} random legal sequences (seed {seed}) over {', '.join(f.interfaces) or 'no interface'}"
    ref = "every legal call returns fmi2OK/fmi2Warning (doStep, completedIntegratorStep may discard)"
    if not f.interfaces:
        return skipped("fuzz", "no interface")
    t0 = time.perf_counter()
    fuzzer = Fuzzer(f, seed)
    for k in range(first, n):
        isolation.progress(k)
        before = len(fuzzer.findings)
        fuzzer.legal_sequence(k)
        for x in fuzzer.findings[before:]:
            x.reproduce = f"flexlink check {f.path} --only fuzz --fuzz {k + 1} --seed {seed}"
        isolation.emit(fuzzer.findings[before:])
    isolation.progress(n)
    found = fuzzer.findings
    res = (f"sequences {first}..{n - 1} in the last process" if first else f"{n} sequences")
    res += f", {fuzzer.calls} calls, {len(found)} finding(s)"
    return CheckResult("fuzz", inp, ref, res, seconds=time.perf_counter() - t0,
                       details=[x.message for x in found], findings=found)
