"""fmi2GetDirectionalDerivative (both interfaces) against central finite differences, and a plant and an
LQR designed from the FMU alone equal to those from the CasADi model."""

from __future__ import annotations

from pathlib import Path

import control as ct
import numpy as np
import pytest

from flexlink.run.linearize import fmu_state_space, linear_plant
from flexlink.tools.check.derivatives import check_directional_derivatives
from flexlink.tools.check.fmu import Fmu as _Fmu

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def fmus(example_fmu):
    return {n: example_fmu(n) for n in ["rotating_link", "flexible_pendulum", "steel_beam_raise"]}


@pytest.mark.parametrize("name", ["rotating_link", "flexible_pendulum", "steel_beam_raise"])
def test_directional_derivatives_match_central_differences(fmus, name):
    f = _Fmu(fmus[name])
    try:
        r = check_directional_derivatives(f)
    finally:
        f.close()
    assert r.status == "pass", r.details
    assert float(r.result.split()[3]) < 1e-6


@pytest.mark.parametrize("name", ["rotating_link", "rotating_link_linear", "rotating_link_payload"])
def test_lqr_from_the_fmu_alone_equals_lqr_from_the_model(example_fmu, name):
    fmu = example_fmu(name)
    outputs = ["hub.theta", "arm.tip.v", "arm.root.moment", "tip.sy"]
    plant = linear_plant(EXAMPLES / f"{name}.toml", outputs=outputs).sys
    sys = fmu_state_space(fmu, outputs=outputs)
    assert list(sys.state_labels) == list(plant.state_labels)
    assert list(sys.input_labels) == list(plant.input_labels) == ["hub_tau"]
    assert list(sys.output_labels) == list(plant.output_labels)
    for a, b in [(sys.A, plant.A), (sys.B, plant.B), (sys.C, plant.C), (sys.D, plant.D)]:
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(b).max()))
    n = sys.nstates
    Q = np.diag([1 / 0.01**2] + [1.0] * (n - 1))
    R = np.array([[1 / 2.0**2]])
    K_fmu, _, E_fmu = ct.lqr(sys, Q, R)
    K_model, _, E_model = ct.lqr(plant, Q, R)
    np.testing.assert_allclose(K_fmu, K_model, rtol=1e-7)
    np.testing.assert_allclose(np.sort_complex(E_fmu), np.sort_complex(E_model), rtol=1e-7)


@pytest.mark.parametrize("where, error", [("largest", 1e-3), ("median", 1e-4)])
def test_a_wrong_directional_derivative_is_caught(fmus, monkeypatch, where, error):
    """One entry of the FMU's answer off by 1e-3 (the largest) or 1e-4 (a mid-sized entry) of its row's largest
    entry, 100 and 10 times the check's tolerance: central differences converge to the right value at some
    step, so the check fails on that entry and only there."""
    import flexlink.tools.check.derivatives as check

    honest = check.directional_jacobian
    spoiled = []

    def off_by_a_little(inst, unknown, known):
        J = honest(inst, unknown, known)
        if not spoiled:                               # the first Jacobian asked for: ME, states and inputs
            nonzero = np.flatnonzero(np.abs(J) > 1e-6 * np.abs(J).max())
            order = nonzero[np.argsort(np.abs(J.flat[nonzero]))]
            flat = order[-1] if where == "largest" else order[len(order) // 2]
            i, j = np.unravel_index(flat, J.shape)
            J[i, j] += error * np.abs(J[i]).max()
            spoiled.append((int(i), int(j)))
        return J

    monkeypatch.setattr(check, "directional_jacobian", off_by_a_little)
    f = _Fmu(fmus["rotating_link"])
    try:
        r = check_directional_derivatives(f)
    finally:
        f.close()
    assert r.status == "fail"
    problems = [d for d in r.details if "relative error" in d]
    (i, j), = spoiled
    assert len(problems) == 1 and f"column {j}, row {i}:" in problems[0], problems
