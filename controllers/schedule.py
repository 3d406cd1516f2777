"""Gain scheduling over the planned path: the MIMO LQG designed at several poses along the manoeuvre.

A two-link arm's linearisation changes with the elbow angle (the forearm's inertia seen from the shoulder,
the coupling of the two joints): an LQG designed about the start pose can be unstable about a pose the
path reaches (on ``examples/two_link_payload.toml``, designed at elbow −20°: from about 35° on).  The
schedule here:

* **Design points.** ``points`` poses along the path, equally spaced in the path parameter σ ∈ [0, 1]
  (every joint at ``start + σ (target − start)``: the quintic moves all joints in step, so σ is the
  fraction of each joint's travel).  At each, the arm is linearised at rest at that pose
  (:func:`model_at_pose`: the model's start values moved there, the static deflection and holding torques
  of :func:`flexlink.run.linearize.linear_plant`) and the *same* design is made on it
  (:func:`redesign`: the same Bryson limits and torque limits, the same sensors and noise levels) — the
  frozen-pose linearisations; the velocity terms of the moving arm are left to the feedback.
* **Rule.** At sample k the law takes the reference's σ(t_k) (the quintic's s(t/T), 1 after the
  manoeuvre) and interpolates every matrix it uses — the LQR gain K_d, the Kalman filter gain M, the
  sampled plant A_d, B_d and the sensor rows C — linearly between the two neighbouring design points.
  The schedule is a known function of time: no measured signal enters it.
* **Observer consistency.** The estimator's state is the deviation from the reference, in the same
  coordinates (the model's states) at every pose, and the reference, its feedforward and the measurement
  expected on it (``y₀ + C x_ref``, outputs linear in the state) do not depend on the design point; so
  switching matrices moves no state and needs no reset: only the prediction ``A_d, B_d`` and the gains
  change under the estimate.

:func:`frozen_radius` is the check: the spectral radius of the sampled loop of the scheduled (or the fixed)
LQG with the plant linearised at a pose of the path.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import control as ct
import numpy as np

from controllers.design import DesignError, design_kalman, design_lqr, torque_inputs
from controllers.multijoint import MimoLQGLaw, Plan, reference_step
from controllers.robustness import compensator, loop_at_a_time, lqg_plant, robustness_figures
from controllers.trajectory import Reference
from flexlink.run.linearize import linear_plant

__all__ = ["Schedule", "ScheduledLQGLaw", "along_path", "design_schedule", "frozen_radius", "interpolate",
           "model_at_pose", "path_fraction", "redesign", "worst_along_path"]


def model_at_pose(model, pose: Mapping[str, float]):
    """The model with its joints' start angles at ``pose`` (joint name → rad), without building it again.

    What a scene with those ``initial_angle`` values builds; :func:`linear_plant` linearises it there.
    """
    names = {f"{j.name}.theta": j.name for j in model.scene.joints}
    unknown = set(pose) - set(names.values())
    if unknown:
        raise DesignError(f"pose: {sorted(unknown)} are not joints of the scene")
    values = []
    for s in model.start_values:
        joint = names.get(model.coordinates[s.coordinate])
        if not s.rate and joint is not None and joint in pose:
            s = dataclasses.replace(s, value=float(pose[joint]))
        values.append(s)
    return dataclasses.replace(model, start_values=values)


def redesign(d, plant):
    """The design ``d`` made again on another linearisation ``plant`` of the same model.

    The same Bryson limits and torque limits (LQR), the same sensors, sensor noise and process noise
    (Kalman), the same sample time, so that the schedule's points differ by the pose alone.  A
    :class:`controllers.manoeuvre.ControlDesign` (no PD).
    """
    from controllers.manoeuvre import ControlDesign

    lqr = design_lqr(plant, d.dt, d.lqr.torque_limits, limits=d.lqr.limits)
    m = len(d.lqr.inputs)
    qn = np.diag(d.kalman.QN)
    kalman = design_kalman(plant, d.dt, d.kalman.sensors, torque_noise=float(np.sqrt(qn[0])),
                           elastic_noise=float(np.sqrt(qn[m])) if len(qn) > m else 0.0, noise=d.kalman.noise)
    return ControlDesign(plant, d.dt, lqr.torque_limit, lqr, kalman, None)


@dataclass
class Schedule:
    """Design points along the path, between which the law's matrices are interpolated.

    ``sigma`` (path parameter, ascending from 0 to 1), the pose of each (joint → rad) and its design;
    ``designs[0]`` is the design about the start pose.
    """

    sigma: np.ndarray
    poses: list[dict]
    designs: list

    def matrices(self, s: float) -> tuple[np.ndarray, ...]:
        """(M, C, K_d, A_d, B_d) at path parameter ``s``: linear between the neighbouring design points."""
        return interpolate(self.sigma, [_matrices(d) for d in self.designs], s)


def interpolate(sigma: np.ndarray, tables: Sequence[tuple[np.ndarray, ...]], s: float) -> tuple[np.ndarray, ...]:
    """The matrices of ``tables`` (one tuple per design point at ``sigma``) at ``s``: linear between neighbours.

    The schedule's rule (module docstring), shared by the scheduled laws with and without integral action.
    """
    i = int(np.clip(np.searchsorted(sigma, s, side="right") - 1, 0, len(sigma) - 2))
    lam = float(np.clip((s - sigma[i]) / (sigma[i + 1] - sigma[i]), 0.0, 1.0))
    return tuple((1 - lam) * np.asarray(a) + lam * np.asarray(b)
                 for a, b in zip(tables[i], tables[i + 1], strict=True))


def _matrices(d) -> tuple[np.ndarray, ...]:
    return (d.kalman.Md, d.kalman.C, d.lqr.Kd, np.asarray(d.lqr.plant_d.A), np.asarray(d.lqr.plant_d.B))


def _pose(pl: Plan, s: float) -> dict:
    return {j: float(a + s * (b - a)) for j, a, b in zip(pl.joints, pl.angle_start, pl.target, strict=True)}


def plant_at(d, pose: Mapping[str, float]):
    """The plant of design ``d`` linearised at rest at ``pose`` (same parameters, same outputs)."""
    params = {par.name: float(v) for par, v in zip(d.plant.model.parameters, d.plant.op.p, strict=True)}
    return linear_plant(model_at_pose(d.plant.model, pose), parameters=params)


def design_schedule(d, pl: Plan, points: int) -> Schedule:
    """A schedule of ``points`` ≥ 2 design points equally spaced in the path parameter.

    ``d`` (the design about the start pose) is the first, :func:`redesign` on :func:`plant_at` the others.
    """
    if not (isinstance(points, int) and points >= 2):
        raise DesignError(f"--schedule: at least 2 design points along the path (start and target), got {points}")
    sigma = np.linspace(0.0, 1.0, points)
    poses = [_pose(pl, s) for s in sigma]
    designs = [d] + [redesign(d, plant_at(d, pose)) for pose in poses[1:]]
    return Schedule(sigma, poses, designs)


def path_fraction(reference: Reference) -> np.ndarray:
    """σ at every sample of ``reference``: the quintic's ``s = τ³(10 − 15τ + 6τ²)``, τ = t/T, 1 after T."""
    tau = np.clip(reference.time / reference.duration, 0.0, 1.0)
    return tau**3 * (10 - 15 * tau + 6 * tau**2)


