"""Dynamics of the single-link model (issue "Single flexible link", items 6 and 7): energy conservation of the
undamped free motion of every kinematic model (CVODES reference simulation, tight tolerances: all three are
Lagrangian, the second-order one included since issue 14), Kelvin–Voigt modal decay exp(−κω²t), and the
linear model's M, B, K built by hand from seed 000 eqs. (3.27)-(3.31) against ``linearise`` (CasADi AD).
Run with ``pytest -s`` for the drift figures.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import SEED000_LINK, clamped_free_lambdas, make_link_scene

from flexlink.mechanics.analysis import linearise, natural_frequencies, operating_point
from flexlink.mechanics.model import build_model
from flexlink.mechanics.reference import simulate_reference
from flexlink.mechanics.shapes import make_basis

L, RHO, EI = SEED000_LINK["length"], SEED000_LINK["linear_density"], SEED000_LINK["EI"]
GRAVITY = (0.0, -9.81, 0.0)
PAYLOAD = {"mass": 0.5, "inertia": 1e-3}


def _initial_state(model, scene, tip_deflection: float):
    """Start state with a smooth initial deflection of the given tip value: the first eigenfunction (η1),
    or for FE the parabola v = a (x/L)² at the nodes (w_k, θ_k) = (a x_k²/L², 2a x_k/L²), exact in the mesh."""
    link = scene.links[0]
    basis = make_basis(link.shapes.kind, link.shapes.count, link.length, link.linear_density)
    q0, v0 = model.start_state()
    first = model.n_q - basis.n
    if link.shapes.kind == "fe":
        x = np.linspace(0.0, link.length, link.shapes.count + 1)[1:]
        q0[first::2] = tip_deflection * (x / link.length) ** 2
        q0[first + 1::2] = 2 * tip_deflection * x / link.length**2
    else:
        q0[first] = tip_deflection / basis.integrals.tip[0]
    return q0, v0


def _energy(model, res):
    return res.output(model, "energy.kinetic") + res.output(model, "energy.potential")


def _run(scene, tip_deflection, stop, samples=101, rtol=1e-11, atol=1e-13):
    model = build_model(scene)
    q0, v0 = _initial_state(model, scene, tip_deflection)
    res = simulate_reference(model, np.linspace(0.0, stop, samples), q0=q0, v0=v0, rtol=rtol, atol=atol)
    return model, res


# ---------------------------------------------------------------------------------------------------------
# 6. Energy
# ---------------------------------------------------------------------------------------------------------

CONSERVATIVE = [
    ("linear", "clamped-free", 3, (0.0, 0.0, 0.0), None),
    ("linear", "clamped-free", 3, GRAVITY, PAYLOAD),
    ("first-order", "clamped-free", 3, (0.0, 0.0, 0.0), None),
    ("first-order", "clamped-free", 3, (0.0, 0.0, 0.0), PAYLOAD),
    ("first-order", "clamped-free", 3, GRAVITY, None),
    ("first-order", "fe", 2, GRAVITY, PAYLOAD),     # (CVODES cost grows fast with the FE count's top frequency)
    ("second-order", "clamped-free", 3, (0.0, 0.0, 0.0), None),
    ("second-order", "clamped-free", 3, GRAVITY, PAYLOAD),
    ("second-order", "fe", 2, GRAVITY, PAYLOAD),
]


@pytest.mark.parametrize("kinematics, kind, count, gravity, payload", CONSERVATIVE)
def test_energy_is_conserved(kinematics, kind, count, gravity, payload):
    """Free hub (torque 0) with an initial rate of 2 rad/s and a 5 cm initial tip deflection, ~6 periods of
    the first flexible mode; with gravity the link also swings as a pendulum. Every model is Lagrangian
    (the equations come from T − V with nothing truncated afterwards; second-order: each body's energy is kept
    to second order in its own elastic coordinates), so T + V is an invariant up to the integrator's error.
    (Before issue 14 the second-order *equations* were truncated to first order in η and T + V drifted by
    O(a²) relative to E.)"""
    scene = make_link_scene(kind, count, kinematics, drive="torque", hub_inertia=0.1, rate=2.0, gravity=gravity,
                            payload=payload)
    model, res = _run(scene, 0.05, 1.0, rtol=1e-10, atol=1e-12)
    energy = _energy(model, res)
    drift = np.max(np.abs(energy - energy[0])) / np.max(res.output(model, "energy.kinetic"))
    assert np.ptp(res.output(model, "hub.theta")) > 0.3           # the hub did move
    print(f"\n{kinematics} {kind} x{count} gravity={gravity[1] != 0} payload={payload is not None}: "
          f"max|E − E0|/max T = {drift:.2e}")
    assert drift < 1e-7, drift


def test_kelvin_voigt_modal_decay():
    """Hub held, eigenfunction basis, first mode only: η̈ + κω₁²η̇ + ω₁²η = 0 (ζ = κω₁/2). Over one damped
    period T_d = 2π/(ω₁√(1 − ζ²)) the state (η, η̇) is multiplied by exp(−ζω₁T_d), the energy exactly by
    exp(−κω₁²T_d). First-order kinematics: with the hub held its equations are exactly this linear modal
    equation; the second-order model's kinetic energy of the foreshortening (ρ∫u̇², fourth order in η)
    shifts the decay by 5e-5 at this 5 cm amplitude (1.5e-8 at 1 mm, ∝ amplitude²)."""
    w1 = clamped_free_lambdas(1)[0] ** 2 * math.sqrt(EI / (RHO * L**4))
    zeta = 0.02
    kappa = 2 * zeta / w1
    scene = make_link_scene("clamped-free", 3, "first-order", kelvin_voigt=kappa)
    model = build_model(scene)
    q0, v0 = _initial_state(model, scene, 0.05)
    period = 2 * math.pi / (w1 * math.sqrt(1 - zeta**2))
    times = period * np.arange(6)
    res = simulate_reference(model, times, q0=q0, v0=v0, rtol=1e-13, atol=1e-15)   # 1e-11: 3e-8 after 5 T_d
    energy = _energy(model, res)
    expected = energy[0] * np.exp(-kappa * w1**2 * times)
    print(f"\nKelvin-Voigt κ = {kappa:.4g} s (ζ1 = {zeta}): E(k T_d)/E(0) = {energy / energy[0]}")
    np.testing.assert_allclose(energy, expected, rtol=1e-8)
    assert np.max(np.abs(res.q[:, 1:])) < 1e-12                     # the other modes stay at rest


# ---------------------------------------------------------------------------------------------------------
# 7. Linear model: M, B, K by hand (seed 000 eqs. 3.27-3.31) against linearise (CasADi AD)
# ---------------------------------------------------------------------------------------------------------


def _hand_matrices(kind, count, hub_inertia, hub_damping, kappa, payload):
    """Seed 000 (3.28)-(3.30), plus the tip payload: a point mass m at (L, v(L)) and a rotary inertia J
    turning with θ + v'(L); with the kinetic energy taken at η = 0 (linear model), they add
    m [L, φ(L)ᵀ]ᵀ[L, φ(L)ᵀ] + J [1, φ'(L)ᵀ]ᵀ[1, φ'(L)ᵀ] to M."""
    g = make_basis(kind, count, L, RHO).integrals
    n = len(g.phi)
    M = np.zeros((n + 1, n + 1))
    M[0, 0] = hub_inertia + RHO * L**3 / 3
    M[0, 1:] = M[1:, 0] = RHO * g.x_phi
    M[1:, 1:] = RHO * g.phi_phi
    if payload:
        a = np.concatenate([[L], g.tip])
        b = np.concatenate([[1.0], g.tip_slope])
        M += payload["mass"] * np.outer(a, a) + payload["inertia"] * np.outer(b, b)
    B = np.zeros((n + 1, n + 1))
    B[0, 0] = hub_damping
    B[1:, 1:] = kappa * EI * g.curv
    K = np.zeros((n + 1, n + 1))
    K[1:, 1:] = EI * g.curv
    return M, B, K


@pytest.mark.parametrize("kind, count", [("clamped-free", 3), ("fe", 3), ("polynomial", 3)])
@pytest.mark.parametrize("payload", [None, PAYLOAD])
def test_linear_model_matrices_by_hand(kind, count, payload):
    hub_inertia, hub_damping, kappa = 0.1, 0.05, 2e-3
    scene = make_link_scene(kind, count, "linear", drive="torque", hub_inertia=hub_inertia, hub_damping=hub_damping,
                            kelvin_voigt=kappa, payload=payload)
    model = build_model(scene)
    assert model.linear_in_state and model.jacobian_constant
    M, B, K = _hand_matrices(kind, count, hub_inertia, hub_damping, kappa, payload)
    for rate in (0.0, 3.0):                                     # the linear model does not depend on the rate
        lin = linearise(model, operating_point(model, rate))
        scale = np.max(np.abs(M))
        np.testing.assert_allclose(lin.M, M, rtol=1e-12, atol=1e-14 * scale)
        np.testing.assert_allclose(lin.C, B, rtol=1e-12, atol=1e-14 * np.max(np.abs(B)))
        np.testing.assert_allclose(lin.K, K, rtol=1e-12, atol=1e-14 * np.max(np.abs(K)))
        np.testing.assert_allclose(lin.B, np.eye(model.n_q)[:, :1], atol=1e-15)    # f = [T, 0]ᵀ (3.31)
    modes = natural_frequencies(model, 0.0)
    w2 = np.sort(np.real(np.linalg.eigvals(np.linalg.solve(M, K))))
    np.testing.assert_allclose(2 * np.pi * np.array(modes.frequencies_hz), np.sqrt(w2[1:]), rtol=1e-10)
