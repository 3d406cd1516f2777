"""win64 binaries (``--platforms linux64,win64``), and the proof that they run: one C host
(tests/c/cross_host.c) compiled with gcc and cross-compiled with MinGW-w64 drives the linux64 ``.so`` natively
and the win64 ``.dll`` under Wine through the same Co-Simulation and Model Exchange sequences; the two print
the bits of every variable at every communication point, which must agree to RTOL of the variable's scale: the
largest magnitude, over the run, of the variables of its unit (so that a quantity that is zero up to rounding,
such as an in-plane joint's out-of-plane moment, is compared on the scale of its kind).  An FMU state
serialised by one platform's library and restored by the other's must continue as the original did.  The FMI 3
FMU (``--fmi 3``) is run the same way by tests/c/cross_host3.c.

The two libraries differ in one respect: MinGW-w64 links its own sincos (x87 fsincos), glibc has another, and
they round a few arguments differently by one unit in the last place.  The 4-coordinate rotating link keeps
that at 1e-16 (RTOL 1e-12); the 17-coordinate flexible pendulum, whose stiff finite-element coordinates
amplify it (as any perturbation of the inputs), agrees within RTOL 1e-8 because SS22 accepts a step only within
its Newton tolerance of the step's solution (tests/test_ss22_numerics.py): a decision that hinged on a rate
measured at the rounding floor once made the two platforms accept different, wrong steps (docs/integrator.md).

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
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

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

#: scene → settings (a motion that exercises the nonlinear terms), RTOL, the Model Exchange run (stop time, the
#: host's Runge-Kutta step), the joint angle and the deflection that show the run is not trivial.
CASES = {
    "rotating_link": ({"hub.tau": 0.5, "hub.initial_rate": 1.0}, 1e-12, ("0.2", "0.001"), "hub.theta", "arm.tip.v"),
    "flexible_pendulum": ({"pivot.initial_angle": -1.2}, 1e-8, ("0.1", "0.0001"), "pivot.theta", "strip.tip.v"),
}
CS_RUN = ("0.5", "0.01")     # stop time, communication step


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
def built(tmp_path_factory) -> Callable[[str], dict]:
    """``built(scene)``: the example built for both platforms (once per module), unzipped, with its model
    description."""
    if MINGW is None:
        pytest.skip(NO_MINGW)
    root = tmp_path_factory.mktemp("windows")
    out: dict[str, dict] = {}

    def get(name: str) -> dict:
        if name not in out:
            d = root / name
            path = build_fmu(ROOT / "examples" / f"{name}.toml", d / f"{name}.fmu", platforms="linux64,win64").fmu
            with zipfile.ZipFile(path) as z:
                z.extractall(d / "unzipped")
            md = fmpy.read_model_description(str(path))
            ident = md.coSimulation.modelIdentifier
            out[name] = {"name": name, "path": path, "dir": d, "md": md,
                         "linux64": d / "unzipped" / "binaries" / "linux64" / f"{ident}.so",
                         "win64": d / "unzipped" / "binaries" / "win64" / f"{ident}.dll"}
        return out[name]
    return get


@need_mingw
def test_fmu_with_win64_binary_is_valid_and_exports_the_fmi_interface(built):
    """fmpy accepts the model description; the DLL exports exactly the 44 functions that the standard's
    fmi2Functions.h declares (a host looks them up by name) and needs no MinGW runtime DLL, only Windows'
    own kernel32 and msvcrt."""
    fmu = built("rotating_link")
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
def hosts(tmp_path_factory) -> dict[str, Path]:
    """cross_host.c for both platforms (the same source, gcc and MinGW-w64)."""
    if MINGW is None:
        pytest.skip(NO_MINGW)
    d = tmp_path_factory.mktemp("hosts")
    out = {"linux64": d / "cross_host", "win64": d / "cross_host.exe"}
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


def run_host(platform: str, fmu: dict, hosts: dict, wine_env: dict, mode: str, run: tuple[str, str],
             state: tuple[str, Path] | None = None) -> np.ndarray:
    """One host run on ``platform`` with the scene's settings; its rows (time, then every variable by value
    reference) as floats."""
    md = fmu["md"]
    vr = {v.name: v.valueReference for v in md.modelVariables}
    settings = [f"{vr[name]}={value!r}" for name, value in CASES[fmu["name"]][0].items()]
    local = platform == "linux64"
    path = str if local else _windows_path
    extra = [state[0], path(state[1])] if state else []
    args = [mode, path(fmu[platform]), md.guid, str(len(md.modelVariables)), str(len(md.derivatives)), *run,
            *extra, *settings]
    command = [str(hosts["linux64"])] if local else [WINE, str(hosts["win64"])]
    res = subprocess.run([*command, *args], capture_output=True, text=True, timeout=600, check=False,
                         env=None if local else wine_env)
    assert res.returncode == 0, f"{platform} {mode}: exit {res.returncode}\n{res.stderr[-3000:]}"
    rows = [[struct.unpack(">d", bytes.fromhex(w))[0] for w in line.split()] for line in res.stdout.splitlines()
            if line.strip()]
    return np.array(rows)


def assert_same_run(fmu: dict, linux: np.ndarray, windows: np.ndarray) -> None:
    """Equal to the scene's RTOL of each variable's scale: the largest magnitude over the run among the
    variables of its unit (the time column on its own)."""
    assert linux.shape == windows.shape and linux.shape[0] > 2
    units = ["time"] + [v.unit or f"{v.name} (no unit)" for v in fmu["md"].modelVariables]
    largest = np.max(np.abs(linux), axis=0)
    scale = np.array([max(largest[k] for k in range(len(units)) if units[k] == u) for u in units])
    rtol = CASES[fmu["name"]][1]
    excess = np.abs(linux - windows) - rtol * scale
    worst = int(np.argmax(np.max(excess, axis=0)))
    differs = np.max(np.abs(linux - windows)[:, worst])
    assert np.max(excess) <= 0.0, f"column {worst} ({units[worst]}) differs by {differs} on a scale of {scale[worst]}"


def assert_moves(fmu: dict, rows: np.ndarray) -> None:
    """The run is not trivial: the joint turns and the link bends."""
    vr = {v.name: v.valueReference for v in fmu["md"].modelVariables}
    _, _, _, angle, deflection = CASES[fmu["name"]]
    assert np.ptp(rows[:, 1 + vr[angle]]) > 0.01
    assert np.max(np.abs(rows[:, 1 + vr[deflection]])) > 1e-5


@need_mingw
@need_wine
@pytest.mark.parametrize("scene", list(CASES))
@pytest.mark.parametrize("mode", ["cs", "me"])
def test_win64_under_wine_equals_linux64(built, hosts, wine_env, scene, mode):
    fmu = built(scene)
    run = CS_RUN if mode == "cs" else CASES[scene][2]
    linux = run_host("linux64", fmu, hosts, wine_env, mode, run)
    windows = run_host("win64", fmu, hosts, wine_env, mode, run)
    assert_moves(fmu, linux)
    assert_same_run(fmu, linux, windows)


@need_mingw
@need_wine
@pytest.mark.parametrize("saver,loader", [("linux64", "win64"), ("win64", "linux64")])
def test_fmu_state_serialised_on_one_platform_continues_on_the_other(built, hosts, wine_env, saver, loader):
    """The saving run goes on to the end; the loading run starts from the saved bytes (its own settings are
    overwritten by the state) and must print the same rows as the saver's continuation."""
    fmu = built("rotating_link")
    state = fmu["dir"] / f"state-{saver}.bin"
    whole = run_host(saver, fmu, hosts, wine_env, "cs", CS_RUN, ("save", state))
    assert state.stat().st_size > 0
    continued = run_host(loader, fmu, hosts, wine_env, "cs", CS_RUN, ("load", state))
    assert continued[0, 0] > 0.2          # it started in the middle, not from t = 0
    assert_same_run(fmu, whole[-len(continued):], continued)


