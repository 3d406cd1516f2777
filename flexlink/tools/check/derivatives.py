"""Check ``directional-derivatives``: ``fmi2GetDirectionalDerivative`` against central finite differences.

Model Exchange: derivatives and outputs w.r.t. states and inputs; Co-Simulation: outputs w.r.t. inputs;
in each interface that declares ``providesDirectionalDerivative``; Real outputs and inputs only.
"""

from __future__ import annotations

import time

import numpy as np

from flexlink.tools.check import isolation
from flexlink.tools.check.findings import CheckResult, Finding, skipped
from flexlink.tools.check.fmu import Fmu, c_doubles, free, start

FD_TOLERANCE = 1e-5         # directional derivative vs central differences, relative to the column


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
    """Central difference quotients, with h and with 2h, per factor of FD_STEP_FACTORS.

    The quotients (g(j, h) − g(j, −h)) / 2h, one column per known j, with h = factor × steps[j], and the same
    with 2h (their difference is the reference's own error estimate).
    """
    pairs = []
    for factor in FD_STEP_FACTORS:
        hs = [factor * h for h in steps]
        F = [(g(j, h) - g(j, -h)) / (2 * h) for j, h in enumerate(hs)]
        F2 = [(g(j, 2 * h) - g(j, -2 * h)) / (4 * h) for j, h in enumerate(hs)]
        pairs.append((np.array(F).T, np.array(F2).T))
    return pairs


class _Comparison:
    """Directional derivatives against the differences of ``_central_differences``, findings collected."""

    def __init__(self):
        self.worst = 0.0
        self.found: list[Finding] = []
        self.details: list[str] = []

    def __call__(self, label: str, J: np.ndarray, pairs, scale: np.ndarray, names: tuple[list, list]) -> None:
        """The entries of J that disagree with the finite differences at every step.

        Columns are scaled by the knowns' nominal values, then each row by its largest entry: the error
        relative to the size of that unknown's sensitivity.  An entry fails only if at every step of
        ``pairs`` (see FD_STEP_FACTORS) it is off by more than FD_TOLERANCE and by more than 4 |F − F2|, the
        differences' own error estimate there.
        """
        Js = J * scale
        rows = np.max(np.abs(Js), axis=1, initial=0.0)
        for F, _ in pairs:
            rows = np.maximum(rows, np.max(np.abs(F * scale), axis=1, initial=0.0))
        rows = np.where(rows > 0, rows, 1.0)[:, None]
        errs = np.array([np.abs(Js - F * scale) / rows for F, _ in pairs])
        owns = np.array([4.0 * np.abs(F - F2) * scale / rows for F, F2 in pairs])
        excess = np.min(errs - np.maximum(owns, FD_TOLERANCE), axis=0)       # > 0: off at every step
        best = np.argmin(errs, axis=0)
        err = np.take_along_axis(errs, best[None], axis=0)[0]
        unexplained = np.maximum(np.min(errs - owns, axis=0), 0.0)
        self.worst = max(self.worst, float(unexplained.max(initial=0.0)))
        for j in range(J.shape[1]):
            if excess[:, j].max(initial=-1.0) > 0.0:
                i = int(np.argmax(excess[:, j]))
                F = pairs[best[i, j]][0]
                self.found.append(Finding("directional-derivative", f"{label}: column {j}, row {i}: "
                                          f"d {names[0][i]} / d {names[1][j]}: relative "
                                          f"error {err[i, j]:.2e} at the best step, beyond the differences' own "
                                          f"error (directional {J[i, j]:.6g}, differences {F[i, j]:.6g})"))
        self.details.append(f"{label}: {J.shape[0]} x {J.shape[1]}, worst {float(unexplained.max(initial=0.0)):.2e}"
                            f" beyond the differences' own error ({float(err.max(initial=0.0)):.2e} in all)")


