"""Shape functions and their constant integrals, each checked against an independent reference:
published roots, beam theory (orthogonality, boundary conditions, frequencies, static deflection),
scipy's adaptive quadrature on ``evaluate``, closed forms and finite differences."""

import math

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import quad

from flexlink.mechanics.shapes import (
    KINDS,
    ShapeIntegrals,
    clamped_free_roots,
    integrals_from_rule,
    make_basis,
)
from flexlink.mechanics.shapes.base import composite_gauss_legendre

LENGTH = 1.7
RHO = 2.5
EI = 3.2

# Published cantilever roots (Blevins, Formulas for Natural Frequency and Mode Shape, table 8-1).
PUBLISHED_ROOTS = [1.875104, 4.694091, 7.854757, 10.995541, 14.137168]

# Small bases for the (slow, adaptive) scipy reference integrals.
QUAD_CASES = [("clamped-free", 6), ("polynomial", 4), ("fe", 3)]


def _naive_clamped_free(lam: float, x: np.ndarray, length: float, rho: float, derivative: int) -> np.ndarray:
    """The textbook formula, evaluated as written (for the demonstration that it fails)."""
    z = lam * x / length
    c = -(math.sin(lam) + math.sinh(lam)) / (math.cos(lam) + math.cosh(lam))
    a = 1.0 / (abs(c) * math.sqrt(rho * length))
    trig = [
        (np.sin(z), np.cos(z)),
        (np.cos(z), -np.sin(z)),
        (-np.sin(z), -np.cos(z)),
        (-np.cos(z), np.sin(z)),
    ][derivative % 4]
    hyp = [(np.sinh(z), np.cosh(z)), (np.cosh(z), np.sinh(z))][derivative % 2]
    return a * (lam / length) ** derivative * (trig[0] - hyp[0] + c * (trig[1] - hyp[1]))


def _frequency_parameters(basis, count: int = 3) -> np.ndarray:
    """λ_i = L (ω_i² ρ/EI)^(1/4) from the generalized eigenproblem (EI·curv, ρ·phi_phi)."""
    integrals = basis.integrals
    w2 = scipy.linalg.eigh(EI * integrals.curv, RHO * integrals.phi_phi, eigvals_only=True)
    return basis.length * (w2[:count] * RHO / EI) ** 0.25


# --- make_basis and evaluate: the contract -------------------------------------------------------


def test_kinds_and_sizes():
    assert set(KINDS) == {"clamped-free", "polynomial", "fe"}
    for kind, count, n in [("clamped-free", 4, 4), ("polynomial", 4, 4), ("fe", 4, 8)]:
        basis = make_basis(kind, count, LENGTH, RHO)
        assert (basis.kind, basis.length, basis.n) == (kind, LENGTH, n)
        assert basis.evaluate(0.3).shape == (1, n)
        assert basis.evaluate(np.linspace(0, LENGTH, 7), 2).shape == (7, n)
        assert isinstance(basis.integrals, ShapeIntegrals)
        assert basis.integrals is basis.integrals  # computed once


@pytest.mark.parametrize(
    "args, message",
    [
        (("beam", 3, 1.0), "unknown shape kind"),
        (("fe", 0, 1.0), ">= 1"),
        (("polynomial", -2, 1.0), ">= 1"),
        (("clamped-free", 2.5, 1.0), "integer"),
        (("fe", 3, 0.0), "length"),
        (("clamped-free", 3, 1.0, -1.0), "linear_density"),
    ],
)
def test_make_basis_rejects(args, message):
    with pytest.raises(ValueError, match=message):
        make_basis(*args)


def test_evaluate_rejects_points_outside_and_bad_derivative():
    basis = make_basis("fe", 2, LENGTH)
    with pytest.raises(ValueError, match=r"\[0, L\]"):
        basis.evaluate([0.5, LENGTH * 1.01])
    with pytest.raises(ValueError, match=r"\[0, L\]"):
        basis.evaluate(-1e-3)
    with pytest.raises(ValueError, match="derivative"):
        basis.evaluate(0.5, -1)
    # Round-off of a caller's grid at the tip is accepted.
    assert basis.evaluate(LENGTH * (1 + 1e-15)).shape == (1, 4)


