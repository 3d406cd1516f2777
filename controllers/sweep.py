"""Parameter studies at scale: full grids and Monte Carlo runs of one FMU on Dask (``flexlink sweep``).

Its command line (parser, :class:`SweepSpec` from the options, the run) is :mod:`controllers.sweep_cli`.

The FMU is built once (:func:`flexlink.export.cache.cached_fmu`) and shipped to the workers, as bytes (default) or
as a path on a shared file system; each worker process writes it out once and keeps one FMU instance per
worker thread, reset (``fmi2Reset``) between cases.  A case only sets the FMU's tunable parameters
(the scene's names, docs/embedding.md "Variables", e.g. ``arm.payload.mass``) before initialisation: no re-export.

A case is either

* **closed loop** (``controller="lqr"|"pd"``): the rest-to-rest manoeuvre of
  :func:`controllers.manoeuvre.rest_to_rest`, with the controller designed once on the scene's nominal
  values (the sweep tests the nominal controller against the varied plant), or
* **open loop** (``stop_time``): the scene's default inputs (start values) for ``stop_time`` seconds.

With several torque-driven joints a closed-loop case is the MIMO LQG's manoeuvre of every joint
(``target_deg`` one angle per joint; :mod:`controllers.montecarlo`: its figures and stability verdict).

Each case gives one row of named scalar metrics (:data:`CLOSED_LOOP_METRICS`, :data:`OPEN_LOOP_METRICS`),
``failed``/``error`` (an FMU error, a refused parameter, ``fmi2Discard``, a divergence: recorded, the sweep
goes on), optional decimated time series (list columns), the wall time and the worker.

Robustness: completed cases are appended (flushed, fsync'ed) to a JSON-lines journal beside the output
file (``FILE.journal.jsonl``) as they arrive, so an interrupted or crashed sweep loses nothing finished;
running the same sweep again (or ``resume=True``, the default) recomputes only the cases whose parameter
values are not in the journal yet.  A worker that dies mid-case (killed, out of memory, a crash inside the
FMU) has its cases rescheduled by Dask; a batch that still cannot run is resubmitted once and then
recorded as failed.  At the end the journal is consolidated into FILE (``.parquet`` or ``.csv``), one row
per case of the sweep, sorted by case number.

Scheduling: the default is an embedded ``dask.distributed.LocalCluster`` (processes, one per core, one
thread each); ``scheduler="tcp://host:8786"`` uses a running cluster (its workers need flexlink
installed); ``scheduler="serial"`` runs the same code in a plain loop in this process, without Dask.

Examples
--------
>>> from controllers.sweep import SweepSpec, run_sweep                                       # doctest: +SKIP
>>> df = run_sweep(SweepSpec("examples/rotating_link_payload.toml", {"arm.payload.mass": "0.5:2.0:21"},
...                          controller="lqr", target_deg=90, duration=1.5, settle=1.5, out="payload.parquet"))
>>> df[["arm.payload.mass", "residual_vibration_rms_m", "overshoot_deg"]]              # doctest: +SKIP
>>> run_sweep(SweepSpec("examples/rotating_link_payload.toml", samples=200, seed=1, controller="pd",
...                     target_deg=90, duration=1.5, distributions={"arm.EI": "normal:93.72:5:80:110"}))
>>> run_sweep(SweepSpec.from_toml("payload.toml", seed=2))        # a spec file, one field overridden
"""

from __future__ import annotations

import atexit
import functools
import hashlib
import itertools
import json
import math
import os
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controllers.deadline import CaseTimeout, Deadline
from controllers.options import SENSORS
from flexlink.errors import FlexlinkError

__all__ = [
    "CLOSED_LOOP_METRICS",
    "OPEN_LOOP_METRICS",
    "SweepSpec",
    "journal_path",
    "make_cases",
    "plot_sweep",
    "run_sweep",
    "summary_table",
]

CLOSED_LOOP_METRICS = (
    "final_error_deg",            # joint angle minus target at the end of the settle window
    "overshoot_deg",              # largest excursion past the target, in the direction of motion (>= 0)
    "overshoot_pct",              # the same in % of the commanded angle
    "settling_time_s",            # from the start until |error| stays within settle_band x |commanded angle|
    "residual_vibration_rms_m",   # RMS of <last link>.tip.v minus its static value over the settle window
    "peak_torque_nm",             # max |<joint>.tau| (saturated)
    "max_tip_deflection_m",       # max |<last link>.tip.v minus its static value at the target|
    "saturated_fraction",         # fraction of samples at the torque limit
    "realtime_factor",            # simulated s per wall-clock s of the loop (timing: not reproducible)
)
OPEN_LOOP_METRICS = (
    "final_angle_deg",            # first joint's angle at stop_time
    "final_tip_deflection_m",     # <last link>.tip.v at stop_time
    "max_tip_deflection_m",       # max |<last link>.tip.v|
    "residual_vibration_rms_m",   # RMS of tip.v about its mean over the last `settle` seconds
    "peak_torque_nm",             # max |<joint>.tau| over every joint (input or output)
    "realtime_factor",
)
PLOT_METRICS = ("overshoot_deg", "settling_time_s", "residual_vibration_rms_m", "peak_torque_nm",
                "max_tip_deflection_m", "final_error_deg", "final_angle_deg", "final_tip_deflection_m")
DISTRIBUTIONS = ("uniform", "normal", "loguniform")
ROW_FIELDS = ("case", "key", "status", "failed", "error")


