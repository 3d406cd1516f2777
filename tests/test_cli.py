"""The commands of SCENE.md as a user runs them: subprocesses from the repository root, exit status, stdout,
stderr (one line on bad input, never a traceback), the files written.

``flexlink simulate`` caches its FMU under $XDG_CACHE_HOME: every run here gets a private cache directory.
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = "examples/rotating_link.toml"
FLEXLINK = [str(Path(sys.executable).with_name("flexlink"))]
if not Path(FLEXLINK[0]).exists():                      # not installed as a script: the module does the same
    FLEXLINK = [sys.executable, "-m", "flexlink.cli"]


def run(args: list[str], cache: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "XDG_CACHE_HOME": str(cache), "MPLBACKEND": "Agg"}
    return subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout, check=False)


def flexlink(*args: str, cache: Path) -> subprocess.CompletedProcess[str]:
    return run([*FLEXLINK, *args], cache)


def ok(result: subprocess.CompletedProcess[str]) -> subprocess.CompletedProcess[str]:
    assert result.returncode == 0, f"exit {result.returncode}\n{result.stdout}\n{result.stderr}"
    assert "Traceback" not in result.stderr, result.stderr
    return result


def read_csv(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return {name: np.array([float(r[i]) for r in rows[1:]]) for i, name in enumerate(rows[0])}


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("xdg-cache")


# ------------------------------------------------------------------------------------------------ build


def test_build_into_an_existing_folder_names_the_fmu_after_the_model(tmp_path, cache):
    """``-o DIR`` with DIR an existing folder writes DIR/<model identifier>.fmu (as cp does), no temporary
    file is left beside it."""
    result = ok(flexlink("build", "examples/rotating_link_linear.toml", "-o", str(tmp_path), cache=cache))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rotating_link_linear.fmu"]
    assert str(tmp_path / "rotating_link_linear.fmu") in result.stdout


def test_build_commands_write_valid_fmus(tmp_path, cache):
    from fmpy.validation import validate_fmu

    outputs = {"flexlink": tmp_path / "a" / "cli.fmu", "build_fmu.py": tmp_path / "b" / "script.fmu"}
    commands = {"flexlink": [*FLEXLINK, "build", SCENE, "-o", str(outputs["flexlink"])],
                "build_fmu.py": [sys.executable, "build_fmu.py", SCENE, "-o", str(outputs["build_fmu.py"])]}
    with ThreadPoolExecutor(2) as pool:
        results = dict(zip(commands, pool.map(lambda c: run(c, cache), commands.values()), strict=True))
    for name, result in results.items():
        ok(result)
        assert outputs[name].is_file(), name
        assert validate_fmu(str(outputs[name])) == [], name
        assert str(outputs[name]) in result.stdout, result.stdout


# ------------------------------------------------------------------------------------------------ modes


def _first_order_copy(tmp_path: Path) -> Path:
    text = (ROOT / SCENE).read_text()
    assert 'kinematics = "second-order"' in text
    path = tmp_path / "rotating_link_first_order.toml"
    path.write_text(text.replace('kinematics = "second-order"', 'kinematics = "first-order"'))
    return path


def test_modes_json(tmp_path, cache):
    """--json: SCENE.md's object, frequencies ascending, the first one what the library computes.

    First-order kinematics keeps the centrifugal softening −W² ∫ρφ² but not the stiffening: the link
    diverges once the rate exceeds its clamped-free first bending frequency, λ₁² √(EI/(ρL⁴)) = 11.90 rad/s
    (λ₁ = 1.8751; the 3-shape model is a little stiffer).  Below it (0.8×) all modes are oscillatory, above
    it (1.25×) one mode is unstable; the second-order scene stays stable at the same rate."""
    critical = 1.875104068711961**2 * math.sqrt(93.72 / (0.349 * 2.2**4))
    first_order = _first_order_copy(tmp_path)
    jobs = {"default": ("modes", SCENE, "--json"),
            "slow": ("modes", str(first_order), "--rate", repr(0.8 * critical), "--json"),
            "fast": ("modes", str(first_order), "--rate", repr(1.25 * critical), "--json"),
            "second-order": ("modes", SCENE, "--rate", repr(1.25 * critical), "--json")}
    with ThreadPoolExecutor(2) as pool:
        results = dict(zip(jobs, pool.map(lambda a: flexlink(*a, cache=cache), jobs.values()), strict=True))
    out = {name: json.loads(ok(r).stdout) for name, r in results.items()}

    default = out["default"]
    assert set(default) >= {"rate", "frequencies_hz", "unstable"}
    assert default["rate"] == 0.0 and default["unstable"] == []
    f = default["frequencies_hz"]
    assert len(f) >= 2 and f == sorted(f) and all(x > 0 for x in f)
    expected = natural_frequencies(build_model(load_scene(ROOT / SCENE))).frequencies_hz
    assert f[0] == pytest.approx(expected[0], rel=1e-12)
    assert f[0] == pytest.approx(5.760, rel=1e-3)              # the scene file's reference value

    assert out["slow"]["unstable"] == []
    assert out["slow"]["frequencies_hz"][0] < f[0]             # softening
    assert len(out["fast"]["unstable"]) >= 1 and all(x > 0 for x in out["fast"]["unstable"])
    assert out["fast"]["rate"] == pytest.approx(1.25 * critical)
    assert out["second-order"]["unstable"] == []
    assert out["second-order"]["frequencies_hz"][0] > f[0]     # stiffening
    for o in out.values():
        assert o["frequencies_hz"] == sorted(o["frequencies_hz"])


# ------------------------------------------------------------------------------------------------ simulate


@pytest.fixture(scope="module")
def simulations(tmp_path_factory, cache):
    """Three runs of 1 s at 0.01 s: with a constant 0.2 N m torque from a CSV (also plotted), without input,
    and with the torque and hub.inertia = 0.2."""
    d = tmp_path_factory.mktemp("simulate")
    (d / "in.csv").write_text("time,hub.tau\n0,0.2\n2,0.2\n")
    common = ["simulate", SCENE, "--stop-time", "1", "--step", "0.01"]
    first = ok(flexlink(*common, "--input", str(d / "in.csv"), "--csv", str(d / "torque.csv"), "--plot",
                        str(d / "torque.png"), cache=cache))            # builds the cached FMU once
    (d / "torque.stderr").write_text(first.stderr)
    (d / "ramp.csv").write_text("time,hub.tau\n0,0.2\n0.5,0.6\n2,0.6\n")
    jobs = {"free": [*common, "--csv", str(d / "free.csv")],
            "heavy": [*common, "--input", str(d / "in.csv"), "--set", "hub.inertia=0.2", "--csv",
                      str(d / "heavy.csv"), "--progress"],
            "linear": [*common, "--input", str(d / "ramp.csv"), "--csv", str(d / "linear.csv"),
                       "--output", "hub.theta", "hub.tau", "--plot", str(d / "linear.png")],
            "hold": [*common, "--input", str(d / "ramp.csv"), "--interpolation", "hold", "--csv",
                     str(d / "hold.csv"), "--output", "hub.theta"],
            "stdout": [*common, "--csv", "-", "--output", "hub.theta", "arm.tip.v", "--progress"]}
    with ThreadPoolExecutor(2) as pool:
        for name, result in zip(jobs, pool.map(lambda a: flexlink(*a, cache=cache), jobs.values()), strict=True):
            (d / f"{name}.stderr").write_text(ok(result).stderr)
            (d / f"{name}.stdout").write_text(result.stdout)
    return d


def test_simulate_writes_csv_and_plot(simulations, fmu_outputs):
    d = simulations
    res = read_csv(d / "torque.csv")
    assert list(res)[0] == "time"
    assert set(fmu_outputs) <= set(res)
    assert res["time"][0] == 0.0 and res["time"][-1] == pytest.approx(1.0) and len(res["time"]) == 101
    assert all(np.all(np.isfinite(v)) for v in res.values())
    png = (d / "torque.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


@pytest.fixture(scope="module")
def fmu_outputs(simulations, cache) -> list[str]:
    import fmpy

    (fmu,) = (cache / "flexlink").glob("rotating_link-*.fmu")
    return [v.name for v in fmpy.read_model_description(str(fmu)).modelVariables if v.causality == "output"]


def test_simulate_input_and_set_take_effect(simulations):
    """0.2 N m on the hub: the arm turns about like a rigid body, θ(1 s) ≈ τ t²/(2 J), J = J_hub + ρL³/3;
    without input it stays at rest; hub.inertia = 0.2 slows it in the ratio of the inertias."""
    torque, free, heavy = (read_csv(simulations / f"{n}.csv") for n in ("torque", "free", "heavy"))
    assert np.all(free["hub.theta"] == 0.0) and np.all(free["arm.tip.v"] == 0.0)
    rho, length = 0.349, 2.2
    j_arm = rho * length**3 / 3
    for res, j_hub in ((torque, 0.1), (heavy, 0.2)):
        assert res["hub.theta"][-1] == pytest.approx(0.2 / (2 * (j_hub + j_arm)), rel=0.03)
        assert np.max(np.abs(res["arm.tip.v"])) > 1e-4           # the arm bends
    assert heavy["hub.theta"][-1] / torque["hub.theta"][-1] == pytest.approx((0.1 + j_arm) / (0.2 + j_arm), rel=0.02)


def test_simulate_interpolation_hold_and_linear(simulations):
    """A torque table 0.2 N m at 0, 0.6 N m from 0.5 s: held, the torque steps at 0.5 s; linear, it ramps
    from 0.2 to 0.6 over the first half second. Rigid-body rotation θ(1) = ∫₀¹ (1 − s) τ(s) ds / J gives
    0.15 / J and 0.21667 / J (the arm's vibration and the communication step move it by well under 3 %)."""
    j = 0.1 + 0.349 * 2.2**3 / 3
    held, linear = (read_csv(simulations / f"{n}.csv") for n in ("hold", "linear"))
    assert held["hub.theta"][-1] == pytest.approx(0.15 / j, rel=0.03)
    assert linear["hub.theta"][-1] == pytest.approx((0.1 + 0.8 * (0.125 - 0.125 / 3) + 0.05) / j, rel=0.03)


def test_hold_inputs_is_a_staircase():
    from flexlink.run.simulate import hold_inputs

    table = np.array([(0.0, 1.0), (1.0, 2.0), (1.0, 5.0), (3.0, 4.0)], dtype=[("time", float), ("u", float)])
    held = hold_inputs(table)
    assert held["time"].tolist() == [0.0, 1.0, 1.0, 1.0, 3.0, 3.0]
    assert held["u"].tolist() == [1.0, 1.0, 2.0, 5.0, 5.0, 4.0]


def test_simulate_output_selection_warning_and_progress(simulations):
    """--output writes those columns only, in that order; a run without --input warns (one line naming the
    input and its start value), a run with it does not; --progress draws the bar on stderr even into a pipe,
    and without it (stderr not a terminal) nothing is drawn."""
    d = simulations
    with open(d / "linear.csv") as f:
        assert f.readline().strip() == "time,hub.theta,hub.tau"
    (warning,) = (d / "free.stderr").read_text().splitlines()
    assert warning.startswith("flexlink: warning: no --input given") and "hub.tau = 0.0" in warning
    assert (d / "torque.stderr").read_text() == ""
    assert "s simulated" in (d / "heavy.stderr").read_text()
    assert "simulat" not in (d / "linear.stderr").read_text()


def test_simulate_csv_to_stdout_is_only_the_csv(simulations):
    """--csv - with the progress bar on: stdout is exactly the CSV of the same run written to a file (the
    bar, the warning and the summary all on stderr)."""
    d = simulations
    stdout = (d / "stdout.stdout").read_text()
    lines = stdout.splitlines()
    assert lines[0] == "time,hub.theta,arm.tip.v" and len(lines) == 102
    free = read_csv(d / "free.csv")
    (d / "from_stdout.csv").write_text(stdout)
    piped = read_csv(d / "from_stdout.csv")
    for name in ("time", "hub.theta", "arm.tip.v"):
        assert np.array_equal(piped[name], free[name]), name
    err = (d / "stdout.stderr").read_text()
    assert "s simulated" in err and "simulated 1.0 s in" in err and "warning" in err


def test_plot_axes_carry_the_model_description_units(fmu_outputs, cache):
    """Every y axis of the plot names the unit the FMU's model description declares for that variable."""
    import fmpy

    from flexlink.run.simulate import result_figure, variable_units

    (fmu,) = (cache / "flexlink").glob("rotating_link-*.fmu")
    md = fmpy.read_model_description(str(fmu))
    declared = {v.name: v.unit for v in md.modelVariables}
    names = ["hub.tau", "hub.theta", "arm.tip.v", "arm.eta[1]"]
    result = np.zeros(3, dtype=[("time", float)] + [(n, float) for n in names])
    fig = result_figure(result, names, units=variable_units(md))
    labels = [ax.get_ylabel() for ax in fig.axes]
    for name, label in zip(names, labels, strict=True):
        assert label.startswith(name)
        assert label.endswith(f"({declared[name]})") if declared[name] else label.endswith("(no unit given)")
    assert declared["hub.tau"] == "N.m" and declared["hub.theta"] == "rad"


# ------------------------------------------------------------------------------------------------ bad input

BAD = {
    "missing-scene": (["simulate", "examples/no_such_scene.toml", "--stop-time", "1"], ["no_such_scene.toml"]),
    "missing-scene-build": (["build", "examples/no_such_scene.toml", "-o", "{tmp}/x.fmu"], ["no_such_scene.toml"]),
    "negative-length": (["simulate", "{negative}", "--stop-time", "1"], ["length", "-2.2"]),
    "negative-length-modes": (["modes", "{negative}"], ["length"]),
    "negative-length-build": (["build", "{negative}", "-o", "{tmp}/x.fmu"], ["length"]),
    "unknown-set-name": ([*"simulate {scene} --stop-time 1 --set arm.stiffness=3".split()], ["arm.stiffness"]),
    "set-an-output": ([*"simulate {scene} --stop-time 1 --set tip.x=1".split()], ["tip.x", "output"]),
    "set-not-a-number": ([*"simulate {scene} --stop-time 1 --set hub.inertia=abc".split()], ["hub.inertia", "abc"]),
    "set-without-value": ([*"simulate {scene} --stop-time 1 --set hub.inertia".split()], ["hub.inertia"]),
    "input-unknown-column": ([*"simulate {scene} --stop-time 1 --input {tmp}/unknown.csv".split()], ["hub.torque"]),
    "input-nan": ([*"simulate {scene} --stop-time 1 --input {tmp}/nan.csv".split()], ["nan.csv", "NaN"]),
    "input-decreasing-time": ([*"simulate {scene} --stop-time 1 --input {tmp}/decreasing.csv".split()],
                              ["decreasing.csv", "time"]),
    "input-missing-file": ([*"simulate {scene} --stop-time 1 --input {tmp}/none.csv".split()], ["none.csv"]),
    "negative-stop-time": ([*"simulate {scene} --stop-time -1".split()], ["--stop-time"]),
    "nan-stop-time": ([*"simulate {scene} --stop-time nan".split()], ["--stop-time"]),
    "negative-step": ([*"simulate {scene} --stop-time 1 --step -0.01".split()], ["--step"]),
    "negative-EI": ([*"simulate {scene} --stop-time 1 --set arm.EI=-1".split()], ["arm.EI"]),
    "unknown-output": ([*"simulate {scene} --stop-time 1 --output hub.thet".split()], ["hub.thet", "hub.theta"]),
    "zero-solver-step": ([*"simulate {scene} --stop-time 1 --set solver.step=0".split()], ["solver.step"]),
    "build-onto-a-folder": ([*"build {scene} -o {tmp}/taken".split()], ["rotating_link.fmu", "is a folder"]),
}


@pytest.fixture(scope="module")
def bad_runs(tmp_path_factory, cache) -> dict[str, subprocess.CompletedProcess[str]]:
    """All bad-input commands, two at a time (after one good run has filled the FMU cache)."""
    tmp = tmp_path_factory.mktemp("bad")
    (tmp / "unknown.csv").write_text("time,hub.torque\n0,1\n1,1\n")
    (tmp / "nan.csv").write_text("time,hub.tau\n0,0.1\n0.5,nan\n1,0\n")
    (tmp / "decreasing.csv").write_text("time,hub.tau\n0,0.1\n0.6,0.2\n0.4,0.3\n")
    negative = tmp / "negative.toml"
    text = (ROOT / SCENE).read_text()
    assert "length = 2.2 " in text
    negative.write_text(text.replace("length = 2.2 ", "length = -2.2 "))
    (tmp / "taken" / "rotating_link.fmu").mkdir(parents=True)     # where -o {tmp}/taken would put the FMU
    ok(flexlink("simulate", SCENE, "--stop-time", "0.01", cache=cache))

    def go(args):
        return flexlink(*(a.format(tmp=tmp, scene=SCENE, negative=negative) for a in args), cache=cache)

    with ThreadPoolExecutor(2) as pool:
        return dict(zip(BAD, pool.map(go, [args for args, _ in BAD.values()]), strict=True))


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_gives_one_line_and_no_traceback(bad_runs, case):
    result = bad_runs[case]
    words = BAD[case][1]
    assert result.returncode != 0
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert all(w in lines[0] for w in words), (words, lines[0])
