"""Controller design on a linearised plant: LQR (Bryson's rule), Kalman estimator, joint PD baseline.

Everything returns plain arrays, equal to python-control's results to the last bit: the Riccati solutions
and the sampling are :mod:`controllers.riccati`'s, python-control's own SciPy calls made without importing
python-control (1.2–1.5 s of imports before a designing command's first FMU call, issue 22):

* :func:`bryson_weights` — Q, R from physical limits (max joint error per joint, max tip deflection and
  root moment per link, torque limit per joint), ``Q = C_zᵀ diag(1/z_max²) C_z``, ``R = diag(1/u_max²)``;
* :func:`design_lqr` — ``control.lqr`` on the continuous plant and ``control.dlqr`` on the plant sampled
  (zero-order hold) at the controller's sample time, on every torque-driven joint;
* :func:`design_kalman` — ``control.lqe`` / ``control.dlqe`` from realistic sensors (every joint's encoder
  plus the links' root strain gauges or the tip accelerometer) and a torque-disturbance process noise;
* :func:`design_pd` — joint PD whose rigid-body closed-loop pair sits at a given natural frequency and
  damping ratio, placed exactly on the flexible model (not only on the rigid inertia);
* :func:`rigid_pair` — natural frequency and damping of the dominant (slowest) closed-loop pair.

The plant is a :class:`flexlink.run.linearize.LinearPlant` (deviation variables about its operating point).
A design that cannot be made — no torque-driven joint, a rigid-body or undamped mode the torques cannot move
or the sensors cannot see, no sensor — raises :class:`DesignError` with one line naming the cause.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from controllers import riccati
from controllers.riccati import SampledSystem
from flexlink.errors import FlexlinkError
from flexlink.run.linearize import LinearPlant, signal_name

__all__ = [
    "SENSOR_NOISE",
    "DesignError",
    "KalmanDesign",
    "LQRDesign",
    "PDDesign",
    "accelerometers",
    "bryson_weights",
    "design_kalman",
    "design_lqr",
    "design_pd",
    "is_link_accelerometer",
    "joint_encoders",
    "stabilizability",
    "rigid_pair",
    "sample",
    "sensor_set",
    "torque_inputs",
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
    if name.startswith(("tip.s", "tip.a")) or is_link_accelerometer(name):
        return "specific_force"
    if name.endswith(".tip.v") or name.endswith(".tip.w"):
        return "deflection"
    raise FlexlinkError(f"{name}: no default noise level for this output; give it in `noise`")


def is_link_accelerometer(name: str) -> bool:
    """Whether an output is an axis of a link's declared tip accelerometer, ``<link>.tip.s{x,y,z}``."""
    head, _, axis = name.rpartition(".tip.s")
    return bool(head) and axis in ("x", "y", "z")


def accelerometers(plant_or_model) -> list[str]:
    """The accelerometer axes ``--sensors accelerometer`` reads: x and y of every link's tip accelerometer.

    Every link that declares one in the scene (``sensors = ["accelerometer"]``: ``<link>.tip.sx``, ``.sy``), in scene
    order, and the last link's tip (``tip.sx``, ``tip.sy``, the end effector's) unless the last link declares its
    own there.  The z axes are outputs too, but on a planar arm they read nothing (``tip.sz`` stays 0): a spatial
    arm's design names them in an explicit sensor list.
    """
    model = plant_or_model.model if isinstance(plant_or_model, LinearPlant) else plant_or_model
    outputs = {s.name for s in model.outputs}
    links = [lk.name for lk in model.scene.links if f"{lk.name}.tip.sx" in outputs]
    names = [f"{lk}.tip.s{c}" for lk in links for c in "xy"]
    if model.scene.links[-1].name not in links:
        names += [s for s in ("tip.sx", "tip.sy") if s in outputs]
    return names


def joint_encoders(plant_or_model) -> list[str]:
    """``<joint>.theta`` of every joint whose angle is a free coordinate, in scene order: the encoders.

    Torque-driven and free joints are measured; a position-driven joint's angle is its law, known without a
    sensor.
    """
    model = plant_or_model.model if isinstance(plant_or_model, LinearPlant) else plant_or_model
    return [f"{j.name}.theta" for j in model.scene.joints if f"{j.name}.theta" in model.coordinates]