# ============================================================================ cases: grids and Monte Carlo
def _num(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise FlexlinkError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise FlexlinkError(f"{what}: expected a finite number, got {text!r}")
    return v


def _parse_grid_axis(name: str, spec) -> list[float]:
    """``"LO:HI:N"`` (N evenly spaced values, ends included), ``"V1,V2,..."``, ``"V"``, or a sequence."""
    what = f"--param {name}"
    if isinstance(spec, str):
        text = spec.strip()
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise FlexlinkError(f"{what}={text}: expected LO:HI:N (N values from LO to HI), V1,V2,... or V")
            lo, hi = _num(parts[0], what), _num(parts[1], what)
            try:
                n = int(parts[2])
            except ValueError:
                raise FlexlinkError(f"{what}={text}: N = {parts[2]!r} is not a whole number") from None
            if n < 1:
                raise FlexlinkError(f"{what}={text}: N must be at least 1")
            return [lo] if n == 1 else [float(v) for v in np.linspace(lo, hi, n)]
        values = [_num(p, what) for p in text.split(",") if p.strip()]
    elif isinstance(spec, int | float):
        values = [_num(str(spec), what)]
    else:
        values = [_num(str(v), what) for v in spec]
    if not values:
        raise FlexlinkError(f"{what}: no values")
    return values


@dataclass(frozen=True)
class Distribution:
    """One parameter's law in a Monte Carlo sweep, drawn for every case from the sweep's seeded generator.

    ``uniform(lo, hi)``, ``normal(mean, std)`` truncated to ``[lo, hi]``, ``loguniform(lo, hi)``, or a constant
    (``kind="fixed"``, ``a`` the value).
    """

    kind: str
    a: float
    b: float = math.nan
    lo: float = -math.inf
    hi: float = math.inf

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        if self.kind == "fixed":
            return np.full(n, self.a)
        if self.kind == "uniform":
            return rng.uniform(self.a, self.b, n)
        if self.kind == "loguniform":
            return np.exp(rng.uniform(math.log(self.a), math.log(self.b), n))
        out = rng.normal(self.a, self.b, n)          # normal, truncated by redrawing what falls outside
        for _ in range(1000):
            bad = (out < self.lo) | (out > self.hi)
            if not bad.any():
                return out
            out[bad] = rng.normal(self.a, self.b, int(bad.sum()))
        raise FlexlinkError(f"normal({self.a}, {self.b}) truncated to [{self.lo}, {self.hi}]: almost no mass "
                            "inside the bounds")


def _parse_distribution(name: str, spec, option: str = "--distribution") -> Distribution:
    """``uniform:LO:HI``, ``normal:MEAN:STD[:LO:HI]``, ``loguniform:LO:HI``, ``LO:HI`` (uniform) or ``V``."""
    if isinstance(spec, Distribution):
        return spec
    what = f"{option} {name}"
    if isinstance(spec, int | float):
        return Distribution("fixed", _num(str(spec), what))
    if not isinstance(spec, str):
        raise FlexlinkError(f"{what}: expected a string such as 'normal:MEAN:STD' or 'uniform:LO:HI'")
    parts = [p.strip() for p in spec.strip().split(":")]
    kind = parts[0].lower() if parts and parts[0][:1].isalpha() else None
    if kind is None:       # LO:HI or V
        if len(parts) == 1:
            return Distribution("fixed", _num(parts[0], what))
        if len(parts) == 2:
            kind = "uniform"
            parts = ["uniform", *parts]
        else:
            raise FlexlinkError(f"{what}={spec}: with --samples, give LO:HI (uniform) or a value; grids "
                                "(LO:HI:N) are for sweeps without --samples")
    if kind not in DISTRIBUTIONS:
        raise FlexlinkError(f"{what}={spec}: unknown distribution {parts[0]!r}; expected one of {DISTRIBUTIONS}")
    nums = [_num(p, what) for p in parts[1:]]
    if kind in ("uniform", "loguniform"):
        if len(nums) != 2 or not nums[0] < nums[1]:
            raise FlexlinkError(f"{what}={spec}: expected {kind}:LO:HI with LO < HI")
        if kind == "loguniform" and nums[0] <= 0:
            raise FlexlinkError(f"{what}={spec}: loguniform needs 0 < LO < HI")
        return Distribution(kind, nums[0], nums[1], nums[0], nums[1])
    if len(nums) not in (2, 4) or not nums[1] > 0:
        raise FlexlinkError(f"{what}={spec}: expected normal:MEAN:STD or normal:MEAN:STD:LO:HI with STD > 0")
    lo, hi = (nums[2], nums[3]) if len(nums) == 4 else (-math.inf, math.inf)
    if not lo < hi:
        raise FlexlinkError(f"{what}={spec}: expected LO < HI")
    return Distribution("normal", nums[0], nums[1], lo, hi)


def make_cases(params: Mapping[str, object] | None = None, *, samples: int | None = None, seed: int = 0,
               distributions: Mapping[str, object] | None = None) -> tuple[str, list[dict[str, float]]]:
    """The cases of a sweep, each the FMU parameters it sets, and whether they form a grid or a Monte Carlo set.

    ``("grid", [...])`` is the full product of the ``params`` axes, last name varying fastest; with
    ``samples``, ``("monte-carlo", [...])`` holds ``samples`` draws (seeded) of ``params`` (``LO:HI`` uniform,
    or a value) and ``distributions`` (:func:`_parse_distribution`).  The same arguments always give the same
    cases, which is what lets a journal be resumed.
    """
    params = dict(params or {})
    distributions = dict(distributions or {})
    both = set(params) & set(distributions)
    if both:
        raise FlexlinkError(f"{sorted(both)}: given both as --param and --distribution")
    if samples is None:
        if distributions:
            raise FlexlinkError("--distribution needs --samples N (a Monte Carlo sweep)")
        if not params:
            raise FlexlinkError("nothing to sweep: give at least one --param NAME=LO:HI:N")
        axes = {name: _parse_grid_axis(name, spec) for name, spec in params.items()}
        names = list(axes)
        return "grid", [dict(zip(names, combo, strict=True)) for combo in itertools.product(*axes.values())]
    if isinstance(samples, bool) or not isinstance(samples, int | np.integer) or samples < 1:
        raise FlexlinkError(f"--samples must be a positive whole number, got {samples!r}")
    dists = {name: _parse_distribution(name, spec, "--param") for name, spec in params.items()}
    dists.update({name: _parse_distribution(name, spec) for name, spec in distributions.items()})
    if not dists:
        raise FlexlinkError("--samples needs at least one --param NAME=LO:HI or --distribution NAME=...")
    rng = np.random.default_rng(seed)
    drawn = {name: d.draw(rng, int(samples)) for name, d in dists.items()}
    return "monte-carlo", [{name: float(drawn[name][i]) for name in dists} for i in range(int(samples))]


def case_key(params: Mapping[str, float]) -> str:
    """The identity of a case in a journal: its parameter names and exact values."""
    return ";".join(f"{name}={float(v)!r}" for name, v in params.items())


# ============================================================================ the description of a sweep
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
    the file's); :func:`run_sweep` takes it together with the objects only a running program has (a Dask
    client, a callback).  Construction checks every value that needs neither the scene nor the FMU, so that
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
        values = _merge(_read_spec(path), overrides)
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


