"""Monte Carlo robustness of the multi-joint LQG or joint PD, for ``flexlink sweep``.

The sweep runs on a scene with several torque-driven joints.

Every case drives the FMU with its parameters drawn (payload mass, link stiffness, ...) and the controller,
the reference and the feedforward designed once on the scene's nominal values: the sweep tests the fixed
design against the varied plant.  ``--controller lqr`` runs the MIMO LQG, ``--controller pd`` the joint PD
of ``flexlink control``'s comparison (:class:`controllers.multijoint.JointPDLaw`), both saturated at the
design's torque limits (the sweep has no LQG run whose peak torques would bound the PD).  A case is two runs
on one FMU instance:

* **hold** — the start pose held after a small torque pulse on every joint (0.1 N m for 5 samples), for
  1.5 s: ``hold_decay_ratio`` is the largest, over the law's sensors' deviations from the operating point,
  of the RMS over the last third of the run to the RMS over its first third after the pulse, and ``stable``
  is its verdict (1 when < 1).  It is the closed loop that :func:`linear_verdict` builds from the model: a
  fixed-pose verdict, which the test checks sample by sample.
* **manoeuvre** — ``flexlink control SCENE --target A,B,...``'s run, its figures those of
  :func:`controllers.multijoint.metrics` for the worst joint or link, against the nominal plan.  A plant that
  is stable at the start pose may still not survive the manoeuvre (the arm's dynamics change along the
  path: docs/control.md): ``completed`` is 0 when the run left the model's validity (the FMU refused the
  step), and then its figures are empty.
"""

from __future__ import annotations

import math

import numpy as np

from flexlink.errors import FlexlinkError

__all__ = ["MULTIJOINT_METRICS", "linear_verdict", "stability_summary"]

MULTIJOINT_METRICS = (
    "stable",                     # hold at the start pose: 1 when the pulse response dies out
    "hold_decay_ratio",           # its RMS over the last third / over the first third (largest over sensors)
    "completed",                  # 1: the manoeuvre stayed within the model's validity
    "settled",                    # 1: settling_time_s is within the run
    "settling_time_s",            # every joint within settle_band_deg, every tip within settle_band_m, to the end
    "residual_vibration_rms_m",   # largest over the links: RMS of tip.v minus its nominal static value
    "final_error_deg",            # largest |joint angle − target| at the end
    "peak_torque_nm",             # largest |torque| over the joints
    "max_tip_deflection_m",       # largest over the links
    "saturated_fraction",         # largest over the joints
    "realtime_factor",
)


def torque_joints(sc) -> list[str]:
    return [j.name for j in sc.joints if j.drive == "torque"]


def settings(sc, controller: str, target_deg, duration: float, settle: float, sample_time: float,
             torque_limit, sensors: str) -> dict:
    """The shared settings of a multi-joint closed-loop sweep (checked here, before any FMU is run)."""
    from controllers.trajectory import check_times

    joints = torque_joints(sc)
    targets = [float(v) for v in np.atleast_1d(target_deg)]
    if len(targets) != len(joints):
        raise FlexlinkError(f"--target: one angle per torque-driven joint ({', '.join(joints)}), got {len(targets)}")
    if controller not in ("lqr", "pd"):
        raise FlexlinkError(f"--controller: expected lqr (the MIMO LQG) or pd (the joint PD), got {controller!r}")
    check_times(duration, settle, sample_time)
    if isinstance(torque_limit, float | int) and not (math.isfinite(torque_limit) and torque_limit > 0):
        raise FlexlinkError(f"--torque-limit must be positive, got {torque_limit}")
    return {"multijoint": True, "controller": controller, "targets": [math.radians(v) for v in targets],
            "target_deg": targets, "duration": float(duration), "torque_limit": torque_limit, "sensors": sensors,
            "settle_band_deg": 0.1, "settle_band_m": 1e-3,
            "record": [f"{j}.theta" for j in joints] + [f"{lk.name}.tip.v" for lk in sc.links]}


