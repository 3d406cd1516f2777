"""Integral action on the joint positions: the sampled LQR augmented with the integral of each joint's error.

Why: the multi-joint LQG holds its targets exactly only when the plant is its model.  A constant torque the
model lacks — a payload heavier than the scene's under gravity, a friction or motor offset — is met by the
state feedback alone with a steady joint error (the disturbance over the loop's stiffness).  The integral of
each actuated joint's encoder error, fed back as well, drives that error to zero.

* **Design.** The ZOH-sampled plant of the design (``x⁺ = A_d x + B_d u``) is augmented with one integrator per
  actuated joint, ``ξ⁺ = ξ + dt e``, ``e`` the joint's encoder reading minus its reference (``e = C_e x`` in
  the deviation).  ``control.dlqr`` on the augmented plant, with the design's Q and R and, per joint,
  Bryson's weight ``1/(e_max T_i)²`` on ξ (``e_max`` the design's joint-error limit, ``T_i`` the integral
  time: an error of ``e_max`` held for ``T_i`` is worth one unit), gives ``u = −K_x x − K_ξ ξ``.
* **Law** (:class:`IntegralLQGLaw`): the multi-joint LQG (:class:`controllers.multijoint.MimoLQGLaw`, its
  Kalman estimate, reference and feedforward) with ``K_x`` in place of the LQR gain, minus ``K_ξ ξ``; ξ
  integrates the measured encoder errors.  The estimator is told the torque applied, integral part included.
  Anti-windup by conditional integration: ξ holds while a torque is at its limit.
* **Margins** (:func:`integral_robustness`): the loop-at-a-time and disk margins of the sampled loop with the
  integrators (:func:`controllers.robustness.loop_at_a_time`), as ``flexlink control --design-only`` gives
  those of the LQG.

* **Scheduled** (:func:`design_scheduled_integral`, :class:`ScheduledIntegralLQGLaw`): with gain scheduling
  over the path (:mod:`controllers.schedule`) the same augmentation at every design point of the schedule,
  each on its own sampled plant and Kalman design, and the augmented gains ``K_x``, ``K_ξ`` interpolated in
  the path parameter σ with the other matrices (:func:`controllers.schedule.interpolate`).  ξ is the
  integral of the joints' encoder errors, the same coordinates at every pose: switching gains moves no
  integrator state.  Anti-windup as above.

Sensors linear in the state only (encoders, strain gauges): the accelerometer LQG's estimator follows the
reference (:mod:`controllers.multijoint`), to which this law does not extend yet.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import control as ct
import numpy as np

from controllers import riccati
from controllers.design import DesignError, torque_inputs
from controllers.multijoint import MimoLQGLaw, checked_step, reference_step
from controllers.robustness import loop_at_a_time, lqg_plant
from controllers.schedule import Schedule, interpolate, path_fraction
from controllers.trajectory import Reference

__all__ = ["IntegralDesign", "IntegralLQGLaw", "ScheduledIntegral", "ScheduledIntegralLQGLaw", "design_integral",
           "design_scheduled_integral", "integral_compensator", "integral_robustness", "sampled_integral_compensator"]


@dataclass
class IntegralDesign:
    """The LQR with integral action on the joint positions (module docstring).

    ``Kx`` (m, n) on the state deviation, ``Ki`` (m, m) on the joints' error integrals, ``encoders``: the
    Kalman sensors integrated (one per actuated joint, in the order of the torques), ``rows`` their rows in the
    sensor vector, ``integral_time`` (joint → s), ``poles_d`` the augmented sampled loop's poles (state
    feedback), ``design`` the LQG design it extends.
    """

    design: Any
    Kx: np.ndarray
    Ki: np.ndarray
    encoders: list[str]
    rows: list[int]
    integral_time: dict
    poles_d: np.ndarray


def design_integral(d, integral_time: float | Mapping[str, float] = 0.5) -> IntegralDesign:
    """Augment the sampled LQR of design ``d`` with the integral of every actuated joint's encoder error.

    Parameters
    ----------
    d : controllers.manoeuvre.ControlDesign
        The multi-joint (or one-joint) LQG design; its Kalman sensors must include every actuated joint's
        encoder and read nothing through the torques.
    integral_time : float or dict
        T_i, s, one for all joints or per joint: Bryson's limit on a joint's error integral is ``e_max T_i``.

    Raises
    ------
    DesignError
        A joint without its encoder among the sensors, sensors with feedthrough, a non-positive T_i.
    """
    joints = list(d.lqr.torque_limits)
    encoders = [f"{j}.theta" for j in joints]
    missing = [e for e in encoders if e not in d.kalman.sensors]
    if missing:
        raise DesignError(f"integral action: the encoders {', '.join(missing)} are not among the Kalman sensors")
    if np.any(np.asarray(d.kalman.D)[:, torque_inputs(d.plant)] != 0):
        raise DesignError("integral action: the sensors read the torques (accelerometers); use the strain gauges")
    ti = {j: float(integral_time[j] if isinstance(integral_time, Mapping) else integral_time) for j in joints}
    if not all(np.isfinite(v) and v > 0 for v in ti.values()):
        raise DesignError(f"integral action: the integral time must be positive, got {ti}")
    rows = [d.kalman.sensors.index(e) for e in encoders]
    Ad, Bd = np.asarray(d.lqr.plant_d.A), np.asarray(d.lqr.plant_d.B)
    Ce = np.asarray(d.kalman.C)[rows]
    n, m = Bd.shape
    Aa = np.block([[Ad, np.zeros((n, m))], [d.dt * Ce, np.eye(m)]])
    Ba = np.vstack([Bd, np.zeros((m, m))])
    qi = [1.0 / (d.lqr.limits[e] * ti[j]) ** 2 for j, e in zip(joints, encoders, strict=True)]
    Qa = np.block([[np.asarray(d.lqr.Q), np.zeros((n, m))], [np.zeros((m, n)), np.diag(qi)]])
    try:
        K, _, E = riccati.dlqr(Aa, Ba, Qa, np.asarray(d.lqr.R))
    except (ValueError, np.linalg.LinAlgError) as e:
        raise DesignError(f"integral action: the augmented Riccati equation has no stabilising solution "
                          f"({' '.join(str(e).split())})") from None
    K = np.asarray(K)
    return IntegralDesign(d, K[:, :n], K[:, n:], encoders, rows, ti, np.asarray(E))


class IntegralLQGLaw(MimoLQGLaw):
    """The multi-joint LQG with integral action on the joint positions (module docstring).

    ``step(y, x_ref, u_ff)`` → the saturated torques; ``xi`` the joints' error integrals (rad s).
    """

    kind = "lqr"

    def __init__(self, integral: IntegralDesign, limits: Sequence[float], reference: Reference):
        super().__init__(integral.design, limits, reference)
        if self.schedule is not None:
            raise DesignError("integral action: the sensors read the torques (accelerometers); use the strain gauges")
        self.Kx, self.Ki, self.rows = integral.Kx, integral.Ki, integral.rows
        self.Ce = self.C[self.rows]

    def reset(self) -> None:
        """Start a run: as :meth:`MimoLQGLaw.reset`, the integrals at zero."""
        super().reset()
        self.xi = np.zeros(len(self.u0))

    def matrices(self, k: int) -> tuple[np.ndarray, ...]:
        """(M, C, K_x, A_d, B_d): the LQG's, with the augmented design's state gain."""
        M, C, _, Ad, Bd = super().matrices(k)
        return M, C, self.Kx, Ad, Bd

    def integral_gain(self, k: int) -> np.ndarray:
        """K_ξ that sample ``k`` uses: the one design's (the scheduled law overrides this)."""
        return self.Ki

    @checked_step
    def step(self, y, x_ref, u_ff) -> np.ndarray:
        """One sample: the LQG with ``−K_ξ ξ`` added to the feedforward, the estimator told the torque applied.

        The error integrated is the measured encoder reading's deviation from the reference, ``y_e − y₀_e −
        C_e x_ref``; it is not integrated in a sample whose torque saturates (conditional anti-windup).
        """
        k = self.k
        v = -self.integral_gain(k) @ self.xi
        u = super().step(y, x_ref, u_ff + v)
        self.dz = self.dz + self.matrices(k)[4] @ v          # the prediction saw v as feedforward: it was torque
        if np.all(np.abs(u) < self.limits):
            e = np.asarray(y)[self.rows] - self.y0[self.rows] - self.Ce @ x_ref
            self.xi = self.xi + self.dt * e
        return u


