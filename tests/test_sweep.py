"""Parameter sweeps on Dask (``controllers.sweep``, ``flexlink sweep``), at CI size.

* cases: grids (full product, order), seeded Monte Carlo (uniform, truncated normal), bad specs;
* 30 closed-loop LQR cases (a short 5° manoeuvre) on a local Dask cluster of 2 worker processes give
  exactly the numbers of the same runs in a plain ``rest_to_rest`` loop; a parameter the FMU refuses
  (``arm.EI = -1``) is a failed row with the FMU's message, and the sweep goes on;
* a worker killed (SIGKILL) mid-sweep: nothing finished is lost, the sweep completes with the same numbers;
* an interrupted sweep resumes from its journal and recomputes only the missing cases (a torn journal
  line included); a journal of another sweep is refused unless ``overwrite``;
* the command line: open loop on the local cluster (CSV, plot), Monte Carlo in a plain loop (parquet,
  histograms), bad input (exit 2, one message).

The full-size figure (a few hundred runs, runs per second against the plain loop) is
``python benchmarks/sweep_throughput.py``.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from controllers.sweep import SweepSpec, journal_path, make_cases, run_sweep, summary_table
from flexlink.errors import FlexlinkError

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "rotating_link_payload.toml"
# 5° in 0.4 s peaks at 0.35 m of tip deflection (80 % of the validity limit, 20 % of 2.2 m); 10° would be
# refused by the FMU's guard
MANOEUVRE = {"controller": "lqr", "target_deg": 5.0, "duration": 0.4, "settle": 0.2}
GRID = {"arm.payload.mass": "0.3:1.0:10", "arm.EI": "80,93.72,-1"}          # 30 cases, 10 refused
EXACT = ("final_error_deg", "residual_vibration_rms_m", "peak_torque_nm", "max_tip_deflection_m",
         "saturated_fraction")                                               # realtime_factor is timing


# ------------------------------------------------------------------------------------------------ cases
def test_grid_is_the_full_product_last_name_fastest():
    kind, cases = make_cases({"a": "0:1:3", "b": "5,6"})
    assert kind == "grid"
    assert cases == [{"a": 0.0, "b": 5.0}, {"a": 0.0, "b": 6.0}, {"a": 0.5, "b": 5.0}, {"a": 0.5, "b": 6.0},
                     {"a": 1.0, "b": 5.0}, {"a": 1.0, "b": 6.0}]
    assert make_cases({"a": [1, 2], "b": 3.0})[1] == [{"a": 1.0, "b": 3.0}, {"a": 2.0, "b": 3.0}]


def test_monte_carlo_is_seeded_and_respects_bounds():
    params, dists = {"m": "0.5:2.0", "k": 7.0}, {"EI": "normal:93.72:20:80:100"}
    kind, a = make_cases(params, samples=2000, seed=3, distributions=dists)
    _, b = make_cases(params, samples=2000, seed=3, distributions=dists)
    _, c = make_cases(params, samples=2000, seed=4, distributions=dists)
    assert kind == "monte-carlo" and a == b and a != c
    m = np.array([x["m"] for x in a])
    ei = np.array([x["EI"] for x in a])
    assert m.min() >= 0.5 and m.max() <= 2.0 and abs(m.mean() - 1.25) < 0.05
    assert ei.min() >= 80 and ei.max() <= 100 and all(x["k"] == 7.0 for x in a)
    _, d = make_cases(None, samples=500, seed=0, distributions={"x": "normal:1:0.1", "y": "loguniform:1:100"})
    assert abs(np.mean([x["x"] for x in d]) - 1.0) < 0.02
    assert 1 <= min(x["y"] for x in d) and max(x["y"] for x in d) <= 100


@pytest.mark.parametrize("params, kwargs, message", [
    ({"a": "0:1"}, {}, "expected LO:HI:N"),
    ({"a": "0:1:x"}, {}, "not a whole number"),
    ({"a": "0:nan:3"}, {}, "finite"),
    ({}, {}, "nothing to sweep"),
    ({"a": "0:1:3"}, {"samples": 10}, "grids (LO:HI:N) are for sweeps without --samples"),
    ({}, {"samples": 10, "distributions": {"a": "gamma:1:2"}}, "unknown distribution"),
    ({}, {"samples": 10, "distributions": {"a": "normal:1:-2"}}, "STD > 0"),
    ({}, {"samples": 0, "distributions": {"a": "uniform:1:2"}}, "positive whole number"),
    ({}, {"distributions": {"a": "uniform:1:2"}}, "needs --samples"),
])
def test_bad_case_specs_are_one_clear_message(params, kwargs, message):
    with pytest.raises(FlexlinkError) as e:
        make_cases(params, **kwargs)
    assert message in str(e.value)


# ------------------------------------------------------------------------------------------------ the spec
def _cli_spec(argv):
    from controllers.sweep_cli import spec_from_args
    from flexlink.cli import build_parser

    return spec_from_args(build_parser().parse_args(["sweep", *argv]))


def test_a_spec_file_and_the_equivalent_command_line_are_the_same_sweep(tmp_path):
    out = tmp_path / "mc.parquet"
    (tmp_path / "mc.toml").write_text(f"""
