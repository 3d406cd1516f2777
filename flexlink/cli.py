"""The ``flexlink`` command (SCENE.md "Commands").  Bad input: one message, exit status 2."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

from flexlink.errors import FlexlinkError
from flexlink.paths import SCENE_HELP, check_output_paths, output_file, plot_file


def _announce(scene_path) -> None:
    """A build expected to take long is said on stderr before it starts (the estimate of flexlink.scene.budget)."""
    from flexlink.scene.budget import ANNOUNCE_SECONDS, estimate
    from flexlink.scene.loader import load_scene

    cost = estimate(load_scene(scene_path))
    if cost.build_seconds > ANNOUNCE_SECONDS:
        print(f"flexlink: {cost.lines()[0]}; building", file=sys.stderr, flush=True)


def _cmd_build(args) -> int:
    from flexlink.export.fmu import build_fmu

    _announce(args.scene)
    rep = build_fmu(args.scene, args.output, keep_dir=args.keep_sources, platforms=args.platforms,
                    fmi_version=args.fmi)
    total = sum(rep.seconds.values())
    print(f"{rep.fmu}: {rep.n_coordinates} coordinates, {rep.operations} operations, "
          f"{rep.generated_c_bytes / 1024:.0f} KiB generated C, FMU {rep.fmu_bytes / 1024:.0f} KiB, "
          f"built in {total:.2f} s (" + ", ".join(f"{k} {v:.2f} s" for k, v in rep.seconds.items()) + ")")
    return 0


def _cmd_modes(args) -> int:
    from flexlink.mechanics.analysis import natural_frequencies
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene

    model = build_model(load_scene(args.scene))
    modes = natural_frequencies(model, args.rate)
    if args.json:
        print(json.dumps({"rate": args.rate, "frequencies_hz": modes.frequencies_hz, "unstable": modes.unstable_hz}))
        return 0
    print(f"{model.scene.name}: {model.n_q} coordinates ({', '.join(model.coordinates)}), hub rate {args.rate} rad/s")
    for k, f in enumerate(modes.frequencies_hz, 1):
        print(f"  mode {k}: {f:12.6g} Hz")
    for f in modes.unstable_hz:
        print(f"  unstable (divergence): |omega| = {f:.6g} Hz")
    if modes.rigid:
        print(f"  ({modes.rigid} rigid-body mode(s) left out)")
    return 0


def _cmd_simulate(args) -> int:
    from flexlink.export.fmu import cached_fmu
    from flexlink.run.simulate import check_run, parse_assignments, plot_result, read_input_csv, simulate, write_csv

    check_run(args.stop_time, args.step)        # before the build
    start = parse_assignments(args.set)
    fmu = cached_fmu(args.scene)
    inputs = None
    if args.input:
        import fmpy

        md = fmpy.read_model_description(str(fmu))
        inputs = read_input_csv(args.input, [v.name for v in md.modelVariables if v.causality == "input"])
    t0 = time.perf_counter()
    result = simulate(fmu, args.stop_time, step=args.step, inputs=inputs, start_values=start)
    wall = time.perf_counter() - t0
    if args.csv:
        write_csv(result, args.csv)
    if args.plot:
        plot_result(result, args.plot, title=Path(args.scene).stem)
    last = result[-1]
    shown = [n for n in result.dtype.names if n != "time"][:8]
    print(f"simulated {args.stop_time} s in {wall:.3f} s wall ({len(result)} points); at t = {last['time']:.6g}:")
    for n in shown:
        print(f"  {n:24s} {last[n]: .6g}")
    return 0


def _cmd_explain(args) -> int:
    from flexlink.scene.budget import estimate
    from flexlink.scene.loader import load_scene
    from flexlink.tools.explain import explain, fidelity, format_explanation, format_fidelity

    target = None
    if args.error_target is not None:
        try:
            target = float(args.error_target)
        except ValueError:
            target = None
        if target is None or not (math.isfinite(target) and target > 0):
            raise FlexlinkError(f"--error-target must be a positive number (a relative RMS error such as 1e-3), "
                                f"got {args.error_target!r}")
    cost = estimate(load_scene(args.scene))
    data = {**dataclasses.asdict(cost), "coordinates": cost.coordinates}
    if args.estimate:
        print(json.dumps(data) if args.json else "\n".join(cost.lines()))
        return 0
    if not args.json:
        print("\n".join(cost.lines()), flush=True)      # before the build, which may take a while
    info = explain(args.scene)
    info["estimate"] = data
    if target is not None:
        progress = (lambda m: print(m, file=sys.stderr, flush=True)) if sys.stderr.isatty() else None
        info["fidelity"] = fidelity(args.scene, target, quick=args.quick, progress=progress)
    if args.json:
        print(json.dumps(info))
    else:
        print(format_explanation(info) + ("\n" + format_fidelity(info["fidelity"]) if target is not None else ""))
    return 0


def _cmd_bench(args) -> int:
    from flexlink.tools.bench import plot_bench, report_markdown, run_bench

    rows, info = run_bench(args.scene, quick=args.quick, repeats=args.repeats)
    if args.plot:
        plot_bench(rows, info, args.plot)
    if args.report:
        Path(args.report).write_text(report_markdown(rows, info))
    if args.json:
        print(json.dumps([r.as_dict() for r in rows]))
    else:
        print(report_markdown(rows, info))
    return 0


def _add_plugin_commands(sub) -> None:
    """Sub-commands of the applications built on flexlink (``demo``, ``control``, ``linearize``, ``sweep``
    from the ``controllers`` package), found through the ``flexlink.commands`` entry points: the library
    does not import what sits above it."""
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group="flexlink.commands"), key=lambda e: e.name):
        try:
            ep.load()(sub)
        except Exception as e:      # a broken application must not take the library's own commands down
            print(f"flexlink: the commands of {ep.value} are unavailable ({type(e).__name__}: {e})",
                  file=sys.stderr)


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors in one line, like every other bad input (argparse prints the usage,
    which wraps over several lines for the long commands, then the error); ``--help`` still shows the usage."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The whole ``flexlink`` parser, the applications' sub-commands included: what ``main`` parses, and what
    the command reference (docs/commands.md) is checked against."""
    parser = _Parser(prog="flexlink", description="Flexible-link robots as FMI 2.0 and FMI 3.0 FMUs.")
    parser.add_argument("--allow-large", action="store_true",
                        help="build scenes past the size budgets (docs/budget.md); sets FLEXLINK_ALLOW_LARGE=1 "
                             "for every command")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build", help="export the FMU of a scene")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="the FMU file to write, or a folder (it receives <model identifier>.fmu)")
    p.add_argument("--keep-sources", metavar="DIR", help="keep the build directory (generated C) in DIR")
    p.add_argument("--platforms", default="linux64", metavar="P[,P]",
                   help="binaries to compile: linux64 (default), win64 (needs MinGW-w64), or linux64,win64")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                   help="FMI version of the FMU: 2 (default, FMI 2.0) or 3 (FMI 3.0); both with Co-Simulation and "
                        "Model Exchange")
    p.set_defaults(func=_cmd_build)

    p = sub.add_parser("modes", help="natural frequencies about an equilibrium")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--rate", type=float, default=0.0, help="steady rate of the first joint, rad/s")
    p.add_argument("--json", action="store_true", help="print the frequencies (Hz) as JSON")
    p.set_defaults(func=_cmd_modes)

    p = sub.add_parser("simulate", help="build (cached) and simulate the FMU with fmpy")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--stop-time", type=float, required=True, metavar="T", help="end of the run, s")
    p.add_argument("--step", type=float, metavar="H", help="communication step, s")
    p.add_argument("--input", metavar="IN.csv", help="CSV: time, then one column per input name")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="start value of a parameter (FMU name, e.g. hub.inertia=0.2; repeat)")
    p.add_argument("--csv", type=output_file, metavar="OUT.csv", help="write every output at every step")
    p.add_argument("--plot", type=plot_file, metavar="OUT.png", help="plot the outputs against time")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("explain", help="coordinates, terms and why, frequencies, recommended SS22 step")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--json", action="store_true", help="print the explanation as JSON")
    p.add_argument("--error-target", metavar="E", help="also measure the fidelity ladder (modes, kinematics, "
                   "deformation) and recommend its cheapest level with relative RMS error below E")
    p.add_argument("--quick", action="store_true", help="with --error-target: modes 1-3 and a shorter run (CI size)")
    p.add_argument("--estimate", action="store_true", help="only the estimate (sizes, rough build time and code "
                   "size, budgets exceeded), without building the model")
    p.set_defaults(func=_cmd_explain)

    p = sub.add_parser("bench", help="speed against error: SS22 against CVODES, IDAS and SciPy on the same equations")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    p.add_argument("--plot", type=plot_file, metavar="OUT.png", help="CPU time against error, every method")
    p.add_argument("--report", type=output_file, metavar="OUT.md", help="write the rows as a Markdown report")
    p.add_argument("--quick", action="store_true", help="fewer settings and a shorter run (CI size)")
    p.add_argument("--repeats", type=int, help="timed runs per setting (median; default 5, quick 2)")
    p.set_defaults(func=_cmd_bench)

    from flexlink.tools.check import add_parser as add_check_parser

    add_check_parser(sub)
    _add_plugin_commands(sub)
    return parser


