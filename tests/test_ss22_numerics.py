"""SS22's numerical properties, measured on real FMUs against SS22's own analysis (DESIGN.md §3).

For one undamped mode ü + ω²u = 0 the SS22 step is a linear map x_{n+1} = A x_n of (u, u̇), with A
derived here from the algorithm's formulas (α = −ω²(u + Θ₁Δt u̇)/(1 + Θ₂Δt²ω²/2), u₁ = u + Δt u̇ + Δt²/2 α,
u̇₁ = u̇ + Δt α).  Any sequence it produces obeys u_{n+2} − tr(A) u_{n+1} + det(A) u_n = 0, so the FMU's
own sequence tells tr(A) and det(A) (= ρ², the square of the amplitude ratio per step) by least squares.
"""

from __future__ import annotations

import ctypes
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

from flexlink.export.cache import cached_fmu
from flexlink.mechanics.analysis import linearise, natural_frequencies, operating_point
from flexlink.mechanics.model import build_model
from flexlink.run.simulate import SlaveRunner
from flexlink.scene.loader import load_scene, parse_scene


def ss22_amplification(omega: float, dt: float, theta1: float, theta2: float) -> np.ndarray:
    w2 = omega**2
    d = 1.0 + theta2 * dt**2 * w2 / 2
    # α = c_u u + c_v u̇
    c_u, c_v = -w2 / d, -w2 * theta1 * dt / d
    return np.array([[1 + dt**2 / 2 * c_u, dt + dt**2 / 2 * c_v], [dt * c_u, 1 + dt * c_v]])


def _modal_scene():
    """Seed-000 link, linear kinematics, hub position-driven by a bump then held: afterwards every
    mass-normalised eigenmode is an independent undamped oscillator."""
    return parse_scene({
        "name": "modal",
        "joint": [{"name": "hub", "drive": "position", "trajectory": {"segments": [
            {"until": 0.3, "poly": [0.05], "cos": [[-0.05, 2 * np.pi / 0.3, 0.0]]},
            {"until": float("inf"), "poly": [0.0]}]}}],
        "link": [{"name": "arm", "length": 2.2, "linear_density": 0.349, "EI": 93.72,
                  "shapes": {"kind": "clamped-free", "count": 3}, "kinematics": "linear"}],
    })


@pytest.fixture(scope="module")
def modal_fmu(tmp_path_factory):
    scene = _modal_scene()
    model = build_model(scene)
    fmu = cached_fmu(scene, model=model)
    return model, fmu


@pytest.mark.parametrize("theta", [(0.5, 0.5), (0.5, 0.8), (0.6, 0.6), (0.8, 0.8), (1.0, 1.0)])
def test_numerical_damping_and_frequency_follow_the_ss22_amplification_matrix(modal_fmu, theta):
    model, fmu = modal_fmu
    omega1 = 2 * np.pi * natural_frequencies(model).frequencies_hz[0]
    dt = 0.02                                     # ω₁Δt ≈ 0.24: a visibly damped mode for Θ > ½
    with SlaveRunner(fmu) as runner:
        res = runner.run(3.0, dt, start={"solver.step": dt, "solver.theta1": theta[0], "solver.theta2": theta[1]},
                         outputs=["arm.eta[1]"])
    u = res["arm.eta[1]"][res["time"] > 0.3 + 1e-9]
    X = np.column_stack([u[1:-1], -u[:-2]])
    (tr, det), *_ = np.linalg.lstsq(X, u[2:], rcond=None)
    A = ss22_amplification(omega1, dt, *theta)
    assert tr == pytest.approx(np.trace(A), abs=1e-9)
    assert det == pytest.approx(np.linalg.det(A), abs=1e-9)
    if theta == (0.5, 0.5):
        assert det == pytest.approx(1.0, abs=1e-9)          # Θ = ½: no numerical damping at all


def test_numerical_damping_grows_with_theta():
    rho = [max(abs(np.linalg.eigvals(ss22_amplification(1.0, 0.5, t, t)))) for t in (0.5, 0.6, 0.7, 0.8, 0.9, 1.0)]
    assert rho[0] == pytest.approx(1.0)
    assert all(a > b for a, b in zip(rho[:-1], rho[1:], strict=True))