scene = "{SCENE.as_posix()}"
samples = 7
seed = 3
controller = "pd"
target_deg = 10
duration = 0.4
settle = 0.2
out = "mc.parquet"
scheduler = "serial"
[params]
"arm.payload.mass" = "0.3:0.8"
[distributions]
"arm.EI" = "normal:93.72:5:85:100"
""")
    argv = [str(SCENE), "--samples", "7", "--seed", "3", "--controller", "pd", "--target", "10", "--duration",
            "0.4", "--settle", "0.2", "--out", str(out), "--scheduler", "serial", "--param",
            "arm.payload.mass=0.3:0.8", "--distribution", "arm.EI=normal:93.72:5:85:100"]
    from_file, from_line = _cli_spec(["--spec", str(tmp_path / "mc.toml")]), _cli_spec(argv)
    assert from_file == from_line                            # every field, the target as [10.0] in both
    assert from_file.cases() == from_line.cases() == make_cases({"arm.payload.mass": "0.3:0.8"}, samples=7,
                                                                seed=3,
                                                                distributions={"arm.EI": "normal:93.72:5:85:100"})
    assert SweepSpec.from_toml(tmp_path / "mc.toml").cases() == from_file.cases()
    # the command line's options override the file's: another seed, another draw; a --param adds an axis
    other = _cli_spec(["--spec", str(tmp_path / "mc.toml"), "--seed", "4", "--param", "arm.damping=0.1:0.2"])
    assert other.seed == 4 and other.samples == 7 and other.cases() != from_file.cases()
    assert other.params == {"arm.payload.mass": "0.3:0.8", "arm.damping": "0.1:0.2"}
    # a grid as a TOML array is the grid of the command line's V1,V2
    (tmp_path / "grid.toml").write_text(f'scene = "{SCENE.as_posix()}"\nstop_time = 0.1\n'
                                        '[params]\n"arm.EI" = [80, 93.72]\n"arm.payload.mass" = "0.3:1.0:3"\n')
    grid = SweepSpec.from_toml(tmp_path / "grid.toml")
    assert grid.cases() == _cli_spec([str(SCENE), "--stop-time", "0.1", "--out", str(out), "--param",
                                      "arm.EI=80,93.72", "--param", "arm.payload.mass=0.3:1.0:3"]).cases()


@pytest.mark.parametrize("text, message", [
    ('settel = 1.0', "unknown key 'settel'"),
    ('samples = "ten"', "samples = 'ten': expected a whole number"),
    ("settle = true", "settle = true: expected a number"),
    ('series = ["hub.theta", 3]', "series = ['hub.theta', 3]: expected an array of strings"),
    ('[params]\n"arm.EI" = {lo = 1}', "params.arm.EI = {'lo': 1}: expected a string"),
    ('settle = -1.0', "settle (--settle) must be a positive number of seconds, got -1.0"),
    # a boolean where a limit's number is meant: TOML's true is not 1 (Python's bool is an int)
    ("torque_limit = {shoulder = true}", "torque_limit.shoulder = true: expected a number (N m), got a boolean"),
    # the command line's text in a file: refused by SweepSpec itself (the limit's parser), not by the file's types
    ('torque_limit = "shoulder=true"', "torque_limit (--torque-limit): expected a number, got 'true'"),
    ("joint_error = [0.2, false]", "joint_error[2] = false: expected a number (deg), got a boolean"),
    ("mode_limit = true", "mode_limit = true: expected a number (modal units), an array of numbers"),
    ('root_moment = {upper = "x"}', "root_moment.upper = 'x': expected a number (N m), got a string"),
    ('[distributions]\n"arm.EI" = false', 'distributions.arm.EI = false: expected a string such as "normal:MEAN:STD"'),
    ('scene = [', "not a valid TOML file"),
])
def test_a_bad_spec_file_is_one_message_naming_the_key(tmp_path, capsys, text, message):
    """From Python and from ``flexlink sweep --spec``, the one line names the file too (the command line builds
    its SweepSpec itself, not through ``from_toml``: a value SweepSpec refuses named no file before)."""
    path = tmp_path / "bad.toml"
    path.write_text(f'scene = "{SCENE.as_posix()}"\nstop_time = 0.1\n' + text + "\n")
    with pytest.raises(FlexlinkError) as e:
        SweepSpec.from_toml(path)
    assert str(e.value).startswith(f"{path}: ") and message in str(e.value), str(e.value)
    from flexlink.cli import main

    assert main(["sweep", "--spec", str(path), "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}: " in err and message in err and "Traceback" not in err, err


def test_the_command_line_needs_a_scene_and_an_output(tmp_path, capsys):
    from flexlink.cli import main

    (tmp_path / "s.toml").write_text("stop_time = 0.1\n[params]\n\"arm.EI\" = \"80,90\"\n")
    for argv, message in [(["--spec", str(tmp_path / "s.toml")], "give the scene"),
                          ([str(SCENE), "--stop-time", "0.1", "--param", "arm.EI=80"], "--out FILE"),
                          (["--spec", str(tmp_path / "nope.toml")], "cannot be read")]:
        assert main(["sweep", *argv]) == 2
        assert message in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def fmu():
    from flexlink.export.cache import cached_fmu

    return cached_fmu(SCENE)


@pytest.fixture(scope="module")
def client():
    """A local Dask cluster as on this machine: 2 worker processes, 1 thread each (closed at the end)."""
    import logging

    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=logging.CRITICAL)
    c = Client(cluster, timeout="60s")
    try:
        c.wait_for_workers(2, timeout=120)
        yield c
    finally:
        c.close(timeout=30)
        cluster.close(timeout=30)


@pytest.fixture(scope="module")
def plain_loop(fmu):
    """The GRID cases one after the other with controllers.manoeuvre.rest_to_rest: no Dask, no sweep code."""
    from controllers.cosim import FmuLoop
    from controllers.manoeuvre import default_torque_limit, design, rest_to_rest
    from flexlink.run.linearize import linear_plant

    target = math.radians(MANOEUVRE["target_deg"])
    limit = default_torque_limit(linear_plant(SCENE, outputs=["hub.theta"]), target, MANOEUVRE["duration"])
    d = design(SCENE, torque_limit=limit, dt=1e-3)                 # as `flexlink control` would
    _, cases = make_cases(GRID)
    rows = []
    loop = FmuLoop(fmu)
    for c in cases:
        try:
            res = rest_to_rest(d, loop, target, MANOEUVRE["duration"], MANOEUVRE["settle"], "lqr", parameters=c)
            rows.append({**c, **res.metrics, "failed": False})
        except FlexlinkError as e:
            rows.append({**c, "failed": True, "error": str(e)})
            loop.close()
            loop = FmuLoop(fmu)
    loop.close()
    return pd.DataFrame(rows)


def _check_against_plain_loop(df, ref):
    assert len(df) == len(ref) == 30
    assert list(df["failed"]) == list(ref["failed"])
    ok = ~ref["failed"].to_numpy()
    assert ok.sum() == 20
    for m in EXACT:
        np.testing.assert_array_equal(df.loc[ok, m].to_numpy(), ref.loc[ok, m].to_numpy(), err_msg=m)


def _journal(out):
    docs = [json.loads(x) for x in journal_path(out).read_text().splitlines() if x.strip()]
    return docs[0], docs[1:]


def _worker_dirs() -> set[str]:
    """The sweep workers' folders (their FMU's copy) in this machine's temporary directory."""
    import tempfile

    return {p.name for p in Path(tempfile.gettempdir()).glob("flexlink-sweep-*")}