def _option_names(parser: argparse.ArgumentParser, command: str) -> dict[str, str]:
    """``dest`` → the option's longest spelling (``--plot``), in the sub-command's parser: for messages."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: max(a.option_strings, key=len) for a in sub.choices[command]._actions if a.option_strings}


def _quiet_numerics():
    """numpy's floating-point warnings off (``length = 1e-300`` overflows in the shape functions): a command's
    answer is its output or its one-line error, which the checks that notice a non-finite result give (the
    static equilibrium, the guards, the FMU's refusals); a page of RuntimeWarnings before it helps nobody."""
    import numpy as np

    return np.errstate(all="ignore")


def _quiet_stdout() -> None:
    """After a closed pipe (``flexlink linearize … | head``): point stdout at /dev/null, so that the
    interpreter's last flush does not raise again at exit."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.allow_large:
        os.environ["FLEXLINK_ALLOW_LARGE"] = "1"
    try:
        check_output_paths(args, _option_names(parser, args.command))
        with _quiet_numerics():
            status = args.func(args)
        sys.stdout.flush()          # a closed pipe shows here, inside the handler, not at the interpreter's exit
        return status
    except FlexlinkError as e:
        print(f"flexlink: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (``| head``): stop quietly, as Unix tools do; 128 + SIGPIPE, as a shell reports
        # a tool that the signal ended
        _quiet_stdout()
        return 141
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
