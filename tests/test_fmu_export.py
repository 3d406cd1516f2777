"""The exported FMU: standard compliance, independent importers, and agreement with the reference.

Every example scene is exported once per session.  The FMU's trajectories are compared with the
CVODES reference simulation of the same symbolic model (flexlink.mechanics.reference); the tolerance is not a
number picked to pass but a convergence study: halving SS22's step must divide the error by about 4
(Θ = ½ is second-order accurate), which shows the remaining difference is SS22's own truncation error.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from flexlink.export.cache import cached_fmu
from flexlink.mechanics.analysis import static_deflection
from flexlink.mechanics.model import build_model
from flexlink.mechanics.reference import simulate_reference
from flexlink.run.simulate import SlaveRunner
from flexlink.scene.loader import Scene, load_scene
from flexlink.tools.importers import fmutool_check, libcosim_available, run_libcosim

FULL = os.environ.get("FLEXLINK_FULL") == "1"
EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples").glob("*.toml"))


@pytest.fixture(scope="session")
def example_fmus():
    return {path.stem: cached_fmu(path) for path in EXAMPLES}


@pytest.mark.parametrize("name", [p.stem for p in EXAMPLES])
def test_model_description_validates(example_fmus, name):
    from fmpy.validation import validate_fmu

    fmu = example_fmus[name]
    assert validate_fmu(str(fmu)) == []
    cli = subprocess.run([sys.executable, "-m", "fmpy.cli", "validate", str(fmu)],
                         capture_output=True, text=True)
    assert cli.returncode == 0, cli.stdout + cli.stderr
    assert "No problems found" in cli.stdout


@pytest.mark.parametrize("name", [p.stem for p in EXAMPLES])
def test_fmpy_and_independent_importers_agree(example_fmus, name):
    """fmpy's simulate_fmu, libcosim (FMI Library) and fmutool all accept and run the FMU."""
    import fmpy

    fmu = example_fmus[name]
    md = fmpy.read_model_description(str(fmu))
    outputs = [v.name for v in md.modelVariables if v.causality == "output"][:4]
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.2, output_interval=0.01, output=outputs)
    assert np.all(np.isfinite([res[n] for n in outputs]))
    check = fmutool_check(fmu)
    assert check.ok, check.log
    if not libcosim_available():
        pytest.skip("libcosimpy is not installed")
    run = run_libcosim(fmu, 0.2, 0.01, outputs)
    assert run.ok, run.log
    for n in outputs:
        assert run.values[n] == pytest.approx(res[n][-1], rel=1e-9, abs=1e-12), n


def _fmu_vs_reference(scene_path, stop, comm, steps, *, inputs=None, pieces=None, start=None, outputs, tmp_path,
                      settings=None):
    """RMS error (over the communication points) of the FMU against the reference, for each SS22 step."""
    scene = scene_path if isinstance(scene_path, Scene) else load_scene(scene_path)
    model = build_model(scene)
    fmu = cached_fmu(scene, model=model)
    times = np.arange(int(round(stop / comm)) + 1) * comm
    q0, v0 = model.start_state()
    for s in model.start_values:
        if start and s.name in start:
            (v0 if s.rate else q0)[s.coordinate] = start[s.name]
    if model.static_coordinates:
        u0 = model.default_inputs(0.0)
        for law in model.laws:
            u0[law.u_offset + 1:law.u_offset + 3] = 0.0
        q0 = static_deflection(model, q0, v0, u0, model.p0, model.static_coordinates)
    ref = simulate_reference(model, times, inputs=pieces, q0=q0, v0=v0)
    errors = []
    settings = settings or {}
    with SlaveRunner(fmu) as runner:
        for h in steps:
            res = runner.run(stop, comm, inputs=inputs, start={**(start or {}), "solver.step": h, **settings},
                             outputs=outputs)
            errors.append({n: float(np.sqrt(np.mean((res[n] - ref.output(model, n)) ** 2))) for n in outputs})
    scale = {n: float(np.sqrt(np.mean(ref.output(model, n) ** 2))) for n in outputs}
    return errors, scale


