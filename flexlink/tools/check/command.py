"""``flexlink check FMU``: the command line (options, bad input, output formats, exit status).

Exit status: 0 no error finding (warnings allowed, unless ``--strict``); 1 an error finding (or, with
``--strict``, a warning); 2 bad input (no such file, not an FMI 2.0 or 3.0 FMU, an interface it lacks, a bad
option), reported in one line.  An FMI 3.0 FMU gets every check through fmpy's FMI 3 support
(``fmu.Fmi3AsFmi2``), with FMI 3.0's own rules where they differ, but libcosim (FMI 1.0 and 2.0 only),
reported as skipped.  ``--platform win64`` checks the FMU's Windows DLL under Wine instead of its Linux binary
(:mod:`.win64`); without Wine or the MinGW-w64 cross-compiler it is bad input (one line, exit status 2).
"""

from __future__ import annotations

import json
import math
import os
import zipfile

from flexlink.errors import FlexlinkError
from flexlink.paths import output_file
from flexlink.tools.check.driver import CALL_LIMIT, CI_FUZZ, NAMES, check_fmu
from flexlink.tools.check.report import as_json, passed, totals, write_junit, write_report


def _names(text: str | None, option: str) -> list[str] | None:
    if text is None:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in NAMES]
    if unknown or not names:
        raise FlexlinkError(f"{option} {text}: unknown check {', '.join(unknown) or '(none)'}; the checks are "
                            + ", ".join(NAMES))
    return names


def _validate(args) -> tuple[str, ...]:
    """Bad input as one FlexlinkError line; returns the interfaces to check."""
    import fmpy

    if not os.path.exists(args.fmu):
        raise FlexlinkError(f"{args.fmu}: no such file")
    if not os.path.isfile(args.fmu):
        raise FlexlinkError(f"{args.fmu}: is not a file; expected an FMU (.fmu)")
    if not zipfile.is_zipfile(args.fmu):
        raise FlexlinkError(f"{args.fmu}: not an FMU (not a zip archive)")
    with zipfile.ZipFile(args.fmu) as z:
        members = set(z.namelist())
    if "modelDescription.xml" not in members:
        raise FlexlinkError(f"{args.fmu}: not an FMU (no modelDescription.xml)")
    try:
        md = fmpy.read_model_description(args.fmu, validate=False)
    except Exception as e:                      # lxml's syntax errors, fmpy's own, ...
        raise FlexlinkError(f"{args.fmu}: unreadable modelDescription.xml: {str(e).splitlines()[0]}") from None
    if md.fmiVersion not in ("2.0", "3.0"):
        raise FlexlinkError(f"{args.fmu}: FMI {md.fmiVersion}; flexlink check supports FMI 2.0 and 3.0")
    for option, value in (("--me-vs-cs-stop", args.me_vs_cs_stop), ("--tolerance", args.tolerance),
                          ("--call-timeout", args.call_timeout)):
        if value is not None and not (0.0 < value < math.inf):
            raise FlexlinkError(f"{option} {value}: must be a positive number" +
                                (" of seconds" if option != "--tolerance" else ""))
    if args.fuzz < 0:
        raise FlexlinkError(f"--fuzz {args.fuzz}: must be 0 or more")
    wanted = {"cs": ("CS",), "me": ("ME",), "both": ("CS", "ME")}[args.interface]
    declared = {"CS": md.coSimulation, "ME": md.modelExchange}
    present = tuple(k for k in wanted if declared[k] is not None)
    if not present:
        raise FlexlinkError(f"{args.fmu}: has no {' or '.join(wanted)} interface to check")
    if getattr(args, "platform", "linux64") == "win64":
        from flexlink.tools.check import win64

        reason = win64.missing()
        if reason is not None:
            raise FlexlinkError(f"{args.fmu}: {reason}")
        try:
            win64.dll_members(members, md.fmiVersion, {declared[k].modelIdentifier for k in present})
        except FlexlinkError as e:
            raise FlexlinkError(f"{args.fmu}: {e}") from None
        return present
    for k in present:
        folder = fmpy.platform_tuple if md.fmiVersion == "3.0" else fmpy.platform
        binary = f"binaries/{folder}/{declared[k].modelIdentifier}{fmpy.sharedLibraryExtension}"
        if binary not in members:
            raise FlexlinkError(f"{args.fmu}: no {binary}: flexlink check runs the FMU's binary for this platform"
                                + (" (its win64 binary: --platform win64)" if any("/win64/" in m or
                                   "/x86_64-windows/" in m for m in members) else ""))
    return present