@pytest.mark.parametrize("theta", [(0.5, 0.5), (0.5, 0.75), (0.8, 0.8), (1.0, 1.0)])
def test_bounded_with_step_ten_times_the_highest_period(tmp_path, theta):
    """Seed 001 §4.9 raise of the FE steel beam with Δt = 10 periods of its highest mode (23 kHz): SS22
    stays bounded for Θ₂ ≥ Θ₁ ≥ ½ and follows the slow motion, where an explicit method explodes.

    (With Θ₁ = ½ < Θ₂ unresolved modes are only marginally stable: alternating step sizes — a regular
    step then a short remainder in every communication step — made this case diverge until the FMU
    split communication steps into equal internal steps.)"""
    scene = load_scene("examples/steel_beam_raise.toml")
    model = build_model(scene)
    lin = linearise(model, operating_point(model))
    w2 = np.real(np.linalg.eigvals(np.linalg.solve(lin.M, lin.K)))
    t_min = 2 * np.pi / np.sqrt(w2.max())
    dt = 10 * t_min
    # central differences are stable only for ω Δt ≤ 2
    assert np.sqrt(w2.max()) * dt > 2 * 30
    fmu = cached_fmu(scene, model=model)
    with SlaveRunner(fmu) as runner:
        fine = runner.run(1.5, 0.01, start={"solver.step": t_min / 10}, outputs=["beam.tip.v"])
        coarse = runner.run(1.5, 0.01, start={"solver.step": dt, "solver.theta1": theta[0],
                                              "solver.theta2": theta[1]}, outputs=["beam.tip.v"])
    peak = np.max(np.abs(fine["beam.tip.v"]))
    assert np.all(np.isfinite(coarse["beam.tip.v"]))
    assert np.max(np.abs(coarse["beam.tip.v"])) < 1.5 * peak
    # the quasi-static motion is still there: once the law holds (t > 1 s) both oscillate about the same
    # mean deflection (Θ > ½ filters the 54 Hz oscillation out, Θ = ½ keeps it)
    late = fine["time"] > 1.0
    assert np.mean(coarse["beam.tip.v"][late]) == pytest.approx(np.mean(fine["beam.tip.v"][late]), abs=0.05 * peak)


def test_order_four_option_converges_at_order_four(tmp_path):
    """solver.order = 4: SS22 with Θ = ½ plus one Richardson extrapolation per step (the symmetric method's
    error expands in even powers of Δt).  Against the CVODES reference, halving the step divides the error by
    16; the option refuses Θ ≠ ½, where the expansion has odd terms.  The steps are within the option's
    stability bound (ω_max Δt ≤ 0.3, tests/test_richardson.py): 1 ms at this link's 34 Hz is 0.21."""
    from fmpy.fmi1 import FMICallException

    fmu, errors, orders = _observed_orders("examples/rotating_link_linear.toml", 2.5, (1e-3, 5e-4, 2.5e-4),
                                           {"solver.order": 4})
    assert all(abs(p - 4.0) < 0.5 for p in orders), (errors, orders)
    with SlaveRunner(fmu) as runner, pytest.raises(FMICallException):
        runner.run(0.1, 0.01, start={"solver.order": 4, "solver.theta1": 0.6, "solver.theta2": 0.6})


def _observed_orders(scene_path: str, stop: float, steps, start: dict, ref_rtol: float = 1e-12):
    """The FMU of a scene, its bench manoeuvre's error against the CVODES reference of the same equations
    (rtol ``ref_rtol``) at each ``solver.step`` of ``steps`` (with the ``start`` values), and the orders
    observed between halvings."""
    from flexlink.tools.bench import default_case, reference_outputs, relative_error

    scene = load_scene(scene_path)
    model = build_model(scene)
    fmu = cached_fmu(scene, model=model)
    case = default_case(model, stop=stop)
    ref = reference_outputs(case, ref_rtol)
    errors = []
    with SlaveRunner(fmu) as runner:
        for h in steps:
            res = runner.run(case.stop, 0.01, inputs=case.inputs_at, start={"solver.step": h, **start},
                             outputs=case.outputs)
            errors.append(relative_error(case, res, ref))
    return fmu, errors, [np.log2(a / b) for a, b in zip(errors[:-1], errors[1:], strict=True)]


