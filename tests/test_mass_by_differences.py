"""The mass matrix from differences of the residual (flexlink.export.codegen.mass_by_differences).

Where "auto" would generate M(q) as a large matrix graph (a reduced FE link of 12 modes and more,
second-order kinematics), the FMU takes it from N_Q + 1 residuals:
r is affine in the accelerations, so M e_j = (r(q, 0, s e_j) − r(q, 0, 0)) / s; and the Newton matrix's
columns carry their M part in the residuals of their differences in q and v.  The references are independent
of that C: CasADi's symbolic M = ∂r/∂a of the same model (``SymbolicModel.mass_matrix_function``) and its
Jacobians ∂r/∂v, ∂r/∂q, evaluated in Python.  The FMU's own matrices are read through ``model_newton_matrix``
by tests/c/mass_probe.c, compiled with the FMU's sources.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from source_probe import compile_probe

from flexlink.export.cache import cached_fmu
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene

PROBE = Path(__file__).resolve().parent / "c" / "mass_probe.c"
MODES = 12


def _link_scene() -> dict:
    joint = dict(name="hub", axis=[0.0, 0.0, 1.0], inertia=1e-2)
    link = dict(name="arm", length=1.0, linear_density=2.0, EI=100.0, deformation=["v"],
                shapes=dict(kind="fe", count=16, modes=MODES), kinematics="second-order")
    return dict(name="mass_differences", gravity=[0.0, 0.0, -9.81], joint=[joint], link=[link],
                fmu=dict(step=1e-4, newton_matrix="auto"))


def _build_probe(scene_data: dict, work: Path):
    """(model, FMU sources, the compiled probe) of a scene, built under "auto"."""
    scene = parse_scene(scene_data)
    model = build_model(scene)
    src, exe = compile_probe(cached_fmu(scene, model=model), PROBE, work)
    return model, src, exe


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    """The 12-mode link under "auto": its generated M would be a large matrix graph."""
    return _build_probe(_link_scene(), tmp_path_factory.mktemp("mass_probe"))


def _probe(exe: Path, c: tuple[float, float, float], *values: np.ndarray) -> np.ndarray:
    """The FMU's c[0] M + c[1] ∂r/∂v + c[2] ∂r/∂q at (q, v, a, u, p)."""
    stdin = "\n".join(f"{x:.17g}" for x in (*c, *np.concatenate(values)))
    out = subprocess.run([str(exe)], input=stdin, capture_output=True, text=True, check=True).stdout
    n = values[0].size
    return np.array([float(x) for x in out.split()]).reshape(n, n).T      # column-major


def _probe_M(exe: Path, q: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    zero = np.zeros_like(q)
    return _probe(exe, (1.0, 0.0, 0.0), q, zero, zero, u, p)


def _inputs(model) -> np.ndarray:
    return np.full(len(model.inputs), 0.5)


def test_auto_takes_the_mass_matrix_from_the_residual_at_this_size(probe):
    """No generated mass-matrix unit: model.c forms M from residuals."""
    _, src, _ = probe
    assert not list(src.glob("*_mass_matrix.c"))
    assert "mass_matrix_differences.c.in" in (src / "model.c").read_text()


def test_the_differenced_mass_matrix_is_casadis_to_rounding(probe):
    """At rest and at three random deflections (each modal coordinate up to its nominal scale): the FMU's M
    equals CasADi's ∂r/∂a to 64 ε of M's largest entry, and is symmetric."""
    model, _, exe = probe
    rng = np.random.default_rng(15)
    nominal = np.asarray(model.nominal_q)
    p = np.asarray(model.p0, float)
    u = _inputs(model)
    for k in range(4):
        q = np.zeros(model.n_q) if k == 0 else rng.uniform(-1.0, 1.0, model.n_q) * nominal
        M = _probe_M(exe, q, u, p)
        reference = np.array(model.mass_matrix_function()(q, u, p))
        scale = np.max(np.abs(reference))
        error = np.max(np.abs(M - reference)) / scale
        assert error <= 64 * np.finfo(float).eps, (k, error)        # measured: up to 6.2 ε
        assert np.array_equal(M, M.T)


@pytest.mark.parametrize("weights", ["ss22", "stiffness", "double_mass", "no_stiffness"])
def test_the_newton_matrix_carries_its_mass_matrix_in_its_columns(probe, weights):
    """SS22's Newton matrix M + cv ∂r/∂v + cq ∂r/∂q (Θ = ½ at the scene's step) at rest and at three random
    states: its M part from the same residuals as its differences in q and v.  Against CasADi's exact
    Jacobians, within 1e-6 of the matrix's largest entry.  Also with other weights (ca, cv, cq): K alone
    (0, 0, 1: Richardson's stability check and the static equilibrium ask for it), 2 M, and no K, so that the
    M part follows ca and not the difference's step.  Why that size: a column moves q_j by √ε of its
    scale (and a_j by the matching multiple), so a forward difference leaves about √ε = 1.5e-8 of the
    residual's curvature -- the position part's own, and M's change with q_j (∂M/∂q_j, the cross term the M
    part now carries); the rest is that curvature's size."""
    model, _, exe = probe
    import casadi as ca

    rng = np.random.default_rng(22)
    dt = model.scene.fmu.solver.step
    ca_, cv, cq = {"ss22": (1.0, 0.5 * dt, 0.25 * dt * dt), "stiffness": (0.0, 0.0, 1.0),
                   "double_mass": (2.0, 0.5 * dt, 0.25 * dt * dt), "no_stiffness": (1.0, 0.5 * dt, 0.0)}[weights]
    nominal = np.asarray(model.nominal_q)
    p = np.asarray(model.p0, float)
    u = _inputs(model)
    q_, v_, a_ = (ca.MX.sym(n, model.n_q) for n in "qva")
    r = model.residual(q_, v_, a_, u, p)
    jacobians = ca.Function("jacobians", [q_, v_, a_], [ca.jacobian(r, a_), ca.jacobian(r, v_), ca.jacobian(r, q_)])
    for k in range(4):
        q, v, a = (rng.uniform(-1.0, 1.0, model.n_q) * nominal * s * (k > 0) for s in (1.0, 10.0, 100.0))
        M, C, K = (np.array(x) for x in jacobians(q, v, a))
        J = _probe(exe, (ca_, cv, cq), q, v, a, u, p)
        reference = ca_ * M + cv * C + cq * K
        relative = np.max(np.abs(J - reference)) / np.max(np.abs(reference))
        assert relative <= 1e-6, (k, relative)      # measured: up to 2.1e-7 (no K), 4e-8 (SS22)


def test_the_complex_step_carries_the_modal_maps(probe):
    """The residual under gravity takes its Lagrange derivative in reverse mode through the maps, so its
    scalar code calls their adjoints too (products by the transpose, linear): the directional derivatives
    are still the complex step on it, with no generated forward functions (they were 1.4 MB of C here when
    the adjoints turned the complex step off: the independent review of 2026-11-27)."""
    model, src, _ = probe
    from flexlink.export.codegen import _casadi_functions

    plan = _casadi_functions(model, "probe", True)
    called = set(plan.residual.function.get_function())
    assert any(name.startswith("adj") for name in called) and any(n.startswith("dense_map_") for n in called)
    assert plan.complex_step
    assert list(src.glob("*_complex.c")) and not list(src.glob("*_forward.c"))
