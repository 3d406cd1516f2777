"""The command line against random arguments and mutated scenes (issue 18): every invocation ends with exit
status 0, or 2 with one line on stderr, within a time limit — never a traceback, never a hang.

Arguments are drawn from the real parser (every sub-command and option, the ``controllers`` ones included)
with values good, bad and absurd; scenes are examples/rotating_link.toml with a key deleted, retyped or set
to an edge value, or its text cut short. The commands that build an FMU (``build``, ``control`` without
``--design-only``, ``sweep``, ``demo``, ``bench``, ``explain --error-target``) are left out: what the fuzzing
looks for is a bad-input path, not a long build; ``simulate`` and ``animate`` run on the unchanged scene
only, from an FMU built once into the run's cache. At CI size a few dozen invocations run; ``FLEXLINK_FULL=1`` runs 500
(marked slow). A failure prints the seed and the command line.
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import tomllib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from flexlink.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "rotating_link.toml"
FLEXLINK = [str(Path(sys.executable).with_name("flexlink"))]
if not Path(FLEXLINK[0]).exists():
    FLEXLINK = [sys.executable, "-m", "flexlink.cli"]
# no FMU built but one (see above)
COMMANDS = ("modes", "explain", "linearize", "control", "check", "simulate", "animate")
# The scene contract sets no upper bound on a model's size: shapes.count = 10**6 is a build of hours, a long
# run rather than a bad input, so sizes stay at most 8 here (64 clamped-free modes: explain takes minutes).
SIZES = ("count", "modes", "mesh")
STOP_TIMES = ["0.01", "0.05", "0", "-1", "nan", "inf", "abc", "1e308", ""]       # simulate: short runs or bad
TIMEOUT = 120.0
CI_CASES, FULL_CASES = 24, 500

NUMBERS = ["0", "1", "-1", "0.5", "1e-3", "nan", "inf", "-inf", "1e308", "-0", "5e-324", "abc", "", "1,2", "0x10"]
WORDS = ["hub.inertia=0.2", "hub.inertia=-1", "arm.EI=nan", "nope=1", "=", "hub.tau", "tip.x=1", "a=b=c",
         "arm.tip.v", "hub.theta", "x" * 300, "lqr", "pd", "strain", "tcp://127.0.0.1:1"]


def _paths(tmp: Path) -> list[str]:
    return [str(SCENE), str(tmp / "scene.toml"), str(tmp / "missing.toml"), str(tmp), str(tmp / "no" / "x.png"),
            str(tmp / "out.png"), str(tmp / "out.json"), str(tmp / "out.npz"), str(tmp / "out.xyz"),
            str(tmp / "out.gif"), str(tmp / "not_an_fmu.fmu"), str(tmp / "in.csv"), str(tmp / "bad.csv"), "-", ""]


def _value(rng: random.Random, action: argparse.Action, tmp: Path) -> str:
    if action.choices and rng.random() < 0.7:
        return rng.choice(list(action.choices))
    if action.dest == "stop_time":
        return rng.choice(STOP_TIMES)
    pool = rng.choice([NUMBERS, WORDS, _paths(tmp)])
    return rng.choice(pool)


def random_argv(rng: random.Random, tmp: Path) -> list[str]:
    """A sub-command, its positional arguments (mostly a scene), and a random subset of its options with
    random values; now and then an unknown option or a missing value."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    command = rng.choice(COMMANDS)
    parser = sub[command]
    argv = [command]
    for a in parser._actions:
        if isinstance(a, argparse._HelpAction) or (command == "explain" and a.dest == "error_target"):
            continue
        if not a.option_strings:
            good = str(SCENE) if command in ("simulate", "animate") else str(tmp / "scene.toml")   # one FMU
            argv.append(rng.choice(_paths(tmp)[:4] if rng.random() < 0.3 else [good]))
        elif rng.random() < (0.9 if a.required else 0.35):
            argv.append(rng.choice(a.option_strings))
            if a.nargs != 0:
                argv.append(_value(rng, a, tmp))
    if command == "control" and "--design-only" not in argv:
        argv.append("--design-only")                     # a design, no FMU
    if rng.random() < 0.1:
        argv.insert(rng.randrange(1, len(argv) + 1), rng.choice(["--no-such-option", "-x", "--"]))
    return argv