def test_integrals_are_read_only():
    integrals = make_basis("polynomial", 3, LENGTH).integrals
    with pytest.raises(ValueError):
        integrals.phi_phi[0, 0] = 1.0


# --- eigenfunctions ----------------------------------------------------------------------------


def test_roots_against_published_values():
    np.testing.assert_allclose(clamped_free_roots(5), PUBLISHED_ROOTS, rtol=0, atol=1e-6)


def test_roots_equal_scipys_brentq():
    """The bisection to adjacent floats lands where scipy's Brent solver does, at its tightest tolerance."""
    from scipy.optimize import brentq

    def f(lam):
        return math.cos(lam) + 1.0 / math.cosh(lam)

    reference = [brentq(f, (i - 1) * math.pi, i * math.pi, xtol=1e-300, rtol=4 * np.finfo(float).eps)
                 for i in range(1, 41)]
    np.testing.assert_allclose(clamped_free_roots(40), reference, rtol=4 * np.finfo(float).eps, atol=0)


def test_roots_follow_the_asymptote():
    roots = clamped_free_roots(40)
    for i in range(6, 41):
        asymptote = (2 * i - 1) * math.pi / 2
        lam = roots[i - 1]
        # λ = λ0 + δ with cos(λ0 + δ) = −sech(λ0 + δ): δ ≈ (−1)^(i+1) 2 e^{−λ0}, so the plain asymptote is
        # right to its own accuracy 2 e^{−λ0} and the corrected one to round-off.
        assert abs(lam - asymptote) <= 2.01 * math.exp(-asymptote) + 4 * np.finfo(float).eps * lam
        corrected = asymptote + (-1) ** (i + 1) * 2 * math.exp(-asymptote)
        assert abs(lam - corrected) <= 4 * np.finfo(float).eps * lam + 10 * math.exp(-2 * asymptote)


def test_twenty_eigenfunctions_orthonormal_and_stiffness_diagonal():
    basis = make_basis("clamped-free", 20, LENGTH, RHO)
    integrals = basis.integrals
    lam = clamped_free_roots(20)
    np.testing.assert_allclose(RHO * integrals.phi_phi, np.eye(20), rtol=0, atol=1e-9)
    scale = np.sqrt(np.outer(lam**4, lam**4)) / (LENGTH**4 * RHO)
    np.testing.assert_allclose(integrals.curv / scale, np.eye(20), rtol=0, atol=1e-9)


def test_twenty_eigenfunctions_boundary_conditions_and_ode():
    basis = make_basis("clamped-free", 20, LENGTH, RHO)
    lam = clamped_free_roots(20)
    k = lam / LENGTH
    x = np.linspace(0, LENGTH, 301)
    # Each derivative scaled by its natural size k^d/√(ρL), so the residuals are relative.
    scaled = [basis.evaluate(x, d) * math.sqrt(RHO * LENGTH) / k**d for d in range(5)]
    assert np.abs(scaled[0][0]).max() < 1e-12 and np.abs(scaled[1][0]).max() < 1e-12  # clamped root
    assert np.abs(scaled[2][-1]).max() < 1e-10 and np.abs(scaled[3][-1]).max() < 1e-10  # free tip
    np.testing.assert_allclose(scaled[4], scaled[0], rtol=0, atol=1e-10)  # φ'''' = (λ/L)^4 φ
    # Classical values of the normalised cantilever mode (times 1/√(ρL)): φ(L) = 2(−1)^(i+1), φ''(0) = 2λ²/L².
    signs = (-1.0) ** np.arange(20)
    np.testing.assert_allclose(scaled[0][-1], 2 * signs, rtol=1e-12)
    np.testing.assert_allclose(scaled[2][0], 2.0, rtol=1e-12)


