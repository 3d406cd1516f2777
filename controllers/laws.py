"""Sampled control laws, run step by step against the FMU and as python-control systems.

Every law has the same shape, at each sample k (t_k = k·dt)::

    x̂_k = state estimate from the measurements y_k (deviations from the operating point)
    u_k = sat(u₀ + u_ff[k] − K (x̂_k − x_ref[k]))      (sat: ± torque limit)

* :class:`LQGLaw` — x̂_k from the steady-state Kalman filter (``dlqe``), in its "current estimator" form:
  predict with the sampled model and the torque actually applied (after saturation: no wind-up),
  correct with y_k before computing u_k; K from ``dlqr``.
* :class:`PDLaw` — x̂_k has only the joint angle and rate, measured (encoder and rate sensor).

A measured output with feedthrough (the accelerometer: D ≠ 0) is sampled at t_k while the previous
torque u_{k−1} is still applied — that is what a co-simulation master reads after ``doStep`` — so the
estimator predicts it with ``D u_{k−1}``.

**Outputs linearised along the reference.** The plant is linearised at rest, but an output such as the
tip accelerometer is far from linear over a large manoeuvre: seen in the deflected tip frame, the
tangential and centripetal accelerations leak into ``tip.sy`` in proportion to the tip slope, and its
sensitivity to the torque (D) changes several-fold (on the payload scene: −0.047 at rest, −0.24 at
0.26 m of deflection).  Predicting the measurement with the rest-pose C, D then closes a fast loop
u_{k−1} → y_k → u_k that destabilises the LQG.  :meth:`SampledLaw.follow` therefore gives the estimator a
measurement model linearised along the reference — ``ŷ_k = h(x_ref,k, u_ff,k−1) + C_k (x̂ − x_ref,k) +
D_k (u_{k−1} − u_ff,k−1)`` — which is the rest-pose model for outputs linear in the state (encoder, strain
gauge) and for any small manoeuvre.

:meth:`SampledLaw.statespace` returns the unsaturated law as a discrete ``control.StateSpace`` from
(measurements, x_ref, u_ff) to u, the very matrices that :meth:`SampledLaw.step` uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from controllers.trajectory import Reference

if TYPE_CHECKING:             # python-control (2-7 s of imports) only where a law is designed or analysed,
    import casadi as ca  # CasADi only where the sensors are linearised along a reference
    import control as ct

    from controllers.design import KalmanDesign, LQRDesign, PDDesign
    from flexlink.run.linearize import LinearPlant

__all__ = ["AffineForm", "LQGLaw", "MeasurementSchedule", "PDLaw", "SampledLaw", "measurement_schedule",
           "reference_names"]


def reference_names(n: int) -> list[str]:
    """python-control names of the reference inputs: ``xref[0..n-1]`` and ``uff``."""
    return [f"xref[{i}]" for i in range(n)] + ["uff"]


@dataclass
class MeasurementSchedule:
    """The sensors' outputs linearised along a reference, per sample k.

    ``y_ref[k] = h(x₀ + x_ref[k], u₀ + u_ff[k−1])`` (absolute), ``C[k] = ∂h/∂x``, ``D[k] = ∂h/∂u`` there: a
    sensor that is not affine in the state (a tip position far from the rest pose) is read by the estimator
    as it is along the manoeuvre, not as at rest.
    """

    y_ref: np.ndarray   # (N, p)
    C: np.ndarray       # (N, p, n)
    D: np.ndarray       # (N, p), or (N, p, m) for the m inputs of a multi-joint law
    u_ff_prev: np.ndarray  # (N,) or (N, m): deviation torque held while y_k is sampled, along the reference


def _sensor_function(plant: LinearPlant, sensors: list[str], inputs: tuple[int, ...] = (0,)) -> ca.Function | None:
    """The sensors as a scalar (SX) function (x, u, p) → (y, ∂y/∂x, ∂y/∂u), cached on the plant.

    ``∂y/∂u`` is taken on the plant's ``inputs`` (indices in ``plant.inputs``: the first for one joint, every
    joint torque for the multi-joint law).  None when the sensors are affine in (x, u): the rest-pose model is
    then exact.
    """
    key = ("sensor_function", tuple(sensors), tuple(inputs))
    if key in plant.cache:
        return plant.cache[key]
    import casadi as ca

    from controllers.sensor_model import sensor_outputs

    model = plant.model
    u = ca.SX.sym("u", model.residual.size1_in(3))
    p = ca.SX.sym("p", model.residual.size1_in(4))
    x, y = sensor_outputs(model, sensors, u, p)
    cols = [k for k, s in enumerate(model.inputs) if s.fmu_variable]
    Cx, Du = ca.jacobian(y, x), ca.jacobian(y, u)[:, [cols[i] for i in inputs]]
    xu = ca.vertcat(x, u)
    f = None
    if ca.depends_on(ca.vertcat(ca.vec(Cx), ca.vec(Du)), xu):
        f = ca.Function("sensors", [x, u, p], [y, Cx, Du])
    plant.cache[key] = f
    return f


def measurement_schedule(plant: LinearPlant, sensors: list[str], reference: Reference,
                         inputs: list[int] | None = None) -> MeasurementSchedule | None:
    """Linearise the sensors' outputs about every sample of ``reference``.

    ``inputs``: the indices in ``plant.inputs`` that ``reference.u_ff`` drives, one column each (the
    multi-joint law's joint torques); None: the first input, ``u_ff`` one number per sample, and ``D``,
    ``u_ff_prev`` without the input axis (the single-joint law).  None when the sensors are affine in the
    state and input (encoder, strain gauge): the rest-pose model is then the same.
    """
    cols_p = [0] if inputs is None else list(inputs)
    f = _sensor_function(plant, sensors, tuple(cols_p))
    if f is None:
        return None
    model = plant.model
    cols = [k for k, s in enumerate(model.inputs) if s.fmu_variable]
    N = len(reference.time)
    u_ff = np.asarray(reference.u_ff, dtype=float).reshape(N, len(cols_p))
    u_prev = np.vstack([np.zeros((1, len(cols_p))), u_ff[:-1]])
    X = plant.x0[None, :] + reference.x
    U = np.tile(plant.op.u, (N, 1))
    for j, i in enumerate(cols_p):
        U[:, cols[i]] = plant.u0[i] + u_prev[:, j]
    Y, Cs, Ds = f.map(N)(X.T, U.T, plant.op.p)
    p_ = len(sensors)
    n = plant.nstates
    Cs = np.asarray(Cs, dtype=float).reshape(p_, N, n).transpose(1, 0, 2)   # columns k·n + j → [k, :, j]
    Ds = np.asarray(Ds, dtype=float).reshape(p_, N, len(cols_p)).transpose(1, 0, 2)
    if inputs is None:
        return MeasurementSchedule(np.asarray(Y, dtype=float).T, Cs, Ds[:, :, 0], u_prev[:, 0])
    return MeasurementSchedule(np.asarray(Y, dtype=float).T, Cs, Ds, u_prev)


@dataclass
class AffineForm:
    """A law along one reference as one matrix product per sample.

    Issue 22: the closed loop through fmpy spends its time in Python, so a sample must be as few calls as
    possible.

    With ``w_k = (y_k, s_k, u_{k−1}, 1)`` — the measurements (FMU values), the law's state, the torque
    applied at the previous sample (absolute; ``u0`` before the first) and 1 — one sample is::

        (s_{k+1}, v_k) = G w_k,   G = [Gy, Gs, gu, g1]
        u_k = clip(v_k + r[k], −limit, limit)

    ``r[k]`` carries everything that depends on the reference (``u0 + u_ff[k] + K x_ref[k]``), so nothing of
    the reference is copied into ``w`` during the run.  Same arithmetic as :meth:`SampledLaw.step` up to
    rounding (the estimator's correction and prediction folded into one matrix).
    """

    Gy: np.ndarray      # (ns + 1, p) on the sensors, in ``sensors`` order
    Gs: np.ndarray      # (ns + 1, ns) on the law's state
    gu: np.ndarray      # (ns + 1,) on the previous torque (absolute)
    g1: np.ndarray      # (ns + 1,) constant
    r: np.ndarray       # (N,) torque offset per sample (absolute)
    u0: float           # torque before the first sample (the operating point's)
    limit: float

    @property
    def n_state(self) -> int:
        """The number of the law's own states (0 for the static PD)."""
        return self.Gs.shape[1]


class SampledLaw:
    """Common part: sensors, operating point, gain, saturation."""

    kind = "law"

    def __init__(self, plant: LinearPlant, dt: float, K: np.ndarray, sensors: list[str], torque_limit: float):
        self.plant = plant
        self.dt = float(dt)
        self.K = np.atleast_2d(np.asarray(K, dtype=float))
        self.sensors = list(sensors)
        self.torque_limit = float(torque_limit)
        rows = [plant.output_row(s) for s in self.sensors]
        self.y0 = plant.y0[rows]
        self.u0 = float(plant.u0[0])
        self.input = plant.inputs[0]
        self.n = plant.nstates
        self.k = 0

    def reset(self) -> None:
        """Back to rest at the operating point, sample counter to 0 (call before each run)."""
        self.k = 0

    def follow(self, reference: Reference | None) -> None:
        """Use the measurement model linearised along ``reference`` in the next runs (None: the rest-pose one).

        Only the LQG's estimator uses it.
        """

    def estimate(self, y: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
        """The state deviation x̂_k the law feeds back, from the measurements y_k (each law its own)."""
        raise NotImplementedError

    def step(self, y, x_ref: np.ndarray, u_ff: float) -> float:
        """One sample: measurements y_k (FMU values, in ``sensors`` order) → applied torque u_k."""
        xh = self.estimate(np.asarray(y, dtype=float), x_ref)
        self.k += 1
        du = u_ff - float(self.K[0] @ (xh - x_ref))
        u = min(max(self.u0 + du, -self.torque_limit), self.torque_limit)
        self.applied(u - self.u0)
        return u

    def applied(self, du: float) -> None:
        """Told the deviation torque actually applied (after saturation)."""

    def affine(self, reference: Reference) -> AffineForm | None:
        """The law along ``reference`` as an :class:`AffineForm`, or None when it has none.

        With None the loop calls :meth:`step`.  Call after :meth:`follow`.
        """
        return None

    def _offsets(self, reference: Reference) -> np.ndarray:
        """``u0 + u_ff[k] + K x_ref[k]`` for every sample: the reference's part of the torque."""
        return self.u0 + reference.u_ff + reference.x @ self.K[0]

    def statespace(self) -> ct.StateSpace:
        """The unsaturated law as a discrete python-control system, for the linear closed loop and margins."""
        raise NotImplementedError

    def _names(self):
        from flexlink.run.linearize import signal_name

        return [signal_name(s) for s in self.sensors] + reference_names(self.n), [signal_name(self.input)]


class LQGLaw(SampledLaw):
    """LQR state feedback on the Kalman filter's estimate (separation principle)."""

    kind = "lqr"

    def __init__(self, lqr: LQRDesign, kalman: KalmanDesign, torque_limit: float | None = None):
        super().__init__(lqr.plant, lqr.dt, lqr.Kd, kalman.sensors,
                         lqr.torque_limit if torque_limit is None else torque_limit)
        if abs(kalman.dt - lqr.dt) > 1e-15:
            raise ValueError("the LQR and the Kalman filter must share the sample time")
        self.lqr, self.kalman = lqr, kalman
        self.Ad, self.Bd = np.asarray(lqr.plant_d.A), np.asarray(lqr.plant_d.B)[:, 0]
        self.C, self.D = kalman.C, kalman.D[:, 0]
        self.M = kalman.Md
        self.has_feedthrough = bool(np.any(self.D != 0))
        self.schedule: MeasurementSchedule | None = None
        # one sample without a schedule as two products on buffers allocated once (issue 22: the law was
        # half of the closed loop's time per step): x̂ = [I − MC, M, −MD, −M y₀] (z, y, u_prev, 1),
        # z⁺ = [A_d, B_d] (x̂, u − u₀)
        p = len(self.sensors)
        self._E = np.hstack([np.eye(self.n) - self.M @ self.C, self.M, (-self.M @ self.D)[:, None],
                             (-self.M @ self.y0)[:, None]])
        self._P = np.hstack([self.Ad, self.Bd[:, None]])
        self._zy = np.zeros(self.n + p + 2)
        self._xu = np.zeros(self.n + 1)
        self._K0 = self.K[0]
        self.reset()

    def reset(self) -> None:
        """Back to rest: also the estimate at the operating point and no torque held."""
        super().reset()
        self.z = np.zeros(self.n)       # prior estimate x̂_k|k−1
        self.u_prev = 0.0               # deviation torque held while y_k was sampled
        self.xh = np.zeros(self.n)

    def follow(self, reference: Reference | None) -> None:
        """Read the sensors along ``reference`` (:func:`measurement_schedule`; None: as at rest)."""
        self.schedule = None if reference is None else measurement_schedule(self.plant, self.sensors, reference)

    def step(self, y, x_ref: np.ndarray, u_ff: float) -> float:
        """One sample, as :meth:`SampledLaw.step`.

        Without a measurement schedule in the composed form (same arithmetic up to rounding).
        """
        if self.schedule is not None and self.k < len(self.schedule.y_ref):
            return super().step(y, x_ref, u_ff)
        n, zy, xu = self.n, self._zy, self._xu
        zy[:n] = self.z
        zy[n:-2] = y
        zy[-2] = self.u_prev
        zy[-1] = 1.0
        xh = xu[:n]
        np.dot(self._E, zy, out=xh)
        self.k += 1
        u = self.u0 + u_ff - float(self._K0 @ (xh - x_ref))
        u = min(max(u, -self.torque_limit), self.torque_limit)
        xu[n] = self.u_prev = u - self.u0
        self.xh = xh.copy()
        self.z = self._P @ xu
        return u

    def affine(self, reference: Reference) -> AffineForm | None:
        """The LQG as an :class:`AffineForm`; None with a measurement schedule (it varies per sample).

        The state is ``s = A_d x̂`` (the prediction without the torque's part, which comes in through
        ``u_{k−1}``), so ``x̂_k = X (y_k, s_k, u_{k−1}, 1)`` with
        ``X = [M, I − MC, (I − MC) B_d − MD, −M y₀ − ((I − MC) B_d − MD) u₀]``; ``v = −K x̂``, ``s⁺ = A_d x̂``.
        """
        if self.schedule is not None:
            return None
        IMC = np.eye(self.n) - self.M @ self.C
        xu = IMC @ self.Bd - self.M @ self.D
        X = np.hstack([self.M, IMC, xu[:, None], (-self.M @ self.y0 - xu * self.u0)[:, None]])
        G = np.vstack([self.Ad @ X, -self.K[0] @ X])
        p, n = len(self.sensors), self.n
        return AffineForm(G[:, :p], G[:, p:p + n], G[:, p + n], G[:, p + n + 1], self._offsets(reference),
                          self.u0, self.torque_limit)

    def estimate(self, y: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
        """The Kalman filter's corrected estimate x̂_k|k from its prediction and the innovation y_k − ŷ_k."""
        sc, k = self.schedule, self.k
        if sc is None or k >= len(sc.y_ref):
            y_hat = self.y0 + self.C @ self.z + self.D * self.u_prev
        else:
            y_hat = sc.y_ref[k] + sc.C[k] @ (self.z - x_ref) + sc.D[k] * (self.u_prev - sc.u_ff_prev[k])
        self.xh = self.z + self.M @ (y - y_hat)
        return self.xh

    def applied(self, du: float) -> None:
        """Predict the next state with the torque actually applied (after saturation), not the one asked."""
        self.z = self.Ad @ self.xh + self.Bd * du
        self.u_prev = du

    def statespace(self) -> ct.StateSpace:
        """Unsaturated law: states (x̂_k|k−1[, u_{k−1}]), inputs (y − y0, x_ref, u_ff), output u − u0."""
        n = self.n
        K, M, C = self.K, self.M, self.C
        D = self.D.reshape(-1, 1)
        IMC = np.eye(n) - M @ C
        # x̂ = (I − MC) z − M D u_prev + M y ;  u = u_ff − K x̂ + K x_ref
        Fz, Fp, Fy = IMC, -M @ D, M
        Uz, Up, Uy, Ur, Uf = -K @ Fz, -K @ Fp, -K @ Fy, K, np.ones((1, 1))
        Ad, Bd = self.Ad, self.Bd.reshape(-1, 1)
        # z⁺ = Ad x̂ + Bd u
        Az = np.hstack([Ad @ Fz + Bd @ Uz, Ad @ Fp + Bd @ Up])
        Bz = np.hstack([Ad @ Fy + Bd @ Uy, Bd @ Ur, Bd @ Uf])
        Au = np.hstack([Uz, Up])
        Bu = np.hstack([Uy, Ur, Uf])
        Cc, Dc = np.hstack([Uz, Up]), np.hstack([Uy, Ur, Uf])
        states = [f"xhat[{i}]" for i in range(n)]
        if self.has_feedthrough:
            A = np.vstack([Az, Au])
            B = np.vstack([Bz, Bu])
            states.append("u_prev")
        else:
            A, B, Cc = Az[:, :n], Bz, Cc[:, :n]
        inputs, outputs = self._names()
        import control as ct

        return ct.ss(A, B, Cc, Dc, self.dt, inputs=inputs, outputs=outputs, states=states, name="lqg")


class PDLaw(SampledLaw):
    """Joint PD on the measured joint angle and rate."""

    kind = "pd"

    def __init__(self, pd: PDDesign, plant: LinearPlant, dt: float, torque_limit: float):
        joint = pd.joint
        super().__init__(plant, dt, pd.gain_matrix(plant), [f"{joint}.theta", f"{joint}.omega"], torque_limit)
        self.pd = pd
        self.S = np.zeros((self.n, 2))
        self.S[plant.state_index(f"{joint}.theta"), 0] = 1.0
        self.S[plant.state_index(f"der({joint}.theta)"), 1] = 1.0

    def estimate(self, y: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
        """The measured joint angle and rate placed in the state vector; the rest of x̂ is zero."""
        return self.S @ (y - self.y0)

    def affine(self, reference: Reference) -> AffineForm:
        """No state: ``v = −K S (y − y₀)``."""
        KS = self.K[0] @ self.S
        return AffineForm(-KS[None, :], np.zeros((1, 0)), np.zeros(1), np.array([KS @ self.y0]),
                          self._offsets(reference), self.u0, self.torque_limit)

    def statespace(self) -> ct.StateSpace:
        """Static law u − u0 = u_ff − K (S (y − y0) − x_ref), as a state-less discrete system."""
        inputs, outputs = self._names()
        Dc = np.hstack([-self.K @ self.S, self.K, np.ones((1, 1))])
        import control as ct

        return ct.ss([], np.zeros((0, Dc.shape[1])), np.zeros((1, 0)), Dc, self.dt, inputs=inputs, outputs=outputs,
                     name="pd")
