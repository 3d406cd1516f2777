"""``flexlink bench`` (CI size): the work–precision rows are what they claim to be.

The SS22 rows converge at order 2 against the reference (so the "error" column measures integration
error, not a modelling difference), the reference is far more accurate than any row, and tighter
tolerances make CVODES more accurate."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from flexlink.bench import run_bench


@pytest.fixture(scope="module")
def quick_bench():
    return run_bench("examples/rotating_link_linear.toml", quick=True, repeats=1)


def test_rows_and_reference(quick_bench):
    rows, info = quick_bench
    assert info["reference_error"] < 1e-8
    assert {r.method for r in rows} >= {"ss22 (FMU)", "fmpy CVODE (ME)", "cvodes", "idas", "scipy Radau"}
    for r in rows:
        assert np.isfinite(r.error) and r.error > 10 * info["reference_error"]
        assert r.cpu_s_per_simulated_s > 0


def test_ss22_rows_converge_at_order_two(quick_bench):
    rows, _ = quick_bench
    errors = [r.error for r in rows if r.method == "ss22 (FMU)"]        # steps halve from row to row
    orders = [np.log2(a / b) for a, b in zip(errors[:-1], errors[1:], strict=True)]
    assert all(abs(p - 2.0) < 0.5 for p in orders[1:]), orders


def test_cvodes_tighter_tolerance_is_more_accurate(quick_bench):
    rows, _ = quick_bench
    errors = [r.error for r in rows if r.method == "cvodes"]
    assert errors[1] < errors[0] / 10


def test_cli_json(tmp_path):
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "bench", "examples/rotating_link_linear.toml",
                          "--quick", "--repeats", "1", "--json", "--report", str(tmp_path / "r.md")],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    rows = json.loads(out.stdout)
    assert set(rows[0]) == {"method", "setting", "cpu_s_per_simulated_s", "error"}
    assert (tmp_path / "r.md").read_text().startswith("# Speed against error")