def test_a_law_with_jerk_converges_at_second_order():
    """A prescribed law whose jerk is not zero (aluminium_arm_smooth's quintic rest-to-rest law): the law's
    coordinate moves in each step with its mean acceleration (θ̇₁ − θ̇₀)/Δt, so the free coordinates feel the
    trapezoid of its rates and the run keeps SS22's second order.  Moving it so as to land on the end angle
    instead (the first version) is off the mean acceleration by Δt θ⃛/6 at every step: the run converged at
    first order (relative errors 1.04e-3, 4.7e-4, 2.2e-4: orders 1.15, 1.07).  Against the CVODES reference
    of the same equations, halving solver.step divides the error by 4.  (Order 4 is refused at such steps on
    this FE beam: ω_max Δt > 0.3, tests/test_richardson.py.)"""
    _, errors, orders = _observed_orders("examples/aluminium_arm_smooth.toml", 1.0, (2e-3, 1e-3, 5e-4), {})
    assert all(abs(p - 2.0) < 0.3 for p in orders), (errors, orders)


def test_order_four_with_a_jerky_law_converges_at_order_four(tmp_path):
    """solver.order = 4 on a prescribed law whose jerk is not zero (aluminium_arm_smooth's quintic law on the
    same arm with two clamped-free modes, so that steps within order 4's bound ω_max Δt ≤ 0.3 stay
    affordable, and with gravity, so that the residual depends on the law's angle, not only on its rates):
    Richardson's extrapolation needs a step symmetric in time, so the law's weighted angle is
    (θ₀ + θ₁)/2 as a free coordinate's is (θ₀ + Δt(θ̇₀ + θ̇₁)/4, which differs by Δt³θ⃛/24, fell to order 3 on
    a reviewer's one-coordinate model; on this arm the difference is below what this test resolves).
    Against CVODES (rtol 1e-14), halving the step divides the error by 16 (measured 3.98, 3.92)."""
    from flexlink.mechanics.analysis import natural_frequencies

    src = Path("examples/aluminium_arm_smooth.toml").read_text()
    path = tmp_path / "arm_modes.toml"
    path.write_text(src.replace('shapes = { kind = "fe", count = 5 }', 'shapes = { kind = "clamped-free", count = 2 }')
                    .replace("gravity = [0.0, 0.0, 0.0]", "gravity = [0.0, -9.81, 0.0]"))
    omega_max = 2 * np.pi * max(natural_frequencies(build_model(load_scene(path))).frequencies_hz)
    h = 0.3 / omega_max
    # errors down to 1e-10: the reference at rtol 1e-14 (1e-12 is itself off by 5.5e-10 of the peak)
    _, errors, orders = _observed_orders(str(path), 1.0, (h, h / 2, h / 4),
                                         {"solver.order": 4, "solver.tolerance": 1e-13}, ref_rtol=1e-14)
    assert all(abs(p - 4.0) < 0.5 for p in orders), (errors, orders)


def test_one_increment_steps_keep_the_newton_error_far_below_the_step_error():
    """A step accepted after one increment on its matrix's last measured rate (fmu_src/ss22.h) must still be
    converged: its run against the same run iterated to 1e-13 differs by far less than the step's own
    truncation error (the 1e-13 run against the run at h/2, × 4/3).  The 1e-13 run is the reference because it
    is converged: it agrees with the run at 1e-12 to far less again (since the recurrence start, fmu_src/
    predictor.c, a start can be close enough for the one-increment stop even at 1e-13, so the reference is
    shown converged rather than assumed to iterate twice).  Before the rule, rotating_link took 2.00 iterations
    a step at every tolerance (docs/performance.md), so the count below fails without it."""
    r = _newton_study("rotating_link.toml", 1.0, tolerance=1e-6)
    assert r["reference_spread"] < 1e-2 * 1e-3 * r["truncation"]    # the reference: 100× inside the bound judged
    assert r["newton"] < 1e-3 * r["truncation"]
    assert r["iterations"] < 1.5


