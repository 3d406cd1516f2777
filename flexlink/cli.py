"""The ``flexlink`` command line: one sub-command per stage or tool, documented in docs/commands.md.

Each sub-command imports its stage only when it runs, so that ``flexlink --help`` and a bad option answer at
once.  Bad input of any kind (a scene, an option, an output path, a refused FMU call) is one message on
stderr and exit status 2, never a traceback; the applications above the library (``controllers``) add their
sub-commands through the ``flexlink.commands`` entry point.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from flexlink.errors import FlexlinkError
from flexlink.options import finite
from flexlink.paths import SCENE_HELP, check_output_paths, film_file, output_file, plot_file, stream_file

if TYPE_CHECKING:                      # the commands import numpy and fmpy only when they run
    import numpy as np
    from fmpy.model_description import ModelDescription


def _announce(scene_path: str) -> None:
    """A build expected to take long is said on stderr before it starts (the estimate of flexlink.scene.budget)."""
    from flexlink.scene.budget import ANNOUNCE_SECONDS, estimate
    from flexlink.scene.loader import load_scene

    cost = estimate(load_scene(scene_path))
    if cost.build_seconds > ANNOUNCE_SECONDS:
        print(f"flexlink: {cost.lines()[0]}; building", file=sys.stderr, flush=True)


def _cmd_build(args: argparse.Namespace) -> int:
    from flexlink.export.fmu import build_fmu

    _announce(args.scene)
    rep = build_fmu(args.scene, args.output, keep_dir=args.keep_sources, platforms=args.platforms,
                    fmi_version=args.fmi)
    total = sum(rep.seconds.values())
    print(f"{rep.fmu}: {rep.n_coordinates} coordinates, {rep.operations} operations, "
          f"{rep.generated_c_bytes / 1024:.0f} KiB generated C, FMU {rep.fmu_bytes / 1024:.0f} KiB, "
          f"built in {total:.2f} s (" + ", ".join(f"{k} {v:.2f} s" for k, v in rep.seconds.items()) + ")")
    return 0


def _cmd_modes(args: argparse.Namespace) -> int:
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


def _cmd_simulate(args: argparse.Namespace) -> int:
    import fmpy

    from flexlink.export.cache import cached_fmu
    from flexlink.run import simulate as run

    run.check_run(args.stop_time, args.step)        # before the build
    start = run.parse_assignments(args.set)
    fmu = cached_fmu(args.scene)
    md = fmpy.read_model_description(str(fmu))
    outputs = run.choose_outputs(md, args.output)
    input_names = [v.name for v in md.modelVariables if v.causality == "input"]
    t0 = time.perf_counter()
    result = _drive(args, fmu, md, start, args.step, list(dict.fromkeys(input_names + outputs)), args.progress)
    wall = time.perf_counter() - t0
    if args.csv:
        run.write_csv(result, args.csv, outputs)
    if args.plot:
        shown = list(dict.fromkeys(input_names + (outputs if args.output else outputs[:6])))
        run.plot_result(result, args.plot, shown, title=Path(args.scene).stem, units=run.variable_units(md))
    last = result[-1]
    summary = sys.stderr if args.csv == "-" else sys.stdout      # stdout holds nothing but the CSV then
    print(f"simulated {args.stop_time} s in {wall:.3f} s wall ({len(result)} points); at t = {last['time']:.6g}:",
          file=summary)
    for n in outputs[:8] if not args.output else outputs:
        print(f"  {n:24s} {last[n]: .6g}", file=summary)
    return 0


def _drive(args: argparse.Namespace, fmu: Path, md: ModelDescription, start: dict[str, float], step: float | None,
           outputs: list[str], show_progress: bool | None) -> np.ndarray:
    """Run the FMU as ``--input``, ``--interpolation`` and ``--set`` say, with the progress bar.

    ``show_progress``: None shows it on a terminal only.  After the run, say which inputs nobody gave.
    """
    from flexlink.run import progress
    from flexlink.run import simulate as run

    input_names = [v.name for v in md.modelVariables if v.causality == "input"]
    inputs = run.read_input_csv(args.input, input_names) if args.input else None
    bar = progress.RunProgress(args.stop_time, force=show_progress is True) if progress.wanted(show_progress) \
        else contextlib.nullcontext()
    with bar as step_finished:
        result = run.simulate(fmu, args.stop_time, step=step, inputs=inputs, start_values=start, outputs=outputs,
                              interpolation=args.interpolation, step_finished=step_finished)
    _warn_unset_inputs(md, input_names, inputs, start)     # after the run: a refused run's error stays one line
    return result


def _warn_unset_inputs(md: ModelDescription, input_names: list[str], inputs: np.ndarray | None,
                       start: dict[str, float]) -> None:
    """One line on stderr for each run whose inputs nobody gives.

    They keep their start values throughout, which is rarely what a user who forgot ``--input`` meant (an arm
    that never moves).
    """
    columns = inputs.dtype.names if inputs is not None else None      # read_input_csv: time, then the inputs
    given = set(columns[1:]) if columns is not None else set()
    unset = [v for v in md.modelVariables if v.name in input_names and v.name not in given and v.name not in start]
    if unset:
        held = ", ".join(f"{v.name} = {v.start}" for v in unset)
        how = "not among --input's columns" if inputs is not None else "no --input given"
        print(f"flexlink: warning: {how}: the input(s) keep their start values for the whole run ({held})",
              file=sys.stderr)


def _cmd_animate(args: argparse.Namespace) -> int:
    import fmpy

    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.centreline import centreline
    from flexlink.run import animate
    from flexlink.run import simulate as run
    from flexlink.scene.loader import load_scene

    if not (math.isfinite(args.fps) and 0 < args.fps <= 100):
        raise FlexlinkError(f"--fps must lie in (0, 100], got {args.fps}")
    if args.magnify is not None and not (math.isfinite(args.magnify) and args.magnify > 0):
        raise FlexlinkError(f"--magnify must be a positive number, got {args.magnify}")
    step = 1.0 / args.fps
    run.check_run(args.stop_time, step, step_option="--fps")
    if args.stop_time * args.fps > animate.MAX_FRAMES:
        raise FlexlinkError(f"{args.stop_time * args.fps:.0f} frames (--stop-time × --fps), more than "
                            f"{animate.MAX_FRAMES}: give a lower --fps or a shorter --stop-time")
    start = run.parse_assignments(args.set)
    line = centreline(load_scene(args.scene))
    fmu = cached_fmu(args.scene)
    result = _drive(args, fmu, fmpy.read_model_description(str(fmu)), start, step, line.coordinates, None)
    film = animate.arm_film(line, result, args.magnify, frame_step=step)
    figure = animate.write_film(film, args.output, fps=args.fps, title=Path(args.scene).stem, view=args.view,
                                still=args.still)
    print(f"{args.output}: {len(film.times)} frames at {args.fps:g} per second, {figure.view} view, deflection "
          f"× {film.magnification:g} (largest true deflection {film.deflection * 1e3:.3g} mm)"
          + (f"; still frame {args.still}" if args.still else ""))
    return 0


def _add_input_options(p: argparse.ArgumentParser) -> None:
    """--input, --interpolation and --set: how a run of the FMU is driven (simulate, animate)."""
    from flexlink.run import INTERPOLATIONS  # not flexlink.run.simulate: the parser imports no numpy, no fmpy

    p.add_argument("--input", metavar="IN.csv", help="CSV: time, then one column per input name (two rows at "
                   "the same time make a jump); an input without a column keeps its start value, with a warning")
    p.add_argument("--interpolation", choices=INTERPOLATIONS, default="linear",
                   help="--input between its rows: linear (default; fmpy's own, for a sampled continuous signal) "
                        "or hold (each value until the next row, for piecewise-constant commands); the FMU gets "
                        "the value at each communication point and holds it over the step")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="start value of a parameter (FMU name, e.g. hub.inertia=0.2; repeat)")


def _cmd_explain(args: argparse.Namespace) -> int:
    from flexlink.scene.budget import estimate
    from flexlink.scene.loader import load_scene

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
    from flexlink.tools.explain import explain, fidelity, format_explanation, format_fidelity  # CasADi, SciPy

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


def _cmd_bench(args: argparse.Namespace) -> int:
    from flexlink.tools.bench import plot_bench, report_markdown, rows_json, run_bench

    rows, info = run_bench(args.scene, quick=args.quick, repeats=args.repeats, stop=args.stop)
    if args.plot:
        plot_bench(rows, info, args.plot)
    if args.report:
        Path(args.report).write_text(report_markdown(rows, info))
    if args.json:
        print(json.dumps(rows_json(rows, info)))
    else:
        print(report_markdown(rows, info))
    return 0


def _add_plugin_commands(sub: argparse._SubParsersAction[_Parser]) -> None:
    """Add the sub-commands of the applications built on flexlink, found through entry points.

    ``demo``, ``control``, ``linearize``, ``sweep`` from the ``controllers`` package, found through the
    ``flexlink.commands`` entry points: the library does not import what sits above it.
    """
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group="flexlink.commands"), key=lambda e: e.name):
        try:
            ep.load()(sub)
        except Exception as e:      # a broken application must not take the library's own commands down
            print(f"flexlink: the commands of {ep.value} are unavailable ({type(e).__name__}: {e})",
                  file=sys.stderr)


class _Parser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line, like every other bad input.

    argparse prints the usage, which wraps over several lines for the long commands, then the error;
    ``--help`` still shows the usage.
    """

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The whole ``flexlink`` parser, the applications' sub-commands included.

    What ``main`` parses, and what the command reference (docs/commands.md) is generated from and checked
    against.
    """
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
    p.add_argument("--rate", type=finite, default=0.0, help="steady rate of the first joint, rad/s")
    p.add_argument("--json", action="store_true", help="print the frequencies (Hz) as JSON")
    p.set_defaults(func=_cmd_modes)

    p = sub.add_parser("simulate", help="build (cached) and simulate the FMU with fmpy")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--stop-time", type=float, required=True, metavar="T", help="end of the run, s")
    p.add_argument("--step", type=float, metavar="H", help="communication step, s")
    _add_input_options(p)
    p.add_argument("--output", nargs="+", action="extend", metavar="NAME",
                   help="outputs (or inputs) to write, plot and print (FMU names, e.g. hub.theta arm.tip.v; "
                        "default: every output written, the first six plotted; the inputs are always plotted)")
    p.add_argument("--csv", type=stream_file, metavar="OUT.csv", help="write time and the outputs at every step "
                   "(- : to standard output, the summary then goes to stderr)")
    p.add_argument("--plot", type=plot_file, metavar="OUT.png", help="plot the inputs and outputs against time, "
                   "with their units")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="a progress bar with the remaining time on stderr for runs over 2 s (default: only when "
                        "stderr is a terminal; --progress shows it at once, even into a file)")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("animate", help="a film of the deformed arm over time (gif or mp4) from an FMU run")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--stop-time", type=float, required=True, metavar="T", help="end of the run, s")
    _add_input_options(p)
    p.add_argument("-o", "--output", type=film_file, required=True, metavar="OUT.gif",
                   help="the film: .gif (Pillow) or .mp4 (ffmpeg: from PATH, else imageio-ffmpeg's)")
    p.add_argument("--magnify", type=float, metavar="K", help="deflection magnification (the elastic coordinates' "
                   "effect only; joint angles true); default: 1, 2 or 5 × 10ⁿ making the largest deflection "
                   "about 8 %% of the arm's reach; drawn in every frame")
    p.add_argument("--view", choices=("auto", "3d", "xy", "xz", "yz"), default="auto",
                   help="projection: auto (the plane of a planar arm, else 3d), 3d, or a world plane")
    p.add_argument("--fps", type=float, default=25.0, help="frames per simulated second (also the communication "
                   "step, 1/fps); the film plays in real time (default 25)")
    p.add_argument("--still", type=plot_file, metavar="OUT.png", help="also write the frame of the largest "
                   "deflection as a figure")
    p.set_defaults(func=_cmd_animate)

    p = sub.add_parser("explain", help="coordinates, terms and why, frequencies, recommended SS22 step")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--json", action="store_true", help="print the explanation as JSON")
    p.add_argument("--error-target", metavar="E", help="also measure the fidelity ladder (modes, kinematics, "
                   "deformation) and recommend its cheapest level with relative RMS error below E, checked "
                   "directly (its FMU against the truth on a second manoeuvre)")
    p.add_argument("--quick", action="store_true", help="with --error-target: modes 1-3 and a shorter run (CI size)")
    p.add_argument("--estimate", action="store_true", help="only the estimate (sizes, rough build time and code "
                   "size, budgets exceeded), without building the model")
    p.set_defaults(func=_cmd_explain)

    p = sub.add_parser("bench", help="speed against error: SS22 against CVODES, IDAS and SciPy on the same equations")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    p.add_argument("--plot", type=plot_file, metavar="OUT.png", help="CPU time against error, every method")
    p.add_argument("--report", type=output_file, metavar="OUT.md", help="write the rows as a Markdown report")
    p.add_argument("--quick", action="store_true", help="fewer settings and a shorter run (CI size): 2.5 s, or less "
                   "where the reference or Radau would be slow (timed over the first 2 ms, docs/fidelity.md); "
                   "reference CVODES rtol 1e-10")
    p.add_argument("--stop", type=float, metavar="SECONDS", help="the run's horizon, from 1 ms to the scene's stop "
                   "time (5 s); default 5 s, or --quick's")
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


def _quiet_numerics() -> np.errstate:
    """A context with numpy's floating-point warnings off (``length = 1e-300`` overflows in the shape functions).

    A command's answer is its output or its one-line error, which the checks that notice a non-finite result
    give (the static equilibrium, the guards, the FMU's refusals); a page of RuntimeWarnings before it helps
    nobody.
    """
    import numpy as np

    return np.errstate(all="ignore")


def _quiet_stdout() -> None:
    """After a closed pipe (``flexlink linearize … | head``): point stdout at /dev/null.

    So that the interpreter's last flush does not raise again at exit.
    """
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def main(argv: list[str] | None = None) -> int:
    """Run the ``flexlink`` command line and return its exit status.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after ``flexlink``; ``sys.argv[1:]`` if None.

    Returns
    -------
    int
        0 on success; 2 for bad input of any kind (a :class:`~flexlink.errors.FlexlinkError`, printed as one
        line, or a usage error); 141 when the reader of stdout went away (``| head``); 130 on Ctrl-C.  A
        sub-command may return its own status (``flexlink check``: 1 for findings).
    """
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
