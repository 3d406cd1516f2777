"""Rest-to-rest manoeuvres of the first joint in closed loop through the FMU (``flexlink control``).

:func:`design` linearises the scene about its start pose and designs, on that one plant, the LQR
(Bryson's rule), the Kalman estimator and the PD baseline (rigid-body pair at the LQR's natural
frequency, ζ = 0.7).  :func:`rest_to_rest` runs one controller through an :class:`~controllers.cosim.
FmuLoop` and measures its figures (docs/control.md, "One joint"); :func:`predict_manoeuvre` gives the linear
closed-loop prediction of the same run.

The two controllers share the manoeuvre (start, target, duration), the sample time and the torque
limit; they differ in what they know of the link:

* ``"lqr"`` — 2-DOF: feedforward and state reference from the flexible model (the minimum-jerk
  rest-to-rest torque, :func:`~controllers.trajectory.min_jerk_reference`), LQR feedback on the Kalman
  estimate (hub encoder + root strain gauge, or tip accelerometer);
* ``"pd"`` — the classical joint servo: quintic joint reference, rigid-body feedforward ``J θ̈``, PD on
  the measured joint angle and rate.

Scope: the linear design holds about one pose, so the manoeuvre must not change the loads (no gravity
torque about the first joint's axis); the first joint must be torque-driven and start at rest.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from controllers.cosim import FmuLoop, LoopResult
from controllers.design import (
    KalmanDesign,
    LQRDesign,
    PDDesign,
    default_limits,
    design_kalman,
    design_lqr,
    design_pd,
)
from controllers.figures import ManoeuvreResult
from controllers.laws import LQGLaw, PDLaw, SampledLaw
from controllers.trajectory import Reference, min_jerk_reference, quintic_reference
from controllers.trajectory import check_times as _check_times
from flexlink.errors import FlexlinkError
from flexlink.run.linearize import LinearPlant, linear_plant

__all__ = [
    "ControlDesign",
    "ManoeuvreResult",
    "default_torque_limit",
    "design",
    "predict_manoeuvre",
    "reference",
    "rest_to_rest",
    "stability_report",
    "static_tip",
]

CONTROLLERS = ("lqr", "pd")


@dataclass
class ControlDesign:
    """The plant and every controller designed on it (python-control's results, :mod:`controllers.riccati`)."""

    plant: LinearPlant
    dt: float
    torque_limit: float
    lqr: LQRDesign
    kalman: KalmanDesign
    pd: PDDesign | None
    _targets: dict = field(default_factory=dict, repr=False)
    _robustness: dict | None = field(default=None, repr=False)

    @property
    def actuated_joints(self) -> list[str]:
        """The torque-driven joints the LQR drives (the rows of ``lqr.K``)."""
        return [u.removesuffix(".tau") for u in self.lqr.inputs]

    def robustness(self) -> dict:
        """Loop-at-a-time margins at each actuator, peak sensitivity and closed-loop poles (computed once).

        Of the continuous LQR state feedback (``"lqr"``) and of the sampled LQG (``"lqg"``):
        :func:`controllers.robustness.robustness`.
        """
        if self._robustness is None:
            from controllers.robustness import robustness

            self._robustness = robustness(self.lqr, self.kalman)
        return self._robustness

    @property
    def joint_pd(self) -> PDDesign:
        """The joint PD, which only a single-joint design has (``pd`` is None with several actuated joints)."""
        if self.pd is None:
            raise FlexlinkError(f"the joint PD is designed for one torque-driven joint; this design has "
                                f"{len(self.lqr.inputs)} ({', '.join(self.actuated_joints)}): controllers.multijoint "
                                "runs it (JointPDLaw)")
        return self.pd

    @property
    def joint(self) -> str:
        """The first joint, the one the single-joint manoeuvre drives."""
        return self.plant.model.scene.joints[0].name

    @property
    def link(self) -> str:
        """The last link, whose tip deflection the manoeuvre's residual vibration is measured on."""
        return self.plant.model.scene.links[-1].name

    @property
    def start_angle(self) -> float:
        """The first joint's angle at the operating point (rad): targets are absolute, references relative."""
        return float(self.plant.x0[self.joint_index])

    @property
    def joint_index(self) -> int:
        """The first joint's angle's index among the model's coordinates (and the plant's states)."""
        return self.plant.model.coordinates.index(f"{self.joint}.theta")

    def law(self, controller: str) -> SampledLaw:
        """A fresh sampled law: ``"lqr"`` (LQR + Kalman) or ``"pd"``; single-joint designs only."""
        if controller in CONTROLLERS and len(self.lqr.inputs) > 1:
            raise FlexlinkError(f"the sampled laws here drive one joint so far; this design has "
                                f"{len(self.lqr.inputs)} actuated joints ({', '.join(self.actuated_joints)}): "
                                "controllers.multijoint runs it (MimoLQGLaw, JointPDLaw, compare)")
        if controller == "lqr":
            return LQGLaw(self.lqr, self.kalman, self.torque_limit)
        if controller == "pd":
            return PDLaw(self.joint_pd, self.plant, self.dt, self.torque_limit)
        raise FlexlinkError(f"--controller: expected one of {CONTROLLERS}, got {controller!r}")


def default_torque_limit(plant: LinearPlant, delta: float, duration: float, factor: float = 1.5) -> float:
    """``factor`` × the peak torque of the rigid quintic (``J · 10/√3 · |Δ|/T²``), rounded up to 0.5 N m."""
    j = plant.model.coordinates.index(plant.model.scene.joints[0].name + ".theta")
    J = plant.mechanics.M[j, j]
    peak = J * 10.0 / math.sqrt(3.0) * abs(delta) / duration**2
    return math.ceil(2.0 * factor * peak) / 2.0


def check_scene(model) -> None:
    """The scenes this module controls: a torque-driven first joint starting at rest."""
    joint = model.scene.joints[0]
    if joint.drive != "torque" or f"{joint.name}.tau" not in [s.name for s in model.inputs]:
        raise FlexlinkError(f'joint "{joint.name}": the control command needs a torque-driven first joint '
                            f'(drive = "torque"), got drive = "{joint.drive}"')
    if joint.initial_rate != 0.0:
        raise FlexlinkError(f'joint "{joint.name}": a rest-to-rest manoeuvre starts at rest; initial_rate = '
                            f"{joint.initial_rate} rad/s")


def design(scene_or_model, *, torque_limit: float | Mapping[str, float], dt: float = 1e-3, sensors="strain",
           hub_error: float | Mapping[str, float] = math.radians(0.5),
           tip_deflection: float | Mapping[str, float] = 5e-3,
           root_moment: float | Mapping[str, float] | None = None,
           torque_noise: float | None = None, elastic_noise: float | None = None, pd_zeta: float = 0.7,
           parameters: Mapping[str, float] | None = None, limits: Mapping[str, float] | None = None) -> ControlDesign:
    """Linearise about the start pose and design LQR, Kalman estimator and PD baseline.

    The LQR and the Kalman estimator act on every torque-driven joint (their encoders and, with
    ``sensors="strain"``, every link's root strain gauge); the PD baseline and the sampled laws that
    :func:`rest_to_rest` runs are single-joint (``pd`` is None with several actuated joints:
    :mod:`controllers.multijoint` runs those).

    Parameters
    ----------
    scene_or_model : path, Scene or SymbolicModel
    torque_limit : float or dict
        N m: the saturation of both controllers and Bryson's torque limit; a mapping gives one per joint.
    dt : float
        Controller sample time, s (also the communication step with the FMU).
    sensors : {"strain", "accelerometer"} or list of str
        Kalman estimator's sensors (:func:`controllers.design.sensor_set`).
    hub_error, tip_deflection, root_moment : float or dict
        Bryson limits: max joint error (rad, default 0.5°, per joint), max tip deflection (m, 5 mm, per
        link), max root bending moment (N m, default 10 % of the torque limit of the joint carrying the link);
        a mapping by joint / link name gives them one by one.
    torque_noise, elastic_noise : float, optional
        Kalman process noise (model uncertainty), N m; default 5 % of the (largest) torque limit each.
    pd_zeta : float
        Damping ratio of the PD's rigid-body pair (its frequency is the LQR's).
    parameters : dict, optional
        Design-point FMU parameters (default: the scene's values).
    limits : dict, optional
        More Bryson limits by FMU output name (SI), laid over those of ``hub_error``, ``tip_deflection`` and
        ``root_moment``: a mode's ``<link>.eta[k]``, or one joint's or link's limit (what ``flexlink control``'s
        ``--joint-error``, ``--mode-limit`` … give, :mod:`controllers.weights`).
    """
    plant = linear_plant(scene_or_model, parameters=parameters)    # all outputs: sensors, Bryson, records
    check_scene(plant.model)
    bryson = default_limits(plant, torque_limit, hub_error=hub_error, tip_deflection=tip_deflection,
                            root_moment=root_moment)
    for name in limits or {}:
        if name not in plant.outputs:
            raise FlexlinkError(f"Bryson limit on {name!r}: not an output of the model")
    lqr = design_lqr(plant, dt, torque_limit, limits={**bryson, **(limits or {})})
    tn = 0.05 * max(lqr.torque_limits.values()) if torque_noise is None else torque_noise
    en = tn if elastic_noise is None else elastic_noise
    kalman = design_kalman(plant, dt, sensors, torque_noise=tn, elastic_noise=en)
    wn, _ = lqr.rigid_pair
    pd = design_pd(plant, wn, pd_zeta) if len(lqr.inputs) == 1 else None
    return ControlDesign(plant, float(dt), lqr.torque_limit, lqr, kalman, pd)


def static_tip(d: ControlDesign, target: float) -> float:
    """The tip's static deflection ``<link>.tip.v`` at rest at the target, the zero of the residual vibration.

    It also checks that the manoeuvre does not change the loads (the plant at the target is the plant at the
    start), which the linear design assumes.  Cached per target.
    """
    if target in d._targets:
        return d._targets[target]
    model = d.plant.model
    other = linear_plant(model, angle=target, parameters=_params(d), outputs=[f"{d.link}.tip.v"])
    scale = max(1.0, float(np.max(np.abs(d.plant.A))))
    same_u = np.allclose(other.u0, d.plant.u0, atol=1e-9 * max(1.0, d.torque_limit))
    if not same_u or not np.allclose(other.A, d.plant.A, atol=1e-9 * scale):
        raise FlexlinkError("the first joint's loads change between the start and the target (gravity about its "
                            "axis?): this controller is designed about one pose and cannot move between two")
    d._targets[target] = float(other.y0[0])
    return d._targets[target]


def _params(d: ControlDesign) -> dict[str, float]:
    return {par.name: float(v) for par, v in zip(d.plant.model.parameters, d.plant.op.p, strict=True)}


def reference(d: ControlDesign, controller: str, target: float, duration: float, settle: float) -> Reference:
    """The reference each controller tracks (deviations from the start pose), over duration + settle."""
    delta = target - d.start_angle
    total = duration + settle
    if controller == "lqr":
        return min_jerk_reference(d.lqr.plant_d, d.joint_index, delta, duration, total)
    if controller == "pd":
        return quintic_reference(d.plant, delta, duration, total, d.dt, d.joint_pd.inertia)
    raise FlexlinkError(f"--controller: expected one of {CONTROLLERS}, got {controller!r}")


def _metrics(d: ControlDesign, series: Mapping[str, np.ndarray], target: float, duration: float, settle: float,
             controller: str, wall_time: float | None) -> dict:
    from controllers.figures import manoeuvre_figures

    return manoeuvre_figures(series, joint=d.joint, link=d.link, torque_input=d.plant.inputs[0],
                             torque_limit=d.torque_limit, static_tip=static_tip(d, target), target=target,
                             duration=duration, settle=settle, sample_time=d.dt, controller=controller,
                             wall_time=wall_time)


def rest_to_rest(d: ControlDesign, loop: FmuLoop | str | os.PathLike, target: float, duration: float,
                 settle: float = 1.5, controller: str = "lqr", parameters: Mapping[str, float] | None = None,
                 noise: Mapping[str, float] | bool | None = None, seed: int = 0) -> ManoeuvreResult:
    """Rest-to-rest manoeuvre of the first joint to ``target`` (rad, absolute) through the FMU.

    Parameters
    ----------
    d : ControlDesign
    loop : FmuLoop or path of the FMU
        Reusing one :class:`FmuLoop` for several runs resets the same instance (``fmi2Reset``).
    target : float
        Final angle of the first joint, rad.
    duration, settle : float
        Manoeuvre time and the window after it over which the residual vibration is measured, s; the final
        error is taken at the end of the window.
    controller : {"lqr", "pd"}
    parameters : dict, optional
        FMU parameters for this run (e.g. ``{"arm.payload.mass": 0.65}``), without re-export.
    noise : dict or True, optional
        Sensor noise added to what the law reads; ``True`` uses the Kalman design's sensor levels.

    Returns
    -------
    ManoeuvreResult
        ``metrics``: ``final_error_deg``, ``residual_vibration_rms_m`` (RMS over the settle window of
        ``<last link>.tip.v`` minus its static value at the final pose), ``peak_torque_nm``,
        ``realtime_factor`` (simulated s per wall-clock s of the loop), ``max_tip_deflection_m``,
        ``saturated_fraction``.
    """
    _check_times(duration, settle, d.dt)
    static_tip(d, target)
    law = d.law(controller)
    ref = reference(d, controller, target, duration, settle)
    if noise is True:
        from controllers.design import SENSOR_NOISE, sensor_kind

        noise = {s: d.kalman.noise.get(s, SENSOR_NOISE[sensor_kind(s)]) for s in law.sensors}
    own = not isinstance(loop, FmuLoop)
    fl = loop if isinstance(loop, FmuLoop) else FmuLoop(loop, record=[f"{d.joint}.theta", f"{d.link}.tip.v"])
    for name in (f"{d.joint}.theta", f"{d.link}.tip.v"):
        if name not in fl.record:
            fl.record.append(name)
    try:
        law.follow(ref)
        res: LoopResult = fl.run(law, ref, parameters=parameters, noise=noise or None, seed=seed)
    finally:
        if own:
            fl.close()
    series = dict(res.series)
    series[f"{d.joint}.theta_ref"] = ref.theta + d.start_angle
    metrics = _metrics(d, series, target, duration, settle, controller, res.wall_time)
    return ManoeuvreResult(controller, target, duration, settle, series, ref, metrics, dict(parameters or {}))


def predict_manoeuvre(d: ControlDesign, target: float, duration: float, settle: float = 1.5,
                      controller: str = "lqr", plant: LinearPlant | None = None,
                      outputs: list[str] | None = None) -> dict:
    """The linear closed-loop prediction of :func:`rest_to_rest`, to compare the FMU's run with.

    It is python-control's ``forced_response`` without saturation; ``plant`` may differ from the design plant
    (e.g. another payload).
    """
    from controllers.closedloop import predict  # python-control: only where its systems are needed (issue 22)

    _check_times(duration, settle, d.dt)
    law = d.law(controller)
    ref = reference(d, controller, target, duration, settle)
    outputs = outputs or [f"{d.joint}.theta", f"{d.link}.tip.v"]
    return predict(plant or d.plant, law, ref, outputs)


def stability_report(d: ControlDesign, controller: str, parameters: Mapping[str, float] | None = None) -> dict:
    """Margins of the loop broken at the torque input and closed-loop stability.

    The plant is linearised at ``parameters`` while the controller stays the nominal one: how far a design
    holds when the arm differs from the one it was designed on.
    """
    from controllers.closedloop import margins  # python-control: only where its systems are needed

    plant = d.plant if not parameters else linear_plant(d.plant.model, parameters={**_params(d), **parameters})
    return margins(plant, d.law(controller))