def run_check(args) -> int:
    """``flexlink check``; see the module docstring for the exit status."""
    interfaces = _validate(args)
    only, skip = _names(args.only, "--only"), _names(args.skip, "--skip")
    try:
        results = check_fmu(args.fmu, fuzz=args.fuzz, seed=args.seed, importers=not args.no_importers,
                            stop_time=args.me_vs_cs_stop, tolerance=args.tolerance, interfaces=interfaces,
                            only=only, skip=skip, call_limit=args.call_timeout or CALL_LIMIT,
                            platform=getattr(args, "platform", "linux64"))
    except (OSError, zipfile.BadZipFile) as e:          # an FMU that cannot be extracted, ...
        raise FlexlinkError(f"{args.fmu}: {type(e).__name__}: {e}") from None
    ok = passed(results, args.strict)
    if args.json:
        print(json.dumps(as_json(results, args.fmu, args.strict), indent=2))
    else:
        for r in results:
            n_errors, n_warnings = r.counts()
            counts = f" [{n_errors} error(s), {n_warnings} warning(s)]" if r.findings else ""
            print(f"{r.status.upper():5s} {r.name:24s} {r.result}{counts}  ({r.seconds:.1f} s)")
            for x in r.findings[:10]:
                print(f"      {x.line()}")
                if x.sequence:
                    print(f"        calls: {' ; '.join(x.sequence[-4:])}")
                if x.reproduce:
                    print(f"        reproduce: {x.reproduce}")
        errors, warnings = totals(results)
        print(f"{'passed' if ok else 'FAILED'}: {errors} error(s), {warnings} warning(s)"
              + (" (--strict: warnings count)" if args.strict else ""))
    if args.report:
        j, m = write_report(results, args.report, args.fmu, args.strict)
        if not args.json:
            print(f"report: {m}, {j}")
    if args.junit:
        write_junit(results, args.junit, args.fmu)
    return 0 if ok else 1


def add_parser(sub) -> None:
    """The ``check`` subcommand and its options, on the CLI's subparsers ``sub``."""
    p = sub.add_parser("check", help="FMU compliance harness: validation, ME vs CS, fuzzing, illegal calls, FMU "
                                     "state, directional derivatives, independent importers (docs/check.md)")
    p.add_argument("fmu", metavar="FMU", help="the FMU file to check")
    p.add_argument("--report", metavar="DIR", help="write report.md and report.json to DIR")
    p.add_argument("--json", action="store_true", help="print the results as JSON instead of text")
    p.add_argument("--junit", metavar="FILE", type=output_file,
                   help="write JUnit XML (one test case per check) to FILE")
    p.add_argument("--only", metavar="CHECKS", help="comma-separated checks to run: " + ", ".join(NAMES))
    p.add_argument("--skip", metavar="CHECKS", help="comma-separated checks not to run")
    p.add_argument("--interface", choices=["cs", "me", "both"], default="both",
                   help="interfaces to check (default: both, those the FMU declares)")
    p.add_argument("--strict", action="store_true", help="warnings fail the run too (exit status 1)")
    p.add_argument("--tolerance", type=float, metavar="REL",
                   help="ME vs CS tolerance, max |ME - CS| / peak per output (default: flexlink FMUs their own; "
                        "other FMUs: measured, not judged)")
    p.add_argument("--call-timeout", type=float, metavar="SECONDS",
                   help=f"an FMI call taking longer is reported as not returning (default {CALL_LIMIT:g})")
    p.add_argument("--fuzz", type=int, default=CI_FUZZ, metavar="N",
                   help=f"random legal call sequences (default {CI_FUZZ}; full size: 5000)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the fuzzing (default 0)")
    p.add_argument("--me-vs-cs-stop", type=float, metavar="SECONDS",
                   help="length of the ME vs CS comparison (default: the FMU's stop time, at most 0.5 s for "
                        "flexlink FMUs, 10 s for others)")
    p.add_argument("--no-importers", action="store_true", help="skip libcosim and fmutool")
    p.add_argument("--platform", choices=["linux64", "win64"], default="linux64",
                   help="the FMU's binary to check (default linux64); win64: its DLL under Wine, through "
                        "flexlink's call server (needs wine64 and x86_64-w64-mingw32-gcc; docs/check.md)")
    p.set_defaults(func=run_check)