def _newton_study(scene_name: str, stop: float, tolerance: float | None = None) -> dict:
    """The scene's bench manoeuvre at its own step: the run at ``tolerance`` (default: the scene's) against
    the same run iterated to 1e-13 (Newton error) and the 1e-13 run against the run at h/2, × 4/3 (Richardson's
    estimate of the step's truncation error), both relative to each output's peak; and the counters per step."""
    from flexlink.tools.bench import default_case

    path = Path(__file__).resolve().parent.parent / "examples" / scene_name
    scene = load_scene(path)
    model = build_model(scene)
    case = default_case(model, stop=stop)
    tol = tolerance if tolerance is not None else scene.fmu.solver.tolerance
    fmu = cached_fmu(scene, model=model)
    with zipfile.ZipFile(fmu) as z:      # what a mass update costs, in residuals (fmu_src/mass_update.c)
        config = z.read("sources/config.h").decode()
    update_cost = float(re.search(r"#define CONSISTENT_REFRESH_COST (\S+)", config).group(1))
    with SlaveRunner(fmu) as runner:
        names = [n for n in case.outputs if n in runner.vr]
        h = scene.fmu.solver.step

        def run(t: float, step: float) -> tuple[dict, dict]:
            res = runner.run(case.stop, 0.01, inputs=case.inputs_at, outputs=names,
                             start={"solver.tolerance": t, "solver.step": step})
            return res, runner.solver_statistics()

        tight, tight_stats = run(1e-13, h)
        tighter_12, _ = run(1e-12, h)
        half, _ = run(1e-13, h / 2)
        loose, stats = run(tol, h)

    def worst(a: dict, b: dict) -> float:
        return max(float(np.max(np.abs(a[n] - b[n])) / max(np.max(np.abs(b[n])), 1e-300)) for n in names)

    return {"newton": worst(loose, tight), "truncation": worst(tight, half) * 4.0 / 3.0,
            "iterations": stats["newton_iterations"] / stats["steps"], "steps": stats["steps"],
            "factorisations": stats["factorisations"] / stats["steps"],
            "mass_updates": stats.get("mass_updates", 0) / stats["steps"], "update_cost": update_cost,
            "tight_iterations": tight_stats["newton_iterations"] / tight_stats["steps"],
            "reference_spread": worst(tighter_12, tight)}


def test_a_whipping_chain_refreshes_its_stale_newton_matrix():
    """fast_two_link whips to 3 rad/s: its mass matrix M(q) turns with the links, and the kept Newton matrix's
    contraction rate grows with its age (2e-4 after 950 steps, 0.18 after 5000, measured on a copy of the loop,
    docs/integrator.md).  Kept while it contracted by 2 an iteration, it cost 7.2 iterations a step at the
    default tolerance 1e-10 over 2 s of the manoeuvre.  The refresh rule (fmu_src/ss22.h, SS22_REFRESH_COST)
    buys a new matrix once the iterations beyond two a step since the last one add up to what a matrix costs,
    2 N_Q iterations: so over the run those extra iterations can be at most (factorisations + 1) times that
    cost plus the two steps around each refresh (at most 20 iterations each), whatever the chain does.  Without
    the rule (one factorisation in 5000 steps, 3.4 iterations a step) this fails by a factor of 30; the
    iteration error must stay far below the step's own, and the full evaluations within issue 22's 0.1 a step.
    Since 2026-11-29 most new matrices here are mass updates (fmu_src/mass_update.c), bought once the
    iterations beyond two add up to their own cost, CONSISTENT_REFRESH_COST residuals (about 2 here): each pays
    for that cost and the steps around it."""
    from flexlink.scene.solver import NEWTON_MAX_ITERATIONS

    r = _newton_study("fast_two_link.toml", 0.5)
    n_q = build_model(load_scene(Path(__file__).resolve().parent.parent / "examples" / "fast_two_link.toml")).n_q
    extra = (r["iterations"] - 2.0) * r["steps"]
    full, updates = (r["factorisations"] - r["mass_updates"]) * r["steps"], r["mass_updates"] * r["steps"]
    assert extra <= ((full + 1) * (2 * n_q + 2 * NEWTON_MAX_ITERATIONS)
                     + updates * (max(1.0, r["update_cost"]) + 2 * NEWTON_MAX_ITERATIONS)), r
    assert full / r["steps"] <= 0.1, r
    assert r["newton"] < 1e-3 * r["truncation"], r


