"""Speed against error (``flexlink bench``): SS22 in the FMU against the integrators a user would pick.

Every method integrates the same equations (the scene's symbolic model) over the same manoeuvre: for a
torque-driven first joint +τ for 1 s, −τ for 1 s, then free (issue 6's scene), for a position-driven one
its built-in law.  The error of a run is the largest, over the named outputs, of its RMS deviation from
the reference at 10 ms samples (a fiftieth of a horizon below 0.5 s) divided by the output's RMS.  The
reference is CVODES at rtol 1e-12 (1e-10 with --quick, over a horizon :func:`bench_horizon` may shorten); its
own accuracy is stated (its difference from the run at rtol 1e-13, 1e-9 with --quick), and a row whose error
is not above it is flagged, so that no method is judged below it.  Times are CPU
seconds per simulated second of the integration alone (integrator construction and, for the FMU, the
Python loop are not charged: the FMU is timed with one fmi2DoStep per input switch), medians of
``repeats`` runs.
"""

from __future__ import annotations

import dataclasses
import itertools
import statistics
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.mechanics.model import SymbolicModel
from flexlink.mechanics.reference import simulate_reference
from flexlink.run.host import FmuCallError, FmuHost


@dataclass
class BenchCase:
    """A manoeuvre to measure: the model, its duration, sample times, piecewise-constant inputs, outputs."""

    model: SymbolicModel
    stop: float
    times: np.ndarray
    pieces: list                      # [(t, {input: value})], piecewise-constant inputs
    outputs: list[str]
    switches: list[float] = field(default_factory=list)

    def inputs_at(self, t: float) -> dict[str, float]:
        """The inputs in force at time ``t`` (a switch at ``t`` included)."""
        out: dict[str, float] = {}
        for ts, values in self.pieces:
            if ts <= t + 1e-12:
                out.update(values)
        return out


@dataclass
class BenchRow:
    """One method at one setting.

    For the FMU's SS22 rows also the integrator's work per internal step (factorisations and Newton
    iterations, from its logStatistics counters); a setting the FMU refused (fmi2Discard or fmi2Error) is a
    failed row: no cost or error, the FMU's reason in ``failure``.
    """

    method: str
    setting: str
    cpu_s_per_simulated_s: float
    error: float
    lu_per_step: float | None = None
    iterations_per_step: float | None = None
    failure: str | None = None

    def as_dict(self) -> dict:
        """The row for the JSON report (a failed row's figures are null)."""
        failed = self.failure is not None           # no figures (JSON has no NaN)
        return {"method": self.method, "setting": self.setting,
                "cpu_s_per_simulated_s": None if failed else self.cpu_s_per_simulated_s,
                "error": None if failed else self.error,
                "lu_per_step": self.lu_per_step, "iterations_per_step": self.iterations_per_step,
                "failure": self.failure}


def default_case(model: SymbolicModel, stop: float = 5.0, torque: float = 0.2, sample: float = 0.01) -> BenchCase:
    """The bench's manoeuvre, sampled every ``sample`` s.

    A torque-driven first joint gets +``torque`` for 1 s, −``torque`` for 1 s, then none; its angle and the
    last link's tip deflection are the outputs.  Otherwise the scene's first position law must be a built-in
    trajectory; the tip deflection and the first joint's torque are the outputs.  The tip is the last link's
    that bends in plane (a rigid tool at the end of the chain is passed over).
    """
    scene = model.scene
    joint = scene.joints[0].name
    deflections = {s.name for s in model.outputs if s.name.endswith(".tip.v")}
    # the last link that bends in plane (a rigid tool at the end has no tip deflection)
    link = next((k.name for k in reversed(scene.links) if f"{k.name}.tip.v" in deflections), None)
    if link is None:
        raise FlexlinkError("flexlink bench needs a link with an in-plane tip deflection (deformation \"v\")")
    names = [s.name for s in model.inputs]
    outputs = [f"{joint}.theta", f"{link}.tip.v"]
    pieces: list = []
    if f"{joint}.tau" in names:
        pieces = [(0.0, {f"{joint}.tau": torque}), (1.0, {f"{joint}.tau": -torque}), (2.0, {f"{joint}.tau": 0.0})]
    elif model.laws and model.laws[0].trajectory is not None:
        outputs = [f"{link}.tip.v", f"{joint}.tau"]
    else:
        raise FlexlinkError("flexlink bench needs a torque-driven first joint or a built-in trajectory")
    if not (stop > 0 and sample > 0 and np.isfinite(stop) and np.isfinite(sample)):
        raise FlexlinkError(f"the bench's manoeuvre: stop = {stop:g} s and sample = {sample:g} s must be > 0")
    # the sample times in [0, stop] (rounding to the nearest count put one past stop, outside every method's run)
    samples = int(np.floor(stop / sample + 1e-9))
    times = np.round(np.arange(samples + 1) * sample, 12)
    switches = sorted({ts for ts, _ in pieces if 0 < ts < stop})
    return BenchCase(model, stop, times, pieces, outputs, switches)


