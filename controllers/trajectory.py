"""Rest-to-rest references for the first joint: the quintic and its flexible-model generalisation.

* :func:`quintic` — θ(t) = θ₀ + Δ (10τ³ − 15τ⁴ + 6τ⁵), τ = t/T: the minimum-jerk rest-to-rest law of a
  *rigid* link (it minimises ∫ θ⃛² dt, i.e. ∫ τ̇² for J θ̈ = τ).  The joint PD tracks it, with the
  rigid-body feedforward ``J θ̈``.
* :func:`min_jerk_feedforward` — the same criterion on the *whole* linearised flexible model: the sampled
  torque sequence (zero-order hold, the controller's sample time) with minimal Σ (u_k − u_{k−1})² that
  brings every state — joint angle, elastic coordinates and rates — from rest to rest at the target in
  the given time, starting and ending with zero torque.  For a rigid link it is the quintic; for the
  flexible link it leaves, in the linear sampled model, no residual vibration at all.  The state
  trajectory it produces is the LQR's reference ``x_ref``, the torque its feedforward ``u_ff``.

All quantities are deviations from the plant's operating point (the start pose).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from controllers.riccati import SampledSystem

__all__ = ["Reference", "check_times", "min_jerk_feedforward", "min_jerk_reference", "quintic", "quintic_reference"]


def quintic(t, delta: float, duration: float):
    """(θ, θ̇, θ̈) of the quintic rest-to-rest law from 0 to ``delta`` in ``duration`` (held after)."""
    tau = np.clip(np.asarray(t, dtype=float) / duration, 0.0, 1.0)
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    sd = 30 * tau**2 * (1 - tau) ** 2 / duration
    sdd = 60 * tau * (1 - tau) * (1 - 2 * tau) / duration**2
    return delta * s, delta * sd, delta * sdd


@dataclass
class Reference:
    """A sampled reference: state ``x[k]`` and feedforward ``u_ff[k]`` at ``time[k] = k·dt`` (deviations).

    ``u_ff[k]`` is held over ``[t_k, t_k + dt)``.  ``theta``, ``omega`` are the first joint's reference angle
    and rate (the corresponding entries of ``x``).
    """

    kind: str
    dt: float
    duration: float
    time: np.ndarray
    x: np.ndarray
    u_ff: np.ndarray
    joint_index: int

    @property
    def theta(self) -> np.ndarray:
        """The driven joint's reference angle at each sample (a deviation from the start pose), rad."""
        return self.x[:, self.joint_index]

    @property
    def omega(self) -> np.ndarray:
        """The driven joint's reference rate at each sample, rad/s (the rates are the second half of x)."""
        return self.x[:, self.x.shape[1] // 2 + self.joint_index]


def _grid(duration: float, total: float, dt: float):
    n_move = int(round(duration / dt))
    if abs(n_move * dt - duration) > 1e-9 * max(1.0, duration):
        raise ValueError(f"the manoeuvre duration {duration} s is not a multiple of the sample time {dt} s")
    n_total = int(round(total / dt))
    return n_move, n_total, np.arange(n_total + 1) * dt


def quintic_reference(plant, delta: float, duration: float, total: float, dt: float, inertia: float) -> Reference:
    """The joint PD's reference: quintic angle and rate, elastic coordinates zero, ``u_ff = J θ̈``."""
    n_move, n_total, t = _grid(duration, total, dt)
    n = plant.nstates
    j = plant.model.coordinates.index(plant.model.scene.joints[0].name + ".theta")
    th, thd, thdd = quintic(t, delta, duration)
    x = np.zeros((len(t), n))
    x[:, j], x[:, n // 2 + j] = th, thd
    return Reference("quintic", dt, duration, t, x, inertia * thdd, j)


def min_jerk_feedforward(plant_d: SampledSystem, x_final, n_steps: int) -> np.ndarray:
    """The smoothest torque sequence that takes the sampled plant from rest to ``x_final`` in N steps.

    Torque sequence u_0 … u_{N−1} of minimal Σ_{k=0}^{N} (u_k − u_{k−1})² (u_{−1} = u_N = 0) with
    u_0 = u_{N−1} = 0 that takes the sampled plant from x = 0 to ``x_final`` in N steps.

    Equality-constrained least squares: u = H⁻¹Gᵀ(G H⁻¹ Gᵀ)⁻¹ g with H the (tridiagonal) second-difference
    matrix and G the constraint rows (x_N = Σ A^{N−1−k} B u_k, the two end torques), scaled row by row.
    """
    A, B = np.asarray(plant_d.A), np.asarray(plant_d.B)[:, 0]
    n = A.shape[0]
    G = np.zeros((n + 2, n_steps))
    v = B.copy()
    for k in range(n_steps - 1, -1, -1):
        G[:n, k] = v
        v = A @ v
    G[n, 0] = 1.0
    G[n + 1, -1] = 1.0
    g = np.concatenate([np.asarray(x_final, dtype=float), [0.0, 0.0]])
    norms = np.linalg.norm(G, axis=1)
    keep = norms > 1e-300
    G, g = G[keep] / norms[keep, None], g[keep] / norms[keep]
    bands = np.zeros((2, n_steps))
    bands[0, 1:] = -1.0
    bands[1, :] = 2.0
    import scipy.linalg

    HiGt = scipy.linalg.solveh_banded(bands, G.T)
    S = G @ HiGt
    lam = np.linalg.lstsq(S, g, rcond=1e-13)[0]
    return HiGt @ lam


def min_jerk_reference(plant_d: SampledSystem, joint_index: int, delta: float, duration: float, total: float,
                       x_final=None) -> Reference:
    """The LQR's reference: :func:`min_jerk_feedforward` and the sampled plant's response to it.

    ``x_final`` defaults to the rest state with the joint at ``delta`` (elastic deflection unchanged).
    After the manoeuvre, ``x_ref`` stays at ``x_final`` and ``u_ff`` at 0.
    """
    dt = float(plant_d.dt)
    n_move, n_total, t = _grid(duration, total, dt)
    n = plant_d.nstates
    if x_final is None:
        x_final = np.zeros(n)
        x_final[joint_index] = delta
    u = np.zeros(len(t))
    u[:n_move] = min_jerk_feedforward(plant_d, x_final, n_move)
    A, B = np.asarray(plant_d.A), np.asarray(plant_d.B)[:, 0]
    x = np.zeros((len(t), n))
    for k in range(n_move):
        x[k + 1] = A @ x[k] + B * u[k]
    x[n_move:] = x_final
    return Reference("min-jerk", dt, duration, t, x, u, joint_index)


def check_times(duration: float, settle: float, dt: float) -> None:
    """A manoeuvre's times: positive, multiples of the sample time, a run that ends (one clear message)."""
    from flexlink.errors import FlexlinkError
    from flexlink.run.simulate import check_run

    if not (np.isfinite(duration) and duration > 0):
        raise FlexlinkError(f"--duration must be a positive number of seconds, got {duration}")
    if not (np.isfinite(settle) and settle > 0):
        raise FlexlinkError(f"--settle must be a positive number of seconds, got {settle}")
    for what, v in (("--duration", duration), ("--settle", settle)):
        if abs(round(v / dt) * dt - v) > 1e-9 * max(1.0, v):
            raise FlexlinkError(f"{what} {v} s must be a multiple of the sample time {dt} s")
    check_run(duration + settle, dt, "--duration + --settle", "--sample-time")    # a run that would not end
