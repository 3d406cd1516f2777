"""Outputs read without the consistent acceleration (fmu_src/variables.c, fmu_update_static_outputs).

A host that reads positions, rates, deflections or energies after each step needs no acceleration: those
outputs are functions of (q, v, u, p) alone, and the FMU evaluates them without M(q) a = −r(q, v, 0, u, p),
its mass matrix and its LU.  Reactions, accelerations and specific forces depend on the acceleration, and a read
of one of them still solves for it.  The references: which outputs depend on the acceleration is what they
are (a reaction is a mass times an acceleration); the values are those of an instance that reads an
acceleration-dependent output at every point (the full update), and CasADi's own outputs at the consistent
acceleration solved by numpy.
"""

from __future__ import annotations

import numpy as np
import pytest

from flexlink.export.cache import cached_fmu
from flexlink.export.codegen import outputs_using_acceleration
from flexlink.mechanics.model import build_model
from flexlink.run.host import FmuHost
from flexlink.scene.loader import load_scene

SCENE = "examples/rotating_link.toml"
STATIC = ["hub.theta", "hub.omega", "arm.tip.v", "arm.root.moment", "tip.x", "tip.y", "energy.kinetic",
          "energy.potential"]
DYNAMIC = ["hub.reaction.fx", "hub.reaction.fy", "hub.reaction.mz", "tip.ax", "tip.ay", "tip.sx", "tip.sy"]


@pytest.fixture(scope="module")
def built():
    scene = load_scene(SCENE)
    model = build_model(scene)
    return model, cached_fmu(scene, model=model)


def test_the_outputs_that_need_the_acceleration_are_the_reactions_and_the_accelerations(built):
    """The hub's in-plane reaction force and moment, the tip's acceleration and specific force move with the
    acceleration; angles, rates, deflections, the root's bending moment (EI v''(0), a deflection) and the
    energies do not.  The marks are structural: the out-of-plane components of the same vectors, zero in a
    planar model, may be marked too (a read of one then solves for the acceleration, as every read did)."""
    model, _ = built
    uses = dict(zip((s.name for s in model.outputs), outputs_using_acceleration(model), strict=True))
    assert all(uses[n] for n in DYNAMIC)
    assert not any(uses[n] for n in STATIC)
    assert {n for n, u in uses.items() if u} <= set(DYNAMIC) | {"hub.reaction.fz", "hub.reaction.mx",
                                                                "hub.reaction.my", "tip.az", "tip.sz"}


def _run(fmu, read: list[str], steps: int = 300) -> tuple[np.ndarray, dict]:
    """A torque profile at 1 ms communication steps, reading ``read`` after every step."""
    with FmuHost(fmu) as host:
        host.initialize()
        rows = []
        for k in range(steps):
            host.set_values({"hub.tau": 0.4 * np.sin(0.02 * k) + (0.3 if k < 100 else -0.2)})
            host.instance.doStep(k * 1e-3, 1e-3)
            rows.append(host.get_real(read))
        return np.array(rows), host.solver_statistics()


def test_reading_only_outputs_without_the_acceleration_solves_for_none_and_changes_nothing(built):
    """The same run read two ways: only STATIC outputs, or those and a reaction at every point.  The STATIC
    values are the same to the last bit; the first host's run made no consistent acceleration after the
    initialisation's (the mass matrices counted), the second one at every point."""
    _, fmu = built
    alone, stats_alone = _run(fmu, STATIC)
    with_reaction, stats_full = _run(fmu, STATIC + ["hub.reaction.mz"])
    assert np.array_equal(alone, with_reaction[:, :len(STATIC)])
    assert stats_alone["mass_matrices"] <= 1 < 300 <= stats_full["mass_matrices"], (stats_alone, stats_full)


def test_an_acceleration_output_read_after_the_others_is_the_consistent_one(built):
    """After a read of STATIC outputs, a read of the reactions and the tip acceleration solves for the
    acceleration: equal to CasADi's outputs at a = −M⁻¹ r(q, v, 0, u, p) solved by numpy at the FMU's state."""
    model, fmu = built
    coords = model.coordinates
    with FmuHost(fmu) as host:
        host.initialize()
        for k in range(50):
            host.set_values({"hub.tau": 0.5})
            host.instance.doStep(k * 1e-3, 1e-3)
            host.get_real(STATIC)
        got = np.array(host.get_real(DYNAMIC))
        q = np.array(host.get_real([f"q.{c}" for c in coords]))
        v = np.array(host.get_real([f"v.{c}" for c in coords]))
    u, p = np.array([0.5]), np.array(model.p0, float)
    M = np.array(model.mass_matrix_function()(q, u, p))
    a = np.linalg.solve(M, -np.array(model.residual(q, v, np.zeros(model.n_q), u, p)).ravel())
    y = np.array(model.outputs_function(q, v, a, u, p)).ravel()
    want = np.array([y[model.output_index(n)] for n in DYNAMIC])
    assert got == pytest.approx(want, rel=1e-9, abs=1e-9 * np.max(np.abs(want)))
