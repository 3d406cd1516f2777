"""The consistent acceleration with a kept factorised mass matrix (fmu_src/consistent.c).

A host that steps at the solver's step asks for M(q) a = −r(q, v, 0, u, p) at every communication point.
Where a new M costs several residuals the FMU keeps an earlier M's factors and iterates on the residual.  The
reference here is independent of that C: CasADi's own mass matrix and residual of the same model, evaluated
in Python at the state the FMU reports, and solved by numpy — the direct solve the FMU made before.
"""

from __future__ import annotations

import re
import zipfile

import numpy as np
import pytest
from serial_state import reseal

from flexlink.export.cache import cached_fmu
from flexlink.mechanics.model import build_model
from flexlink.run.host import FmuHost
from flexlink.scene.loader import parse_scene

MODES = 16      # a new M and its LU cost 18 residuals here (M from 17 residuals): the kept form is compiled in


def _link_scene(newton_matrix: str = "auto") -> dict:
    """One torque-driven link of 16 Hermite elements reduced to 16 modes, second-order kinematics: its mass
    matrix moves with the deflection (the foreshortening), so a kept one is never exact."""
    joint = dict(name="hub", axis=[0.0, 0.0, 1.0], inertia=1e-2)
    link = dict(name="arm", length=1.0, linear_density=2.0, EI=100.0, deformation=["v"],
                shapes=dict(kind="fe", count=16, modes=MODES), kinematics="second-order")
    return dict(name="kept_mass", gravity=[0.0, 0.0, 0.0], joint=[joint], link=[link],
                fmu=dict(step=1e-4, newton_matrix=newton_matrix))


def _build(newton_matrix: str):
    scene = parse_scene(_link_scene(newton_matrix))
    model = build_model(scene)
    return model, cached_fmu(scene, model=model)


@pytest.fixture(scope="module")
def built():
    return _build("auto")


@pytest.fixture(scope="module")
def built_generated_mass():
    """The same link with its mass matrix generated ("columns" keeps it): a new M costs 6.7 residuals by
    the operation counts, where "auto"'s residual differences cost 18."""
    return _build("columns")


def _reference(model, q, v, u, p) -> np.ndarray:
    """a = −M⁻¹ r(q, v, 0, u, p) from CasADi's mass matrix and residual, solved by numpy."""
    M = np.array(model.mass_matrix_function()(q, u, p))
    r0 = np.array(model.residual(q, v, np.zeros(model.n_q), u, p)).ravel()
    return np.linalg.solve(M, -r0), np.linalg.cond(M * np.asarray(model.nominal_q))   # of M in nominal units


def _names(model):
    coords = model.coordinates
    return [f"q.{c}" for c in coords], [f"v.{c}" for c in coords], [f"der(v.{c})" for c in coords]


def _state_after_a_torque_step(host: FmuHost, accelerations: list[str]) -> bytearray:
    """Initialise, push the hub with 4 N m for 2 ms, read the accelerations (kept factors made), serialise."""
    host.initialize()
    host.set_values({"hub.tau": 4.0})
    host.instance.doStep(0.0, 2e-3)
    host.get_real(accelerations)
    return bytearray(host.instance.serializeFMUstate(host.instance.getFMUstate()))


def _compare(host: FmuHost, model, p: np.ndarray, torque: float) -> float:
    """The FMU's der(v) against the reference at its state, in the scaled norm the FMU's stop uses; returns
    the difference over the bound its tolerance and both solves' round-off allow."""
    qn, vn, an = _names(model)
    q, v, a = (np.array(host.get_real(n)) for n in (qn, vn, an))
    ref, cond = _reference(model, q, v, np.array([torque]), p)
    nominal = np.asarray(model.nominal_q)
    size = np.max(np.abs(ref) / nominal)
    bound = (1e-13 + 8 * cond * np.finfo(float).eps) * size
    return float(np.max(np.abs(a - ref) / nominal) / bound)


def test_the_kept_form_is_compiled_into_this_model(built):
    """The build's price of a new M (config.h) is past the threshold, so the tests below test the kept form."""
    _, fmu = built
    with zipfile.ZipFile(fmu) as z:
        config = z.read("sources/config.h").decode()
        source = z.read("sources/consistent.c").decode()
    cost = float(re.search(r"#define CONSISTENT_REFRESH_COST (\S+)", config).group(1))
    threshold = float(re.search(r"#define CONSISTENT_KEEP_MIN_COST (\S+)", source).group(1))
    assert cost >= threshold


