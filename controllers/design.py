"""Controller design on a linearised plant: LQR (Bryson's rule), Kalman estimator, joint PD baseline.

Everything returns python-control objects or plain arrays that python-control produced:

* :func:`bryson_weights` — Q, R from physical limits (max hub error, max tip deflection, max root moment,
  torque limit), ``Q = C_zᵀ diag(1/z_max²) C_z``, ``R = 1/u_max²``;
* :func:`design_lqr` — ``control.lqr`` on the continuous plant and ``control.dlqr`` on the plant sampled
  (zero-order hold) at the controller's sample time;
* :func:`design_kalman` — ``control.lqe`` / ``control.dlqe`` from realistic sensors (hub encoder plus
  root strain gauge or tip accelerometer) and a torque-disturbance process noise;
* :func:`design_pd` — joint PD whose rigid-body closed-loop pair sits at a given natural frequency and
  damping ratio, placed exactly on the flexible model (not only on the rigid inertia);
* :func:`rigid_pair` — natural frequency and damping of the dominant (slowest) closed-loop pair.

The plant is a :class:`flexlink.run.linearize.LinearPlant` (deviation variables about its operating point).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import control as ct
import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.run.linearize import LinearPlant

__all__ = [
    "SENSOR_NOISE",
    "KalmanDesign",
    "LQRDesign",
    "PDDesign",
    "bryson_weights",
    "design_kalman",
    "design_lqr",
    "design_pd",
    "rigid_pair",
    "sample",
    "sensor_set",
]

#: Default sensor noise, standard deviation per sensor kind (SI): a 16384-count/rev encoder (quantisation
#: step / √12), a root strain-gauge bridge read as a bending moment, a MEMS accelerometer over a 500 Hz band.
SENSOR_NOISE = {
    "theta": 2 * np.pi / 16384 / np.sqrt(12.0),   # rad
    "omega": 1e-3,                                 # rad/s (tachometer)
    "moment": 5e-3,                                # N m
    "specific_force": 0.05,                        # m/s²
    "deflection": 1e-4,                            # m
}


def sensor_kind(name: str) -> str:
    """The :data:`SENSOR_NOISE` entry that applies to an output name."""
    return _sensor_kind(name)


def _sensor_kind(name: str) -> str:
    if name.endswith(".theta"):
        return "theta"
    if name.endswith(".omega"):
        return "omega"
    if name.endswith(".root.moment"):
        return "moment"
    if name.startswith("tip.s") or name.startswith("tip.a"):
        return "specific_force"
    if name.endswith(".tip.v") or name.endswith(".tip.w"):
        return "deflection"
    raise FlexlinkError(f"{name}: no default noise level for this output; give it in `noise`")


def sensor_set(plant_or_model, kind: str) -> list[str]:
    """FMU names of a sensor set: ``"strain"`` (hub encoder + root strain gauge of the last link) or
    ``"accelerometer"`` (hub encoder + two-axis tip accelerometer: specific force x and y in the tip frame).

    At rest ``tip.sx`` (centripetal, second order in the rate) has a zero row in the linearised C, so the
    stationary Kalman filter gives it no gain: the information comes from ``tip.sy``.
    """
    model = plant_or_model.model if isinstance(plant_or_model, LinearPlant) else plant_or_model
    joint, link = model.scene.joints[0].name, model.scene.links[-1].name
    if kind == "strain":
        return [f"{joint}.theta", f"{link}.root.moment"]
    if kind == "accelerometer":
        return [f"{joint}.theta", "tip.sx", "tip.sy"]
    raise FlexlinkError(f'sensors: expected "strain" or "accelerometer", got {kind!r}')


def sample(plant: LinearPlant, dt: float) -> ct.StateSpace:
    """The plant sampled with a zero-order hold at ``dt`` (``control.sample_system``), names kept."""
    return ct.sample_system(plant.sys, dt, method="zoh", name=plant.sys.name + "_d")


def bryson_weights(plant: LinearPlant, limits: Mapping[str, float], torque_limit: float):
    """Bryson's rule: ``Q = C_zᵀ diag(1/z_max²) C_z`` over the outputs named in ``limits``, ``R = 1/u_max²``.

    Parameters
    ----------
    plant : LinearPlant
        Must have the outputs named in ``limits`` (FMU names).
    limits : dict
        FMU output name → largest acceptable deviation (SI), e.g. ``{"hub.theta": 0.0175,
        "arm.tip.v": 0.005, "arm.root.moment": 0.8}``.
    torque_limit : float
        Largest acceptable torque, N m.

    Returns
    -------
    Q : (n, n) ndarray, R : (1, 1) ndarray
    """
    rows = [plant.output_row(name) for name in limits]
    Cz = plant.sys.C[rows]
    if np.any(plant.sys.D[rows] != 0):
        raise FlexlinkError(f"Bryson weights on outputs with feedthrough ({list(limits)}) are not supported")
    w = np.array([1.0 / float(v) ** 2 for v in limits.values()])
    Q = Cz.T @ np.diag(w) @ Cz
    return 0.5 * (Q + Q.T), np.array([[1.0 / torque_limit**2]])


@dataclass
class LQRDesign:
    """Continuous and sampled LQR gains for ``u = u_ff − K (x − x_ref)``.

    Attributes
    ----------
    K, S, poles : continuous ``control.lqr`` results (gain, Riccati solution, closed-loop poles)
    Kd, Sd, poles_d : sampled ``control.dlqr`` results at ``dt``
    Q, R : the weights; ``limits`` and ``torque_limit`` the physical values they came from
    plant_d : the ZOH-sampled plant (``control.StateSpace``, ``dt`` set)
    """

    plant: LinearPlant
    dt: float
    Q: np.ndarray
    R: np.ndarray
    K: np.ndarray
    S: np.ndarray
    poles: np.ndarray
    Kd: np.ndarray
    Sd: np.ndarray
    poles_d: np.ndarray
    plant_d: ct.StateSpace
    limits: dict = field(default_factory=dict)
    torque_limit: float = np.inf

    @property
    def rigid_pair(self) -> tuple[float, float]:
        """(ω_n rad/s, ζ) of the continuous design's dominant closed-loop pair."""
        return rigid_pair(self.poles)


