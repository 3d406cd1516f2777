"""``flexlink control`` and ``flexlink linearize`` (docs/commands.md, docs/control.md).

The parsers are built for every ``flexlink`` command (``--help`` included): this module imports numpy,
python-control and the model builder only inside the commands that use them (tests/test_startup_imports.py).

``flexlink.cli`` wires them in with :func:`add_control_parsers`; each ``cmd_*`` returns the exit status and
raises :class:`flexlink.errors.FlexlinkError` on bad input (the caller prints it and exits 2).
"""

from __future__ import annotations

import json
import math

from controllers.options import SENSORS, add_weight_options
from controllers.options import angles as _angles
from controllers.options import finite as _finite
from flexlink.errors import FlexlinkError
from flexlink.paths import SCENE_HELP, output_file, plot_file

__all__ = ["add_control_parsers", "cmd_control", "cmd_linearize"]


def add_commands(subparsers) -> None:
    """The ``flexlink.commands`` entry point (pyproject.toml): this package's sub-commands of ``flexlink``."""
    from controllers.sweep_cli import add_sweep_parser

    p = subparsers.add_parser("demo", help="the quick start's main job: build an example FMU, run it in closed loop, "
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
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--rate", type=_finite, default=0.0, help="steady rate of the first joint, rad/s")
    p.add_argument("--angle", type=_finite, metavar="DEG", help="angle of the first joint (default: initial angle)")
    p.add_argument("--output", action="append", metavar="NAME", dest="outputs",
                   help="keep this output (FMU name; repeat; default: all outputs)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="change a tunable parameter")
    p.add_argument("--json", action="store_true", help="print the matrices and names as JSON")
    p.add_argument("--save", type=output_file, metavar="FILE",
                   help="also save them: FILE.json (as --json) or FILE.npz (arrays)")
    p.set_defaults(func=cmd_linearize)

    p = subparsers.add_parser("control", help="rest-to-rest manoeuvre in closed loop (fmpy): the first joint, or "
                                              "every joint of a multi-joint arm (MIMO LQG against joint PD); "
                                              "LQR/Kalman design on every torque-driven joint with its margins")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--target", type=_angles, metavar="DEG[,DEG...]",
                   help="final angle of the first joint (the run); with several torque-driven joints one per joint, "
                        "comma-separated: the MIMO LQG and the joint PD both run and are compared")
    p.add_argument("--duration", type=_finite, metavar="S", help="manoeuvre time (the run)")
    p.add_argument("--design-only", action="store_true",
                   help="design the LQR/Kalman on every torque-driven joint and report its margins, closed-loop "
                        "poles and peak sensitivity; no FMU, no run (needs --torque-limit or --target/--duration)")
    p.add_argument("--settle", type=_finite, default=1.5, metavar="S",
                   help="window after the manoeuvre for the residual vibration and final error (default 1.5)")
    p.add_argument("--controller", choices=("lqr", "pd"), default="lqr",
                   help="lqr: LQR + Kalman estimator with model feedforward; pd: joint PD baseline")
    add_weight_options(p, "saturation and Bryson torque limit of every joint, or one per torque-driven joint "
                          "comma-separated in scene order, or by joint name (default: 1.5 x the rigid quintic's peak "
                          "torque of the first joint; with several joints 1.5 x the largest peak of the "
                          "inverse-dynamics feedforward)")
    p.add_argument("--sample-time", type=_finite, default=1e-3, metavar="S", help="controller sample time (1 ms)")
    p.add_argument("--sensors", choices=SENSORS, default="strain",
                   help="Kalman sensors besides the joint encoders: the links' root strain gauges or the tip "
                        "accelerometers (the last tip's and every link's the scene declares)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="FMU parameter for the run (the design keeps the scene's values)")
    p.add_argument("--noise", action="store_true",
                   help="add each sensor's noise (the Kalman design's levels) to what the controllers read")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the --noise draws (default 0)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.add_argument("--plot", type=plot_file, metavar="OUT.png",
                   help="time responses, closed-loop poles, loop Bode with margins")
    p.add_argument("--schedule", type=int, metavar="N",
                   help="with several torque-driven joints: gain scheduling over the path, the LQG designed at N "
                        "poses along it (N >= 2, start and target included) and interpolated; the run compares it "
                        "with the fixed LQG designed at the start; both laws' margins along the path, worst case "
                        "and where, are reported (with --design-only, without a run) (docs/control.md)")
    p.add_argument("--integral", type=_finite, metavar="TI",
                   help="with several torque-driven joints: integral action on the joint positions in the LQG, "
                        "integral time TI s (Bryson weight 1/(joint-error limit x TI)^2 on each joint's error "
                        "integral; strain gauges; with --schedule in the scheduled and the fixed LQG, designed at "
                        "every pose; exported by --export-fmu and --export-ssp) (docs/control.md)")
    p.add_argument("--export-fmu", type=output_file, metavar="CTRL.fmu",
                   help="also write the sampled LQG (Kalman current estimator + discrete LQR, saturation) as a "
                        "pure-C FMI 2.0 Co-Simulation FMU, its sample time the fixed communication step; with "
                        "--schedule the scheduled LQG, its matrices switched along the path; with --sensors "
                        "accelerometer it plays the --target manoeuvre, its model along it as tables (docs/control.md)")
    p.add_argument("--export-ssp", type=output_file, metavar="SYSTEM.ssp",
                   help="also write an SSP 1.0 package: the scene's FMU and the controller FMU playing the "
                        "--target manoeuvre (needs --target and --duration), connected, the sample time as the "
                        "communication step; with --schedule the scheduled LQG (docs/control.md)")
    p.set_defaults(func=cmd_control)


def cmd_linearize(args) -> int:
    """Run ``flexlink linearize``: the state-space matrices about the first joint's angle and steady rate.

    The matrices are printed with their row and column names (python-control's labels spell ``.`` as ``_``)
    or as JSON, and with ``--save`` also written as JSON or NPZ for other tools.  Everything printed comes
    from the plant's matrices (:class:`flexlink.run.linearize.LinearPlant`), not from its python-control
    system, whose import would be most of the command's time (docs/performance.md); the poles are
    ``numpy.linalg.eigvals(A)``, which is what ``StateSpace.poles`` computes (tests/test_control_linearize.py
    checks every printed number against python-control's system).
    """
    import numpy as np

    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant, signal_name
    from flexlink.run.simulate import parse_assignments
    from flexlink.scene.loader import load_scene

    model = build_model(load_scene(args.scene))
    angle = None if args.angle is None else math.radians(args.angle)
    plant = linear_plant(model, rate=args.rate, angle=angle, parameters=parse_assignments(args.set),
                         outputs=args.outputs)
    labels = {"inputs": [signal_name(s) for s in plant.inputs], "outputs": [signal_name(s) for s in plant.outputs]}
    doc = {
        "rate": args.rate,
        "states": plant.states,
        "inputs": plant.inputs,
        "outputs": plant.outputs,
        "python_control_names": labels,
        "operating_point": {"x": plant.x0.tolist(), "u": plant.u0.tolist(), "y": plant.y0.tolist()},
        "A": plant.A.tolist(), "B": plant.B.tolist(), "C": plant.C.tolist(), "D": plant.D.tolist(),
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
    _print_matrix("A", plant.A, plant.states, plant.states)
    _print_matrix("B", plant.B, plant.states, plant.inputs)
    _print_matrix("C", plant.C, plant.outputs, plant.states)
    _print_matrix("D", plant.D, plant.outputs, plant.inputs)
    poles = np.sort_complex(np.linalg.eigvals(plant.A).astype(complex))
    print("poles (rad/s): " + ", ".join(f"{p.real:.6g}{p.imag:+.6g}j" for p in poles))
    print("(python-control spells the inputs/outputs with '_' for '.': " + ", ".join(labels["inputs"]) + ")")
    return 0


def _save(path: str, doc: dict) -> None:
    import numpy as np

    try:
        if path.endswith(".npz"):
            np.savez(path, **{k: np.asarray(doc[k]) for k in ("A", "B", "C", "D")},  # type: ignore[arg-type]
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
    import numpy as np

    M = np.asarray(M)
    w_row = max(len(r) for r in rows) if rows else 1
    w = max(13, *(len(c) + 1 for c in cols)) if cols else 13
    print(f"\n{name} =")
    print(" " * (w_row + 2) + "".join(f"{c:>{w}}" for c in cols))
    for r, line in zip(rows, M, strict=True):
        print(f"  {r:<{w_row}}" + "".join(f"{v:>{w}.6g}" for v in line))


def cmd_control(args) -> int:
    """Run ``flexlink control``: design the controllers, run the manoeuvre through the FMU, report its figures.

    Every check that needs no model runs first, so that bad input costs no build; a repeated command is
    answered from the design cache (:mod:`controllers.design_cache`) without the linearisation and design.
    """
    from controllers.weights import check_names, overrides, torque_limits
    from flexlink.run.simulate import parse_assignments
    from flexlink.scene.loader import load_scene

    _check_control_args(args)
    run_params = parse_assignments(args.set)
    if not args.design_only:
        from controllers.trajectory import check_times

        check_times(args.duration, args.settle, args.sample_time)       # before the model and the FMU are built
    scene = load_scene(args.scene)
    check_names(scene, args)                    # a misspelt joint or link costs no model build
    key = _cache_key(args, scene)
    if key is not None:
        from controllers.design_cache import load

        entry = load(key)
        if entry is not None and (not args.json or entry.get("json") is not None):
            if entry.get("kind") == "multijoint":
                return _run_multijoint_cached(args, scene, entry, run_params)
            return _run_cached(args, scene, entry, run_params)
    import numpy as np

    from controllers.manoeuvre import check_scene, design
    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant

    model = build_model(scene)
    check_scene(model)
    weights = overrides(model, args)
    plant = linear_plant(model, outputs=[f"{model.scene.joints[0].name}.theta"])
    targets = [math.radians(v) for v in args.target] if args.target is not None else None
    target = targets[0] if targets else None
    if args.duration is not None and not args.duration > 0:
        raise FlexlinkError(f"--duration must be a positive number of seconds, got {args.duration}")
    limit = torque_limits(plant, args.torque_limit)
    if limit is None:
        limit = _default_limits(plant, targets, args.duration, args.sample_time)
    try:
        d = design(model, torque_limit=limit, dt=args.sample_time, sensors=args.sensors, limits=weights)
    except (ValueError, np.linalg.LinAlgError) as e:
        raise FlexlinkError(f"{args.scene}: the LQR/Kalman design failed ({' '.join(str(e).split())})") from None
    if args.schedule is not None and (len(d.actuated_joints) < 2 or targets is None or args.duration is None):
        raise FlexlinkError("--schedule: gain scheduling over the path needs several torque-driven joints and the "
                            "path: --target and --duration")
    if args.integral is not None and len(d.actuated_joints) < 2:
        raise FlexlinkError("--integral: integral action is part of the multi-joint LQG (several torque-driven "
                            "joints)")
    if args.export_fmu and args.schedule is None:      # with --schedule: once the schedule is designed
        _export(args, d)
    if args.export_ssp and args.schedule is None:
        _export_ssp(args, d, targets)
    if args.design_only:
        return _report_design(args, d, targets)
    assert targets is not None and target is not None        # required without --design-only (checked above)
    if len(d.actuated_joints) > 1:
        return _run_multijoint(args, d, targets, run_params, key)
    if len(targets) > 1:
        raise FlexlinkError(f"--target: {len(targets)} angles for one torque-driven joint")
    return _run_single(args, d, plant, target, limit, run_params, key)


def _check_control_args(args) -> None:
    """Refuse contradictory or out-of-range options of ``flexlink control`` before the scene is read."""
    if not (args.sample_time > 0):
        raise FlexlinkError(f"--sample-time must be positive, got {args.sample_time}")
    if args.schedule is not None and args.schedule < 2:
        raise FlexlinkError(f"--schedule: at least 2 design points along the path (start and target), got "
                            f"{args.schedule}")
    if not args.design_only and (args.target is None or args.duration is None):
        raise FlexlinkError("--target and --duration are required for the closed-loop run (or give --design-only)")
    if args.integral is not None and not args.integral > 0:
        raise FlexlinkError(f"--integral: the integral time must be a positive number of seconds, got {args.integral}")
    if args.schedule is not None and (args.target is None or args.duration is None):
        raise FlexlinkError("--schedule: gain scheduling over the path needs the path: --target and --duration")
    if args.design_only and args.torque_limit is None and (args.target is None or args.duration is None):
        raise FlexlinkError("--design-only needs --torque-limit (or --target and --duration for the default)")


def _run_single(args, d, plant, target: float, limit, run_params: dict, key: str | None) -> int:
    """The one-joint manoeuvre through the FMU, its plot on request, its figures reported (and cached)."""
    from controllers.cosim import FmuLoop
    from controllers.manoeuvre import predict_manoeuvre, rest_to_rest
    from flexlink.export.cache import cached_fmu

    model = plant.model
    fmu = cached_fmu(args.scene)          # built (or found in the cache) before the timed run
    with FmuLoop(fmu) as loop:
        for name in run_params:
            if name not in loop.variables or loop.variables[name].causality != "parameter":
                raise FlexlinkError(f"--set {name}: not a parameter of the FMU")
        res = rest_to_rest(d, loop, target, args.duration, args.settle, args.controller, parameters=run_params,
                           noise=args.noise, seed=args.seed)
    m = res.metrics
    wn, zeta = d.lqr.rigid_pair
    if args.plot:
        from controllers.plots import plot_manoeuvre

        pred = None
        if not run_params:
            pred = predict_manoeuvre(d, target, args.duration, args.settle, args.controller)
        plot_manoeuvre(args.plot, [res], d, [pred],
                       title=f"{model.scene.name}: {args.controller.upper()}, {args.target[0]:g} deg in "
                             f"{args.duration:g} s, torque limit {limit:g} N m")
    info = {"name": model.scene.name, "start_deg": math.degrees(float(plant.x0[0])), "limit": limit, "wn": wn,
            "bryson_limits": d.lqr.limits,
            "zeta": zeta, "sensors": d.kalman.sensors if args.controller == "lqr" else d.law("pd").sensors}
    if args.controller == "pd":
        info.update(kp=d.joint_pd.kp, kd=d.joint_pd.kd, pd_zeta=d.joint_pd.zeta)
    rob = _robustness_json(d, args.controller) if args.json else None
    if key is not None:
        _store(key, args, d, target, info, rob)
    _report_single(args, info, m, run_params, rob)
    return 0


def _cache_key(args, scene) -> str | None:
    """The design cache's key of a run (:mod:`controllers.design_cache`).

    None for what the cache does not hold (--design-only, --noise, --plot, exports, --schedule, --integral) or
    when it is off.
    """
    if (args.design_only or args.noise or args.plot or args.export_fmu or args.export_ssp
            or args.schedule is not None or args.integral is not None or args.target is None):
        return None
    from controllers.design_cache import cache_key, enabled

    if not enabled():
        return None
    return cache_key(scene, {"target": args.target, "duration": args.duration, "settle": args.settle,
                             "controller": args.controller, "torque_limit": args.torque_limit,
                             "root_moment": args.root_moment, "joint_error": args.joint_error,
                             "tip_deflection": args.tip_deflection, "mode_limit": args.mode_limit,
                             "sample_time": args.sample_time,
                             "sensors": args.sensors})


def _store(key: str, args, d, target: float, info: dict, rob: dict | None) -> None:
    """Cache what the run needs (its law's affine form along the reference) and what it prints."""
    from controllers.design_cache import load, store
    from controllers.manoeuvre import reference, static_tip

    law = d.law(args.controller)
    ref = reference(d, args.controller, target, args.duration, args.settle)
    law.follow(ref)
    law.reset()
    form = law.affine(ref)
    if form is None:
        return
    old = load(key) or {}
    store(key, {"law": {"kind": law.kind, "dt": law.dt, "sensors": list(law.sensors), "input": law.input,
                        "form": form},
                "reference": ref, "info": info, "json": rob if rob is not None else old.get("json"),
                "context": {"joint": d.joint, "link": d.link, "torque_input": d.plant.inputs[0],
                            "torque_limit": d.torque_limit, "static_tip": static_tip(d, target),
                            "start_angle": d.start_angle}})


def _run_cached(args, scene, entry: dict, run_params: dict) -> int:
    """A repeated one-joint command: the cached law and reference through the FMU, the same figures."""
    from controllers.design_cache import CachedLaw
    from controllers.figures import manoeuvre_figures
    from flexlink.export.cache import cached_fmu

    c = entry["context"]
    fmu = cached_fmu(scene)
    with _loop(fmu, run_params) as loop:
        loop.record = [f"{c['joint']}.theta", f"{c['link']}.tip.v"]
        res = loop.run(CachedLaw(**entry["law"]), entry["reference"], parameters=run_params)
    target = math.radians(args.target[0])
    m = manoeuvre_figures(res.series, joint=c["joint"], link=c["link"], torque_input=c["torque_input"],
                          torque_limit=c["torque_limit"], static_tip=c["static_tip"], target=target,
                          duration=args.duration, settle=args.settle, sample_time=args.sample_time,
                          controller=args.controller, wall_time=res.wall_time)
    _report_single(args, entry["info"], m, run_params, entry.get("json"))
    return 0


def _report_single(args, info: dict, m: dict, run_params: dict, rob: dict | None) -> None:
    """The one-joint run's figures, printed or as JSON."""
    if args.json:
        m = dict(m)
        m.update({"sensors": info["sensors"], "rigid_pair_rad_s": info["wn"], "rigid_pair_zeta": info["zeta"],
                  "bryson_limits": info.get("bryson_limits"),
                  "parameters": run_params, "robustness": rob})
        print(json.dumps(m))
        return
    wn, zeta = info["wn"], info["zeta"]
    print(f"{info['name']}: {args.controller.upper()} rest-to-rest {info['start_deg']:g} -> "
          f"{args.target[0]:g} deg in {args.duration:g} s (+ {args.settle:g} s settle), sample time "
          f"{args.sample_time:g} s, torque limit {info['limit']:g} N m")
    if args.controller == "lqr":
        print(f"  LQR rigid-body pair {wn:.3g} rad/s (zeta {zeta:.2f}); Kalman sensors: {', '.join(info['sensors'])}")
    else:
        print(f"  PD kp {info['kp']:.4g} N m/rad, kd {info['kd']:.4g} N m s/rad (pair at {wn:.3g} rad/s, zeta "
              f"{info['pd_zeta']})")
    print(f"  final error          {m['final_error_deg']: .3e} deg")
    print(f"  residual vibration   {m['residual_vibration_rms_m']: .3e} m RMS (tip.v over the settle window)")
    print(f"  peak torque          {m['peak_torque_nm']: .4g} N m (saturated {100 * m['saturated_fraction']:.1f} %)")
    print(f"  max tip deflection   {m['max_tip_deflection_m']: .4g} m")
    print(f"  realtime factor      {m['realtime_factor']: .1f} (simulated s per wall-clock s)")
    if args.plot:
        print(f"  wrote {args.plot}")


def _export(args, d, schedule=None) -> None:
    """``--export-fmu``: write the controller FMU (:func:`controllers.export.export_controller_fmu`).

    With ``schedule`` it is scheduled along the path; one line on stderr (stdout may carry --json).
    """
    import sys

    from controllers.export import export_controller_fmu, reads_along

    ref = None
    if reads_along(d) and args.target is not None and args.duration is not None:   # the accelerometer: built in
        from controllers.multijoint import check_multijoint, inverse_dynamics_reference, plan

        check_multijoint(d)
        ref = inverse_dynamics_reference(d.plant, plan(d.plant, [math.radians(v) for v in args.target]), d.dt,
                                         args.duration, args.settle)
    integ = _integral_design(args, d) if schedule is None else _scheduled_integral(args, schedule)
    path = export_controller_fmu(d, args.export_fmu, schedule=schedule, duration=args.duration, reference=ref,
                                 integral=integ)
    what = "sampled LQG" if schedule is None else f"sampled LQG scheduled at {len(schedule.designs)} poses"
    if integ is not None:
        what += f" with integral action (integral time {args.integral:g} s)"
    plays = "" if ref is None else f", playing the manoeuvre ({args.duration + args.settle:g} s)"
    print(f"wrote {path}: {what} of {', '.join(d.actuated_joints)} at {d.dt:g} s{plays} (inputs: "
          f"{', '.join(d.kalman.sensors)}, x_ref, u_ff, w; outputs: {', '.join(d.lqr.inputs)})", file=sys.stderr)


def _export_ssp(args, d, targets, schedule=None) -> None:
    """``--export-ssp``: write the plant and controller FMUs playing the manoeuvre as one SSP package.

    The package is :func:`controllers.ssp.write_ssp`'s, scheduled along the path with ``schedule``; one line on
    stderr.
    """
    import sys

    from controllers.multijoint import check_multijoint, inverse_dynamics_reference, plan
    from controllers.ssp import write_ssp
    from controllers.trajectory import check_times
    from flexlink.export.cache import cached_fmu

    if targets is None or args.duration is None:
        raise FlexlinkError("--export-ssp: the package runs a manoeuvre; give --target and --duration")
    if not args.export_ssp.endswith(".ssp"):
        raise FlexlinkError(f"--export-ssp {args.export_ssp}: expected a file name ending in .ssp")
    check_multijoint(d)
    pl = plan(d.plant, targets)
    check_times(args.duration, args.settle, d.dt)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, args.duration, args.settle)
    integ = _integral_design(args, d) if schedule is None else _scheduled_integral(args, schedule)
    path = write_ssp(d, cached_fmu(args.scene), args.export_ssp, ref, schedule=schedule, integral=integ)
    what = "" if schedule is None else f" scheduled at {len(schedule.designs)} poses"
    if integ is not None:
        what += f" with integral action (integral time {args.integral:g} s)"
    print(f"wrote {path}: {d.plant.model.scene.name}'s FMU and its sampled LQG{what} ({', '.join(d.actuated_joints)}) "
          f"for {args.duration + args.settle:g} s at a {d.dt:g} s communication step", file=sys.stderr)


def _integral_design(args, d):
    """``--integral TI``'s augmented design (:func:`controllers.integral.design_integral`), None without it."""
    if args.integral is None:
        return None
    from controllers.integral import design_integral

    return design_integral(d, args.integral)


def _default_limits(plant, targets, duration, dt):
    """One joint: 1.5 x the rigid quintic's peak torque; several: 1.5 x the largest inverse-dynamics peak."""
    from controllers.design import actuated_joints
    from controllers.manoeuvre import default_torque_limit
    from controllers.multijoint import default_torque_limit as multijoint_limit

    if len(actuated_joints(plant)) == 1:
        return default_torque_limit(plant, targets[0] - float(plant.x0[0]), duration)
    return multijoint_limit(plant, targets, duration, dt)


def _run_multijoint(args, d, targets, run_params, key: str | None = None) -> int:
    """``flexlink control`` with several torque-driven joints: the MIMO LQG and the joint PD through the FMU.

    Both run the same manoeuvre (:func:`controllers.multijoint.compare`); the figures are printed or given as
    JSON, with the plot on request; what a repeated command needs is stored under ``key``
    (:mod:`controllers.design_cache`).
    """
    from controllers.multijoint import JointPDLaw, MimoLQGLaw, check_multijoint, compare, joint_pd_gains, plan
    from controllers.trajectory import check_times
    from flexlink.export.cache import cached_fmu

    if args.controller != "lqr":
        raise FlexlinkError("--controller: with several torque-driven joints the run compares the LQG and the joint "
                            "PD; leave --controller out")
    check_multijoint(d)                   # the refusals before an FMU is built
    pl = plan(d.plant, targets)
    check_times(args.duration, args.settle, d.dt)
    fmu = cached_fmu(args.scene)
    if args.schedule is not None:
        return _run_scheduled(args, d, targets, run_params, fmu)
    integ = None
    with _loop(fmu, run_params) as loop:
        if args.integral is None:
            runs = compare(d, loop, targets, args.duration, args.settle, parameters=run_params, pl=pl,
                           noise=args.noise, seed=args.seed)
        else:
            runs, integ = _compare_integral(args, d, pl, loop, run_params)
    move = _move(d, targets)
    if args.plot:
        from controllers.plots import plot_multijoint
        from controllers.robustness import robustness_figures

        loop_rob = d.robustness()["lqg"] if integ is None else _integral_loop(integ)
        plot_multijoint(args.plot, runs, title=f"{d.plant.model.scene.name}: {move} in {args.duration:g} s; LQG "
                                               "(MIMO, Kalman) against joint PD with the LQG's peak torques",
                        robustness=robustness_figures({"lqg": loop_rob})["lqg"])
    kp, kd = joint_pd_gains(d)
    info = {"name": d.plant.model.scene.name, "dt": d.dt, "joints": d.actuated_joints, "sensors": d.kalman.sensors,
            "move": move, "kp": kp.tolist(), "kd": kd.tolist(), "integral_time_s": args.integral}
    doc = None
    if args.json:
        rob = _robustness_json(d, "lqr", integ)
        rob["pd"] = _pd_robustness(d, runs["pd"])
        doc = {"joints": d.actuated_joints, "targets_deg": [math.degrees(t) for t in targets],
               "duration_s": args.duration, "settle_s": args.settle, "sample_time_s": d.dt,
               "sensors": d.kalman.sensors, "pd_gains": {"kp": kp.tolist(), "kd": kd.tolist()}, "robustness": rob,
               "torque_limits_nm": d.lqr.torque_limits, "bryson_limits": d.lqr.limits,
               "integral_time_s": args.integral,
               "noise": {"sigma": d.kalman.noise, "seed": args.seed} if args.noise else None}
    if key is not None:
        from controllers.design_cache import load, store

        ref = runs["lqr"].reference
        store(key, {"kind": "multijoint", "plan": pl, "reference": ref, "x0": d.plant.x0.copy(),
                    "lqg": MimoLQGLaw(d, [d.lqr.torque_limits[j] for j in pl.joints], ref),
                    "pd": JointPDLaw(d, [1.0] * len(pl.joints)), "info": info,
                    "json": doc if doc is not None else (load(key) or {}).get("json")})
    _report_multijoint(args, info, runs, run_params, doc)
    return 0


def _compare_integral(args, d, pl, loop, run_params):
    """``--integral TI``: the LQG with integral action (:mod:`controllers.integral`) and the joint PD, compared.

    As :func:`controllers.multijoint.compare`, the LQG's law replaced; returns the runs and the integral design.
    """
    from controllers.integral import IntegralLQGLaw, design_integral
    from controllers.multijoint import JointPDLaw, compare_laws, inverse_dynamics_reference

    integ = design_integral(d, args.integral)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, args.duration, args.settle)
    lqg = IntegralLQGLaw(integ, [d.lqr.torque_limits[j] for j in pl.joints], ref)
    runs = compare_laws(loop, pl, ref, lqg, JointPDLaw(d, [1.0] * len(pl.joints)), d.plant.x0,
                        parameters=run_params, noise=d.kalman.noise if args.noise else None, seed=args.seed)
    return runs, integ


def _integral_loop(integ) -> dict:
    from controllers.integral import integral_robustness

    return integral_robustness(integ)


def _run_multijoint_cached(args, scene, entry: dict, run_params: dict) -> int:
    """A repeated multi-joint command: the cached plan, reference and laws through the FMU."""
    from controllers.multijoint import compare_laws
    from flexlink.export.cache import cached_fmu

    with _loop(cached_fmu(scene), run_params) as loop:
        runs = compare_laws(loop, entry["plan"], entry["reference"], entry["lqg"], entry["pd"], entry["x0"],
                            parameters=run_params)
    _report_multijoint(args, entry["info"], runs, run_params, entry.get("json"))
    return 0


def _report_multijoint(args, info: dict, runs: dict, run_params: dict, doc: dict | None) -> None:
    if args.json:
        print(json.dumps({"lqg": runs["lqr"].metrics, "pd": runs["pd"].metrics, **(doc or {}),
                          "parameters": run_params}))
        return
    _print_comparison(args, info, runs)


def _loop(fmu, run_params):
    """The FMU's closed loop, the ``--set`` names checked against its parameters."""
    from controllers.cosim import FmuLoop

    loop = FmuLoop(fmu)
    for name in run_params:
        if name not in loop.variables or loop.variables[name].causality != "parameter":
            loop.close()
            raise FlexlinkError(f"--set {name}: not a parameter of the FMU")
    return loop


def _move(d, targets) -> str:
    joints = d.actuated_joints
    start = {j: math.degrees(float(d.plant.op.q[d.plant.model.coordinates.index(f"{j}.theta")])) for j in joints}
    return ", ".join(f"{j} {start[j]:g} -> {math.degrees(t):g} deg" for j, t in zip(joints, targets, strict=True))


def _run_scheduled(args, d, targets, run_params, fmu) -> int:
    """``--schedule N``: the LQG scheduled over the path against the fixed one (:mod:`controllers.schedule`).

    Besides the two runs, the frozen-pose spectral radius and margins of both at the design points and three
    poses between each two (:func:`_path_margins`) show where each loses margin.
    """
    import numpy as np

    from controllers.multijoint import inverse_dynamics_reference
    from controllers.plots import path_margins_text
    from controllers.schedule import compare_schedule

    pl, schedule = _scheduled_design(args, d, targets)
    integ = _scheduled_integral(args, schedule)
    ref = inverse_dynamics_reference(d.plant, pl, d.dt, args.duration, args.settle)
    noise = {"noise": d.kalman.noise, "seed": args.seed} if args.noise else {}    # both laws read the design's sensors
    with _loop(fmu, run_params) as loop:
        runs = compare_schedule(d, schedule, loop, pl, ref, integral=integ, parameters=run_params, **noise)
    margins = _path_margins(d, schedule, pl, args.schedule, integ)
    radius = [{"sigma": p["sigma"], "pose_deg": p["pose_deg"], "fixed": f["spectral_radius"],
               "scheduled": p["spectral_radius"]}
              for p, f in zip(margins["scheduled"]["points"], margins["fixed"]["points"], strict=True)]
    move = _move(d, targets)
    done = {k: r for k, r in runs.items() if not isinstance(r, str)}
    if args.plot:
        from controllers.plots import plot_multijoint

        plot_multijoint(args.plot, done, title=f"{d.plant.model.scene.name}: {move} in {args.duration:g} s; LQG "
                                               f"scheduled at {args.schedule} poses against the fixed LQG",
                        caption=path_margins_text(margins))
    if args.json:
        print(json.dumps({**{k: (r if isinstance(r, str) else r.metrics) for k, r in runs.items()},
                          "joints": d.actuated_joints, "targets_deg": [math.degrees(t) for t in targets],
                          "duration_s": args.duration, "settle_s": args.settle, "sample_time_s": d.dt,
                          "torque_limits_nm": d.lqr.torque_limits, "bryson_limits": d.lqr.limits,
                          "schedule": {"points": args.schedule, "sigma": schedule.sigma.tolist(),
                                       "poses_deg": [{j: math.degrees(v) for j, v in p.items()}
                                                     for p in schedule.poses]},
                          "frozen_spectral_radius": radius, "robustness_along_path": margins,
                          "integral_time_s": args.integral, "parameters": run_params,
                          "noise": {"sigma": noise["noise"], "seed": args.seed} if noise else None}))
        return 0
    print(f"{d.plant.model.scene.name}: rest-to-rest {move} in {args.duration:g} s (+ {args.settle:g} s settle), "
          f"sample time {d.dt:g} s; feedforward: the model's inverse dynamics along the joints' quintics")
    print(f"  scheduled LQG: designed at {args.schedule} poses along the path ("
          + "; ".join(", ".join(f"{v:.4g}" for v in np.degrees(list(p.values()))) for p in schedule.poses)
          + " deg), interpolated by the path parameter; fixed LQG: designed at the start pose")
    if integ is not None:
        print(f"  both with integral action on the joint positions, integral time {args.integral:g} s (the "
              "augmented gains designed at every pose of the schedule)")
    print("  frozen-pose spectral radius (sampled loop, < 1 holds the pose), fixed / scheduled: "
          + ", ".join(f"{r['fixed']:.4f}/{r['scheduled']:.4f}" for r in radius))
    print("  " + path_margins_text(margins).replace("\n", "\n  "))
    for k, r in runs.items():
        if isinstance(r, str):
            print(f"  {k} LQG: left the beam model's validity: {r}")
    _print_table({("scheduled LQG" if k == "scheduled" else "fixed LQG"): r.metrics for k, r in done.items()})
    if args.plot:
        print(f"  wrote {args.plot}")
    return 0


def _print_table(columns: dict) -> None:
    """The figures of several runs side by side (label → metrics)."""
    first = next(iter(columns.values()))

    def st(m):
        return "not settled" if m["settling_time_s"] is None else f"{m['settling_time_s']:.4g} s"

    def row(label, values, fmt="14.4g", suffix=""):
        print(f"  {label:34s}" + "".join(f"{v:{fmt}}" for v in values) + suffix)

    row("", list(columns), ">14s")
    row("settling time", [st(m) for m in columns.values()], ">14s",
        f"   (joints within {first['settle_band_deg']:g} deg, tips within {1e3 * first['settle_band_m']:g} mm)")
    for lk in first["links"]:
        for key, what in (("residual_vibration_rms_m", "residual vibration RMS"), ("max_tip_deflection_m", "max tip")):
            row(f"{lk}.tip.v {what} (mm)", [1e3 * m["links"][lk][key] for m in columns.values()])
    for j in first["joints"]:
        for key, what in (("final_error_deg", "final error (deg)"), ("peak_torque_nm", "peak torque (N m)")):
            row(f"{j} {what}", [m["joints"][j][key] for m in columns.values()])
    row("realtime factor", [m["realtime_factor"] for m in columns.values()], "14.1f")


def _pd_robustness(d, pd_run) -> dict:
    """The joint PD's loop-at-a-time margins and closed-loop poles (sampled plant, encoders and rates)."""
    from controllers.closedloop import sampled_plant
    from controllers.design import torque_inputs
    from controllers.multijoint import JointPDLaw
    from controllers.robustness import loop_at_a_time, robustness_figures

    law = JointPDLaw(d, list(pd_run.metrics["torque_limits_nm"].values()))
    P = sampled_plant(d.plant, d.dt, law.sensors)[:, torque_inputs(d.plant)]
    return robustness_figures({"pd": loop_at_a_time(P, -law.G, law.inputs)})["pd"]


def _print_comparison(args, info: dict, runs: dict) -> None:
    lqg, pd = runs["lqr"].metrics, runs["pd"].metrics
    print(f"{info['name']}: rest-to-rest {info['move']} in {args.duration:g} s (+ {args.settle:g} s settle), "
          f"sample time {info['dt']:g} s; feedforward: the model's inverse dynamics along the joints' quintics")
    print(f"  LQG: LQR on {', '.join(info['joints'])} + Kalman ({', '.join(info['sensors'])}), torque limits "
          + ", ".join(f"{v:g}" for v in lqg["torque_limits_nm"].values()) + " N m")
    if info.get("integral_time_s") is not None:
        print(f"  LQG with integral action on the joint positions, integral time {info['integral_time_s']:g} s")
    print("  PD:  kp " + ", ".join(f"{v:.4g}" for v in info["kp"]) + " N m/rad, kd "
          + ", ".join(f"{v:.4g}" for v in info["kd"]) + " N m s/rad, torque limits = the LQG run's peaks")
    if args.noise:
        print(f"  sensor noise (seed {args.seed}): the Kalman design's sigma per sensor, 1e-3 rad/s on the PD's rates")
    _print_table({"LQG": lqg, "PD": pd})
    if args.plot:
        print(f"  wrote {args.plot}")


def _robustness_json(d, controller: str, integ=None) -> dict:
    """The design's margins as JSON values (``controllers.robustness.robustness_figures``).

    They are the continuous LQR's, the sampled LQG's, and with one sample of computation delay the predictive
    LQG's and those of the LQG unaware of it (sensors without feedthrough); with the PD, its own sampled loop
    as ``"pd"`` too; with ``integ`` (:func:`controllers.integral.design_integral`) the sampled LQG with integral
    action as ``"lqg_integral"``.
    """
    import numpy as np

    from controllers.closedloop import sampled_plant
    from controllers.robustness import loop_at_a_time, robustness_figures

    rob = dict(d.robustness())
    if not np.any(d.kalman.D != 0):
        from controllers.robustness import delayed_robustness

        rob.update(delayed_robustness(d.lqr, d.kalman))
    if controller == "pd":
        law = d.law("pd")
        rob["pd"] = loop_at_a_time(sampled_plant(d.plant, d.dt, law.sensors), -law.K @ law.S, [law.input])
    if integ is not None:
        rob["lqg_integral"] = _integral_loop(integ)
    return robustness_figures(rob)


def _lead(a: dict) -> str:
    """`` (lead)`` after a phase margin that a phase lead uses up (a loop with open-loop unstable poles)."""
    if a.get("phase_margin_sense") != "lead":
        return ""
    return f" (lead; {a.get('open_loop_unstable_poles')} open-loop unstable poles)"


def _report_design(args, d, targets=None) -> int:
    """``flexlink control --design-only``: gains' shapes, weights, margins, closed-loop poles.

    With ``--schedule`` also the schedule's margins along the path (:func:`_schedule_margins`), and its
    controller FMU or SSP package on request.
    """
    wn, zeta = d.lqr.rigid_pair
    integ = None
    if args.integral is not None:
        from controllers.integral import design_integral

        integ = design_integral(d, args.integral)
    rob = _robustness_json(d, "lqr", integ)
    along = None if args.schedule is None else _schedule_margins(args, d, targets)
    if args.json:
        print(json.dumps({
            "actuated_joints": d.actuated_joints, "inputs": d.lqr.inputs, "states": d.plant.states,
            "sample_time_s": d.dt, "torque_limits_nm": d.lqr.torque_limits, "bryson_limits": d.lqr.limits,
            "lqr_weights": {"Q": d.lqr.Q.tolist(), "R": d.lqr.R.tolist()},
            "sensors": d.kalman.sensors, "K": d.lqr.K.tolist(), "Kd": d.lqr.Kd.tolist(),
            "rigid_pair_rad_s": wn, "rigid_pair_zeta": zeta, "robustness": rob, "integral_time_s": args.integral,
            **({} if along is None else {"robustness_along_path": along})}))
        return 0
    model = d.plant.model
    print(f"{model.scene.name}: LQR on {', '.join(d.actuated_joints)} ({d.plant.sys.nstates} states), sample time "
          f"{d.dt:g} s, torque limits " + ", ".join(f"{j} {v:g} N m" for j, v in d.lqr.torque_limits.items()))
    print(f"  Kalman sensors: {', '.join(d.kalman.sensors)}; slowest LQR pair {wn:.3g} rad/s (zeta {zeta:.2f})")
    from controllers.weights import describe

    print(f"  Bryson limits (Q = sum of C_z^T C_z / limit^2, R = diag(1/torque limit^2)): {describe(d.lqr.limits)}")

    def db(v):
        return "inf" if v is None else f"{v:.3g}"

    for loop, what in (("lqr", "continuous LQR, full state"), ("lqg", f"sampled LQG at {d.dt:g} s"),
                       ("lqg_delay1", "predictive LQG, one sample of delay (the SSP package's)"),
                       ("lqg_integral", f"sampled LQG with integral action (integral time {args.integral} s)")):
        if loop not in rob:
            continue
        r = rob[loop]
        print(f"  {what}: {'stable' if r['stable'] else 'UNSTABLE'}, peak sensitivity "
              f"{db(r['peak_sensitivity'])} (all loops); disk margins balanced (skew {r['disk_skew']:g})")
        for a in r["actuators"]:
            gr = "-inf" if a["gain_reduction_margin_db"] is None else f"{a['gain_reduction_margin_db']:.3g}"
            print(f"    {a['input']:<16} gain margin {db(a['gain_margin_db'])} dB (down {gr} dB), phase margin "
                  f"{db(a['phase_margin_deg'])} deg{_lead(a)} at {db(a['gain_crossover_hz'])} Hz, peak sensitivity "
                  f"{db(a['peak_sensitivity'])}; disk margin {db(a['disk_margin'])}: ±{db(a['disk_gain_margin_db'])}"
                  f" dB with ±{db(a['disk_phase_margin_deg'])} deg at {db(a['disk_margin_hz'])} Hz")
        ml = r["multiloop"]
        print(f"    {'all at once':<16} disk margin {db(ml['disk_margin'])}: ±{db(ml['disk_gain_margin_db'])} dB with "
              f"±{db(ml['disk_phase_margin_deg'])} deg at every actuator simultaneously, at "
              f"{db(ml['disk_margin_hz'])} Hz"
              + ("" if ml["exact"] else f" (μ bounds: at most {db(ml['disk_margin_upper'])})"))
    if "lqg_delay1_unaware" in rob:
        print(f"  the sampled LQG with that delay (not predicting it): "
              f"{'stable' if rob['lqg_delay1_unaware']['stable'] else 'UNSTABLE'}")
    if along is not None:
        from controllers.plots import path_margins_text

        print(f"  scheduled at {args.schedule} poses along the path; " + path_margins_text(along).replace("\n", "\n  "))
    return 0


def _schedule_margins(args, d, targets) -> dict:
    """``--design-only --schedule N``: the schedule designed along the path (exported on request), its margins.

    :func:`controllers.schedule.along_path` at the design points and three poses between each two, as a
    scheduled run reports them.
    """
    from controllers.multijoint import check_multijoint

    check_multijoint(d)
    pl, schedule = _scheduled_design(args, d, targets)
    return _path_margins(d, schedule, pl, args.schedule, _scheduled_integral(args, schedule))


def _scheduled_integral(args, schedule):
    """``--integral TI`` with ``--schedule N``: the augmented design at every design point, None without it."""
    if args.integral is None:
        return None
    from controllers.integral import design_scheduled_integral

    return design_scheduled_integral(schedule, args.integral)


def _scheduled_design(args, d, targets):
    """The plan to ``targets`` and the schedule of ``--schedule N`` along it, its controller exported on request."""
    from controllers.multijoint import plan
    from controllers.schedule import design_schedule

    pl = plan(d.plant, targets)
    schedule = design_schedule(d, pl, args.schedule)
    if args.export_fmu:
        _export(args, d, schedule)
    if args.export_ssp:
        _export_ssp(args, d, targets, schedule)
    return pl, schedule


def _path_margins(d, schedule, pl, points: int, integral=None) -> dict:
    """Both laws' margins frozen at the ``points`` design points and three poses between each two.

    With ``integral`` (:func:`_scheduled_integral`) those of both laws with integral action.
    """
    import numpy as np

    from controllers.schedule import along_path

    return along_path(d, schedule, pl, np.linspace(0.0, 1.0, 4 * points - 3).tolist(), integral=integral)