def test_a_host_stepping_at_the_solver_step_gets_the_direct_solves_acceleration(built):
    """Every one of 300 communication points, against the reference.  (A stop on the iteration's first ratio of
    increments failed here by 3.8 bounds at the 26th point: fmu_src/consistent.c says why.)"""
    model, fmu = built
    p = np.array(model.p0, float)
    with FmuHost(fmu) as host:
        host.initialize()
        t, worst = 0.0, 0.0
        for k in range(300):
            torque = 2.0 if k < 150 else -2.0
            host.set_values({"hub.tau": torque})
            host.instance.doStep(t, 1e-4)
            t += 1e-4
            worst = max(worst, _compare(host, model, p, torque))
        stats = host.solver_statistics()
    assert worst <= 1.0, worst
    # the kept factors did the work: far fewer mass matrices than communication points, residuals iterated
    assert stats["mass_matrices"] <= 10 and stats["consistent_iterations"] >= 300, stats


def test_a_parameter_set_or_a_jump_in_the_state_buys_a_new_mass_matrix(built):
    """A heavier link makes the kept M another model's: the FMU forgets it (one new M at the next point), and
    the acceleration is the new model's.  A long step that swings the link far away still ends exact."""
    model, fmu = built
    p = np.array(model.p0, float)
    density = model.parameter_index("arm.linear_density")
    with FmuHost(fmu) as host:
        host.initialize()
        host.set_values({"hub.tau": 5.0})
        host.instance.doStep(0.0, 1e-3)
        before = _compare(host, model, p, 5.0)
        host.set_values({"arm.linear_density": 3 * p[density]})
        p[density] *= 3
        host.instance.doStep(1e-3, 1e-4)
        after = _compare(host, model, p, 5.0)
        host.instance.doStep(1.1e-3, 0.5)
        far = _compare(host, model, p, 5.0)
        stats = host.solver_statistics()
    assert max(before, after, far) <= 1.0, (before, after, far)
    assert stats["mass_matrices"] >= 2, stats


def test_a_restored_state_gives_the_same_accelerations_to_the_last_bit(built):
    """The kept factors are part of the FMU state: a restored state, in this instance or a new one, repeats the
    accelerations bit for bit (a restore with the factors left behind would differ at round-off)."""
    model, fmu = built
    _, _, an = _names(model)

    def advance(host, t0):
        rows = []
        for k in range(20):
            host.set_values({"hub.tau": 1.0 + 0.1 * k})
            host.instance.doStep(t0 + k * 1e-4, 1e-4)
            rows.append(host.get_real(an))
        return np.array(rows)

    with FmuHost(fmu) as host, FmuHost(fmu) as other:
        host.initialize()
        advance(host, 0.0)
        state = host.instance.getFMUstate()
        blob = host.instance.serializeFMUstate(state)
        first = advance(host, 20e-4)
        host.instance.setFMUstate(state)
        assert np.array_equal(advance(host, 20e-4), first)
        other.initialize()
        other.instance.setFMUstate(other.instance.deSerializeFMUstate(blob))
        assert np.array_equal(advance(other, 20e-4), first)
        host.instance.freeFMUstate(state)


