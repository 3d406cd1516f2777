"""A sweep's results on disk: the journal that makes a sweep resumable, the results file, and their table.

Apart from the orchestration (:mod:`controllers.sweep`) because what is on disk has rules of its own that no
run should need to know: completed rows are appended to a JSON-lines journal beside the results file
(``FILE.journal.jsonl``, flushed and fsync'ed row by row, a torn last line skipped), a journal or file of
another sweep is refused unless ``--overwrite``, an overwrite changes nothing until the sweep's design is
accepted, and at the end the rows (from this run or the journal) become one table, one row per case in case
order, written to ``.parquet`` or ``.csv`` through a temporary file.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from controllers.sweep_cases import case_key
from flexlink.errors import FlexlinkError

__all__ = ["case_rows", "journal_path", "open_journal", "results_frame", "results_so_far", "write_output"]

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


def write_output(df, path: Path) -> None:
    """``df`` written to ``path`` (``.parquet``, else CSV with the series as JSON text), replacing it whole."""
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


def results_so_far(out: Path, *, sweep: str, resume: bool, overwrite: bool) -> tuple[dict[str, dict], list[dict]]:
    """The rows already done (by case key), and those to journal again; nothing on disk is changed.

    The rows come from ``out``'s journal or, without one, from ``out`` itself (whose rows are then the second
    list: :func:`open_journal` journals them again).  Another sweep's results are refused unless ``overwrite``,
    so that rows of different settings never mix in one file.  With ``overwrite`` nothing is read: FILE and
    its journal are discarded by :func:`open_journal`, once the sweep's design is accepted, so that an
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


def open_journal(out: Path, header: dict, *, overwrite: bool, rows: list[dict]) -> _Journal:
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


def case_rows(cases: list[dict[str, float]], names: list[str], done: dict[str, dict],
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


def results_frame(rows: list[dict], names: list[str], metric_names: Sequence[str], series: Sequence[str]):
    """The rows as the sweep's DataFrame: its columns in a fixed order (missing ones NaN), typed, by case."""
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
