"""The mass matrix's Gram form of the foreshortening rates (issue 15) is the Hessian of the same energy.

With second-order kinematics on the point sums, the mass matrix takes the share Σ w u̇² of the relative
kinetic energy as 2 Aᵀ W A (A = ∂u̇/∂η̇, :class:`flexlink.mechanics.kinematics.RateGram`) instead of
CasADi's Hessian of the sums.  Independent references: CasADi's ∂²T/∂q̇² of the whole kinetic energy, the
residual's own derivative ∂r/∂a (automatic differentiation through the Lagrange equations), and CasADi's
Jacobian of the points' u̇ — each at random states, to 1e-12 of the matrix's scale.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from flexlink.mechanics.assembly import ChainAssembly
from flexlink.mechanics.kinematics import _foreshortening_points, use_tensors
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene


def _scene() -> dict:
    """A spatial two-link chain on the point sums: 8 clamped-free shapes bending both ways and twisting, then
    a finite-element link of 8 modes; the second joint position-driven (its coordinate is not free)."""
    joints = [dict(name="j1", axis=[0.0, 0.0, 1.0], inertia=0.05),
              dict(name="j2", axis=[0.0, 1.0, 0.0], inertia=0.01, drive="position")]
    links = [dict(name="l1", length=0.8, linear_density=1.2, EI=300.0, EI_out=200.0, GJ=80.0, polar_inertia=1e-4,
                  deformation=["v", "w", "alpha"], shapes=dict(kind="clamped-free", count=8),
                  kinematics="second-order"),
             dict(name="l2", length=0.6, linear_density=0.9, EI=150.0, deformation=["v"],
                  shapes=dict(kind="fe", count=10, modes=8), kinematics="second-order",
                  payload=dict(mass=0.4, inertia=0.002))]
    return dict(name="gram_chain", gravity=[0.0, -9.81, 0.0], joint=joints, link=links)


@pytest.fixture(scope="module")
def chain() -> ChainAssembly:
    c = ChainAssembly(parse_scene(_scene()))
    c.assemble_kinematics()
    return c


def _states(chain: ChainAssembly, count: int):
    """Random (qa, va, p): angles over the circle, deflections of a few percent of the links, large rates."""
    rng = np.random.default_rng(15)
    kinds = np.array(chain.kinds)
    p = np.array([item.value for item in chain.P.items])
    for _ in range(count):
        elastic = rng.normal(scale=0.02, size=kinds.size)
        qa = np.where(kinds == "elastic", elastic, rng.uniform(-np.pi, np.pi, kinds.size))
        yield qa, rng.normal(scale=3.0, size=kinds.size), p


def test_both_links_take_the_gram_form(chain):
    """Both links are past the tensors' threshold, so both carry a RateGram (v and w stacked on the first)."""
    assert [gram.rates for _, gram, _ in chain.rate_grams] == [("v", "w"), ("v",)]
    assert not any(use_tensors(part.bending.points, 1) for part in chain.parts)


def test_mass_matrix_equals_the_hessian_of_T(chain):
    """M (Hessian of T less Σ w u̇², plus ρ Aᵀ W A) = CasADi's ∂²T/∂q̇² of the whole T, at random states."""
    reference = ca.Function("H", [chain.qa, chain.va, chain.p], [ca.hessian(chain.T, chain.va)[0]])
    gram = ca.Function("M", [chain.qa, chain.p], [chain.mass_matrix_all()])
    for qa, va, p in _states(chain, 6):
        expected = np.array(reference(qa, va, p))
        got = np.array(gram(qa, p))
        assert np.max(np.abs(got - expected)) <= 1e-12 * np.max(np.abs(expected))
        assert np.max(np.abs(got - got.T)) <= 1e-13 * np.max(np.abs(expected))


def test_rate_jacobian_is_the_derivative_of_the_points_rates(chain):
    """A = ∂u̇/∂η̇ equals CasADi's Jacobian of the points' u̇ (the rule's integral of v'v̇' + w'ẇ')."""
    part = chain.parts[0]
    d = chain.deformation(part, chain.qa, chain.va)
    fields = _foreshortening_points(part.bending.points, d)
    _, gram, rates = chain.rate_grams[0]
    reference = ca.Function("J", [chain.qa, chain.va], [ca.jacobian(fields.u_dot, chain.va)[:, rates]])
    ours = ca.Function("A", [chain.qa], [gram.jacobian])
    for qa, va, _ in _states(chain, 4):
        expected = np.array(reference(qa, va))
        assert np.max(np.abs(np.array(ours(qa)) - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_free_mass_matrix_is_the_residuals_derivative_in_the_accelerations():
    """The generated mass matrix equals ∂r/∂a of the residual (AD through Lagrange's equations), free rows only."""
    model = build_model(parse_scene(_scene()))
    q, v, a, u, p = (ca.MX.sym(n, *model.residual.size_in(i)) for i, n in enumerate("qvaup"))
    dr_da = ca.Function("J", [q, v, a, u, p], [ca.jacobian(model.residual(q, v, a, u, p), a)])
    rng = np.random.default_rng(22)
    kinds = np.array(model.coordinate_kinds)
    for _ in range(4):
        qs = np.where(kinds == "elastic", rng.normal(scale=0.02, size=kinds.size), rng.uniform(-3, 3, kinds.size))
        vs, acc, us = rng.normal(size=model.n_q), rng.normal(size=model.n_q), rng.normal(size=len(model.inputs))
        expected = np.array(dr_da(qs, vs, acc, us, model.p0))
        got = np.array(model.mass_matrix_function()(qs, us, model.p0))
        assert np.max(np.abs(got - expected)) <= 1e-12 * np.max(np.abs(expected))
