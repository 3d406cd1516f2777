"""The design cache of ``flexlink control`` (issue 22): a repeated one-joint command runs from the cache.

* the cached run's figures are the designed run's (every figure but the realtime factor equal: the same law
  along the same reference through the same FMU), for the LQR and the PD;
* a process that runs from the cache never imports python-control or the design modules (``sys.modules``);
* a corrupt entry is a miss (the command designs again and rewrites it), the cache off
  (``FLEXLINK_DESIGN_CACHE=0``) writes nothing, and a changed option is another entry.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from conftest import EXAMPLES

SCENE = str(EXAMPLES / "rotating_link.toml")
ARGS = ["control", SCENE, "--target", "90", "--duration", "1.5", "--settle", "0.5", "--json"]

PROBE = """
import json, sys
from flexlink.cli import main
status = main(sys.argv[1:])
heavy = sorted(m for m in ("control", "controllers.manoeuvre", "controllers.design", "flexlink.run.linearize")
               if m in sys.modules)
print("MODULES " + json.dumps(heavy), file=sys.stderr)
sys.exit(status)
"""


def _run(args, cache_dir, **env):
    e = {**os.environ, "FLEXLINK_DESIGN_CACHE": str(cache_dir), **env}
    p = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True, text=True, env=e, timeout=600)
    assert p.returncode == 0, p.stderr
    modules = json.loads(next(ln for ln in p.stderr.splitlines() if ln.startswith("MODULES "))[8:])
    return json.loads(p.stdout), modules


@pytest.mark.parametrize("controller", ["lqr", "pd"])
def test_cached_run_is_the_designed_run(tmp_path, example_fmu, controller):
    example_fmu("rotating_link")                                        # the FMU built once, not per process
    args = [*ARGS, "--controller", controller]
    first, heavy_first = _run(args, tmp_path)
    assert "control" in heavy_first and len(list(tmp_path.glob("*.pickle"))) == 1
    again, heavy_again = _run(args, tmp_path)
    assert heavy_again == []                                            # no python-control, no design
    for k, v in first.items():
        if k != "realtime_factor":
            assert again[k] == v, k
    assert again["robustness"]["lqg"]["stable"]


def test_corrupt_entry_off_switch_and_other_options(tmp_path, example_fmu):
    example_fmu("rotating_link")
    first, _ = _run(ARGS, tmp_path)
    (entry,) = tmp_path.glob("*.pickle")
    entry.write_bytes(b"not a pickle")
    again, heavy = _run(ARGS, tmp_path)
    assert "control" in heavy and again["final_error_deg"] == first["final_error_deg"]
    _, heavy = _run(ARGS, tmp_path)
    assert heavy == []                                                 # rewritten by the run above
    off = tmp_path / "off"
    _, heavy = _run(ARGS, off, FLEXLINK_DESIGN_CACHE="0")
    assert "control" in heavy and not off.exists()
    _run([*ARGS[:-1], "--sample-time", "2e-3", "--json"], tmp_path)
    assert len(list(tmp_path.glob("*.pickle"))) == 2


def test_multi_joint_run_from_the_cache(tmp_path, example_fmu):
    """The two-link arm's LQG-against-PD comparison: a repeated command replays the cached plan, reference
    and laws (the PD's limits the new LQG run's peaks) with the designed run's figures."""
    example_fmu("two_link_payload")
    args = ["control", str(EXAMPLES / "two_link_payload.toml"), "--target", "60,20", "--duration", "1.5",
            "--settle", "0.5", "--torque-limit", "60", "--json"]
    first, heavy_first = _run(args, tmp_path)
    again, heavy_again = _run(args, tmp_path)
    assert "control" in heavy_first and heavy_again == []
    for run in ("lqg", "pd"):
        for k, v in first[run].items():
            if k != "realtime_factor":
                assert again[run][k] == v, (run, k)
    assert again["robustness"] == first["robustness"] and again["pd_gains"] == first["pd_gains"]