# ------------------------------------------------------------------- every step's own Newton error

def step_newton_errors(scene_name: str, steps: int, start: dict[str, float] | None = None) -> np.ndarray:
    """Each SS22 step's Newton error in tolerance units, measured from outside the integrator.

    The Co-Simulation FMU takes one internal step per fmi2DoStep; its states before and after give the step's
    constant acceleration α = (v₁ − v₀)/Δt.  The exact solution α* of that step's equation is found here with
    the Model Exchange interface of the same FMU, whose derivatives f(q, v) = M⁻¹(F − h) are the model without
    the integrator: α* solves α = f(q̄(α), v̄(α)), q̄ = q₀ + Θ₁Δt v₀ + Θ₂Δt²/2 α, v̄ = v₀ + Θ₁Δt α (the SS22
    residual times M⁻¹), by Newton with the directional derivatives of f.  The error is what the tolerance
    bounds (the ``solver.tolerance`` description): max over i of Δt |α_i − α*_i| / nominal_i, divided by the
    tolerance.  Only scenes whose inputs hold still over a step (no built-in law: SS22 weights a law's inputs
    over the step, ME takes them at one time)."""
    from flexlink.run.host import FmuHost

    scene = load_scene(Path(__file__).resolve().parent.parent / "examples" / scene_name)
    fmu = cached_fmu(scene)
    solver = scene.fmu.solver
    h, tol, (t1, t2) = solver.step, solver.tolerance, solver.theta
    with FmuHost(fmu) as cs:
        md = cs.model_description
        states = [u.variable.derivative.name for u in md.derivatives]
        ders = [cs.vr[u.variable.name] for u in md.derivatives]
        n = len(states) // 2
        cs.initialize(start)
        x = [cs.get_real(states)]
        for k in range(steps):
            cs.call("fmi2DoStep", cs.instance.doStep, k * h, h)
            x.append(cs.get_real(states))
    x = np.array(x)
    with FmuHost(fmu, interface="ModelExchange") as me:
        inst = me.instance
        me.initialize(start)
        me.call("fmi2NewDiscreteStates", inst.newDiscreteStates)
        me.call("fmi2EnterContinuousTimeMode", inst.enterContinuousTimeMode)
        raw = (ctypes.c_double * (2 * n))()
        me.call("fmi2GetNominalsOfContinuousStates", inst.getNominalsOfContinuousStates, raw, 2 * n)
        nominal = np.array(raw[:n])
        state_refs = [me.vr[s] for s in states]

        xbar, dx = (ctypes.c_double * (2 * n))(), (ctypes.c_double * (2 * n))()

        def at(q0: np.ndarray, v0: np.ndarray, a: np.ndarray) -> np.ndarray:
            xbar[:] = np.concatenate([q0 + t1 * h * v0 + t2 * h * h / 2 * a, v0 + t1 * h * a]).tolist()
            me.call("fmi2SetContinuousStates", inst.setContinuousStates, xbar, 2 * n)
            me.call("fmi2GetDerivatives", inst.getDerivatives, dx, 2 * n)
            return np.array(dx[n:])

        errors = []
        for k in range(steps):
            q0, v0 = x[k, :n], x[k, n:]
            alpha = (x[k + 1, n:] - v0) / h
            exact = alpha.copy()
            residual = exact - at(q0, v0, exact)
            jac = np.array([inst.getDirectionalDerivative(ders[n:], [r], [1.0]) for r in state_refs]).T
            g = np.eye(n) - t2 * h * h / 2 * jac[:, :n] - t1 * h * jac[:, n:]
            for _ in range(3):             # Newton at α (near α*: quadratic), then the same matrix
                exact -= np.linalg.solve(g, residual)
                residual = exact - at(q0, v0, exact)
            errors.append(np.max(np.abs(alpha - exact) * h / nominal) / tol)
    return np.array(errors)