def default_limits(plant: LinearPlant, torque_limit: float, *, hub_error: float = np.radians(1.0),
                   tip_deflection: float = 5e-3, root_moment: float | None = None) -> dict[str, float]:
    """The physical limits behind the default weights.

    Max hub error 1°, max tip deflection 5 mm, max root bending moment 10 % of the torque limit (it damps
    the higher modes, which the tip deflection alone barely weighs).
    """
    model = plant.model
    joint, link = model.scene.joints[0].name, model.scene.links[-1].name
    limits = {f"{joint}.theta": hub_error, f"{link}.tip.v": tip_deflection}
    root_moment = 0.1 * torque_limit if root_moment is None else root_moment
    if root_moment and np.isfinite(root_moment):
        limits[f"{link}.root.moment"] = root_moment
    return limits


def design_lqr(plant: LinearPlant, dt: float, torque_limit: float, limits: Mapping[str, float] | None = None,
               **limit_kw) -> LQRDesign:
    """LQR from Bryson's rule, continuous (``control.lqr``) and sampled at ``dt`` (``control.dlqr``).

    Parameters
    ----------
    plant : LinearPlant
    dt : float
        Controller sample time, s.
    torque_limit : float
        N m; also the R weight.
    limits : dict, optional
        Output limits for :func:`bryson_weights` (default :func:`default_limits` with ``limit_kw``:
        ``hub_error``, ``tip_deflection``, ``root_moment``).
    """
    limits = dict(limits) if limits is not None else default_limits(plant, torque_limit, **limit_kw)
    Q, R = bryson_weights(plant, limits, torque_limit)
    K, S, E = ct.lqr(plant.sys, Q, R)
    plant_d = sample(plant, dt)
    Kd, Sd, Ed = ct.dlqr(plant_d, Q, R)
    return LQRDesign(plant, dt, Q, R, np.asarray(K), np.asarray(S), np.asarray(E), np.asarray(Kd), np.asarray(Sd),
                     np.asarray(Ed), plant_d, limits, float(torque_limit))


