"""What an importer's Model Exchange solver gets from a flexlink FMU (benchmarks/me_importers.py has the table
for every example): fmpy's CVode converges to the CVODES reference of the same equations as its tolerance
tightens (the ME interface is the model, not an approximation of it), and fmpy's explicit Euler, which
amplifies every undamped mode at any step, is stopped by the FMU's guards with fmi2Discard instead of being
handed a diverged state with fmi2OK."""

from __future__ import annotations

import pytest
from conftest import EXAMPLES
from fmpy.fmi1 import FMICallException

from flexlink.export.cache import cached_fmu
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.bench import default_case, reference_outputs, relative_error, run_model_exchange


@pytest.fixture(scope="module")
def rotating_link():
    scene = load_scene(EXAMPLES / "rotating_link.toml")
    model = build_model(scene)
    case = default_case(model, stop=1.0)
    return scene, case, cached_fmu(scene, model=model), reference_outputs(case)


def test_cvode_converges_to_the_reference(rotating_link):
    _, case, fmu, ref = rotating_link
    errors = [relative_error(case, run_model_exchange(case, fmu, relative_tolerance=tol)[0], ref)
              for tol in (1e-4, 1e-6, 1e-8)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-4                    # CVODE's own error at rtol 1e-8, not a model difference


def test_explicit_euler_is_refused_not_returned_diverged(rotating_link):
    """Euler's amplification |1 + iωh| > 1 for every undamped mode: the motion grows until a guard stops
    it, with fmi2Discard at fmi2CompletedIntegratorStep (the validity or finiteness guard)."""
    scene, case, fmu, _ = rotating_link
    with pytest.raises(FMICallException, match="discard"):
        run_model_exchange(case, fmu, solver="Euler", step_size=scene.fmu.solver.step)


def test_a_modally_reduced_fe_beam_runs_under_cvode_where_the_full_one_stops(tmp_path):
    """docs/fmi.md's advice to ME importers stopped by stiffness: steel_beam_raise's 5 Hermite elements (top
    mode in the kHz) stop fmpy's CVode on mxstep within milliseconds; the same beam reduced to its first 3
    modes (``shapes.modes``) runs the raise, to CVode's own tolerance of the reduced model's CVODES reference
    (the reduction's error against the full beam, 3e-4 here, is measured by benchmarks/modal_reduction_me.py:
    its full CVODES reference takes minutes)."""
    text = (EXAMPLES / "steel_beam_raise.toml").read_text()
    reduced = text.replace('shapes = { kind = "fe", count = 5 }', 'shapes = { kind = "fe", count = 5, modes = 3 }')
    assert reduced != text
    (tmp_path / "reduced.toml").write_text(reduced.replace('name = "steel_beam_raise"', 'name = "raise_3_modes"'))
    for path, runs in ((EXAMPLES / "steel_beam_raise.toml", False), (tmp_path / "reduced.toml", True)):
        scene = load_scene(path)
        model = build_model(scene)
        case = default_case(model, stop=1.0)
        fmu = cached_fmu(scene, model=model)
        if not runs:
            with pytest.raises(RuntimeError, match="mxstep"):
                run_model_exchange(case, fmu, relative_tolerance=1e-6)
            continue
        y, _ = run_model_exchange(case, fmu, relative_tolerance=1e-6)
        assert relative_error(case, y, reference_outputs(case, rtol=1e-9)) < 1e-2
