"""Modal reduction of finite-element links (issue 9): ``shapes.modes = N`` keeps the first N fixed-interface modes.

The checks are exact properties of a Ritz reduction on the eigenvectors (the reduced model has exactly the
full model's first N frequencies, joint held), the Ritz upper bound with the joint free, the analytic
clamped–free roots, and convergence of the response to the full FE model's as modes are added."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from flexlink.errors import SceneError
from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.mechanics.reference import simulate_reference
from flexlink.mechanics.shapes import make_basis
from flexlink.mechanics.shapes.reduction import ModalBeamBasis, fixed_interface_modes
from flexlink.scene.loader import parse_scene
from flexlink.tools.bench import BenchCase, relative_error

LAMBDA = np.array([1.87510407, 4.69409113, 7.85475744, 10.99554073])     # clamped–free roots


def test_massless_condensation_equals_the_singular_generalised_problem():
    """Degrees of freedom without mass: the condensed problem gives the finite eigenvalues of K x = ω² M x,
    found independently as the non-zero eigenvalues 1/ω² of K⁻¹M."""
    rng = np.random.default_rng(3)
    n, m = 12, 7
    A = rng.standard_normal((n, n))
    K = A @ A.T + n * np.eye(n)
    B = rng.standard_normal((m, m))
    M = np.zeros((n, n))
    massive = np.sort(rng.choice(n, m, replace=False))
    M[np.ix_(massive, massive)] = B @ B.T + np.eye(m)
    basis = fixed_interface_modes(K, M)
    mu = np.sort(np.real(np.linalg.eigvals(np.linalg.solve(K, M))))[::-1][:m]
    assert np.allclose(basis.omega2, 1 / mu, rtol=1e-10)
    # each mode satisfies K ψ = ω² M ψ on every row (massless rows included) and is M-orthonormal
    for w2, psi in zip(basis.omega2, basis.shapes.T, strict=True):
        assert np.linalg.norm(K @ psi - w2 * M @ psi) < 1e-9 * np.linalg.norm(K @ psi)
    assert np.allclose(basis.shapes.T @ M @ basis.shapes, np.eye(m), atol=1e-10)


def test_reduced_beam_keeps_the_first_frequencies_of_the_fe_beam_exactly():
    fe = make_basis("fe", 20, 1.0)
    full = scipy.linalg.eigh(fe.integrals.curv, fe.integrals.phi_phi, eigvals_only=True)
    for modes in (1, 3, 4):
        red = ModalBeamBasis(fe, modes)
        w2 = scipy.linalg.eigh(red.integrals.curv, red.integrals.phi_phi, eigvals_only=True)
        assert np.allclose(w2, full[:modes], rtol=1e-11)
        k = min(modes, 3)                  # the 20-element beam is converged to 1e-5 on the first three
        assert np.allclose(w2[:k] ** 0.25, LAMBDA[:k], rtol=1e-5)
        assert np.allclose(red.evaluate([1.0])[0], 1.0)                # η in metres of tip deflection (peak)


BASE = tomllib.loads(Path("examples/steel_beam_raise.toml").read_text())


def _raise_scene(count: int, modes: int | None, kinematics: str = "second-order"):
    data = json.loads(json.dumps(BASE))
    data["link"][0]["shapes"] = {"kind": "fe", "count": count} | ({"modes": modes} if modes else {})
    data["link"][0]["kinematics"] = kinematics
    return parse_scene(data)


def test_joint_free_reduced_frequencies_are_ritz_upper_bounds():
    data = tomllib.loads(Path("examples/rotating_link.toml").read_text())
    data["link"][0]["shapes"] = {"kind": "fe", "count": 16}
    full = natural_frequencies(build_model(parse_scene(data))).frequencies_hz
    previous = None
    for modes in (2, 4, 8):
        data["link"][0]["shapes"]["modes"] = modes
        red = natural_frequencies(build_model(parse_scene(data))).frequencies_hz
        assert all(r >= f * (1 - 1e-12) for r, f in zip(red, full, strict=False))
        if previous is not None:
            assert red[0] <= previous[0] * (1 + 1e-12) and red[1] <= previous[1] * (1 + 1e-12)
        previous = red
    assert red[0] == pytest.approx(full[0], rel=1e-6)


def test_reduced_raise_converges_to_the_full_fe_model():
    """Seed 001 §4.9 manoeuvre: the reduced model's tip deflection and joint torque approach the full
    10-element model's as modes are added."""
    times = np.round(np.arange(0, 1.2001, 2e-3), 12)

    def run(modes):
        model = build_model(_raise_scene(6, modes))
        res = simulate_reference(model, times, rtol=1e-8, atol=1e-11)
        return {n: res.output(model, n) for n in ("beam.tip.v", "base.tau")}, model

    truth, full_model = run(None)
    case = BenchCase(full_model, 0.5, times, [], ["beam.tip.v", "base.tau"])
    errors = [relative_error(case, run(m)[0], truth) for m in (1, 2, 4)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-2


def test_modes_only_for_finite_elements():
    data = json.loads(json.dumps(BASE))
    data["link"][0]["shapes"] = {"kind": "clamped-free", "count": 3, "modes": 2}
    with pytest.raises(SceneError, match=r"link\[1\]\.shapes\.modes"):
        parse_scene(data)
    data["link"][0]["shapes"] = {"kind": "fe", "count": 3, "modes": 7}
    with pytest.raises(SceneError, match="at most 6"):
        parse_scene(data)
