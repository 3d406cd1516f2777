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
