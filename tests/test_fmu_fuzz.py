"""Parameter and step fuzz of real FMUs in a C host under AddressSanitizer and UBSan (issue 21): random start
values of parameters and solver settings (one in four out of range: NaN, ±inf, negative, subnormal, 1e300),
random inputs and communication steps.  Every call answers within a wall-clock bound, fmi2OK from fmi2DoStep
implies finite outputs and a kinetic energy >= 0, and a refusal leaves the instance usable (fmi2Reset
answers).  The host is tests/c/fuzz_host.c; its library is rebuilt from the FMU's own ``sources/`` with
the sanitizers, as tests/test_fmu_memory.py does.  CI size: 150 cases per FMU (about 30 s with the builds);
``FLEXLINK_FULL=1``: 10 000 per FMU."""

from __future__ import annotations

import os
import subprocess
import zipfile
from pathlib import Path

import fmpy
import pytest

from flexlink.export import cbuild
from flexlink.export.cache import cached_fmu

ROOT = Path(__file__).resolve().parent.parent
SCENES = ["rotating_link", "flexible_pendulum", "steel_beam_raise"]
CASES = 10_000 if os.environ.get("FLEXLINK_FULL") else 150
# wall-clock bound of one call: a doStep takes at most 1e6 internal steps (cs_step.c) of about 10 µs at -O2,
# here unoptimised and sanitised (about 10× slower) on a shared machine: 60 s leaves room, a hang does not pass
CALL_BOUND_S = 60.0
# the whole run's backstop (the host bounds each call itself): every case's calls at their bound, at most
# 8 hours (the full size's 10 000 cases × 20 calls × 60 s would overflow the poll timeout of subprocess)
RUN_BOUND_S = min(CASES * 20 * CALL_BOUND_S, 8 * 3600.0)


def _kinds(md) -> tuple[str, list[str]]:
    kinds, start = [], []
    for v in sorted(md.modelVariables, key=lambda v: v.valueReference):
        if v.causality == "parameter":
            kinds.append("p")
        elif v.causality == "input":
            kinds.append("i")
        elif v.causality == "output":
            kinds.append("k" if v.name == "energy.kinetic" else "o")
        else:
            kinds.append("-")
        start.append(repr(float(v.start)) if v.start is not None else "0")
    return "".join(kinds), start


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    out = d / "fuzz_host"
    cmd = [*cbuild.compiler(), "-std=c99", "-Wall", "-Wextra", "-Werror", *cbuild.SANITIZE_CFLAGS,
           f"-I{cbuild.fmi_headers_dir()}", str(ROOT / "tests" / "c" / "fuzz_host.c"), "-o", str(out), "-ldl", "-lm"]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    return d, out


@pytest.mark.parametrize("name", SCENES)
def test_fuzz_parameters_and_steps(host, name):
    d, exe = host
    fmu = cached_fmu(ROOT / "examples" / f"{name}.toml")
    unzip = d / name
    with zipfile.ZipFile(fmu) as z:
        z.extractall(unzip)
    md = fmpy.read_model_description(str(fmu))
    lib = cbuild.compile_shared_library(sorted((unzip / "sources").glob("*.c")), [unzip / "sources"],
                                        d / f"{name}_asan.so", sanitize=True)
    kinds, start = _kinds(md)
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=1", UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1")
    res = subprocess.run([str(exe), str(lib), md.guid, kinds, str(CASES), "21", str(CALL_BOUND_S), *start],
                         capture_output=True, text=True, env=env, timeout=RUN_BOUND_S, check=False)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    counts = dict(zip(res.stdout.split()[::2], map(int, res.stdout.split()[1::2]), strict=True))
    # the fuzz exercised both sides: runs that stepped and values that were refused
    assert counts["steps_ok"] > 0 and counts["refused_at_initialisation"] + counts["steps_refused"] > 0, res.stdout