# ------------------------------------------------------------------------------------------------ Dask
def test_dask_sweep_equals_the_plain_loop_and_records_refused_cases(client, fmu, plain_loop, tmp_path):
    out = tmp_path / "grid.parquet"
    t0 = time.perf_counter()
    before = _worker_dirs()
    df = run_sweep(SweepSpec(SCENE, GRID, fmu=fmu, out=out, **MANOEUVRE), client=client)
    # the workers (alive, the cluster is the caller's) kept no copy of the FMU once the sweep was done
    assert _worker_dirs() <= before, _worker_dirs() - before
    print(f"\n30 closed-loop cases on 2 Dask workers: {time.perf_counter() - t0:.2f} s")
    print(summary_table(df))
    _check_against_plain_loop(df, plain_loop)
    assert df["case"].tolist() == list(range(30)) and df.attrs["computed"] == 30
    assert len(set(df["worker"])) == 2                              # both workers took cases
    bad = df[df["arm.EI"] == -1]
    assert len(bad) == 10 and bad["failed"].all() and (bad["status"] == "failed").all()
    assert all("arm.EI = -1: must be > 0" in e for e in bad["error"]), bad["error"].iloc[0]
    assert bad["residual_vibration_rms_m"].isna().all()
    good = df[df["arm.EI"] != -1]
    assert not good["failed"].any() and (good["error"] == "").all()
    assert (good["overshoot_deg"] >= 0).all() and (good["peak_torque_nm"] > 0).all()
    back = pd.read_parquet(out)                                     # the file: one row per case, failures too
    assert len(back) == 30 and back["failed"].sum() == 10
    np.testing.assert_array_equal(back["peak_torque_nm"].to_numpy(), df["peak_torque_nm"].to_numpy())
    # overshoot and final error agree with the time series kept on request
    one = run_sweep(SweepSpec(SCENE, {"arm.payload.mass": 0.3, "arm.EI": 93.72}, fmu=fmu,
                              series=["hub.theta"], series_every=1, **MANOEUVRE), client=client)
    theta, t = np.array(one["series.hub.theta"][0]), np.array(one["series.time"][0])
    assert len(t) == 601 and t[-1] == pytest.approx(0.6)
    target = MANOEUVRE["target_deg"]
    assert one["overshoot_deg"][0] == pytest.approx(max(0.0, np.degrees(theta.max()) - target), abs=1e-12)
    assert one["final_error_deg"][0] == pytest.approx(np.degrees(theta[-1]) - target, abs=1e-12)