#: Law-free examples (ME and SS22 see the same inputs), each in a motion that bends it: scene → (steps, start).
AUDITED = {
    "flexible_pendulum.toml": (500, {"pivot.initial_angle": -1.2}),
    "fast_two_link.toml": (300, {"shoulder.tau": 0.2}),
    "planar_chain_5.toml": (300, {"shoulder.tau": 0.2}),
    "two_link_payload.toml": (300, {"shoulder.tau": 0.2}),
    "elastic_joint.toml": (300, {"motor.tau": 0.2}),
    "rotating_link.toml": (300, {"hub.tau": 0.5, "hub.initial_rate": 1.0}),
    "rotating_link_payload.toml": (300, {"hub.tau": 0.5}),
}


@pytest.mark.parametrize("scene", list(AUDITED))
def test_every_accepted_step_is_within_the_newton_tolerance_of_its_solution(scene):
    """The ``solver.tolerance`` contract, step by step (``step_newton_errors``): no accepted step is farther
    from its own exact solution than the tolerance.  Judged on the ratio of a step's last two increments, the
    integrator accepted flexible_pendulum's steps up to 1.1e5 tolerances off (before the refresh rule) and 3e4
    (with it): such a ratio alternates between 1e-5 and 0.2 from one increment to the next, or is noise when the
    later increment is at the rounding floor (fmu_src/ss22.c, record_rate; docs/integrator.md).  The rounding
    floor itself is about 0.01 to 0.2 tolerances here, so the bound is the tolerance, not a multiple of it."""
    steps, start = AUDITED[scene]
    errors = step_newton_errors(scene, steps, start)
    assert np.max(errors) <= 1.0, (int(np.argmax(errors)), float(np.max(errors)))


def test_steps_whose_increments_contract_ever_slower_stay_within_their_tolerance():
    """``planar_chain_5`` at its 1 ms step under 0.5 N m: with a kept matrix the ratios of a step's increments
    rise (its first increment takes out what the matrix contracts fast, the later ones what it contracts slowly),
    so the last ratio under-states the next one.  Judged on it, steps were accepted up to 1.49 tolerances from
    their solution within these 800 steps (benchmarks/step_audit.py); fmu_src/ss22.c, in_step_rate, takes the
    next ratio as at least the one before and, where they rise, rising twice more by the same factor (rising
    once more left step 776 at 1.21 tolerances)."""
    errors = step_newton_errors("planar_chain_5.toml", 800, {"shoulder.tau": 0.5})
    assert np.max(errors) <= 1.0, (int(np.argmax(errors)), float(np.max(errors)))


def test_steps_whose_ratios_jump_after_agreeing_stay_within_their_tolerance():
    """``fast_two_link`` under 20 and 5 N m at its 0.1 ms step: a motion so violent that every step's predictor
    misses by about 1e11 tolerances.  With a kept matrix the ratios of a step's increments can agree and then jump:
    step 91's were 5.9e-5 and 6.9e-5, and the next would have been 0.011 (benchmarks/newton_trace.py, whose
    "left" column is the FMU's own remaining error).  Judged on the kept rate as it stood, step 91 ended 7.3
    tolerances from its solution by this audit (7.1 by benchmarks/step_audit.py); fmu_src/ss22.c judges every
    stop on the aged rate (at least SS22_RATE_FLOOR, to the power 0.8), as its one- and two-increment stops
    were already."""
    errors = step_newton_errors("fast_two_link.toml", 200, {"shoulder.tau": 20.0, "elbow.tau": 5.0})
    assert np.max(errors) <= 1.0, (int(np.argmax(errors)), float(np.max(errors)))


def _benchmark(name: str):
    """A module of benchmarks/: step_audit (the audit that follows built-in laws, from the residual's own CasADi
    function) or newton_trace (the instrumented SS22 loop)."""
    import importlib
    import sys

    bench = str(Path(__file__).resolve().parent.parent / "benchmarks")
    sys.path.insert(0, bench)
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(bench)