def test_naive_formula_fails_where_the_cancellation_free_one_holds():
    basis = make_basis("clamped-free", 20, LENGTH, RHO)
    lam = clamped_free_roots(20)
    x = np.linspace(0, LENGTH, 401)
    ours = basis.evaluate(x)
    # Low modes: the naive formula is still accurate and must agree (independent check of form and sign).
    for i in range(5):
        np.testing.assert_allclose(_naive_clamped_free(lam[i], x, LENGTH, RHO, 0), ours[:, i], atol=1e-8)
    # Mode 12: sinh and c cosh ~ e^36/2 cancel; the naive values near the tip are wrong by ~10 %.
    # (At x = L exactly the naive φ''(L) and φ'''(L) still vanish, because c is defined by φ''(L) = 0
    # from the very same rounded sinh λ, cosh λ; anywhere inside the span the rounding no longer cancels.)
    i = 11
    naive = _naive_clamped_free(lam[i], x, LENGTH, RHO, 0)
    size = np.abs(ours[:, i]).max()
    assert np.abs(naive - ours[:, i]).max() / size > 0.05
    # Its mass normalisation and orthogonality break down at the 1e-3 level; ours hold to 1e-12.
    xq, wq = composite_gauss_legendre(np.linspace(0, LENGTH, 65), 16)
    naive_q = _naive_clamped_free(lam[i], xq, LENGTH, RHO, 0)
    ours_q = basis.evaluate(xq)
    assert abs(RHO * wq @ naive_q**2 - 1) > 1e-3
    assert abs(RHO * wq @ (naive_q * ours_q[:, 0])) > 1e-3
    assert abs(RHO * wq @ ours_q[:, i] ** 2 - 1) < 1e-12
    assert abs(RHO * wq @ (ours_q[:, i] * ours_q[:, 0])) < 1e-12


def test_eigen_quadrature_is_converged_to_machine_precision():
    basis = make_basis("clamped-free", 20, LENGTH, RHO)
    fine = integrals_from_rule(basis, *composite_gauss_legendre(np.linspace(0, LENGTH, 129), 24))
    for name, value in vars(basis.integrals).items():
        reference = getattr(fine, name)
        atol = 1e-13 * np.abs(reference).max()
        np.testing.assert_allclose(value, reference, rtol=0, atol=atol, err_msg=name)


# --- every integral against scipy.integrate.quad on evaluate ------------------------------------


def _breakpoints(basis, a: float, b: float):
    """FE nodes strictly inside (a, b): quad must not integrate across the kinks blindly."""
    if basis.kind != "fe":
        return None
    nodes = np.linspace(0, basis.length, basis.count + 1)[1:-1]
    inside = [p for p in nodes if a < p < b]
    return inside or None


def _quad(basis, f, a: float, b: float, size: float) -> float:
    """Adaptive Gauss–Kronrod to ~1e-13 of the integrand's own size (|f| ≤ size on [a, b])."""
    tol = 1e-13 * size * max(b - a, 1e-300)
    return quad(f, a, b, points=_breakpoints(basis, a, b), epsabs=tol, epsrel=1e-13, limit=200)[0]


class _Rows:
    """evaluate() one point at a time, memoised: the nested quads revisit the same nodes for each (i, j)."""

    def __init__(self, basis):
        self.basis, self.cache = basis, {}

    def __call__(self, x: float, derivative: int) -> np.ndarray:
        key = (derivative, float(x))
        if key not in self.cache:
            self.cache[key] = self.basis.evaluate(x, derivative)[0]
        return self.cache[key]