def integral_compensator(integral: IntegralDesign) -> ct.StateSpace:
    """The law of :class:`IntegralLQGLaw` as a state space from the sensors' to the torques' deviations."""
    return sampled_integral_compensator(_table(integral), integral.rows, integral.design.dt)


def sampled_integral_compensator(matrices: tuple[np.ndarray, ...], rows: Sequence[int], dt: float) -> ct.StateSpace:
    """The LQG with integral action of ``matrices`` = (M, C, K_x, A_d, B_d, K_ξ) as a state space, sensors → torques.

    State (z, ξ): ``x̂ = (I − M C) z + M y``, ``u = −K_x x̂ − K_ξ ξ``, ``z⁺ = A_d x̂ + B_d u``,
    ``ξ⁺ = ξ + dt S_e y`` (``S_e`` selects the encoders, ``rows`` of the sensors).  Deviations throughout.
    """
    M, C, Kx, Ad, Bd, Ki = (np.asarray(a) for a in matrices)
    n, m = Bd.shape
    F = np.eye(n) - M @ C
    Se = np.eye(C.shape[0])[list(rows)]
    A = np.block([[(Ad - Bd @ Kx) @ F, -Bd @ Ki], [np.zeros((m, n)), np.eye(m)]])
    B = np.vstack([(Ad - Bd @ Kx) @ M, dt * Se])
    return ct.ss(A, B, np.hstack([-Kx @ F, -Ki]), -Kx @ M, dt)