def mutated_scene(rng: random.Random) -> str:
    """examples/rotating_link.toml with one random change: a key deleted, given another type or an edge value,
    an unknown key added, or the text cut short."""
    text = SCENE.read_text()
    doc = tomllib.loads(text)
    kind = rng.random()
    if kind < 0.15:
        return text[: rng.randrange(len(text))]
    tables = [("", doc), ("joint", doc["joint"][0]), ("link", doc["link"][0]), ("shapes", doc["link"][0]["shapes"])]
    _, table = rng.choice(tables)
    key = rng.choice(list(table))
    edges = [-1.0, 0.0, 1e-300, 1e300, float("nan"), float("inf"), "text", True, [], [1.0, 2.0], {"a": 1}, 10**6,
             -3, 2.5, [0.0, 0.0, 0.0], ["v", "v"], "second-order", "fe", 400]
    if kind < 0.3:
        del table[key]
    elif kind < 0.4:
        table["unknown_key"] = 1.0
    else:
        table[key] = rng.choice(edges)
        if key in SIZES and isinstance(table[key], int) and table[key] > 8:
            table[key] = rng.choice([0, -3, 8])
    return _dump(doc)


def _dump(doc: dict) -> str:
    """A small TOML writer for the scene's shape (top level, [[joint]], [[link]], inline tables)."""
    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if v != v else ("inf" if v == float("inf") else ("-inf" if v == -float("inf") else repr(v)))
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return str(v)

    lines = [f"{k} = {value(v)}" for k, v in doc.items() if not (isinstance(v, list) and v and isinstance(v[0], dict))]
    for k, v in doc.items():
        if isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                lines += ["", f"[[{k}]]", *(f"{a} = {value(b)}" for a, b in item.items())]
    return "\n".join(lines) + "\n"


def run_case(seed: int, tmp_root: Path) -> tuple[int, list[str], subprocess.CompletedProcess[str] | str]:
    rng = random.Random(seed)
    tmp = tmp_root / f"case{seed}"
    tmp.mkdir()
    (tmp / "scene.toml").write_text(mutated_scene(rng) if rng.random() < 0.6 else SCENE.read_text())
    (tmp / "not_an_fmu.fmu").write_text("not a zip\n")
    (tmp / "in.csv").write_text("time,hub.tau\n0,0.1\n0.02,-0.1\n")
    (tmp / "bad.csv").write_text(rng.choice(["time,hub.tau\n0,nan\n", "time\n", "", "x,y\n1,2\n",
                                             "time,hub.tau\n1,0\n0,1\n", "time,hub.tau\n0,1e999\n"]))
    argv = random_argv(rng, tmp)
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_root / "cache"), "MPLBACKEND": "Agg"}
    try:
        result = subprocess.run([*FLEXLINK, *argv], cwd=tmp, env=env, capture_output=True, text=True,
                                timeout=TIMEOUT, check=False)
    except subprocess.TimeoutExpired:
        return seed, argv, f"no answer within {TIMEOUT:.0f} s (a hang)"
    return seed, argv, result


def verdict(result: subprocess.CompletedProcess[str] | str) -> str | None:
    """None if the invocation behaved; else what was wrong."""
    if isinstance(result, str):
        return result
    if "Traceback" in result.stderr or "Traceback" in result.stdout:
        return "a traceback:\n" + result.stderr[-2000:]
    if result.returncode == 0:
        return None
    if result.returncode != 2:
        return f"exit status {result.returncode}:\n{result.stderr[-2000:]}"
    lines = result.stderr.strip().splitlines()
    if len(lines) != 1:
        return f"{len(lines)} lines on stderr:\n{result.stderr[-2000:]}"
    return None


def fuzz(cases: int, tmp_path: Path, first_seed: int = 0) -> None:
    with ThreadPoolExecutor(2) as pool:
        outcomes = list(pool.map(lambda s: run_case(s, tmp_path), range(first_seed, first_seed + cases)))
    failures = [f"seed {seed}: flexlink {' '.join(argv)}\n  {why}" for seed, argv, result in outcomes
                if (why := verdict(result))]
    assert not failures, f"{len(failures)} of {cases} invocations misbehaved:\n" + "\n".join(failures[:10])


def test_fuzz_the_command_line(tmp_path):
    fuzz(CI_CASES, tmp_path)


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("FLEXLINK_FULL"), reason="full size: FLEXLINK_FULL=1")
def test_fuzz_the_command_line_full(tmp_path):
    fuzz(FULL_CASES, tmp_path, first_seed=1000)
