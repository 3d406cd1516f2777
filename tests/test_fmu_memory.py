"""Real generated FMUs (generic glue + CasADi code) through a full run in a small C host
(tests/c/fmu_run.c): under valgrind, and rebuilt from the FMU's own ``sources/`` with AddressSanitizer and
UBSan.  No leak, no invalid access, and the run reproduces itself after an FMU-state round trip."""

from __future__ import annotations

import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import fmpy
import pytest

from flexlink.export import cbuild
from flexlink.export.cache import cached_fmu

ROOT = Path(__file__).resolve().parent.parent
SCENES = ["rotating_link", "steel_beam_raise", "flexible_pendulum"]


def _host(directory: Path, sanitize: bool) -> Path:
    out = directory / ("fmu_run_asan" if sanitize else "fmu_run")
    flags = list(cbuild.SANITIZE_CFLAGS) if sanitize else ["-O1", "-g"]
    cmd = [*cbuild.compiler(), "-std=c99", "-Wall", "-Wextra", "-Werror", *flags, f"-I{cbuild.fmi_headers_dir()}",
           str(ROOT / "tests" / "c" / "fmu_run.c"), "-o", str(out), "-ldl"]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    return out


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("memory")
    out = {"dir": d, "host": _host(d, False), "host_asan": _host(d, True)}
    for name in SCENES:
        fmu = cached_fmu(ROOT / "examples" / f"{name}.toml")
        unzip = d / name
        with zipfile.ZipFile(fmu) as z:
            z.extractall(unzip)
        md = fmpy.read_model_description(str(fmu))
        sources = [unzip / "sources" / f.name for f in md.coSimulation.sourceFiles] \
            if hasattr(md.coSimulation, "sourceFiles") and md.coSimulation.sourceFiles \
            else sorted((unzip / "sources").glob("*.c"))
        asan = cbuild.compile_shared_library(sources, [unzip / "sources"], d / f"{name}_asan.so", sanitize=True)
        out[name] = (unzip / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so", asan, md)
    return out


def _args(md, lib):
    return [str(lib), md.guid, str(len(md.modelVariables)), "0.2", "0.01"]


@pytest.mark.parametrize("name", SCENES)
def test_full_run_under_valgrind(built, name):
    if shutil.which("valgrind") is None:
        pytest.skip("valgrind is not installed (apt-get install valgrind)")
    lib, _, md = built[name]
    cmd = ["valgrind", "-q", "--error-exitcode=1", "--leak-check=full", "--errors-for-leak-kinds=definite,indirect",
           str(built["host"]), *_args(md, lib)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-4000:]


@pytest.mark.parametrize("name", SCENES)
def test_full_run_with_sanitizers_matches_the_shipped_binary(built, name):
    lib, asan, md = built[name]
    plain = subprocess.run([str(built["host"]), *_args(md, lib)], capture_output=True, text=True, timeout=120)
    assert plain.returncode == 0, plain.stderr
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=1", UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1")
    res = subprocess.run([str(built["host_asan"]), *_args(md, asan)], capture_output=True, text=True, timeout=300,
                         env=env, check=False)
    assert res.returncode == 0, res.stderr[-4000:]
    # rebuilt from sources/ (at -O1, with checks), the run gives the shipped binary's values to rounding
    a = [float(line.split()[1]) for line in plain.stdout.splitlines()]
    b = [float(line.split()[1]) for line in res.stdout.splitlines()]
    assert a == pytest.approx(b, rel=1e-9, abs=1e-12)