def relative_error(case: BenchCase, y: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> float:
    """The largest, over the case's outputs, RMS error against ``ref`` divided by the reference's RMS."""
    return max(float(np.sqrt(np.mean((y[n] - ref[n]) ** 2)) / max(np.sqrt(np.mean(ref[n] ** 2)), 1e-300))
               for n in case.outputs)


def start_state(case: BenchCase) -> tuple[np.ndarray, np.ndarray]:
    """(q, v) the FMU starts the case from.

    A coordinate the scene starts in static equilibrium is solved for as the FMU does it (laws at rest), so
    that every method, the reference included, integrates from the same state.
    """
    from flexlink.mechanics.analysis import static_deflection

    model = case.model
    q0, v0 = model.start_state()
    if model.static_coordinates:
        u0 = model.default_inputs(0.0)
        for law in model.laws:
            u0[law.u_offset + 1:law.u_offset + 3] = 0.0
        q0 = static_deflection(model, q0, v0, u0, model.p0, model.static_coordinates)
    return q0, v0


def reference_outputs(case: BenchCase, rtol: float = 1e-12) -> dict[str, np.ndarray]:
    """The case's outputs under CVODES, from the state the FMU starts from (:func:`start_state`)."""
    model = case.model
    q0, v0 = start_state(case)
    res = simulate_reference(model, case.times, inputs=case.pieces, q0=q0, v0=v0, rtol=rtol, atol=rtol * 1e-3)
    return {n: res.output(model, n) for n in case.outputs}


# ------------------------------------------------------------------------------------------- the FMU

def time_slave(host: FmuHost, case: BenchCase, start: dict, repeats: int) -> float:
    """Median CPU seconds per simulated second of a Co-Simulation :class:`FmuHost` over ``case``.

    Reset, ``start`` set (each with its type's setter), then one fmi2DoStep per input switch, so that no
    Python loop is charged; an interval longer than a tenth of what one fmi2DoStep may integrate
    (``DOSTEP_MAX_INTERNAL_STEPS`` internal steps, which the FMU refuses to exceed) is split into doSteps of
    that length, a handful of calls. A refusal is a :class:`FmuCallError` with the FMU's reason.
    """
    from flexlink.scene.solver import DOSTEP_MAX_INTERNAL_STEPS

    slave, vr = host.instance, host.vr
    bounds = [0.0, *case.switches, case.stop]
    cpu = []
    for _ in range(repeats):
        host.initialize(start)
        longest = host.get_real(["solver.step"])[0] * DOSTEP_MAX_INTERNAL_STEPS / 10
        t0 = time.process_time()
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
            u = case.inputs_at(lo)
            if u:
                slave.setReal([vr[k] for k in u], list(u.values()))
            pieces = min(max(1, int(np.ceil((hi - lo) / longest))), 1000)   # beyond: the FMU says why
            for a, b in itertools.pairwise(np.linspace(lo, hi, pieces + 1)):
                host.call("fmi2DoStep", slave.doStep, float(a), float(b - a))
        cpu.append(time.process_time() - t0)
    return statistics.median(cpu) / case.stop


def bench_ss22(case: BenchCase, fmu, steps, thetas, ref, repeats: int = 5, order: int = 2) -> list[BenchRow]:
    """SS22 through the FMU at each step and Θ: cost, error, and the integrator's work per internal step.

    A setting the FMU refuses is recorded as a failed row with the FMU's reason, and the study goes on.
    """
    from flexlink.run.simulate import SlaveRunner

    rows = []
    method = "ss22 (FMU)" if order == 2 else "ss22 order 4 (FMU, Richardson)"
    for theta in thetas:
        for h in steps:
            settings = dataclasses.replace(case.model.scene.fmu.solver, step=h, theta=theta, order=order)
            start = settings.start_values()
            setting = f"step={h:g}" + ("" if theta == (0.5, 0.5) else f", theta={theta[0]:g}/{theta[1]:g}")
            with SlaveRunner(fmu) as runner:      # a fresh instance: a refused setting leaves its own broken
                try:
                    res = runner.run(case.stop, float(case.times[1] - case.times[0]), inputs=case.inputs_at,
                                     start=start, outputs=case.outputs)
                    stats = runner.solver_statistics()
                    cost = time_slave(runner, case, start, repeats)
                except FmuCallError as e:
                    reason = e.reason
                    rows.append(BenchRow(method, setting, float("nan"), float("nan"), failure=reason))
                    continue
            per_step = {k: stats[k] / stats["steps"] for k in ("factorisations", "newton_iterations")} \
                if stats.get("steps") else {}
            rows.append(BenchRow(method, setting, cost, relative_error(case, res, ref),
                                 per_step.get("factorisations"), per_step.get("newton_iterations")))
    return rows


# ------------------------------------------------------------------------------- the same equations

def _ode(model: SymbolicModel):
    """X' = (v, a(q, v, u, p)) as SX, with the inputs' values and the parameters as the integrator's p."""
    n = model.n_q
    f = model.residual.expand()
    x = ca.SX.sym("x", 2 * n)
    u = ca.SX.sym("u", f.size1_in(3))
    p = ca.SX.sym("p", f.size1_in(4))
    a = ca.SX.sym("a", n)
    r = f(x[:n], x[n:], a, u, p)
    M = ca.substitute(ca.jacobian(r, a), a, ca.DM.zeros(n))
    acc = -ca.solve(M, ca.substitute(r, a, ca.DM.zeros(n)))
    return x, u, p, ca.vertcat(x[n:], acc)


def _law_switches(case: BenchCase) -> set[float]:
    """The ends of the built-in laws' segments inside the case (where a law's acceleration may jump)."""
    return {s.until for law in case.model.laws if law.trajectory is not None
            for s in law.trajectory.segments if 0.0 < s.until < case.stop}


def _segments(case: BenchCase):
    """(start, end, sample times in (start, end]) of each interval between input switches and law segment ends.

    An integrator is restarted at each, as the reference is (CVODES across a jump at tight tolerances fails).
    """
    bounds = [0.0, *sorted(set(case.switches) | _law_switches(case)), case.stop]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        grid = [t for t in case.times if lo < t <= hi + 1e-12]
        if not grid or abs(grid[-1] - hi) > 1e-12:
            grid.append(hi)         # a law's segment end between samples: the restart's state
        yield lo, hi, grid


def _model_inputs(case: BenchCase, t: float) -> np.ndarray:
    u = case.model.default_inputs(t)
    names = [s.name for s in case.model.inputs]
    for k, val in case.inputs_at(t).items():
        u[names.index(k)] = val
    return u


def _outputs(case: BenchCase, X: np.ndarray) -> dict[str, np.ndarray]:
    model, n = case.model, case.model.n_q
    mass = model.mass_matrix_function()
    rows = []
    for k, t in enumerate(case.times):
        q, v = X[k, :n], X[k, n:]
        u = _model_inputs(case, float(t))
        M = np.asarray(mass(q, u, model.p0))
        a = -np.linalg.solve(M, np.asarray(model.residual(q, v, np.zeros(n), u, model.p0)).ravel())
        rows.append(np.asarray(model.outputs_function(q, v, a, u, model.p0)).ravel())
    Y = np.array(rows)
    return {name: Y[:, model.output_index(name)] for name in case.outputs}


def _check_host_laws(case: BenchCase) -> None:
    """Refuse a host-driven law that moves (one clear error, no traceback).

    The FMU extends such a law in time from the moment the host sets it (θ_ref + ω_ref s + α_ref s²/2), which
    depends on how often the host calls, not on the case alone.
    """
    for law in case.model.laws:
        if law.trajectory is None:
            for lo, _hi, _grid in _segments(case):
                if np.any(_model_inputs(case, lo)[law.u_offset + 1:law.u_offset + 3] != 0.0):
                    raise FlexlinkError(
                        f'the CasADi and SciPy comparisons cannot follow joint "{law.joint}": its law is set by the '
                        "host with a non-zero rate or acceleration, which the FMU extends in time from each call "
                        "(give it a built-in trajectory, or hold it)")


def _segment_ode(case: BenchCase, ode, lo: float, hi: float):
    """(x, t, the integrator's p, X') on [lo, hi], the same equations as the FMU's.

    The held inputs and the parameters are p; the built-in laws' (θ, θ̇, θ̈) are the functions of t the FMU
    evaluates (the law's segment that holds on the interval), as in the reference.
    """
    from flexlink.mechanics.reference import _law_expression

    x, u, p, rhs = ode
    t = ca.SX.sym("t")
    u_t = u
    for law in case.model.laws:
        if law.trajectory is not None:
            o = law.u_offset
            u_t = ca.vertcat(u_t[:o], *_law_expression(law.trajectory, t, 0.5 * (lo + hi)), u_t[o + 3:])
    return x, t, ca.vertcat(u, p), ca.substitute(rhs, u, ca.densify(u_t))


def casadi_integrators(case: BenchCase, plugin: str, tol: float, ode=None, max_order: int | None = None) -> list[tuple]:
    """One of CasADi's SUNDIALS integrators per interval of :func:`_segments`: (integrator, its p value).

    ``max_order`` caps the BDF order (SUNDIALS' default 5): above 2 BDF is not A-stable, and undamped modes far
    above the step, a stiff FE beam's, force high orders into tiny steps where BDF2 takes large ones.
    """
    _check_host_laws(case)
    ode = ode or _ode(case.model)
    out = []
    for lo, hi, grid in _segments(case):
        x, t, pp, rhs = _segment_ode(case, ode, lo, hi)
        F = ca.integrator("F", plugin, {"x": x, "t": t, "p": pp, "ode": rhs}, lo, grid,
                          {"abstol": tol * 1e-3, "reltol": tol, "max_num_steps": 10**7}
                          | ({"max_order": max_order} if max_order else {}))
        out.append((F, np.concatenate([_model_inputs(case, lo), case.model.p0]), grid))
    return out


def _on_times(case: BenchCase, pieces: list[tuple[list[float], np.ndarray]]) -> np.ndarray:
    """The states at ``case.times`` (rows) from the intervals' (grid, states) and the start state."""
    times, xs = [0.0], [np.concatenate(start_state(case))]
    for grid, X in pieces:
        times.extend(grid)
        xs.extend(X)
    keep = [next(k for k, tk in enumerate(times) if abs(tk - t) <= 1e-12) for t in case.times]
    return np.array(xs)[keep]


def casadi_states(case: BenchCase, plugin: str, tol: float, repeats: int = 5, ode=None,
                  max_order: int | None = None) -> tuple[float, np.ndarray]:
    """One of CasADi's SUNDIALS integrators (CVODES, IDAS) over ``case``, from the FMU's start state.

    Restarted at every input switch and every end of a built-in law's segment.  Returns the median CPU
    seconds per simulated second and the states (q, v) at ``case.times`` (rows).
    """
    integrators = casadi_integrators(case, plugin, tol, ode, max_order)
    x0 = np.concatenate(start_state(case))
    cpu = []
    for _ in range(repeats):
        pieces = []
        xk = x0
        t0 = time.process_time()
        for F, pk, grid in integrators:
            res = np.asarray(F(x0=xk, p=pk)["xf"])
            pieces.append((grid, res.T))
            xk = res[:, -1]
        cpu.append(time.process_time() - t0)
    return statistics.median(cpu) / case.stop, _on_times(case, pieces)


def bench_casadi(case: BenchCase, plugin: str, tolerances, ref, repeats: int = 5,
                 max_order: int | None = None) -> list[BenchRow]:
    """CasADi's SUNDIALS integrators (CVODES, IDAS), restarted at every input switch.

    With ``max_order`` the method is named for it ("cvodes BDF<=2").
    """
    ode = _ode(case.model)
    rows = []
    name = f"{plugin} BDF<={max_order}" if max_order else plugin
    for tol in tolerances:
        cpu, X = casadi_states(case, plugin, tol, repeats, ode, max_order)
        y = _outputs(case, X)
        rows.append(BenchRow(name, f"rtol={tol:g}", cpu, relative_error(case, y, ref)))
    return rows


def bench_scipy(case: BenchCase, method: str, tolerances, ref, repeats: int = 3) -> list[BenchRow]:
    """SciPy's solve_ivp on the same equations (right-hand side and Jacobian from CasADi)."""
    from scipy.integrate import solve_ivp

    _check_host_laws(case)
    ode = _ode(case.model)
    segments = []
    for lo, hi, grid in _segments(case):
        x, t, pp, rhs = _segment_ode(case, ode, lo, hi)
        pk = np.concatenate([_model_inputs(case, lo), case.model.p0])
        f = ca.Function("f", [t, x, pp], [rhs])
        jac = ca.Function("ode_jacobian", [t, x, pp], [ca.jacobian(rhs, x)])
        segments.append((lo, hi, grid, pk, f, jac))
    x0 = np.concatenate(start_state(case))
    rows = []
    for tol in tolerances:
        cpu = []
        for _ in range(repeats):
            pieces = []
            xk = x0
            t0 = time.process_time()
            for lo, hi, grid, pk, f, jac in segments:
                kwargs = {}
                if method in ("Radau", "BDF", "LSODA"):
                    kwargs["jac"] = lambda t, y, pk=pk, jac=jac: np.asarray(jac(t, y, pk))
                sol = solve_ivp(lambda t, y, pk=pk, f=f: np.asarray(f(t, y, pk)).ravel(), (lo, hi), xk,
                                method=method, t_eval=grid, rtol=tol, atol=tol * 1e-3, **kwargs)
                pieces.append((grid, sol.y.T))
                xk = sol.y[:, -1]
            cpu.append(time.process_time() - t0)
        y = _outputs(case, _on_times(case, pieces))
        rows.append(BenchRow(f"scipy {method}", f"rtol={tol:g}", statistics.median(cpu) / case.stop,
                             relative_error(case, y, ref)))
    return rows


def model_exchange_inputs(case: BenchCase) -> np.ndarray | None:
    """Fmpy's input table of a case.

    A switch is two rows at the same time (fmpy's discontinuity), the value before and after; the last row
    holds the value of the last interval (fmpy interpolates linearly between rows: a switch at the stop time
    itself would otherwise ramp the whole last interval).
    """
    names = [s.name for s in case.model.inputs if s.fmu_variable]
    if not names:
        return None
    rows_in = []
    for t in [0.0, *case.switches, case.stop]:
        for side in ((t - 1e-6, t) if 0 < t < case.stop else (t - 1e-6,) if t == case.stop else (t,)):
            u = case.inputs_at(side)
            rows_in.append((t, *[u.get(n, 0.0) for n in names]))
    return np.array(rows_in, dtype=[("time", float), *[(n, float) for n in names]])


def run_model_exchange(case: BenchCase, fmu, *, solver: str = "CVode", relative_tolerance: float | None = None,
                       step_size: float | None = None, timeout: float | None = None
                       ) -> tuple[dict[str, np.ndarray], float]:
    """The case's outputs on its sample grid from the FMU's Model Exchange interface, and the CPU seconds.

    Under one of fmpy's solvers (CVode, or its explicit Euler at ``step_size``).  Past ``timeout`` wall-clock
    seconds fmpy stops early: a TimeoutError, not a short result.
    """
    import fmpy

    sample = float(case.times[1] - case.times[0])
    t0 = time.process_time()
    res = fmpy.simulate_fmu(str(fmu), fmi_type="ModelExchange", solver=solver, relative_tolerance=relative_tolerance,
                            step_size=step_size, stop_time=case.stop, output_interval=sample,
                            input=model_exchange_inputs(case), output=case.outputs, timeout=timeout)
    cpu = time.process_time() - t0
    if res["time"][-1] < case.stop - 0.5 * sample:
        raise TimeoutError(f"stopped at t = {res['time'][-1]:g} s after {timeout:g} s of wall-clock time")
    return {n: np.interp(case.times, res["time"], res[n]) for n in case.outputs}, cpu


def bench_model_exchange(case: BenchCase, fmu, tolerances, ref, repeats: int = 3) -> list[BenchRow]:
    """The same FMU's Model Exchange interface under fmpy's CVODE (what an FMI host would run).

    Restarted at the input switches by fmpy's input handling; the time includes fmpy's Python loop around the
    FMU calls.
    """
    rows = []
    for tol in tolerances:
        runs = [run_model_exchange(case, fmu, relative_tolerance=tol) for _ in range(repeats)]
        y = runs[-1][0]
        rows.append(BenchRow("fmpy CVODE (ME)", f"rtol={tol:g}", statistics.median(c for _, c in runs) / case.stop,
                             relative_error(case, y, ref)))
    return rows


SAMPLE = 0.01                       # s, the output samples of a horizon of 0.5 s or more
REFERENCE_RTOL = 1e-12              # the reference's CVODES; its error is its difference from rtol 1e-13
QUICK_REFERENCE_RTOL = 1e-10        # --quick's, its error its difference from rtol 1e-9 (CVODES near 1e-12 is slow)
QUICK_STOP = 2.5                    # s, --quick's longest horizon
MIN_STOP = 1e-3                     # s, the shortest horizon
PROBE = 2e-3                        # s, the window --quick times its reference over
QUICK_BUDGET = 2.0                  # CPU s, --quick's reference's and Radau's estimated cost


@dataclass
class Horizon:
    """The bench's horizon (s), why it was chosen (said in the report), the reference's rtol and its check's."""

    stop: float
    why: str
    rtol: float = REFERENCE_RTOL
    check_rtol: float = REFERENCE_RTOL / 10


def check_stop(stop: float | None) -> None:
    """Refuse a ``--stop`` the bench cannot run: not a number of seconds in [1 ms, the scene's stop time]."""
    from flexlink.export.description import DEFAULT_STOP_TIME

    if stop is None:
        return
    if not (np.isfinite(stop) and stop > 0):
        raise FlexlinkError(f"--stop {stop:g}: the bench's horizon must be a number of seconds > 0")
    if stop < MIN_STOP:
        raise FlexlinkError(f"--stop {stop:g} s: the bench's horizon must be at least {MIN_STOP:g} s "
                            "(its outputs are sampled 50 times over it)")
    if stop > DEFAULT_STOP_TIME:
        raise FlexlinkError(f"--stop {stop:g} s is beyond the scene's stop time, {DEFAULT_STOP_TIME:g} s "
                            "(the bench's manoeuvre, and the FMU's DefaultExperiment)")


def bench_horizon(model: SymbolicModel, quick: bool, stop: float | None = None) -> Horizon:
    """The horizon of a bench run: ``stop``, the whole manoeuvre (5 s), or for ``quick`` at most 2.5 s.

    A quick run takes less where the reference would be slow.  Its reference is CVODES at rtol 1e-10, its
    error stated as its difference from rtol 1e-9 (an over-estimate: mostly the looser run's error); a full
    run's at 1e-12 against 1e-13.  The quick horizon comes from the cost of the reference and of SciPy's Radau
    at rtol 1e-6 (its Python right-hand side made a stiff plate's quick run slow where the reference was cheap),
    timed (CPU, integration alone) over the first 2 ms of the manoeuvre: the longest of 1, 2 or 5 × 10ᵏ s up to
    2.5 s over which the two cost at most ``QUICK_BUDGET`` CPU seconds, and no shorter than 1 ms.  Timed, not estimated
    from the scene: a rule from the highest mode and the coordinate count (CVODES's BDF steps at a fraction of
    the highest mode's period on undamped stiff modes), n² (0.05 + 2e-4 f_max) CPU s per simulated s, fitted
    fast_two_link (26 coordinates, 16 kHz: about 2000) but missed six_axis_arm_torque (19 coordinates, 5.2 kHz:
    about 3200, 8× the rule).  The first 2 ms cost more than the average (CVODES starts with small steps), so
    the horizon errs short.
    """
    from flexlink.export.description import DEFAULT_STOP_TIME

    quick_tols = (QUICK_REFERENCE_RTOL, QUICK_REFERENCE_RTOL * 10)
    if stop is not None:
        return Horizon(stop, "--stop", *(quick_tols if quick else (REFERENCE_RTOL, REFERENCE_RTOL / 10)))
    if not quick:
        return Horizon(DEFAULT_STOP_TIME, "the whole manoeuvre")
    probe = default_case(model, stop=PROBE, sample=PROBE / 50)
    ref_rate, X = casadi_states(probe, "cvodes", QUICK_REFERENCE_RTOL, 1)       # CPU s per simulated s
    radau_rate = bench_scipy(probe, "Radau", [1e-6], _outputs(probe, X), 1)[0].cpu_s_per_simulated_s
    rate = ref_rate + radau_rate
    if rate * QUICK_STOP <= QUICK_BUDGET:
        return Horizon(QUICK_STOP, "--quick", *quick_tols)
    fit = QUICK_BUDGET / rate
    power = 10.0 ** np.floor(np.log10(fit))
    short = max(MIN_STOP, max(m * power for m in (1, 2, 5) if m * power <= fit * (1 + 1e-12)))
    return Horizon(float(f"{short:.3g}"), f"--quick, shortened: the reference and SciPy's Radau at rtol 1e-6 took "
                   f"{ref_rate:.3g} and {radau_rate:.3g} CPU s per simulated s over the first {PROBE * 1e3:g} ms",
                   *quick_tols)


def bench_case(model: SymbolicModel, quick: bool, stop: float | None = None) -> tuple[BenchCase, Horizon]:
    """The bench's manoeuvre over :func:`bench_horizon`'s horizon and the horizon.

    Sampled every 10 ms or, below 0.5 s, every fiftieth of it (a window of a few milliseconds still has samples
    to measure an error at).
    """
    horizon = bench_horizon(model, quick, stop)
    return default_case(model, stop=horizon.stop, sample=min(SAMPLE, horizon.stop / 50)), horizon


def reference_pair(case: BenchCase, rtol: float, check_rtol: float
                   ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The reference's outputs and the same at ``check_rtol``, whose difference is its stated error.

    CVODES at ``rtol`` on the bench's own ODE, as scalar expressions (flexlink.mechanics.reference's form above
    24 coordinates took over a minute for 1 ms of fast_two_link's 26).
    """
    ode = _ode(case.model)
    ref, check = (_outputs(case, casadi_states(case, "cvodes", tol, 1, ode)[1]) for tol in (rtol, check_rtol))
    return ref, check


def run_bench(scene_path, *, quick: bool = False, repeats: int | None = None,
              stop: float | None = None) -> tuple[list[BenchRow], dict]:
    """The work–precision study of a scene; ``quick`` for CI-sized runs, ``stop`` the horizon (s).

    The case is :func:`bench_case`'s; SS22's steps shrink with its sample (at most 0.4 of it), so that a short
    window is still measured at steps that resolve it.
    """
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene

    check_stop(stop)                                    # before the model is built
    scene = load_scene(scene_path)
    model = build_model(scene)
    case, horizon = bench_case(model, quick, stop)
    repeats = repeats or (2 if quick else 5)
    ref, ref_check = reference_pair(case, horizon.rtol, horizon.check_rtol)
    still = [name for name in case.outputs if not np.any(ref[name])]
    if still:       # a relative error against an output that stays exactly 0 says nothing
        raise FlexlinkError(f"the bench's manoeuvre leaves {' and '.join(still)} at exactly 0 on this scene "
                            f"(nothing drives it: a held joint and no load), so there is no error to measure; "
                            f"give the scene a torque-driven first joint, a moving trajectory or gravity")
    sample = float(case.times[1] - case.times[0])
    info = {"scene": str(scene_path), "outputs": case.outputs, "stop_time": case.stop, "sample": sample,
            "horizon": horizon.why, "reference": f"CVODES rtol {horizon.rtol:g}",
            "reference_check": f"rtol {horizon.check_rtol:g}", "reference_error": relative_error(case, ref, ref_check)}
    scale = sample / SAMPLE
    steps = [h * scale for h in ([4e-3, 2e-3, 1e-3, 5e-4] if quick else
                                 [8e-3, 4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4])]
    thetas = [(0.5, 0.5)] if quick else [(0.5, 0.5), (0.6, 0.6)]
    tols = [1e-4, 1e-6] if quick else [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9]
    fmu = cached_fmu(scene, model=model)      # built once per scene and flexlink (what `flexlink run` uses)
    rows = bench_ss22(case, fmu, steps, thetas, ref, repeats)
    rows += bench_ss22(case, fmu, steps, [(0.5, 0.5)], ref, repeats, order=4)
    rows += bench_model_exchange(case, fmu, tols[:2] if quick else tols[:5], ref, max(1, repeats // 2))
    rows += bench_casadi(case, "cvodes", tols, ref, repeats)
    rows += bench_casadi(case, "idas", tols, ref, repeats)
    for method in (["Radau"] if quick else ["Radau", "LSODA", "DOP853"]):
        rows += bench_scipy(case, method, tols[:2] if quick else tols[:5], ref, max(1, repeats // 2))
    return rows, info


def plot_bench(rows: list[BenchRow], info: dict, path) -> None:
    """Write the speed-against-error plot of the rows (one series per method) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    for method in dict.fromkeys(r.method for r in rows):
        pts = sorted((r.error, r.cpu_s_per_simulated_s) for r in rows if r.method == method and r.failure is None)
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=method)
    ax.axvline(info["reference_error"], color="gray", ls=":", lw=1, label="reference accuracy")
    ax.set_xlabel("relative RMS error (" + ", ".join(info["outputs"]) + ")")
    ax.set_ylabel("CPU s per simulated s")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(f"work-precision: {info['scene']}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report_markdown(rows: list[BenchRow], info: dict) -> str:
    """The bench's report as Markdown: the case, the reference's own error, and one table row per row.

    A row whose error is not above the reference's own error is flagged: there the error measured is the
    reference's as much as the method's.
    """
    floor = info["reference_error"]
    lines = [f"# Speed against error: {info['scene']}", "",
             f"Outputs {', '.join(info['outputs'])} over {info['stop_time']:g} s ({info.get('horizon', '')}), "
             f"sampled every {info.get('sample', SAMPLE):g} s; reference {info['reference']} (its own error, its "
             f"difference from {info.get('reference_check', 'rtol 1e-13')}: {floor:.1e}).", "",
             "| method | setting | CPU s / simulated s | relative error | LU / step | Newton iterations / step |",
             "| --- | --- | --- | --- | --- | --- |"]
    lines += [_markdown_row(r, floor) for r in rows]
    flagged = sum(below_reference(r, floor) for r in rows)
    if flagged:
        lines += ["", f"{flagged} row(s) marked \"≤ reference\": their error is not above the reference's own, "
                  "so it is not theirs alone."]
    return "\n".join(lines) + "\n"


def below_reference(row: BenchRow, reference_error: float) -> bool:
    """Whether a row's error is not above the reference's own (its error is then not the method's alone)."""
    return row.failure is None and not row.error > reference_error


def rows_json(rows: list[BenchRow], info: dict) -> list[dict]:
    """The rows for ``--json``, each with ``below_reference_error`` (:func:`below_reference`)."""
    return [r.as_dict() | {"below_reference_error": below_reference(r, info["reference_error"])} for r in rows]


def _markdown_row(r: BenchRow, reference_error: float = 0.0) -> str:
    if r.failure is not None:
        return f"| {r.method} | {r.setting} | failed: {r.failure} | – | – | – |"

    def per_step(x):
        return "–" if x is None else f"{x:.3g}"

    flag = " (≤ reference)" if below_reference(r, reference_error) else ""
    return (f"| {r.method} | {r.setting} | {r.cpu_s_per_simulated_s:.3g} | {r.error:.2e}{flag} | "
            f"{per_step(r.lu_per_step)} | {per_step(r.iterations_per_step)} |")