def _model_exchange(f: Fmu, rng, compare: _Comparison) -> None:
    outs = [f.vr[n] for n in f.outputs]
    ders = [f.vr[n] for n in f.derivatives]
    ins = [f.vr[n] for n in f.inputs]
    excitation = f.real_excitation()
    me = f.instance("ME")
    start(f, me, "ME", f.excitation())
    nominal = np.zeros(f.nx)
    me.getNominalsOfContinuousStates(c_doubles(nominal), f.nx)
    x = np.zeros(f.nx)
    me.getContinuousStates(c_doubles(x), f.nx)
    x = x + 0.05 * nominal * rng.standard_normal(f.nx)      # away from the (symmetric) start
    me.setTime(0.05)

    def evaluate(xx):
        me.setContinuousStates(c_doubles(np.ascontiguousarray(xx)), f.nx)
        dx = np.zeros(f.nx)
        me.getDerivatives(c_doubles(dx), f.nx)
        return np.concatenate([dx, np.asarray(me.getReal(outs) if outs else [], float)])

    evaluate(x)
    J = directional_jacobian(me, ders + outs, [f.vr[n] for n in f.states] + ins)
    steps = [1e-5 * max(abs(x[j]), nominal[j]) for j in range(f.nx)]
    pairs = _central_differences(lambda j, d: evaluate(x + d * np.eye(f.nx)[j]), steps)
    evaluate(x)
    inputs = [_InputProbe(me, vr, excitation.get(n, float(f.vars[n].start or 0.0)), lambda: evaluate(x))
              for n, vr in zip(f.inputs, ins, strict=True)]
    if inputs:
        pairs_u = _central_differences(lambda k, d: inputs[k](d), [p.step for p in inputs])
        if f.nx:
            pairs = [(np.hstack([F, Fu]), np.hstack([F2, F2u])) for (F, F2), (Fu, F2u) in zip(pairs, pairs_u,
                                                                                             strict=True)]
        else:
            pairs = pairs_u
    compare("ME d(der, outputs)/d(states, inputs)", J, pairs, np.concatenate([nominal, np.ones(len(ins))]),
            (f.derivatives + f.outputs, f.states + f.inputs))
    free(me)


def _co_simulation(f: Fmu, compare: _Comparison) -> None:
    outs = [f.vr[n] for n in f.outputs]
    ins = [f.vr[n] for n in f.inputs]
    excitation = f.real_excitation()
    cs = f.instance("CS")
    start(f, cs, "CS", f.excitation())
    step = f.md.defaultExperiment.stepSize if f.md.defaultExperiment else None
    cs.doStep(0.0, 0.01 if f.is_flexlink or not step else float(step))
    J = directional_jacobian(cs, outs, ins)
    probes = [_InputProbe(cs, vr, excitation.get(n, float(f.vars[n].start or 0.0)),
                          lambda: np.asarray(cs.getReal(outs), float))
              for n, vr in zip(f.inputs, ins, strict=True)]
    pairs = _central_differences(lambda k, d: probes[k](d), [p.step for p in probes])
    compare("CS d(outputs)/d(inputs)", J, pairs, np.ones(len(ins)), (f.outputs, f.inputs))
    free(cs)


def check_directional_derivatives(f: Fmu, seed: int = 1) -> CheckResult:
    """The check, in each interface that declares ``providesDirectionalDerivative`` (skipped otherwise)."""
    declared = [k for k in f.interfaces if f.can(k, "providesDirectionalDerivative")]
    me = "ME" in declared and (f.nx or f.inputs) and (f.nx or f.outputs)
    cs = "CS" in declared and f.inputs and f.outputs
    if not (me or cs):
        why = ("providesDirectionalDerivative is not declared" if not declared else
               "no Real knowns and unknowns to differentiate")
        return skipped("directional-derivatives", why)
    t0 = time.perf_counter()
    compare = _Comparison()
    try:
        if me:
            _model_exchange(f, np.random.default_rng(seed), compare)
        if cs:
            _co_simulation(f, compare)
    except Exception as e:
        compare.found.append(Finding("legal-call", f"{type(e).__name__}: {e}", sequence=isolation.recent()))
    found = compare.found
    res = (f"worst column error {compare.worst:.2e} beyond the differences' own error"
           + (f"; {len(found)} failure(s)" if found else ""))
    return CheckResult("directional-derivatives", "random state about the start, t = 0.05 s",
                       f"central differences, tolerance {FD_TOLERANCE}", res, seconds=time.perf_counter() - t0,
                       details=[x.message for x in found] + compare.details, findings=found)
