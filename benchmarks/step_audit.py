"""Every SS22 step's Newton error, audited from outside the FMU, on scenes with built-in joint laws too.

    python benchmarks/step_audit.py SCENE.toml [--stop T] [--tolerance TOL] [--set NAME=VALUE ...] [--worst N]
                                               [--pd KP KD REF [--sample N]]

The Co-Simulation FMU is stepped one internal step per ``fmi2DoStep`` (a communication step of
``solver.step``); its states before and after each step give the step's constant acceleration
α = (v₁ − v₀)/Δt.  The exact solution α* of that step's equation is then found here, without the FMU, from the
scene's CasADi residual r(q, v, a, u, p) (``flexlink.mechanics.model.build_model``), by full Newton with its
exact Jacobian in α:

    r(q₀ + Θ₁Δt v₀ + Θ₂Δt²/2 α, v₀ + Θ₁Δt α, α, ū, p) = 0,

with ū as SS22 weights the inputs over the step (``docs/integrator.md``, ``fmu_src/ss22.h``): Θ₁u₁ + (1 − Θ₁)u₀
for the host's inputs, and for a built-in law — its (θ, θ̇) taken exactly at both ends of the step from the
scene's trajectory (``Trajectory.evaluate``) — the mean acceleration ᾱ = (θ̇₁ − θ̇₀)/Δt, the weighted rate
θ̇₀ + Θ₁Δt ᾱ and the weighted angle θ₀ + Θ₁Δt θ̇₀ + Θ₂Δt²/2 ᾱ + Θ₂(θ₁ − θ₀ − Δt(θ̇₀ + θ̇₁)/2).  The error is what
``solver.tolerance`` bounds: max over i of Δt |α_i − α*_i| / nominal_i, printed in tolerances.  Host-driven laws
(``<joint>.theta_ref``) are not followed: the audit refuses them.  ``--pd`` drives the torque-driven joints by a
sampled PD instead of holding their torques, every ``--sample`` steps: a closed loop's inputs, which jump at
every sample.

``tests/test_ss22_numerics.py`` runs ``step_errors`` on scenes with laws; its Model Exchange audit covers the
law-free ones with the FMU's own derivatives.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from flexlink.errors import FlexlinkError

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Audit:
    """A run's steps: their start times, each step's Newton error in tolerances, the settings, and the FMU's own
    counters of the run (``FmuHost.solver_statistics``: Newton iterations, factorisations, mass updates)."""

    time: np.ndarray
    errors: np.ndarray
    step: float
    tolerance: float
    statistics: dict[str, int]


def _weighted_inputs(model, u0: np.ndarray, u1: np.ndarray, h: float, t1: float, t2: float) -> np.ndarray:
    """ū over a step: the host's inputs weighted by Θ₁, each built-in law moved with its mean acceleration."""
    u = t1 * u1 + (1.0 - t1) * u0
    for law in model.laws:
        o = law.u_offset
        x0, xd0, x1, xd1 = u0[o], u0[o + 1], u1[o], u1[o + 1]
        abar = (xd1 - xd0) / h
        u[o] = x0 + t1 * h * xd0 + t2 * h * h / 2 * abar + t2 * (x1 - x0 - h / 2 * (xd0 + xd1))
        u[o + 1] = xd0 + t1 * h * abar
        u[o + 2] = abar
    return u


@dataclass
class SampledPD:
    """A host's sampled PD on every torque-driven joint: τ = kp (ref − θ) − kd θ̇ (ref for the first such joint,
    0 for the others), set every ``every`` steps from the FMU's outputs: the host inputs then jump at every
    sample, as under a controller in closed loop."""

    kp: float
    kd: float
    ref: float
    every: int = 1


def _pd_torques(cs, joints: list[str], pd: SampledPD) -> list[float]:
    """The PD's torques from the joints' present angles and rates."""
    theta = cs.get_real([f"{j}.theta" for j in joints])
    omega = cs.get_real([f"{j}.omega" for j in joints])
    return [pd.kp * ((pd.ref if k == 0 else 0.0) - th) - pd.kd * w
            for k, (th, w) in enumerate(zip(theta, omega, strict=True))]


