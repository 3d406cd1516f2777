"""The LQR's weights in ``flexlink sweep`` (``--joint-error``, ``--tip-deflection``, ``--root-moment``,
``--mode-limit``, ``--torque-limit`` per joint; docs/sweeps.md), parsed as ``flexlink control`` parses them.

* The design every member of a sweep runs (the one shipped to the workers) has the gains of python-control's
  ``sample_system`` + ``dlqr`` on the plant linearised here, with Q and R built here by Bryson's rule from the
  limits the options say; the same limits from a spec file give the same design.
* A sweep with weights runs through the FMU, and its weights are part of its identity: its results are not
  resumed by a sweep with other weights.
* A bad name, count or value is one line and exit status 2, and leaves no journal behind; with ``--overwrite``
  it leaves the results it would have replaced as they were, resumable.
"""

from __future__ import annotations

import math

import cloudpickle
import control as ct
import numpy as np
import pandas as pd
import pytest
from conftest import EXAMPLES

from controllers.sweep import SweepSpec, _prepare
from controllers.sweep_cli import spec_from_args
from flexlink.cli import build_parser, main
from flexlink.mechanics.model import build_model
from flexlink.run.linearize import linear_plant
from flexlink.scene.loader import load_scene

SCENE = str(EXAMPLES / "two_link_payload.toml")
DT = 1e-3
MANOEUVRE = ["--target", "60,20", "--duration", "1.5", "--settle", "0.5"]
WEIGHTS = ["--torque-limit", "shoulder=60,elbow=40", "--joint-error", "shoulder=0.2", "--tip-deflection", "fore=2",
           "--root-moment", "60,30", "--mode-limit", "upper.eta[1]=2e-3"]
#: What WEIGHTS say, SI: the elbow's joint error and the upper arm's tip deflection keep their defaults.
LIMITS = {"shoulder.theta": math.radians(0.2), "elbow.theta": math.radians(0.5), "upper.tip.v": 5e-3,
          "upper.root.moment": 60.0, "fore.tip.v": 2e-3, "fore.root.moment": 30.0, "upper.eta[1]": 2e-3}


def python_control_dlqr(plant, limits: dict[str, float], torque: list[float]) -> np.ndarray:
    """Bryson's Q, R written here from the plant's output rows, and python-control's dlqr on its ZOH sampling."""
    Cz = np.asarray(plant.C)[[plant.outputs.index(name) for name in limits]]
    Q = Cz.T @ np.diag([1.0 / v**2 for v in limits.values()]) @ Cz
    Q = 0.5 * (Q + Q.T)
    R = np.diag([1.0 / u**2 for u in torque])
    cols = [plant.inputs.index(n) for n in ("shoulder.tau", "elbow.tau")]
    sysd = ct.sample_system(ct.ss(plant.A, np.asarray(plant.B)[:, cols], plant.C, np.asarray(plant.D)[:, cols]), DT)
    K, _, _ = ct.dlqr(sysd.A, sysd.B, Q, R)
    return np.asarray(K)


def member_design(spec: SweepSpec):  # the example's FMU from the cache that example_fmu fills
    """The design a sweep's members run: the one ``run_sweep`` ships to its workers (cloudpickled)."""
    settings, blob = _prepare(spec).make_design()
    return settings, cloudpickle.loads(blob)


def test_a_sweep_members_gains_are_python_controls_dlqr(example_fmu, tmp_path):
    fmu = str(example_fmu("two_link_payload"))
    args = build_parser().parse_args(["sweep", SCENE, *MANOEUVRE, *WEIGHTS, "--param", "fore.payload.mass=1.5",
                                      "--out", str(tmp_path / "w.csv")])
    settings, d = member_design(spec_from_args(args))
    assert d.lqr.limits == pytest.approx(LIMITS, rel=1e-15)
    assert d.lqr.torque_limits == {"shoulder": 60.0, "elbow": 40.0}
    K = python_control_dlqr(linear_plant(build_model(load_scene(SCENE))), LIMITS, [60.0, 40.0])
    np.testing.assert_allclose(d.lqr.Kd, K, rtol=0, atol=1e-9 * np.abs(K).max())
    assert settings["weights"]["joint_error"] == {"shoulder": 0.2}
    # the same limits from a spec file: a TOML table by name, an array one per link, text as on the command line
    spec = tmp_path / "w.toml"
    spec.write_text(f'scene = "{SCENE}"\nfmu = "{fmu}"\ntarget_deg = [60, 20]\nduration = 1.5\nsettle = 0.5\n'
                    'params = {"fore.payload.mass" = 1.5}\ntorque_limit = {shoulder = 60, elbow = 40}\n'
                    'joint_error = {shoulder = 0.2}\n'
                    'tip_deflection = {fore = 2}\nroot_moment = [60, 30]\nmode_limit = "upper.eta[1]=2e-3"\n')
    _, d2 = member_design(SweepSpec.from_toml(spec))
    np.testing.assert_array_equal(d2.lqr.Kd, d.lqr.Kd)