def sensor_set(plant_or_model, kind: str) -> list[str]:
    """FMU names of a sensor set, what the Kalman filter of a design reads.

    The set is the encoders of every joint (:func:`joint_encoders`) plus ``"strain"`` (the root strain gauge of
    every link that has one) or ``"accelerometer"`` (two-axis tip accelerometers, specific force x and y in the tip
    frame: every link's that the scene declares and the last tip's, :func:`accelerometers`).

    At rest ``tip.sx`` (centripetal, second order in the rate) has a zero row in the linearised C, so the
    stationary Kalman filter gives it no gain: the information comes from ``tip.sy``.
    """
    model = plant_or_model.model if isinstance(plant_or_model, LinearPlant) else plant_or_model
    outputs = [s.name for s in model.outputs]
    if kind == "strain":
        extra = [f"{lk.name}.root.moment" for lk in model.scene.links if f"{lk.name}.root.moment" in outputs]
    elif kind == "accelerometer":
        extra = accelerometers(model)
    else:
        raise FlexlinkError(f'sensors: expected "strain" or "accelerometer", got {kind!r}')
    return joint_encoders(model) + extra


def torque_inputs(plant: LinearPlant) -> list[int]:
    """Indices in ``plant.inputs`` of the joint torques, in scene order: the actuators of the designs here.

    They are the ``<joint>.tau`` inputs of the torque-driven joints; a tip load input is a disturbance, not an
    actuator.
    """
    names = [f"{j.name}.tau" for j in plant.model.scene.joints if j.drive == "torque"]
    return [plant.inputs.index(n) for n in names if n in plant.inputs]


def actuated_joints(plant: LinearPlant) -> list[str]:
    """Names of the torque-driven joints, in the order of :func:`torque_inputs`."""
    return [plant.inputs[i].removesuffix(".tau") for i in torque_inputs(plant)]


def _actuated_columns(plant: LinearPlant) -> list[int]:
    """:func:`torque_inputs`, refused (one line) when there is none: the columns of B the designs act on."""
    cols = torque_inputs(plant)
    if not cols:
        drives = ", ".join(f'{j.name} (drive = "{j.drive}")' for j in plant.model.scene.joints)
        raise FlexlinkError(f"no torque-driven joint: nothing to actuate (joints: {drives})")
    return cols


def per_joint(value, joints: Sequence[str], what: str, known: Sequence[str] | None = None) -> dict[str, float]:
    """A number for every joint (or link) in ``joints``, from one number for all or a mapping by name.

    The names a mapping lacks get none (``nan``); names outside ``known`` (default ``joints``) are refused, so
    that a misspelt joint is an error rather than a silently unweighted one.
    """
    if isinstance(value, Mapping):
        known = list(joints if known is None else known)
        for k in value:
            if k not in known:
                raise FlexlinkError(f"{what}: {k!r} is not one of {known}")
        return {j: float(value[j]) if j in value else float("nan") for j in joints}
    return {j: float(value) for j in joints}


def sample(plant: LinearPlant, dt: float, inputs: Sequence[int] | None = None) -> SampledSystem:
    """The plant sampled with a zero-order hold at ``dt``, names kept: ``control.sample_system``'s matrices.

    ``inputs`` (indices in ``plant.inputs``, default all) restricts B and D to those columns.
    """
    cols = list(range(len(plant.inputs))) if inputs is None else list(inputs)
    return SampledSystem.sample(plant.A, plant.B[:, cols], plant.C, plant.D[:, cols], dt, name=plant.name + "_d",
                                states=plant.states, inputs=[signal_name(plant.inputs[i]) for i in cols],
                                outputs=[signal_name(s) for s in plant.outputs])


class DesignError(FlexlinkError):
    """A design that cannot be made (no actuator, an uncontrollable or unobservable mode, no sensor)."""


def _torque_limits(plant: LinearPlant, torque_limit) -> dict[str, float]:
    """Joint name → torque limit (N m) of every actuated joint.

    From one number, or a mapping by joint (or by its ``<joint>.tau`` input, the FMU's name).
    """
    joints = actuated_joints(plant)
    if isinstance(torque_limit, Mapping):
        named = {str(k).removesuffix(".tau"): v for k, v in torque_limit.items()}
        for k in named:
            if k not in joints:
                raise DesignError(_no_actuator(plant, k, "a torque limit"))
        missing = [j for j in joints if j not in named]
        if missing:
            raise DesignError(f"torque limit: none given for the actuated joint(s) {missing}")
        limits = {j: float(named[j]) for j in joints}
    else:
        limits = {j: float(torque_limit) for j in joints}
    for j, v in limits.items():
        if not (v > 0):
            raise DesignError(f'joint "{j}": the torque limit must be positive, got {v}')
    return limits


