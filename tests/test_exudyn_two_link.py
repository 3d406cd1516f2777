"""flexlink against an independent geometrically exact beam model (Exudyn) on examples/fast_two_link.toml.

The case (issue 14): a planar two-link aluminium arm driven by τ₁ = 40 sin 2πt, τ₂ = 10 sin 2πt for t < 1 s,
0 afterwards, 1 ms communication steps, Θ = ½. The Exudyn model (tests/references/exudyn_arm.py) is built from
Exudyn's own items: geometrically exact 2D beams (Simo–Reissner, linear elements) made inextensible and
shear-rigid by a large EA and GA, rigid hubs with the rotor inertias, revolute joints, the elbow torque reacting
on link 1's tip, a point payload; generalised-α. It is converged first (N and 2N elements, step h and h/2,
EA = GA ten times larger: the changes are printed and must be small against the tolerances), then flexlink's
FMU (converged in its step, h and h/2) must agree with it:
joint angles to 1e-3 of their amplitude, tip deflections to 1e-2 of theirs.

The FMU holds an input over a communication step; it is fed the torque at the middle of each step (a
second-order sampling of the continuous law that Exudyn evaluates), so both sides see the same load to
O(Δt²) ≈ 1e-6 relative.

CI size: 0–1.2 s, Exudyn N = 32/64 elements per link at h = 1e-4/5e-5 s. FLEXLINK_FULL=1: 0–2 s, N = 64/128 at
h = 5e-5/2.5e-5 s, and flexlink itself with 12 elements per link (an FMU build of a few minutes).
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("exudyn")

from references.exudyn_arm import simulate, torques  # noqa: E402

from flexlink.export.cache import cached_fmu  # noqa: E402
from flexlink.run.simulate import SlaveRunner  # noqa: E402
from flexlink.scene.loader import parse_scene  # noqa: E402

FULL = os.environ.get("FLEXLINK_FULL") == "1"
SCENE = Path(__file__).resolve().parents[1] / "examples" / "fast_two_link.toml"
COMM = 1e-3
STOP = 2.0 if FULL else 1.2
N_EXUDYN, H_EXUDYN = (64, 5e-5) if FULL else (32, 1e-4)
ANGLES = ("shoulder.theta", "elbow.theta")
TIPS = ("upper.tip.v", "fore.tip.v")
TOLERANCE = {**dict.fromkeys(ANGLES, 1e-3), **dict.fromkeys(TIPS, 1e-2)}
CONVERGED = 0.3      # a reference's own change (N → 2N, h → h/2) below 0.3 × the comparison tolerance


def midpoint_inputs(t: float) -> dict[str, float]:
    tau1, tau2 = torques(t + 0.5 * COMM)
    return {"shoulder.tau": tau1, "elbow.tau": tau2}


def run_flexlink(fmu, step: float) -> dict[str, np.ndarray]:
    with SlaveRunner(fmu) as runner:
        return runner.run(STOP, COMM, inputs=midpoint_inputs, start={"solver.step": step},
                          outputs=[*ANGLES, *TIPS])


def deviation(a: dict, b: dict) -> dict[str, float]:
    """max |a − b| over [0, STOP] relative to max |b|, per output (b's time grid; a interpolated onto it)."""
    t = b["time"]
    keep = t <= STOP + 1e-9
    return {k: float(np.max(np.abs(np.interp(t[keep], a["time"], a[k]) - b[k][keep])) / np.max(np.abs(b[k][keep])))
            for k in TOLERANCE}


def show(title: str, dev: dict[str, float]) -> None:
    print(f"{title:<44s}" + "  ".join(f"{k} {v:.2e}" for k, v in dev.items()))


@pytest.fixture(scope="module")
def exudyn_runs():
    runs = {(n, h): simulate(n, h, STOP, output_step=COMM)
            for n, h in [(N_EXUDYN, H_EXUDYN), (2 * N_EXUDYN, H_EXUDYN), (N_EXUDYN, H_EXUDYN / 2)]}
    runs["EA×10"] = simulate(N_EXUDYN, H_EXUDYN, STOP, output_step=COMM, EA=1e10, GA=1e10)
    return runs


@pytest.fixture(scope="module")
def flexlink_runs():
    fmu = cached_fmu(SCENE)
    return {step: run_flexlink(fmu, step) for step in ((1e-4, 2e-5) if FULL else (1e-4, 5e-5))}


def test_exudyn_reference_is_converged_in_elements_step_and_stiffness(exudyn_runs):
    """N → 2N elements, h → h/2, and EA = GA ten times stiffer (inextensible, shear-rigid limit)."""
    n, h = N_EXUDYN, H_EXUDYN
    base = exudyn_runs[(n, h)]
    for key, what in [((2 * n, h), f"Exudyn N {n} → {2 * n}, h {h:g}"),
                      ((n, h / 2), f"Exudyn h {h:g} → {h / 2:g}, N {n}"),
                      ("EA×10", "Exudyn EA = GA 1e9 → 1e10 N")]:
        dev = deviation(base, exudyn_runs[key])
        show(what, dev)
        for k, v in dev.items():
            assert v < CONVERGED * TOLERANCE[k], (what, k, v)


def test_flexlink_is_converged_in_step(flexlink_runs):
    (h1, coarse), (h2, fine) = sorted(flexlink_runs.items(), reverse=True)
    dev = deviation(coarse, fine)
    show(f"flexlink h {h1:g} → {h2:g}", dev)
    for k, v in dev.items():
        assert v < CONVERGED * TOLERANCE[k], (k, v)


def test_flexlink_agrees_with_exudyn(flexlink_runs, exudyn_runs):
    """Joint angles to 1e-3 of their amplitude, tip deflections to 1e-2, against the finest Exudyn runs."""
    flex = flexlink_runs[min(flexlink_runs)]
    amplitude = {k: float(np.max(np.abs(flex[k]))) for k in TOLERANCE}
    print("amplitudes: " + "  ".join(f"{k} {v:.4g}" for k, v in amplitude.items()))
    assert amplitude["shoulder.theta"] > 1.0 and amplitude["elbow.theta"] > 1.0    # a large motion, not a wiggle
    assert amplitude["upper.tip.v"] > 1e-3 and amplitude["fore.tip.v"] > 5e-4
    for key in [(2 * N_EXUDYN, H_EXUDYN), (N_EXUDYN, H_EXUDYN / 2)]:
        dev = deviation(flex, exudyn_runs[key])
        show(f"flexlink h {min(flexlink_runs):g} vs Exudyn N {key[0]}, h {key[1]:g}", dev)
        for k, v in dev.items():
            assert v < TOLERANCE[k], (key, k, v)


@pytest.mark.skipif(not FULL, reason="builds a 12-element FMU (minutes); FLEXLINK_FULL=1")
def test_flexlink_converged_in_elements_against_exudyn(flexlink_runs, exudyn_runs):
    """flexlink with 12 elements per link: how much of the difference is flexlink's own 6-element discretisation."""
    data = tomllib.loads(SCENE.read_text())
    for link in data["link"]:
        link["shapes"]["count"] = 12
    fine = run_flexlink(cached_fmu(parse_scene(data)), 1e-4)
    ref = exudyn_runs[(2 * N_EXUDYN, H_EXUDYN)]
    show("flexlink 6 → 12 elements, h 1e-4", deviation(flexlink_runs[1e-4], fine))
    dev = deviation(fine, ref)
    show(f"flexlink 12 el. vs Exudyn N {2 * N_EXUDYN}", dev)
    for k, v in dev.items():
        assert v < TOLERANCE[k], (k, v)