def _read_spec(path: Path) -> dict[str, object]:
    """The fields a spec file gives, checked against the TOML types they take (:func:`_spec_values`)."""
    import tomllib

    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise FlexlinkError(f"--spec {path}: cannot be read ({e.strerror})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise FlexlinkError(f"{path}: not a valid TOML file ({e})") from None
    return _spec_values(path, doc)


def _merge(values: Mapping[str, object], overrides: Mapping[str, object]) -> dict[str, object]:
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


# ============================================================================ the job shipped to the workers
@dataclass
class _SweepJob:
    """What every case of one sweep shares (pickled once and scattered to the workers)."""

    key: str                              # sweep id: hash of the scene and every setting below
    fmu_name: str
    fmu_bytes: bytes | None               # the FMU itself, or None when fmu_path is on a shared file system
    fmu_path: str | None
    mode: str                             # "closed" | "open"
    settings: dict
    design_blob: bytes | None = None      # cloudpickled controllers.manoeuvre.ControlDesign (closed loop)
    series: tuple[str, ...] = ()
    series_every: int = 1
    metrics: tuple[str, ...] = field(default=())
    case_timeout: float | None = None     # wall-clock seconds a case may take (None: no limit)


class _WorkerJob:
    """One worker thread's FMU instance (and design) for one sweep."""

    def __init__(self, spec: _SweepJob):
        self.spec = spec
        self.dir = tempfile.mkdtemp(prefix="flexlink-sweep-")
        if spec.fmu_bytes is not None:
            self.fmu = os.path.join(self.dir, spec.fmu_name)
            with open(self.fmu, "wb") as f:
                f.write(spec.fmu_bytes)
        else:
            assert spec.fmu_path is not None          # _sweep_job gives the bytes or the path
            self.fmu = spec.fmu_path
        self.design = None
        if spec.design_blob is not None:
            import cloudpickle

            self.design = cloudpickle.loads(spec.design_blob)
        self.runner = None

    def instance(self):
        """The FMU instance, created (extracted, instantiated) on first use and after a failed case."""
        if self.runner is None:
            s = self.spec.settings
            cwd = os.getcwd()      # fmpy changes into the binaries folder to load the library and does not
            try:                   # come back when loading fails
                if self.spec.mode == "closed":
                    from controllers.cosim import FmuLoop

                    record = [*s["record"], *[n for n in self.spec.series if n not in s["record"]]]
                    self.runner = FmuLoop(self.fmu, record=record, instance_name="flexlink_sweep")
                else:
                    from flexlink.run.simulate import SlaveRunner

                    self.runner = SlaveRunner(self.fmu, instance_name="flexlink_sweep")
            finally:
                os.chdir(cwd)
        return self.runner

    def drop_instance(self) -> None:
        if self.runner is not None:
            try:
                self.runner.close()
            except Exception:  # noqa: BLE001 (an instance in error: freeing is best effort)
                pass
            self.runner = None

    def close(self) -> None:
        self.drop_instance()
        shutil.rmtree(self.dir, ignore_errors=True)


_LOCAL = threading.local()
_ALL_JOBS: list[_WorkerJob] = []
_JOBS_LOCK = threading.Lock()
_KEEP_JOBS = 2                       # per thread: a long-lived cluster worker does not pile up instances


def _close_all_jobs() -> None:
    with _JOBS_LOCK:
        for job in _ALL_JOBS:
            job.close()
        _ALL_JOBS.clear()


atexit.register(_close_all_jobs)


def _worker_job(spec: _SweepJob) -> _WorkerJob:
    jobs = getattr(_LOCAL, "jobs", None)
    if jobs is None:
        jobs = _LOCAL.jobs = {}
    job = jobs.get(spec.key)
    if job is None:
        while len(jobs) >= _KEEP_JOBS:
            old = jobs.pop(next(iter(jobs)))
            old.close()
            with _JOBS_LOCK:
                if old in _ALL_JOBS:
                    _ALL_JOBS.remove(old)
        job = jobs[spec.key] = _WorkerJob(spec)
        with _JOBS_LOCK:
            _ALL_JOBS.append(job)
    return job


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().name)
    except (ImportError, ValueError):
        return f"pid{os.getpid()}"


def _error_text(e: BaseException) -> str:
    text = str(e).strip() or type(e).__name__
    if not isinstance(e, FlexlinkError):
        text = f"{type(e).__name__}: {text}"
    return " ".join(text.split())


def _closed_loop_case(job: _WorkerJob, params: dict[str, float]) -> tuple[dict, dict]:
    from controllers.manoeuvre import rest_to_rest

    s, d = job.spec.settings, job.design
    assert d is not None                          # a closed-loop sweep ships its design
    if s.get("multijoint"):
        from controllers.montecarlo import case

        return case(job, params)
    loop = job.instance()
    res = rest_to_rest(d, loop, s["target"], s["duration"], s["settle"], s["controller"], parameters=params)
    m = {k: res.metrics[k] for k in CLOSED_LOOP_METRICS if k in res.metrics}
    t = res.series["time"]
    theta = res.series[f"{d.joint}.theta"]
    delta = s["target"] - d.start_angle
    sign = 1.0 if delta >= 0 else -1.0
    over = max(0.0, float(np.max(sign * (theta - s["target"]))))
    m["overshoot_deg"] = math.degrees(over)
    m["overshoot_pct"] = 100.0 * over / abs(delta) if delta else math.nan
    band = s["settle_band"] * abs(delta) if delta else math.radians(0.01)
    outside = np.nonzero(np.abs(theta - s["target"]) > band)[0]
    if len(outside) == 0:
        m["settling_time_s"] = 0.0
    elif outside[-1] == len(t) - 1:
        m["settling_time_s"] = math.nan            # still outside the band at the end of the run
    else:
        m["settling_time_s"] = float(t[outside[-1] + 1])
    if not all(math.isfinite(v) for k, v in m.items() if k not in ("settling_time_s", "overshoot_pct")):
        raise FlexlinkError("the run diverged (non-finite outputs)")
    return m, res.series


