"""The accelerometer LQG's measurement prediction: linear along the reference against the model's (EKF-style).

    python benchmarks/accel_predictor.py [--targets 60,20] [--duration 1.5] [--settle 1.5] [--limit 60] [--json]

On examples/two_link_payload.toml (tip accelerometer) and on the same arm with an accelerometer declared on
its upper link (at the elbow), the multi-joint LQG with ``--sensors accelerometer`` is run through the plant
FMU in closed loop twice in the same process, on the same reference and feedforward: with
``prediction="linear"`` (ŷ = h(x_ref) + C_k δx̂ + D_k δu, the former law) and ``prediction="model"`` (ŷ =
h(x̂, u_{k−1}), the model's sensor outputs at the estimate; :mod:`controllers.sensor_model`), each as the Python
law and as its controller FMU (``--export-fmu``'s C) stepped beside the plant FMU by fmpy.  Printed per run:
settling time, residual tip vibration (RMS after the manoeuvre), peak torques, and the chatter: the RMS of the
torque increments u_k − u_{k−1} from 20 ms after the manoeuvre's end (after the LQR's kick at the reference's
jump to rest) to the end, and the number of samples after the manoeuvre where a torque is more than 5 N m off
its feedforward.  The runs are deterministic (no noise): one run each is the figure.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "two_link_payload.toml"
PREDICTIONS = ("linear", "model")


def elbow_scene(directory: Path) -> Path:
    """The example with ``sensors = ["accelerometer"]`` on its upper link (as tests/test_control_perlink_accel.py)."""
    head, tail = EXAMPLE.read_text().split('kinematics = "second-order"', 1)
    path = directory / "two_link_elbow_accel.toml"
    path.write_text(head + 'kinematics = "second-order"\nsensors = ["accelerometer"]' + tail)
    return path


def chatter(res, joints: list[str], duration: float, dt: float) -> dict:
    """RMS of the torque increments from 20 ms after the manoeuvre's end; samples > 5 N m off the feedforward."""
    t = res.series["time"]
    after = t >= duration + 0.02 - 1e-12
    ref = res.reference
    out = {}
    for k, j in enumerate(joints):
        u = res.series[f"{j}.tau"]
        inc = np.diff(u)[after[1:]]
        u_ff = ref.u_ff[:, k] if ref.u_ff.ndim == 2 else ref.u_ff
        off = np.abs(u - u_ff[: len(u)] - (u[-1] - u_ff[len(u) - 1]))[t >= duration - 1e-12]
        out[j] = {"increment_rms_nm": float(np.sqrt(np.mean(inc**2))), "samples_off_5nm": int(np.sum(off > 5.0))}
    return out


def run_scene(scene: Path, targets: list[float], duration: float, settle: float, limit: float) -> dict:
    """Both predictions on one scene, through its FMU, in the same process."""
    from controllers.cosim import FmuLoop
    from controllers.export import FmuLaw, export_controller_fmu
    from controllers.manoeuvre import design
    from controllers.multijoint import MimoLQGLaw, inverse_dynamics_reference, plan, run
    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene

    d = design(build_model(load_scene(scene)), torque_limit=limit, dt=1e-3, sensors="accelerometer")
    pl = plan(d.plant, targets)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, duration, settle)
    out = {"sensors": d.kalman.sensors}
    limits = np.full(len(pl.joints), limit)
    with FmuLoop(cached_fmu(scene)) as loop, tempfile.TemporaryDirectory() as tmp:
        for prediction in PREDICTIONS:
            law = MimoLQGLaw(d, list(limits), ref, prediction)
            out[prediction] = figures(run(d, loop, pl, ref, law), pl.joints, duration, d.dt)
            # the controller FMU of the same law (ctrl_fmu.c, with the generated sensor function for "model")
            ctrl = FmuLaw(export_controller_fmu(d, Path(tmp) / f"{prediction}.fmu", limits=limits, reference=ref,
                                                prediction=prediction), builtin=True)
            ctrl.limits = limits                    # what multijoint.run's figures read of a law
            try:
                out[f"{prediction} (controller FMU)"] = figures(run(d, loop, pl, ref, ctrl), pl.joints, duration,
                                                                d.dt)
            finally:
                ctrl.close()
    return out


def figures(res, joints: list[str], duration: float, dt: float) -> dict:
    """The run's figures of the table."""
    m = res.metrics
    return {"settling_time_s": m["settling_time_s"], "residual_vibration_rms_m": m["residual_vibration_rms_m"],
            "peak_torque_nm": {j: m["joints"][j]["peak_torque_nm"] for j in joints},
            "final_error_deg": {j: m["joints"][j]["final_error_deg"] for j in joints},
            "chatter": chatter(res, joints, duration, dt)}


def main(argv: list[str] | None = None) -> int:
    """Run both scenes and print the table (or ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--targets", default="60,20", help="degrees per joint (default 60,20)")
    ap.add_argument("--duration", type=float, default=1.5)
    ap.add_argument("--settle", type=float, default=1.5)
    ap.add_argument("--limit", type=float, default=60.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    targets = [math.radians(float(v)) for v in args.targets.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        scenes = {"tip accelerometer": EXAMPLE, "elbow + tip accelerometers": elbow_scene(Path(tmp))}
        result = {name: run_scene(s, targets, args.duration, args.settle, args.limit) for name, s in scenes.items()}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"two_link_payload, {args.targets} deg in {args.duration} s + {args.settle} s, limit {args.limit} N m")
    print("| sensors | prediction | settling (s) | residual RMS (mm) | peak torques (N m) | torque-increment RMS "
          "after +20 ms (N m) | samples > 5 N m off |")
    print("|---|---|---|---|---|---|---|")
    for name, r in result.items():
        for pred in [k for k in r if k != "sensors"]:
            m = r[pred]
            st = "none" if m["settling_time_s"] is None else f"{m['settling_time_s']:.3f}"
            peaks = ", ".join(f"{v:.1f}" for v in m["peak_torque_nm"].values())
            inc = ", ".join(f"{v['increment_rms_nm']:.3g}" for v in m["chatter"].values())
            off = ", ".join(str(v["samples_off_5nm"]) for v in m["chatter"].values())
            print(f"| {name} | {pred} | {st} | {1e3 * m['residual_vibration_rms_m']:.3f} | {peaks} | {inc} | {off} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
