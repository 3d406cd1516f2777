"""Issue 18: paths into nowhere, files that are not FMUs, a reader that goes away — one line and exit status 2
(141 for a closed pipe, as a shell reports a tool ended by SIGPIPE), never a traceback, and never after the
work: every option that names an output file is found by walking the real parser (the applications'
sub-commands included), so a new ``--plot`` that forgets its check fails here.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from flexlink.cli import build_parser
from flexlink.errors import FlexlinkError
from flexlink.paths import check_output_path, film_file, output_file, plot_file, stream_file

ROOT = Path(__file__).resolve().parents[1]
SCENE = "examples/rotating_link.toml"
FLEXLINK = [str(Path(sys.executable).with_name("flexlink"))]
if not Path(FLEXLINK[0]).exists():
    FLEXLINK = [sys.executable, "-m", "flexlink.cli"]


def run(args: list[str], tmp: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp / "cache"), "MPLBACKEND": "Agg"}
    return subprocess.run([*FLEXLINK, *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout, check=False)


def one_line(result: subprocess.CompletedProcess[str], *words: str) -> str:
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr + result.stdout, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert all(w in lines[0] for w in words), (words, lines[0])
    return lines[0]


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def output_options() -> list[tuple[str, str]]:
    """(command, option) for every option whose value is a file the command writes."""
    found = []
    for name, p in _subparsers(build_parser()).items():
        for a in p._actions:
            if a.option_strings and a.type in (output_file, plot_file, film_file, stream_file):
                found.append((name, max(a.option_strings, key=len)))
    return found


# what the other required arguments of a command get, so that only the option under test is wrong
REQUIRED = {"--stop-time": "0.01", "--out": "{tmp}/ok.csv", "--output": "{tmp}/ok.fmu",
            ("animate", "--output"): "{tmp}/ok.gif"}


def test_the_parser_has_the_output_options_we_expect():
    """The walk below finds the output files of the library's and the controllers' commands (the entry point)."""
    found = set(output_options())
    assert {("simulate", "--csv"), ("simulate", "--plot"), ("bench", "--plot"), ("bench", "--report"),
            ("linearize", "--save"), ("control", "--plot"), ("sweep", "--out"), ("sweep", "--plot"),
            ("animate", "--output"), ("animate", "--still")} <= found


@pytest.mark.parametrize(("command", "option"), output_options())
def test_output_into_a_missing_folder_is_refused_before_the_work(tmp_path, command, option):
    p = _subparsers(build_parser())[command]
    args = [command] + ([SCENE] if any(a.dest == "scene" for a in p._actions) else [])
    if any(a.dest == "fmu" for a in p._actions):          # flexlink check: an FMU, which is never opened
        args.append(str(tmp_path / "some.fmu"))
    for a in p._actions:
        flag = max(a.option_strings, key=len) if a.option_strings else None
        if a.required and flag and flag != option:
            args += [flag, REQUIRED.get((command, flag), REQUIRED[flag]).format(tmp=tmp_path)]
    suffix = (".png" if "plot" in option or option == "--still" else ".gif" if command == "animate"
              else ".csv" if command in ("sweep", "simulate") else ".json")
    missing = tmp_path / "no_such_folder" / f"out{suffix}"
    one_line(run([*args, option, str(missing)], tmp_path), option, "does not exist")
    # refused before the work: no FMU built into the private cache, nothing written
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.fmu"))
    assert not any(tmp_path.glob("ok.*"))


@pytest.mark.parametrize(("option", "value", "words"), [
    ("--plot", "{tmp}/x.png/", ["--plot", "names a folder"]),
    ("--csv", "{tmp}", ["--csv", "is a folder"]),
    ("--csv", "/proc/x.csv", ["--csv", "the folder /proc takes no new file"]),
    ("--plot", "{tmp}/x.png/.", ["--plot", "names a folder"]),
], ids=["trailing-slash", "folder", "proc", "dot"])
def test_an_output_that_cannot_be_a_file_is_refused_before_the_run(tmp_path, option, value, words):
    """A name ending in a separator (matplotlib would write ``x.png/.png`` after the run), a folder, and a
    folder whose permission bits let root write but which takes no file (/proc): one line, before the work
    (the walk of 2026-11-29 found the first and the last ending in a traceback after the simulation)."""
    if value.startswith("/proc") and not (Path("/proc").is_dir() and os.access("/proc", os.W_OK)):
        pytest.skip("the case of root, whose permission bits pass /proc (others are refused by those bits)")
    one_line(run(["simulate", SCENE, "--stop-time", "0.01", option, value.format(tmp=tmp_path)], tmp_path), *words)
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.fmu"))


def test_check_junit_into_a_folder_is_refused_before_the_checks(tmp_path):
    """``flexlink check F --junit DIR`` ran every check, then failed in a traceback writing DIR."""
    one_line(run(["check", str(tmp_path / "some.fmu"), "--junit", str(tmp_path)], tmp_path), "--junit",
             "is a folder")


def test_plot_in_an_unknown_format_is_refused(tmp_path):
    one_line(run(["simulate", SCENE, "--stop-time", "0.01", "--plot", str(tmp_path / "x.nosuchformat")], tmp_path),
             "--plot", ".png")


@pytest.mark.parametrize("bad", ["", "folder", "missing/x.csv"])
def test_check_output_path(tmp_path, bad):
    (tmp_path / "folder").mkdir()
    with pytest.raises(FlexlinkError, match="--csv"):
        check_output_path(output_file(str(tmp_path / bad) if bad else ""), "--csv")
    check_output_path(output_file(str(tmp_path / "fine.csv")), "--csv")


def _not_fmus(tmp: Path) -> dict[str, tuple[Path, str]]:
    text = tmp / "text.fmu"
    text.write_text("not a zip archive\n")
    empty = tmp / "empty.fmu"
    empty.write_bytes(b"")
    nomd = tmp / "nomd.fmu"
    with zipfile.ZipFile(nomd, "w") as z:
        z.writestr("binaries/readme.txt", "x")
    badmd = tmp / "badmd.fmu"
    with zipfile.ZipFile(badmd, "w") as z:
        z.writestr("modelDescription.xml", "<fmiModelDescription")
    truncated = tmp / "truncated.fmu"
    with zipfile.ZipFile(truncated, "w") as z:
        z.writestr("modelDescription.xml", "<x/>" * 1000)
    truncated.write_bytes(truncated.read_bytes()[:60])
    return {"text": (text, "not an FMU"), "empty": (empty, "not an FMU"), "no-model-description": (nomd, "no "
            "modelDescription.xml"), "broken-xml": (badmd, "modelDescription.xml"),
            "truncated-zip": (truncated, "not an FMU"), "folder": (tmp, "not a file")}


@pytest.mark.parametrize("case", ["text", "empty", "no-model-description", "broken-xml", "truncated-zip", "folder"])
def test_check_on_a_file_that_is_not_an_fmu(tmp_path, case):
    path, words = _not_fmus(tmp_path)[case]
    one_line(run(["check", str(path), "--no-importers"], tmp_path), str(path), words)


def test_a_closed_pipe_ends_quietly(tmp_path):
    """``flexlink linearize … | head``: the reader is gone before the first line; no BrokenPipeError, no
    'Exception ignored' at exit, status 141 (128 + SIGPIPE)."""
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    proc = subprocess.Popen([*FLEXLINK, "linearize", SCENE], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    proc.stdout.close()                     # the reader goes away at once
    try:
        err = proc.stderr.read()
        status = proc.wait(timeout=120)
    finally:
        proc.kill()
    assert err == "", err
    assert status == 141


def test_build_output_with_a_trailing_slash_is_a_folder(tmp_path):
    """``flexlink build S -o out/``: the FMU goes into the folder out/ (created), not into a file named out."""
    from flexlink.errors import BuildError
    from flexlink.export.fmu import fmu_path

    assert fmu_path(f"{tmp_path}/new/", "arm") == tmp_path / "new" / "arm.fmu" and (tmp_path / "new").is_dir()
    assert fmu_path(tmp_path / "new", "arm") == tmp_path / "new" / "arm.fmu"
    assert fmu_path(tmp_path / "x.fmu", "arm") == tmp_path / "x.fmu"
    (tmp_path / "file").write_text("")
    with pytest.raises(BuildError, match="is a file"):
        fmu_path(f"{tmp_path}/file/", "arm")


@pytest.mark.parametrize("args", [[], ["nosuchcommand"], ["control", SCENE, "--target"], ["sweep", SCENE],
                                  ["modes", SCENE, "--rate", "abc"], ["modes", SCENE, "--rate", "nan"],
                                  ["modes", SCENE, "--rate", "inf"], ["linearize", SCENE, "--no-such-option"]])
def test_usage_errors_are_one_line(tmp_path, args):
    """argparse's own errors too: one line naming the problem and where the help is, not the usage; a
    non-finite ``--rate`` named as such (it was "the static equilibrium did not converge")."""
    words = ["--rate", "finite"] if args and args[-1] in ("nan", "inf") else []
    one_line(run(args, tmp_path), "error:", "--help", *words)


@pytest.mark.parametrize("args", [
    ["simulate", SCENE, "--stop-time", "0.01", "--step", "1e-12"],
    ["simulate", SCENE, "--stop-time", "1", "--step", "5e-324"],
    ["control", SCENE, "--target", "10", "--duration", "1", "--sample-time", "1e-9"],
    ["sweep", SCENE, "--param", "hub.inertia=0.1", "--stop-time", "1", "--sample-time", "1e-9", "--scheduler",
     "serial", "--out", "{tmp}/s.csv"],
], ids=["simulate-1e10-steps", "simulate-subnormal-step", "control-1e9-samples", "sweep-1e9-samples"])
def test_a_run_that_would_not_end_is_refused_before_the_build(tmp_path, args):
    """``--stop-time 0.01 --step 1e-12`` asks for 10¹⁰ communication steps (and fmpy would keep them all):
    refused at once, naming the count, before an FMU is built."""
    result = run([a.format(tmp=tmp_path) for a in args], tmp_path)
    one_line(result, "communication steps", "more than")
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.fmu"))


@pytest.mark.parametrize(("stop", "words"), [
    ("0", ["--stop 0", "> 0"]), ("-1", ["> 0"]), ("nan", ["> 0"]), ("inf", ["> 0"]),
    ("5.5", ["beyond the scene's stop time, 5 s"]), ("1e-4", ["at least 0.001 s"]),
    ("abc", ["--stop", "invalid float value"]),
])
def test_bench_stop_out_of_range_is_one_error(tmp_path, stop, words):
    """``flexlink bench --stop``: the horizon must be from 1 ms to the scene's stop time (the FMU's
    DefaultExperiment, 5 s, which is also the bench's whole manoeuvre); anything else is one line, exit status 2,
    before the model is built (so quickly)."""
    one_line(run(["bench", SCENE, "--stop", stop], tmp_path, timeout=60), *words)


def test_an_output_name_too_long_for_the_file_system(tmp_path):
    one_line(run(["linearize", SCENE, "--save", "x" * 300 + ".json"], tmp_path), "--save", "cannot be written")


def test_numerical_warnings_do_not_bury_the_message(tmp_path):
    """A link 1e-300 m long overflows in the shape functions: the answer is the one line that says what failed,
    not numpy's RuntimeWarnings before it."""
    scene = tmp_path / "tiny.toml"
    scene.write_text((ROOT / SCENE).read_text().replace("length = 2.2 ", "length = 1e-300 "))
    one_line(run(["modes", str(scene)], tmp_path), "did not converge")