def _assert_second_order(errors, scale, name, max_relative):
    """Observed order log2(e(h)/e(h/2)) within 2 ± 0.45 (max-norm errors of oscillating signals approach
    the asymptote with some scatter), and the error at the largest step small against the signal."""
    e = [err[name] for err in errors]
    orders = [np.log2(a / b) for a, b in zip(e[:-1], e[1:], strict=True)]
    print(f"{name}: errors {[f'{x:.3g}' for x in e]} (signal {scale[name]:.3g}), "
          f"observed orders {[f'{p:.2f}' for p in orders]}")
    assert all(abs(p - 2.0) < 0.45 for p in orders), (name, e)
    assert e[0] < max_relative * scale[name]


def test_rotating_link_bang_bang_matches_reference(tmp_path):
    """Seed-000 link, second-order kinematics (Newton every step), ±0.2 N m torque (issue 6's scene)."""
    def torque(t):
        return {"hub.tau": 0.2 if t < 1.0 else (-0.2 if t < 2.0 else 0.0)}

    errors, scale = _fmu_vs_reference(
        "examples/rotating_link.toml", 3.0, 0.05, [1e-3, 5e-4, 2.5e-4], inputs=torque,
        pieces=[(0.0, {"hub.tau": 0.2}), (1.0, {"hub.tau": -0.2}), (2.0, {"hub.tau": 0.0})],
        outputs=["hub.theta", "arm.tip.v", "arm.root.moment", "tip.y"], tmp_path=tmp_path)
    for n in ("hub.theta", "arm.tip.v", "arm.root.moment"):
        _assert_second_order(errors, scale, n, 0.2)


def test_steel_beam_released_under_gravity_matches_reference(tmp_path):
    """Seed 001 §4.8: FE beam, position-held joint, released undeformed under gravity (54 Hz).

    Released undeformed, every FE mode is excited, up to 23 kHz: the convergence study uses steps that
    resolve them all (ω_max Δt ≤ 0.6).  At the scene's own 1e-4 s the upper modes keep their amplitude with
    a wrong phase (Θ = ½ does not damp them; Θ > ½ does, see test_ss22_numerics)."""
    errors, scale = _fmu_vs_reference(
        "examples/steel_beam_gravity.toml", 0.02, 1e-3, [1.6e-5, 8e-6, 4e-6],
        outputs=["beam.tip.v", "base.tau"], tmp_path=tmp_path)
    _assert_second_order(errors, scale, "beam.tip.v", 0.05)
    # the torque reads accelerations ~ω² η of every mode: the reference's own absolute error (atol 1e-13 on η)
    # is amplified by ω_max² ≈ 2e10, a floor near 1e-3 of the signal
    assert errors[-1]["base.tau"] < 2e-3 * scale["base.tau"]


def test_steel_beam_raised_from_sag_matches_reference(tmp_path):
    """Seed 001 §4.9: built-in law θ = π/4 (1 − cos πt), static start; the joint torque is an output."""
    errors, scale = _fmu_vs_reference(
        "examples/steel_beam_raise.toml", 0.05, 1e-3, [1.6e-5, 8e-6, 4e-6],
        outputs=["beam.tip.v", "base.tau", "base.theta"], tmp_path=tmp_path)
    _assert_second_order(errors, scale, "beam.tip.v", 0.05)
    assert max(e["base.theta"] for e in errors) < 1e-12   # the law itself is exact


