"""win64 binaries (``--platforms linux64,win64``), and the proof that they run: one C host
(tests/c/cross_host.c) compiled with gcc and cross-compiled with MinGW-w64 drives the linux64 ``.so`` natively
and the win64 ``.dll`` under Wine through the same Co-Simulation and Model Exchange sequences; the two print
the bits of every variable at every communication point, which must agree to 1e-12 of each variable's
largest magnitude in the run.  An FMU state serialised by one platform's library and restored by the other's
must continue as the original did.

Needs ``x86_64-w64-mingw32-gcc`` (Debian: gcc-mingw-w64-x86-64) and Wine (wine64 and wine); skipped with the
reason when they are missing, installed by .ci/run in CI.  Wine runs in a private prefix in a temporary
folder (created on the first run, about 15 s), removed at the end."""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu

from flexlink.errors import BuildError
from flexlink.export import cbuild
from flexlink.export.fmu import build_fmu

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "examples" / "rotating_link.toml"
HOST = ROOT / "tests" / "c" / "cross_host.c"
MINGW = shutil.which(cbuild.MINGW_CC)
WINE = shutil.which("wine64") or shutil.which("wine")     # Debian's wine64 package puts its loader behind `wine`
NO_MINGW = f"{cbuild.MINGW_CC} is not installed (Debian/Ubuntu: apt-get install gcc-mingw-w64-x86-64)"
NO_WINE = "Wine is not installed (Debian/Ubuntu: apt-get install wine64 wine)"
need_mingw = pytest.mark.skipif(MINGW is None, reason=NO_MINGW)
need_wine = pytest.mark.skipif(WINE is None, reason=NO_WINE)

#: A motion that exercises the nonlinear terms: a hub torque (input) and an initial hub rate (parameter).
SETTINGS = {"hub.tau": 0.5, "hub.initial_rate": 1.0}
CS_RUN = ("0.5", "0.01")     # stop time, communication step
ME_RUN = ("0.2", "0.001")    # stop time, the host's Runge-Kutta step
RTOL = 1e-12


# ------------------------------------------------------------------------------------- a missing compiler

def test_win64_without_mingw_is_one_line_and_exit_2(tmp_path):
    """No cross-compiler on PATH: the command says which package to install, before building anything."""
    empty = tmp_path / "bin"
    empty.mkdir()
    res = subprocess.run([sys.executable, "-m", "flexlink.cli", "build", str(SCENE), "-o", str(tmp_path / "x.fmu"),
                          "--platforms", "linux64,win64"], capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, PATH=str(empty)), check=False)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "x86_64-w64-mingw32-gcc" in lines[0] and "gcc-mingw-w64-x86-64" in lines[0]
    assert not (tmp_path / "x.fmu").exists()


def test_unknown_platform_and_missing_cross_compiler_are_build_errors(tmp_path, monkeypatch):
    with pytest.raises(BuildError, match="win32.*linux64, win64"):
        build_fmu(SCENE, tmp_path / "x.fmu", platforms="linux64,win32")
    monkeypatch.setenv("FLEXLINK_MINGW_CC", "no-such-mingw-gcc")
    with pytest.raises(BuildError, match="no-such-mingw-gcc.*gcc-mingw-w64-x86-64"):
        build_fmu(SCENE, tmp_path / "x.fmu", platforms=["win64"])


# ---------------------------------------------------------------------------------------- the win64 FMU

@pytest.fixture(scope="module")
def fmu(tmp_path_factory) -> dict:
    """The example built for both platforms, unzipped, with its model description."""
    if MINGW is None:
        pytest.skip(NO_MINGW)
    d = tmp_path_factory.mktemp("windows")
    path = build_fmu(SCENE, d / "rotating_link.fmu", platforms="linux64,win64").fmu
    with zipfile.ZipFile(path) as z:
        z.extractall(d / "unzipped")
    md = fmpy.read_model_description(str(path))
    ident = md.coSimulation.modelIdentifier
    return {"path": path, "dir": d, "md": md,
            "linux64": d / "unzipped" / "binaries" / "linux64" / f"{ident}.so",
            "win64": d / "unzipped" / "binaries" / "win64" / f"{ident}.dll"}


@need_mingw
def test_fmu_with_win64_binary_is_valid_and_exports_the_fmi_interface(fmu):
    """fmpy accepts the model description; the DLL exports exactly the 44 functions that the standard's
    fmi2Functions.h declares (a host looks them up by name) and needs no MinGW runtime DLL, only Windows'
    own kernel32 and msvcrt."""
    assert validate_fmu(str(fmu["path"])) == []
    with zipfile.ZipFile(fmu["path"]) as z:
        names = set(z.namelist())
    assert {"binaries/linux64/rotating_link.so", "binaries/win64/rotating_link.dll"} <= names
    header = (cbuild.fmi_headers_dir() / "fmi2Functions.h").read_text()
    declared = set(re.findall(r"FMI2_Export\s+\w+TYPE\s+(fmi2\w+)\s*;", header))
    assert len(declared) == 44
    dump = subprocess.run(["x86_64-w64-mingw32-objdump", "-p", str(fmu["win64"])], capture_output=True,
                          text=True, check=True).stdout
    table = dump.split("[Ordinal/Name Pointer] Table", 1)[1]
    exported = set(re.findall(r"^\s*\[\s*\d+\]\s+(\w+)\s*$", table, flags=re.M))
    assert exported == declared
    assert {d.lower() for d in re.findall(r"DLL Name: (\S+)", dump)} == {"kernel32.dll", "msvcrt.dll"}