def test_every_accepted_step_is_within_its_tolerance_on_a_scene_with_laws():
    """The same contract on the six-axis arm, whose six joints follow built-in laws (the Model Exchange audit
    above cannot follow them: ME takes a law at one time, SS22 weights it over the step).  The exact solution
    of each step is found from the scene's CasADi residual with the laws' (θ, θ̇) at both ends of the step
    (``benchmarks/step_audit.py``).  The kept contraction rate of an old Newton matrix grows with its age (a
    step's first ratio of increments about 0.012 × its age in steps here), and before the one-increment stop
    grew it with the age (fmu_src/ss22.c, one_increment_rate) it accepted 8 steps of the first 0.25 s beyond
    their tolerance, the worst by 2.07 (47 in 4 s, the worst by 3.6).  When first ratios confirmed the one-increment
    stops' measure interval for every start (2026-11-28, d1e52b1), 7 steps near t = 0.43 s were beyond, the worst by
    2.45 (fmu_src/ss22.c, measure_interval_of).  CI size: the first 0.5 s; FLEXLINK_FULL=1: 4 s, through the laws'
    end at 3 s."""
    import os

    stop = 4.0 if os.environ.get("FLEXLINK_FULL") == "1" else 0.5
    arm = Path(__file__).resolve().parent.parent / "examples" / "six_axis_arm.toml"
    audit = _benchmark("step_audit").step_errors(arm, stop)
    assert len(audit.errors) == round(stop / 5e-4)
    worst = int(np.argmax(audit.errors))
    assert audit.errors[worst] <= 1.0, (float(audit.time[worst]), float(audit.errors[worst]))


def test_every_accepted_step_is_within_its_tolerance_in_closed_loop():
    """The same audit with the torques from a PD sampled every step (step_audit's ``--pd``): the host's inputs
    jump at every step, where the recurrence start follows them by its inputs' term (fmu_src/predictor.c) and
    every step is one of the two after a jump: rotating_link and the 3-link chain at their 1 ms, the chain's
    PD on all three joints.  And the 5-link chain near its recommended step (125 µs) under a PD every 1 ms: most
    of its steps start more than 1e3 tolerances off, and before fmu_src/ss22.h's SS22_FAR_START 7 of these 240
    steps were beyond (worst 2.57; 28 of 2414 over 0.3 s, worst 6.73)."""
    audit_of = _benchmark("step_audit")
    root = Path(__file__).resolve().parent.parent
    for scene, pd, stop, start in [
            (root / "examples" / "rotating_link.toml", audit_of.SampledPD(1.0, 0.2, 0.5), 1.0, None),
            (root / "benchmarks" / "scenes" / "planar_chain_3.toml", audit_of.SampledPD(1.0, 0.1, 0.5), 0.5, None),
            (root / "examples" / "planar_chain_5.toml", audit_of.SampledPD(1.0, 0.1, 0.5, every=8), 0.03,
             {"solver.step": 1.25e-4})]:
        audit = audit_of.step_errors(scene, stop, start, pd=pd)
        worst = int(np.argmax(audit.errors))
        assert audit.errors[worst] <= 1.0, (scene.name, float(audit.time[worst]), float(audit.errors[worst]))


def test_mass_updated_matrices_keep_every_step_within_its_tolerance():
    """fmu_src/mass_update.c: on a chain whose mass matrix turns with its motion, a kept Newton matrix's M part
    is updated alone (J = M(q) + the velocity and position parts of its last full evaluation) once the
    iterations it wasted pay for a new M and its LU.  ``planar_chain_5`` at its scene's 1 ms step under a PD
    sampled every step (every start far off, ``SS22_FAR_START``) and the six-axis arm through its laws' fastest
    second: the audit's counters show the updates happening, and no step ends beyond its tolerance.  (While the
    update was taken at a step's start and its first ratios judged at the full evaluation's age, the arm's 4 s
    audit had 567 of 8000 steps beyond, the worst by 46.5 near t = 1.13 s: docs/integrator.md, "The mass
    update".)"""
    audit_of = _benchmark("step_audit")
    root = Path(__file__).resolve().parent.parent
    for scene, stop, start, pd in [
            (root / "examples" / "planar_chain_5.toml", 0.3, None, audit_of.SampledPD(1.0, 0.1, 0.5)),
            (root / "examples" / "six_axis_arm.toml", 1.2, None, None)]:
        audit = audit_of.step_errors(scene, stop, start, pd=pd)
        assert audit.statistics["mass_updates"] > 0, (scene.name, audit.statistics)
        worst = int(np.argmax(audit.errors))
        assert audit.errors[worst] <= 1.0, (scene.name, float(audit.time[worst]), float(audit.errors[worst]))


