"""Reference simulation of a symbolic model with CasADi's CVODES, to check everything else against.

The state is (q, v) and q̈ = −M(q)⁻¹ r(q, v, 0, u, p) (r is affine in the acceleration).  Inputs are
piecewise constant and built-in joint laws piecewise analytic: the integrator is restarted at every
switch (CVODES, called once across an input discontinuity at tight tolerances, fails: it was observed to).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import casadi as ca
import numpy as np
import numpy.typing as npt

from flexlink.mechanics.model import SymbolicModel
from flexlink.scene.loader import Trajectory

Symbol = TypeVar("Symbol", ca.SX, ca.MX)


@dataclass
class ReferenceResult:
    """The reference trajectory at the requested times: states, accelerations, inputs and outputs.

    Rows are times; ``y`` holds every output of the model, so a test compares any of them with the FMU's.
    """

    time: np.ndarray
    q: np.ndarray          # (len(time), n_q)
    v: np.ndarray
    a: np.ndarray
    u: np.ndarray          # model inputs at each time
    y: np.ndarray          # outputs, in model.outputs order

    def output(self, model: SymbolicModel, name: str) -> np.ndarray:
        """The time series of the output ``name`` (as the FMU names it) of ``model``."""
        return self.y[:, model.output_index(name)]


def _law_expression(trajectory: Trajectory, t: Symbol, t_mid: float) -> tuple[Symbol, Symbol, Symbol]:
    """(θ, θ̇, θ̈) of the law's segment that holds at t_mid, symbolic in t."""
    seg = trajectory.segments[-1]
    for s in trajectory.segments:
        if t_mid < s.until:
            seg = s
            break
    theta = sum((c * t**k for k, c in enumerate(seg.poly)), 0 * t)
    for amp, w, phase in seg.cos:
        theta += amp * ca.cos(w * t + phase)
    theta_d = ca.jacobian(theta, t)
    return theta, theta_d, ca.jacobian(theta_d, t)


def simulate_reference(model: SymbolicModel, times: npt.ArrayLike, *,
                       inputs: Sequence[tuple[float, Mapping[str, float]]] | None = None,
                       p: npt.ArrayLike | None = None, q0: npt.ArrayLike | None = None,
                       v0: npt.ArrayLike | None = None,
                       rtol: float = 1e-11, atol: float = 1e-13) -> ReferenceResult:
    """Integrate the model over ``times`` (increasing, times[0] the start).

    ``inputs``: list of ``(t_switch, {input name: value})`` pieces (held until the next switch),
    applied on top of the inputs' start values; built-in laws are evaluated exactly.
    """
    times = np.asarray(times, dtype=float)
    p = model.p0 if p is None else np.asarray(p, dtype=float)
    qs, vs = model.start_state()
    q0 = qs if q0 is None else np.asarray(q0, dtype=float)
    v0 = vs if v0 is None else np.asarray(v0, dtype=float)
    names = [s.name for s in model.inputs]
    pieces = sorted(inputs or [], key=lambda x: x[0])

    n = model.n_q
    # scalar expressions for small models: CVODES calls them many times, and SX calls are cheap
    # Any: SX or MX is chosen by size, and CasADi's stubs type each overload for one of them, never their union
    sym: Any = ca.SX if n <= 24 else ca.MX
    residual = model.residual.expand() if sym is ca.SX else model.residual
    q, v, a = sym.sym("q", n), sym.sym("v", n), sym.sym("a", n)
    t = sym.sym("t")
    u_base = sym.sym("u_base", len(names))
    pp = sym.sym("p", len(p))
    r = residual(q, v, a, u_base, pp)
    M = ca.jacobian(r, a)
    rhs_acc = -ca.solve(ca.substitute(M, a, ca.DM.zeros(n)), ca.substitute(r, a, ca.DM.zeros(n)))
    accel = ca.Function("accel", [q, v, u_base, pp], [rhs_acc])

    # switch times: input changes and law segment boundaries
    switches = {float(ts) for ts, _ in pieces}
    for law in model.laws:
        if law.trajectory is not None:
            switches |= {s.until for s in law.trajectory.segments if np.isfinite(s.until)}
    t0, tf = times[0], times[-1]
    bounds = [t0] + sorted(s for s in switches if t0 < s < tf) + [tf]

    def base_inputs(tm: float) -> np.ndarray:
        u = np.array([s.start for s in model.inputs], dtype=float)
        for ts, values in pieces:
            if ts <= tm:
                for k, val in values.items():
                    u[names.index(k)] = val
        return u

    x = np.concatenate([q0, v0])
    out_t, out_x = [t0], [x.copy()]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        mid = 0.5 * (lo + hi)
        ub = base_inputs(mid)
        u_sym = sym(ca.DM(ub))
        for law in model.laws:
            if law.trajectory is not None:
                th = _law_expression(law.trajectory, t, mid)
                u_sym = ca.vertcat(u_sym[:law.u_offset], *th, u_sym[law.u_offset + 3:])
        xs = sym.sym("x", 2 * n)
        ode = ca.vertcat(xs[n:], accel(xs[:n], xs[n:], u_sym, pp))
        grid = [tm for tm in times if lo < tm <= hi]
        if not grid or grid[-1] != hi:
            grid.append(hi)
        F = ca.integrator("ref", "cvodes", {"x": xs, "t": t, "p": pp, "ode": ode}, lo, grid,
                          {"abstol": atol, "reltol": rtol, "max_num_steps": 10**7})
        res = np.asarray(F(x0=x, p=p)["xf"], dtype=float)
        for k, tm in enumerate(grid):
            if any(abs(tm - tt) <= 1e-12 * max(1, abs(tt)) for tt in times) and tm > t0:
                out_t.append(tm)
                out_x.append(res[:, k].copy())
        x = res[:, -1]
    T = np.array(out_t)
    X = np.array(out_x)
    Q, V = X[:, :n], X[:, n:]
    U = np.array([_inputs_at(model, base_inputs, tm) for tm in T])
    A = np.array([np.asarray(accel(Q[i], V[i], U[i], p)).ravel() for i in range(len(T))])
    Y = np.array([np.asarray(model.outputs_function(Q[i], V[i], A[i], U[i], p)).ravel() for i in range(len(T))])
    return ReferenceResult(T, Q, V, A, U, Y)


def _inputs_at(model: SymbolicModel, base_inputs: Callable[[float], np.ndarray], tm: float) -> np.ndarray:
    """The full input vector at ``tm``: the held inputs, the built-in laws' (θ, θ̇, θ̈) evaluated exactly."""
    u = base_inputs(tm)
    for law in model.laws:
        if law.trajectory is not None:
            u[law.u_offset:law.u_offset + 3] = law.trajectory.evaluate(tm)
    return u
