"""``flexlink sweep``'s command line: its parser, the :class:`~controllers.sweep.SweepSpec` it makes, its run.

Apart from :mod:`controllers.sweep` so that building ``flexlink``'s parser (``flexlink --help``, any other
command) imports neither numpy nor the sweep's machinery: they are imported when ``flexlink sweep`` runs
(tests/test_startup_imports.py).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from controllers.options import SENSORS, add_weight_options, angles
from flexlink.errors import FlexlinkError
from flexlink.paths import SCENE_HELP, OutputPath, check_output_path, output_file, plot_file

if TYPE_CHECKING:
    from controllers.sweep_spec import SweepSpec

__all__ = ["add_sweep_parser", "cmd_sweep", "spec_from_args"]


def add_sweep_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``flexlink sweep`` to ``flexlink``'s sub-parsers.

    Every option that describes the sweep stores under its :class:`SweepSpec` field's name and has no default
    of its own (``argparse.SUPPRESS``): the spec's defaults live in the class, and an option the user did not
    give never overrides the ``--spec`` file.
    """
    p = subparsers.add_parser("sweep", help="parameter grid or Monte Carlo study of the FMU on Dask",
                              argument_default=argparse.SUPPRESS)
    p.add_argument("scene", nargs="?", help=SCENE_HELP + "; optional with --spec (its scene key)")
    p.add_argument("--spec", metavar="FILE.toml", default=None,
                   help="the sweep described in a TOML file (docs/sweeps.md; its keys are run_sweep's "
                        "SweepSpec fields); the command line's options override the file's")
    p.add_argument("--param", dest="params", action="append", metavar="NAME=LO:HI:N",
                   help="FMU parameter: grid axis LO:HI:N, V1,V2,..., or V (repeat for a full grid); with "
                        "--samples: LO:HI (uniform) or V")
    p.add_argument("--samples", type=int, metavar="N", help="Monte Carlo: N seeded draws instead of a grid")
    p.add_argument("--seed", type=int, help="Monte Carlo seed (default 0)")
    p.add_argument("--distribution", dest="distributions", action="append", metavar="NAME=DIST",
                   help="Monte Carlo parameter: uniform:LO:HI, normal:MEAN:STD[:LO:HI], loguniform:LO:HI")
    p.add_argument("--controller", choices=("lqr", "pd"),
                   help="closed loop: the rest-to-rest manoeuvre of `flexlink control` with this controller "
                        "(default lqr when --target or --duration is given)")
    p.add_argument("--target", dest="target_deg", type=angles, metavar="DEG[,DEG...]",
                   help="closed loop: final angle of the first joint; with several torque-driven joints one per "
                        "joint, comma-separated (the MIMO LQG's or, with --controller pd, the joint PD's "
                        "manoeuvre, its stability verdict)")
    p.add_argument("--duration", type=float, metavar="S", help="closed loop: manoeuvre time")
    p.add_argument("--settle", type=float, metavar="S",
                   help="window after the manoeuvre (closed loop) / at the end (open loop) for the residual "
                        "vibration (default 1.5)")
    p.add_argument("--settle-band", type=float, metavar="FRACTION",
                   help="settling-time band, fraction of the commanded angle (default 0.02)")
    add_weight_options(p, "closed loop: saturation and Bryson torque limit of every joint, or one per torque-driven "
                          "joint in scene order, or by joint name (default as flexlink control)")
    p.add_argument("--sensors", choices=SENSORS,
                   help="closed loop: the Kalman sensors, as in flexlink control (default strain)")
    p.add_argument("--stop-time", type=float, metavar="S", help="open loop: run the scene's default inputs")
    p.add_argument("--sample-time", type=float, metavar="S", help="controller sample time / communication step (1 ms)")
    p.add_argument("--series", action="append", metavar="NAME",
                   help="also keep this output's time series (list column series.NAME; repeat)")
    p.add_argument("--series-every", type=int, metavar="K", help="keep every K-th sample (10)")
    _add_scheduling_options(p)
    p.set_defaults(func=cmd_sweep)