def _no_actuator(plant: LinearPlant, name: str, what: str) -> str:
    for j in plant.model.scene.joints:
        if j.name == name:
            return (f'joint "{name}" is not torque-driven (drive = "{j.drive}"): it has no actuator, so {what} '
                    f"cannot apply to it")
    return f"{what}: {name!r} is not a joint of the scene; the actuated joints are {actuated_joints(plant)}"


def bryson_weights(plant: LinearPlant, limits: Mapping[str, float], torque_limit):
    """Bryson's rule, the LQR weights that make each named output's and torque's limit cost alike.

    ``Q = C_zᵀ diag(1/z_max²) C_z`` over the outputs named in ``limits``, ``R = diag(1/u_max,i²)`` over the
    joint torques.

    Parameters
    ----------
    plant : LinearPlant
        Must have the outputs named in ``limits`` (FMU names).
    limits : dict
        FMU output name → largest acceptable deviation (SI), e.g. ``{"hub.theta": 0.0175,
        "arm.tip.v": 0.005, "arm.root.moment": 0.8}``; the modal coordinates ``<link>.eta[k]`` are outputs
        too (a weight per mode).
    torque_limit : float or dict
        Largest acceptable torque, N m: one for every torque-driven joint, or a mapping joint name (or
        ``<joint>.tau``) → limit.

    Returns
    -------
    Q : (n, n) ndarray, R : (m, m) ndarray (m torque-driven joints, in :func:`torque_inputs` order)
    """
    rows = [plant.output_row(name) for name in limits]
    Cz = plant.C[rows]
    if np.any(plant.D[rows] != 0):
        raise FlexlinkError(f"Bryson weights on outputs with feedthrough ({list(limits)}) are not supported")
    w = np.array([1.0 / float(v) ** 2 for v in limits.values()])
    Q = Cz.T @ np.diag(w) @ Cz
    u_max = np.array(list(_torque_limits(plant, torque_limit).values()))
    return 0.5 * (Q + Q.T), np.diag(1.0 / u_max**2)


@dataclass
class LQRDesign:
    """Continuous and sampled LQR gains for ``u = u_ff − K (x − x_ref)`` on the joint torques.

    Attributes
    ----------
    K, S, poles : continuous ``control.lqr`` results (gain (m, n), Riccati solution, closed-loop poles)
    Kd, Sd, poles_d : sampled ``control.dlqr`` results at ``dt``
    Q, R : the weights; ``limits`` and ``torque_limits`` (joint → N m) the physical values they came from;
        ``torque_limit`` the first actuated joint's (what the single-joint laws saturate at)
    plant_d : the ZOH-sampled plant (:class:`controllers.riccati.SampledSystem`: ``A``, ``B``, ``dt``; its
        ``sys`` is python-control's), joint torques as its inputs
    inputs : FMU names of the m joint torques (the rows of K)
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
    plant_d: SampledSystem
    limits: dict = field(default_factory=dict)
    torque_limit: float = np.inf
    torque_limits: dict = field(default_factory=dict)
    inputs: list = field(default_factory=list)

    @property
    def rigid_pair(self) -> tuple[float, float]:
        """(ω_n rad/s, ζ) of the continuous design's dominant closed-loop pair."""
        return rigid_pair(self.poles)


