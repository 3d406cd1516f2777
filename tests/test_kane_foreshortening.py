"""The foreshortening's equations in Kane's form are the consistent second-order Lagrangian's (issue 15).

A second-order link on the point sums takes the share of its equations that the foreshortening u brings from
:func:`flexlink.mechanics.kinematics.foreshortening_forces` (Kane's sums at the points, the frame's momenta and
their rates formed by hand) instead of CasADi's Lagrange derivative d/dt ∂T/∂q̇ − ∂T/∂q through the point sums.
The reference is that derivative itself: the same builder with ``KANE_FORESHORTENING = False`` differentiates
the whole kinetic energy by automatic differentiation.  Both residuals are compared at random states, rates,
accelerations, inputs and parameters, to round-off (1e-13 of the residual's scale): on the 32-mode link of
issue 15, on 2- and 3-shape links forced onto the points, planar and spatial, and on a spatial chain whose
second link sits on the first one's second-order tip frame (orthogonal only to second order), with gravity,
torsion, a payload and a position-driven joint.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from conftest import EXAMPLES

from flexlink.mechanics import assembly, kinematics
from flexlink.mechanics.assembly import ChainAssembly
from flexlink.mechanics.outputs import chain_outputs
from flexlink.scene.loader import load_scene, parse_scene


def _link(count: int | None = None, *, kind: str = "fe", modes: int | None = None,
          deformation: tuple[str, ...] = ("v",)) -> dict:
    shapes = dict(kind=kind, count=count) if modes is None else dict(kind=kind, count=count, modes=modes)
    return dict(name="arm", length=1.0, linear_density=2.0, EI=100.0, EI_out=60.0, GJ=40.0, polar_inertia=1e-4,
                deformation=list(deformation), shapes=shapes, kinematics="second-order")


def _one_link(link: dict, gravity=(0.0, 0.0, 0.0), axis=(0.0, 0.0, 1.0)) -> dict:
    return dict(name="kane_link", gravity=list(gravity), joint=[dict(name="hub", axis=list(axis), inertia=1e-2)],
                link=[link])


def _chain() -> dict:
    """Two spatial links: 8 clamped-free shapes bending both ways and twisting (a rule without nodal values:
    ∫u and ∫xu in their modal forms), then 8 modes of 10 Hermite elements with a payload, position-driven."""
    joints = [dict(name="j1", axis=[0.0, 0.0, 1.0], inertia=0.05),
              dict(name="j2", axis=[0.0, 1.0, 0.0], inertia=0.01, drive="position", origin=[0.02, 0.0, 0.01])]
    first = dict(_link(8, kind="clamped-free", deformation=("v", "w", "alpha")), name="l1", length=0.8)
    second = dict(_link(10, modes=8), name="l2", length=0.6, payload=dict(mass=0.4, inertia=0.002))
    return dict(name="kane_chain", gravity=[0.0, -9.81, 1.5], joint=joints, link=[first, second])


def _built(scene: dict, kane: bool, monkeypatch) -> ChainAssembly:
    monkeypatch.setattr(assembly, "KANE_FORESHORTENING", kane)
    chain = ChainAssembly(parse_scene(scene))
    chain.assemble_kinematics()
    chain.add_potential_and_dissipation()
    chain.add_equations()
    return chain


def _random_points(chain: ChainAssembly, count: int = 6):
    """(q, q̇, q̈, u, p): angles over the circle, deflections of a few percent, large rates and accelerations."""
    rng = np.random.default_rng(22)
    kinds = np.array(chain.kinds)
    nominal = np.array([item.value for item in chain.P.items])
    for _ in range(count):
        q = np.where(kinds == "elastic", rng.normal(scale=0.03, size=kinds.size), rng.uniform(-3, 3, kinds.size))
        yield (q, rng.normal(scale=3.0, size=kinds.size), rng.normal(scale=30.0, size=kinds.size),
               rng.normal(size=chain.u.numel()), nominal * rng.uniform(0.5, 2.0, nominal.size))


def _largest_difference(scene: dict, monkeypatch, kane_links: int) -> float:
    """max |r_Kane − r_Lagrange| / max |r_Lagrange| over random states of the whole residual r_all."""
    kane, lagrange = _built(scene, True, monkeypatch), _built(scene, False, monkeypatch)
    assert len(kane.kane_links) == kane_links and not lagrange.kane_links
    rng = np.random.default_rng(22)
    kinds = np.array(kane.kinds)
    nominal = np.array([item.value for item in kane.P.items])
    worst = 0.0
    for _ in range(6):
        q = np.where(kinds == "elastic", rng.normal(scale=0.03, size=kinds.size), rng.uniform(-3, 3, kinds.size))
        v, a = rng.normal(scale=3.0, size=kinds.size), rng.normal(scale=30.0, size=kinds.size)
        u = rng.normal(size=kane.u.numel())
        p = nominal * rng.uniform(0.5, 2.0, nominal.size)
        r_kane = np.array(kane.r_all(q, v, a, u, p)).ravel()
        r_lagrange = np.array(lagrange.r_all(q, v, a, u, p)).ravel()
        worst = max(worst, float(np.max(np.abs(r_kane - r_lagrange)) / np.max(np.abs(r_lagrange))))
    return worst


@pytest.mark.parametrize("scene", [
    pytest.param(_one_link(_link(16, modes=32)), id="32-modes"),
    pytest.param(_one_link(_link(16, modes=8), gravity=(0.0, -9.81, 0.0)), id="8-modes-gravity"),
])
def test_many_mode_links_take_kane_and_match_lagrange(scene, monkeypatch):
    assert _largest_difference(scene, monkeypatch, 1) < 1e-13


@pytest.mark.parametrize("scene", [
    pytest.param(_one_link(_link(4, modes=3)), id="3-modes-planar"),
    pytest.param(_one_link(_link(2, kind="clamped-free", deformation=("v", "w")), gravity=(0.0, -9.81, 2.0),
                           axis=(0.0, 1.0, 1.0)), id="2-shapes-spatial"),
    pytest.param(_one_link(_link(3, kind="polynomial", deformation=("v", "w", "alpha"))), id="3-shapes-twist"),
])
def test_few_shape_links_on_the_points_match_lagrange(scene, monkeypatch):
    """Below the tensors' threshold the points are forced (TENSOR_MAX_SHAPES = 0), so Kane's form applies."""
    monkeypatch.setattr(kinematics, "TENSOR_MAX_SHAPES", 0)
    assert _largest_difference(scene, monkeypatch, 1) < 1e-13


def test_a_chain_on_a_second_order_tip_frame_matches_lagrange(monkeypatch):
    """The second link's frame is the first's tip, R·(I + [ψ×] + ½[ψ×]²): its velocities are not a rigid
    motion's, which the frame's share (momenta, their rates and the transport term) must still reproduce."""
    assert _largest_difference(_chain(), monkeypatch, 2) < 1e-13


def test_a_linear_link_keeps_the_lagrange_derivative(monkeypatch):
    """A chain with a linear link evaluates T at its η = 0: Kane's sums are not that energy's, so no link of
    it takes them (and the residual is CasADi's derivative, as before)."""
    scene = _chain()
    scene["link"][0]["kinematics"] = "linear"
    chain = _built(scene, True, monkeypatch)
    assert chain.kane_links == []


def test_kane_form_takes_fewer_operations(monkeypatch):
    """The point of the form: the 32-mode link's residual in fewer scalar operations than through AD."""
    def operations(kane: bool) -> int:
        f = _built(_one_link(_link(16, modes=32)), kane, monkeypatch).residual.expand()
        args = f.sx_in()
        return int(ca.Function("r", args, f.call(args), {"cse": True}).n_instructions())

    assert operations(True) < 0.75 * operations(False)



@pytest.mark.parametrize("scene", [pytest.param(_one_link(_link(16, modes=32)), id="32-modes"),
                                   pytest.param(_chain(), id="spatial-chain")])
def test_outputs_match_the_lagrange_builders(scene, monkeypatch):
    """Reactions (the foreshortening's momenta differentiated by hand) and the kinetic energy (T_rest plus the
    Kane links' share) equal the outputs of the builder that differentiates the whole momenta by AD."""
    def outputs(kane: bool):
        chain = _built(scene, kane, monkeypatch)
        signals, expressions = chain_outputs(chain)
        return chain, signals, ca.Function("y", [chain.qa, chain.va, chain.aa, chain.u, chain.p],
                                           [ca.vertcat(*expressions)])

    kane, signals, y_kane = outputs(True)
    _, _, y_lagrange = outputs(False)
    names = [s.name for s in signals]
    assert any(".reaction.m" in name for name in names) and "energy.kinetic" in names
    for point in _random_points(kane):
        a, b = np.array(y_kane(*point)).ravel(), np.array(y_lagrange(*point)).ravel()
        scale = np.maximum(np.abs(b), 1e-3 * np.max(np.abs(b)))      # each output against its own size
        assert np.max(np.abs(a - b) / scale) < 1e-11, names[int(np.argmax(np.abs(a - b) / scale))]


@pytest.mark.parametrize("example", ["fast_two_link", "spatial_cantilever", "elastic_joint"])
def test_example_residuals_match_lagrange(example, monkeypatch):
    """Examples whose links take Kane's form (reduced or plain finite elements past the tensors): two flexible
    links in a row, a spatial cantilever, an elastic joint before the link."""
    scene = load_scene(EXAMPLES / f"{example}.toml")
    chains = [_built_scene(scene, kane, monkeypatch) for kane in (True, False)]
    assert chains[0].kane_links and not chains[1].kane_links
    for point in _random_points(chains[0], 4):
        r_kane, r_lagrange = (np.array(c.r_all(*point)).ravel() for c in chains)
        assert np.max(np.abs(r_kane - r_lagrange)) < 1e-13 * np.max(np.abs(r_lagrange))


def _built_scene(scene, kane: bool, monkeypatch) -> ChainAssembly:
    monkeypatch.setattr(assembly, "KANE_FORESHORTENING", kane)
    chain = ChainAssembly(scene)
    chain.assemble_kinematics()
    chain.add_potential_and_dissipation()
    chain.add_equations()
    return chain