@pytest.mark.parametrize("kind, count", QUAD_CASES)
def test_integrals_against_adaptive_quadrature(kind, count):
    basis = make_basis(kind, count, LENGTH, RHO)
    got = basis.integrals
    n, L = basis.n, LENGTH
    row = _Rows(basis)
    grid = np.linspace(0, L, 401)
    size = [np.abs(basis.evaluate(grid, d)).max(axis=0) for d in range(3)]  # per column, for tolerances

    phi = [_quad(basis, lambda x, i=i: row(x, 0)[i], 0, L, size[0][i]) for i in range(n)]
    x_phi = [_quad(basis, lambda x, i=i: x * row(x, 0)[i], 0, L, L * size[0][i]) for i in range(n)]
    mats = {name: np.zeros((n, n)) for name in ("phi_phi", "curv", "fs_tip", "fs", "fs_x")}
    for i in range(n):
        for j in range(i, n):
            s0, s1, s2 = (size[d][i] * size[d][j] for d in range(3))
            entries = {
                "phi_phi": _quad(basis, lambda x, i=i, j=j: row(x, 0)[i] * row(x, 0)[j], 0, L, s0),
                "curv": _quad(basis, lambda x, i=i, j=j: row(x, 2)[i] * row(x, 2)[j], 0, L, s2),
                "fs_tip": _quad(basis, lambda x, i=i, j=j: row(x, 1)[i] * row(x, 1)[j], 0, L, s1),
            }
            inner_cache = {}

            def inner(x, i=i, j=j, s1=s1, inner_cache=inner_cache):
                if x not in inner_cache:
                    inner_cache[x] = _quad(basis, lambda xi: row(xi, 1)[i] * row(xi, 1)[j], 0, x, s1)
                return inner_cache[x]

            # The double integrals as written, ∫₀ᴸ ∫₀ˣ … dξ dx: nested quad, no change of order.
            entries["fs"] = _quad(basis, inner, 0, L, L * s1)
            entries["fs_x"] = _quad(basis, lambda x, inner=inner: x * inner(x), 0, L, L * L * s1)
            for name, value in entries.items():
                mats[name][i, j] = mats[name][j, i] = value

    def close(name, actual, reference):
        atol = 1e-10 * np.abs(reference).max()
        np.testing.assert_allclose(actual, reference, rtol=0, atol=atol, err_msg=name)

    close("phi", got.phi, phi)
    close("x_phi", got.x_phi, x_phi)
    for name, reference in mats.items():
        close(name, getattr(got, name), reference)
    close("tip", got.tip, row(L, 0))
    close("tip_slope", got.tip_slope, row(L, 1))
    close("root_curvature", got.root_curvature, row(0.0, 2))


def test_polynomial_integrals_closed_form():
    """Monomials integrate in closed form: an exactness check of the Gauss rule up to count = 8."""
    L = LENGTH
    basis = make_basis("polynomial", 8, L)
    p = np.arange(2, 10, dtype=float)
    pi, pj = np.meshgrid(p, p, indexing="ij")
    s = pi + pj
    expected = dict(
        phi=L / (p + 1),
        x_phi=L**2 / (p + 2),
        phi_phi=L / (s + 1),
        curv=pi * (pi - 1) * pj * (pj - 1) / (L**3 * (s - 3)),
        fs_tip=pi * pj / (L * (s - 1)),
        fs=pi * pj / (s * (s - 1)),
        fs_x=pi * pj * L / ((s - 1) * (s + 1)),
        tip=np.ones(8),
        tip_slope=p / L,
        root_curvature=np.r_[2 / L**2, np.zeros(7)],
    )
    for name, reference in expected.items():
        actual = getattr(basis.integrals, name)
        np.testing.assert_allclose(actual, reference, rtol=1e-13, atol=1e-15, err_msg=name)


def test_fe_nodal_interpolation():
    """η are the nodal deflections and slopes: φ at node k is 1 in w_k's column, φ' is 1 in θ_k's."""
    count = 4
    basis = make_basis("fe", count, LENGTH)
    nodes = np.linspace(0, LENGTH, count + 1)
    values, slopes = basis.evaluate(nodes, 0), basis.evaluate(nodes, 1)
    expected_w = np.zeros((count + 1, 2 * count))
    expected_t = np.zeros((count + 1, 2 * count))
    for k in range(1, count + 1):
        expected_w[k, 2 * (k - 1)] = 1.0
        expected_t[k, 2 * (k - 1) + 1] = 1.0
    np.testing.assert_allclose(values, expected_w, atol=1e-14)
    np.testing.assert_allclose(slopes, expected_t, atol=1e-13)
    # Root curvature of the first element's right-node functions: N3'' = 6/h², (h N4)'' = −2/h.
    h = LENGTH / count
    expected = np.r_[6 / h**2, -2 / h, np.zeros(6)]
    np.testing.assert_allclose(basis.integrals.root_curvature, expected, rtol=1e-13)


# --- frequencies ---------------------------------------------------------------------------------


def test_eigenfunction_basis_gives_exact_frequencies():
    basis = make_basis("clamped-free", 20, LENGTH, RHO)
    np.testing.assert_allclose(_frequency_parameters(basis, 20), clamped_free_roots(20), rtol=1e-10)