def _open_loop_case(job: _WorkerJob, params: dict[str, float]) -> tuple[dict, dict]:
    from fmpy.fmi1 import FMICallException

    s = job.spec.settings
    runner = job.instance()
    outputs = list(dict.fromkeys([*s["record"], *job.spec.series]))
    n_msg = len(runner.messages)
    t0 = time.perf_counter()
    try:
        res = runner.run(s["stop_time"], s["sample_time"], start=params, outputs=outputs)
    except FMICallException as e:
        detail = "; ".join(m.replace("%%", "%") for m in runner.messages[n_msg:][-3:]) or "no message from the FMU"
        raise FlexlinkError(f"{job.spec.fmu_name}: {e}: {detail}") from None
    wall = time.perf_counter() - t0
    t = res["time"]
    theta = res[s["joint_theta"]]
    tip = res[s["tip"]]
    window = t >= t[-1] - s["settle"] - 1e-12
    torques = [np.max(np.abs(res[n])) for n in s["torques"] if n in res]
    torques += [abs(float(params.get(n, s["torque_start"].get(n, 0.0)))) for n in s["torque_start"]]
    m = {
        "final_angle_deg": math.degrees(float(theta[-1])),
        "final_tip_deflection_m": float(tip[-1]),
        "max_tip_deflection_m": float(np.max(np.abs(tip))),
        "residual_vibration_rms_m": float(np.sqrt(np.mean((tip[window] - np.mean(tip[window])) ** 2))),
        "peak_torque_nm": float(max(torques)) if torques else math.nan,
        "realtime_factor": float(t[-1] / wall) if wall > 0 else math.nan,
    }
    if not all(math.isfinite(v) for k, v in m.items() if k != "peak_torque_nm"):
        raise FlexlinkError("the run diverged (non-finite outputs)")
    return m, res


def _run_case(spec: _SweepJob, case: int, params: dict[str, float]) -> dict:
    """One case on this worker: a row (never raises for a failing case)."""
    t0 = time.perf_counter()
    row: dict = {"case": case, "key": case_key(params), **params}
    job = _worker_job(spec)
    try:
        with Deadline(spec.case_timeout):
            metrics, series = (_closed_loop_case if spec.mode == "closed" else _open_loop_case)(job, params)
        row.update(status="ok", failed=False, error="")
        row.update(metrics)
        if spec.series:
            every = max(1, spec.series_every)
            row["series.time"] = [float(x) for x in series["time"][::every]]
            for name in spec.series:
                row[f"series.{name}"] = [float(x) for x in series[name][::every]]
    except CaseTimeout:
        job.drop_instance()   # stopped mid-run: a fresh instance for the next case
        row.update(status="timeout", failed=True, error=f"timed out: still running after the case timeout of "
                                                        f"{spec.case_timeout:g} s (wall clock)")
    except Exception as e:  # noqa: BLE001 (every failure of a case is a result)
        job.drop_instance()   # an instance that reported an error is not trusted with the next case
        row.update(status="failed", failed=True, error=_error_text(e))
    row["wall_s"] = time.perf_counter() - t0
    row["worker"] = _worker_name()
    return row


def _run_batch(spec: _SweepJob, batch: list[tuple[int, dict[str, float]]]) -> list[dict]:
    return [_run_case(spec, case, params) for case, params in batch]


# ============================================================================ journal and output file
def journal_path(out: str | os.PathLike) -> Path:
    """The JSON-lines journal kept beside the output file (``results.parquet.journal.jsonl``)."""
    return Path(f"{os.fspath(out)}.journal.jsonl")


def _read_journal(path: Path) -> tuple[dict | None, list[dict]]:
    """Header and rows of a journal.

    Records are whole lines, written and flushed one by one, so a line that is not a JSON object was torn by a
    crash while it was written: it is skipped (its case is run again).
    """
    header, rows = None, []
    with path.open(errors="replace") as f:
        lines = f.read().splitlines()
    for line in lines:
        try:
            doc = json.loads(line)
        except json.JSONDecodeError:
            continue
        if not isinstance(doc, dict) or ("case" in doc and "key" not in doc):
            continue
        if "sweep" in doc and "case" not in doc:
            header = header or doc
        else:
            rows.append(doc)
    return header, rows


def _read_output(path: Path):
    import pandas as pd

    try:
        return pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    except Exception as e:  # noqa: BLE001
        raise FlexlinkError(f"{path}: cannot read the results file to resume from it ({e})") from None


class _Journal:
    def __init__(self, path: Path, header: dict):
        self.path = path
        fresh = not path.exists() or path.stat().st_size == 0
        if not fresh:      # a torn last line would swallow the next record: end it first
            with path.open("rb") as f:
                f.seek(-1, os.SEEK_END)
                torn = f.read(1) != b"\n"
        self.f = path.open("a")
        if fresh:
            self.write([header])
        elif torn:
            self.f.write("\n")

    def write(self, docs: list[dict]) -> None:
        for doc in docs:
            self.f.write(json.dumps(doc, default=_json_default) + "\n")
        self.f.flush()
        os.fsync(self.f.fileno())

    def close(self) -> None:
        self.f.close()


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def _write_output(df, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    if path.suffix == ".parquet":
        df.to_parquet(tmp, index=False)
    else:
        out = df.copy()
        for c in out.columns:
            if c.startswith("series."):
                out[c] = [json.dumps(v) if isinstance(v, list) else v for v in out[c]]
        out.to_csv(tmp, index=False)
    tmp.replace(path)


# ============================================================================ the sweep
def _design(model, *, controller, target, duration, sample_time, torque_limit, sensors, weights=None):
    from controllers.manoeuvre import _target, check_scene, default_torque_limit, design
    from controllers.weights import bryson_limits, torque_limits
    from flexlink.run.linearize import linear_plant

    check_scene(model)
    plant = linear_plant(model, outputs=[f"{model.scene.joints[0].name}.theta"])
    limit = torque_limits(plant, torque_limit)
    if limit is None:
        limit = default_torque_limit(plant, target - float(plant.x0[0]), duration)
    if isinstance(limit, float | int) and not limit > 0:
        raise FlexlinkError(f"--torque-limit must be positive, got {limit}")
    d = design(model, torque_limit=limit, dt=sample_time, sensors=sensors, limits=bryson_limits(model, weights))
    d.law(controller)
    _target(d, target)          # checks the manoeuvre and caches the static deflection for the workers
    return d


_DESIGNS: dict[str, tuple] = {}     # this process's designs: (ControlDesign, its cloudpickle)



def _sweep_id(doc: dict) -> str:
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:16]


