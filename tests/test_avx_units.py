"""The AVX twins of the Newton iteration's units (fmu_src/avx.h, ``flexlink.export.codegen.avx_units``).

A twin is the same generated C compiled a second time for processors with AVX, and model.c calls it where the
processor has AVX.  It runs the same operations in the same order on the same doubles, so the claim is the
same bits, and the reference is the baseline unit itself: evaluated side by side on random arguments
(tests/c/avx_probe.c), and whole runs of an FMU against the same FMU compiled without its twins
(``FLEXLINK_NO_AVX``), through fmpy.  That those runs did go through the twins is read off the shipped
library's disassembly (model.c's calls reach them, and they are AVX code).  The MinGW-w64 assembly of the
twins must hold no 256-bit register: 64-bit Windows aligns the stack to 16 bytes, and gcc would spill such a
register to a 32-byte aligned slot.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from source_probe import compile_probe

from flexlink.export import cbuild
from flexlink.export.cache import cached_fmu
from flexlink.export.cbuild import compile_shared_library, fmi_headers
from flexlink.export.codegen import generate
from flexlink.mechanics.model import build_model
from flexlink.run.host import FmuHost
from flexlink.scene.loader import load_scene, parse_scene

ROOT = Path(__file__).resolve().parent.parent
PROBE = Path(__file__).resolve().parent / "c" / "avx_probe.c"
CHAIN = ROOT / "examples" / "planar_chain_5.toml"


def _processor_has_avx() -> bool:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return any(re.search(r"\bavx\b", line) for line in text.splitlines() if line.startswith("flags"))


need_avx = pytest.mark.skipif(not _processor_has_avx(), reason="this processor has no AVX: the twins never run")


def _dense_link():
    """One link of 16 Hermite elements reduced to 16 modes: its nodal maps stay dense products
    (points.DENSE_MAP_MIN_ENTRIES), the generated loop the twin compiles too."""
    return parse_scene(dict(
        name="dense_link", gravity=[0.0, 0.0, 0.0],
        joint=[dict(name="hub", axis=[0.0, 0.0, 1.0], inertia=0.01)],
        link=[dict(name="arm", length=1.0, linear_density=2.0, EI=100.0, deformation=["v"],
                   shapes=dict(kind="fe", count=16, modes=16), kinematics="second-order")],
        fmu=dict(step=1e-4)))


def _listed_sources(fmu: Path) -> list[str]:
    """The C files the FMU's description lists for its Co-Simulation interface."""
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    return [f.get("name") for f in root.findall("CoSimulation/SourceFiles/File")]


def _units(fmu: Path) -> list[str]:
    """The units with a twin in an FMU's sources (``<unit>_avx.c``)."""
    with zipfile.ZipFile(fmu) as z:
        return sorted(Path(n).name.removesuffix("_avx.c") for n in z.namelist() if n.endswith("_avx.c"))


@pytest.fixture(scope="module")
def chain_fmu() -> Path:
    return cached_fmu(load_scene(CHAIN))


@pytest.fixture(scope="module")
def dense_fmu() -> Path:
    return cached_fmu(_dense_link())


def test_the_newton_iterations_units_have_twins_listed_with_the_sources(chain_fmu, dense_fmu):
    """planar_chain_5 generates its mass matrix (the Newton matrix takes M from it): the residual and M have
    twins; the 16-mode link takes M from residuals: the residual alone.  The outputs (once a communication
    step) have none.  Every twin is a source file of the description, so that an importer compiles it."""
    assert _units(chain_fmu) == ["planar_chain_5_mass_matrix", "planar_chain_5_residual"]
    assert _units(dense_fmu) == ["dense_link_residual"]
    for fmu in (chain_fmu, dense_fmu):
        assert {f"{u}_avx.c" for u in _units(fmu)} <= set(_listed_sources(fmu))


@need_avx
@pytest.mark.parametrize("which", ["chain_residual", "chain_mass_matrix", "dense_residual"])
def test_a_twin_gives_its_units_bits_on_random_arguments(which, chain_fmu, dense_fmu, tmp_path):
    fmu = chain_fmu if which.startswith("chain") else dense_fmu
    unit = {"chain_residual": "planar_chain_5_residual", "chain_mass_matrix": "planar_chain_5_mass_matrix",
            "dense_residual": "dense_link_residual"}[which]
    _, exe = compile_probe(fmu, PROBE, tmp_path, defines=(f"UNIT={unit}",))
    out = subprocess.run([str(exe), "2000"], check=True, capture_output=True, text=True).stdout
    values, differ, nonfinite = (int(x) for x in re.fullmatch(r"values (\d+) differ (\d+) nonfinite (\d+)\n",
                                                               out).groups())
    assert values >= 2000 * 17              # at least one value per coordinate and argument set
    assert nonfinite == 0
    assert differ == 0