class ScheduledLQGLaw(MimoLQGLaw):
    """The multi-joint LQG with the matrices of a :class:`Schedule` at the reference's path parameter.

    A :class:`controllers.multijoint.MimoLQGLaw` (module docstring); its operating point (u₀, y₀) and
    reference are the start design's, as the fixed law's, so that the two differ by the scheduling alone.
    """

    kind = "scheduled"

    def __init__(self, schedule: Schedule, limits: Sequence[float], reference: Reference, prediction: str = "model"):
        super().__init__(schedule.designs[0], limits, reference, prediction)
        sigma = path_fraction(reference)
        self._at = [schedule.matrices(float(s)) for s in sigma]
        _, _, _, Ad, Bd = self._at[-1]                 # after the manoeuvre: the target's design
        self.W = reference_step(reference, Ad, Bd)

    def matrices(self, k: int) -> tuple[np.ndarray, ...]:
        """(M, C, K_d, A_d, B_d) at sample ``k``, interpolated once per sample at construction."""
        return self._at[k]


def frozen_radius(law_matrices: tuple[np.ndarray, ...], plant_design) -> float:
    """Spectral radius of a sampled LQG in loop with a frozen-pose plant: < 1 is a loop that holds that pose.

    The LQG has the matrices ``(M, C, K_d, A_d, B_d)``; the plant is that of ``plant_design`` (its own
    sampled linearisation, :func:`controllers.robustness.lqg_plant`).
    """
    M, C, K, Ad, Bd = law_matrices
    p = plant_design
    D = p.kalman.D[:, torque_inputs(p.lqr.plant)]
    Kc = compensator(Ad, Bd, K, M, C, D, p.dt)
    cl = ct.feedback(ct.series(lqg_plant(p.lqr, p.kalman), Kc), np.eye(len(p.lqr.inputs)), sign=1)
    return float(np.max(np.abs(cl.poles())))