def test_flexible_pendulum_swing_matches_reference(tmp_path):
    """Seed 001 §6.3: free joint, released 3° from hanging, undeformed.

    Released undeformed, every FE mode (up to 1.2 kHz) rings with ~1e-6 rad in the swing; the study
    converges only once their phase error over the window is small, hence steps with ω_max Δt ≤ 0.03.
    CI size: the first 20 ms (FLEXLINK_FULL=1: 100 ms; 175 000 SS22 steps of the 17-coordinate model)."""
    joint = load_scene("examples/flexible_pendulum.toml").joints[0].name
    start = {f"{joint}.initial_angle": -np.pi / 2 + np.radians(3.0)}
    errors, scale = _fmu_vs_reference(
        "examples/flexible_pendulum.toml", 0.1 if FULL else 0.02, 0.005, [4e-6, 2e-6, 1e-6], start=start,
        outputs=[f"{joint}.theta", "tip.x"], tmp_path=tmp_path)
    _assert_second_order(errors, scale, f"{joint}.theta", 0.01)


def test_fmu_cache_key_covers_the_c_sources_and_templates(tmp_path, monkeypatch):
    """A change to any file of fmu_src/ (C sources, headers, codegen templates), or a new version of CasADi,
    numpy or scipy, is a new cached FMU."""
    import shutil

    from flexlink.export import cache, cbuild
    from flexlink.export import fmu as fmu_module

    src = tmp_path / "fmu_src"
    shutil.copytree(cbuild.fmu_src_dir(), src, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(cache, "fmu_src_dir", lambda: src)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))

    def build(scene, path, model=None, **_):                # no compiler: only the cache key is tested
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_bytes(b"")

    monkeypatch.setattr(fmu_module, "build_fmu", build)
    scene = EXAMPLES[0]
    paths = [cache.cached_fmu(scene)]
    for name in ("templates/model.c.in", "cs_step.c", "cosimulation.h"):
        with (src / name).open("a") as f:
            f.write("\n")
        paths.append(cache.cached_fmu(scene))
    real = cache._installed
    for package in ("casadi", "numpy", "scipy"):       # an upgrade of what writes the code: a new FMU too
        monkeypatch.setattr(cache, "_installed", lambda p, changed=package: real(p) + ("+1" if p == changed else ""))
        paths.append(cache.cached_fmu(scene))
    monkeypatch.setattr(cache, "_installed", real)
    assert len(set(paths)) == len(paths)
    assert cache.cached_fmu(scene) == paths[-4]      # unchanged sources and packages: the same cached FMU
    assert real("casadi").startswith("casadi-") and real("no_such_package") == "no_such_package absent"


def test_generated_code_optimisation_level(monkeypatch, tmp_path):
    """Without FLEXLINK_OPTIMISE: a generated function is compiled at -O2 up to 5 000 operations, -Og above
    (docs/integrator.md, "Code generation"); the variable imposes a level, a bad value is a BuildError naming it;
    the level is part of the FMU cache key."""
    from flexlink.errors import BuildError
    from flexlink.export import cache
    from flexlink.export import fmu as fmu_module
    from flexlink.export.codegen import generated_code_optimisation

    monkeypatch.delenv("FLEXLINK_OPTIMISE", raising=False)
    assert generated_code_optimisation(5_000) == "O2"
    assert generated_code_optimisation(5_001) == "Og"
    assert generated_code_optimisation(500_000, matrix_graph=True) == "O2"      # loops, not straight-line code
    monkeypatch.setenv("FLEXLINK_OPTIMISE", "O0")
    assert generated_code_optimisation(10) == "O0"
    monkeypatch.setenv("FLEXLINK_OPTIMISE", "O3")
    with pytest.raises(BuildError, match="FLEXLINK_OPTIMISE='O3'"):
        generated_code_optimisation(10)
    keys = []
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(fmu_module, "build_fmu", lambda scene, path, model=None, **_: None)
    for level in ("O0", "O2"):
        monkeypatch.setenv("FLEXLINK_OPTIMISE", level)
        keys.append(cache.cached_fmu(EXAMPLES[0]))
    assert keys[0] != keys[1]
