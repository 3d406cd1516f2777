"""A coordinate nothing resists is refused with the scene, before any C is generated
(flexlink.mechanics.wellposed): a massless stub at the end of the chain on a joint without rotor inertia
leaves that joint's angle undetermined (its row of M + Θ₁ΔtC + Θ₂Δt²/2 K is zero: there is no equation
for it), and the FMU itself can only refuse its first step -- checked by building it without the check."""

from __future__ import annotations

import pytest
from fmpy.fmi1 import FMICallException

from flexlink.errors import SceneError
from flexlink.export.fmu import build_fmu
from flexlink.mechanics import model as model_module
from flexlink.mechanics.model import build_model
from flexlink.run.simulate import SlaveRunner
from flexlink.scene.loader import parse_scene


def stub_scene(*, inertia: float = 0.0, damping: float = 0.0, stub_mass: float = 0.0) -> dict:
    """A flexible arm, then joint j2 carrying a rigid stub at its tip."""
    return dict(
        name="stub",
        joint=[dict(name="j1", axis=[0.0, 0.0, 1.0], inertia=0.01),
               dict(name="j2", axis=[0.0, 0.0, 1.0], inertia=inertia, damping=damping)],
        link=[dict(name="arm", length=1.0, linear_density=1.0, EI=50.0, deformation=["v"],
                   shapes=dict(kind="clamped-free", count=2)),
              dict(name="stub", length=0.1, deformation=[], mass=stub_mass,
                   **({"center_of_mass": [0.05, 0.0, 0.0]} if stub_mass else {}))])


def test_a_coordinate_nothing_resists_is_refused_with_the_scene():
    with pytest.raises(SceneError) as info:
        build_model(parse_scene(stub_scene()))
    message = str(info.value)
    assert 'joint[2] "j2"' in message and "j2.theta" in message and "\n" not in message


def test_without_the_check_the_fmu_refuses_its_first_step(tmp_path, monkeypatch):
    """The refusal is not a false alarm: the same scene built past the check cannot take a step."""
    monkeypatch.setattr(model_module, "check_step_matrix", lambda model: None)
    fmu = build_fmu(parse_scene(stub_scene()), tmp_path / "stub.fmu").fmu
    with SlaveRunner(fmu) as runner, pytest.raises(FMICallException):
        runner.run(0.01, 0.001, outputs=["j2.theta"])


@pytest.mark.parametrize("fix", [dict(inertia=1e-4), dict(damping=0.1), dict(stub_mass=0.5)])
def test_inertia_damping_or_mass_make_it_a_valid_scene(fix):
    """Each remedy the message names gives the coordinate an equation: the model builds."""
    build_model(parse_scene(stub_scene(**fix)))
