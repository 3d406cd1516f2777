"""controllers.riccati against python-control: the LQR, Kalman and sampling results the designs use, computed
without importing python-control (issue 22), equal to python-control 0.10's own (``control.lqr``, ``dlqr``,
``lqe``, ``dlqe`` with ``method="scipy"``, ``sample_system(method="zoh")``, the frequency response
``sys[i, j](s)``) to the last bit, on the example plants and on random ones; and a design made by
controllers.design, field by field, equal to the one the same design makes through python-control.
"""

from __future__ import annotations

from pathlib import Path

import control as ct
import numpy as np
import pytest

from controllers import riccati
from controllers.design import _frequency_response, design_kalman, design_lqr, torque_inputs
from flexlink.mechanics.model import build_model
from flexlink.run.linearize import linear_plant
from flexlink.scene.loader import load_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DT = 1e-3


def _same(ours, theirs) -> None:
    """Equal to the bit (the same SciPy calls on the same arrays), NaN nowhere."""
    for a, b in zip(ours, theirs, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a, b)


def _random_plant(seed: int, n: int, m: int, p: int):
    """A random (A, B, C, QN-shaped) problem: A with eigenvalues on both sides of the imaginary axis."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    B, C = rng.standard_normal((n, m)), rng.standard_normal((p, n))
    W = rng.standard_normal((n, n))
    Q = W @ W.T + np.eye(n)
    V = rng.standard_normal((m, m))
    R = V @ V.T + np.eye(m)
    return A, B, C, 0.5 * (Q + Q.T), 0.5 * (R + R.T)


@pytest.fixture(scope="module", params=["rotating_link.toml", "two_link_payload.toml"])
def plant(request):
    return linear_plant(build_model(load_scene(EXAMPLES / request.param)))


@pytest.mark.parametrize("seed", range(4))
def test_random_problems_equal_python_control(seed):
    n, m, p = 6 + seed, 1 + seed % 3, 2 + seed % 2
    A, B, C, Q, R = _random_plant(seed, n, m, p)
    _same(riccati.lqr(A, B, Q, R), ct.lqr(A, B, Q, R, method="scipy"))
    Ad, Bd = riccati.zoh(A, B, 0.05)
    sysd = ct.sample_system(ct.ss(A, B, C, np.zeros((p, m))), 0.05, method="zoh")
    _same((Ad, Bd), (sysd.A, sysd.B))
    _same(riccati.dlqr(Ad, Bd, Q, R), ct.dlqr(sysd, Q, R, method="scipy"))
    G = np.eye(n)
    RN = np.eye(p) * 0.1
    _same(riccati.lqe(A, G, C, Q, RN), ct.lqe(A, G, C, Q, RN, method="scipy"))
    _same(riccati.dlqe(Ad, G, C, Q, RN), ct.dlqe(Ad, G, C, Q, RN, method="scipy"))


def test_refusals_are_python_controls():
    """A weight that is not symmetric, or a plant that cannot be stabilised: refused by both (ValueError here,
    python-control's own exception or SciPy's there)."""
    A, B, C, Q, R = _random_plant(7, 4, 1, 2)
    Qa = Q.copy()
    Qa[0, 1] += 1e-3
    with pytest.raises(ValueError, match="symmetric"):
        riccati.lqr(A, B, Qa, R)
    with pytest.raises(ct.ControlArgument, match="symmetric"):
        ct.lqr(A, B, Qa, R, method="scipy")
    # an unstable mode (λ = 2: right half-plane and outside the unit circle) that nothing reaches
    Au, Bu = np.diag([2.0, -1.0, 0.5, -0.5]), np.array([[0.0], [1.0], [1.0], [1.0]])
    for ours, theirs in ((riccati.lqr, ct.lqr), (riccati.dlqr, ct.dlqr)):
        with pytest.raises((ValueError, np.linalg.LinAlgError)):
            ours(Au, Bu, Q, R)
        with pytest.raises((ValueError, np.linalg.LinAlgError)):
            theirs(Au, Bu, Q, R, method="scipy")


def test_example_plants_equal_python_control(plant):
    cols = torque_inputs(plant)
    sys = plant.sys[:, cols]
    d = design_lqr(plant, DT, 8.5)            # Bryson's default limits, as flexlink control designs
    _same((d.K, d.S, d.poles), ct.lqr(sys, d.Q, d.R, method="scipy"))
    sysd = ct.sample_system(sys, DT, method="zoh", name=plant.sys.name + "_d")
    _same((d.plant_d.A, d.plant_d.B, d.plant_d.C, d.plant_d.D), (sysd.A, sysd.B, sysd.C, sysd.D))
    _same((d.Kd, d.Sd, d.poles_d), ct.dlqr(sysd, d.Q, d.R, method="scipy"))
    # the sampled system's python-control form: python-control's own sampled system, with the continuous
    # plant's state names (python-control's sys[:, cols] renames a subsystem's states x[0], x[1], …)
    s = d.plant_d.sys
    _same((s.A, s.B, s.C, s.D), (sysd.A, sysd.B, sysd.C, sysd.D))
    assert (s.dt, s.name, s.input_labels, s.output_labels) == \
        (sysd.dt, sysd.name, sysd.input_labels, sysd.output_labels)
    assert s.state_labels == plant.sys.state_labels
    kf = design_kalman(plant, DT, "strain", torque_noise=0.3, elastic_noise=0.3)
    n = plant.nstates
    _same((kf.L, kf.P, kf.poles), ct.lqe(plant.sys.A, np.eye(n), kf.C, 0.5 * (kf.G @ kf.QN @ kf.G.T +
                                                                             (kf.G @ kf.QN @ kf.G.T).T), kf.RN,
                                        method="scipy"))
    Gd = ct.sample_system(ct.ss(plant.sys.A, kf.G, np.zeros((1, n)), 0), DT, method="zoh").B
    W = Gd @ kf.QN @ Gd.T
    sysd_all = ct.sample_system(plant.sys, DT, method="zoh")
    _same((kf.Ld, kf.Pd, kf.poles_d), ct.dlqe(sysd_all.A, np.eye(n), kf.C, 0.5 * (W + W.T), kf.RN, method="scipy"))


def test_frequency_response_equals_python_control(plant):
    """The PD design's ``G(s*)``: python-control evaluates ``sys[i, j](s)`` the same way (no Slycot here)."""
    i = plant.output_row(plant.outputs[0])
    for s in (3.0 + 4.0j, -2.0 + 0.5j, 100j):
        assert _frequency_response(plant, i, 0, s) == complex(np.squeeze(plant.sys[i, 0](s)))