# ------------------------------------------------------------------------------------------------ FMI 3.0

HOST3 = ROOT / "tests" / "c" / "cross_host3.c"


@need_mingw
@need_wine
def test_fmi3_win64_under_wine_equals_linux64_and_the_fmi2_fmu(built, hosts, wine_env, tmp_path):
    """``--fmi 3 --platforms linux64,win64``: tests/c/cross_host3.c (the FMI 3.0 counterpart of cross_host.c, for
    both platforms) runs Co-Simulation and Model Exchange on the x86_64-linux .so and, under Wine, on the
    x86_64-windows .dll; both equal, and equal to the FMI 2 FMU's run of the same scene (the linux64 host)."""
    path = build_fmu(SCENE, tmp_path / "rl3.fmu", platforms="linux64,win64", fmi_version=3).fmu
    with zipfile.ZipFile(path) as z:
        z.extractall(tmp_path / "unzipped")
    md = fmpy.read_model_description(str(path))
    ident = md.coSimulation.modelIdentifier
    exe = {"linux64": tmp_path / "cross_host3", "win64": tmp_path / "cross_host3.exe"}
    flags = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O1", f"-I{cbuild.fmi_headers_dir()}", str(HOST3)]
    for cc, out, libs in ((cbuild.compiler(), exe["linux64"], ["-ldl"]), ([MINGW], exe["win64"], [])):
        res = subprocess.run([*cc, *flags, "-o", str(out), *libs], capture_output=True, text=True, check=False)
        assert res.returncode == 0, res.stderr
    fmu3 = {"linux64": tmp_path / "unzipped" / "binaries" / "x86_64-linux" / f"{ident}.so",
            "win64": tmp_path / "unzipped" / "binaries" / "x86_64-windows" / f"{ident}.dll"}
    vr = {v.name: v.valueReference for v in md.modelVariables}
    settings = [f"{vr[name]}={value!r}" for name, value in CASES["rotating_link"][0].items()]
    fmu2 = built("rotating_link")
    # every Float64 variable in value-reference order, arrays whole: the FMI 2 FMU's values in its order (element
    # k of an array sits at the reference of element 1 plus k - 1: docs/fmi.md) but solver.order (an Enumeration,
    # read with fmi3GetInt64), then time
    assert any(v.shape for v in md.modelVariables)
    floats = sorted((v for v in md.modelVariables if v.type == "Float64"), key=lambda v: v.valueReference)
    refs = ",".join(str(v.valueReference) for v in floats)
    n_values = sum(int(np.prod(v.shape)) if v.shape else 1 for v in floats)
    others = {v.valueReference for v in md.modelVariables if v.type != "Float64"}
    keep = [k for k in range(len(fmu2["md"].modelVariables)) if k not in others]     # FMI 2: reference = position
    assert others == {vr["solver.order"]} and n_values == len(keep) + 1
    fmu2_floats = {**fmu2, "md": SimpleNamespace(modelVariables=[fmu2["md"].modelVariables[k] for k in keep])}
    for mode in ("cs", "me"):
        run = CS_RUN if mode == "cs" else CASES["rotating_link"][2]
        rows = {}
        for platform in ("linux64", "win64"):
            local = platform == "linux64"
            path_of = str if local else _windows_path
            command = [str(exe["linux64"])] if local else [WINE, str(exe["win64"])]
            res = subprocess.run([*command, mode, path_of(fmu3[platform]), md.instantiationToken, refs,
                                  str(n_values), str(md.numberOfContinuousStates), *run, *settings],
                                 capture_output=True, text=True, timeout=600, check=False,
                                 env=None if local else wine_env)
            assert res.returncode == 0, f"{platform} {mode}: exit {res.returncode}\n{res.stderr[-3000:]}"
            rows[platform] = np.array([[struct.unpack(">d", bytes.fromhex(w))[0] for w in line.split()]
                                       for line in res.stdout.splitlines() if line.strip()])
        assert_same_run(fmu2_floats, rows["linux64"][:, :-1], rows["win64"][:, :-1])
        # the variable time is the host's time (the FMU sums its steps: rounding apart), on both platforms
        for platform in ("linux64", "win64"):
            np.testing.assert_allclose(rows[platform][:, -1], rows[platform][:, 0], rtol=0, atol=1e-12)
        fmi2 = run_host("linux64", fmu2, hosts, wine_env, mode, run)
        assert_moves(fmu2, fmi2)
        assert_same_run(fmu2_floats, fmi2[:, [0] + [1 + k for k in keep]], rows["linux64"][:, :-1])