def compare_schedule(d, schedule: Schedule, loop, pl: Plan, ref: Reference, integral=None, **kw) -> dict:
    """The scheduled LQG and the fixed one (``d``), each through the FMU, on the same manoeuvre.

    The same reference, feedforward and torque limits (:func:`controllers.multijoint.run`; ``kw`` its
    keywords).  With ``integral`` (a :class:`controllers.integral.ScheduledIntegral` of ``schedule``) both
    laws have integral action: the scheduled one :class:`controllers.integral.ScheduledIntegralLQGLaw`, the
    fixed one :class:`controllers.integral.IntegralLQGLaw` of the start design.  The fixed run comes last:
    where it leaves the beam model's validity (the FMU refuses the step) its entry is the message instead of
    a result.  Returns ``{"scheduled": result, "fixed": result or str}``.
    """
    from controllers.cosim import FmuLoopError
    from controllers.multijoint import run

    limits = [d.lqr.torque_limits[j] for j in pl.joints]
    scheduled: MimoLQGLaw
    if integral is None:
        scheduled, fixed = ScheduledLQGLaw(schedule, limits, ref), MimoLQGLaw(d, limits, ref)
    else:
        scheduled, fixed = integral.laws(limits, ref)
    out = {"scheduled": run(d, loop, pl, ref, scheduled, **kw)}
    try:
        out["fixed"] = run(d, loop, pl, ref, fixed, **kw)
    except FmuLoopError as e:
        if "validity" not in str(e):
            raise
        out["fixed"] = str(e)
    return out


#: Worst case of each margin along a path: the smallest (gain, phase, disk margins; the gain reduction
#: tolerated, a negative dB figure, is worst where it is closest to 0 dB) or the largest (peak sensitivity).
_WORST = {"gain_margin_db": min, "gain_reduction_margin_db": max, "phase_margin_deg": min, "disk_margin": min,
          "peak_sensitivity": max}


