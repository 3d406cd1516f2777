"""The description of a sweep, :class:`SweepSpec`: its fields, their checks, and the TOML spec file that holds them.

Apart from the running of a sweep (:mod:`controllers.sweep`) because a spec is checked before anything runs:
every value that needs neither the scene nor the FMU is refused here, in one message naming the field and its
``flexlink sweep`` option (and the spec file's name and key when it came from a file), so that a bad spec is
refused before an FMU is built or a worker started.  The command line (:mod:`controllers.sweep_cli`) reads
the spec file with :func:`read_spec` and lays its options over it with :func:`merge_spec`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controllers.options import SENSORS
from controllers.sweep_cases import make_cases
from flexlink.errors import FlexlinkError

__all__ = ["SweepSpec", "merge_spec", "read_spec"]

_NUMBER = (int, float)
# the TOML value each field takes (bool is refused where a number is meant: TOML's true is not 1)
_SPEC_TYPES: dict[str, tuple[type, ...]] = {
    "scene": (str,), "params": (dict,), "samples": (int,), "seed": (int,), "distributions": (dict,),
    "controller": (str,), "target_deg": (*_NUMBER, list), "duration": _NUMBER, "settle": _NUMBER,
    "settle_band": _NUMBER, "torque_limit": (*_NUMBER, list, dict, str), "joint_error": (*_NUMBER, list, dict, str),
    "tip_deflection": (*_NUMBER, list, dict, str), "root_moment": (*_NUMBER, list, dict, str),
    "mode_limit": (*_NUMBER, list, dict, str), "sensors": (str,), "stop_time": _NUMBER,
    "sample_time": _NUMBER, "series": (list,), "series_every": (int,), "out": (str,), "resume": (bool,),
    "overwrite": (bool,), "scheduler": (str,), "n_workers": (int,), "batch_size": (int,), "shared_fs": (bool,),
    "progress": (bool,), "fmu": (str,), "case_timeout": _NUMBER,
}
_SPEC_PATHS = ("scene", "out", "fmu")          # relative to the spec file's folder
#: The LQR's limits (``flexlink control``'s options, :mod:`controllers.weights`): a number for all, one per item
#: in scene order, or a table by name; the torque limit too.
_LIMITS = ("torque_limit", "joint_error", "tip_deflection", "root_moment", "mode_limit")
_LIMIT_UNITS = {"torque_limit": "N m", "joint_error": "deg", "tip_deflection": "mm", "root_moment": "N m",
                "mode_limit": "modal units"}


@dataclass
class SweepSpec:
    """One parameter sweep: what varies, what each case runs, where the rows go and how cases are scheduled.

    It is the one description of a sweep, whether it is written in Python, in a TOML file
    (:meth:`from_toml`, whose keys are the field names) or as ``flexlink sweep``'s options (which override
    the file's); :func:`controllers.sweep.run_sweep` takes it together with the objects only a running program
    has (a Dask client, a callback).  Construction checks every value that needs neither the scene nor the FMU, so that
    a bad spec is refused before an FMU is built or a worker started.

    Parameters
    ----------
    scene : str or path-like
        The scene TOML whose FMU is swept.
    params : mapping, optional
        FMU parameter name → grid axis (``"LO:HI:N"``, ``"V1,V2"``, a value or a sequence); with
        ``samples``: ``"LO:HI"`` (uniform) or a fixed value.
    samples, seed, distributions :
        Monte Carlo instead of a grid: ``samples`` seeded draws; ``distributions`` maps names to
        ``"uniform:LO:HI"``, ``"normal:MEAN:STD[:LO:HI]"`` (truncated) or ``"loguniform:LO:HI"``.
    controller, target_deg, duration, settle, settle_band, torque_limit, sensors :
        Closed loop (``controller`` "lqr" or "pd", "lqr" when only a target or a duration is given): the
        rest-to-rest manoeuvre of the first joint to ``target_deg`` in ``duration`` s plus ``settle`` s (as
        ``flexlink control``; with several torque-driven joints one angle per joint; kept as a tuple of
        floats); the settling time is measured to a band of ``settle_band`` × the commanded angle.  The
        controller is designed once on the scene's values.
    torque_limit, joint_error, tip_deflection, root_moment, mode_limit :
        The LQR's limits as ``flexlink control`` takes them (N m, deg, mm, N m, modal units): a number for
        every joint, link or mode, a sequence of one per item in scene order, a mapping by name, or the
        command line's text (``"shoulder=60,elbow=40"``); checked against the scene by
        :mod:`controllers.weights`.
    stop_time : float, optional
        Open loop instead: the scene's default inputs for ``stop_time`` s (``settle``: the final window of the
        residual vibration).
    sample_time : float
        Controller sample time / communication step, s.
    series, series_every :
        FMU outputs to keep as time series (list columns ``series.<name>`` and ``series.time``), every
        ``series_every``-th sample.
    out : path, optional
        Results file (``.parquet`` or ``.csv``); its journal ``out + ".journal.jsonl"`` is written as cases
        complete.  Without ``out`` nothing is written (and nothing can be resumed).
    resume, overwrite :
        An existing journal (or file) of the same sweep is resumed (only missing cases are run) unless
        ``overwrite``; one of another sweep is refused unless ``overwrite``.  ``resume=False`` without
        ``overwrite`` refuses to touch existing results.
    scheduler, n_workers, batch_size, shared_fs :
        ``scheduler``: a Dask scheduler address, or ``"serial"`` for a plain loop in this process; else an
        embedded LocalCluster of ``n_workers`` processes (default: one per core).  ``batch_size`` cases per
        Dask task (default: about 4 tasks per worker, at most 16 cases each).  ``shared_fs``: send the workers
        the FMU's path instead of its bytes.
    progress : bool or None
        tqdm progress bar on stderr (None: only on a terminal).
    fmu : path, optional
        Use this FMU (built from ``scene``) instead of building or caching one.
    case_timeout : float, optional
        Wall-clock seconds one case may run (:mod:`controllers.deadline`); a case still running then is a
        row with ``status = "timeout"``.  Timed-out rows are run again on resume (a limit depends on the
        machine's load, not on the case).

    Raises
    ------
    FlexlinkError
        For a value out of range or settings that contradict each other, named as the field and its option.
    """

    scene: str | os.PathLike
    params: Mapping[str, object] = field(default_factory=dict)
    samples: int | None = None
    seed: int = 0
    distributions: Mapping[str, object] = field(default_factory=dict)
    controller: str | None = None
    target_deg: float | Sequence[float] | None = None
    duration: float | None = None
    settle: float = 1.5
    settle_band: float = 0.02
    torque_limit: float | Sequence[float] | Mapping[str, float] | None = None
    joint_error: float | Sequence[float] | Mapping[str, float] | None = None
    tip_deflection: float | Sequence[float] | Mapping[str, float] | None = None
    root_moment: float | Sequence[float] | Mapping[str, float] | None = None
    mode_limit: float | Sequence[float] | Mapping[str, float] | None = None
    sensors: str = "strain"
    stop_time: float | None = None
    sample_time: float = 1e-3
    series: Sequence[str] = ()
    series_every: int = 10
    out: str | os.PathLike | None = None
    resume: bool = True
    overwrite: bool = False
    scheduler: str | None = None
    n_workers: int | None = None
    batch_size: int | None = None
    shared_fs: bool = False
    progress: bool | None = False
    fmu: str | os.PathLike | None = None
    case_timeout: float | None = None

    def __post_init__(self) -> None:
        self.params = dict(self.params or {})
        self.distributions = dict(self.distributions or {})
        self.series = tuple(self.series)
        if self.target_deg is not None:            # one form whatever the source: 90, [90] and "90" alike
            self.target_deg = tuple(float(v) for v in np.atleast_1d(self.target_deg))
        if self.controller is None and (self.target_deg is not None or self.duration is not None):
            self.controller = "lqr"                # a manoeuvre without a named controller: the LQR
        self.series_every = _check_options(controller=self.controller, stop_time=self.stop_time,
                                           sample_time=self.sample_time, settle=self.settle,
                                           settle_band=self.settle_band, series_every=self.series_every)
        if self.controller is not None and self.controller not in ("lqr", "pd"):
            raise FlexlinkError(f"controller (--controller): expected 'lqr' or 'pd', got {self.controller!r}")
        for name in _LIMITS:
            setattr(self, name, _limit_value(name, getattr(self, name)))
        if self.sensors not in SENSORS:
            raise FlexlinkError(f"sensors (--sensors): expected one of {SENSORS}, got {self.sensors!r}")
        for name, option in (("n_workers", "--workers"), ("batch_size", "--batch-size")):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise FlexlinkError(f"{name} ({option}) must be at least 1, got {value}")
        t = self.case_timeout
        if t is not None and not (math.isfinite(t) and t > 0):
            raise FlexlinkError(f"case_timeout (--case-timeout) must be a positive number of seconds, got {t}")

    def cases(self) -> tuple[str, list[dict[str, float]]]:
        """The sweep's cases, ``("grid" | "monte-carlo", [params of each case])`` (:func:`make_cases`)."""
        return make_cases(self.params, samples=self.samples, seed=self.seed, distributions=self.distributions)

    @classmethod
    def from_toml(cls, path: str | os.PathLike, **overrides: object) -> SweepSpec:
        """The spec a TOML file describes, with ``overrides`` (a command line's options) taking precedence.

        The file's keys are the field names; ``params`` and ``distributions`` are tables (a name in
        ``overrides``' tables replaces the file's entry of that name, the others are kept).  Relative
        ``scene``, ``out`` and ``fmu`` paths are read from the file's folder, as a scene's own paths are, so
        that a spec beside its scene works from any working directory.

        Raises
        ------
        FlexlinkError
            Naming the file and the key: a file that cannot be read or is not TOML, an unknown key, a value of
            the wrong type, or a value the checks of the class refuse.
        """
        path = Path(path)
        values = merge_spec(read_spec(path), overrides)
        if "scene" not in values:
            raise FlexlinkError(f"{path}: no scene: give scene = \"FILE.toml\" in the file or as an override")
        try:
            return cls(**values)                   # type: ignore[arg-type]  # each value's type checked
        except FlexlinkError as e:
            raise FlexlinkError(f"{path}: {e}") from None


def _limit_value(name: str, value):
    """One of :data:`_LIMITS` in the form :mod:`controllers.weights` takes, each value checked positive.

    A number (or a list of one) is one value for all — a float for ``torque_limit``, as the one-joint design
    takes it, else a list of one; a sequence one per item; a mapping by name; text, the command line's syntax.
    """
    import argparse

    from controllers.options import limits

    option = "--" + name.replace("_", "-")

    def one(v) -> float:
        if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
            raise FlexlinkError(f"{name} ({option}): expected a number, got {v!r}")
        if not (math.isfinite(v) and v > 0):
            raise FlexlinkError(f"{name} ({option}): expected a positive number, got {v!r}")
        return float(v)

    if value is None:
        return None
    if isinstance(value, str):
        try:
            value = limits(value)
        except argparse.ArgumentTypeError as e:
            raise FlexlinkError(f"{name} ({option}): {e}") from None
    if isinstance(value, Mapping):
        return {str(k): one(v) for k, v in value.items()}
    items = [one(v) for v in (value if isinstance(value, Sequence) else [value])]
    if not items:
        raise FlexlinkError(f"{name} ({option}): no value")
    return items[0] if name == "torque_limit" and len(items) == 1 else items


def read_spec(path: Path) -> dict[str, object]:
    """The fields a spec file gives, checked against the TOML types they take (:func:`_spec_values`)."""
    import tomllib

    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise FlexlinkError(f"--spec {path}: cannot be read ({e.strerror})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise FlexlinkError(f"{path}: not a valid TOML file ({e})") from None
    return _spec_values(path, doc)


def merge_spec(values: Mapping[str, object], overrides: Mapping[str, object]) -> dict[str, object]:
    """``values`` with ``overrides`` over them; the tables ``params`` and ``distributions`` merge by name."""
    merged = {**values, **overrides}
    for name in ("params", "distributions"):
        below, above = values.get(name), overrides.get(name)
        if isinstance(below, Mapping) and isinstance(above, Mapping):
            merged[name] = {**below, **above}
    return merged


def _spec_values(path: Path, doc: dict) -> dict[str, object]:
    """The fields a spec file gives, each checked against the TOML type it must have, paths made absolute."""
    values: dict[str, object] = {}
    for key, value in doc.items():
        kinds = _SPEC_TYPES.get(key)
        if kinds is None:
            raise FlexlinkError(f"{path}: unknown key {key!r}; the keys of a sweep spec are "
                                + ", ".join(_SPEC_TYPES))
        if isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
            raise FlexlinkError(f"{path}: {key} = {_shown(value)}: expected {_describe(key, kinds)}")
        _check_items(path, key, value)
        if key in _SPEC_PATHS:
            value = str(path.parent / str(value))
        values[key] = value
    return values


def _shown(value: object) -> str:
    """A spec file's value as TOML writes it where that differs from Python (``true``, not ``True``)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return "[" + ", ".join(_shown(x) for x in value) + "]"
    return repr(value)


def _describe(key: str, kinds: tuple[type, ...]) -> str:
    """What a spec key takes, in TOML's words, for the message that refuses another value."""
    if key in _LIMITS:
        return (f"a number ({_LIMIT_UNITS[key]}), an array of numbers (one per item in scene order), a table by "
                "name or the command line's text")
    array = "an array of strings (output names)" if key == "series" else "an array of numbers"
    words = {dict: "a table", list: array, bool: "true or false", str: "a string"}
    if kinds == (int,):
        return "a whole number"
    number = ["a number"] if float in kinds else []
    return " or ".join(number + [words[k] for k in kinds if k in words])


def _kind(x: object) -> str:
    """The TOML type of a spec file's value, for a message that refuses it."""
    kinds = ((bool, "a boolean"), (str, "a string"), (dict, "a table"), (list, "an array"))
    return next((word for kind, word in kinds if isinstance(x, kind)), type(x).__name__)


def _is_number(x: object) -> bool:
    """A TOML integer or float: its true and false are not numbers (Python's bool is an int)."""
    return isinstance(x, int | float) and not isinstance(x, bool)


def _check_items(path: Path, key: str, value: object) -> None:
    """The elements of a spec file's tables and arrays: numbers and strings as the field takes them.

    A limit's element that is not a number (``torque_limit = {shoulder = true}``) is named with the limit's
    unit, and a boolean as the boolean it is: TOML's true is not 1.
    """
    if key in _LIMITS:
        items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
        for name, item in items:
            if not _is_number(item):
                where = f"{key}.{name}" if isinstance(value, dict) else f"{key}[{name + 1}]"
                raise FlexlinkError(f"{path}: {where} = {_shown(item)}: expected a number ({_LIMIT_UNITS[key]}), "
                                    f"got {_kind(item)}")
    elif isinstance(value, dict):
        for name, item in value.items():
            ok = (isinstance(item, str) or _is_number(item) or key == "params" and isinstance(item, list)
                  and all(_is_number(x) for x in item))
            if not ok:
                what = ('a string such as "LO:HI:N", a number or an array of numbers' if key == "params"
                        else 'a string such as "normal:MEAN:STD" or a number')
                raise FlexlinkError(f"{path}: {key}.{name} = {_shown(item)}: expected {what}")
    elif isinstance(value, list):
        kind = str if key == "series" else (int, float)
        if not all(isinstance(x, kind) and not isinstance(x, bool) for x in value):
            what = "strings (output names)" if key == "series" else "numbers"
            raise FlexlinkError(f"{path}: {key} = {_shown(value)}: expected an array of {what}")


def _check_options(*, controller, stop_time, sample_time, settle, settle_band, series_every) -> int:
    """Refuse inconsistent or out-of-range settings before the FMU is built; returns ``series_every`` as an int."""
    if (controller is None) == (stop_time is None):
        raise FlexlinkError("give either a closed-loop manoeuvre (controller, target_deg, duration: --controller, "
                            "--target, --duration) or an open-loop stop_time (--stop-time)")
    if not (math.isfinite(sample_time) and sample_time > 0):
        raise FlexlinkError(f"sample_time (--sample-time) must be positive, got {sample_time}")
    if not (math.isfinite(settle) and settle > 0):
        raise FlexlinkError(f"settle (--settle) must be a positive number of seconds, got {settle}")
    if not 0 < settle_band < 1:
        raise FlexlinkError(f"settle_band (--settle-band) must be between 0 and 1, got {settle_band}")
    if stop_time is not None:
        from flexlink.run.simulate import check_run

        check_run(stop_time, sample_time, "--stop-time", "--sample-time")      # a run that would not end
    series_every = int(series_every)
    if series_every < 1:
        raise FlexlinkError(f"series_every (--series-every) must be at least 1, got {series_every}")
    return series_every