def step_errors(scene_path: str | Path, stop: float, start: dict[str, float] | None = None,
                pd: SampledPD | None = None) -> Audit:
    """Each step's Newton error over [0, stop] of the scene at its ``solver.step`` (``start``: start values,
    parameters, inputs held from t = 0 and solver settings alike; ``pd``: the torques from a sampled PD
    instead)."""
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.run.host import FmuHost
    from flexlink.scene.loader import load_scene

    start = dict(start or {})
    scene = load_scene(Path(scene_path))
    model = build_model(scene)
    if any(law.trajectory is None for law in model.laws):
        raise SystemExit(f"{scene_path}: a host-driven law (theta_ref): the audit follows built-in laws only")
    fmu = cached_fmu(scene, model=model)
    solver = scene.fmu.solver
    h = float(start.get("solver.step", solver.step))
    tol = float(start.get("solver.tolerance", solver.tolerance))
    t1 = float(start.get("solver.theta1", solver.theta[0]))
    t2 = float(start.get("solver.theta2", solver.theta[1]))
    steps = int(round(stop / h))
    n = model.n_q
    with FmuHost(fmu) as cs:
        states = [u.variable.derivative.name for u in cs.model_description.derivatives]
        cs.initialize(start)
        p = np.array(cs.get_real([par.name for par in model.parameters]))
        law_slots = {law.u_offset + k for law in model.laws for k in range(3)}
        held = [i for i, s in enumerate(model.inputs) if i not in law_slots]
        u_host = np.array([s.start for s in model.inputs], dtype=float)
        u_host[held] = cs.get_real([model.inputs[i].name for i in held])
        names = [s.name for s in model.inputs]
        joints = [n[:-len(".tau")] for n in names if n.endswith(".tau")] if pd else []
        if pd and not joints:
            raise FlexlinkError(f"{scene_path}: --pd needs a torque-driven joint (an input <joint>.tau)")
        x, u_steps = [cs.get_real(states)], []
        for k in range(steps):
            if pd and k % pd.every == 0:
                cs.set_values(dict(zip([f"{j}.tau" for j in joints], _pd_torques(cs, joints, pd), strict=True)))
            u_steps.append(np.array(cs.get_real([model.inputs[i].name for i in held])))
            cs.call("fmi2DoStep", cs.instance.doStep, k * h, h)
            x.append(cs.get_real(states))
        statistics = cs.solver_statistics()
    x = np.array(x)

    sym = ca.SX if n <= 24 else ca.MX
    residual = model.residual.expand() if sym is ca.SX else model.residual
    a, q0, v0 = sym.sym("a", n), sym.sym("q0", n), sym.sym("v0", n)
    ub, pp, d = sym.sym("u", len(model.inputs)), sym.sym("p", len(p)), sym.sym("dt")
    r = residual(q0 + t1 * d * v0 + t2 * d * d / 2 * a, v0 + t1 * d * a, a, ub, pp)
    newton = ca.Function("newton", [a, q0, v0, ub, pp, d], [r, ca.jacobian(r, a)])

    def inputs_at(t: float, k: int) -> np.ndarray:
        u = u_host.copy()
        u[held] = u_steps[k]                # the host's inputs held over step k
        for law in model.laws:
            u[law.u_offset:law.u_offset + 3] = law.trajectory.evaluate(t)
        return u

    nominal = np.asarray(model.nominal_q, dtype=float)
    errors = np.empty(steps)
    # the FMU's own step times: its step k runs from where step k - 1 ended to the communication point k h + h,
    # and its Δt is their difference (5e-4 s steps near t = 3 s differ from h in the last bits)
    ends = [0.0] + [k * h + h for k in range(steps)]
    for k in range(steps):
        q, v = x[k, :n], x[k, n:]
        dt = ends[k + 1] - ends[k]
        alpha = (x[k + 1, n:] - v) / dt
        u = _weighted_inputs(model, inputs_at(ends[k], k), inputs_at(ends[k + 1], k), dt, t1, t2)
        exact = alpha.copy()
        for _ in range(4):                 # full Newton from the accepted α (near α*: quadratic)
            res, jac = newton(exact, q, v, u, p, dt)
            exact -= np.linalg.solve(np.asarray(jac), np.asarray(res).ravel())
        errors[k] = np.max(np.abs(alpha - exact) * dt / nominal) / tol
    return Audit(np.array(ends[:-1]), errors, h, tol, statistics)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--stop", type=float, default=1.0)
    ap.add_argument("--tolerance", type=float, help="solver.tolerance (default: the scene's)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a start value")
    ap.add_argument("--worst", type=int, default=10, help="list the N worst steps")
    ap.add_argument("--pd", nargs=3, type=float, metavar=("KP", "KD", "REF"),
                    help="torques from a sampled PD on every torque-driven joint (the first one to REF rad)")
    ap.add_argument("--sample", type=int, default=1, metavar="N", help="the PD's sample: every N steps")
    args = ap.parse_args(argv)
    if args.sample < 1:
        ap.error(f"--sample must be >= 1, got {args.sample}")
    try:
        start = {k: float(v) for k, v in (s.split("=", 1) for s in args.set)}
    except ValueError:
        ap.error(f"--set takes NAME=NUMBER, got {args.set}")   # exit status 2
    if args.tolerance is not None:
        start["solver.tolerance"] = args.tolerance
    try:
        pd = SampledPD(*args.pd, every=args.sample) if args.pd else None
        audit = step_errors(args.scene, args.stop, start, pd)
    except FlexlinkError as exc:    # a bad scene or start value, or a step the FMU refused: exit status 2
        print(f"step_audit: {exc}", file=sys.stderr)
        return 2
    e = audit.errors
    print(f"{args.scene}: {len(e)} steps of {audit.step:g} s at tolerance {audit.tolerance:g}: worst "
          f"{e.max():.3g} tolerances (step at t = {audit.time[int(np.argmax(e))]:.6g} s), {int(np.sum(e > 1))} "
          f"beyond 1, median {np.median(e):.3g}")
    st = audit.statistics
    if st.get("steps"):
        updates = st.get("mass_updates", 0)
        print(f"  {st['newton_iterations'] / st['steps']:.2f} Newton iterations a step; "
              f"{(st['factorisations'] - updates) / st['steps']:.3f} full Newton matrices and "
              f"{updates / st['steps']:.3f} mass updates a step")
    for k in np.argsort(e)[::-1][:args.worst]:
        print(f"  t = {audit.time[k]:.6f}  {e[k]:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