@dataclass
class _Prepared:
    """What a sweep is once its scene is read and its FMU known: the cases, the identity, the shared settings."""

    name: str                             # the scene's name, for the progress bar
    kind: str                             # "grid" | "monte-carlo"
    cases: list[dict[str, float]]
    names: list[str]                      # the swept parameters
    fmu_path: Path
    mode: str                             # "closed" | "open"
    metric_names: Sequence[str]
    settings: dict
    make_design: Callable[[], tuple[dict, bytes]] | None
    sweep: str                            # the sweep's identity in a journal


def run_sweep(spec: SweepSpec, *, client: object = None,
              on_result: Callable[[dict, int, int], None] | None = None):
    """Run the parameter sweep ``spec`` describes and return one row per case as a pandas DataFrame.

    Parameters
    ----------
    spec : SweepSpec
        The sweep: scene, cases, what each case runs, output file and scheduling.
    client : dask.distributed.Client, optional
        An existing Dask client to run the cases on (``spec.scheduler`` and ``spec.n_workers`` are then
        unused); it is not closed.
    on_result : callable, optional
        ``on_result(row, done, total)`` after each completed case (in this process).

    Returns
    -------
    pandas.DataFrame
        Columns ``case``, the parameters, ``status``, ``failed``, ``error``, the metrics, ``wall_s``,
        ``worker``, ``key``, ``sweep``; ``df.attrs``: ``kind`` (grid / monte-carlo), ``parameters``,
        ``computed`` (cases run now), ``resumed`` (taken from the journal), ``wall_s``, ``mode``.
    """
    t_start = time.perf_counter()
    prep = _prepare(spec)
    out = Path(spec.out) if spec.out is not None else None
    done: dict[str, dict] = {}
    rejournal: list[dict] = []
    if out is not None:
        done, rejournal = _results_so_far(out, sweep=prep.sweep, resume=spec.resume, overwrite=spec.overwrite)
        done = {k: r for k, r in done.items() if r.get("status") != "timeout"}
    todo = [(i, c) for i, c in enumerate(prep.cases) if case_key(c) not in done]
    resumed = len(prep.cases) - len(todo)
    new_rows: dict[str, dict] = {}
    run_settings = prep.settings
    job = None
    # the controller is designed before anything on disk changes: a design refused (a weight's count) leaves
    # FILE and its journal as they were, an overwrite's included, and no journal of its own
    if todo:
        job = _sweep_job(prep.sweep, prep.fmu_path, prep.settings, prep.make_design,
                         shared_fs=spec.shared_fs, mode=prep.mode, metric_names=prep.metric_names,
                         series=spec.series, series_every=spec.series_every)
        job.case_timeout = spec.case_timeout
        run_settings = job.settings
    journal = None
    if out is not None:
        journal = _open_journal(out, {"sweep": prep.sweep, "scene": str(Path(spec.scene)), "mode": prep.mode,
                                      "settings": prep.settings}, overwrite=spec.overwrite, rows=rejournal)
    try:
        if job is not None:
            new_rows = _run_cases(job, todo, sweep=prep.sweep, total=len(prep.cases), resumed=resumed,
                                  desc=f"sweep {prep.name}", progress=spec.progress, journal=journal,
                                  on_result=on_result, scheduler=spec.scheduler, client=client,
                                  n_workers=spec.n_workers, batch_size=spec.batch_size)
    finally:
        if journal is not None:
            journal.close()
    df = _frame(_case_rows(prep.cases, prep.names, done, new_rows), prep.names, prep.metric_names, spec.series)
    df.attrs.update(kind=prep.kind, parameters=prep.names, computed=len(todo), resumed=resumed, mode=prep.mode,
                    wall_s=time.perf_counter() - t_start, sweep=prep.sweep, settings=run_settings,
                    journal=str(journal_path(out)) if out is not None else None)
    if out is not None:
        _write_output(df, out)
    return df


def _prepare(spec: SweepSpec) -> _Prepared:
    """Read the scene, draw the cases, find (or build) the FMU and check the names against it, settle the mode.

    The sweep's identity hashes the scene file and every setting that changes a row, so that a journal is
    resumed only by the very same sweep.
    """
    import flexlink
    from flexlink.export.cache import cached_fmu
    from flexlink.scene.loader import load_scene

    scene_path = Path(spec.scene)
    sc = load_scene(scene_path)
    weights = _weights(sc, spec)
    kind, cases = spec.cases()
    names = list(cases[0])
    fmu_path = Path(spec.fmu) if spec.fmu is not None else cached_fmu(scene_path)
    variables = _fmu_variables(fmu_path, names, spec.series)
    mode, metric_names, settings, make_design = _sweep_settings(
        sc, scene_path, variables, controller=spec.controller, target_deg=spec.target_deg, duration=spec.duration,
        settle=spec.settle, settle_band=spec.settle_band, torque_limit=spec.torque_limit, sensors=spec.sensors,
        stop_time=spec.stop_time, sample_time=spec.sample_time, weights=weights)
    sweep = _sweep_id({"scene": hashlib.sha256(scene_path.read_bytes()).hexdigest(), "mode": mode,
                       "settings": settings, "series": list(spec.series), "series_every": spec.series_every,
                       "flexlink": flexlink.__version__})
    return _Prepared(sc.name, kind, cases, names, fmu_path, mode, metric_names, settings, make_design, sweep)


def _weights(sc, spec: SweepSpec) -> dict:
    """The LQR's limits the spec gives (names checked against the scene before any build), for the settings."""
    from types import SimpleNamespace

    from controllers.weights import OPTIONS, check_names

    given = {name: getattr(spec, name) for name in OPTIONS if getattr(spec, name) is not None}
    if (given or spec.torque_limit is not None) and spec.controller is None:
        raise FlexlinkError("the LQR's limits (--torque-limit, --joint-error, ...) need a closed-loop manoeuvre "
                            "(--target, --duration)")
    check_names(sc, SimpleNamespace(torque_limit=spec.torque_limit, **{name: getattr(spec, name) for name in OPTIONS}))
    return given


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


