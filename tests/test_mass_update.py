"""SS22's mass update of a kept Newton matrix (fmu_src/mass_update.c, ss22.h's SS22_MASS_UPDATE).

J = M + Θ₁Δt ∂r/∂v + Θ₂Δt²/2 ∂r/∂q.  A model whose M is generated apart from the rest of J (the Newton matrix
from M and differences of the residual) keeps J − M of each full evaluation, and the update replaces M alone:
J_upd = M(q₂) + Θ₁Δt C(q₁, v₁, a₁) + Θ₂Δt²/2 K(q₁, v₁, a₁).  The references are CasADi's own Jacobians of the
scene's residual, evaluated in Python; the FMU's factors are read through tests/c/mass_update_probe.c, compiled
with the FMU's sources.  That the update keeps every step within its tolerance is audited in
tests/test_ss22_numerics.py (``test_mass_updated_matrices_keep_every_step_within_its_tolerance``).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from source_probe import compile_probe

from flexlink.export.cache import cached_fmu
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene, parse_scene

ROOT = Path(__file__).resolve().parent.parent
PROBE = Path(__file__).resolve().parent / "c" / "mass_update_probe.c"


def _sources(scene, work: Path, probe: Path = PROBE):
    """(model, the FMU's extracted sources directory, the probe compiled with them)."""
    model = build_model(scene)
    src, exe = compile_probe(cached_fmu(scene, model=model), probe, work)
    return model, src, exe


def _flag(src: Path) -> int:
    """config.h's MODEL_MASS_UPDATE."""
    for line in (src / "config.h").read_text().splitlines():
        if line.startswith("#define MODEL_MASS_UPDATE "):
            return int(line.split()[-1])
    raise AssertionError("config.h has no MODEL_MASS_UPDATE")


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """planar_chain_5 (20 coordinates, second-order kinematics): M generated, the rest by differences."""
    return _sources(load_scene(ROOT / "examples" / "planar_chain_5.toml"), tmp_path_factory.mktemp("mass_update"))


def test_a_chain_with_a_generated_mass_matrix_has_the_update(chain):
    _, src, _ = chain
    assert _flag(src) == 1


def test_the_updated_matrix_is_the_new_mass_matrix_plus_the_kept_rest(chain):
    """Two random states of the chain (coordinates up to their nominal scales, rates and accelerations 10 and
    100 times that): the updated factors' solutions x of J x = b for random b have a backward error
    ‖J x − b‖ / (‖J‖ ‖x‖) within 1e-7 against CasADi's M(q₂) + Θ₁Δt C(q₁) + Θ₂Δt²/2 K(q₁) (the kept rest
    comes from forward differences of the residual, √ε of its curvature: tests/test_mass_by_differences.py),
    while against the full matrix at q₁ or at q₂ it is over 1e-5: the update took M from q₂ and the velocity
    and position parts from q₁."""
    model, _, exe = chain
    rng = np.random.default_rng(29)
    dt = model.scene.fmu.solver.step
    t1, t2 = model.scene.fmu.solver.theta
    cv, cq = t1 * dt, t2 * 0.5 * dt * dt
    n = model.n_q
    nominal = np.asarray(model.nominal_q)
    p = np.asarray(model.p0, float)
    u = np.full(len(model.inputs), 0.5)
    q_, v_, a_ = (ca.MX.sym(s, n) for s in "qva")
    r = model.residual(q_, v_, a_, u, p)
    jacobians = ca.Function("jacobians", [q_, v_, a_], [ca.jacobian(r, a_), ca.jacobian(r, v_), ca.jacobian(r, q_)])
    q1, q2 = (rng.uniform(-1.0, 1.0, n) * nominal for _ in range(2))
    v1, a1 = rng.uniform(-1.0, 1.0, n) * nominal * 10.0, rng.uniform(-1.0, 1.0, n) * nominal * 100.0
    rhs = rng.standard_normal((4, n))
    stdin = "\n".join(f"{x:.17g}" for x in (dt, t1, t2, *q1, *v1, *a1, *q2, *u, *p, *rhs.ravel()))
    out = subprocess.run([str(exe)], input=stdin, capture_output=True, text=True, check=True).stdout.split()
    assert int(out[0]) == 1
    x = np.array([float(v) for v in out[1:]]).reshape(rhs.shape)
    M1, C1, K1 = (np.array(m) for m in jacobians(q1, v1, a1))
    M2, C2, K2 = (np.array(m) for m in jacobians(q2, v1, a1))

    def miss(J: np.ndarray) -> float:
        """The solutions' backward error against J: ‖J x − b‖ / (‖J‖ ‖x‖), the largest over the b."""
        size = np.linalg.norm(J, 2)
        return max(np.linalg.norm(J @ xi - bi) / (size * np.linalg.norm(xi)) for xi, bi in zip(x, rhs, strict=True))


    assert miss(M2 + cv * C1 + cq * K1) <= 1e-7          # measured: 6.7e-10
    assert miss(M1 + cv * C1 + cq * K1) > 1e-5           # 7.1e-3: M is not q1's
    assert miss(M2 + cv * C2 + cq * K2) > 1e-5           # 1.9e-4: the rest is not q2's


@pytest.mark.parametrize(("scene", "why"), [
    ("rotating_link_linear", "linear in the state: the Newton matrix is constant"),
    ("mass_differences", "M from differences of the residual: an update would cost a full evaluation"),
    ("dense", 'newton_matrix = "dense": J is generated whole'),
])
def test_models_where_it_would_not_pay_have_none(scene, why, tmp_path):
    """codegen.mass_update: only where M comes from a generated mass matrix and the rest from differences."""
    if scene == "rotating_link_linear":
        loaded = load_scene(ROOT / "examples" / "rotating_link_linear.toml")
    elif scene == "mass_differences":          # tests/test_mass_by_differences.py's link: 12 modes, auto
        link = dict(name="arm", length=1.0, linear_density=2.0, EI=100.0, deformation=["v"],
                    shapes=dict(kind="fe", count=16, modes=12), kinematics="second-order")
        loaded = parse_scene(dict(name="mass_differences", gravity=[0.0, 0.0, -9.81],
                                  joint=[dict(name="hub", axis=[0.0, 0.0, 1.0], inertia=1e-2)], link=[link],
                                  fmu=dict(step=1e-4, newton_matrix="auto")))
    else:
        data = dict(name="dense_two_link", gravity=[0.0, -9.81, 0.0],
                    joint=[dict(name=f"j{k}", axis=[0.0, 0.0, 1.0], inertia=1e-3) for k in (1, 2)],
                    link=[dict(name=f"l{k}", length=0.4, linear_density=1.5, EI=40.0, deformation=["v"],
                               shapes=dict(kind="clamped-free", count=2), kinematics="second-order")
                          for k in (1, 2)],
                    fmu=dict(step=1e-3, newton_matrix="dense"))
        loaded = parse_scene(data)
    _, src, _ = _sources(loaded, tmp_path)
    assert _flag(src) == 0, why
