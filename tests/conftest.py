"""Shared helpers for the single-link model tests (tests/test_model_*.py): a scene factory and a root
bracketer for the transcendental frequency equations that the tests solve themselves."""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from flexlink.scene.loader import Scene, parse_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

# The suite builds dozens of FMUs and runs each for a moment: their CasADi code is compiled at -O0 (a
# second-order link: gcc 4x faster, the FMU about 3x slower per step; the generic C keeps -O2).  With
# FLEXLINK_FULL=1 the FMUs are built as users get them.  Set here, so command-line runs inherit it.
if os.environ.get("FLEXLINK_FULL") != "1":
    os.environ.setdefault("FLEXLINK_OPTIMISE", "O0")

@pytest.fixture
def check_harness_lock():
    """Hold an exclusive lock for the test: the checks of tests/test_check.py and of the third-party FMUs
    (tests/test_check_third_party.py) never run at the same time on xdist workers.  Run side by side, the
    PythonFMU fixture's process died of SIGABRT in the fuzz's fmi2Instantiate with a wrong GUID and resource
    location (three CI runs of 2026-11-27, reproduced with `pytest -n 2 --dist loadfile` on those two files;
    one after the other they pass), and twice more on 2026-11-27 with the lock.  The cause is not found.  The
    old finding said "in" the last call even when it had returned: the process may have died at its exit,
    with the wrong-GUID instance never freed.  The harness now frees it, says "after" when no call was in
    progress, and quotes the child's last stderr lines (tests/test_check_isolation.py), so that a recurrence
    names its cause."""
    import fcntl
    import tempfile

    with open(os.path.join(tempfile.gettempdir(), "flexlink-tests-check-harness.lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture(scope="session")
def example_fmu():
    """``example_fmu(name)``: the FMU of examples/<name>.toml, from flexlink's build cache (several test files,
    the command-line runs and the test processes check the same examples; the FMUs are only read)."""
    from flexlink.export.cache import cached_fmu

    return lambda name: cached_fmu(EXAMPLES / f"{name}.toml")


# Seed 000 §3.4.3 link (examples/rotating_link.toml): E = 71 GPa, I_z = 1.32e-9 m^4, rho = 0.349 kg/m, L = 2.2 m.
SEED000_LINK = {"length": 2.2, "linear_density": 0.349, "EI": 93.72}


def make_link_scene(kind: str = "clamped-free", count: int = 3, kinematics: str = "second-order", *,
                    drive: str = "position", hub_inertia: float = 0.0, hub_damping: float = 0.0,
                    angle: float = 0.0, rate: float = 0.0, gravity=(0.0, 0.0, 0.0), payload: dict | None = None,
                    kelvin_voigt: float = 0.0, length: float = SEED000_LINK["length"],
                    linear_density: float = SEED000_LINK["linear_density"], EI: float = SEED000_LINK["EI"]) -> Scene:
    """One joint (axis z) driving one in-plane link.

    ``drive="position"``: the hub is held at ``angle`` by a built-in constant law (the steady rate of
    ``natural_frequencies(model, rate=W)`` is then imposed by the analysis); otherwise the hub is a free
    coordinate starting at ``angle`` with rate ``rate``.
    """
    joint = {"name": "hub", "axis": [0.0, 0.0, 1.0], "drive": drive, "inertia": hub_inertia, "damping": hub_damping}
    if drive == "position":
        joint["trajectory"] = {"segments": [{"until": math.inf, "poly": [angle]}]}
    else:
        joint["initial_angle"] = angle
        joint["initial_rate"] = rate
    link = {"name": "arm", "length": length, "linear_density": linear_density, "EI": EI, "deformation": ["v"],
            "shapes": {"kind": kind, "count": count}, "kinematics": kinematics, "kelvin_voigt": kelvin_voigt}
    if payload:
        link["payload"] = dict(payload)
    return parse_scene({"name": "single_link", "gravity": list(gravity), "joint": [joint], "link": [link]})


def bracket_roots(f, lo: float, hi: float, samples: int = 4000) -> np.ndarray:
    """All sign changes of f on [lo, hi] (sampled), each refined by brentq to full precision."""
    xs = np.linspace(lo, hi, samples)
    fs = np.array([f(x) for x in xs])
    out = []
    for i in range(samples - 1):
        if fs[i] == 0.0:
            out.append(xs[i])
        elif fs[i] * fs[i + 1] < 0.0:
            out.append(brentq(f, xs[i], xs[i + 1], xtol=1e-15, rtol=4 * np.finfo(float).eps))
    return np.array(out)


def clamped_free_lambdas(count: int) -> np.ndarray:
    """Roots of 1 + cos λ cosh λ = 0, written as cos λ + 1/cosh λ = 0 (no overflow), one per (i−1/2)π ± π/2."""
    return np.array([brentq(lambda lam: math.cos(lam) + 1.0 / math.cosh(lam), (i - 1) * math.pi, i * math.pi,
                            xtol=1e-15) for i in range(1, count + 1)])


def broken_loop_margins(T, i: int, w):
    """python-control's (gain margin dB, |phase margin| deg) of the loop ``T`` (torques applied → torques asked
    for, positive feedback) broken at input i with the other channels closed (``control.feedback``), from its
    frequency response on the grid w (``control.frd``, interpolated; ``stability_margins``, every crossover)."""
    import warnings

    import control as ct

    m = T.ninputs
    L = -ct.feedback(T, np.diag([0.0 if k == i else 1.0 for k in range(m)]), sign=1)[i, i]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gm, pm, *_ = ct.stability_margins(ct.frd(L, w, smooth=True), returnall=True)
    return float(20 * np.log10(np.min(gm[gm > 1]))), float(np.min(np.abs(pm)))


def assert_margins_are_python_controls(actuators, T, dt: float, where: str = "") -> None:
    """Each actuator's gain and phase margins (``actuators``: our figures, one dict per loop input) equal
    python-control's on the loop ``T`` broken at that input (:func:`broken_loop_margins`, on a grid up to
    Nyquist), to the grid's resolution."""
    import pytest

    w = np.logspace(-3, np.log10(np.pi / dt), 6000)[:-1]
    for i, fig in enumerate(actuators):
        gm, pm = broken_loop_margins(T, i, w)
        print(f"\n{where}{fig['input']}: gain margin {fig['gain_margin_db']:.4f} dB (python-control {gm:.4f}), "
              f"phase margin {fig['phase_margin_deg']:.3f}°")
        assert fig["gain_margin_db"] == pytest.approx(gm, abs=2e-3)
        assert abs(fig["phase_margin_deg"]) == pytest.approx(pm, abs=2e-2)


class BiasedLaw:
    """A controller law's torques plus a constant torque ``bias`` the model lacks (the disturbance that integral
    action must reject), with the law's interface (kind, limits, sample time, sensors, inputs)."""

    def __init__(self, law, bias):
        self.law, self.bias, self.kind, self.limits = law, np.asarray(bias), law.kind, getattr(law, "limits", None)
        self.dt, self.sensors, self.inputs = law.dt, law.sensors, law.inputs

    def reset(self):
        self.law.reset()

    def step(self, y, x_ref, u_ff):
        return self.law.step(y, x_ref, u_ff) + self.bias


def assert_runs_equal(a, b, rel: float = 1e-9) -> dict:
    """Two closed-loop runs' series equal to ``rel`` of each series' scale (at least 1); the largest differences."""
    worst = {}
    for name, x in a.series.items():
        scale = max(1.0, float(np.max(np.abs(x))))
        worst[name] = float(np.max(np.abs(b[name] - x)))
        assert worst[name] <= rel * scale, name
    return worst


def two_link_plant_at(angles: tuple):
    """examples/two_link_payload.toml with its joints' initial_angle at ``angles`` (shoulder, elbow), built and
    linearised afresh (cached: the schedule tests ask for the same poses)."""
    return _two_link_plant(tuple(round(float(a), 12) for a in angles))


@functools.cache
def _two_link_plant(angles: tuple):
    import tomllib

    from flexlink.mechanics.model import build_model
    from flexlink.run.linearize import linear_plant

    data = tomllib.loads((EXAMPLES / "two_link_payload.toml").read_text())
    for j, a in zip(data["joint"], angles, strict=True):
        j["initial_angle"] = a
    return linear_plant(build_model(parse_scene(data)))