def design(model, s: dict, sample_time: float):
    """The nominal design, checked for the multi-joint run: every case runs this one law.

    Its torque limit is ``--torque-limit`` (one for all, one per joint or by name) or the multi-joint default
    of ``flexlink control``; its Bryson limits those of the weight options (``s["weights"]``,
    :func:`controllers.weights.bryson_limits`) over the defaults.
    """
    from controllers.manoeuvre import design as lqg_design
    from controllers.multijoint import check_multijoint, default_torque_limit, plan
    from controllers.weights import bryson_limits, torque_limits
    from flexlink.run.linearize import linear_plant

    plant = linear_plant(model)
    limit = torque_limits(plant, s["torque_limit"])
    if limit is None:
        limit = default_torque_limit(plant, s["targets"], s["duration"], sample_time)
    d = lqg_design(model, torque_limit=limit, dt=sample_time, sensors=s["sensors"],
                   limits=bryson_limits(model, s.get("weights")))
    check_multijoint(d)
    plan(d.plant, s["targets"])
    return d


HOLD_S, PULSE_NM, PULSE_SAMPLES = 1.5, 0.1, 5


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


def law(d, controller: str, reference):
    """The sweep's law: the MIMO LQG or the joint PD, saturated at the design's torque limits."""
    from controllers.multijoint import JointPDLaw, MimoLQGLaw

    limits = [d.lqr.torque_limits[j] for j in d.actuated_joints]
    return MimoLQGLaw(d, limits, reference) if controller == "lqr" else JointPDLaw(d, limits)


def hold_decay_ratio(job, params: dict) -> float:
    """The hold run's decay ratio (module docstring): the nominal law at the start pose after a torque pulse.

    inf when the response grows out of the model's validity (the FMU refuses the step).
    """
    from controllers.cosim import FmuLoopError
    from controllers.trajectory import Reference

    d = job.design
    n = int(round(HOLD_S / d.dt))
    u_ff = np.zeros((n + 1, len(d.lqr.inputs)))
    u_ff[:PULSE_SAMPLES] = PULSE_NM
    ref = Reference("pulse", d.dt, 0.0, np.arange(n + 1) * d.dt, np.zeros((n + 1, d.plant.sys.nstates)), u_ff, 0)
    held = law(d, job.spec.settings.get("controller", "lqr"), ref)
    try:
        res = job.instance().run(held, ref, parameters=params)
    except FmuLoopError as e:
        job.drop_instance()                   # an instance that reported an error is not reused
        if "validity" not in str(e):
            raise
        return math.inf
    third = (n - PULSE_SAMPLES) // 3
    ratios = []
    for s in held.sensors:
        dev = res[s][PULSE_SAMPLES:] - d.plant.y0[d.plant.output_row(s)]
        ratios.append(_rms(dev[-third:]) / max(_rms(dev[:third]), 1e-300))
    return max(ratios)