def test_killing_a_worker_mid_sweep_loses_nothing(client, fmu, plain_loop, tmp_path):
    victim = next(iter(client.run(os.getpid).values()))
    seen: dict[str, tuple] = {}
    killed = []

    def on_result(row, done, total):
        seen[row["key"]] = (row["worker"], row["wall_s"])
        if done >= 4 and not killed:
            os.kill(victim, signal.SIGKILL)
            killed.append(done)

    out = tmp_path / "killed.parquet"
    before = _worker_dirs()
    df = run_sweep(SweepSpec(SCENE, GRID, fmu=fmu, out=out, batch_size=2, **MANOEUVRE), client=client,
                             on_result=on_result)
    assert killed
    assert _worker_dirs() <= before, _worker_dirs() - before    # the killed worker's folder too
    _check_against_plain_loop(df, plain_loop)
    assert df.attrs["computed"] == 30 and len(seen) == 30
    _, rows = _journal(out)                       # every row reported, before and after the kill, as it was
    assert len(rows) == 30
    for r in df.itertuples():
        assert (r.worker, r.wall_s) == seen[r.key]
    client.wait_for_workers(2, timeout=120)       # the nanny restarted the killed worker


def test_interrupted_sweep_resumes_only_the_missing_cases(client, fmu, tmp_path):
    out = tmp_path / "resume.csv"
    grid = {"arm.payload.mass": "0.3:1.0:8", "arm.EI": "80,93.72"}

    def stop(row, done, total):
        if done == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(SweepSpec(SCENE, grid, fmu=fmu, out=out, batch_size=1, **MANOEUVRE), client=client,
                  on_result=stop)
    assert not out.exists()
    header, rows = _journal(out)
    n_first = len(rows)
    assert 5 <= n_first < 16 and header["mode"] == "closed"
    first = {r["key"]: r for r in rows}
    with journal_path(out).open("a") as f:        # a crash while writing: a torn last line
        f.write('{"case": 99, "key": "arm.payload.mass=0.3;arm')
    df = run_sweep(SweepSpec(SCENE, grid, fmu=fmu, out=out, **MANOEUVRE), client=client)
    assert df.attrs["resumed"] == n_first and df.attrs["computed"] == 16 - n_first
    assert len(df) == 16 and not df["failed"].any()
    for r in df.itertuples():                     # the first run's rows are kept, not recomputed
        if r.key in first:
            assert r.wall_s == first[r.key]["wall_s"] and r.worker == first[r.key]["worker"]
    back = pd.read_csv(out)
    assert len(back) == 16 and back["case"].tolist() == list(range(16))
    # nothing missing: nothing recomputed; a larger grid computes only its new cases
    again = run_sweep(SweepSpec(SCENE, grid, scheduler="serial", fmu=fmu, out=out, **MANOEUVRE))
    assert again.attrs["computed"] == 0 and again.attrs["resumed"] == 16
    np.testing.assert_array_equal(again["peak_torque_nm"].to_numpy(), df["peak_torque_nm"].to_numpy())
    more = run_sweep(SweepSpec(SCENE, {"arm.payload.mass": "0.3:1.0:8", "arm.EI": "80,93.72,100"},
                               scheduler="serial", fmu=fmu, out=out, **MANOEUVRE))
    assert more.attrs["computed"] == 8 and len(more) == 24
    # the consolidated file alone (journal deleted) is resumed from too
    journal_path(out).unlink()
    alone = run_sweep(SweepSpec(SCENE, grid, scheduler="serial", fmu=fmu, out=out, **MANOEUVRE))
    assert alone.attrs["computed"] == 0
    # other settings are refused, unless overwritten
    with pytest.raises(FlexlinkError, match="other settings"):
        run_sweep(SweepSpec(SCENE, grid, scheduler="serial", fmu=fmu, out=out,
                            **{**MANOEUVRE, "target_deg": 4.0}))
    fresh = run_sweep(SweepSpec(SCENE, {"arm.payload.mass": "0.3:1.0:2"}, scheduler="serial", fmu=fmu, out=out,
                                overwrite=True, **{**MANOEUVRE, "target_deg": 4.0}))
    assert fresh.attrs["computed"] == 2 and len(pd.read_csv(out)) == 2


