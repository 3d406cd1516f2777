"""``flexlink control`` and ``flexlink linearize`` (SCENE.md "Commands").

``flexlink.cli`` wires them in with :func:`add_control_parsers`; each ``cmd_*`` returns the exit status and
raises :class:`flexlink.errors.FlexlinkError` on bad input (the caller prints it and exits 2).
"""

from __future__ import annotations

import json
import math

import numpy as np

from flexlink.errors import FlexlinkError

__all__ = ["add_control_parsers", "cmd_control", "cmd_linearize"]


def _finite(text: str) -> float:
    import argparse

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def add_commands(subparsers) -> None:
    """The ``flexlink.commands`` entry point (pyproject.toml): this package's sub-commands of ``flexlink``."""
    from controllers.sweep import add_sweep_parser

    p = subparsers.add_parser("demo", help="the README's main job: build an example FMU, run it in closed loop, "
                                           "plot")
    p.add_argument("--out", default="out", help="output folder")
    p.add_argument("--open-loop", action="store_true", help="the open-loop bang-bang run against the reference")
    p.set_defaults(func=_cmd_demo)
    add_control_parsers(subparsers)
    add_sweep_parser(subparsers)


def _cmd_demo(args) -> int:
    if args.open_loop:
        from flexlink.tools.demo import run_demo

        return run_demo(args.out)
    from controllers.demo import run_control_demo

    run_control_demo(args.out)
    return 0


def add_control_parsers(subparsers) -> None:
    """Add the ``control`` and ``linearize`` sub-commands to ``flexlink``'s sub-parsers."""
    p = subparsers.add_parser("linearize", help="state-space matrices A, B, C, D with named signals")
    p.add_argument("scene")
    p.add_argument("--rate", type=_finite, default=0.0, help="steady rate of the first joint, rad/s")
    p.add_argument("--angle", type=_finite, metavar="DEG", help="angle of the first joint (default: initial angle)")
    p.add_argument("--output", action="append", metavar="NAME", dest="outputs",
                   help="keep this output (FMU name; repeat; default: all outputs)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="change a tunable parameter")
    p.add_argument("--json", action="store_true", help="print the matrices and names as JSON")
    p.add_argument("--save", metavar="FILE", help="also save them: FILE.json (as --json) or FILE.npz (arrays)")
    p.set_defaults(func=cmd_linearize)

    p = subparsers.add_parser("control", help="rest-to-rest manoeuvre of the first joint in closed loop (fmpy)")
    p.add_argument("scene")
    p.add_argument("--target", type=_finite, required=True, metavar="DEG", help="final angle of the first joint")
    p.add_argument("--duration", type=_finite, required=True, metavar="S", help="manoeuvre time")
    p.add_argument("--settle", type=_finite, default=1.5, metavar="S",
                   help="window after the manoeuvre for the residual vibration and final error (default 1.5)")
    p.add_argument("--controller", choices=("lqr", "pd"), default="lqr",
                   help="lqr: LQR + Kalman estimator with model feedforward; pd: joint PD baseline")
    p.add_argument("--torque-limit", type=_finite, metavar="NM",
                   help="saturation and Bryson torque limit (default: 1.5 x the rigid quintic's peak torque)")
    p.add_argument("--sample-time", type=_finite, default=1e-3, metavar="S", help="controller sample time (1 ms)")
    p.add_argument("--sensors", choices=("strain", "accelerometer"), default="strain",
                   help="Kalman sensors besides the hub encoder: root strain gauge or tip accelerometer")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="FMU parameter for the run (the design keeps the scene's values)")
    p.add_argument("--noise", action="store_true", help="add the sensors' noise to what the controller reads")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.add_argument("--plot", metavar="OUT.png", help="time responses, closed-loop poles, loop Bode with margins")
    p.set_defaults(func=cmd_control)


def cmd_linearize(args) -> int:
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant
    from flexlink.run.simulate import parse_assignments
    from flexlink.scene.loader import load_scene

    model = build_model(load_scene(args.scene))
    angle = None if args.angle is None else math.radians(args.angle)
    plant = linear_plant(model, rate=args.rate, angle=angle, parameters=parse_assignments(args.set),
                         outputs=args.outputs)
    sys = plant.sys
    doc = {
        "rate": args.rate,
        "states": plant.states,
        "inputs": plant.inputs,
        "outputs": plant.outputs,
        "python_control_names": {"inputs": list(sys.input_labels), "outputs": list(sys.output_labels)},
        "operating_point": {"x": plant.x0.tolist(), "u": plant.u0.tolist(), "y": plant.y0.tolist()},
        "A": np.asarray(sys.A).tolist(), "B": np.asarray(sys.B).tolist(),
        "C": np.asarray(sys.C).tolist(), "D": np.asarray(sys.D).tolist(),
    }
    if args.save:
        _save(args.save, doc)
    if args.json:
        print(json.dumps(doc))
        return 0
    first = f"{model.scene.joints[0].name}.theta"
    where = (f"the first joint at {math.degrees(plant.x0[model.coordinates.index(first)]):.6g} deg"
             if first in model.coordinates else "the first joint's law")
    print(f"{model.scene.name}: linearised about {where}, rate {args.rate} rad/s; x = (q, dq/dt), deviations "
          "from the operating point")
    _print_matrix("A", sys.A, plant.states, plant.states)
    _print_matrix("B", sys.B, plant.states, plant.inputs)
    _print_matrix("C", sys.C, plant.outputs, plant.states)
    _print_matrix("D", sys.D, plant.outputs, plant.inputs)
    poles = np.sort_complex(sys.poles())
    print("poles (rad/s): " + ", ".join(f"{p.real:.6g}{p.imag:+.6g}j" for p in poles))
    print("(python-control spells the inputs/outputs with '_' for '.': " + ", ".join(sys.input_labels) + ")")
    return 0