def _fmu_variables(fmu_path: Path, names: list[str], series: Sequence[str]) -> dict:
    """The FMU's variables by name, once the swept names are checked to be its parameters.

    The series must be its variables too: both are refused here, before a worker starts, in one message.
    """
    import fmpy

    md = fmpy.read_model_description(str(fmu_path))
    variables = {v.name: v for v in md.modelVariables}
    tunable = [v.name for v in md.modelVariables if v.causality == "parameter"]
    for name in names:
        if name not in tunable:
            raise FlexlinkError(f"--param {name}: not a parameter of the FMU; its parameters are "
                                + ", ".join(tunable))
    for name in series:
        if name not in variables:
            raise FlexlinkError(f"--series {name}: the FMU has no variable of that name")
    return variables


def _sweep_settings(sc, scene_path: Path, variables: dict, *, controller, target_deg, duration, settle, settle_band,
                    torque_limit, sensors, stop_time, sample_time, weights=None):
    """The mode, metric names and settings shared by every case, which identify the sweep.

    ``weights``: the LQR's limits by option (:func:`_weights`), in the settings (``"weights"``) when given.

    Returns ``(mode, metric_names, settings, make_design or None)``: for closed loop the controller design is
    deferred (it takes seconds) until there are cases to run.
    """
    joint, link = sc.joints[0].name, sc.links[-1].name
    settings: dict = {"sample_time": float(sample_time), "settle": float(settle)}
    if controller is not None and target_deg is not None and duration is not None:
        from controllers import montecarlo

        if len(montecarlo.torque_joints(sc)) > 1:
            settings.update(montecarlo.settings(sc, controller, target_deg, duration, settle, sample_time,
                                                torque_limit, sensors))
            if weights:
                settings["weights"] = weights
            make_design = functools.partial(_closed_loop_design, sc, scene_path, settings, controller=controller,
                                            target_deg=target_deg, duration=duration, sample_time=sample_time,
                                            torque_limit=torque_limit, sensors=sensors)
            return "closed", montecarlo.MULTIJOINT_METRICS, settings, make_design
        target_deg = _one_angle(target_deg)
    if controller is not None:
        from controllers.manoeuvre import CONTROLLERS, _check_times

        if controller not in CONTROLLERS:
            raise FlexlinkError(f"--controller: expected one of {CONTROLLERS}, got {controller!r}")
        if target_deg is None or duration is None:
            raise FlexlinkError("a closed-loop sweep needs --target DEG and --duration S")
        _check_times(duration, settle, sample_time)
        settings.update(controller=controller, target=math.radians(target_deg), target_deg=float(target_deg),
                        duration=float(duration), settle_band=float(settle_band), torque_limit=torque_limit,
                        sensors=sensors, record=[f"{joint}.theta", f"{link}.tip.v"])
        if weights:
            settings["weights"] = weights
        make_design = functools.partial(_closed_loop_design, sc, scene_path, settings, controller=controller,
                                        target_deg=target_deg, duration=duration, sample_time=sample_time,
                                        torque_limit=torque_limit, sensors=sensors)
        return "closed", CLOSED_LOOP_METRICS, settings, make_design
    if not (math.isfinite(stop_time) and stop_time > 0):
        raise FlexlinkError(f"--stop-time must be a positive number of seconds, got {stop_time}")
    if abs(round(stop_time / sample_time) * sample_time - stop_time) > 1e-9 * max(1.0, stop_time):
        raise FlexlinkError(f"--stop-time {stop_time} s must be a multiple of the sample time {sample_time} s")
    torques_out = [f"{j.name}.tau" for j in sc.joints
                   if f"{j.name}.tau" in variables and variables[f"{j.name}.tau"].causality == "output"]
    torque_start = {f"{j.name}.tau": float(variables[f"{j.name}.tau"].start or 0.0) for j in sc.joints
                    if f"{j.name}.tau" in variables and variables[f"{j.name}.tau"].causality == "input"}
    settings.update(stop_time=float(stop_time), joint_theta=f"{joint}.theta", tip=f"{link}.tip.v",
                    torques=torques_out, torque_start=torque_start,
                    record=[f"{joint}.theta", f"{link}.tip.v", *torques_out])
    return "open", OPEN_LOOP_METRICS, settings, None


def _one_angle(target_deg) -> float:
    angles = [float(v) for v in np.atleast_1d(target_deg)]
    if len(angles) != 1:
        raise FlexlinkError(f"--target: one angle for the scene's one torque-driven joint, got {len(angles)}")
    return angles[0]


def _closed_loop_design(sc, scene_path: Path, settings: dict, *, controller, target_deg, duration, sample_time,
                        torque_limit, sensors) -> tuple[dict, bytes]:
    """Linearisation and design (seconds): only when there are cases to run; reused in this process."""
    import cloudpickle

    from flexlink.mechanics.model import build_model

    dkey = json.dumps([hashlib.sha256(scene_path.read_bytes()).hexdigest(), controller,
                       [float(v) for v in np.atleast_1d(target_deg)], float(duration), float(sample_time),
                       torque_limit, sensors, settings.get("weights")])
    if dkey not in _DESIGNS:
        if settings.get("multijoint"):
            from controllers.montecarlo import design

            d = design(build_model(sc), settings, sample_time)
        else:
            d = _design(build_model(sc), controller=controller, target=math.radians(target_deg),
                        duration=duration, sample_time=sample_time, torque_limit=torque_limit, sensors=sensors,
                        weights=settings.get("weights"))
        while len(_DESIGNS) >= 4:
            _DESIGNS.pop(next(iter(_DESIGNS)))
        _DESIGNS[dkey] = (d, cloudpickle.dumps(d))
    d, blob = _DESIGNS[dkey]
    return {**settings, "torque_limit": d.torque_limit}, blob


