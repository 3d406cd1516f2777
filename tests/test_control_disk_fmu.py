"""The disk margins checked on the FMU (issue 16): "a margin that says stable must be stable in the FMU".

The start pose is held in closed loop with the plant FMU (fmpy) after a small 5 ms torque pulse, each
actuator's torque deviation scaled by a real gain between the sampled LQG and the plant (the loop broken at
the plant input, where the disk margins are defined; the estimator still sees the commanded torque):

* **inside the disk**: 0.9 of the way (in dB) to the edge of the reported disk's gain range, up and down —
  at one actuator with its loop-at-a-time disk margin, and at all actuators at once with the simultaneous
  one — the FMU's loop dies out (the last torques below a tenth of those just after the pulse);
* **outside**: at 1.1 of the way to the disk's edge the disk promises nothing; the loop's poles, built here
  from the plant's matrices (ZOH by ``expm``) and the gains, say what happens, and the FMU does it: it dies
  out where they are inside the unit circle, and grows where one is outside (the two-link arm's elbow, where
  the disk's gain range nearly reaches the classical gain margin, and all actuators at once), at the rate
  they predict (the envelope's growth per sample against log ρ, to 10 %, the FMU's integrator converged:
  ``solver.step`` 2.5e-5 s);
* where the disk is conservative (the shoulder, the rotating link: 1.1 × the disk's edge is still inside the
  gain margin), at 1.1 × the critical gain of the classical gain margin the FMU's loop grows.

Every reported disk's edge lies inside the stability range the poles give.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from conftest import EXAMPLES

from controllers.cosim import FmuLoop
from controllers.design import torque_inputs
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw
from controllers.trajectory import Reference
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene

PULSE, HOLD = 0.1, 1500
CASES = {"two_link_payload": 60.0, "rotating_link": 2.0}


class ActuatorGains:
    """The LQG with the torque deviations scaled by ``g`` (one gain per actuator) on their way to the plant."""

    kind = "lqr"

    def __init__(self, law: MimoLQGLaw, g: np.ndarray):
        self.law, self.g = law, np.asarray(g, dtype=float)
        self.dt, self.sensors, self.inputs = law.dt, law.sensors, law.inputs

    def reset(self) -> None:
        self.law.reset()

    def step(self, y, x_ref, u_ff):
        u = self.law.step(y, x_ref, u_ff)
        return self.law.u0 + self.g * (u - self.law.u0)


def radius(d, g: np.ndarray) -> float:
    """Spectral radius of the sampled LQG loop with input gains g, from the plant's A, B (ZOH here), the
    sensors' C and the gains K_d, M_d: x⁺ = A_d x + B_d G u, u = −K_d x̂, x̂ = (I − M C) z + M C x,
    z⁺ = (A_d − B_d K_d) x̂."""
    p, kf = d.plant, d.kalman
    n = p.sys.nstates
    B = np.asarray(p.sys.B)[:, torque_inputs(p)]
    m = B.shape[1]
    E = scipy.linalg.expm(np.block([[p.sys.A, B], [np.zeros((m, n + m))]]) * d.dt)
    Ad, Bd = E[:n, :n], E[:n, n:]
    C = p.sys.C[[p.output_row(s) for s in kf.sensors]]
    G = np.diag(g)
    F, M, K = np.eye(n) - kf.Md @ C, kf.Md, d.lqr.Kd
    A = np.block([[Ad - Bd @ G @ K @ M @ C, -Bd @ G @ K @ F], [(Ad - Bd @ K) @ M @ C, (Ad - Bd @ K) @ F]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


@pytest.fixture(scope="module", params=list(CASES))
def rig(request, example_fmu):
    name = request.param
    d = design(build_model(load_scene(EXAMPLES / f"{name}.toml")), torque_limit=CASES[name], dt=1e-3)
    with FmuLoop(example_fmu(name)) as loop:
        yield d, loop


def hold(d, loop, g: np.ndarray, steps: int, solver_step: float = 1e-4) -> np.ndarray:
    """The largest torque deviation at each sample of the held pose after the pulse, gains g."""
    n, m = d.plant.sys.nstates, len(d.lqr.inputs)
    u_ff = np.zeros((steps + 1, m))
    u_ff[:5] = PULSE
    ref = Reference("pulse", d.dt, 0.0, np.arange(steps + 1) * d.dt, np.zeros((steps + 1, n)), u_ff, 0)
    law = MimoLQGLaw(d, [1e6] * m, ref)
    res = loop.run(ActuatorGains(law, g), ref, parameters={"solver.step": solver_step})
    return np.max(np.abs(np.column_stack([res[u] for u in d.lqr.inputs]) - law.u0), axis=1)


def growth_per_sample(u: np.ndarray, window: int = 36) -> float:
    """The envelope's exponential rate (per sample): a line through the log of its maxima over windows, while
    it is below 20 × its size just after the pulse (small deviations: the linear regime)."""
    early = np.max(u[6:16])
    env = np.array([np.max(u[j:j + window]) for j in range(16, len(u) - window, window)])
    keep = env < 20 * early
    return float(np.polyfit((np.arange(len(env)) * window)[keep], np.log(env[keep]), 1)[0])


def disks(d) -> list[tuple[str, np.ndarray, float]]:
    """(label, direction, disk gain margin dB): each actuator alone, and all together (several actuators)."""
    rob = d.robustness()["lqg"]
    m = len(d.lqr.inputs)
    out = [(a["input"], np.eye(m)[i], a["disk_gain_margin_db"]) for i, a in enumerate(rob["actuators"])]
    if m > 1:
        out.append(("all", np.ones(m), rob["multiloop"]["disk_gain_margin_db"]))
    return out


def test_inside_the_disk_the_fmu_settles(rig):
    d, loop = rig
    for label, e, dgm in disks(d):
        assert math.isfinite(dgm) and dgm > 0
        for side in (1, -1):
            g = 10 ** (side * e * 0.9 * dgm / 20)
            r = radius(d, g)
            assert r < 1, (label, side)                    # the disk's guarantee, on the poles
            u = hold(d, loop, g, HOLD)
            early, late = np.max(u[6:16]), np.max(u[-20:])
            print(f"\n{label} x {g} (0.9 of the disk's {side * dgm:+.3g} dB): radius {r:.5f}, |tau| {early:.3g} -> "
                  f"{late:.3g} N m")
            assert late < 0.1 * early, (label, side)


def test_outside_the_disk_the_fmu_does_what_the_poles_say(rig):
    d, loop = rig
    grew = []
    for label, e, dgm in disks(d):
        g = 10 ** (e * 1.1 * dgm / 20)
        r = radius(d, g)
        if r < 1:
            u = hold(d, loop, g, HOLD)
            assert np.max(u[-20:]) < 0.1 * np.max(u[6:16]), label
            continue
        steps = 16 + math.ceil(math.log(1e3) / math.log(r))
        u = hold(d, loop, g, steps, solver_step=2.5e-5)
        rate = growth_per_sample(u)
        print(f"\n{label} x {g} (1.1 of the disk's {dgm:.3g} dB): radius {r:.5f}, log r {math.log(r):.4g}, FMU's "
              f"growth {rate:.4g} per sample")
        assert np.max(u[-20:]) > 10 * np.max(u[6:16]), label
        assert rate == pytest.approx(math.log(r), rel=0.1), label
        grew.append(label)
    if d.plant.model.scene.name == "two_link_payload":
        assert grew == ["elbow.tau", "all"]


def test_the_gain_margin_bounds_the_disk(rig):
    """Where the disk is conservative: its edge inside the classical gain margin, and 1.1 × the critical gain
    (in dB) grows in the FMU."""
    d, loop = rig
    rob = d.robustness()["lqg"]
    for i, a in enumerate(rob["actuators"]):
        gm = a["gain_margin_db"]
        assert a["disk_gain_margin_db"] <= gm + 1e-9
        assert math.isfinite(gm)
        g = 10 ** (np.eye(len(rob["actuators"]))[i] * 1.1 * gm / 20)
        r = radius(d, g)
        assert r > 1
        u = hold(d, loop, g, 16 + math.ceil(math.log(1e3) / math.log(r)))
        print(f"\n{a['input']} x {g} (1.1 of the gain margin {gm:.3g} dB): radius {r:.5f}, |tau| "
              f"{np.max(u[6:16]):.3g} -> {np.max(u[-20:]):.3g} N m")
        assert np.max(u[-20:]) > 10 * np.max(u[6:16])