def test_a_start_far_off_ends_only_on_an_increment_within_the_tolerance():
    """``six_axis_arm_torque`` at 0.5 ms (50 times its recommended step: its flexible modes ring unresolved) under a
    PD sampled every step: after each torque the line starts 1e5-1e8 tolerances off, and a direction the kept
    matrix contracts slowly holds 7e-7 to 2e-4 of that, which the ratios of the first increments do not see.  On
    ratios of 3.1e-4 and 2.9e-3 step 66 ended 62.7 tolerances from its solution; 48 of the first 200 steps were
    beyond (163 of 2000 over 1 s).  fmu_src/ss22.h, SS22_FAR_START: after a start more than 1e3 tolerances off an
    older matrix ends a step only on an increment within a third of the tolerance.  CI size: 0.1 s;
    FLEXLINK_FULL=1: 1 s."""
    import os

    audit_of = _benchmark("step_audit")
    stop = 1.0 if os.environ.get("FLEXLINK_FULL") == "1" else 0.1
    arm = Path(__file__).resolve().parent.parent / "examples" / "six_axis_arm_torque.toml"
    audit = audit_of.step_errors(arm, stop, pd=audit_of.SampledPD(1.0, 0.1, 0.5))
    assert len(audit.errors) == round(stop / 5e-4)
    worst = int(np.argmax(audit.errors))
    assert audit.errors[worst] <= 1.0, (float(audit.time[worst]), float(audit.errors[worst]))


@pytest.mark.parametrize(("tolerance", "ci_stop"), [(1e-8, 0.5), (1e-9, 1.6)])
def test_the_six_axis_arm_keeps_the_contract_at_looser_tolerances(tolerance, ci_stop):
    """The same audit at tolerances other than the scene's 1e-10.  Before an increment below the tolerance had
    to leave, by its ratio to the step's previous one, rate/(1 - rate) times itself within the tolerance
    (fmu_src/ss22.c, bounds_error) and the one-increment stop's margin was 3, the arm had at 1e-8 124 of its
    first 1000 steps beyond (worst 3.72; 450 of 8000 over 4 s) and at 1e-9 4 of 8000 (worst 3.26, t = 1.52 s);
    either change alone left 383 and 531 of 8000 beyond at 1e-8 (docs/integrator.md, "Every tolerance").  CI
    size: through the first step that was beyond (0.5 s, 1.6 s); FLEXLINK_FULL=1: 4 s."""
    import os

    stop = 4.0 if os.environ.get("FLEXLINK_FULL") == "1" else ci_stop
    arm = Path(__file__).resolve().parent.parent / "examples" / "six_axis_arm.toml"
    audit = _benchmark("step_audit").step_errors(arm, stop, {"solver.tolerance": tolerance})
    assert audit.tolerance == tolerance and len(audit.errors) == round(stop / 5e-4)
    worst = int(np.argmax(audit.errors))
    assert audit.errors[worst] <= 1.0, (float(audit.time[worst]), float(audit.errors[worst]))


def test_the_traced_loop_leaves_every_accepted_step_within_its_tolerance(tmp_path):
    """benchmarks/newton_trace.py's instrumented copy of the SS22 loop, whose ``left`` column is one Newton
    increment with a matrix evaluated at the accepted step, from the FMU's own residual: within the tolerance on
    every step of the whipped arm above (where step 91 had 7.1e-10 left before every stop was aged), and the
    instrumentation still fits fmu_src/ss22.c (its patches name their anchors)."""
    trace = tmp_path / "trace.txt"
    _benchmark("newton_trace").main([str(Path(__file__).resolve().parent.parent / "examples" / "fast_two_link.toml"),
                                     "--stop", "0.012", "--every", "0", "--torque", "20", "--set", "elbow.tau=5",
                                     "--out", str(trace)])
    left = np.array([float(line.split("= left")[1]) for line in trace.read_text().splitlines()])
    assert len(left) == 120 and np.all(left >= 0.0)
    assert np.max(left) <= 1e-10, (int(np.argmax(left)), float(np.max(left)))