def default_limits(plant: LinearPlant, torque_limit, *, hub_error: float | Mapping[str, float] = np.radians(1.0),
                   tip_deflection: float | Mapping[str, float] = 5e-3,
                   root_moment: float | Mapping[str, float] | None = None) -> dict[str, float]:
    """The physical limits behind the default weights, per joint and per link.

    Every joint with a free angle: max error ``hub_error`` (1°); every link with a tip deflection output:
    max tip deflection ``tip_deflection`` (5 mm) and max root bending moment ``root_moment`` (default 10 %
    of the torque limit of the joint that carries the link, else of the largest torque limit: it damps
    the higher modes, which the tip deflection alone barely weighs).  Each may be one number or a mapping
    by joint or link name (a name it lacks gets no weight).
    """
    model = plant.model
    outputs = plant.outputs
    tl = _torque_limits(plant, torque_limit)
    joints = [e.removesuffix(".theta") for e in joint_encoders(model)]
    links = [lk.name for lk in model.scene.links if f"{lk.name}.tip.v" in outputs]
    limits = {f"{j}.theta": v for j, v in per_joint(hub_error, joints, "joint error").items() if np.isfinite(v)}
    tips = per_joint(tip_deflection, links, "tip deflection", [lk.name for lk in model.scene.links])
    if root_moment is None:
        carrier = {lk.name: model.scene.joints[i].name for i, lk in enumerate(model.scene.links)
                   if i < len(model.scene.joints)}
        moments = {lk: 0.1 * (tl[carrier[lk]] if carrier.get(lk) in tl else max(tl.values())) for lk in links}
    else:
        moments = per_joint(root_moment, links, "root moment", [lk.name for lk in model.scene.links])
    for lk in links:
        if np.isfinite(tips[lk]) and tips[lk]:
            limits[f"{lk}.tip.v"] = tips[lk]
        if np.isfinite(moments[lk]) and moments[lk] and f"{lk}.root.moment" in outputs:
            limits[f"{lk}.root.moment"] = moments[lk]
    return limits


def _modes(A: np.ndarray):
    """Eigenvalues with left and right eigenvectors (scipy), the left ones conjugated for ``wᴴ``."""
    import scipy.linalg

    lam, wl, vr = scipy.linalg.eig(A, left=True, right=True)
    return lam, wl, vr


def _mode_name(plant: LinearPlant, lam: complex, v: np.ndarray) -> str:
    n = plant.model.n_q
    coord = plant.model.coordinates[int(np.argmax(np.abs(v[:n])))]
    f = abs(lam) / (2 * np.pi)
    kind = "rigid-body mode (0 Hz)" if f < 1e-6 else f"mode at {f:.4g} Hz"
    return f"the {kind}, mostly {coord}"


def _critical(lam: complex) -> bool:
    """Whether an eigenvalue is on or right of the imaginary axis, which a stabilising design must reach.

    Such a mode is undamped flexible or rigid-body; the tolerance is relative to the eigenvalue's size.
    """
    return lam.real >= -1e-9 * max(1.0, abs(lam))


def _unreachable(A: np.ndarray, B: np.ndarray, vecs: np.ndarray, lam: np.ndarray,
                 tol: float) -> list[tuple[int, np.ndarray]]:
    """The critical eigenvalues at which ``[A − λI, B]`` loses rank (PBH): the modes B cannot move.

    Indices k of lam[k] (one of each conjugate pair), B's columns normalised.  A simple eigenvalue is tested with
    its eigenvector (``vecs[:, k]``: ``wᴴ B ≈ 0`` relative to ``|w|``); a repeated one — the rigid-body modes, a
    Jordan block at 0, or a symmetric part's double mode — by the smallest singular value of ``[A − λI, B]``
    relative to its largest, below ``1e-4 tol`` (the eigenvectors of a cluster are not reliable; on the two-link arm
    a controllable rigid-body pair has 3e-11 there, an unactuated joint 4e-19).

    Returns (k, w) pairs, w the vector that B misses (for a cluster: the left singular vector).
    """
    Bn = B / np.maximum(np.linalg.norm(B, axis=0), 1e-300)
    scale = max(1.0, float(np.max(np.abs(lam))))
    out: list[tuple[int, np.ndarray]] = []
    seen: list[complex] = []
    for k in range(len(lam)):
        lk = lam[k]
        if not _critical(lk) or lk.imag < -1e-9 * max(1.0, abs(lk)):
            continue
        cluster = np.abs(lam - lk) < 1e-6 * max(1.0, abs(lk)) + 1e-6 * np.sqrt(scale)
        if np.count_nonzero(cluster) > 1:
            lc = complex(np.mean(lam[cluster]))
            lc = 0.0 if abs(lc) < 1e-6 * np.sqrt(scale) else lc
            if any(abs(lc - s) < 1e-6 * max(1.0, abs(lc)) + 1e-6 * np.sqrt(scale) for s in seen):
                continue
            seen.append(lc)
            U, sv, _ = np.linalg.svd(np.hstack([A - lc * np.eye(len(A)), Bn]))
            if sv[-1] < 1e-4 * tol * sv[0]:
                out.append((k, U[:, -1]))
        elif np.max(np.abs(vecs[:, k].conj() @ Bn)) < tol * np.linalg.norm(vecs[:, k]):
            out.append((k, vecs[:, k]))
    return out