def rigid_pair(poles) -> tuple[float, float]:
    """Natural frequency (rad/s) and damping ratio of the slowest pair of continuous-time poles.

    With a rigid-body joint the slowest closed-loop pair is the rigid-body one: the flexible modes sit
    above the clamped-link frequencies.  Two real poles give ω_n = √(λ₁λ₂), ζ = −(λ₁+λ₂)/(2ω_n).
    """
    p = np.asarray(poles, dtype=complex)
    p = p[np.argsort(np.abs(p))][:2]
    wn = float(np.sqrt(abs(p[0] * p[1])))
    zeta = float(-(p[0] + p[1]).real / (2 * wn))
    return wn, zeta


@dataclass
class KalmanDesign:
    """Steady-state Kalman estimator from the named sensors.

    Attributes
    ----------
    sensors : FMU names of the measured outputs
    C, D : their rows of the plant's output matrices
    QN, RN : process (torque disturbance, plus ``accel`` on the elastic coordinates) and sensor covariances
    G : process-noise input matrix (continuous)
    L, P, poles : continuous ``control.lqe``
    Ld, Pd, poles_d : sampled ``control.dlqe`` (predictor gain: ``x̂⁺ = A x̂ + B u + L_d (y − C x̂ − D u)``)
    Md : the filter ("current estimator") gain ``P Cᵀ (C P Cᵀ + R)⁻¹`` that corrects x̂ with y_k before u_k
    """

    sensors: list[str]
    dt: float
    C: np.ndarray
    D: np.ndarray
    G: np.ndarray
    QN: np.ndarray
    RN: np.ndarray
    L: np.ndarray
    P: np.ndarray
    poles: np.ndarray
    Ld: np.ndarray
    Pd: np.ndarray
    poles_d: np.ndarray
    Md: np.ndarray
    noise: dict


def design_kalman(plant: LinearPlant, dt: float, sensors: Sequence[str] | str = "strain", *,
                  torque_noise: float = 0.1, elastic_noise: float = 0.0,
                  noise: Mapping[str, float] | None = None) -> KalmanDesign:
    """Kalman estimator (``control.lqe`` and ``control.dlqe``) from realistic sensors.

    Parameters
    ----------
    plant : LinearPlant
        Must have the sensors among its outputs.
    dt : float
        Sample time, s.
    sensors : list of str or {"strain", "accelerometer"}
        FMU output names, or a named set: hub encoder + root strain gauge, or hub
        encoder + tip accelerometer (``tip.sx``, ``tip.sy``: specific force in the tip frame); see
        :func:`sensor_set`.
    torque_noise : float
        Standard deviation of the unknown torque disturbance, N m (process noise through B).
    elastic_noise : float
        Standard deviation of an unknown generalized force on each elastic coordinate (model error).
    noise : dict, optional
        Sensor name → standard deviation, overriding :data:`SENSOR_NOISE`.

    Notes
    -----
    The sampled design treats the disturbances as held over each sample like the torque (``G_d`` is the
    zero-order-hold image of ``G``) and the sensor noise as independent from sample to sample; the
    standard deviations are per sample.
    """
    if isinstance(sensors, str):
        sensors = sensor_set(plant, sensors)
    sensors = list(sensors)
    rows = [plant.output_row(s) for s in sensors]
    C, D = plant.sys.C[rows], plant.sys.D[rows]
    noise = dict(noise or {})
    sigma = {s: float(noise[s]) if s in noise else SENSOR_NOISE[_sensor_kind(s)] for s in sensors}
    RN = np.diag([sigma[s] ** 2 for s in sensors])
    n = plant.sys.nstates
    nq = n // 2
    elastic = [k for k, c in enumerate(plant.model.coordinates) if not c.endswith(".theta")]
    # generalized forces on the elastic coordinates, through M⁻¹ like the torque
    Bq = plant.sys.B[nq:]                        # M⁻¹ B_u
    lin_minv = np.linalg.inv(plant.mechanics.M)
    cols = [Bq[:, 0]] + ([lin_minv[:, k] for k in elastic] if elastic_noise > 0 else [])
    G = np.vstack([np.zeros((nq, len(cols))), np.column_stack(cols)])
    QN = np.diag([torque_noise**2] + ([elastic_noise**2] * len(elastic) if elastic_noise > 0 else []))
    # G QN Gᵀ is passed whole (G = I): python-control insists on exact symmetry
    L, P, E = ct.lqe(plant.sys.A, np.eye(n), C, _sym(G @ QN @ G.T), RN)
    plant_d = sample(plant, dt)
    # the disturbance is held over each sample like the torque: G_d = ∫₀^dt e^{Aτ} dτ G; per-sample
    # covariances QN and RN (the continuous design above uses them as spectral densities: same ratio)
    Gd = ct.sample_system(ct.ss(plant.sys.A, G, np.zeros((1, n)), 0), dt, method="zoh").B
    Ld, Pd, Ed = ct.dlqe(plant_d.A, np.eye(n), C, _sym(Gd @ QN @ Gd.T), RN)
    Md = Pd @ C.T @ np.linalg.inv(C @ Pd @ C.T + RN)
    return KalmanDesign(sensors, dt, C, D, G, QN, RN, np.asarray(L), np.asarray(P), np.asarray(E), np.asarray(Ld),
                        np.asarray(Pd), np.asarray(Ed), Md, {s: float(v) for s, v in sigma.items()})


