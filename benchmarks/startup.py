"""Fixed start-up of every ``flexlink`` command (issue 22: ≤ 1 s): imports and set-up before the work.

    python benchmarks/startup.py [--repeats N] [--baseline DIR] [--json] [--write [PAGE]]

Each command runs in ``--repeats`` fresh processes (default 7), the commands alternated round-robin in the
same run so that the machine's load falls on all of them alike, after one untimed run of each that fills the
FMU build cache and the design cache.  What is timed is the wall time from starting the process to

* the first load of an FMU's binary (``ctypes.CDLL`` of a file under an FMU's ``binaries/``: fmpy's
  instantiation, the first FMU call) for the commands that run an FMU (``simulate``, ``control``), or
* the process's exit for the others (``--help``, ``modes``, ``explain --estimate``, ``linearize``: their
  whole run, work included).

``control`` is timed from the design cache (a repeated command) and with it off (``FLEXLINK_DESIGN_CACHE=0``:
the linearisation and the LQR/Kalman design, SciPy's Riccati solvers in :mod:`controllers.riccati`), for one
joint (also with ``--json``, whose margins import python-control after the first FMU call) and for two.
The table gives the median, the spread, the whole run's median (process start to exit: what the user waits
for, the closed-loop run included) and which of the heavy modules the command imported
(``python -X importtime`` of one more run: numpy, fmpy, CasADi, SciPy, python-control, matplotlib).

``--baseline DIR`` times the same commands from another checkout too (``mkdir DIR && git archive COMMIT |
tar -x -C DIR && echo COMMIT > DIR/COMMIT``: its ``flexlink`` and ``controllers`` are imported from DIR, the
interpreter and packages are this one's), each of its runs right after this tree's, and adds its medians
and the ratios of the same run: a change's before and after under the same load.

The timed processes write and use Python's bytecode caches as an installed package does
(``PYTHONDONTWRITEBYTECODE`` is cleared for them; the untimed run writes the caches): with it set and no
``__pycache__`` yet, every run would compile flexlink's own sources again, ~0.2 s that no user pays twice.

``--write`` puts the table into docs/performance.md between ``<!-- startup:begin -->`` and
``<!-- startup:end -->`` (or into PAGE): the figures there come from this command, never typed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "performance.md"
BEGIN, END = "<!-- startup:begin -->", "<!-- startup:end -->"
SCENE = "examples/rotating_link.toml"
TWO_JOINTS = ["examples/two_link_payload.toml", "--target", "60,20", "--duration", "1.5", "--torque-limit", "60"]
MARK = "FLEXLINK_STARTUP_FIRST_FMU_LOAD"

# a process that runs `flexlink ARGS` and says on stderr when it first loads an FMU's binary
_PRELUDE = f"""
import ctypes, sys
_init = ctypes.CDLL.__init__
def _first(self, name, *a, **k):
    if name and "binaries" in str(name).replace("\\\\", "/").split("/"):
        print("{MARK}", file=sys.stderr, flush=True)
        ctypes.CDLL.__init__ = _init
    _init(self, name, *a, **k)