def _at_rest(lam: np.ndarray, k: int) -> bool:
    """``lam[k]`` is the rigid-body eigenvalue 0 (the cluster test's own zero, :func:`_unreachable`)."""
    return abs(lam[k]) < 1e-6 * np.sqrt(max(1.0, float(np.max(np.abs(lam)))))


def _rigid_blind(K: np.ndarray, G: np.ndarray, tol: float = 1e-6) -> list[np.ndarray]:
    """The rigid-body motions (null space of the stiffness K, n_q × n_q) that the columns of G miss.

    G is n_q × m: the torques' generalised forces, or the sensors' displacement rows transposed.

    PBH at λ = 0 for ``M q̈ + C q̇ + K q = S u``: ``wᴴ [A, B] = 0`` reduces to ``Kᵀ z = 0, Sᵀ z = 0`` (and
    ``K v = 0, C_q v = 0`` for the sensors).  Tested on the mechanics rather than on ``[A, B]``: the
    rigid-body cluster's singular values sit below the stiffest mode's by more than any fixed ratio once a
    chain has stiff torsion or an elastic joint (the six-axis arm: 7e-16 for a controllable arm).
    """
    import scipy.linalg

    Z = scipy.linalg.null_space(K, rcond=1e-9)
    if Z.size == 0 or G.size == 0:
        return [Z[:, k] for k in range(Z.shape[1])] if G.size == 0 else []
    Gn = G / np.maximum(np.linalg.norm(G, axis=0), 1e-300)
    U, sv, _ = np.linalg.svd(Z.T @ Gn)
    sv = np.concatenate([sv, np.zeros(Z.shape[1] - len(sv))]) if len(sv) < Z.shape[1] else sv
    return [Z @ U[:, k] for k in range(Z.shape[1]) if sv[k] < tol]


def stabilizability(plant: LinearPlant, B: np.ndarray | None = None, tol: float = 1e-8) -> list[tuple[complex, str]]:
    """The modes no LQR can stabilise: critical modes that the joint torques cannot move.

    The PBH test (:func:`_unreachable`; the rigid-body modes on the mechanics, :func:`_rigid_blind`) among the modes
    on or right of the imaginary axis.  Returns (eigenvalue, description) pairs, the description naming the
    frequency and the coordinate that dominates the mode.
    """
    A = np.asarray(plant.A)
    B = np.asarray(plant.B[:, _actuated_columns(plant)] if B is None else B)
    lam, wl, _ = _modes(A)
    n = plant.model.n_q
    mech = plant.mechanics
    Minv = np.linalg.inv(mech.M)
    # a left vector (w_q, w_v) of A that B misses: the displacement it weighs is M⁻¹ w_v (undamped)
    out = [(lam[k], _mode_name(plant, lam[k], Minv @ w[n:])) for k, w in _unreachable(A, B, wl, lam, tol)
           if not _at_rest(lam, k)]
    if any(_at_rest(lam, k) for k in range(len(lam))):
        out += [(0j, _mode_name(plant, 0j, z)) for z in _rigid_blind(mech.K.T, mech.M @ B[n:])]
    return out


def _detectability(plant: LinearPlant, C: np.ndarray, tol: float = 1e-8) -> list[tuple[complex, str]]:
    """The dual of :func:`stabilizability`: critical modes the sensors C do not see."""
    A = np.asarray(plant.A)
    C = np.asarray(C)
    lam, _, vr = _modes(A)
    n = plant.model.n_q
    out = [(lam[k], _mode_name(plant, lam[k], v.conj())) for k, v in _unreachable(A.T, C.T, vr.conj(), lam, tol)
           if not _at_rest(lam, k)]
    if any(_at_rest(lam, k) for k in range(len(lam))):
        out += [(0j, _mode_name(plant, 0j, z)) for z in _rigid_blind(plant.mechanics.K, C[:, :n].T)]
    return out


