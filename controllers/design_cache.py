"""The design cache of ``flexlink control`` (issue 22: a repeated command starts in under a second).

A run needs, before its first FMU call, the linearisation and the LQR/Kalman design (the model builder:
CasADi and SciPy, most of a second of imports; :mod:`controllers.riccati`), the reference and the law's
affine form (:class:`controllers.laws.AffineForm`).  Only the last two and a few numbers enter the run
itself.  They are stored, keyed by the parsed scene,
flexlink's version, the sources of flexlink and of the ``controllers`` package and every option the design
and the reference depend on, in ``~/.cache/flexlink/designs/`` beside the build cache (written to a
private file and renamed: a reader never sees half an entry).  A repeated command loads them and runs
the FMU: it imports neither the model builder nor the design modules (nor python-control, which
``--json``'s margins import after a designing run's first FMU call).  A missing, unreadable or outdated
entry is a miss, never an error.  ``FLEXLINK_DESIGN_CACHE=0`` turns the cache off; another value is the
folder to use instead.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import pickle
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:                    # a cached run imports neither the design modules nor python-control
    from controllers.laws import AffineForm
    from controllers.trajectory import Reference
    from flexlink.scene.schema import Scene

__all__ = ["CachedLaw", "cache_key", "enabled", "load", "store"]

VERSION = 1
ENV = "FLEXLINK_DESIGN_CACHE"


def enabled() -> bool:
    """Whether the cache is used: always, unless ``FLEXLINK_DESIGN_CACHE=0`` (a fresh design each run)."""
    return os.environ.get(ENV) != "0"


def cache_key(scene: Scene, options: dict[str, Any]) -> str:
    """The entry's key: a hash of everything a design depends on, so that a stale entry is never found.

    The parsed scene (as the FMU's build cache keys it), flexlink's version, the sources of flexlink (the
    model, its linearisation) and of the controllers, the command's design and run options.
    """
    import flexlink

    h = hashlib.sha256(f"design-cache {VERSION} {flexlink.__version__}".encode())
    h.update(repr(dataclasses.replace(scene, path=None)).encode())
    for root in (Path(flexlink.__file__).resolve().parent, Path(__file__).resolve().parent):
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root).as_posix().encode())
            h.update(f.read_bytes())
    h.update(json.dumps(options, sort_keys=True).encode())
    return h.hexdigest()[:24]


def _path(key: str) -> Path:
    if os.environ.get(ENV):
        return Path(os.environ[ENV]) / f"{key}.pickle"
    from flexlink.export.cache import cache_dir

    return cache_dir() / "designs" / f"{key}.pickle"


def load(key: str) -> dict | None:
    """The entry, or None (absent, unreadable, another format)."""
    try:
        with open(_path(key), "rb") as f:
            entry = pickle.load(f)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError, ValueError):
        return None
    return entry if isinstance(entry, dict) and entry.get("version") == VERSION else None


def store(key: str, entry: dict) -> None:
    """Write the entry atomically; a cache that cannot be written is left alone (the run does not need it)."""
    path = _path(key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".design-", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            pickle.dump({**entry, "version": VERSION}, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError, UnboundLocalError):
            os.unlink(tmp)


@dataclasses.dataclass
class CachedLaw:
    """A law as :class:`controllers.cosim.FmuLoop`'s fast loop runs it: its affine form along the reference.

    The form is the designed law's along the cached reference (the same arithmetic;
    :meth:`controllers.laws.SampledLaw.affine`), so that a repeated run needs neither the design nor
    python-control.
    """

    kind: str
    dt: float
    sensors: list
    input: str
    form: AffineForm

    def reset(self) -> None:
        """Nothing to reset: the affine form carries its state in the loop, not in the law."""

    def affine(self, reference: Reference) -> AffineForm:
        """The cached form, whatever ``reference``: it was computed along the cached reference itself."""
        return self.form

    def step(self, y: object, x_ref: object, u_ff: object) -> float:
        """Refused: a cached law has no estimator to step, only its affine form."""
        raise RuntimeError("a cached law runs in the fast loop only (its affine form)")
