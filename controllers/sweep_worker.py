"""What runs on a sweep's workers: the job they share, one FMU instance per worker thread, and one case's row.

Apart from the orchestration (:mod:`controllers.sweep`) because this is the code Dask ships to the worker
processes (:func:`run_batch` and the pickled :class:`SweepJob`): a worker imports this module, not the
scene-reading and journaling side of the sweep.  A case only sets the FMU's tunable parameters before
initialisation and turns the run into one row of named metrics (:data:`CLOSED_LOOP_METRICS`,
:data:`OPEN_LOOP_METRICS`); a failing case is a row too (``failed``/``error``), never an exception.  Each
worker thread keeps its FMU instance across cases (reset between them) and drops it after a failed case.
"""

from __future__ import annotations

import atexit
import math
import os
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from controllers.deadline import CaseTimeout, Deadline
from controllers.sweep_cases import case_key
from flexlink.errors import FlexlinkError

__all__ = ["CLOSED_LOOP_METRICS", "OPEN_LOOP_METRICS", "SweepJob", "error_text", "release_jobs", "run_batch",
           "run_case"]

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


@dataclass
class SweepJob:
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

    def __init__(self, spec: SweepJob):
        self.spec = spec
        self.dir = tempfile.mkdtemp(prefix=worker_dir_prefix(spec.key))
        if spec.fmu_bytes is not None:
            self.fmu = os.path.join(self.dir, spec.fmu_name)
            with open(self.fmu, "wb") as f:
                f.write(spec.fmu_bytes)
        else:
            assert spec.fmu_path is not None          # controllers.sweep gives the bytes or the path
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


def _worker_job(spec: SweepJob) -> _WorkerJob:
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


def error_text(e: BaseException) -> str:
    """A failure as one line of a row's ``error``: the message, with its exception's type unless it is ours."""
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

    from flexlink.run.host import FmuCallError

    s = job.spec.settings
    runner = job.instance()
    outputs = list(dict.fromkeys([*s["record"], *job.spec.series]))
    n_msg = len(runner.messages)
    t0 = time.perf_counter()
    try:
        res = runner.run(s["stop_time"], s["sample_time"], start=params, outputs=outputs)
    except FmuCallError:
        raise              # it names the FMU, the call and the FMU's logged reason already
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


def run_case(spec: SweepJob, case: int, params: dict[str, float]) -> dict:
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
        row.update(status="failed", failed=True, error=error_text(e))
    row["wall_s"] = time.perf_counter() - t0
    row["worker"] = _worker_name()
    return row


def run_batch(spec: SweepJob, batch: list[tuple[int, dict[str, float]]]) -> list[dict]:
    """One Dask task's cases, in order: their rows (:func:`run_case`)."""
    return [run_case(spec, case, params) for case, params in batch]


def worker_dir_prefix(key: str) -> str:
    """The name prefix of a worker's folder (its FMU's copy) for the sweep ``key``.

    The sweep's own, so that the client can remove the folders of workers killed before they could
    (:mod:`controllers.sweep_schedule`).
    """
    return f"flexlink-sweep-{key}-"


def release_jobs(key: str) -> None:
    """Free this process's FMU instances of the sweep ``key`` (a plain loop's, once its cases are done)."""
    with _JOBS_LOCK:
        for job in [j for j in _ALL_JOBS if j.spec.key == key]:
            job.close()
            _ALL_JOBS.remove(job)
    getattr(_LOCAL, "jobs", {}).pop(key, None)
