"""Parameter studies at scale: full grids and Monte Carlo runs of one FMU on Dask (``flexlink sweep``).

Its command line (parser, :class:`SweepSpec` from the options, the run) is :mod:`controllers.sweep_cli`.
This module is the orchestration (scene, FMU, identity, controller design, the run); each of its other
concerns is a module of its own, and its public names are importable from here:

* :mod:`controllers.sweep_spec`: :class:`SweepSpec`, its checks and its TOML spec file;
* :mod:`controllers.sweep_cases`: the cases, a grid or seeded Monte Carlo draws (:func:`make_cases`);
* :mod:`controllers.sweep_worker`: what runs on the workers, one case's row and its metrics;
* :mod:`controllers.sweep_schedule`: where the cases run (a plain loop, Dask);
* :mod:`controllers.sweep_journal`: the journal, resuming, ``--overwrite`` and the results file;
* :mod:`controllers.sweep_report`: the summary table and the plot.

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

import functools
import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controllers.sweep_cases import case_key, make_cases
from controllers.sweep_journal import (
    case_rows,
    journal_path,
    open_journal,
    results_frame,
    results_so_far,
    write_output,
)
from controllers.sweep_report import plot_sweep, summary_table
from controllers.sweep_schedule import run_cases
from controllers.sweep_spec import SweepSpec
from controllers.sweep_worker import CLOSED_LOOP_METRICS, OPEN_LOOP_METRICS, SweepJob
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


def _design(model, *, controller, target, duration, sample_time, torque_limit, sensors, weights=None):
    from controllers.manoeuvre import check_scene, default_torque_limit, design, static_tip
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
    static_tip(d, target)          # checks the manoeuvre and caches the static deflection for the workers
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
        done, rejournal = results_so_far(out, sweep=prep.sweep, resume=spec.resume, overwrite=spec.overwrite)
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
        journal = open_journal(out, {"sweep": prep.sweep, "scene": str(Path(spec.scene)), "mode": prep.mode,
                                      "settings": prep.settings}, overwrite=spec.overwrite, rows=rejournal)
    try:
        if job is not None:
            new_rows = run_cases(job, todo, sweep=prep.sweep, total=len(prep.cases), resumed=resumed,
                                  desc=f"sweep {prep.name}", progress=spec.progress, journal=journal,
                                  on_result=on_result, scheduler=spec.scheduler, client=client,
                                  n_workers=spec.n_workers, batch_size=spec.batch_size)
    finally:
        if journal is not None:
            journal.close()
    rows = case_rows(prep.cases, prep.names, done, new_rows)
    df = results_frame(rows, prep.names, prep.metric_names, spec.series)
    df.attrs.update(kind=prep.kind, parameters=prep.names, computed=len(todo), resumed=resumed, mode=prep.mode,
                    wall_s=time.perf_counter() - t_start, sweep=prep.sweep, settings=run_settings,
                    journal=str(journal_path(out)) if out is not None else None)
    if out is not None:
        write_output(df, out)
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
        from controllers.manoeuvre import CONTROLLERS
        from controllers.trajectory import check_times

        if controller not in CONTROLLERS:
            raise FlexlinkError(f"--controller: expected one of {CONTROLLERS}, got {controller!r}")
        if target_deg is None or duration is None:
            raise FlexlinkError("a closed-loop sweep needs --target DEG and --duration S")
        check_times(duration, settle, sample_time)
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


def _sweep_job(sweep: str, fmu_path: Path, settings: dict, make_design, *, shared_fs: bool, mode: str,
                metric_names: Sequence[str], series: Sequence[str], series_every: int) -> SweepJob:
    """The job shipped to the workers, with the controller designed now that there are cases to run."""
    run_settings, design_blob = make_design() if make_design is not None else (settings, None)
    return SweepJob(key=f"{sweep}-{os.getpid()}-{time.time_ns()}", fmu_name=fmu_path.name,
                     fmu_bytes=None if shared_fs else fmu_path.read_bytes(),
                     fmu_path=str(fmu_path.resolve()) if shared_fs else None, mode=mode,
                     settings=run_settings, design_blob=design_blob, series=tuple(series),
                     series_every=series_every, metrics=tuple(metric_names))