def along_path(d, schedule, pl, samples: Sequence[float], n_points: int = 4000,
               integral=None) -> dict[str, dict[str, Any]]:
    """The sampled LQG's margins along a planned path, for the scheduled law and the fixed one.

    At each path parameter σ in ``samples`` the arm is linearised at rest at that pose (the schedule's
    frozen-pose plant, :func:`plant_at`) and each law is frozen there: the scheduled one
    with the schedule's matrices interpolated at σ (:meth:`Schedule.matrices`, what
    :class:`ScheduledLQGLaw` uses at that point of the path), the fixed one with the start
    design's.  :func:`controllers.robustness.loop_at_a_time` of each loop gives the margins at each actuator,
    the simultaneous disk margin, the peak sensitivity and the poles, whose largest modulus is the frozen-pose
    spectral radius; the worst of each over the samples, and where, is :func:`worst_along_path`.  Frozen
    poses: the moving arm's velocity terms are not in these loops (as in the schedule's design).

    With ``integral`` (a :class:`controllers.integral.ScheduledIntegral` of ``schedule``) both laws carry
    integral action (:func:`controllers.integral.sampled_integral_compensator`): the scheduled one with the
    augmented gains interpolated at σ, the fixed one with the start design's.

    With sensors that read the torques (accelerometers) the run's estimator is the time-varying Kalman filter
    along the reference (:func:`controllers.multijoint.estimator_along`), not these frozen-pose designs: each
    law's entry then says so in ``note``.

    Returns ``{"scheduled": {"points": [...], "worst": {...}, "note": str | None}, "fixed": {...}}``, JSON-ready
    values (:func:`controllers.robustness.robustness_figures` per point, the poles left out).
    """
    out: dict[str, list] = {"scheduled": [], "fixed": []}
    for s in samples:
        pose = _pose(pl, float(s))
        here = redesign(d, plant_at(d, pose))
        P = lqg_plant(here.lqr, here.kalman)
        D = here.kalman.D[:, torque_inputs(here.lqr.plant)]
        where = {"sigma": float(s), "pose_deg": {j: math.degrees(v) for j, v in pose.items()}}
        for name, Kc in _frozen_compensators(d, schedule, integral, float(s), D):
            loop = loop_at_a_time(P, Kc, d.lqr.inputs, n_points)
            fig = robustness_figures({"loop": loop})["loop"]
            del fig["closed_loop_poles"]
            out[name].append({**where, "spectral_radius": float(np.max(np.abs(loop["closed_loop_poles"]))), **fig})
    note = None
    if np.any(d.kalman.D[:, torque_inputs(d.lqr.plant)] != 0):
        note = ("the sensors read the torques (accelerometers): the run's estimator follows the reference, and "
                "these loops, with the designs' stationary estimators, are not the run's")
    return {name: {"points": pts, "worst": worst_along_path(pts), "note": note} for name, pts in out.items()}


def _frozen_compensators(d, schedule, integral, s: float, D) -> list[tuple[str, ct.StateSpace]]:
    """The scheduled and the fixed law frozen at path parameter ``s``, as compensators (:func:`along_path`)."""
    if integral is None:
        return [(name, compensator(Ad, Bd, K, M, C, D, d.dt))
                for name, (M, C, K, Ad, Bd) in (("scheduled", schedule.matrices(s)), ("fixed", _matrices(d)))]
    return integral.frozen_compensators(s, d.dt)


def worst_along_path(points: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The worst of each margin over the points of :func:`along_path`, with the σ and pose where it is.

    ``stable`` is whether every frozen loop is; ``unstable_sigma`` lists where one is not.  The margins are
    the worst over the stable points (an unstable loop has none: no perturbation is needed); an unbounded
    margin (``None``) is never the worst.  Each entry is ``{"value", "sigma", "pose_deg"}``.
    """
    stable = [p for p in points if p["stable"]]

    def worst(values, pick) -> dict[str, Any] | None:
        found = [(v, p) for v, p in values if v is not None]
        if not found:
            return None
        v, p = pick(found, key=lambda vp: vp[0])
        return {"value": v, "sigma": p["sigma"], "pose_deg": p["pose_deg"]}

    actuators = []
    for i, a in enumerate(points[0]["actuators"]):
        actuators.append({"input": a["input"], **{k: worst([(p["actuators"][i][k], p) for p in stable], pick)
                                                  for k, pick in _WORST.items()}})
    return {"stable": len(stable) == len(points),
            "unstable_sigma": [p["sigma"] for p in points if not p["stable"]],
            "spectral_radius": worst([(p["spectral_radius"], p) for p in points], max),
            "peak_sensitivity": worst([(p["peak_sensitivity"], p) for p in stable], max),
            "multiloop_disk_margin": worst([(p["multiloop"]["disk_margin"], p) for p in stable], min),
            "actuators": actuators}