def _add_scheduling_options(p: argparse.ArgumentParser) -> None:
    """The options of ``flexlink sweep`` that say where cases run and where their rows go."""
    p.add_argument("--scheduler", metavar="ADDR",
                   help="Dask scheduler address (tcp://host:8786), or 'serial' for a plain loop; "
                        "default: a local cluster, one process per core")
    p.add_argument("--workers", dest="n_workers", type=int, metavar="N",
                   help="local cluster size (default: one per core)")
    p.add_argument("--batch-size", type=int, metavar="N", help="cases per Dask task (default: automatic)")
    p.add_argument("--shared-fs", action="store_const", const=True,
                   help="send the workers the FMU's path (a shared file system) instead of its bytes")
    p.add_argument("--out", type=output_file, metavar="FILE",
                   help="results: FILE.parquet or FILE.csv (required, here or as out in --spec)")
    p.add_argument("--resume", action="store_const", const=True,
                   help="resume FILE's sweep (the default whenever FILE or its journal exists)")
    p.add_argument("--overwrite", action="store_const", const=True,
                   help="discard FILE and its journal and start again")
    p.add_argument("--plot", type=plot_file, default=None, metavar="OUT.png",
                   help="metric vs parameter (grid) or histograms (Monte Carlo)")
    p.add_argument("--no-progress", dest="progress", action="store_const", const=False, help="no progress bar")
    p.add_argument("--case-timeout", type=float, metavar="S",
                   help="wall-clock seconds a case may run; one still running then is a failed row (status "
                        "timeout) and the sweep goes on; timed-out cases are run again on resume")


def _parse_named(items: list[str], option: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise FlexlinkError(f"{option} {item!r}: expected NAME=SPEC")
        if name.strip() in out:
            raise FlexlinkError(f"{option} {name.strip()}: given twice")
        out[name.strip()] = value.strip()
    return out


def spec_from_args(args: argparse.Namespace) -> SweepSpec:
    """The :class:`SweepSpec` of a ``flexlink sweep`` command line: its ``--spec`` file, its options over it.

    A terminal gets a progress bar unless ``--no-progress`` or the file says otherwise; the results file is
    required (on the command line or as the file's ``out``) and its folder is checked before anything runs.
    With ``--spec``, a value :class:`SweepSpec` refuses is named with the file, as :meth:`SweepSpec.from_toml`
    names it, whether the value is the file's or an option's over it (the message names the option too).
    """
    from dataclasses import fields

    from controllers.sweep_spec import SweepSpec, merge_spec, read_spec

    given = {f.name: getattr(args, f.name) for f in fields(SweepSpec) if getattr(args, f.name, None) is not None}
    for name, option in (("params", "--param"), ("distributions", "--distribution")):
        if name in given:
            given[name] = _parse_named(given[name], option)
    if given.get("resume") and given.get("overwrite"):
        raise FlexlinkError("--resume and --overwrite contradict each other")
    values: dict[str, object] = {"progress": None}
    if args.spec is not None:
        values.update(read_spec(Path(args.spec)))
    if "scene" not in given and "scene" not in values:
        raise FlexlinkError("give the scene: flexlink sweep SCENE ..., or scene = \"FILE.toml\" in a --spec file "
                            "(see flexlink sweep --help)")
    values = merge_spec(values, given)
    if values.get("out") is None:
        raise FlexlinkError("--out FILE (or out = \"FILE\" in the --spec file) is required: the sweep's results "
                            "and its journal (see flexlink sweep --help)")
    check_output_path(OutputPath(str(values["out"])), "--out")
    try:
        return SweepSpec(**values)                                      # type: ignore[arg-type]  # types checked
    except FlexlinkError as e:
        if args.spec is None:
            raise
        raise FlexlinkError(f"{Path(args.spec)}: {e}") from None       # as SweepSpec.from_toml names the file


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run ``flexlink sweep``: the sweep, its summary table, and the plot when ``--plot`` asks for one."""
    from controllers.sweep import journal_path, plot_sweep, run_sweep, summary_table

    spec = spec_from_args(args)
    try:
        df = run_sweep(spec)
    except KeyboardInterrupt:
        print(f"flexlink sweep: interrupted; finished cases are in {journal_path(spec.out or '')}: run the same "
              "command again to resume", file=sys.stderr)
        return 130
    wall = df.attrs["wall_s"]
    rate = df.attrs["computed"] / wall if wall > 0 else math.nan
    print(summary_table(df))
    if df.attrs["settings"].get("multijoint"):
        from controllers.montecarlo import stability_summary

        print(stability_summary(df))
    print(f"wrote {spec.out} ({len(df)} rows; journal {df.attrs['journal']}); {df.attrs['computed']} cases in "
          f"{wall:.1f} s ({rate:.1f} cases/s including start-up)")
    if args.plot:
        plot_sweep(df, args.plot, title=Path(spec.scene).stem)
        print(f"wrote {args.plot}")
    return 0
