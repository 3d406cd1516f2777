"""An FMU's ``sources/`` build anywhere: strict ISO C99 with every warning an error (gcc, clang, and MinGW-w64 for
Windows), a ``buildDescription.xml`` that fmpy's FMI 3.0 schema accepts and that lists every source file, and
fmpy's own CMake build of the platform binary (``fmpy compile``), whose library simulates like the shipped one."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.model_description import read_build_description

from flexlink.export import cbuild

SCENES = ["rotating_link", "flexible_pendulum"]
STRICT = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2", "-fvisibility=hidden", "-shared"]


@pytest.fixture(scope="module")
def unzipped(example_fmu, tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """scene → (its cached linux64 FMU, that FMU unzipped)."""
    out = {}
    for name in SCENES:
        fmu = example_fmu(name)
        d = tmp_path_factory.mktemp(name)
        with zipfile.ZipFile(fmu) as z:
            z.extractall(d)
        out[name] = (fmu, d)
    return out


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("cc", ["gcc", "clang", cbuild.MINGW_CC])
def test_sources_compile_clean_as_strict_c99(unzipped, tmp_path, name, cc):
    """Every source file that buildDescription.xml lists, with nothing but ``-I sources``: no warning."""
    if shutil.which(cc) is None:
        pytest.skip(f"{cc} is not installed")
    fmu, d = unzipped[name]
    files = read_build_description(fmu)[0].sourceFileSets[0].sourceFiles
    flags = [*STRICT, "-fPIC"] if cc in ("gcc", "clang") else STRICT
    res = subprocess.run([cc, *flags, f"-I{d / 'sources'}", *(str(d / "sources" / f) for f in files),
                          "-o", str(tmp_path / "lib"), "-lm"], capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stderr == "", res.stderr[-4000:]


@pytest.mark.parametrize("name", SCENES)
def test_build_description_lists_every_source_file(unzipped, name):
    """Valid against fmpy's fmi3BuildDescription.xsd; one configuration for the model identifier; its files are
    the modelDescription's SourceFiles of both interfaces and every C file shipped."""
    fmu, d = unzipped[name]
    configurations = read_build_description(fmu, validate=True)
    md = fmpy.read_model_description(str(fmu))
    assert len(configurations) == 1 and len(configurations[0].sourceFileSets) == 1
    assert configurations[0].modelIdentifier == md.coSimulation.modelIdentifier == md.modelExchange.modelIdentifier
    files = configurations[0].sourceFileSets[0].sourceFiles
    assert configurations[0].sourceFileSets[0].language == "C99"
    assert sorted(files) == sorted(p.name for p in (d / "sources").glob("*.c"))
    # fmpy reads an FMI 2.0 FMU's build from <SourceFiles> (both interfaces): the same list
    text = (d / "modelDescription.xml").read_text()
    for interface in ("ModelExchange", "CoSimulation"):
        block = text.split(f"<{interface} ", 1)[1].split(f"</{interface}>", 1)[0]
        assert [line.split('"')[1] for line in block.splitlines() if "<File name=" in line] == files


def test_fmpy_compile_builds_a_binary_that_simulates_like_the_shipped_one(unzipped, tmp_path, monkeypatch):
    """``fmpy compile --all-warnings --warning-as-error`` (its CMake project, Release) replaces the linux64
    binary of a copy; fmpy then simulates both FMUs: the same trajectory to rounding (other compiler flags).
    CMake comes from the test extras (the ``cmake`` wheel, in the environment's bin folder) or the system."""
    monkeypatch.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed (fmpy compile builds with CMake)")
    fmu, _ = unzipped["rotating_link"]
    rebuilt = tmp_path / "rebuilt.fmu"
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(rebuilt, "w") as dst:
        for item in src.infolist():
            if not item.filename.startswith("binaries/"):
                dst.writestr(item, src.read(item))
    res = subprocess.run([sys.executable, "-m", "fmpy.cli", "compile", "--all-warnings", "--warning-as-error",
                          str(rebuilt)], capture_output=True, text=True, timeout=600, check=False)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    with zipfile.ZipFile(rebuilt) as z:
        assert "binaries/linux64/rotating_link.so" in z.namelist()
    kwargs = {"stop_time": 0.5, "output_interval": 0.01, "start_values": {"hub.tau": 0.5, "hub.initial_rate": 1.0},
              "output": ["hub.theta", "arm.tip.v", "tip.y"]}
    shipped = fmpy.simulate_fmu(str(fmu), **kwargs)
    built = fmpy.simulate_fmu(str(rebuilt), **kwargs)
    assert np.ptp(shipped["hub.theta"]) > 0.05 and np.max(np.abs(shipped["arm.tip.v"])) > 1e-5
    for name in kwargs["output"]:
        np.testing.assert_allclose(built[name], shipped[name], rtol=1e-9, atol=1e-12 * np.max(np.abs(shipped[name])))


@pytest.mark.parametrize("level", ["O0", "Og", "O1"])
@pytest.mark.parametrize("cc", ["gcc", "clang", cbuild.MINGW_CC])
def test_a_generated_unit_at_every_optimisation_level_compiles_clean(tmp_path, cc, level):
    """The preamble of a generated unit (fmu_src/templates/unit.c.in) with the optimisation pragma of each level
    a build may choose (the suite itself builds at O0, a default build at O2 or Og): strict C99, no warning, on
    every compiler the sources are shipped for (clang has no ``#pragma GCC optimize`` and would warn)."""
    from flexlink.export.codegen import _optimise_pragma, _template

    if shutil.which(cc) is None:
        pytest.skip(f"{cc} is not installed")
    unit = tmp_path / "unit.c"
    unit.write_text(_template("unit.c.in").substitute(unit="unit", scene="s", optimise=_optimise_pragma(level))
                    + "double unit_twice(double x);\ndouble unit_twice(double x) { return 2.0 * x; }\n")
    assert ("#pragma GCC optimize" in unit.read_text()) == (level != "O2")
    res = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-c", str(unit), "-o",
                          str(tmp_path / "unit.o")], capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stderr == "", res.stderr[-4000:]