# ---------------------------------------------------------------------------------- the host and Wine

@pytest.fixture(scope="module")
def hosts(fmu) -> dict[str, Path]:
    """cross_host.c for both platforms (the same source, gcc and MinGW-w64)."""
    out = {"linux64": fmu["dir"] / "cross_host", "win64": fmu["dir"] / "cross_host.exe"}
    flags = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O1", f"-I{cbuild.fmi_headers_dir()}", str(HOST)]
    for cc, exe, libs in ((cbuild.compiler(), out["linux64"], ["-ldl"]), ([MINGW], out["win64"], [])):
        res = subprocess.run([*cc, *flags, "-o", str(exe), *libs], capture_output=True, text=True, check=False)
        assert res.returncode == 0, res.stderr
    return out


@pytest.fixture(scope="module")
def wine_env():
    """A private Wine prefix (so that nothing in ~/.wine is used or changed), quiet; removed afterwards."""
    if WINE is None:
        pytest.skip(NO_WINE)
    with tempfile.TemporaryDirectory(prefix="flexlink-wine-") as prefix:
        env = dict(os.environ, WINEPREFIX=prefix, WINEDEBUG="-all", WINEDLLOVERRIDES="mscoree,mshtml=")
        yield env
        server = shutil.which("wineserver") or "/usr/lib/wine/wineserver64"
        if Path(server).exists():
            subprocess.run([server, "-k"], env=env, capture_output=True, timeout=60, check=False)


def _windows_path(path: Path) -> str:
    """Wine's drive Z: is the Linux root."""
    return "Z:" + str(path).replace("/", "\\")


def run_host(platform: str, fmu: dict, hosts: dict, wine_env: dict | None, mode: str, run: tuple[str, str],
             state: tuple[str, Path] | None = None) -> np.ndarray:
    """One host run on ``platform``; its rows (time, then every variable by value reference) as floats."""
    md = fmu["md"]
    vr = {v.name: v.valueReference for v in md.modelVariables}
    settings = [f"{vr[name]}={value!r}" for name, value in SETTINGS.items()]
    local = platform == "linux64"
    path = (lambda p: str(p)) if local else _windows_path
    extra = [state[0], path(state[1])] if state else []
    args = [mode, path(fmu[platform]), md.guid, str(len(md.modelVariables)), str(len(md.derivatives)), *run,
            *extra, *settings]
    command = [str(hosts["linux64"])] if local else [WINE, str(hosts["win64"])]
    res = subprocess.run([*command, *args], capture_output=True, text=True, timeout=300, check=False,
                         env=None if local else wine_env)
    assert res.returncode == 0, f"{platform} {mode}: exit {res.returncode}\n{res.stderr[-3000:]}"
    rows = [[struct.unpack(">d", bytes.fromhex(w))[0] for w in line.split()] for line in res.stdout.splitlines()
            if line.strip()]
    return np.array(rows)


def assert_same_run(linux: np.ndarray, windows: np.ndarray) -> None:
    """Equal to RTOL of each column's largest magnitude over the run (the time column included)."""
    assert linux.shape == windows.shape and linux.shape[0] > 2
    scale = np.max(np.abs(linux), axis=0)
    worst = np.max(np.abs(linux - windows) - RTOL * scale)
    assert worst <= 0.0, f"differ by more than {RTOL} of the scale: {np.max(np.abs(linux - windows) / scale)}"


def column(fmu: dict, rows: np.ndarray, name: str) -> np.ndarray:
    vr = {v.name: v.valueReference for v in fmu["md"].modelVariables}
    return rows[:, 1 + vr[name]]


@need_mingw
@need_wine
@pytest.mark.parametrize("mode", ["cs", "me"])
def test_win64_under_wine_equals_linux64(fmu, hosts, wine_env, mode):
    run = CS_RUN if mode == "cs" else ME_RUN
    linux = run_host("linux64", fmu, hosts, wine_env, mode, run)
    windows = run_host("win64", fmu, hosts, wine_env, mode, run)
    # the run is not trivial: the hub turns and the arm bends
    assert np.ptp(column(fmu, linux, "hub.theta")) > 0.05
    assert np.max(np.abs(column(fmu, linux, "arm.tip.v"))) > 1e-5
    assert_same_run(linux, windows)


@need_mingw
@need_wine
@pytest.mark.parametrize("saver,loader", [("linux64", "win64"), ("win64", "linux64")])
def test_fmu_state_serialised_on_one_platform_continues_on_the_other(fmu, hosts, wine_env, saver, loader):
    """The saving run goes on to the end; the loading run starts from the saved bytes (its own settings are
    overwritten by the state) and must print the same rows as the saver's continuation."""
    state = fmu["dir"] / f"state-{saver}.bin"
    whole = run_host(saver, fmu, hosts, wine_env, "cs", CS_RUN, ("save", state))
    assert state.stat().st_size > 0
    continued = run_host(loader, fmu, hosts, wine_env, "cs", CS_RUN, ("load", state))
    assert continued[0, 0] > 0.2          # it started in the middle, not from t = 0
    assert_same_run(whole[-len(continued):], continued)
