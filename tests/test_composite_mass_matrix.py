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
    # the elastic joint's two angles, the position-driven elbow's angle (with its linear link's η) and the
    # wrist's angle (a massless connector) are their bodies' own rates
    assert forms[1].rates[:2] == [chain.motor_coord[1], chain.joint_coord[1]]
    assert forms[2].rates == [chain.joint_coord[2], *chain.parts[2].eta]
    assert forms[3].rates == [chain.joint_coord[3]]
    _check(chain, states=6)


def test_explain_names_the_recursion():
    """`flexlink explain` lists the model's terms: the mass matrix's recursion is one of them (and not on one body)."""
    model = build_model(parse_scene(_mixed()))
    assert any("composite inertia over the 5 bodies" in term for term in model.terms)
    single = build_model(load_scene(EXAMPLES[0].parent / "rotating_link.toml"))
    assert not any("composite inertia" in term for term in single.terms)


def test_the_second_walk_leaves_the_chain_as_it_was():
    """The chain's own records are the same objects with the same entries, and every link keeps its tip."""
    chain = _chain(parse_scene(_mixed()))
    lists = {name: getattr(chain, name) for name in ("bodies", "rate_grams", "kane_links")}
    before = {name: list(value) for name, value in lists.items()}
    tips, origin = [part.tip for part in chain.parts], chain.origin
    body_forms(chain)
    for name, value in lists.items():
        assert getattr(chain, name) is value
        assert len(value) == len(before[name]) and all(a is b for a, b in zip(value, before[name], strict=True))
    assert all(part.tip is tip for part, tip in zip(chain.parts, tips, strict=True))
    assert chain.origin is origin


def _kane_chain() -> dict:
    """Three second-order links past the tensors' threshold (8 modes: Kane's form, rate grams), a torsion-only
    link between them, an elastic and a position-driven joint: cross blocks travel several bodies."""
    joints = [dict(name="j1", axis=[0.0, 0.0, 1.0], inertia=0.05),
              dict(name="j2", axis=[0.0, 1.0, 0.0], inertia=0.02, stiffness=500.0),
              dict(name="j3", axis=[0.0, 1.0, 0.0], inertia=0.01, rpy=[0.4, 0.0, 0.0]),
              dict(name="j4", axis=[0.0, 0.0, 1.0], inertia=0.01, drive="position")]
    bend = dict(linear_density=1.0, EI=120.0, deformation=["v"], shapes=dict(kind="clamped-free", count=8),
                kinematics="second-order")
    links = [dict(name="l1", length=0.5, **bend),
             dict(name="l2", length=0.4, **bend),
             dict(name="shaft", length=0.3, linear_density=0.8, EI=100.0, GJ=60.0, polar_inertia=2e-4,
                  deformation=["alpha"], shapes=dict(kind="clamped-free", count=2)),
             dict(name="l4", length=0.3, **{**bend, "shapes": dict(kind="fe", count=6, modes=8)},
                  payload=dict(mass=0.2, inertia=0.001))]
    return dict(name="kane_chain", gravity=[0.0, 0.0, -9.81], joint=joints, link=links)


def test_kane_links_and_a_torsion_only_link_across_several_bodies():
    chain = _chain(parse_scene(_kane_chain()))
    assert len(chain.kane_links) == 3 and len(chain.rate_grams) == 3
    _check(chain)


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_every_example(path):
    _check(_chain(load_scene(path)))


def test_a_torsion_only_link_builds():
    """A link that only twists (deformation = ["alpha"]) builds: its energy was a crash (None + MX) before."""
    scene = dict(name="twist", gravity=[0.0, 0.0, -9.81], joint=[dict(name="j", axis=[0.0, 0.0, 1.0], inertia=0.01)],
                 link=[dict(name="shaft", length=0.3, linear_density=0.8, EI=100.0, GJ=60.0, polar_inertia=2e-4,
                            deformation=["alpha"], shapes=dict(kind="clamped-free", count=2))])
    model = build_model(parse_scene(scene))
    assert model.coordinates == ["j.theta", "shaft.eta[1]", "shaft.eta[2]"]


def test_a_body_step_that_breaks_the_premise_stops_the_build(monkeypatch):
    """A body whose energy held another body's rate would give a wrong M silently: the recursion refuses it."""
    chain = _chain(parse_scene(_mixed()))
    step = chain.body_step

    def leaky(i, parent):
        energy, *rest = step(i, parent)
        return (energy + chain.va[0] * chain.va[-1] if i == 1 else energy, *rest)

    monkeypatch.setattr(chain, "body_step", leaky)
    with pytest.raises(RuntimeError, match="body 1: .*does not apply"):
        body_forms(chain)
