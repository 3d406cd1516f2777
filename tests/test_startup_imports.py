"""What a command's start imports (issue 22: every command's fixed start-up ≤ 1 s, measured by
``python benchmarks/startup.py``).  Not a timing: the modules in ``sys.modules`` when a command is done, so
that a heavy import that creeps back into a start (CasADi, SciPy, python-control, matplotlib: 0.3–2 s each
on this machine) fails here, whatever the machine's load.  A command imports what its work needs and no
more: the help nothing but the parser (not even numpy or fmpy) and the estimate nothing of the model
builder; a run of a built FMU (``simulate``, ``control`` from its design cache) numpy and fmpy but no model
builder, no python-control, no plotting; ``linearize`` the model builder but not python-control (the slowest
import of all: SciPy's signal and stats, matplotlib's pyplot); a designing ``control`` the model builder and
SciPy's linear algebra (the LQR and Kalman gains, :mod:`controllers.riccati`) but python-control only after
its first FMU call, for what needs python-control's systems (the ``--json`` margins), and not at all
otherwise.  A top-level ``import control`` (or numpy) put back into the parser's modules
(``controllers.cli``), into ``flexlink.run.linearize`` or into the design's modules fails here.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import EXAMPLES

ROOT = Path(__file__).resolve().parents[1]
SCENE = str(EXAMPLES / "rotating_link.toml")
HEAVY = ("casadi", "scipy", "control", "matplotlib", "dask", "pandas")

_RUN = """
import ctypes, json, sys
first = None                      # sys.modules when an FMU's binary is first loaded (fmpy's instantiation)
_init = ctypes.CDLL.__init__
def _first(self, name, *a, **k):
    global first
    if first is None and name and "binaries" in str(name).replace("\\\\", "/").split("/"):
        first = sorted(sys.modules)
    _init(self, name, *a, **k)
ctypes.CDLL.__init__ = _first
from flexlink.cli import main
try:
    status = main(sys.argv[2:])
except SystemExit as e:
    status = e.code
with open(sys.argv[1], "w") as f:
    json.dump({"status": status, "modules": sorted(sys.modules), "first_fmu": first}, f)
"""


def run_imports(tmp_path: Path, args: list[str], **env: str) -> dict:
    """``sys.modules`` of a fresh process that ran ``flexlink ARGS`` (exit status 0): at its end
    (``"modules"``) and when it first loaded an FMU's binary (``"first_fmu"``, None if it never did)."""
    out = tmp_path / "modules.json"
    import os

    res = subprocess.run([sys.executable, "-c", _RUN, str(out), *args], cwd=ROOT, capture_output=True, text=True,
                         env={**os.environ, **env}, check=False)
    data = json.loads(out.read_text())
    assert data["status"] in (0, None), res.stderr
    return data


def imported(tmp_path: Path, args: list[str], **env: str) -> set[str]:
    """The top-level packages in ``sys.modules`` after ``flexlink ARGS`` in a fresh process (exit status 0)."""
    return {m.split(".")[0] for m in run_imports(tmp_path, args, **env)["modules"]}


@pytest.mark.parametrize("args", [["--help"], ["check", "--help"], ["control", "--help"], ["simulate", "--help"],
                                  ["linearize", "--help"], ["sweep", "--help"], ["explain", SCENE, "--estimate"]],
                         ids=" ".join)
def test_help_and_estimates_import_no_model_builder(tmp_path, args):
    mods = imported(tmp_path, args)
    assert not mods & set(HEAVY)
    if "--help" in args:                    # the parser alone: no numpy, no FMU host either
        assert not mods & {"numpy", "fmpy"}


def test_linearize_imports_no_python_control(tmp_path):
    """The matrices come from the model (CasADi, and SciPy's linear algebra); python-control's system is never
    built (tests/test_control_linearize.py: what it prints is python-control's all the same)."""
    mods = imported(tmp_path, ["linearize", SCENE, "--output", "hub.theta", "--json"])
    assert {"casadi", "numpy"} <= mods
    assert not mods & {"control", "matplotlib", "dask", "pandas"}


@pytest.mark.parametrize("args", [["modes", SCENE], ["linearize", SCENE, "--output", "hub.theta", "--json"]],
                         ids=lambda a: a[0])
def test_a_model_build_imports_no_scipy_optimize(tmp_path, args):
    """The clamped-free shapes' roots are bisected in flexlink (tests/test_shapes.py: to scipy's brentq's
    roots): importing ``scipy.optimize`` (special functions, spatial transforms, FFT) cost such a command
    0.2 s of its start-up (docs/performance.md, start-up)."""
    modules = set(run_imports(tmp_path, args)["modules"])
    assert "casadi" in modules
    assert "scipy.optimize" not in modules


def test_a_run_of_a_built_fmu_imports_no_model_builder(tmp_path, example_fmu):
    example_fmu("rotating_link")            # built (CasADi) before: the run itself only finds it
    mods = imported(tmp_path, ["simulate", SCENE, "--stop-time", "0.01", "--step", "1e-3"])
    assert {"numpy", "fmpy"} <= mods
    assert not mods & set(HEAVY)


def test_a_repeated_control_command_imports_no_model_builder(tmp_path, example_fmu):
    """The second run finds the design in its cache (tests/test_control_design_cache.py checks its figures):
    the FMU's cache key costs no CasADi or SciPy (flexlink.export.cache), the law no CasADi."""
    example_fmu("rotating_link")
    args = ["control", SCENE, "--target", "90", "--duration", "1.5", "--settle", "0.5"]
    first = imported(tmp_path, args, FLEXLINK_DESIGN_CACHE=str(tmp_path / "designs"))
    assert {"casadi", "scipy"} <= first     # designing: the model builder, SciPy's Riccati solvers
    again = imported(tmp_path, args, FLEXLINK_DESIGN_CACHE=str(tmp_path / "designs"))
    assert not again & set(HEAVY)


def test_a_designing_control_command_imports_python_control_after_its_first_fmu_call(tmp_path, example_fmu):
    """The design (LQR, Kalman filter, PD, reference) is controllers.riccati's SciPy calls, the same as
    python-control's (tests/test_riccati.py): a designing run imports neither python-control nor what it
    drags in (SciPy's signal and stats, matplotlib) before the FMU runs, and without ``--json`` not at all;
    with ``--json`` the margins, python-control's, come after the first FMU call."""
    example_fmu("rotating_link")
    base = ["control", SCENE, "--target", "90", "--duration", "1.5", "--settle", "0.5"]
    slow = {"control", "matplotlib", "scipy.signal", "scipy.stats"}
    plain = run_imports(tmp_path, base, FLEXLINK_DESIGN_CACHE="0")
    assert {"casadi", "scipy.linalg", "fmpy"} <= set(plain["first_fmu"])
    assert not set(plain["modules"]) & slow
    margins = run_imports(tmp_path, [*base, "--json"], FLEXLINK_DESIGN_CACHE="0")
    assert not set(margins["first_fmu"]) & slow
    assert "control" in margins["modules"]