def test_model_exchange_derivatives_along_a_path_and_after_a_jump(built):
    """An importer's integrator asks for dx/dt = (v, a) at nearby states, then anywhere: every answer is the
    reference's, whether the kept factors were iterated on or replaced."""
    import ctypes

    model, fmu = built
    p = np.array(model.p0, float)
    n = model.n_q
    rng = np.random.default_rng(7)
    with FmuHost(fmu, interface="ModelExchange") as host:
        inst = host.instance
        host.initialize()
        inst.enterContinuousTimeMode()
        x, dx = np.zeros(2 * n), np.zeros(2 * n)
        px, pdx = (a.ctypes.data_as(ctypes.POINTER(ctypes.c_double)) for a in (x, dx))
        host.set_values({"hub.tau": 3.0})
        nominal = np.asarray(model.nominal_q)
        # an integrator's small steps (1e-5 of the nominal values apart), then a state far away
        path = np.cumsum(rng.normal(0.0, 1e-5, (40, 2 * n)), axis=0) * np.concatenate([nominal, 10 * nominal])
        jump = rng.normal(0.0, 0.05, (1, 2 * n)) * np.concatenate([nominal, 10 * nominal])
        worst = 0.0
        for k, state in enumerate(np.vstack([path, jump])):
            x[:] = state
            inst.setTime(1e-3 * k)
            inst.setContinuousStates(px, 2 * n)
            inst.getDerivatives(pdx, 2 * n)
            ref, cond = _reference(model, x[:n], x[n:], np.array([3.0]), p)
            bound = (1e-13 + 8 * cond * np.finfo(float).eps) * np.max(np.abs(ref) / nominal)
            worst = max(worst, float(np.max(np.abs(dx[n:] - ref) / nominal) / bound))
        stats = host.solver_statistics()
    assert worst <= 1.0, worst
    # kept along the path (the first M, and a new one for the far state at most, and the initialisation's)
    assert stats["mass_matrices"] <= 3 and stats["consistent_iterations"] >= 40, stats


def test_a_forged_state_with_a_kept_pivot_out_of_range_is_refused(built):
    """The kept factors come back with an FMU state, so their pivots are checked like the solver cache's: a
    pivot out of range (checksum made right) would index outside the matrix; it is refused, nothing restored."""
    import struct

    import fmpy

    model, fmu = built
    n = model.n_q
    with FmuHost(fmu) as host:
        host.initialize()
        host.set_values({"hub.tau": 1.0})
        host.instance.doStep(0.0, 1e-3)
        host.get_real(["hub.reaction.mz"])
        blob = bytearray(host.instance.serializeFMUstate(host.instance.getFMUstate()))
        # FmuData ends with the kept factors' pivots (padded to 8 bytes), then the two 64-bit counters
        end = len(blob) - 16 - (4 * n) % 8
        pivots = list(struct.unpack(f"<{n}i", blob[end - 4 * n:end]))
        assert all(i <= k < n for i, k in enumerate(pivots)), pivots     # where the layout says they are
        blob[end - 4 * n:end - 4 * n + 4] = struct.pack("<i", 10**6)
        guid = fmpy.read_model_description(str(fmu)).guid
        reseal(blob, guid)
        with pytest.raises(Exception) as refused:
            host.instance.deSerializeFMUstate(bytes(blob))
        assert "kept mass matrix" in str(refused.value) + " ".join(host.messages)