def _check_stabilizable(plant: LinearPlant, B: np.ndarray) -> None:
    bad = stabilizability(plant, B)
    if not bad:
        return
    joints = actuated_joints(plant)
    passive = [j for j in plant.model.scene.joints
               if j.drive != "torque" and f"{j.name}.theta" in plant.model.coordinates]
    what = "; ".join(d for _, d in bad)
    hint = ""
    if passive and any(abs(lam) < 1e-6 for lam, _ in bad):
        hint = " — " + ", ".join(f'joint "{j.name}" is not torque-driven (drive = "{j.drive}"): it has no actuator'
                                 for j in passive)
    raise DesignError(f"the plant is not controllable from the torques of {', '.join(joints)}: {what}{hint}")


def design_lqr(plant: LinearPlant, dt: float, torque_limit, limits: Mapping[str, float] | None = None,
               **limit_kw) -> LQRDesign:
    """LQR from Bryson's rule on every torque-driven joint, continuous and sampled.

    The continuous gain (``control.lqr``) gives the margins; the sampled one at ``dt`` (``control.dlqr``) is
    the one the loop runs.

    Parameters
    ----------
    plant : LinearPlant
    dt : float
        Controller sample time, s.
    torque_limit : float or dict
        N m, one for all torque-driven joints or a mapping by joint; also the R weights.
    limits : dict, optional
        Output limits for :func:`bryson_weights` (default :func:`default_limits` with ``limit_kw``:
        ``hub_error``, ``tip_deflection``, ``root_moment``, each a number or a mapping by joint / link).

    Raises
    ------
    DesignError
        No torque-driven joint; a mode on the imaginary axis (rigid-body or undamped flexible) that the
        torques cannot move or the limits do not weigh, named by its frequency.
    """
    cols = _actuated_columns(plant)
    tl = _torque_limits(plant, torque_limit)
    limits = dict(limits) if limits is not None else default_limits(plant, torque_limit, **limit_kw)
    Q, R = bryson_weights(plant, limits, torque_limit)
    _check_stabilizable(plant, plant.B[:, cols])
    unweighted = _detectability(plant, plant.C[[plant.output_row(z) for z in limits]])
    if unweighted:
        raise DesignError(f"the LQR weights (limits on {', '.join(limits)}) do not weigh "
                          + "; ".join(d for _, d in unweighted) + ": give it a limit")
    try:
        # SciPy's Riccati solvers whether or not Slycot is installed (python-control would switch to
        # Slycot's, which warns "may be inaccurate" on the six-axis arm's lightly damped modes)
        # (controllers.riccati: python-control's lqr/sample_system/dlqr with method="scipy", bit for bit)
        K, S, E = riccati.lqr(plant.A, plant.B[:, cols], Q, R)
        plant_d = sample(plant, dt, cols)
        Kd, Sd, Ed = riccati.dlqr(plant_d.A, plant_d.B, Q, R)
    except (ValueError, np.linalg.LinAlgError) as e:
        raise DesignError(f"the LQR Riccati equation has no stabilising solution ({_one_line(e)})") from None
    return LQRDesign(plant, dt, Q, R, np.asarray(K), np.asarray(S), np.asarray(E), np.asarray(Kd), np.asarray(Sd),
                     np.asarray(Ed), plant_d, limits, next(iter(tl.values())), tl, [f"{j}.tau" for j in tl])