def _save(path: str, doc: dict) -> None:
    try:
        if path.endswith(".npz"):
            np.savez(path, **{k: np.asarray(doc[k]) for k in ("A", "B", "C", "D")},
                     states=np.array(doc["states"]), inputs=np.array(doc["inputs"]),
                     outputs=np.array(doc["outputs"]), x0=np.asarray(doc["operating_point"]["x"]),
                     u0=np.asarray(doc["operating_point"]["u"]), y0=np.asarray(doc["operating_point"]["y"]))
        elif path.endswith(".json"):
            with open(path, "w") as f:
                json.dump(doc, f)
        else:
            raise FlexlinkError(f"--save {path}: expected a .json or .npz file name")
    except OSError as e:
        raise FlexlinkError(f"--save {path}: cannot write the file ({e.strerror})") from None


def _print_matrix(name: str, M, rows: list[str], cols: list[str]) -> None:
    M = np.asarray(M)
    w_row = max(len(r) for r in rows) if rows else 1
    w = max(13, *(len(c) + 1 for c in cols)) if cols else 13
    print(f"\n{name} =")
    print(" " * (w_row + 2) + "".join(f"{c:>{w}}" for c in cols))
    for r, line in zip(rows, M, strict=True):
        print(f"  {r:<{w_row}}" + "".join(f"{v:>{w}.6g}" for v in line))


def cmd_control(args) -> int:
    from controllers.cosim import FmuLoop
    from controllers.manoeuvre import check_scene, default_torque_limit, design, predict_manoeuvre, rest_to_rest
    from flexlink.export.fmu import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant
    from flexlink.run.simulate import parse_assignments
    from flexlink.scene.loader import load_scene

    if not (args.sample_time > 0):
        raise FlexlinkError(f"--sample-time must be positive, got {args.sample_time}")
    if args.torque_limit is not None and not args.torque_limit > 0:
        raise FlexlinkError(f"--torque-limit must be positive, got {args.torque_limit}")
    run_params = parse_assignments(args.set)
    model = build_model(load_scene(args.scene))
    check_scene(model)
    plant = linear_plant(model, outputs=[f"{model.scene.joints[0].name}.theta"])
    target = math.radians(args.target)
    delta = target - float(plant.x0[0])
    if not args.duration > 0:
        raise FlexlinkError(f"--duration must be a positive number of seconds, got {args.duration}")
    limit = args.torque_limit if args.torque_limit is not None else default_torque_limit(plant, delta,
                                                                                          args.duration)
    try:
        d = design(model, torque_limit=limit, dt=args.sample_time, sensors=args.sensors)
    except (ValueError, np.linalg.LinAlgError) as e:
        # e.g. the Riccati solver on a model with uncontrollable high modes (a symmetric plate's torsion)
        raise FlexlinkError(f"{args.scene}: the LQR/Kalman design failed ({e}); a model with fewer modes "
                            "(shapes.modes) may help") from None
    fmu = cached_fmu(args.scene)          # built (or found in the cache) before the timed run
    with FmuLoop(fmu) as loop:
        for name in run_params:
            if name not in loop.variables or loop.variables[name].causality != "parameter":
                raise FlexlinkError(f"--set {name}: not a parameter of the FMU")
        res = rest_to_rest(d, loop, target, args.duration, args.settle, args.controller, parameters=run_params,
                           noise=args.noise)
    m = res.metrics
    wn, zeta = d.lqr.rigid_pair
    if args.plot:
        from controllers.plots import plot_manoeuvre

        pred = None
        if not run_params:
            pred = predict_manoeuvre(d, target, args.duration, args.settle, args.controller)
        plot_manoeuvre(args.plot, [res], d, [pred],
                       title=f"{model.scene.name}: {args.controller.upper()}, {args.target:g} deg in "
                             f"{args.duration:g} s, torque limit {limit:g} N m")
    if args.json:
        m = dict(m)
        m.update({"sensors": d.kalman.sensors if args.controller == "lqr" else d.law("pd").sensors,
                  "rigid_pair_rad_s": wn, "rigid_pair_zeta": zeta, "parameters": run_params})
        print(json.dumps(m))
        return 0
    print(f"{model.scene.name}: {args.controller.upper()} rest-to-rest {math.degrees(float(plant.x0[0])):g} -> "
          f"{args.target:g} deg in {args.duration:g} s (+ {args.settle:g} s settle), sample time "
          f"{args.sample_time:g} s, torque limit {limit:g} N m")
    if args.controller == "lqr":
        print(f"  LQR rigid-body pair {wn:.3g} rad/s (zeta {zeta:.2f}); Kalman sensors: {', '.join(d.kalman.sensors)}")
    else:
        print(f"  PD kp {d.pd.kp:.4g} N m/rad, kd {d.pd.kd:.4g} N m s/rad (pair at {wn:.3g} rad/s, zeta {d.pd.zeta})")
    print(f"  final error          {m['final_error_deg']: .3e} deg")
    print(f"  residual vibration   {m['residual_vibration_rms_m']: .3e} m RMS (tip.v over the settle window)")
    print(f"  peak torque          {m['peak_torque_nm']: .4g} N m (saturated {100 * m['saturated_fraction']:.1f} %)")
    print(f"  max tip deflection   {m['max_tip_deflection_m']: .4g} m")
    print(f"  realtime factor      {m['realtime_factor']: .1f} (simulated s per wall-clock s)")
    if args.plot:
        print(f"  wrote {args.plot}")
    return 0
