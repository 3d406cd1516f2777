"""The README's control job: one example FMU in closed loop, LQR + Kalman against the joint PD baseline.

Build the example FMU, design LQR + Kalman, run a 90° rest-to-rest manoeuvre through fmpy, compare with the
joint PD baseline, print the figures and write the plot.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

from flexlink.errors import FlexlinkError

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "rotating_link.toml"


def run_control_demo(out: str | Path = "out", scene: str | Path = EXAMPLE, target_deg: float = 90.0,
                     duration: float = 1.5, settle: float = 1.5, dt: float = 1e-3) -> dict[str, dict[str, Any]]:
    """Build ``scene``'s FMU in ``out``, run LQR and the joint PD through it, print and plot the figures.

    The controllers are designed on the scene's linearisation; the plot is ``out/<scene>_control.png``.
    Returns the figures by controller (``"lqr"``, ``"pd"``).

    Raises
    ------
    FlexlinkError
        For a scene that has not exactly one torque-driven joint: the joint PD baseline, and so the
        comparison, is single-joint (``flexlink control`` runs the multi-joint LQG).
    """
    from controllers.cosim import FmuLoop
    from controllers.manoeuvre import default_torque_limit, design, predict_manoeuvre, rest_to_rest
    from controllers.plots import plot_manoeuvre
    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant
    from flexlink.scene.loader import load_scene

    sc = load_scene(scene)
    torque_driven = sum(j.drive == "torque" for j in sc.joints)
    if torque_driven != 1:      # before the build: the user does not wait for an FMU the demo cannot use
        raise _not_single_joint(scene, torque_driven)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model = build_model(sc)
    stem = Path(scene).stem
    rep = build_fmu(sc, out / f"{stem}.fmu", model=model)
    print(f"built {rep.fmu} in {sum(rep.seconds.values()):.2f} s")

    target = math.radians(target_deg)
    plant = linear_plant(model)
    limit = default_torque_limit(plant, target - plant.x0[0], duration)
    t0 = time.perf_counter()
    d = design(model, torque_limit=limit, dt=dt)
    if d.pd is None:            # the design's own criterion, checked on the scene before the build too
        raise _not_single_joint(scene, len(d.lqr.inputs))
    wn, zeta = d.lqr.rigid_pair
    print(f"design ({time.perf_counter() - t0:.2f} s): sample time {dt * 1e3:g} ms, torque limit {limit:g} N m "
          f"(1.5 x the rigid quintic's peak); LQR rigid-body pair {wn:.3g} rad/s, zeta {zeta:.2f}; "
          f"Kalman sensors {', '.join(d.kalman.sensors)}; PD kp {d.pd.kp:.4g}, kd {d.pd.kd:.4g}")

    results, preds, figures = [], [], {}
    with FmuLoop(rep.fmu) as loop:
        for controller in ("lqr", "pd"):
            res = rest_to_rest(d, loop, target, duration, settle, controller)
            results.append(res)
            preds.append(predict_manoeuvre(d, target, duration, settle, controller))
            figures[controller] = res.metrics
    from controllers.manoeuvre import stability_report

    print(f"{target_deg:g} deg in {duration:g} s, figures over the {settle:g} s settle window:")
    print(f"  {'':4s} {'final error':>14s} {'residual RMS':>14s} {'peak torque':>12s} {'realtime':>9s} "
          f"{'GM':>8s} {'PM':>7s}")
    for controller, m in figures.items():
        mg = stability_report(d, controller)
        m["margins"] = mg
        print(f"  {controller.upper():4s} {m['final_error_deg']:11.2e} deg {m['residual_vibration_rms_m']:12.3e} m "
              f"{m['peak_torque_nm']:8.3g} N m {m['realtime_factor']:8.1f}x {mg['gain_margin_db']:6.1f}dB "
              f"{mg['phase_margin_deg']:5.1f}°")
    ratio = figures["pd"]["residual_vibration_rms_m"] / max(figures["lqr"]["residual_vibration_rms_m"], 1e-300)
    print(f"  residual vibration: LQR {ratio:.0f} x smaller than PD")
    png = out / f"{stem}_control.png"
    plot_manoeuvre(png, results, d, preds, title=f"{sc.name}: {target_deg:g} deg in {duration:g} s through fmpy "
                                                 f"(solid), linear prediction (dashed)")
    print(f"wrote {png}")
    return figures


def _not_single_joint(scene: str | Path, count: int) -> FlexlinkError:
    return FlexlinkError(f"{scene}: the control demo compares LQR with the joint PD on one torque-driven joint; "
                         f"this scene has {count} (run `flexlink control` on it instead)")