def _one_line(e: Exception) -> str:
    return " ".join(str(e).split())


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
        FMU output names, or a named set: every joint's encoder + every link's root strain gauge, or
        the encoders + the tip accelerometers (``tip.sx``, ``tip.sy``, and ``<link>.tip.sx``, ``.sy`` of every
        link that declares one: specific force in the tip frame); see :func:`sensor_set`.
    torque_noise : float
        Standard deviation of the unknown torque disturbance at each joint torque, N m (process noise
        through B).
    elastic_noise : float
        Standard deviation of an unknown generalized force on each elastic coordinate (model error).
    noise : dict, optional
        Sensor name → standard deviation, overriding :data:`SENSOR_NOISE`.

    Raises
    ------
    DesignError
        No sensor; a mode on the imaginary axis that the sensors do not see (named by its frequency).

    Notes
    -----
    The sampled design treats the disturbances as held over each sample like the torque (``G_d`` is the
    zero-order-hold image of ``G``) and the sensor noise as independent from sample to sample; the
    standard deviations are per sample.
    """
    if isinstance(sensors, str):
        sensors = sensor_set(plant, sensors)
    sensors = list(sensors)
    if not sensors:
        raise DesignError("no sensors: the Kalman estimator needs at least one measured output (the scene has no "
                          "joint encoder, strain gauge or accelerometer to read)")
    rows = [plant.output_row(s) for s in sensors]
    C, D = plant.C[rows], plant.D[rows]
    noise = dict(noise or {})
    sigma = {s: float(noise[s]) if s in noise else SENSOR_NOISE[_sensor_kind(s)] for s in sensors}
    RN = np.diag([sigma[s] ** 2 for s in sensors])
    n = plant.nstates
    nq = n // 2
    elastic = [k for k, c in enumerate(plant.model.coordinates) if not c.endswith(".theta")]
    # a torque disturbance at every joint torque; generalized forces on the elastic coordinates, through M⁻¹
    cols_u = torque_inputs(plant)
    Bq = plant.B[nq:]                            # M⁻¹ B_u
    lin_minv = np.linalg.inv(plant.mechanics.M)
    cols = [Bq[:, i] for i in cols_u] + ([lin_minv[:, k] for k in elastic] if elastic_noise > 0 else [])
    G = np.vstack([np.zeros((nq, len(cols))), np.column_stack(cols)])
    QN = np.diag([torque_noise**2] * len(cols_u) + ([elastic_noise**2] * len(elastic) if elastic_noise > 0 else []))
    blind = _detectability(plant, C)
    if blind:
        raise DesignError(f"the sensors ({', '.join(sensors)}) do not see " + "; ".join(d for _, d in blind)
                          + ": no estimator can track it (add an encoder or a strain gauge on that part)")
    try:
        # G QN Gᵀ is passed whole (G = I): python-control insists on exact symmetry
        # (controllers.riccati: python-control's lqe/sample_system/dlqe with method="scipy", bit for bit)
        L, P, E = riccati.lqe(plant.A, np.eye(n), C, _sym(G @ QN @ G.T), RN)
        plant_d = sample(plant, dt)
        # the disturbance is held over each sample like the torque: G_d = ∫₀^dt e^{Aτ} dτ G; per-sample
        # covariances QN and RN (the continuous design above uses them as spectral densities: same ratio)
        _, Gd = riccati.zoh(plant.A, G, dt)
        Ld, Pd, Ed = riccati.dlqe(plant_d.A, np.eye(n), C, _sym(Gd @ QN @ Gd.T), RN)
    except (ValueError, np.linalg.LinAlgError) as e:
        raise DesignError(f"the Kalman Riccati equation has no stabilising solution ({_one_line(e)})") from None
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
        K = np.zeros((1, plant.nstates))
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
    G = _frequency_response(plant, i_th, 0, s)
    g = -1.0 / G
    kd = g.imag / s.imag
    kp = g.real - s.real * kd
    if kp <= 0 or kd <= 0:
        raise FlexlinkError(f"the PD pair at {wn:.3g} rad/s, zeta {zeta} needs non-positive gains "
                            f"(kp {kp:.3g}, kd {kd:.3g}): choose a lower frequency")
    pd = PDDesign(float(kp), float(kd), float(wn), float(zeta), 0.0, np.array([]), joint)
    A, B = plant.A, plant.B
    pd.poles = np.linalg.eigvals(A - B @ pd.gain_matrix(plant))
    i = plant.model.coordinates.index(f"{joint}.theta")
    pd.inertia = float(plant.mechanics.M[i, i])
    return pd


def _frequency_response(plant: LinearPlant, output: int, input: int, s: complex) -> complex:
    """``C (sI − A)⁻¹ B + D`` of one output and input at ``s``, without importing python-control.

    python-control's own evaluation of ``plant.sys[output, input](s)`` when Slycot is absent: one LU solve.
    """
    n = plant.nstates
    xr = np.linalg.solve(np.complex128(s) * np.eye(n) - plant.A, plant.B[:, [input]])
    return complex((plant.C[[output], :] @ xr + plant.D[[output], :][:, [input]])[0, 0])