def case(job, params: dict) -> tuple[dict, dict]:
    """One Monte Carlo case on a sweep worker (:mod:`controllers.sweep`).

    The hold and the manoeuvre of the nominal LQG through the FMU with ``params`` set.  The plan and the
    reference (seconds of CasADi) are made once per worker.
    """
    from controllers.cosim import FmuLoopError
    from controllers.multijoint import inverse_dynamics_reference, plan, run

    s, d = job.spec.settings, job.design
    if getattr(job, "plan", None) is None:
        job.plan = plan(d.plant, s["targets"])
        job.reference = inverse_dynamics_reference(d.plant, job.plan, d.dt, s["duration"], s["settle"])
    pl, ref = job.plan, job.reference
    ratio = hold_decay_ratio(job, params)
    out = {"stable": float(ratio < 1.0), "hold_decay_ratio": ratio}
    try:
        res = run(d, job.instance(), pl, ref, law(d, s["controller"], ref), parameters=params,
                  band_deg=s["settle_band_deg"], band_m=s["settle_band_m"])
    except FmuLoopError as e:
        job.drop_instance()                   # an instance that reported an error is not reused
        if "validity" not in str(e):
            raise
        return {**out, "completed": 0.0, "settled": 0.0}, {"time": ref.time}
    m, joints, links = res.metrics, res.metrics["joints"].values(), res.metrics["links"].values()
    out.update({
        "completed": 1.0,
        "settled": float(m["settling_time_s"] is not None),
        "settling_time_s": math.nan if m["settling_time_s"] is None else m["settling_time_s"],
        "residual_vibration_rms_m": m["residual_vibration_rms_m"],
        "final_error_deg": max(abs(v["final_error_deg"]) for v in joints),
        "peak_torque_nm": max(v["peak_torque_nm"] for v in joints),
        "max_tip_deflection_m": max(v["max_tip_deflection_m"] for v in links),
        "saturated_fraction": max(v["saturated_fraction"] for v in joints),
        "realtime_factor": m["realtime_factor"],
    })
    if not all(math.isfinite(v) for k, v in out.items() if k not in ("settling_time_s", "hold_decay_ratio")):
        raise FlexlinkError("the run diverged (non-finite outputs)")
    return out, res.series


def stability_summary(df) -> str:
    """The sweep's summary in words: how many cases were stable, completed and settled, and how well.

    The fractions stable (hold verdict), completed and settled (a failed case counts as none of them), and
    the distributions of the settling time and the residual vibration over the settled cases.
    """
    n = len(df)
    ok = df[~df["failed"]]

    def frac(col):
        k = int((ok[col] == 1.0).sum()) if col in ok else 0
        return f"{k} of {n} ({100 * k / n:.1f} %)"

    lines = [f"stable at the start pose (hold): {frac('stable')}; manoeuvre completed: {frac('completed')}, "
             f"settled: {frac('settled')}"]
    settled = ok[ok["settled"] == 1.0] if "settled" in ok else ok.iloc[0:0]
    for col, unit, scale in (("settling_time_s", "s", 1.0), ("residual_vibration_rms_m", "mm", 1e3)):
        v = settled[col].dropna().to_numpy() * scale if col in settled else np.array([])
        if len(v):
            p = np.percentile(v, [5, 50, 95])
            lines.append(f"  {col} over the settled cases: 5 % {p[0]:.4g}, median {p[1]:.4g}, 95 % {p[2]:.4g}, "
                         f"max {v.max():.4g} {unit}")
    return "\n".join(lines)


def linear_verdict(d, params: dict, controller: str = "lqr") -> float:
    """The linear stability verdict of one case: the closed loop's spectral radius (< 1 is stable).

    The nominal sampled law — the LQG (:func:`controllers.robustness.lqg_compensator`) or the joint PD (its
    static gain on the encoders and rates) — in loop with the plant linearised at the start pose with
    ``params`` and sampled (python-control).
    """
    import control as ct

    from controllers.closedloop import sampled_plant
    from controllers.design import torque_inputs
    from controllers.multijoint import JointPDLaw
    from controllers.robustness import lqg_compensator
    from flexlink.run.linearize import linear_plant

    if controller == "lqr":
        sensors, comp = list(d.kalman.sensors), lqg_compensator(d.lqr, d.kalman)
    else:
        pd = JointPDLaw(d, [d.lqr.torque_limits[j] for j in d.actuated_joints])
        sensors, comp = pd.sensors, ct.ss([], [], [], -pd.G, d.dt)
    p = linear_plant(d.plant.model, parameters=params, outputs=sensors)
    P = sampled_plant(p, d.dt, sensors)[:, torque_inputs(p)]
    return float(np.max(np.abs(ct.feedback(P, comp, sign=1).poles())))