# ------------------------------------------------------------------------------------------------ the command
def _flexlink(args, cache, timeout=300):
    env = {**os.environ, "XDG_CACHE_HOME": str(cache), "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-m", "flexlink.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout, check=False)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("xdg-cache")


def test_cli_open_loop_grid_on_the_local_cluster(tmp_path, cache):
    out, png = tmp_path / "raise.csv", tmp_path / "raise.png"
    r = _flexlink(["sweep", "examples/steel_beam_raise.toml", "--param", "beam.EI=40000:90000:3",
                   "--param", "beam.linear_density=9.36,12", "--stop-time", "0.3", "--settle", "0.1",
                   "--out", str(out), "--plot", str(png), "--no-progress"], cache)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert "6 cases (grid): 6 ok, 0 failed" in r.stdout and "peak_torque_nm" in r.stdout
    df = pd.read_csv(out)
    assert len(df) == 6 and not df["failed"].any() and png.stat().st_size > 10_000
    assert df["beam.EI"].tolist() == [40000.0, 40000.0, 65000.0, 65000.0, 90000.0, 90000.0]
    # the heavier beam needs more torque along the same law; a stiffer one deflects less
    torque = df.groupby("beam.linear_density")["peak_torque_nm"].mean()
    assert torque[12.0] > torque[9.36] > 0
    light = df[df["beam.linear_density"] == 9.36].sort_values("beam.EI")["max_tip_deflection_m"].to_numpy()
    assert light[0] > light[-1] > 0


def test_an_open_loop_case_the_fmu_refuses_says_so_once(tmp_path, cache):
    """A refused open-loop case's ``error`` names the FMU, the call and the FMU's reason once each (the walk of
    2026-11-29 found them twice: the refusal already carried them, and the case wrapped it again)."""
    out = tmp_path / "refused.csv"
    r = _flexlink(["sweep", str(SCENE), "--param", "arm.EI=-1,93.72", "--stop-time", "0.05", "--scheduler",
                   "serial", "--out", str(out), "--no-progress"], cache)
    assert r.returncode == 0, r.stderr
    df = pd.read_csv(out, keep_default_na=False)
    (error,) = df[df["arm.EI"] == -1]["error"]
    assert error.count("arm.EI = -1: must be > 0") == 1 and error.count(".fmu") == 1, error
    assert "fmi2SetReal failed with status 3 (error)" in error
    assert df[df["arm.EI"] != -1]["error"].tolist() == [""]


def test_cli_monte_carlo_serial_parquet_and_bad_input(tmp_path, cache, capsys, monkeypatch):
    out, png = tmp_path / "mc.parquet", tmp_path / "mc.png"
    args = ["sweep", "examples/rotating_link_payload.toml", "--samples", "6", "--seed", "2",
            "--param", "arm.payload.mass=0.3:0.8", "--distribution", "arm.EI=normal:93.72:5:85:100",
            "--controller", "pd", "--target", "10", "--duration", "0.4", "--settle", "0.2",
            "--scheduler", "serial", "--out", str(out), "--no-progress"]
    r = _flexlink([*args, "--plot", str(png)], cache)
    assert r.returncode == 0, r.stderr
    assert "6 cases (monte-carlo): 6 ok" in r.stdout and png.exists()
    df = pd.read_parquet(out)
    assert len(df) == 6 and df["arm.EI"].between(85, 100).all() and df["arm.payload.mass"].between(0.3, 0.8).all()
    from flexlink.cli import main

    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    monkeypatch.chdir(ROOT)
    capsys.readouterr()
    assert main(args) == 0                        # the same command again: everything from the journal
    assert "0 computed now, 6 from the journal" in capsys.readouterr().out
    for bad, message in [
        (["--param", "arm.nope=1:2:3", "--stop-time", "0.1"], "--param arm.nope: not a parameter of the FMU"),
        (["--param", "arm.EI=1:2:3"], "give either a closed-loop manoeuvre"),
        (["--param", "arm.EI=1:2:3", "--stop-time", "0.1", "--out", str(tmp_path / "x.txt")], ".parquet or .csv"),
        (["--samples", "3", "--param", "arm.EI=1:2:3", "--stop-time", "0.1"], "are for sweeps without --samples"),
    ]:
        cmd = ["sweep", "examples/rotating_link_payload.toml", *bad, "--scheduler", "serial"]
        if "--out" not in bad:
            cmd += ["--out", str(tmp_path / "bad.csv")]
        assert main(cmd) == 2
        err = capsys.readouterr().err
        assert err.startswith("flexlink: error: ") and message in err and "Traceback" not in err, err


# ------------------------------------------------------------------------------------------------ case timeout
# The same open-loop run with the SS22 step at 1 ms (500 steps: milliseconds) and at 0.1 us (5 million
# Newton steps: minutes): only the second cannot finish within the limit.
SLOW_GRID = {"solver.step": "1e-3,1e-7"}


def test_deadline_stops_a_python_loop_and_never_fires_late():
    from controllers.deadline import CaseTimeout, Deadline

    t0 = time.perf_counter()
    with pytest.raises(CaseTimeout), Deadline(0.3):
        while True:
            pass
    assert 0.3 <= time.perf_counter() - t0 < 2.0
    with Deadline(0.2):
        pass
    time.sleep(0.4)                               # an expiry after the block must not arrive here


def test_case_timeout_is_a_failed_row_and_is_rerun_on_resume(tmp_path, fmu):
    out = tmp_path / "slow.csv"
    spec = SweepSpec(SCENE, SLOW_GRID, stop_time=0.5, sample_time=0.01, scheduler="serial", fmu=fmu, out=out,
                     case_timeout=1.0)
    df = run_sweep(spec)
    fast, slow = df.iloc[0], df.iloc[1]
    assert slow["solver.step"] == 1e-7 and fast["solver.step"] == 1e-3
    assert not fast["failed"] and fast["status"] == "ok" and fast["wall_s"] < 1.0
    assert slow["failed"] and slow["status"] == "timeout" and "case timeout of 1 s" in slow["error"]
    assert 1.0 <= slow["wall_s"] < 3.0                   # stopped at the limit, not at the end of the run
    again = run_sweep(spec)
    assert again.attrs["computed"] == 1 and again.attrs["resumed"] == 1       # only the timed-out case


def test_cli_case_timeout_on_the_local_cluster(tmp_path, cache):
    out = tmp_path / "slow.csv"
    t0 = time.perf_counter()
    # 500 internal steps against 5e8 (at least 75 s at the arm's 0.15 us a step): a 4 s limit leaves the first
    # case room on a loaded machine (at 1 s it timed out at load 10) and the second none
    r = _flexlink(["sweep", str(SCENE), "--param", "solver.step=1e-3,1e-9", "--stop-time", "0.5",
                   "--sample-time", "0.0005", "--case-timeout", "4", "--out", str(out), "--no-progress"], cache)
    assert r.returncode == 0, r.stderr
    assert "2 cases (grid): 1 ok, 1 failed" in r.stdout and "case timeout of 4 s" in r.stdout
    df = pd.read_csv(out)
    assert df["status"].tolist() == ["ok", "timeout"] and df["failed"].tolist() == [False, True]
    assert time.perf_counter() - t0 < 120
