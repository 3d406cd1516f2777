"""Export: scene → symbolic model → generated C → modelDescription.xml → compiled, zipped FMU.

The FMU holds ``modelDescription.xml``, ``binaries/linux64/<id>.so`` (and, on request,
``binaries/win64/<id>.dll`` cross-compiled with MinGW-w64) and ``sources/`` (the generic half from
``fmu_src/``, the generated model half, the FMI headers from the installed fmpy and a
``buildDescription.xml``), so that it can be rebuilt elsewhere.  This module builds and packages; the XML
descriptions are :mod:`flexlink.export.description`'s (FMI 2.0) and :mod:`flexlink.export.fmi3`'s
(``fmi_version=3``); an FMI 3 FMU's binaries sit in ``binaries/x86_64-linux`` and ``binaries/x86_64-windows``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import shutil
import tempfile
import time
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import flexlink
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
from flexlink.export.codegen import OPTIMISE_ENV, generate
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


def cache_dir() -> Path:
    """The folder of :func:`cached_fmu`'s FMUs: ``$XDG_CACHE_HOME/flexlink``, or ``~/.cache/flexlink``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "flexlink"


def cached_fmu(scene: Scene | str | os.PathLike[str], model: SymbolicModel | None = None,
               fmi_version: int = 2) -> Path:
    """The FMU of a scene file (or of a Scene object), rebuilt only when something it is made of changed.

    FMI 2.0, or with ``fmi_version=3`` FMI 3.0; rebuilt when the scene's content, flexlink or the C sources
    change.  The key is the parsed scene, so a file and the same Scene object share one FMU.  Concurrent
    callers (Dask workers, test processes) build it once: the first holds a lock file.
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)             # first: a missing or bad file is a SceneError
    h = hashlib.sha256(repr(dataclasses.replace(scene, path=None)).encode())
    h.update(flexlink.__version__.encode())
    h.update(os.environ.get(OPTIMISE_ENV, "").encode())      # the generated code's optimisation level
    generic = fmu_src_dir()
    for f in sorted(generic.rglob("*")):     # C sources, headers and the templates of codegen
        if f.is_file() and "__pycache__" not in f.parts:
            h.update(f.relative_to(generic).as_posix().encode())
            h.update(f.read_bytes())
    for f in sorted(Path(flexlink.__file__).parent.rglob("*.py")):
        h.update(f.read_bytes())
    version = "" if fmi_version == 2 else f"-fmi{fmi_version}"
    path = cache_dir() / f"{scene.model_identifier}{version}-{h.hexdigest()[:16]}.fmu"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        with _exclusive(path.with_suffix(".lock")):
            if not path.exists():             # built by another process while this one waited
                build_fmu(scene, path, model=model, fmi_version=fmi_version)
    return path


@contextlib.contextmanager
def _exclusive(lock: Path) -> Iterator[None]:
    """An advisory lock on ``lock``, held for the ``with`` block.

    POSIX flock; elsewhere no lock: at worst an FMU is built twice, each build writes a private file and
    renames it into place.
    """
    try:
        import fcntl
    except ImportError:                       # Windows
        yield
        return
    with open(lock, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
