"""The mass matrix by composite inertia (flexlink.mechanics.composite) is CasADi's Hessian of the whole T.

Reference: ∂²T/∂q̇² of the chain's kinetic energy as one expression (CasADi's automatic differentiation
through every body's kinematics), at random states, on every example and on a chain that mixes what the
recursion has to carry across a cut: joint placements, an elastic joint, a position-driven joint, a rigid
body and a massless connector, a linear link (T at η = 0), a second-order link twisting and bending both
ways, a payload and a tool frame.
"""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from flexlink.mechanics.assembly import ChainAssembly
from flexlink.mechanics.composite import body_forms
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene, parse_scene

EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples").glob("*.toml"))


def _mixed() -> dict:
    joints = [dict(name="base", axis=[0.0, 0.0, 1.0], inertia=0.05),
              dict(name="shoulder", axis=[0.0, 1.0, 0.0], inertia=0.02, stiffness=800.0,
                   origin=[0.0, 0.0, 0.3]),
              dict(name="elbow", axis=[0.0, 1.0, 0.0], inertia=0.01, drive="position", rpy=[0.1, 0.0, 0.2]),
              dict(name="wrist", axis=[1.0, 0.0, 0.0], inertia=0.001),
              dict(name="flange", axis=[0.0, 0.0, 1.0], inertia=0.001, origin=[0.05, 0.0, 0.0])]
    links = [dict(name="column", deformation=[], mass=3.0, center_of_mass=[0.0, 0.0, 0.15],
                  inertia=[0.02, 0.02, 0.01, 0.0, 0.001, 0.0], length=0.3),
             dict(name="upper", length=0.6, linear_density=1.2, EI=300.0, EI_out=200.0, GJ=80.0,
                  polar_inertia=1e-4, deformation=["v", "w", "alpha"], shapes=dict(kind="clamped-free", count=2),
                  kinematics="second-order"),
             dict(name="fore", length=0.5, linear_density=0.9, EI=150.0, deformation=["v"],
                  shapes=dict(kind="clamped-free", count=2), kinematics="linear"),
             dict(name="spacer", deformation=[], length=0.0, mass=0.0),
             dict(name="hand", length=0.2, linear_density=0.5, EI=50.0, EI_out=40.0, deformation=["v", "w"],
                  shapes=dict(kind="clamped-free", count=2), kinematics="second-order",
                  payload=dict(mass=0.4, inertia=0.002))]
    return dict(name="mixed", gravity=[0.0, 0.0, -9.81], joint=joints, link=links,
                tool=dict(origin=[0.05, 0.0, 0.0], rpy=[0.0, 0.3, 0.0]))


def _chain(scene) -> ChainAssembly:
    chain = ChainAssembly(scene)
    chain.assemble_kinematics()
    return chain


def _check(chain: ChainAssembly, states: int = 4) -> None:
    reference = ca.Function("H", [chain.qa, chain.va, chain.p], [ca.hessian(chain.T, chain.va)[0]])
    composite = ca.Function("M", [chain.qa, chain.p], [chain.mass_matrix_all()])
    rng = np.random.default_rng(15)
    kinds = np.array(chain.kinds)
    p = np.array([item.value for item in chain.P.items])
    for _ in range(states):
        qa = np.where(kinds == "elastic", rng.normal(scale=0.02, size=kinds.size), rng.uniform(-3, 3, kinds.size))
        expected = np.array(reference(qa, rng.normal(scale=3.0, size=kinds.size), p))
        got = np.array(composite(qa, p))
        assert np.max(np.abs(got - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_the_mixed_chain_cuts_at_every_body():
    chain = _chain(parse_scene(_mixed()))
    forms = body_forms(chain)
    assert [f.cut for f in forms] == [False, True, True, True, True]
    # the elastic joint's two angles and the position-driven joint's angle are their bodies' own rates
    assert forms[1].rates[:2] == [chain.motor_coord[1], chain.joint_coord[1]]
    assert forms[3].rates == [chain.joint_coord[3]]
    _check(chain, states=6)


def test_explain_names_the_recursion():
    """`flexlink explain` lists the model's terms: the mass matrix's recursion is one of them (and not on one body)."""
    model = build_model(parse_scene(_mixed()))
    assert any("composite inertia over the 5 bodies" in term for term in model.terms)
    single = build_model(load_scene(EXAMPLES[0].parent / "rotating_link.toml"))
    assert not any("composite inertia" in term for term in single.terms)


def test_the_second_walk_leaves_the_chain_as_it_was():
    chain = _chain(parse_scene(_mixed()))
    before = (len(chain.bodies), len(chain.rate_grams), len(chain.kane_links), str(chain.origin))
    body_forms(chain)
    assert (len(chain.bodies), len(chain.rate_grams), len(chain.kane_links), str(chain.origin)) == before


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_every_example(path):
    _check(_chain(load_scene(path)))