ctypes.CDLL.__init__ = _first
from flexlink.cli import main
sys.exit(main(sys.argv[1:]))
"""

IMPORT = "--python-code"      # a row whose process runs this code instead of ``flexlink``

#: (label, arguments after ``flexlink`` (or IMPORT and the code to run), until: "fmu" for the first FMU load,
#: "exit" for the whole run, environment additions)
COMMANDS: list[tuple[str, list[str], str, dict[str, str]]] = [
    ("flexlink --help", ["--help"], "exit", {}),
    ("flexlink check --help", ["check", "--help"], "exit", {}),
    ("flexlink control --help", ["control", "--help"], "exit", {}),
    ("flexlink modes", ["modes", SCENE], "exit", {}),
    ("flexlink explain --estimate", ["explain", SCENE, "--estimate"], "exit", {}),
    ("flexlink simulate", ["simulate", SCENE, "--stop-time", "1", "--step", "1e-3"], "fmu", {}),
    ("flexlink control (design cache)", ["control", SCENE, "--target", "90", "--duration", "1.5"], "fmu", {}),
    ("flexlink control (designing)", ["control", SCENE, "--target", "90", "--duration", "1.5"], "fmu",
     {"FLEXLINK_DESIGN_CACHE": "0"}),
    ("flexlink control --json (designing)", ["control", SCENE, "--target", "90", "--duration", "1.5", "--json"],
     "fmu", {"FLEXLINK_DESIGN_CACHE": "0"}),
    ("flexlink control, two joints (designing)", ["control", *TWO_JOINTS], "fmu", {"FLEXLINK_DESIGN_CACHE": "0"}),
    ("flexlink linearize", ["linearize", SCENE, "--output", "hub.theta"], "exit", {}),
    # not a command: what the designing command cannot go below, python-control's own import (with numpy's)
    ("python -c 'import control'", [IMPORT, "import numpy, control"], "exit", {}),
]

HEAVY = ("numpy", "fmpy", "casadi", "scipy", "control", "matplotlib")


def _environment(env: dict[str, str]) -> dict[str, str]:
    """The timed process's environment: this one's with ``env`` added, bytecode caches allowed."""
    out = {**os.environ, **env}
    out.pop("PYTHONDONTWRITEBYTECODE", None)
    return out


def timed_run(args: list[str], until: str, env: dict[str, str], root: Path = ROOT) -> tuple[float, float]:
    """Seconds from starting ``flexlink ARGS`` to its first FMU load (``until="fmu"``) or to its exit, and to
    its exit.

    The process runs in ``root``, whose ``flexlink`` and ``controllers`` it imports (``python -c`` puts the
    working directory first on ``sys.path``).
    """
    argv = [sys.executable, "-c", args[1]] if args[0] == IMPORT else [sys.executable, "-c", _PRELUDE, *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=_environment(env))
    seen = None
    for line in proc.stderr:
        if seen is None and line.startswith(MARK):
            seen = time.perf_counter() - t0
    status = proc.wait()
    total = time.perf_counter() - t0
    if status != 0:
        raise SystemExit(f"flexlink {' '.join(args)} exited with status {status}")
    if until == "fmu":
        if seen is None:
            raise SystemExit(f"flexlink {' '.join(args)} never loaded an FMU")
        return seen, total
    return total, total


def heavy_imports(args: list[str], env: dict[str, str], root: Path = ROOT) -> str:
    """The heavy top-level packages one run imports (``-X importtime``), those imported after its first FMU
    load after a ``;`` (``"numpy, fmpy; control"``: python-control only once the FMU runs)."""
    code = [args[1]] if args[0] == IMPORT else [_PRELUDE, *args]
    res = subprocess.run([sys.executable, "-X", "importtime", "-c", *code], cwd=root,
                         capture_output=True, text=True, env=_environment(env))
    before: set[str] = set()
    after: set[str] = set()
    seen = before
    for line in res.stderr.splitlines():        # importtime's lines and the mark, in the order they happened
        if line.startswith(MARK):
            seen = after
        elif line.startswith("import time:"):
            seen.add(line.split("|")[2].strip())
    text = ", ".join(m for m in HEAVY if m in before) or "–"
    later = [m for m in HEAVY if m in after and m not in before]
    return text + ("; after it: " + ", ".join(later) if later else "")


def measure(repeats: int, baseline: Path | None = None) -> dict:
    """Every command: an untimed run, then ``repeats`` timed runs round-robin; medians, spreads, imports.

    With ``baseline``, each timed run of a command is followed by one from that checkout.
    """
    load0 = os.getloadavg()[0]
    roots = [ROOT] if baseline is None else [ROOT, baseline]
    for _, args, until, env in COMMANDS:
        for root in roots:
            timed_run(args, until, env, root)          # fills the FMU and design caches
    times: dict[Path, list[list[tuple[float, float]]]] = {r: [[] for _ in COMMANDS] for r in roots}
    for _ in range(repeats):
        for k, (_, args, until, env) in enumerate(COMMANDS):
            for root in roots:
                times[root][k].append(timed_run(args, until, env, root))
    rows = []
    for k, (label, args, until, env) in enumerate(COMMANDS):
        ts = [t for t, _ in times[ROOT][k]]
        row = {"command": label, "arguments": args, "until": until, "median_s": statistics.median(ts),
               "min_s": min(ts), "max_s": max(ts), "whole_s": statistics.median(w for _, w in times[ROOT][k]),
               "imports": heavy_imports(args, env)}
        if baseline is not None:
            row["baseline_median_s"] = statistics.median(t for t, _ in times[baseline][k])
            row["baseline_whole_s"] = statistics.median(w for _, w in times[baseline][k])
            row["baseline_imports"] = heavy_imports(args, env, baseline)
        rows.append(row)
    return {"date": time.strftime("%Y-%m-%d"), "machine": platform.machine(), "repeats": repeats,
            "load_start": load0, "load_end": os.getloadavg()[0], "rows": rows,
            "baseline": None if baseline is None else _describe(baseline)}


def _describe(checkout: Path) -> str:
    """What ``checkout`` is: the commit in its ``COMMIT`` file (write it when exporting), else its folder's name."""
    stamp = checkout / "COMMIT"
    return stamp.read_text().strip() if stamp.is_file() else checkout.name