def _results_so_far(out: Path, *, sweep: str, resume: bool, overwrite: bool) -> tuple[dict[str, dict], list[dict]]:
    """The rows already done (by case key), and those to journal again; nothing on disk is changed.

    The rows come from ``out``'s journal or, without one, from ``out`` itself (whose rows are then the second
    list: :func:`_open_journal` journals them again).  Another sweep's results are refused unless ``overwrite``,
    so that rows of different settings never mix in one file.  With ``overwrite`` nothing is read: FILE and
    its journal are discarded by :func:`_open_journal`, once the sweep's design is accepted, so that an
    overwrite refused before any case runs loses nothing and leaves no journal of its own behind.
    """
    if out.suffix not in (".parquet", ".csv"):
        raise FlexlinkError(f"--out {out}: expected a .parquet or .csv file name")
    if overwrite:
        return {}, []
    jpath = journal_path(out)
    old_rows: list[dict] = []
    source = None
    if jpath.exists():
        header, old_rows = _read_journal(jpath)
        source = jpath
        if header is not None and header.get("sweep") != sweep:
            old_rows = [{"sweep": header.get("sweep")}]
    elif out.exists():
        df_old = _read_output(out)
        source = out
        old_rows = df_old.to_dict("records")
    if source is not None and not resume:
        raise FlexlinkError(f"{source} exists: resume it, or pass --overwrite to start again")
    other = {r.get("sweep") for r in old_rows} - {sweep}
    if other:
        raise FlexlinkError(f"{source} holds a sweep with other settings (scene, mode, manoeuvre or series): "
                            "pass --overwrite to replace it, or choose another --out")
    return {r["key"]: r for r in old_rows}, old_rows if source == out else []


def _open_journal(out: Path, header: dict, *, overwrite: bool, rows: list[dict]) -> _Journal:
    """``out``'s journal opened for appending, with ``rows`` (a consolidated file's) journaled again.

    With ``overwrite``, ``out`` and its journal are discarded first: the sweep starts afresh.
    """
    jpath = journal_path(out)
    if overwrite:
        for p in (out, jpath):
            p.unlink(missing_ok=True)
    journal = _Journal(jpath, header)
    if rows:
        journal.write([{k: v for k, v in r.items() if not _is_missing(v)} for r in rows])
    return journal


def _sweep_job(sweep: str, fmu_path: Path, settings: dict, make_design, *, shared_fs: bool, mode: str,
                metric_names: Sequence[str], series: Sequence[str], series_every: int) -> _SweepJob:
    """The job shipped to the workers, with the controller designed now that there are cases to run."""
    run_settings, design_blob = make_design() if make_design is not None else (settings, None)
    return _SweepJob(key=f"{sweep}-{os.getpid()}-{time.time_ns()}", fmu_name=fmu_path.name,
                     fmu_bytes=None if shared_fs else fmu_path.read_bytes(),
                     fmu_path=str(fmu_path.resolve()) if shared_fs else None, mode=mode,
                     settings=run_settings, design_blob=design_blob, series=tuple(series),
                     series_every=series_every, metrics=tuple(metric_names))


def _run_cases(spec: _SweepJob, todo, *, sweep: str, total: int, resumed: int, desc: str, progress, journal,
               on_result, scheduler, client, n_workers, batch_size) -> dict[str, dict]:
    """Run the cases not done yet (serially or on Dask), journaling each row as it arrives; rows by case key."""
    from tqdm.auto import tqdm

    new_rows: dict[str, dict] = {}
    bar = tqdm(total=total, initial=resumed, desc=desc, unit="case",
               disable=None if progress is None else not progress, file=sys.stderr, dynamic_ncols=True)
    n_done = resumed

    def collect(rows: list[dict]) -> None:
        nonlocal n_done
        for r in rows:
            r["sweep"] = sweep
        if journal is not None:
            journal.write(rows)
        for r in rows:
            new_rows[r["key"]] = r
            n_done += 1
            if on_result is not None:
                on_result(r, n_done, total)
        bar.update(len(rows))

    try:
        if scheduler == "serial" and client is None:
            _run_serial(spec, todo, collect)
        else:
            _run_on_dask(spec, todo, collect, client=client, scheduler=scheduler, n_workers=n_workers,
                         batch_size=batch_size)
    finally:
        bar.close()
    return new_rows


def _run_serial(spec: _SweepJob, todo, collect) -> None:
    """``scheduler="serial"``: the cases in a plain loop in this process, then this sweep's FMU instances freed."""
    for case, c in todo:
        collect([_run_case(spec, case, c)])
    with _JOBS_LOCK:
        for job in [j for j in _ALL_JOBS if j.spec.key == spec.key]:
            job.close()
            _ALL_JOBS.remove(job)
    getattr(_LOCAL, "jobs", {}).pop(spec.key, None)


def _case_rows(cases: list[dict[str, float]], names: list[str], done: dict[str, dict],
               new_rows: dict[str, dict]) -> list[dict]:
    """One row per case of the sweep, in case order, from this run or the journal.

    Each row is numbered by this sweep's case order (a resumed row may come from a sweep of another order) and
    carries the exact parameter values of its case.
    """
    rows = []
    for i, c in enumerate(cases):
        k = case_key(c)
        r = dict(new_rows.get(k) or done[k])
        r["case"] = i
        for name in names:
            r[name] = c[name]
        rows.append(r)
    return rows