def _lu_factor(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """fmu_src/linalg.c's lu_factor, transcribed: partial pivoting, L\\U packed column-major, LAPACK's pivots."""
    A = np.array(A, float)
    n = len(A)
    piv = np.zeros(n, int)
    for k in range(n):
        p = k + int(np.argmax(np.abs(A[k:, k])))
        piv[k] = p
        A[[k, p]] = A[[p, k]]
        A[k + 1:, k] /= A[k, k]
        A[k + 1:, k + 1:] -= np.outer(A[k + 1:, k], A[k, k + 1:])
    return A, piv


@pytest.mark.parametrize("b, share", [(3.0, 1e-2), (0.01, 5e-9)])
def test_a_kept_mass_matrix_the_iteration_cannot_use_is_never_accepted(built, b, share):
    """Whatever M the FMU keeps is only a preconditioner: a bad one may cost a new M, never accuracy.

    A kept K = M B⁻¹ with B = M_kept⁻¹ M = I + (b − 1) w cᵀ (cᵀw = 1) written into a state: the iteration's error
    (1 − b)ᵏ along w, and nothing elsewhere but a share along w of the acceleration, so that the first ratio of
    increments is small.  b = 3 diverges (ratio 2: a stop on ρ/(1 − ρ) taken negative accepted it 4 % off);
    b = 0.01 crawls (ratio 0.99: its steps are 1 % of its error, which a stop on the step took at 5e-9).
    """
    model, fmu = built
    p = np.array(model.p0, float)
    n = model.n_q
    qn, vn, an = _names(model)
    nominal = np.asarray(model.nominal_q)
    with FmuHost(fmu) as host:
        blob = _state_after_a_torque_step(host, an)
        q, v = np.array(host.get_real(qn)), np.array(host.get_real(vn))
        M = np.array(model.mass_matrix_function()(q, np.array([4.0]), p))
        a = _reference(model, q, v, np.array([4.0]), p)[0]
        # w: along the largest modal coordinate's nominal unit, its share of a put there; c ⟂ the rest of a
        w = np.zeros(n)
        w[n - 1] = nominal[n - 1] * share * np.max(np.abs(a) / nominal)
        rest = a - w
        c = w - (w @ rest) / (rest @ rest) * rest
        c /= c @ w
        K = M - (b - 1.0) / b * np.outer(M @ w, c)          # M B⁻¹, Sherman-Morrison
        _restore_with_kept(host, fmu, blob, *_lu_factor(K))
        host.set_values({"hub.tau": 4.0})      # the same input: only the outputs are asked for again
        worst = _compare(host, model, p, 4.0)
    assert worst <= 1.0, worst


def test_an_iteration_that_cannot_converge_in_its_budget_buys_a_new_mass_matrix_early(built_generated_mass):
    """A kept M that contracts at 0.05 everywhere (B = M_kept⁻¹ M = 1.05 I) needs about 11 residuals to 1e-13;
    the budget is a new M's price less one (5 here).  The measured rate tells after the second residual that the
    budget cannot reach the tolerance: the new M is bought then, not after the 5 (2 wasted instead of 5)."""
    model, fmu = built_generated_mass
    p = np.array(model.p0, float)
    qn, _, an = _names(model)
    with zipfile.ZipFile(fmu) as z:
        cost = float(re.search(r"#define CONSISTENT_REFRESH_COST (\S+)", z.read("sources/config.h").decode())[1])
    budget = int(cost) - 1
    assert budget >= 3, cost             # room for a saving: the first two residuals are always spent
    with FmuHost(fmu) as host:
        blob = _state_after_a_torque_step(host, an)
        counters = np.frombuffer(bytes(blob[-16:]), "<u8")          # mass matrices, residuals iterated
        M = np.array(model.mass_matrix_function()(np.array(host.get_real(qn)), np.array([4.0]), p))
        _restore_with_kept(host, fmu, blob, *_lu_factor(M / 1.05))
        host.set_values({"hub.tau": 4.0})
        worst = _compare(host, model, p, 4.0)
        stats = host.solver_statistics()
    assert worst <= 1.0, worst
    assert stats["mass_matrices"] - counters[0] == 1, (stats, counters)
    assert stats["consistent_iterations"] - counters[1] == 2, (stats, counters, budget)


def test_a_kept_factor_that_is_not_a_number_is_never_accepted(built):
    """At rest in equilibrium (r0 = 0) a kept U₀₀ = NaN makes a₁ = (NaN, 0, …, 0): a size that let the NaN
    through (max over |aᵢ| kept the later zeros) took it for a = 0 exactly, and outputs NaN with fmi2OK."""
    model, fmu = built
    _, _, an = _names(model)
    with FmuHost(fmu) as host:
        host.initialize()
        host.get_real(an)
        blob = bytearray(host.instance.serializeFMUstate(host.instance.getFMUstate()))
        LU, piv = np.eye(model.n_q), np.arange(model.n_q)
        LU[0, 0] = np.nan
        _restore_with_kept(host, fmu, blob, LU, piv)
        host.set_values({"hub.tau": 0.0})
        a = np.array(host.get_real(an))
    assert np.array_equal(a, np.zeros(model.n_q)), a      # at rest, unforced: a = 0 (the direct solve's)


def _restore_with_kept(host: FmuHost, fmu, blob: bytearray, LU: np.ndarray, piv: np.ndarray) -> None:
    """Write kept factors into a serialised state (checksum made right) and restore it in host."""
    import struct

    import fmpy

    n = len(piv)
    # FmuData ends with the kept factors {int valid; double LU[n²]; int piv[n]} (padded to 8), two counters
    end = len(blob) - 16 - (4 * n) % 8
    start = end - 4 * n - 8 * n * n - 8
    blob[start:start + 4] = struct.pack("<i", 1)
    blob[start + 8:end - 4 * n] = np.asarray(LU, float).tobytes(order="F")
    blob[end - 4 * n:end] = struct.pack(f"<{n}i", *piv)
    reseal(blob, fmpy.read_model_description(str(fmu)).guid)
    host.instance.setFMUstate(host.instance.deSerializeFMUstate(bytes(blob)))
