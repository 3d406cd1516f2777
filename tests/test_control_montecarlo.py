"""Monte Carlo robustness of the two-link LQG through ``flexlink sweep`` (controllers/montecarlo.py).

Four seeded draws of payload mass and both links' stiffness, the nominal design fixed: each case's
stability verdict from the FMU (the start pose held after a torque pulse) against python-control's
closed-loop poles of the plant linearised with that case's parameters, sampled, in loop with the nominal
sampled LQG.  The seed draws stable and unstable plants (checked here from the poles), none within 0.15 % of
the unit circle.
"""

from __future__ import annotations

import pandas as pd
from conftest import EXAMPLES

from controllers.manoeuvre import design
from controllers.montecarlo import linear_verdict
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

SCENE = EXAMPLES / "two_link_payload.toml"
DRAWS = {"fore.payload.mass": "uniform:0.5:6", "upper.EI": "uniform:1800:3400", "fore.EI": "uniform:1800:3400"}


def test_monte_carlo_verdicts_against_the_poles(tmp_path, capsys):
    from flexlink.cli import main

    out = tmp_path / "mc.csv"
    args = ["sweep", str(SCENE), "--samples", "4", "--seed", "1", "--target", "60,20", "--duration", "1.5",
            "--settle", "0.5", "--torque-limit", "60", "--scheduler", "serial", "--out", str(out), "--no-progress"]
    for name, dist in DRAWS.items():
        args += ["--distribution", f"{name}={dist}"]
    assert main(args) == 0
    text = capsys.readouterr().out
    df = pd.read_csv(out)
    assert len(df) == 4 and not df["failed"].any()
    d = design(build_model(load_scene(SCENE)), torque_limit=60.0, dt=1e-3)
    radii = [linear_verdict(d, {k: float(row[k]) for k in DRAWS}) for _, row in df.iterrows()]
    assert all(abs(r - 1) > 0.0015 for r in radii)               # no marginal draw
    assert any(r < 1 for r in radii) and any(r > 1 for r in radii)       # both verdicts drawn
    for r, (_, row) in zip(radii, df.iterrows(), strict=True):
        assert row["stable"] == float(r < 1), (r, row.to_dict())
    n_stable = int((df["stable"] == 1.0).sum())
    assert f"stable at the start pose (hold): {n_stable} of 4" in text
    print(f"\nspectral radii {[round(r, 4) for r in radii]}, hold decay {df['hold_decay_ratio'].round(4).tolist()}")


def test_joint_pd_in_a_multi_joint_sweep(tmp_path, capsys):
    """``--controller pd`` on the two-link arm: each case's hold verdict from the FMU against python-control's
    closed-loop poles of the joint PD (static gain on encoders and rates) with the plant linearised with
    that case's parameters.  A light payload is what the PD does not hold (at the nominal links, a 0.2 kg
    payload gives a radius of 1.12); the seed draws both verdicts (checked here from the poles)."""
    from flexlink.cli import main

    out = tmp_path / "pd.csv"
    draws = {"fore.payload.mass": "uniform:0.1:3", "upper.EI": "uniform:1500:4000"}
    args = ["sweep", str(SCENE), "--samples", "4", "--seed", "3", "--controller", "pd", "--target", "60,20",
            "--duration", "1.5", "--settle", "0.5", "--torque-limit", "60", "--scheduler", "serial", "--out",
            str(out), "--no-progress"]
    for name, dist in draws.items():
        args += ["--distribution", f"{name}={dist}"]
    assert main(args) == 0
    assert "stable at the start pose (hold)" in capsys.readouterr().out
    df = pd.read_csv(out)
    assert len(df) == 4 and not df["failed"].any()
    d = design(build_model(load_scene(SCENE)), torque_limit=60.0, dt=1e-3)
    radii = [linear_verdict(d, {k: float(row[k]) for k in draws}, "pd") for _, row in df.iterrows()]
    print(f"\nPD spectral radii {[round(r, 5) for r in radii]}, hold decay {df['hold_decay_ratio'].round(4).tolist()}"
          f", settled {df['settled'].tolist()}")
    assert all(abs(r - 1) > 1e-3 for r in radii)                    # no marginal draw
    assert any(r < 1 for r in radii) and any(r > 1 for r in radii)       # both verdicts drawn
    for r, (_, row) in zip(radii, df.iterrows(), strict=True):
        assert row["stable"] == float(r < 1), (r, row.to_dict())