def _is_missing(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _frame(rows: list[dict], names: list[str], metric_names: Sequence[str], series: Sequence[str]):
    import pandas as pd

    df = pd.DataFrame(rows)
    cols = ["case", *names, "status", "failed", "error", *metric_names]
    cols += [c for c in ("series.time", *(f"series.{n}" for n in series)) if series]
    cols += ["wall_s", "worker", "key", "sweep"]
    for c in cols:
        if c not in df.columns:
            df[c] = math.nan
    df = df[cols].copy()
    df["failed"] = df["failed"].astype(bool)
    df["error"] = ["" if _is_missing(e) else str(e) for e in df["error"]]
    df["status"] = df["status"].astype(str)
    df["worker"] = df["worker"].astype(str)
    for c in (*names, *metric_names, "wall_s"):
        df[c] = pd.to_numeric(df[c], errors="coerce").astype(float)
    return df.sort_values("case", kind="stable").reset_index(drop=True)


def _run_on_dask(spec: _SweepJob, todo, collect, *, client, scheduler, n_workers, batch_size) -> None:
    import logging

    from dask.distributed import Client, LocalCluster, as_completed

    own_cluster = own_client = None
    try:
        if client is None:
            if scheduler:
                try:
                    client = own_client = Client(scheduler, timeout="20s")
                except (OSError, TimeoutError) as e:
                    raise FlexlinkError(f"--scheduler {scheduler}: cannot connect ({e})") from None
            else:
                n = n_workers or len(os.sched_getaffinity(0)) or 1
                own_cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.ERROR)
                client = own_client = Client(own_cluster)
        n_slots = max(1, sum(client.nthreads().values()))
        size = batch_size or max(1, min(16, math.ceil(len(todo) / (4 * n_slots))))
        batches = [todo[i:i + size] for i in range(0, len(todo), size)]
        job = client.scatter(spec, broadcast=True, hash=False)
        futures = {}

        def submit(k: int, attempt: int):
            f = client.submit(_run_batch, job, batches[k], key=f"flexlink-sweep-{spec.key}-{k}-{attempt}",
                              pure=False)
            futures[f.key] = (k, attempt)
            return f

        ac = as_completed([submit(k, 0) for k in range(len(batches))])
        for fut in ac:
            k, attempt = futures.pop(fut.key)
            if fut.status == "finished":
                collect(fut.result())
            else:
                exc = fut.exception() if fut.status == "error" else None
                if attempt == 0:
                    ac.add(submit(k, 1))      # e.g. KilledWorker after repeated worker deaths: once more
                else:
                    msg = f"the Dask task failed: {_error_text(exc) if exc else fut.status}"
                    collect([{"case": case, "key": case_key(c), **c, "status": "failed", "failed": True,
                              "error": msg, "wall_s": math.nan, "worker": ""} for case, c in batches[k]])
            fut.release()
    finally:
        if own_client is not None:
            try:
                own_client.close()
            except Exception:  # noqa: BLE001 (closing is best effort)
                pass
        if own_cluster is not None:
            own_cluster.close()


# ============================================================================ summary and plots
def summary_table(df) -> str:
    """A plain-text summary: cases, failures (grouped by message), and per metric count/mean/std/min/max."""
    from controllers.montecarlo import MULTIJOINT_METRICS

    metrics = [c for c in (*CLOSED_LOOP_METRICS, *OPEN_LOOP_METRICS, *MULTIJOINT_METRICS) if c in df.columns]
    metrics = list(dict.fromkeys(metrics))
    ok = df[~df["failed"]]
    lines = [f"{len(df)} cases ({df.attrs.get('kind', 'sweep')}): {len(ok)} ok, {int(df['failed'].sum())} failed"
             + (f"; {df.attrs['computed']} computed now, {df.attrs['resumed']} from the journal"
                if "computed" in df.attrs else "")]
    if df["failed"].any():
        lines.append("failures:")
        for msg, n in df.loc[df["failed"], "error"].value_counts().head(5).items():
            cases = df.loc[df["failed"] & (df["error"] == msg), "case"].tolist()
            shown = ", ".join(map(str, cases[:6])) + (", ..." if len(cases) > 6 else "")
            lines.append(f"  {n} x (case {shown}): {msg[:200]}")
    w = max(len(m) for m in metrics) if metrics else 10
    lines.append(f"  {'metric':<{w}} {'n':>5} {'mean':>11} {'std':>11} {'min':>11} {'max':>11}")
    for m in metrics:
        v = ok[m].dropna()
        if len(v) == 0:
            lines.append(f"  {m:<{w}} {0:>5}")
            continue
        std = v.std() if len(v) > 1 else 0.0
        lines.append(f"  {m:<{w}} {len(v):>5} {v.mean():>11.4g} {std:>11.4g} {v.min():>11.4g} {v.max():>11.4g}")
    return "\n".join(lines)


def plot_sweep(df, path: str | os.PathLike, title: str = "") -> None:
    """Plot a sweep's metrics: against the swept parameter for a grid, as histograms for Monte Carlo.

    A grid draws each metric against the first varying parameter, a line per value of the others (failed cases
    as red lines); a Monte Carlo sweep has no axis to draw against, so its metrics are shown as distributions.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(df.attrs.get("parameters") or [])
    metrics = [m for m in PLOT_METRICS if m in df.columns and df[m].notna().any()]
    if not metrics:
        raise FlexlinkError("--plot: no successful case to plot")
    ok = df[~df["failed"]]
    ncol = 2 if len(metrics) > 1 else 1
    nrow = math.ceil(len(metrics) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6.0 * ncol, 3.0 * nrow + 0.6), squeeze=False)
    varying = [n for n in names if df[n].nunique() > 1]
    grid = df.attrs.get("kind") == "grid"
    for ax, m in zip(axes.flat, metrics, strict=False):
        if grid and varying:
            x = varying[0]
            others = varying[1:]
            groups = list(ok.groupby(others)) if others else [((), ok)]
            if len(groups) <= 8:
                for key, g in groups:
                    key = key if isinstance(key, tuple) else (key,)
                    label = ", ".join(f"{n}={v:.4g}" for n, v in zip(others, key, strict=True)) or None
                    g = g.sort_values(x)
                    ax.plot(g[x], g[m], marker="o", ms=3, lw=1.0, label=label)
                if others:
                    ax.legend(fontsize=6)
            else:
                sc = ax.scatter(ok[x], ok[m], c=ok[others[0]], s=10, cmap="viridis")
                fig.colorbar(sc, ax=ax, label=others[0])
            bad = df[df["failed"]]
            for xv in bad[x]:
                ax.axvline(xv, color="red", lw=0.6, alpha=0.4)
            ax.set_xlabel(x)
        else:
            v = ok[m].dropna()
            ax.hist(v, bins=max(5, min(40, int(math.sqrt(len(v))) + 1)), color="tab:blue", alpha=0.8)
            ax.set_xlabel(m)
            ax.set_ylabel("cases")
        ax.set_title(m, fontsize=9)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(metrics):]:
        ax.set_visible(False)
    n_bad = int(df["failed"].sum())
    fig.suptitle((title + ": " if title else "") + f"{len(df)} cases"
                 + (f", {n_bad} failed" + (" (red lines)" if grid and varying else "") if n_bad else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