def markdown(data: dict) -> str:
    """The table of ``data`` (from :func:`measure`) between the page's markers."""
    base = data.get("baseline")
    lines = [BEGIN, "<!-- generated by `python benchmarks/startup.py --write`: edit it, not this block -->", "",
             f"Measured {data['date']} on {data['machine']} (`python benchmarks/startup.py --repeats "
             f"{data['repeats']}" + (" --baseline DIR" if base else "") + "`): wall time from starting the process, "
             f"median of {data['repeats']} fresh processes per command, the commands alternated; load average "
             f"{data['load_start']:.1f} at the start, {data['load_end']:.1f} at the end (2 cores). Scene `{SCENE}`, "
             "FMU, design and bytecode caches filled. *Whole run*: to the process's exit (the closed-loop run "
             "included)."
             + (f" *Before*: commit `{base}`, each of its runs alternated with this tree's." if base else ""), ""]
    head = "| command | until | median [s] (target ≤ 1) | range [s] | whole run [s] |"
    rule = "| --- | --- | --- | --- | --- |"
    if base:
        head += " before: median, whole run [s] | after / before |"
        rule += " --- | --- |"
    lines += [head + " heavy imports (before the first FMU call; after it) |", rule + " --- |"]
    for r in data["rows"]:
        until = "first FMU call" if r["until"] == "fmu" else "exit (whole run)"
        line = (f"| `{r['command']}` | {until} | {r['median_s']:.2f} | {r['min_s']:.2f}–{r['max_s']:.2f} | "
                f"{r['whole_s']:.2f} |")
        if base:
            line += (f" {r['baseline_median_s']:.2f}, {r['baseline_whole_s']:.2f} | "
                     f"{r['median_s'] / r['baseline_median_s']:.2f} |")
        lines.append(line + f" {r['imports']} |")
    lines.append(END)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--baseline", type=Path, metavar="DIR",
                    help="also time a checkout of an earlier commit (git archive COMMIT | tar -x -C DIR; DIR/COMMIT "
                         "names it), alternated with this tree's runs")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--write", nargs="?", const=str(PAGE), metavar="PAGE",
                    help="write the table into PAGE (default docs/performance.md) between its startup markers")
    args = ap.parse_args(argv)
    data = measure(args.repeats, args.baseline)
    if args.json:
        print(json.dumps(data))
        return
    block = markdown(data)
    print(block)
    if args.write:
        from report import rewrite_readme  # the block rewriter of benchmarks/report.py

        rewrite_readme(Path(args.write), block, BEGIN, END)


if __name__ == "__main__":
    main()