def _sym(X: np.ndarray) -> np.ndarray:
    return 0.5 * (X + X.T)


@dataclass
class PDDesign:
    """Joint PD ``u = u_ff + kp (θ_ref − θ) + kd (ω_ref − ω)`` (hub encoder and rate).

    ``poles`` are the continuous closed-loop poles of the flexible model under the PD (python-control),
    ``wn``, ``zeta`` the rigid-body pair it was placed at, ``inertia`` the rigid-body inertia M_θθ used
    by the rigid feedforward ``J θ̈_ref``.
    """

    kp: float
    kd: float
    wn: float
    zeta: float
    inertia: float
    poles: np.ndarray
    joint: str

    def gain_matrix(self, plant: LinearPlant) -> np.ndarray:
        """The PD as a state feedback ``u = −K x`` on the plant's state (for python-control)."""
        K = np.zeros((1, plant.sys.nstates))
        K[0, plant.state_index(f"{self.joint}.theta")] = self.kp
        K[0, plant.state_index(f"der({self.joint}.theta)")] = self.kd
        return K


def design_pd(plant: LinearPlant, wn: float, zeta: float = 0.7) -> PDDesign:
    """Joint PD that places a closed-loop pair of the *flexible* model exactly at ``ω_n``, ``ζ``.

    With G(s) = θ(s)/τ(s) the collocated transfer function, the characteristic equation of the loop is
    ``1 + (k_p + s k_d) G(s) = 0`` (matrix determinant lemma), so at s* = ω_n(−ζ + j√(1−ζ²)):
    ``k_p + s* k_d = −1/G(s*)`` — two real equations for (k_p, k_d).  For a rigid link this is
    ``k_p = J ω_n²``, ``k_d = 2ζω_n J``; the flexibility shifts the gains slightly.
    """
    joint = plant.model.scene.joints[0].name
    i_th = plant.output_row(f"{joint}.theta")
    s = wn * (-zeta + 1j * np.sqrt(1.0 - zeta**2))
    G = complex(np.squeeze(plant.sys[i_th, 0](s)))
    g = -1.0 / G
    kd = g.imag / s.imag
    kp = g.real - s.real * kd
    if kp <= 0 or kd <= 0:
        raise FlexlinkError(f"the PD pair at {wn:.3g} rad/s, zeta {zeta} needs non-positive gains "
                            f"(kp {kp:.3g}, kd {kd:.3g}): choose a lower frequency")
    pd = PDDesign(float(kp), float(kd), float(wn), float(zeta), 0.0, np.array([]), joint)
    A, B = plant.sys.A, plant.sys.B
    pd.poles = np.linalg.eigvals(A - B @ pd.gain_matrix(plant))
    i = plant.model.coordinates.index(f"{joint}.theta")
    pd.inertia = float(plant.mechanics.M[i, i])
    return pd