def test_a_weighted_sweep_runs_and_its_weights_are_its_identity(example_fmu, tmp_path, capsys):
    out = tmp_path / "w.csv"
    base = ["sweep", SCENE, *MANOEUVRE, "--param", "fore.payload.mass=1.5", "--scheduler", "serial",
            "--out", str(out), "--no-progress"]
    assert main([*base, *WEIGHTS]) == 0
    capsys.readouterr()
    df = pd.read_csv(out)
    assert len(df) == 1 and not df["failed"].any() and df["stable"].iloc[0] == 1.0
    assert main([*base, "--torque-limit", "shoulder=60,elbow=40", "--joint-error", "0.3"]) == 2
    err = capsys.readouterr().err
    assert "holds a sweep with other settings" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("options, words", [
    (["--joint-error", "wrist=0.2"], "'wrist' is not a joint of the scene"),
    (["--tip-deflection", "lower=1"], "'lower' is not a link of the scene"),
    (["--torque-limit", "shoulder=60"], "no limit for the torque-driven joint(s) elbow"),
    (["--mode-limit", "upper.eta[3]=1e-3"], "'upper.eta[3]' is not a mode of the model"),
    (["--joint-error", "0.1,0.2,0.3"], "one per item of the joints with an encoder"),
    (["--torque-limit", "60,50,40"], "one limit for all joints or one per torque-driven joint"),
    (["--root-moment", "upper=0"], "expected a positive number"),
    (["--joint-error", "shoulder=-1"], "expected a positive number"),
    (["--mode-limit", "nan"], "expected a finite number"),
])
def test_bad_weights_are_one_line_and_status_2(example_fmu, tmp_path, capsys, options, words):
    out = tmp_path / "bad.csv"
    opts = options if "--torque-limit" in options else ["--torque-limit", "60", *options]
    try:
        status = main(["sweep", SCENE, *MANOEUVRE, *opts, "--param", "fore.payload.mass=1.5", "--scheduler",
                       "serial", "--out", str(out), "--no-progress"])
    except SystemExit as e:                     # argparse's usage error: its own exit, status 2
        status = e.code
    assert status == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and len(err.strip().splitlines()) <= 2
    assert not out.exists() and not (tmp_path / "bad.csv.journal.jsonl").exists()


def test_a_spec_files_bad_weight_names_the_key(tmp_path):
    spec = tmp_path / "w.toml"
    spec.write_text(f'scene = "{SCENE}"\ntarget_deg = [60, 20]\nduration = 1.5\njoint_error = {{shoulder = "x"}}\n')
    with pytest.raises(Exception, match=r"joint_error.shoulder = 'x': expected a number"):
        SweepSpec.from_toml(spec)
    with pytest.raises(Exception, match=r"tip_deflection \(--tip-deflection\): expected a positive number, got -1"):
        SweepSpec(scene=SCENE, target_deg=(60, 20), duration=1.5, tip_deflection=[-1])


def test_an_overwrite_whose_design_is_refused_keeps_the_results_it_would_replace(example_fmu, tmp_path, capsys):
    """``--overwrite`` discards FILE and its journal once the new sweep can run, not before its design.

    A weight's count is checked against the model when the controller is designed (after the scene's names,
    before any case); an overwrite refused then used to have deleted the earlier results and left a journal of
    the refused sweep, which a later run of the earlier sweep read as "a sweep with other settings".
    """
    example_fmu("two_link_payload")
    out = tmp_path / "w.csv"
    base = ["sweep", SCENE, *MANOEUVRE, "--torque-limit", "60", "--param", "fore.payload.mass=1.5", "--scheduler",
            "serial", "--out", str(out), "--no-progress"]
    assert main(base) == 0
    capsys.readouterr()
    journal = tmp_path / "w.csv.journal.jsonl"
    kept = out.read_bytes(), journal.read_bytes()
    assert main([*base, "--overwrite", "--joint-error", "0.1,0.2,0.3"]) == 2
    err = capsys.readouterr().err
    assert "one per item of the joints with an encoder" in err and len(err.strip().splitlines()) == 1
    assert (out.read_bytes(), journal.read_bytes()) == kept
    assert main(base) == 0                        # the earlier sweep resumes from its journal: nothing recomputed
    assert "0 computed now, 1 from the journal" in capsys.readouterr().out
    assert main([*base, "--overwrite"]) == 0      # an overwrite that runs starts afresh
    assert "1 computed now, 0 from the journal" in capsys.readouterr().out
    assert len(pd.read_csv(out)) == 1 and journal.read_bytes() != kept[1]
