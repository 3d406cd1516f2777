"""Fast chains with second-order kinematics run to the end at Θ = ½ at every internal step (issue 14).

Three arms whipped by τᵢ = Aᵢ sin 2πt for t < 1 s and then left to swing: the issue's planar two-link arm
(where the equation-truncated model of flexlink ≤ 0.1 returned fmi2Discard at t ≈ 2.5 s for a 1e-4 s step),
a heavier one in a vertical plane under gravity, and a three-joint spatial arm under gravity.

What the assertions rest on, none of it from our own earlier runs:
* the work–energy theorem: the torques are held over each 1 ms communication step, so the work they do is
  exactly W = Σₖ τₖ (θₖ₊₁ − θₖ), and the model's own energy must change by W: E(t) − E(0) = W(t);
* the integrator's order: SS22 with Θ = ½ is second order, so the energy-balance error and the distance of
  the joint angles from the finest step's shrink by ≈ (h₁/h₂)² between steps.

The spatial arm's torques (3, 15, 4 N m) keep it inside the beam model: with (10, 40, 10) N m the upper
link twists past 0.35 rad at t ≈ 1.31 s and the FMU refuses the step (its validity guard), and at a 2e-4 s
step Newton fails first, at t ≈ 1.03 s, as the twist nears that range — a manoeuvre outside the model, not
a stable one lost.

``FLEXLINK_FULL=1`` runs the issue's steps 1e-3, 1e-4, 2e-5 s on all three arms; CI runs the two-link arm
at 1e-3 and 1e-4 s (each of the others costs minutes of gcc for its second-order Newton matrix).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from flexlink.export.cache import cached_fmu
from flexlink.run.simulate import simulate
from flexlink.scene.loader import load_scene

ROOT = Path(__file__).resolve().parents[1]
FULL = bool(os.environ.get("FLEXLINK_FULL"))
STEPS = [1e-3, 1e-4, 2e-5] if FULL else [1e-3, 1e-4]
COMM = 1e-3

# scene, torque amplitudes per joint (N m), stop time (s)
CASES = {
    "fast_two_link": (ROOT / "examples" / "fast_two_link.toml", (40.0, 10.0), 3.0),
    "fast_heavy_gravity": (ROOT / "benchmarks" / "hard_cases" / "fast_heavy_gravity.toml", (60.0, 20.0), 3.0),
    "fast_spatial_arm": (ROOT / "benchmarks" / "hard_cases" / "fast_spatial_arm.toml", (3.0, 15.0, 4.0), 2.0),
}


def whip(scene, amplitudes, stop: float) -> np.ndarray:
    """The inputs τᵢ = Aᵢ sin 2πt for t < 1 s, 0 after, on the communication grid."""
    t = np.arange(0.0, stop + COMM / 2, COMM)
    names = [f"{j.name}.tau" for j in scene.joints]
    inputs = np.zeros(t.size, dtype=[("time", float)] + [(n, float) for n in names])
    inputs["time"] = t
    for name, amplitude in zip(names, amplitudes, strict=True):
        inputs[name] = np.where(t < 1.0, amplitude * np.sin(2 * np.pi * t), 0.0)
    return inputs


@pytest.fixture(scope="module", params=list(CASES) if FULL else ["fast_two_link"])
def runs(request):
    """Each case run at every step: (scene, inputs, {step: result})."""
    path, amplitudes, stop = CASES[request.param]
    scene = load_scene(path)
    fmu = cached_fmu(scene)
    inputs = whip(scene, amplitudes, stop)
    results = {h: simulate(fmu, stop, step=COMM, inputs=inputs, start_values={"solver.step": h}) for h in STEPS}
    return scene, inputs, results


def balance_error(scene, inputs, result) -> float:
    """max over t of |E(t) − E(0) − W(t)| relative to the largest kinetic energy."""
    energy = result["energy.kinetic"] + result["energy.potential"]
    work = np.zeros_like(energy)
    for joint in scene.joints:
        tau = inputs[f"{joint.name}.tau"][:-1]
        work[1:] += np.cumsum(tau * np.diff(result[f"{joint.name}.theta"]))
    return float(np.max(np.abs(energy - energy[0] - work)) / np.max(result["energy.kinetic"]))


def test_runs_to_the_end_at_every_step(runs):
    scene, _, results = runs
    for h, result in results.items():
        values = np.column_stack([result[n] for n in result.dtype.names])
        assert np.all(np.isfinite(values)), f"non-finite output at step {h}"
        omega = [np.max(np.abs(result[f"{j.name}.omega"])) for j in scene.joints]
        assert max(omega) > 2.0, f"step {h}: the arm was not whipped (peak joint rate {max(omega):.2f} rad/s)"


def test_energy_changes_by_the_work_of_the_torques(runs):
    scene, inputs, results = runs
    errors = {h: balance_error(scene, inputs, r) for h, r in results.items()}
    print(f"\n{scene.name}: energy-balance error / max T: " + ", ".join(f"h={h:g}: {e:.2e}" for h, e in errors.items()))
    assert errors[1e-3] < 1e-2
    assert errors[1e-4] < errors[1e-3] / 30          # second order: ÷100 ideally, ÷30 allows a pre-asymptotic step
    if 2e-5 in errors:
        assert errors[2e-5] < errors[1e-4] / 10      # ÷25 ideally


def test_joint_angles_converge_at_second_order(runs):
    scene, _, results = runs
    finest = min(results)
    coarse = [h for h in sorted(results, reverse=True) if h != finest]
    if FULL:
        names = [f"{j.name}.theta" for j in scene.joints]
        dist = {h: max(np.max(np.abs(results[h][n] - results[finest][n])) for n in names) for h in coarse}
        print(f"\n{scene.name}: max |θ_h − θ_finest|: " + ", ".join(f"h={h:g}: {d:.2e}" for h, d in dist.items()))
        assert dist[1e-4] < dist[1e-3] / 30
    else:                                              # two steps only: the coarse one against the fine one
        names = [f"{j.name}.theta" for j in scene.joints]
        span = max(np.ptp(results[finest][n]) for n in names)
        dist = max(np.max(np.abs(results[coarse[0]][n] - results[finest][n])) for n in names)
        assert dist < 0.05 * span, f"1 ms step off by {dist:.3g} rad on a {span:.3g} rad motion"


def test_energy_of_the_free_swing_is_conserved():
    """The issue's two-link arm, undamped, unforced after the whip (t ≥ 1 s): E = T + V must stay within
    1e-6 of its value at t = 1 s over 100 s at Θ = ½ (FLEXLINK_FULL; 10 s in CI).  The model is a Lagrangian
    (conserved by the exact flow) and SS22 with Θ = ½ keeps it to O(h²); the Newton tolerance is tightened
    to 1e-13 so that what is measured is the integrator, not the stopping rule of its iteration (at the
    default 1e-10 the error grows with the number of steps: 1.4e-6 at h = 1e-4, 2.9e-6 at 5e-5)."""
    path, amplitudes, _ = CASES["fast_two_link"]
    stop, h = (101.0, 5e-5) if FULL else (11.0, 1e-4)
    scene = load_scene(path)
    result = simulate(cached_fmu(scene), stop, step=COMM, inputs=whip(scene, amplitudes, stop),
                      start_values={"solver.step": h, "solver.tolerance": 1e-13})
    energy = result["energy.kinetic"] + result["energy.potential"]
    free = result["time"] >= 1.0
    drift = np.max(np.abs(energy[free] - energy[free][0])) / energy[free][0]
    print(f"\nfree swing {stop - 1:g} s at h = {h:g}: max |E − E(1)| / E(1) = {drift:.2e}")
    assert drift <= 1e-6
