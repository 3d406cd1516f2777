"""Where a sweep's cases run: a plain loop in this process, an embedded Dask ``LocalCluster``, or a running one.

Apart from the orchestration (:mod:`controllers.sweep`) because scheduling is its own failure domain: a Dask
task whose worker died is resubmitted once and then recorded as failed rows, a scheduler that cannot be
reached is one message, and a cluster this sweep started is closed whatever happens.  Whatever the
scheduler, every row comes back through one ``collect`` that journals it as it arrives and moves the
progress bar; the rows are the workers' (:mod:`controllers.sweep_worker`).
"""

from __future__ import annotations

import math
import os
import sys

from controllers.sweep_cases import case_key
from controllers.sweep_worker import SweepJob, error_text, release_jobs, run_batch, run_case, worker_dir_prefix
from flexlink.errors import FlexlinkError

__all__ = ["run_cases"]

def run_cases(spec: SweepJob, todo, *, sweep: str, total: int, resumed: int, desc: str, progress, journal,
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


def _run_serial(spec: SweepJob, todo, collect) -> None:
    """``scheduler="serial"``: the cases in a plain loop in this process, then this sweep's FMU instances freed."""
    for case, c in todo:
        collect([run_case(spec, case, c)])
    release_jobs(spec.key)


def _run_on_dask(spec: SweepJob, todo, collect, *, client, scheduler, n_workers, batch_size) -> None:
    import logging

    from dask.distributed import Client, LocalCluster, as_completed

    own_cluster = own_client = None
    finished = False            # every task done: no worker is still running one of this sweep's cases
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
            f = client.submit(run_batch, job, batches[k], key=f"flexlink-sweep-{spec.key}-{k}-{attempt}",
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
                    msg = f"the Dask task failed: {error_text(exc) if exc else fut.status}"
                    collect([{"case": case, "key": case_key(c), **c, "status": "failed", "failed": True,
                              "error": msg, "wall_s": math.nan, "worker": ""} for case, c in batches[k]])
            fut.release()
        finished = True
    finally:
        if finished:
            _release_workers(client, spec.key)
        if own_client is not None:
            try:
                own_client.close()
            except Exception:  # noqa: BLE001 (closing is best effort)
                pass
        if own_cluster is not None:
            own_cluster.close()
        if finished or own_cluster is not None:     # else a caller's worker may still be running a case there
            _remove_worker_dirs(spec.key)


def _release_workers(client, key: str) -> None:
    """Every worker frees this sweep's FMU instances and removes its copy of the FMU.

    A long-lived cluster would otherwise keep them until its workers exit (best effort: a worker may be gone).
    """
    if client is None:
        return
    try:
        client.run(release_jobs, key)
    except Exception:  # noqa: BLE001 (cleaning up is best effort)
        pass


def _remove_worker_dirs(key: str) -> None:
    """Remove the folders this sweep's workers on this machine left (one killed mid-sweep cannot remove its own).

    They are named for the sweep's key, unique to this run (pid and time), so nothing else is touched.
    """
    import glob
    import shutil
    import tempfile

    for folder in glob.glob(os.path.join(tempfile.gettempdir(), glob.escape(worker_dir_prefix(key)) + "*")):
        shutil.rmtree(folder, ignore_errors=True)