@pytest.mark.skipif(shutil.which("objdump") is None, reason="objdump (binutils) is not installed")
def test_the_shipped_library_calls_the_twins_and_they_are_avx_code(chain_fmu, tmp_path):
    """The linux64 library's disassembly: model_residual and model_newton_matrix's mass matrix reach the twins
    (model.c's dispatch), and AVX's scalar instructions are in it (only the twins are compiled for AVX: the rest
    of the library is SSE2 code)."""
    with zipfile.ZipFile(chain_fmu) as z:
        z.extract("binaries/linux64/planar_chain_5.so", tmp_path)
    text = subprocess.run(["objdump", "-d", "--no-show-raw-insn", str(tmp_path / "binaries/linux64/planar_chain_5.so")],
                          check=True, capture_output=True, text=True).stdout
    bodies = {m.group(1): m.group(2) for m in re.finditer(r"^[0-9a-f]+ <([\w.]+)>:\n(.*?)(?=\n\n|\Z)", text,
                                                          re.MULTILINE | re.DOTALL)}
    assert "<planar_chain_5_residual_avx>" in bodies["model_residual"]
    assert any("<planar_chain_5_mass_matrix_avx>" in body for body in bodies.values())
    assert re.search(r"\bvmulsd\b", bodies["planar_chain_5_residual_avx__f0"])    # the twin's CasADi function
    assert not re.search(r"\bv(mul|add|sub)sd\b", bodies["ss22_step"])   # the generic C: baseline code


def _without_twins(fmu: Path, work: Path) -> Path:
    """A copy of ``fmu`` whose binary is compiled from its own sources with FLEXLINK_NO_AVX."""
    with zipfile.ZipFile(fmu) as z:
        z.extractall(work / "unpacked")
        names = z.namelist()
    src = work / "unpacked" / "sources"
    md = fmpy.read_model_description(str(fmu))
    library = work / "unpacked" / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    for h in fmi_headers(2):
        shutil.copyfile(h, src / h.name)
    compile_shared_library([src / f for f in _listed_sources(fmu)], [src], library,
                           extra_cflags=("-DFLEXLINK_NO_AVX",))
    out = work / "no_avx.fmu"
    with zipfile.ZipFile(out, "w") as z:
        for n in names:
            z.write(work / "unpacked" / n, n)
    return out


def _run(fmu: Path) -> tuple[np.ndarray, int]:
    """1 s of planar_chain_5 at its 1 ms step under a shoulder torque of 0.5 N m (the rows of every output at
    each 10 ms), and the run's ``avx_code``."""
    md = fmpy.read_model_description(str(fmu))
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    rows = []
    with FmuHost(fmu) as host:
        host.initialize({"shoulder.tau": 0.5})
        for k in range(100):
            host.instance.doStep(k * 0.01, 0.01)
            rows.append(host.get_real(outputs))
        stats = host.solver_statistics()
    return np.array(rows), stats["avx_code"]


@need_avx
def test_an_fmu_runs_its_twins_and_runs_as_it_does_without_them(chain_fmu, tmp_path):
    """The statistics log says which code ran; the two runs agree to the bit, and the chain moves."""
    with_twins, used = _run(chain_fmu)
    without, unused = _run(_without_twins(chain_fmu, tmp_path))
    assert (used, unused) == (1, 0)
    assert np.ptp(with_twins[:, 0]) > 0.01
    assert np.array_equal(with_twins, without)


@pytest.mark.skipif(shutil.which(cbuild.MINGW_CC) is None, reason=f"{cbuild.MINGW_CC} is not installed")
@pytest.mark.parametrize("scene", ["chain", "dense"])
def test_the_win64_twins_use_no_256_bit_register(scene, tmp_path):
    """MinGW-w64's assembly of every twin: AVX's scalar instructions (vmulsd), no ymm or zmm register."""
    model = build_model(load_scene(CHAIN) if scene == "chain" else _dense_link())
    gen = generate(model, tmp_path / "sources")
    twins = [p for p in gen.sources if p.name.endswith("_avx.c")]
    assert twins
    for twin in twins:
        asm = tmp_path / f"{twin.stem}.s"
        subprocess.run([cbuild.MINGW_CC, *(f for f in cbuild.CFLAGS if f not in ("-shared", "-fPIC")),
                        f"-I{cbuild.fmu_src_dir()}", f"-I{gen.directory}", "-S", str(twin), "-o", str(asm)],
                       check=True, capture_output=True, text=True)
        text = asm.read_text()
        assert "vmulsd" in text, twin.name
        assert not re.search(r"%[yz]mm\d", text), twin.name
