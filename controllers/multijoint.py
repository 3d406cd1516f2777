"""Rest-to-rest manoeuvre of every torque-driven joint through the FMU: the MIMO LQG against a joint PD.

The reference (:func:`inverse_dynamics_reference`) is a quintic (rigid minimum-jerk) path of each joint,
and the feedforward torque is the model's own inverse dynamics along it: the joints are prescribed, the
elastic coordinates integrated (CasADi ``cvodes`` on the symbolic residual, the equations the FMU solves),
and the torque each joint needs read from its residual row — what the FMU's position-driven joints output
as ``<joint>.tau``, without building a second FMU.  The torque is averaged over each sample (the zero-order
hold then gives the same impulse).  During the manoeuvre the LQG's reference state is that flexible
trajectory (joints *and* elastic coordinates); after it, rest at the targets.  A linear design about the
start pose cannot plan the path itself: the elbow's motion changes the arm's inertia.

Both laws see deviations from that reference:

* :class:`MimoLQGLaw` — the discrete LQR on the Kalman filter's estimate of the deviation ``x − x_ref``
  (current estimator), the saturated torque fed back to the estimator (no wind-up).  Encoders and root
  strain gauges are linear in the state: the measurement expected on the reference is ``y₀ + C x_ref``
  exactly.  The tip accelerometer has feedthrough and is far from linear along a large manoeuvre: it is read
  as the single-joint LQG reads it (:func:`controllers.laws.measurement_schedule`), its expected value the
  model's output at the reference state, acceleration and held feedforward torque, ``h(x_ref,k, u_ff,k−1)
  + C_k δx + D_k (u_{k−1} − u_ff,k−1)``, sampled at t_k while the previous torque is held; the estimator
  then predicts with the plant sampled along the reference and the time-varying Kalman gain
  (:func:`estimator_along`).  Those gains are designed on that linearisation, but the measurement each
  sample expects is, by default, the model's own sensor outputs at the prior estimate and the held torque,
  ``h(x̂_k|k−1, u_{k−1})`` (:mod:`controllers.sensor_model`): the measurement update of an extended Kalman
  filter with the designed (linearised) gains.  The linear form misses the accelerometers' centripetal and
  Coriolis terms, quadratic in the rates, and the torques chattered after a manoeuvre (docs/control.md).
  Without saturation, with encoders and strain gauges, it is :func:`controllers.robustness.lqg_compensator`,
  whose loop-at-a-time margins ``flexlink control --design-only`` reports.
* :class:`JointPDLaw` — one PD per joint on its encoder and rate, the same feedforward, each joint's
  rigid-body pair at the LQR's slowest pair (locked-arm inertia ``M_jj``); its torque limit is the LQG run's
  peak torque of that joint (:func:`compare`), so it never uses more torque than the LQG did.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from controllers.cosim import FmuLoop
from controllers.trajectory import Reference, quintic
from flexlink.errors import FlexlinkError

__all__ = ["ACCELEROMETER", "PREDICTIONS", "EstimatorAlong", "JointPDLaw", "MimoLQGLaw", "checked_step", "compare",
           "compare_laws", "default_torque_limit", "estimator_along", "inverse_dynamics_reference", "joint_pd_gains",
           "kalman_gains_along", "plan", "run", "sensor_noise"]


#: How :class:`MimoLQGLaw` predicts a sensor that is not affine in the state: the model's outputs at the estimate
#: (EKF-style, the default) or their linearisation along the reference.
PREDICTIONS = ("model", "linear")

#: The last tip's accelerometer outputs (:func:`controllers.design.sensor_set`), read along the reference; a
#: link's own, ``<link>.tip.sx`` …, are read the same way (:func:`controllers.design.is_link_accelerometer`).
ACCELEROMETER = ("tip.sx", "tip.sy")


def check_multijoint(d) -> None:
    """Refuse a design the multi-joint run cannot drive, before anything runs.

    It drives every joint by torque (no built-in law to carry along the path), starting at rest, with the
    encoders, root strain gauges and tip accelerometers (:data:`ACCELEROMETER`, ``<link>.tip.s*``).  An elastic
    joint's torque turns its motor (:func:`drive_coordinate`).
    """
    from controllers.design import DesignError, is_link_accelerometer

    model = d.plant.model
    for j in model.scene.joints:
        if j.drive != "torque":
            raise DesignError(f'joint "{j.name}": the multi-joint run drives every joint by torque, got drive = '
                              f'"{j.drive}"')
        if j.initial_rate != 0.0:
            raise DesignError(f'joint "{j.name}": a rest-to-rest manoeuvre starts at rest; initial_rate = '
                              f"{j.initial_rate} rad/s")
    unknown = [s for s in d.kalman.sensors if not s.endswith((".theta", ".root.moment")) and s not in ACCELEROMETER
               and not is_link_accelerometer(s)]
    if unknown:
        raise DesignError(f"sensors {unknown}: the multi-joint run reads the encoders, root strain gauges (--sensors "
                          "strain) and the links' tip accelerometers (--sensors accelerometer)")


def drive_coordinate(model, joint: str) -> str:
    """The coordinate a joint's torque turns: its angle, or an elastic joint's motor angle."""
    motor = f"{joint}.motor_theta"
    return motor if motor in model.coordinates else f"{joint}.theta"


@dataclass
class Plan:
    """Where the manoeuvre goes, computed once and shared by every law that runs it.

    The driven coordinates' indices (:func:`drive_coordinate`), their start and final angles (rad), the joints'
    target angles (link side), the final rest state (absolute) and its holding torques, the static ``<link>.tip.v``
    there, and the joint angles' coordinate indices.
    """

    joints: list[str]
    index: list[int]
    start: np.ndarray
    drive_target: np.ndarray
    x_end: np.ndarray
    u_end: np.ndarray
    tip_static: dict
    target: np.ndarray
    angle_index: list[int]
    angle_start: np.ndarray


def plan(plant, targets: Sequence[float]) -> Plan:
    """The final rest state at ``targets`` (rad, one per actuated joint, link side), as a :class:`Plan`.

    The elastic coordinates are at their static deflection there (zero without gravity), the torques that hold it,
    the tips' static deflection.  An elastic joint's motor ends where its spring holds the link at the target: its
    motor angle is moved by the link's static lag, a few fixed-point passes (the lag changes little with it).
    """
    from controllers.design import actuated_joints
    from flexlink.run.linearize import explicit_functions

    p, model = plant, plant.model
    joints = actuated_joints(plant)
    if len(targets) != len(joints):
        raise FlexlinkError(f"--target: one angle per torque-driven joint ({', '.join(joints)}), got {len(targets)}")
    idx = [model.coordinates.index(drive_coordinate(model, j)) for j in joints]
    angle = [model.coordinates.index(f"{j}.theta") for j in joints]
    aim = np.asarray(targets, dtype=float)
    names = [s.name for s in model.inputs]
    cols = [names.index(f"{j}.tau") for j in joints]
    u = p.op.u.copy()
    u[cols] = 0.0
    drive = aim.copy()
    for _ in range(6):
        q = _rest_at(model, p, idx, drive, u)
        lag = q[angle] - aim
        if np.max(np.abs(lag)) < 1e-10:        # at once without elastic joints (their lag is 0)
            break
        drive -= lag
    else:
        raise FlexlinkError(f"--target: the elastic joints' static lag at the targets does not converge "
                            f"({np.max(np.abs(lag)):.3g} rad left)")
    r = np.asarray(model.residual(q, np.zeros(model.n_q), np.zeros(model.n_q), u, p.op.p), dtype=float).ravel()
    u_end = r[idx]
    u[cols] = u_end
    x_end = np.concatenate([q, np.zeros(model.n_q)])
    _, h = explicit_functions(model)
    y = np.asarray(h(x_end, u, p.op.p), dtype=float).ravel()
    names = [s.name for s in model.outputs]
    tips = {lk.name: float(y[names.index(f"{lk.name}.tip.v")]) for lk in model.scene.links
            if f"{lk.name}.tip.v" in names}
    return Plan(joints, idx, p.x0[idx].copy(), q[idx].copy(), x_end, u_end, tips, aim, angle,
                p.x0[angle].copy())


def _rest_at(model, p, idx, drive, u) -> np.ndarray:
    """The static configuration with the driven coordinates held at ``drive``, the others free."""
    from flexlink.mechanics.analysis import static_deflection

    n = model.n_q
    q = p.op.q.copy()
    q[idx] = drive
    free = [k for k in range(n) if k not in idx]
    return static_deflection(model, q, np.zeros(n), u, p.op.p, free)


def inverse_dynamics_reference(plant, pl: Plan, dt: float, duration: float, settle: float) -> Reference:
    """Quintic path of every joint from its start to its target in ``duration``, with its feedforward.

    The elastic coordinates and the joint torques along it from the model's inverse dynamics (module docstring);
    then rest at the targets for ``settle``.  Deviations from the design's operating point; ``u_ff`` is (N + 1, m).
    """
    from controllers.design import torque_inputs

    p, model = plant, plant.model
    n = model.n_q
    n_move, n_total = int(round(duration / dt)), int(round((duration + settle) / dt))
    t = np.arange(n_total + 1) * dt
    idx, free = pl.index, [k for k in range(n) if k not in pl.index]
    res = model.residual.expand()
    ts = ca.SX.sym("t")
    qf, vf, af = ca.SX.sym("qf", len(free)), ca.SX.sym("vf", len(free)), ca.SX.sym("af", len(free))
    tau = ts / duration
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    sd = 30 * tau**2 * (1 - tau) ** 2 / duration
    sdd = 60 * tau * (1 - tau) * (1 - 2 * tau) / duration**2
    delta = pl.drive_target - pl.start
    q, v, a = [ca.SX.zeros(n) for _ in range(3)]
    for k, i in enumerate(idx):
        q[i], v[i], a[i] = pl.start[k] + delta[k] * s, delta[k] * sd, delta[k] * sdd
    for k, i in enumerate(free):
        q[i], v[i], a[i] = qf[k], vf[k], af[k]
    u = ca.DM(p.op.u)
    names = [s_.name for s_ in model.inputs]
    for j in pl.joints:
        u[names.index(f"{j}.tau")] = 0.0
    r = res(q, v, a, u, p.op.p)
    r_free = r[free]
    M = ca.jacobian(r_free, af)
    acc = -ca.solve(M, ca.substitute(r_free, af, ca.SX.zeros(len(free))))
    torque = ca.substitute(r[idx], af, acc)
    x = ca.vertcat(qf, vf)
    grid = list(t[1:n_move + 1])
    F = ca.integrator("inverse_dynamics", "cvodes", {"x": x, "t": ts, "ode": ca.vertcat(vf, acc), "quad": torque},
                      0.0, grid, {"abstol": 1e-11, "reltol": 1e-10})
    x0f = np.concatenate([p.op.q[free], p.op.v[free]])
    out = F(x0=x0f)
    X = np.hstack([x0f[:, None], np.asarray(out["xf"])]).T              # (n_move + 1, 2 nf)
    Q = np.hstack([np.zeros((len(idx), 1)), np.asarray(out["qf"])]).T    # ∫ torque, (n_move + 1, m)
    xs = np.zeros((n_total + 1, 2 * n))
    th, thd, _ = (np.outer(c, delta) for c in quintic(t[: n_move + 1], 1.0, duration))
    xs[: n_move + 1, idx] = pl.start + th
    xs[: n_move + 1, [n + i for i in idx]] = thd
    xs[: n_move + 1, free] = X[:, : len(free)]
    xs[: n_move + 1, [n + i for i in free]] = X[:, len(free):]
    xs[n_move + 1:] = pl.x_end
    u_ff = np.tile(pl.u_end, (n_total + 1, 1))
    u_ff[:n_move] = np.diff(Q, axis=0) / dt
    u0 = p.u0[torque_inputs(p)]
    return Reference("inverse-dynamics", dt, duration, t, xs - p.x0, u_ff - u0, idx[0])


def default_torque_limit(plant, targets: Sequence[float], duration: float, dt: float = 1e-3,
                         factor: float = 1.5) -> float:
    """The torque limit of a multi-joint run when none is given, from the manoeuvre's own feedforward.

    ``factor`` × the largest peak of the joints' inverse-dynamics feedforward (coupling included), rounded up
    to 0.5 N m: the torque limit of every joint (and Bryson's R) of a multi-joint run when none is given.
    One number for all joints: a smaller limit on the elbow than on the shoulder weighs its torque more and
    gave an LQG that the elbow's motion destabilised (two_link_payload, 60°/40° in 1 s).
    """
    from controllers.design import torque_inputs

    pl = plan(plant, targets)
    ref = inverse_dynamics_reference(plant, pl, dt, duration, dt)
    peak = float(np.max(np.abs(ref.u_ff + plant.u0[torque_inputs(plant)])))
    return max(math.ceil(2.0 * factor * peak) / 2.0, 0.5)


def checked_step(step: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
    """A law's ``step`` that stops at the first overflow, before any torque is computed from an infinity.

    A finite but absurd measurement (1e308 from a broken sensor) gives a finite estimate whose gain product
    overflows: the torque would be clipped from ±inf to a limit and the next estimate be inf.  Under
    ``np.errstate(over="raise", invalid="raise")`` the overflowing operation itself raises, and the sample is the
    law's :meth:`MimoLQGLaw.diverged` error; no infinity is computed with.
    """
    @functools.wraps(step)
    def checked(self, y, x_ref, u_ff) -> np.ndarray:
        with np.errstate(over="raise", invalid="raise"):
            try:
                return step(self, y, x_ref, u_ff)
            except FloatingPointError:
                raise self.diverged() from None
    return checked


class MimoLQGLaw:
    """The discrete LQR on the Kalman estimate of the deviation from the reference (module docstring).

    ``step(y, x_ref, u_ff)`` → the saturated torques (absolute, one per actuated joint).
    """

    kind = "lqr"

    def __init__(self, d, limits: Sequence[float], reference: Reference, prediction: str = "model"):
        from controllers.design import torque_inputs
        from controllers.laws import measurement_schedule
        from controllers.sensor_model import sensor_model

        if prediction not in PREDICTIONS:
            raise FlexlinkError(f"prediction: one of {', '.join(PREDICTIONS)}, got {prediction!r}")
        p = d.plant
        cols = torque_inputs(p)
        self.dt, self.sensors, self.inputs = d.dt, list(d.kalman.sensors), list(d.lqr.inputs)
        self.u0 = p.u0[cols]
        self.y0 = p.y0[[p.output_row(s) for s in self.sensors]]
        self.C, self.M, self.K = d.kalman.C, d.kalman.Md, d.lqr.Kd
        self.D = np.asarray(d.kalman.D)[:, cols]
        self.Ad, self.Bd = np.asarray(d.lqr.plant_d.A), np.asarray(d.lqr.plant_d.B)
        self.limits = np.asarray(limits, dtype=float)
        self.W = reference_step(reference, self.Ad, self.Bd)
        # sensors not affine in the state (the tip accelerometer): read along the reference, as LQGLaw.follow
        self.schedule = measurement_schedule(p, self.sensors, reference, cols)
        self.along = None if self.schedule is None else estimator_along(d, reference, self.schedule.C)
        # such sensors are predicted by the model itself at the estimate (EKF-style), unless told "linear"
        self.prediction = "linear" if self.schedule is None else prediction
        self.x0 = p.x0
        self.h = sensor_model(p, self.sensors, cols) if self.prediction == "model" else None
        self.reset()

    def reset(self) -> None:
        """Start a run: the estimate at the reference (zero deviation), no torque deviation held, sample 0."""
        self.dz = np.zeros(self.Ad.shape[0])      # prior estimate of x − x_ref
        self.u_prev = np.zeros(len(self.u0))      # deviation torque held while y_k is sampled
        self.k = 0

    def matrices(self, k: int) -> tuple[np.ndarray, ...]:
        """(M, C, K, A_d, B_d) that sample ``k`` uses: the one design's (a scheduled law overrides this)."""
        return self.M, self.C, self.K, self.Ad, self.Bd

    def predicted(self, x_ref: np.ndarray, C: np.ndarray) -> np.ndarray:
        """The measurement ``ŷ_k`` the estimator expects at sample ``k`` from its prior deviation estimate.

        Sensors linear in the state: ``y₀ + C (x_ref + δẑ)``.  With a sensor that is not (the accelerometer,
        with feedthrough, sampled at t_k while the previous torque u_{k−1} is held: :mod:`controllers.laws`):
        ``prediction="model"`` (the default), the model's own outputs at the prior estimate and the held torque,
        ``h(x₀ + x_ref,k + δẑ, u₀ + u_{k−1})`` (:mod:`controllers.sensor_model`: an extended Kalman filter's
        measurement prediction); ``"linear"``, the sensors linearised along the reference, ``h(x_ref,k,
        u_ff,k−1) + C_k δẑ + D_k (u_{k−1} − u_ff,k−1)``.
        """
        if self.h is not None:
            return np.asarray(self.h.call([self.x0 + x_ref + self.dz, self.u0 + self.u_prev])[0], dtype=float).ravel()
        sc, k = self.schedule, self.k
        if sc is not None and k < len(sc.y_ref):
            return sc.y_ref[k] + sc.C[k] @ self.dz + sc.D[k] @ (self.u_prev - sc.u_ff_prev[k])
        return self.y0 + C @ (x_ref + self.dz) + self.D @ self.u_prev

    def diverged(self) -> FlexlinkError:
        """The error of a sample whose estimate is not finite or would overflow (the controller FMU refuses too)."""
        return FlexlinkError(f"the LQG's estimate is not finite at sample {self.k} (t = {self.k * self.dt:.6g} s): "
                             "it diverged (a NaN or infinite estimate, or a torque that overflows)")

    def finite(self, dx: np.ndarray) -> np.ndarray:
        """``dx``, or :meth:`diverged` when the estimate is not finite (a NaN measurement)."""
        if not np.all(np.isfinite(dx)):
            raise self.diverged()
        return dx

    @checked_step
    def step(self, y, x_ref, u_ff) -> np.ndarray:
        """One sample: correct the estimate with ``y``, the saturated torques, then predict the next sample."""
        M, C, K, Ad, Bd = self.matrices(self.k)
        W = self.W
        if self.along is not None and self.k < len(self.along.M):
            al = self.along
            M, Ad, Bd, W = al.M[self.k], al.A[self.k], al.B[self.k], al.W
        dx = self.finite(self.dz + M @ (y - self.predicted(x_ref, C)))
        u = np.clip(self.u0 + u_ff - K @ dx, -self.limits, self.limits)
        self.dz = self.finite(Ad @ dx + Bd @ (u - self.u0 - u_ff) - W[self.k])
        self.u_prev = u - self.u0
        self.k += 1
        return u


@dataclass
class EstimatorAlong:
    """The Kalman filter's model along a reference, per sample k (:class:`MimoLQGLaw` with an accelerometer).

    ``A[k]``, ``B[k]``: the plant's flow over [t_k, t_k+1] sampled (zero-order hold) about ``(x_ref,k,
    u_ff,k)``; ``M[k]``: the time-varying Kalman gain with the sensors' rows ``C_k``
    (:func:`kalman_gains_along`); ``W[k]``: the reference's own step (:func:`reference_step`) in that model.
    """

    A: np.ndarray       # (N, n, n)
    B: np.ndarray       # (N, n, m)
    M: np.ndarray       # (N, n, p)
    W: np.ndarray       # (N, n)


def _flow_function(plant, cols: Sequence[int]) -> ca.Function:
    """(x, u, p) → (∂f/∂x, ∂f/∂u on the torques ``cols``) of the first-order flow ``f = (v, a(q, v, u))``."""
    key = ("flow_jacobians", tuple(cols))
    if key in plant.cache:
        return plant.cache[key]
    model = plant.model
    n = model.n_q
    res = model.residual.expand()
    q, v, a = ca.SX.sym("q", n), ca.SX.sym("v", n), ca.SX.sym("a", n)
    u, p = ca.SX.sym("u", res.size1_in(3)), ca.SX.sym("p", res.size1_in(4))
    r = res(q, v, a, u, p)
    zero = ca.SX.zeros(n)
    acc = -ca.solve(ca.substitute(ca.jacobian(r, a), a, zero), ca.substitute(r, a, zero))
    x, f = ca.vertcat(q, v), ca.vertcat(v, acc)
    fmu = [k for k, s_ in enumerate(model.inputs) if s_.fmu_variable]
    fn = ca.Function("flow", [x, u, p], [ca.jacobian(f, x), ca.jacobian(f, u)[:, [fmu[i] for i in cols]]])
    plant.cache[key] = fn
    return fn


def estimator_along(d, reference: Reference, Cs: np.ndarray) -> EstimatorAlong:
    """The plant sampled about every sample of ``reference`` and the Kalman gains along it.

    Why: the accelerometer reads the state's effect within one sample (its rows ``C_k`` meet ``B``: a torque
    step changes the rates, and the centripetal ``tip.sx`` reads the rates at the reference's speed), so the
    rest pose's ``A_d, B_d`` mispredict it along a large manoeuvre by more than its noise — measured on
    two_link_payload (60°/40° in 1.5 s) at 0.64 s: FMU ∂tip.sx/∂τ_elbow over one sample 0.72, rest-pose
    model 0.91 — and the LQG went unstable there.
    """
    from scipy.linalg import expm

    from controllers.design import torque_inputs

    p = d.plant
    cols = torque_inputs(p)
    model = p.model
    fmu = [k for k, s_ in enumerate(model.inputs) if s_.fmu_variable]
    N, n, m = len(reference.time), p.nstates, len(cols)
    U = np.tile(p.op.u, (N, 1))
    u_ff = np.asarray(reference.u_ff, dtype=float).reshape(N, m)
    for j, i in enumerate(cols):
        U[:, fmu[i]] = p.u0[i] + u_ff[:, j]
    Ac, Bc = _flow_function(p, cols).map(N)((p.x0[None, :] + reference.x).T, U.T, p.op.p)
    Ac = np.asarray(Ac, dtype=float).reshape(n, N, n).transpose(1, 0, 2)
    Bc = np.asarray(Bc, dtype=float).reshape(n, N, m).transpose(1, 0, 2)
    A, B = np.empty_like(Ac), np.empty_like(Bc)
    blk = np.zeros((n + m, n + m))
    for k in range(N):
        blk[:n, :n], blk[:n, n:] = Ac[k], Bc[k]
        E = expm(blk * reference.dt)
        A[k], B[k] = E[:n, :n], E[:n, n:]
    x, uf = reference.x, u_ff
    W = np.zeros_like(x)
    n_move = int(round(reference.duration / reference.dt))
    dx, du = x - x[-1], uf - uf[-1]
    for k in range(n_move, N - 1):          # 0 along the inverse dynamics: the reference is the plant's flow
        W[k] = dx[k + 1] - A[k] @ dx[k] - B[k] @ du[k]
    return EstimatorAlong(A, B, kalman_gains_along(d.kalman, A, Cs), W)


def kalman_gains_along(kalman, As: np.ndarray, Cs: np.ndarray) -> np.ndarray:
    """The Kalman filter's gains ``M_k`` for the model ``A_k`` and sensor rows ``C_k`` along a reference, (N, n, p).

    The time-varying filter's Riccati recursion from the stationary design's prior covariance, with its
    per-sample noise covariances: ``Q_d = P_d − A_d (I − M_d C) P_d A_dᵀ`` (the stationary equation solved
    for it, ``A_d`` the rest pose's: ``As[0]``) and ``R``.  The stationary gain is designed on the rest pose's
    rows; the accelerometer's change several-fold along a large manoeuvre (the centripetal ``tip.sx`` has a
    zero row at rest), and with the rest gain ``A_k (I − M_d C_k)`` is unstable (two_link_payload,
    60°/40° in 1.5 s: the estimate diverged from 0.6 s on).
    """
    P, M, C, R = kalman.Pd, kalman.Md, kalman.C, kalman.RN
    n = P.shape[0]
    Q = P - As[0] @ (np.eye(n) - M @ C) @ P @ As[0].T
    Q = 0.5 * (Q + Q.T)
    gains = np.empty((len(Cs), n, C.shape[0]))
    for k, Ck in enumerate(Cs):
        S = Ck @ P @ Ck.T + R
        Mk = np.linalg.solve(S, Ck @ P).T               # P Cₖᵀ S⁻¹ (S, P symmetric)
        gains[k] = Mk
        IMC = np.eye(n) - Mk @ Ck
        P = As[k] @ (IMC @ P @ IMC.T + Mk @ R @ Mk.T) @ As[k].T + Q      # Joseph form: P stays positive
        P = 0.5 * (P + P.T)
    return gains


def reference_step(reference: Reference, Ad: np.ndarray, Bd: np.ndarray) -> np.ndarray:
    """The reference's own step ``w_k`` in the estimator's prediction, non-zero where it leaves the plant's flow.

    Where the reference stops being a trajectory of the plant (from the manoeuvre's end: its jump to rest at
    the targets), the deviation's prediction carries the reference's own step: ``e⁺ = A_d e + B_d (u −
    u_ff) − w_k`` with ``w_k = x_ref,k+1 − F(x_ref,k, u_ff,k)`` (0 along the inverse dynamics).  The plant's
    step F is linearised about the final rest (an equilibrium of the plant: ``F(x_end, u_end) = x_end``),
    so that ``w_k = 0`` once at rest: ``w_k = (x_ref,k+1 − x_end) − A_d (x_ref,k − x_end) − B_d (u_ff,k −
    u_end)``.  Linearised about the start pose instead, gravity's pose-dependent torques make the rest at
    the target a moving state of the model, and the estimator a steady bias (the six-axis arm: 0.11° at
    the shoulder).
    """
    x, uf = reference.x, reference.u_ff
    dx, du = x - x[-1], uf - uf[-1]
    W = np.zeros_like(x)
    n_move = int(round(reference.duration / reference.dt))
    W[n_move:-1] = dx[n_move + 1:] - dx[n_move:-1] @ Ad.T - du[n_move:-1] @ Bd.T
    return W


def joint_pd_gains(d, zeta: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """(kp, kd) per actuated joint, so that the PD is as fast as the LQR and comparable with it.

    Each joint's rigid-body pair sits at the LQR's slowest pair ω_n with damping ζ on the locked-arm inertia
    M_jj: ``kp = M_jj ω_n²``, ``kd = 2 ζ ω_n M_jj``.
    """
    wn, _ = d.lqr.rigid_pair
    model = d.plant.model
    J = np.array([d.plant.mechanics.M[i, i] for i in (model.coordinates.index(drive_coordinate(model, j))
                                                      for j in d.actuated_joints)])
    return J * wn**2, 2 * zeta * wn * J


class JointPDLaw:
    """One PD per joint on its encoder and rate, around the same reference and feedforward."""

    kind = "pd"

    def __init__(self, d, limits: Sequence[float], zeta: float = 0.7):
        from controllers.design import torque_inputs

        p = d.plant
        self.dt, self.inputs = d.dt, list(d.lqr.inputs)
        joints = d.actuated_joints
        self.sensors = [f"{j}.{w}" for j in joints for w in ("theta", "omega")]
        self.kp, self.kd = joint_pd_gains(d, zeta)
        self.u0 = p.u0[torque_inputs(p)]
        self.y0 = p.y0[[p.output_row(s) for s in self.sensors]]
        n = p.nstates
        self.rows = [r for j in joints for r in (p.state_index(f"{j}.theta"), n // 2 + p.state_index(f"{j}.theta"))]
        self.G = self.gain_matrix()
        self.limits = np.asarray(limits, dtype=float)

    def gain_matrix(self) -> np.ndarray:
        """The sensor gains, ``u − u₀ − u_ff = −G (y − y_ref)`` (m × 2m)."""
        m = len(self.kp)
        G = np.zeros((m, 2 * m))
        G[range(m), range(0, 2 * m, 2)] = self.kp
        G[range(m), range(1, 2 * m, 2)] = self.kd
        return G

    def reset(self) -> None:
        """Nothing to reset: the PD keeps no state between samples."""

    def step(self, y, x_ref, u_ff) -> np.ndarray:
        """One sample: feedforward plus the PD on the joints' angle and rate errors, saturated."""
        u = self.u0 + u_ff - self.G @ (y - self.y0 - x_ref[self.rows])
        return np.clip(u, -self.limits, self.limits)


def _settling_time(t: np.ndarray, outside: np.ndarray) -> float | None:
    """The time from which ``outside`` stays False to the end (0 if never True); None if True at the end."""
    if outside[-1]:
        return None
    bad = np.flatnonzero(outside)
    return float(t[bad[-1] + 1]) if len(bad) else 0.0


def metrics(pl: Plan, series: Mapping[str, np.ndarray], duration: float, limits: Sequence[float],
            band_deg: float, band_m: float, wall_time: float | None) -> dict:
    """The run's figures, the same for every law so that runs compare.

    Per joint the final error, peak torque and saturated fraction; per link the residual vibration (RMS of ``tip.v``
    minus its static value at the targets, over the window after the manoeuvre) and the largest tip deflection; the
    settling time (from the start, after which every joint stays within ``band_deg`` of its target and every tip
    within ``band_m`` of its static deflection).
    """
    t = series["time"]
    window = t >= duration - 1e-12
    outside = np.zeros(len(t), dtype=bool)
    joints, links = {}, {}
    for k, j in enumerate(pl.joints):
        err = series[f"{j}.theta"] - pl.target[k]
        u = series[f"{j}.tau"]
        outside |= np.abs(err) > math.radians(band_deg)
        joints[j] = {"final_error_deg": float(np.degrees(err[-1])), "peak_torque_nm": float(np.max(np.abs(u))),
                     "saturated_fraction": float(np.mean(np.abs(u) >= limits[k] * (1 - 1e-12)))}
    for lk, static in pl.tip_static.items():
        dev = series[f"{lk}.tip.v"] - static
        outside |= np.abs(dev) > band_m
        links[lk] = {"residual_vibration_rms_m": float(np.sqrt(np.mean(dev[window] ** 2))),
                     "max_tip_deflection_m": float(np.max(np.abs(dev)))}
    return {"joints": joints, "links": links,
            "residual_vibration_rms_m": max(v["residual_vibration_rms_m"] for v in links.values()),
            "settling_time_s": _settling_time(t, outside), "settle_band_deg": band_deg, "settle_band_m": band_m,
            "realtime_factor": float((t[-1] - t[0]) / wall_time) if wall_time else None}


def sensor_noise(law, levels: Mapping[str, float] | None = None) -> dict[str, float]:
    """The standard deviation of the noise on each sensor a law reads.

    ``levels`` where given (a Kalman design's ``noise``: what its estimator was told), else
    :data:`controllers.design.SENSOR_NOISE` by kind (the PD's encoders and rate sensors): the levels the
    single-joint run adds with ``--noise``.
    """
    from controllers.design import SENSOR_NOISE, sensor_kind

    levels = levels or {}
    return {s: float(levels[s]) if s in levels else SENSOR_NOISE[sensor_kind(s)] for s in law.sensors}


def run(d, loop: FmuLoop, pl: Plan, ref: Reference, law, *, parameters: Mapping[str, float] | None = None,
        band_deg: float = 0.1, band_m: float = 1e-3, x0: np.ndarray | None = None,
        noise: Mapping[str, float] | None = None, seed: int = 0):
    """One closed-loop run of ``law`` along ``ref`` through the FMU.

    ``noise``: sensor name → standard deviation of the white Gaussian noise added to what the law reads (the
    recorded outputs and the figures stay noise-free), drawn from ``seed`` (:meth:`FmuLoop.run`).
    Returns a :class:`controllers.manoeuvre.ManoeuvreResult` with :func:`metrics` (``series`` also holds each
    joint's ``theta_ref``).
    """
    from controllers.figures import ManoeuvreResult

    for name in [f"{j}.theta" for j in pl.joints] + [f"{lk}.tip.v" for lk in pl.tip_static]:
        if name not in loop.record:
            loop.record.append(name)
    res = loop.run(law, ref, parameters=parameters, noise=noise or None, seed=seed)
    x0 = d.plant.x0 if x0 is None else x0             # the operating point (without a design: the cached one)
    series = dict(res.series)
    for k, j in enumerate(pl.joints):
        series[f"{j}.theta_ref"] = ref.x[:, pl.angle_index[k]] + x0[pl.angle_index[k]]
    m = metrics(pl, series, ref.duration, law.limits, band_deg, band_m, res.wall_time)
    m.update({"controller": law.kind, "torque_limits_nm": dict(zip(pl.joints, law.limits.tolist(), strict=True))})
    settle = float(ref.time[-1]) - ref.duration
    return ManoeuvreResult(law.kind, pl.target, ref.duration, settle, series, ref, m, dict(parameters or {}))


def compare(d, loop: FmuLoop, targets: Sequence[float], duration: float, settle: float, *,
            parameters: Mapping[str, float] | None = None, band_deg: float = 0.1, band_m: float = 1e-3,
            pl: Plan | None = None, noise: bool = False, seed: int = 0) -> dict:
    """The MIMO LQG and the joint PD, each through the FMU along the same reference and feedforward.

    The PD's torque limit is the LQG run's peak torque of each joint, so neither law gets more torque.  Returns
    ``{"lqr": result, "pd": result}``. ``pl``: the :func:`plan` to ``targets`` if the caller has it already.
    ``noise``: each law reads its sensors with their noise (:func:`sensor_noise`, the Kalman design's levels),
    drawn from ``seed``.
    """
    from controllers.trajectory import check_times

    check_times(duration, settle, d.dt)
    check_multijoint(d)
    pl = plan(d.plant, targets) if pl is None else pl
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, duration, settle)
    laws = (MimoLQGLaw(d, [d.lqr.torque_limits[j] for j in pl.joints], ref), JointPDLaw(d, [1.0] * len(pl.joints)))
    return compare_laws(loop, pl, ref, *laws, d.plant.x0, parameters=parameters, band_deg=band_deg, band_m=band_m,
                        noise=d.kalman.noise if noise else None, seed=seed)


def compare_laws(loop: FmuLoop, pl: Plan, ref: Reference, lqg_law, pd_law, x0: np.ndarray, *,
                 noise: Mapping[str, float] | None = None, seed: int = 0, **kw) -> dict:
    """:func:`compare` from its laws, which the design cache can hold without the design.

    The LQG runs first, then the PD with its torque limits set to the LQG run's peaks.  ``noise`` (None: none):
    the Kalman design's sensor levels, each law's sensors read with :func:`sensor_noise` of them, the same
    ``seed`` for both.
    """
    lqg_noise = None if noise is None else sensor_noise(lqg_law, noise)
    lqg = run(None, loop, pl, ref, lqg_law, x0=x0, noise=lqg_noise, seed=seed, **kw)
    pd_law.limits = np.asarray([lqg.metrics["joints"][j]["peak_torque_nm"] for j in pl.joints])
    pd_noise = None if noise is None else sensor_noise(pd_law, noise)
    pd = run(None, loop, pl, ref, pd_law, x0=x0, noise=pd_noise, seed=seed, **kw)
    return {"lqr": lqg, "pd": pd}
