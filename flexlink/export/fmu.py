"""Export: scene → symbolic model → generated C → modelDescription.xml → compiled, zipped FMU.

The FMU holds ``modelDescription.xml``, ``binaries/linux64/<id>.so`` (and, on request,
``binaries/win64/<id>.dll`` cross-compiled with MinGW-w64) and ``sources/`` (the generic half from
``fmu_src/``, the generated model half, the FMI headers from the installed fmpy and a
``buildDescription.xml``), so that it can be rebuilt elsewhere.  This module builds and packages; the XML
descriptions are :mod:`flexlink.export.description`'s (FMI 2.0) and :mod:`flexlink.export.fmi3`'s
(``fmi_version=3``); an FMI 3 FMU's binaries sit in ``binaries/x86_64-linux`` and ``binaries/x86_64-windows``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from flexlink.errors import BuildError
from flexlink.export.cbuild import (
    FMI_VERSIONS,
    LIBRARY_SUFFIX,
    PLATFORM_FOLDER,
    compile_shared_library,
    compiler,
    fmi_headers,
    fmu_src_dir,
    generic_headers,
    generic_sources,
    parse_platforms,
)
from flexlink.export.codegen import generate
from flexlink.export.description import build_description, model_description
from flexlink.mechanics.model import SymbolicModel, build_model
from flexlink.scene.loader import Scene, load_scene


@dataclass
class BuildReport:
    """What a build made and what it took: the figures ``flexlink build`` prints and the build benchmark fits.

    ``seconds`` holds the time of each stage (model, codegen, compile, package), so that a slow build says
    which stage is slow; ``operations`` and the sizes show how the generated model grows with the scene.
    """

    fmu: Path
    guid: str
    seconds: dict[str, float]      # model, codegen, compile, package
    n_coordinates: int
    operations: int
    generated_c_bytes: int
    fmu_bytes: int


def fmu_path(output: str | os.PathLike, identifier: str) -> Path:
    """Where ``build_fmu`` writes: ``output`` itself, or ``<identifier>.fmu`` in it.

    The latter when ``output`` is an existing folder or ends in a path separator (``-o out/``: a folder,
    created if missing — pathlib would drop the slash and write a file named ``out``).

    Raises
    ------
    BuildError
        For ``out/`` naming an existing file, or a folder where the FMU's file would go.
    """
    text = os.fspath(output)
    path = Path(text)
    if text.endswith(("/", os.sep)):
        if path.exists() and not path.is_dir():
            raise BuildError(f"{text}: is a file, not a folder")
        path.mkdir(parents=True, exist_ok=True)
    if path.is_dir():
        path = path / f"{identifier}.fmu"
    if path.is_dir():
        raise BuildError(f"{path}: is a folder; give the FMU's file name")
    return path


def build_fmu(scene: Scene | str | os.PathLike, output: str | os.PathLike, *, keep_dir: str | None = None,
              model: SymbolicModel | None = None, platforms: str | Sequence[str] = ("linux64",),
              fmi_version: int = 2) -> BuildReport:
    """Export ``scene`` as an FMU (Model Exchange and Co-Simulation) at ``output``.

    An FMI 2.0 FMU, or with ``fmi_version=3`` an FMI 3.0 one; an existing folder as ``output`` receives
    ``<model identifier>.fmu``.  ``platforms`` ("linux64", "win64", or both as a sequence or
    ``"linux64,win64"``) names the binaries compiled from the same sources.  A missing compiler (MinGW-w64 for
    win64) is a BuildError raised before the model is built, so that the user does not wait for code
    generation to learn it.  ``model`` reuses a model already built from the same scene; ``keep_dir`` keeps
    the build folder (generated C, objects) for inspection.

    Raises
    ------
    BuildError
        For an unknown FMI version or platform, a missing compiler, a failed compilation or a bad output path.
    SceneError
        For a scene file that cannot be read or is invalid.
    """
    t0 = time.perf_counter()
    if fmi_version not in FMI_VERSIONS:
        raise BuildError(f"FMI version {fmi_version!r}: choose 2 or 3")
    platforms = parse_platforms(platforms)
    for platform in platforms:
        compiler(platform)
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    output = fmu_path(output, scene.model_identifier)
    model = build_model(scene) if model is None else model
    t1 = time.perf_counter()
    work = Path(keep_dir) if keep_dir else Path(tempfile.mkdtemp(prefix="flexlink-build-"))
    try:
        src = work / "sources"
        if src.exists():
            shutil.rmtree(src)
        gen = generate(model, src)
        t2 = time.perf_counter()
        generic = fmu_src_dir()
        for name in [*generic_sources(fmi_version), *generic_headers(fmi_version)]:
            shutil.copyfile(generic / name, src / name)
        for h in fmi_headers(fmi_version):
            shutil.copyfile(h, src / h.name)
        c_files = [*generic_sources(fmi_version), *(p.name for p in gen.sources)]
        if fmi_version == 3:      # which FMI 3 value references are arrays (flexlink.export.fmi3)
            from flexlink.export.fmi3 import write_layout

            c_files.append(write_layout(model, gen, src))
        (src / "buildDescription.xml").write_text(build_description(gen.identifier, c_files))
        libraries = [work / "binaries" / PLATFORM_FOLDER[fmi_version][platform]
                     / f"{gen.identifier}{LIBRARY_SUFFIX[platform]}" for platform in platforms]
        for platform, library in zip(platforms, libraries, strict=True):
            compile_shared_library([src / f for f in c_files], [src], library, platform=platform)
        t3 = time.perf_counter()
        if fmi_version == 3:
            from flexlink.export.fmi3 import model_description_fmi3  # it builds on this module's pieces

            xml = model_description_fmi3(model, gen)
        else:
            xml = model_description(model, gen, c_files)
        (work / "modelDescription.xml").write_text(xml)
        output.parent.mkdir(parents=True, exist_ok=True)
        tmp = output.with_suffix(f"{output.suffix}.{os.getpid()}.part")   # unique: concurrent builders
        try:
            with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
                z.write(work / "modelDescription.xml", "modelDescription.xml")
                for library in libraries:
                    z.write(library, library.relative_to(work).as_posix())
                for f in sorted(src.iterdir()):
                    z.write(f, f"sources/{f.name}")
            tmp.replace(output)
        finally:
            tmp.unlink(missing_ok=True)
        t4 = time.perf_counter()
        generated_bytes = sum(p.stat().st_size for p in gen.generated)
        return BuildReport(output, gen.guid, {"model": t1 - t0, "codegen": t2 - t1, "compile": t3 - t2,
                                              "package": t4 - t3}, model.n_q, gen.operations,
                           generated_bytes, output.stat().st_size)
    finally:
        if not keep_dir:
            shutil.rmtree(work, ignore_errors=True)