def _table(integral: IntegralDesign) -> tuple[np.ndarray, ...]:
    """(M, C, K_x, A_d, B_d, K_ξ) of an augmented design: what its law uses."""
    d = integral.design
    return (np.asarray(d.kalman.Md), np.asarray(d.kalman.C), integral.Kx, np.asarray(d.lqr.plant_d.A),
            np.asarray(d.lqr.plant_d.B), integral.Ki)


def integral_robustness(integral: IntegralDesign, n_points: int = 4000) -> dict[str, Any]:
    """Margins of the sampled loop with integral action (:func:`controllers.robustness.loop_at_a_time`)."""
    d = integral.design
    return loop_at_a_time(lqg_plant(d.lqr, d.kalman), integral_compensator(integral), d.lqr.inputs, n_points)


@dataclass
class ScheduledIntegral:
    """Integral action in a gain schedule: the augmented design at each of its design points (module docstring).

    ``schedule`` (:class:`controllers.schedule.Schedule`), ``designs`` the :class:`IntegralDesign` of each of
    its points, in order; ``designs[0]`` is the start design's.
    """

    schedule: Schedule
    designs: list[IntegralDesign]

    @property
    def tables(self) -> list[tuple[np.ndarray, ...]]:
        """(M, C, K_x, A_d, B_d, K_ξ) at each design point."""
        return [_table(i) for i in self.designs]

    def matrices(self, s: float) -> tuple[np.ndarray, ...]:
        """(M, C, K_x, A_d, B_d, K_ξ) at path parameter ``s``, linear between neighbouring design points."""
        return interpolate(self.schedule.sigma, self.tables, s)

    def laws(self, limits, ref) -> tuple[MimoLQGLaw, MimoLQGLaw]:
        """The scheduled law and the fixed one of the start design, both with integral action.

        For :func:`controllers.schedule.compare_schedule`, which cannot import this module (it imports that one).
        """
        return (ScheduledIntegralLQGLaw(self, limits, ref), IntegralLQGLaw(self.designs[0], limits, ref))

    def frozen_compensators(self, s: float, dt: float) -> list[tuple[str, Any]]:
        """The scheduled and the fixed loop's compensators frozen at ``s`` (:func:`controllers.schedule.along_path`)."""
        fixed = self.designs[0]
        return [("scheduled", sampled_integral_compensator(self.matrices(s), fixed.rows, dt)),
                ("fixed", sampled_integral_compensator(self.tables[0], fixed.rows, dt))]


def design_scheduled_integral(schedule: Schedule,
                              integral_time: float | Mapping[str, float] = 0.5) -> ScheduledIntegral:
    """:func:`design_integral` at every design point of ``schedule`` (the same T_i, Bryson limits and weights).

    Raises
    ------
    DesignError
        As :func:`design_integral`, naming the design point (σ) whose augmented design fails.
    """
    designs = []
    for s, d in zip(schedule.sigma, schedule.designs, strict=True):
        try:
            designs.append(design_integral(d, integral_time))
        except DesignError as e:
            raise DesignError(f"{e} (the schedule's design point at path parameter {s:g})") from None
    return ScheduledIntegral(schedule, designs)


class ScheduledIntegralLQGLaw(IntegralLQGLaw):
    """The scheduled LQG (:class:`controllers.schedule.ScheduledLQGLaw`) with integral action on the joints.

    Its operating point, reference and feedforward are the start design's, as the scheduled law's; at sample
    k every matrix, K_x and K_ξ included, is the schedule's at the reference's path parameter σ(t_k).
    """

    kind = "scheduled"

    def __init__(self, integral: ScheduledIntegral, limits: Sequence[float], reference: Reference):
        super().__init__(integral.designs[0], limits, reference)
        tables = integral.tables
        self._at = [interpolate(integral.schedule.sigma, tables, float(s)) for s in path_fraction(reference)]
        _, _, _, Ad, Bd, _ = self._at[-1]              # after the manoeuvre: the target's design
        self.W = reference_step(reference, Ad, Bd)

    def matrices(self, k: int) -> tuple[np.ndarray, ...]:
        """(M, C, K_x, A_d, B_d) at sample ``k``, interpolated once per sample at construction."""
        return self._at[k][:5]

    def integral_gain(self, k: int) -> np.ndarray:
        """K_ξ at sample ``k``, interpolated with the other matrices."""
        return self._at[k][5]