def test_fe_frequencies_converge_like_h4():
    exact = clamped_free_roots(3)
    counts = np.array([4, 8, 16, 32])
    errors = np.array([_frequency_parameters(make_basis("fe", c, LENGTH)) / exact - 1 for c in counts])
    assert np.all(errors > 0)  # Rayleigh–Ritz: upper bounds
    assert np.all(np.diff(errors, axis=0) < 0)  # nested meshes: monotone
    for mode in range(3):
        slope = np.polyfit(np.log(counts), np.log(errors[:, mode]), 1)[0]
        assert -4.3 < slope < -3.7, (mode, slope)


def test_polynomial_frequencies_converge_fast():
    exact = clamped_free_roots(3)
    counts = np.arange(1, 8)
    lam1 = np.array([_frequency_parameters(make_basis("polynomial", c, LENGTH), 1)[0] for c in counts])
    errors = lam1 / exact[0] - 1
    assert np.all(errors > -1e-13) and np.all(np.diff(errors) < 0)
    # Geometric: more than a decade per added polynomial (measured ≈ 1.9) …
    decades_per_shape = -np.polyfit(counts, np.log10(errors), 1)[0]
    assert decades_per_shape > 1.5
    # … i.e. far faster than FE's h^4: doubling 3 → 6 shapes gains a factor ≫ 2^4.
    assert math.log2(errors[2] / errors[5]) > 15
    assert np.all(np.abs(_frequency_parameters(make_basis("polynomial", 10, LENGTH)) / exact - 1) < 1e-8)


# --- static deflection under a uniform load ---------------------------------------------------------


def _uniform_load_solution(basis, q: float = 0.7) -> np.ndarray:
    integrals = basis.integrals
    return np.linalg.solve(EI * integrals.curv, q * integrals.phi)


def _exact_deflection(x, q: float = 0.7):
    x = np.asarray(x)
    v = q * x**2 * (6 * LENGTH**2 - 4 * LENGTH * x + x**2) / (24 * EI)
    slope = q * x * (3 * LENGTH**2 - 3 * LENGTH * x + x**2) / (6 * EI)
    return v, slope


@pytest.mark.parametrize("count", [1, 2, 5, 12])
def test_fe_static_deflection_nodally_exact(count):
    basis = make_basis("fe", count, LENGTH)
    eta = _uniform_load_solution(basis)
    tip = basis.integrals.tip @ eta
    assert tip == pytest.approx(0.7 * LENGTH**4 / (8 * EI), rel=1e-11)
    v, slope = _exact_deflection(np.linspace(0, LENGTH, count + 1)[1:])
    np.testing.assert_allclose(eta[0::2], v, rtol=1e-10)
    np.testing.assert_allclose(eta[1::2], slope, rtol=1e-10)


@pytest.mark.parametrize("count", [3, 4, 6])
def test_polynomial_static_deflection_exact_from_three_shapes(count):
    basis = make_basis("polynomial", count, LENGTH)
    eta = _uniform_load_solution(basis)
    assert basis.integrals.tip @ eta == pytest.approx(0.7 * LENGTH**4 / (8 * EI), rel=1e-10)
    x = np.linspace(0, LENGTH, 11)
    np.testing.assert_allclose(basis.evaluate(x) @ eta, _exact_deflection(x)[0], rtol=1e-9, atol=1e-14)


def test_polynomial_static_deflection_below_three_shapes():
    # One shape misses the tip value; two give it exactly (the tip-load influence function is the cubic
    # in their span, so the Ritz tip value is exact) but not the quartic field.
    eta1 = _uniform_load_solution(make_basis("polynomial", 1, LENGTH))
    assert abs(eta1[0] / (0.7 * LENGTH**4 / (8 * EI)) - 1) > 0.1
    basis2 = make_basis("polynomial", 2, LENGTH)
    eta2 = _uniform_load_solution(basis2)
    assert basis2.integrals.tip @ eta2 == pytest.approx(0.7 * LENGTH**4 / (8 * EI), rel=1e-12)
    x = np.linspace(0, LENGTH, 11)
    assert np.abs(basis2.evaluate(x) @ eta2 - _exact_deflection(x)[0]).max() > 1e-3 * 0.7 * LENGTH**4 / EI


