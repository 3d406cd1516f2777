"""Check ``fuzz``: seeded random *legal* call sequences, each call of which must succeed.

Sequence k draws from its own generator, seeded with (seed, k), so that it is the same whether the run
starts at sequence 0 or at k: the check marks its progress sequence by sequence, and a call that does not
return (or crashes) ends that sequence only; the harness (:mod:`flexlink.tools.check.isolation`) reports it
and resumes at sequence k + 1 in a fresh process.  ``--fuzz k+1 --seed S`` replays up to sequence k.

Only what the FMU declares is called: its interfaces; FMU state round trips with ``canGetAndSetFMUstate``
(serialization with ``canSerializeFMUstate``); directional derivatives with
``providesDirectionalDerivative``; one communication step size per sequence without
``canHandleVariableCommunicationStepSize``.  Inputs get values of their type within their declaration
(discrete ones only where the state machine lets them change: CS between steps, ME at initialisation).
A Model Exchange step is an integrator's: error-controlled, shortened where the FMU discards, stopped at
the time events the FMU announces and at the first zero crossing of its event indicators (located by
bisection), and the event handled, so that a correct FMU with state events is never stepped over one.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from flexlink.tools.check import isolation
from flexlink.tools.check.driver import CI_FUZZ  # with the harness's other sizes: the parser imports no numpy
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

MAX_FINDINGS = 50
MAX_SUBSTEPS = 20    # integrator steps per Model Exchange operation
TOLERANCE = 1e-5     # relative error per integrator step (Euler against Heun)


class Fuzzer:
    """The fuzz's state: one instance per interface, re-instantiated for each sequence.

    Every call's status is checked against what the standard allows and the surprises are collected in
    ``findings``.
    """

    LEGAL = (OK, WARNING)

    def __init__(self, f: Fmu, seed: int, earlier: Sequence[str] = ()):
        self.f = f
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.sequence = 0
        self.findings: list[Finding] = []
        # what earlier processes of this fuzz found (it resumes in a fresh one after a hang or a crash): a
        # repeated finding is reported once and MAX_FINDINGS holds for the whole fuzz
        self.earlier = len(earlier)
        self.seen: set[str] = {_key(m) for m in earlier}
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
        self.state_events: list[tuple[int, float]] = []     # (sequence, time) of the state events located
        step = f.md.defaultExperiment.stepSize if f.md.defaultExperiment else None
        self.fixed_step = float(step) if step else 1e-2

    def expect(self, ok_statuses, status, what: str) -> None:
        """Count the call; a status outside ``ok_statuses`` is a ``legal-call`` finding."""
        self.calls += 1
        if status not in ok_statuses:
            self.report(Finding("legal-call", f"sequence {self.sequence}: {what}: status {status}",
                                sequence=isolation.recent()))

    def report(self, finding: Finding) -> None:
        """Add a finding, unless one of its kind was reported already or MAX_FINDINGS were.

        "Already" counts this process and the earlier ones of this fuzz.
        """
        key = _key(finding.message)
        if key not in self.seen and self.earlier + len(self.findings) < MAX_FINDINGS:
            self.seen.add(key)
            self.findings.append(finding)

    def init(self, inst, kind: str) -> None:
        """Initialise the instance; Model Exchange: through the event iteration to continuous-time mode."""
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
        """Sequence k, on interface k mod the number of interfaces, with its own generator.

        Instantiate, maybe change a parameter, initialise, 3 to 14 random legal operations, maybe reset,
        terminate, free.
        """
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
            return self._model_exchange_step(inst, t, t + float(rng.uniform(1e-4, 2e-2)))
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

    def _model_exchange_step(self, inst, t0: float, t: float) -> float:
        """What an integrator does from the current time t0 towards t (not past the next time event).

        Up to MAX_SUBSTEPS accepted steps (:meth:`_integrator_step`), each completed, until t or an event.
        Returns the time reached.
        """
        event = self.next_event.get("ME")
        at_event = event is not None and t >= event
        if event is not None and at_event:
            t = event
        for _ in range(MAX_SUBSTEPS):
            reached, handled = self._integrator_step(inst, t0, t, at_event)
            if handled or reached == t0 or reached >= t:
                return reached
            t0 = reached
        return t0

    def _integrator_step(self, inst, t0: float, t: float, time_event: bool) -> tuple[float, bool]:
        """One error-controlled step (:meth:`_integrate`) towards t, completed, and its event handled.

        The first zero crossing of the event indicators in the step is located (:meth:`_locate`), the step
        completed (which may discard a state outside the model's validity), then a time event at t, a state
        event or a step event handled.  Returns the time reached and whether an event was handled.
        """
        legal = self.LEGAL
        z0 = self._vector(inst.getEventIndicators, self.f.nz, "getEventIndicators")
        reached = self._integrate(inst, t0, t)
        if reached is None:
            return t0, False
        t1, x0, dx0, x1 = reached
        crossed = False
        if self.f.nz and z0 is not None:
            z1 = self._vector(inst.getEventIndicators, self.f.nz, "getEventIndicators")
            dx1 = self._vector(inst.getDerivatives, self.f.nx, "getDerivatives")
            if z1 is not None and dx1 is not None and _crossing(z0, z1).any():
                path = _Hermite(t0, t1, x0, dx0, x1, dx1)
                t1, crossed = self._locate(inst, path, z0), True
        try:
            enter, _ = inst.completedIntegratorStep()
            self.calls += 1
        except Exception as e:
            self.expect(legal + (DISCARD,), getattr(e, "status", 3), "completedIntegratorStep")
            enter = False
        handled = bool(enter or crossed or (time_event and t1 == t))
        if handled:
            self.expect(legal, call(inst.enterEventMode), "enterEventMode")
            self._event_iteration(inst)
            self.expect(legal, call(inst.enterContinuousTimeMode), "enterContinuousTimeMode")
        return t1, handled

    def _vector(self, getter, n: int, what: str) -> np.ndarray | None:
        """fmi2GetContinuousStates / fmi2GetDerivatives / fmi2GetEventIndicators into a new array.

        None on fmi2Discard, which an integrator answers with a smaller step; an error is a finding.
        """
        if n == 0:
            return np.zeros(0)
        out = np.zeros(n)
        status = call(getter, c_doubles(out), n)
        self.expect(self.LEGAL + (DISCARD,), status, what)
        return out if status in self.LEGAL else None

    def _move(self, inst, t: float, x: np.ndarray) -> bool:
        """fmi2SetTime and fmi2SetContinuousStates; False if the FMU discards them."""
        for status, what in ((call(inst.setTime, t), "setTime"),
                             (call(inst.setContinuousStates, c_doubles(x), len(x)) if len(x) else OK,
                              "setContinuousStates")):
            self.expect(self.LEGAL + (DISCARD,), status, what)
            if status not in self.LEGAL:
                return False
        return True

    def _integrate(self, inst, t0: float, t: float):
        """One step of Heun's method with Euler's as its error estimate (TOLERANCE).

        The step is halved on a larger error or an fmi2Discard (as FMI 2.0 §2.1.3 tells an integrator to), up
        to 40 times: a stiff model gets a step it is stable at, as a real integrator would give it.  Returns
        (t1, x0, dx0, x1), the FMU left at t1 and x1, or None if no step was accepted (the FMU is put back at
        t0).
        """
        nx = self.f.nx
        x0 = self._vector(inst.getContinuousStates, nx, "getContinuousStates")
        dx0 = self._vector(inst.getDerivatives, nx, "getDerivatives")
        if x0 is None or dx0 is None:
            return None
        h = t - t0
        for _ in range(40):
            euler = x0 + h * dx0
            if self._move(inst, t0 + h, euler):
                dx1 = self._vector(inst.getDerivatives, nx, "getDerivatives")
                if dx1 is not None:
                    heun = x0 + 0.5 * h * (dx0 + dx1)
                    error = np.max(np.abs(heun - euler) / (TOLERANCE * (1.0 + np.abs(heun))), initial=0.0)
                    if error <= 1.0 and self._move(inst, t0 + h, heun):
                        return t0 + h, x0, dx0, heun
            h *= 0.5
        self._move(inst, t0, x0)
        return None

    def _locate(self, inst, path: _Hermite, z0: np.ndarray) -> float:
        """Bisection in time for the first sign change of an event indicator along the step's interpolant.

        To 1e-12 of the step; the FMU is left just after it, where the sign has changed, as fmpy's Model
        Exchange loop leaves it at CVODE's root.  Returns that time.
        """
        lo, hi = 0.0, 1.0
        while hi - lo > 1e-12:
            mid = 0.5 * (lo + hi)
            if not self._move(inst, *path(mid)):
                break
            z = self._vector(inst.getEventIndicators, self.f.nz, "getEventIndicators")
            if z is None:
                break
            lo, hi = (lo, mid) if _crossing(z0, z).any() else (mid, hi)
        t, x = path(hi)
        self._move(inst, t, x)
        self.state_events.append((self.sequence, t))
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
            self.report(Finding("fmu-state", f"sequence {self.sequence}: FMU state round trip: {e}",
                                sequence=isolation.recent()))


def _key(message: str) -> str:
    """What makes findings repeats of each other.

    The call without its arguments and the outcome ("sequence 3: doStep(0.1, 0.01): status 3" -> "doStep:
    status 3"); other messages (a hang or a crash reported by the harness, an FMU state round trip) as they
    are, less their sequence.
    """
    text = message.split(": ", 1)[1] if message.startswith("sequence ") else message
    call, _, outcome = text.rpartition(": ")
    return f"{call.split('(')[0]}: {outcome}" if call else text


class _Hermite:
    """The cubic Hermite interpolant of a step from (t0, x0, dx0) to (t1, x1, dx1).

    It is an integrator's dense output (exact where the solution is a cubic, a free fall for one):
    ``path(s)`` is (t, x) at the fraction s of the step.
    """

    def __init__(self, t0: float, t1: float, x0: np.ndarray, dx0: np.ndarray, x1: np.ndarray, dx1: np.ndarray):
        self.t0, self.h, self.x0, self.dx0, self.x1, self.dx1 = t0, t1 - t0, x0, dx0, x1, dx1

    def __call__(self, s: float) -> tuple[float, np.ndarray]:
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, 3 * s**2 - 2 * s**3, s**3 - s**2
        x = h00 * self.x0 + h10 * self.h * self.dx0 + h01 * self.x1 + h11 * self.h * self.dx1
        return self.t0 + s * self.h, x


def _crossing(z0: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Which event indicators changed sign from z0 to z.

    From nonzero to zero or to the other sign, as CVODE's root-finding in fmpy's Model Exchange loop counts
    them.
    """
    return (z0 != 0.0) & ((z == 0.0) | (np.sign(z) != np.sign(z0)))


def check_fuzz(f: Fmu, n: int = CI_FUZZ, seed: int = 0, first: int = 0,
               earlier: Sequence[str] = ()) -> CheckResult:
    """Sequences ``first`` .. n - 1 of the fuzz.

    The harness starts again after one that hangs or crashes, handing over the messages of what was
    ``earlier`` found.
    """
    inp = f"{n} random legal sequences (seed {seed}) over {', '.join(f.interfaces) or 'no interface'}"
    ref = "every legal call returns fmi2OK/fmi2Warning (doStep, completedIntegratorStep may discard)"
    if not f.interfaces:
        return skipped("fuzz", "no interface")
    t0 = time.perf_counter()
    fuzzer = Fuzzer(f, seed, earlier)
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
    if f.nz and "ME" in f.interfaces:
        res += f", {len(fuzzer.state_events)} state event(s) located"
    return CheckResult("fuzz", inp, ref, res, seconds=time.perf_counter() - t0,
                       details=[x.message for x in found], findings=found)
