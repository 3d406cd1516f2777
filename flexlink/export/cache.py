"""The FMU cache: a scene's FMU found by the hash of what it is made of, built only when missing.

Apart from :mod:`flexlink.export.fmu` so that finding an FMU already built costs no CasADi, SciPy or code
generator import (issue 22: a repeated ``flexlink control`` starts in well under a second): the builder is
imported only when the FMU is missing.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import importlib.util
import os
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import flexlink
from flexlink.export.cbuild import OPTIMISE_ENV, fmu_src_dir
from flexlink.scene.loader import Scene, load_scene

if TYPE_CHECKING:
    from flexlink.mechanics.model import SymbolicModel

__all__ = ["OPTIMISE_ENV", "cache_dir", "cached_fmu"]

# OPTIMISE_ENV (flexlink.export.cbuild) imposes the generated code's optimisation level: part of the cache key.
# The packages whose versions are part of it too: CasADi writes the generated C, numpy and scipy compute the
# shape functions and their integrals (an upgrade may change the code or its last bits: the FMU is rebuilt).
_GENERATORS = ("casadi", "numpy", "scipy")


def cache_dir() -> Path:
    """The folder of :func:`cached_fmu`'s FMUs: ``$XDG_CACHE_HOME/flexlink``, or ``~/.cache/flexlink``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "flexlink"


def cached_fmu(scene: Scene | str | os.PathLike[str], model: SymbolicModel | None = None,
               fmi_version: int = 2) -> Path:
    """The FMU of a scene file (or of a Scene object), rebuilt only when something it is made of changed.

    FMI 2.0, or with ``fmi_version=3`` FMI 3.0; rebuilt when the scene's content, flexlink, the C sources or
    the versions of CasADi, numpy and scipy change.  The key is the parsed scene, so a file and the same Scene
    object share one FMU.  Concurrent callers (Dask workers, test processes) build it once: the first holds a
    lock file.
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)             # first: a missing or bad file is a SceneError
    h = hashlib.sha256(repr(dataclasses.replace(scene, path=None)).encode())
    h.update(flexlink.__version__.encode())
    h.update(os.environ.get(OPTIMISE_ENV, "").encode())      # the generated code's optimisation level
    for package in _GENERATORS:               # what writes the C and the shape integrals
        h.update(_installed(package).encode())
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
        from flexlink.export import fmu

        path.parent.mkdir(parents=True, exist_ok=True)
        with _exclusive(path.with_suffix(".lock")):
            if not path.exists():             # built by another process while this one waited
                fmu.build_fmu(scene, path, model=model, fmi_version=fmi_version)
    return path


def _installed(package: str) -> str:
    """The installed distribution of ``package``, as its ``.dist-info`` folder names it (``casadi-3.8.2``).

    Found without importing the package or ``importlib.metadata`` (0.2 s of imports on a command whose FMU is
    cached); a package installed some other way (an editable install, whose ``.dist-info`` lies elsewhere) is
    named by its module file's modification time, one imported from a zip by its path.
    """
    spec = importlib.util.find_spec(package)
    if spec is None or spec.origin is None:
        return f"{package} absent"
    module = Path(spec.origin)
    infos = sorted(p.name for p in module.parent.parent.glob(f"{package}-*.dist-info"))
    if infos:
        return "|".join(infos)                # every one: two installs side by side are not one of them
    try:
        return f"{package} {module.stat().st_mtime_ns}"
    except OSError:                           # imported from a zip: its path is all there is
        return f"{package} {spec.origin}"


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
