"""benchmarks/scaling.py's command line: a re-run of the issue's table needs the families of an earlier run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "scaling.py"


def test_table_only_without_an_earlier_run_is_one_clear_error(tmp_path):
    """--table-only into a directory without scaling.json: exit status 2 and one line naming the file (it was a
    FileNotFoundError traceback), and nothing written there."""
    run = subprocess.run([sys.executable, str(SCRIPT), "--table-only", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2
    assert "Traceback" not in run.stderr and str(tmp_path / "scaling.json") in run.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_table_is_timed_in_turns(tmp_path, monkeypatch):
    """retime_interleaved runs each row's driver once a round, in turns, and takes the median of its rounds:
    drivers that print a different time each round (a file counts their calls) and a row without a driver."""
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import scaling

    log = tmp_path / "calls"
    driver = ("import json, sys, pathlib; p = pathlib.Path(sys.argv[1]); p.open('a').write(sys.argv[2]); "
              "n = p.read_text().count(sys.argv[2]); "
              "print(json.dumps({'step_s': float(sys.argv[2]) * [1, 9, 2][n - 1] * 1e-6, 'residual_s': 1e-6}))")
    rows = [{"timing": [sys.executable, "-c", driver, str(log), "1"], "step_us": 0.0},
            {"timing": [sys.executable, "-c", driver, str(log), "3"], "step_us": 0.0},
            {"timing": None, "step_us": 7.0}]
    scaling.retime_interleaved(rows, 3)
    assert log.read_text() == "131313"                     # in turns, not one row's runs after the other
    assert [r["step_us"] for r in rows] == [2.0, 6.0, 7.0]   # medians of (1, 9, 2) and (3, 27, 6); untouched
    assert rows[0]["interleaved_runs"] == 3 and "interleaved_runs" not in rows[2]