def test_eigen_static_deflection_converges():
    target = 0.7 * LENGTH**4 / (8 * EI)
    errors = []
    for count in (1, 5, 20):
        basis = make_basis("clamped-free", count, LENGTH, RHO)
        errors.append(abs(basis.integrals.tip @ _uniform_load_solution(basis) / target - 1))
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-6


# --- derivatives against finite differences --------------------------------------------------------


@pytest.mark.parametrize("kind, count", [("clamped-free", 12), ("polynomial", 6), ("fe", 3)])
def test_derivatives_against_finite_differences(kind, count):
    basis = make_basis(kind, count, LENGTH, RHO)
    x = LENGTH * np.array([0.07, 0.29, 0.52, 0.81, 0.95])  # away from the FE nodes (thirds)
    step = 1e-6 * LENGTH
    for d in (1, 2, 3):
        fd = (basis.evaluate(x + step, d - 1) - basis.evaluate(x - step, d - 1)) / (2 * step)
        exact = basis.evaluate(x, d)
        scale = np.abs(basis.evaluate(np.linspace(0, LENGTH, 201), d)).max(axis=0) + 1e-300
        np.testing.assert_allclose(fd / scale, exact / scale, rtol=0, atol=2e-6, err_msg=f"derivative {d}")


def test_fe_derivatives_jump_only_where_expected():
    """φ and φ' are continuous across nodes; φ'' jumps (cubic Hermite elements are only C¹)."""
    basis = make_basis("fe", 3, LENGTH)
    node = LENGTH / 3
    eps = 1e-9
    for d in (0, 1):
        np.testing.assert_allclose(basis.evaluate(node - eps, d), basis.evaluate(node + eps, d), atol=1e-7)
    assert np.abs(basis.evaluate(node - eps, 2) - basis.evaluate(node + eps, 2)).max() > 1.0
    # At a node (however it was rounded) the second and third derivatives are those of the right element.
    for count in (13, 16, 18):  # with L = 1.7 some k·L/N fall one ulp short of the node
        basis = make_basis("fe", count, LENGTH)
        for nodes in (np.arange(count) * (LENGTH / count), np.linspace(0, LENGTH, count + 1)[:-1]):
            for d in (2, 3):
                right = basis.evaluate(nodes + 1e-10, d)
                np.testing.assert_allclose(basis.evaluate(nodes, d), right, rtol=1e-6)


@pytest.mark.parametrize("kind, count", [("clamped-free", 1), ("clamped-free", 4), ("fe", 3), ("fe", 6),
                                         ("polynomial", 4)])
def test_point_rule_reproduces_the_foreshortening_integrals(kind, count):
    """The second-order model's point rule (u at Gauss points by the integration matrix) against the
    double integrals ∫₀ᴸ∫₀ˣ φ'φ'ᵀ and ∫₀ᴸ x∫₀ˣ φ'φ'ᵀ, which ShapeIntegrals forms by swapping the order of
    integration (a different route): exact for the piecewise-cubic elements and polynomials, converged for
    the eigenfunctions; and the weights integrate φφᵀ."""
    basis = make_basis(kind, count, 1.3, 0.7)
    rule, g = basis.points, basis.integrals
    to_x = rule.local + rule.start @ rule.panel_sums          # ∫₀^{x_k} f = Σ_j to_x[k, j] f(x_j)
    F = np.einsum("kj,ja,jb->kab", to_x, rule.slope, rule.slope)
    tol = 1e-12 if kind == "clamped-free" else 1e-14
    np.testing.assert_allclose(np.einsum("k,kab->ab", rule.w, F), g.fs, atol=tol * np.abs(g.fs).max())
    np.testing.assert_allclose(np.einsum("k,kab->ab", rule.w * rule.x, F), g.fs_x, atol=tol * np.abs(g.fs_x).max())
    np.testing.assert_allclose(rule.phi.T @ (rule.w[:, None] * rule.phi), g.phi_phi,
                               atol=tol * np.abs(g.phi_phi).max())
