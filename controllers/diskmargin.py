"""The multi-loop (simultaneous) disk margin at the plant input, from the structured singular value μ.

Independent gain and phase variations at every actuator at once, computed in numpy/scipy (Slycot's μ is
not used: see below).

**What it is.**  Each actuator's torque is multiplied by its own factor ``f_i = (1 + δ_i/2)/(1 − δ_i/2)``
(balanced skew, σ = 0), ``|δ_i| < α``: a disk in the complex plane around 1 that holds the gains within
``[(2 − α)/(2 + α), (2 + α)/(2 − α)]`` together with phases within ``±2 atan(α/2)``.  With the loop ``L`` at
the plant input and ``S = (I + L)⁻¹``, the loop with these factors is ``det(I + L F) = det(I + L) ·
det(I − (S − I/2) Δ) / det(I − Δ/2)``, so the loop loses stability first where ``det(I − M Δ) = 0``,
``M = S − I/2 = (S − T)/2``, ``Δ = diag(δ_i)`` complex: the margin is ``α = 1 / max_ω μ_Δ(M(jω))``, the form
python-control documents for ``control.disk_margins`` (``S + (skew − 1)/2 I``, whose MIMO branch calls
Slycot's ``ab13md``, not installed here: Slycot changes the designs through ``dlqr`` and its μ did not
finish on the six-axis arm).  With one actuator it is the loop-at-a-time disk margin ``1/‖S − ½‖∞``.

**Bounds.**  For m scalar complex blocks, μ lies between

* the lower bound ``ρ(M Q)`` for any diagonal unitary Q (μ is its maximum over Q): a power iteration
  (Packard and Doyle, "The complex structured singular value", Automatica 1993, for scalar blocks) gives Q,
  polished by a local maximisation over the phases (:func:`mu_lower`); it comes with the destabilising
  perturbation ``Δ = Q/λ`` (λ the eigenvalue of M Q of largest modulus): ``det(I − M Δ) = 0`` with
  ``|δ_i| = 1/ρ``;
* the upper bound ``min_D σ̄(D M D⁻¹)`` over positive diagonal D, convex in log D (:func:`mu_upper`): BFGS
  with the singular vectors' gradient ``σ (|u_i|² − |v_i|²)``, then Nelder–Mead where σ̄ is not smooth.
  It equals μ for m ≤ 3 (Doyle 1982); beyond, both bounds are reported.

**Over frequency** (:func:`multiloop_disk_margin`): the lower bound on the whole grid at once (the power
iteration batched in numpy), the cheap upper bounds ``σ̄(M)`` and ``σ̄`` with Osborne's scaling at once,
the optimal D-scaling only where a cheap bound exceeds the best optimal one found so far (in decreasing
order: a frequency whose cheap bound is below cannot hold the peak), then both bounds refined between the
peak's neighbouring grid points (bounded scalar search on the response evaluated there).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar

__all__ = ["MultiLoopMargin", "balanced_sensitivity", "disk_gain_phase", "mu_lower", "mu_upper",
           "multiloop_disk_margin"]

#: Above this many actuators the D-scaled upper bound may exceed μ (Doyle 1982): both bounds are reported.
EXACT_BLOCKS = 3


def balanced_sensitivity(Tw: np.ndarray) -> np.ndarray:
    """The balanced sensitivity ``M = S − I/2`` at each frequency.

    From ``T = K_c P`` (torques in → torques asked, positive feedback
    ``u = T u``; the loop in python-control's negative convention is ``L = −T``, ``S = (I − T)⁻¹``).

    Parameters
    ----------
    Tw : (N, m, m) complex array
        T's frequency response.

    Returns
    -------
    (N, m, m) complex array
        The balanced sensitivity (S − T)/2 at each frequency.
    """
    m = Tw.shape[-1]
    eye = np.eye(m)
    return np.linalg.inv(eye[None] - Tw) - 0.5 * eye[None]


def disk_gain_phase(alpha: float) -> tuple[float, float]:
    """The balanced disk's gain margin (dB) and phase margin (deg) from its size α.

    As ``control.disk_margins`` states them: gains within ``(2 ± α)/(2 ∓ α)`` (unbounded upwards from α ≥ 2),
    phases within ``±2 atan(α/2)`` (90° from α ≥ 2).
    """
    if not np.isfinite(alpha) or alpha >= 2.0:
        return math.inf, 90.0
    if alpha <= 0.0:
        return 0.0, 0.0
    return 20.0 * math.log10((2.0 + alpha) / (2.0 - alpha)), math.degrees(2.0 * math.atan(alpha / 2.0))


def _sigma_scaled(lam: np.ndarray, M: np.ndarray) -> tuple[float, np.ndarray]:
    """σ̄(D M D⁻¹) with ``D = diag(e^λ)`` (λ_0 = 0 fixed) and its gradient in λ_1…, ``σ (|u_i|² − |v_i|²)``."""
    d = np.exp(np.concatenate([[0.0], lam]))
    N = d[:, None] * M / d[None, :]
    U, s, Vh = np.linalg.svd(N)
    u, v = U[:, 0], Vh[0].conj()
    return float(s[0]), (s[0] * (np.abs(u) ** 2 - np.abs(v) ** 2))[1:]


def _osborne(M: np.ndarray, sweeps: int = 8) -> np.ndarray:
    """Osborne's balancing of |M|: log-scalings λ (λ_0 = 0).

    log-scalings λ (λ_0 = 0) of Osborne's balancing of |M| (row and column norms made equal), the
    minimiser of the Frobenius norm of D M D⁻¹: the start of the σ̄ minimisation, a cheap upper bound on
    its own.  Works on a batch (…, m, m).
    """
    A = np.abs(M) ** 2
    m = A.shape[-1]
    lam = np.zeros(A.shape[:-1])
    off = 1.0 - np.eye(m)
    for _ in range(sweeps):
        for i in range(m):
            d = np.exp(2.0 * lam)
            col = np.sum(A[..., :, i] * off[:, i] * d, axis=-1) / d[..., i]       # Σ_k |m_ki|² d_k²/d_i²
            row = np.sum(A[..., i, :] * off[i] / d, axis=-1) * d[..., i]          # Σ_k |m_ik|² d_i²/d_k²
            ok = (col > 0) & (row > 0)
            lam[..., i] += np.where(ok, 0.25 * np.log(np.where(ok, col, 1.0) / np.where(ok, row, 1.0)), 0.0)
    return lam - lam[..., :1]


def mu_upper(M: np.ndarray, enough: float = -math.inf) -> tuple[float, np.ndarray]:
    """The D-scaled upper bound of μ over diagonal complex scalar blocks, ``min_D σ̄(D M D⁻¹)``.

    Parameters
    ----------
    M : (m, m) complex array
    enough : float, optional
        Stop as soon as the bound is at or below this (the search over frequency needs no tighter bound
        where it is already below the peak found).

    Returns
    -------
    float
        The bound (equal to μ for m ≤ 3).
    (m,) array
        The scaling D reaching it (D_0 = 1).
    """
    M = np.asarray(M, dtype=complex)
    m = M.shape[0]
    if m == 1:
        return float(abs(M[0, 0])), np.ones(1)
    lam0 = _osborne(M)[1:]

    def f(lam: np.ndarray) -> float:
        return _sigma_scaled(lam, M)[0]

    best = minimize(lambda x: _sigma_scaled(x, M), lam0, jac=True, method="BFGS", options={"gtol": 1e-12})
    x = best.x if best.fun <= f(lam0) else lam0
    if f(x) <= enough:
        pass
    elif m == 2:                               # one variable: a bracketing search is exact on the non-smooth
        r = minimize_scalar(lambda t: f(np.array([t])), bracket=(x[0] - 0.1, x[0] + 0.1), tol=1e-12)
        if r.fun < f(x):
            x = np.array([r.x])
    else:                                    # where σ̄ is a double singular value BFGS stops short
        r = minimize(f, x, method="Nelder-Mead", options={"xatol": 1e-11, "fatol": 1e-15, "maxiter": 4000})
        if r.fun < f(x):
            x = r.x
    return f(x), np.exp(np.concatenate([[0.0], x]))


def _power_lower(M: np.ndarray, iterations: int = 60) -> np.ndarray:
    """The power iteration's lower bound of μ for scalar complex blocks, batched.

    Diagonal unitary Q (as phases, shape (…, m)) from the power iteration for scalar complex blocks,
    batched over frequencies: ``M b = β a``, ``z = ∠a |w|``, ``Mᴴ z = β w``, ``b = ∠w |a|``; at its fixed
    point ``M Q a = β a`` with ``Q = ∠w ∠ā``.
    """
    shape = M.shape[:-1]
    rng = np.random.default_rng(0)
    b = np.ones(shape, dtype=complex) + 0.1 * rng.standard_normal(shape)
    w = b.copy()

    def unit(x: np.ndarray) -> np.ndarray:
        return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-300)

    def phase(x: np.ndarray) -> np.ndarray:
        return np.exp(1j * np.angle(x))

    a = b
    for _ in range(iterations):
        a = unit((M @ b[..., None])[..., 0])
        z = unit(phase(a) * np.abs(w))
        w = unit((np.swapaxes(M.conj(), -1, -2) @ z[..., None])[..., 0])
        b = unit(phase(w) * np.abs(a))
    return np.angle(w) - np.angle(a)


def _rho(theta: np.ndarray, M: np.ndarray) -> tuple[float, complex, np.ndarray]:
    """ρ(M Q), Q = diag(e^{jθ}), its eigenvalue of largest modulus and Q."""
    q = np.exp(1j * theta)
    ev = np.linalg.eigvals(M * q[None, :])
    k = int(np.argmax(np.abs(ev)))
    return float(abs(ev[k])), complex(ev[k]), q


def mu_lower(M: np.ndarray, theta0: np.ndarray | None = None, polish: bool = True,
             enough: float = math.inf) -> tuple[float, np.ndarray]:
    """A lower bound of μ with its destabilising perturbation.

    Parameters
    ----------
    M : (m, m) complex array
    theta0 : (m,) array, optional
        Phases to start from (default: the power iteration's).
    polish : bool
        Maximise ρ over the phases from there (Nelder–Mead); without, the power iteration's bound.
    enough : float, optional
        No polish when the start reaches this (an upper bound: the lower bound is then μ).

    Returns
    -------
    float
        ``β = ρ(M Q) ≤ μ(M)``, Q polished by Nelder–Mead over its phases (the first fixed).
    (m,) complex array
        ``δ`` with ``det(I − M diag(δ)) = 0`` and every ``|δ_i| = 1/β``.
    """
    M = np.asarray(M, dtype=complex)
    m = M.shape[0]
    theta = _power_lower(M) if theta0 is None else np.asarray(theta0, dtype=float)
    if m > 1 and polish and _rho(theta, M)[0] < enough * (1 - 1e-12):
        def neg(t: np.ndarray) -> float:
            return -_rho(np.concatenate([[theta[0]], t]), M)[0]

        r = minimize(neg, theta[1:], method="Nelder-Mead",
                     options={"xatol": 1e-11, "fatol": 1e-15, "maxiter": 400 * m})
        if r.fun < neg(theta[1:]):
            theta = np.concatenate([[theta[0]], r.x])
    beta, lam, q = _rho(theta, M)
    return beta, q / lam


@dataclass
class MultiLoopMargin:
    """The simultaneous balanced disk margin at the plant input (module docstring).

    ``alpha`` is guaranteed (``1/max μ_upper``: every simultaneous perturbation with all ``|δ_i| < alpha``
    leaves the loop stable); ``alpha_upper`` (``1/max μ_lower``) is the size of ``delta``, a perturbation
    that puts a closed-loop pole on the stability boundary at ``omega`` (rad/s).  ``exact``: the two agree
    to 1e-9, the margin is then the margin itself, not a bound (μ reached: always so in theory for up to
    :data:`EXACT_BLOCKS` actuators, where the D-scaled bound is μ).
    """

    alpha: float
    alpha_upper: float
    omega: float
    delta: np.ndarray
    exact: bool

    def figures(self) -> dict[str, float | bool]:
        """The JSON entries of the margin.

        ``disk_margin`` (guaranteed), ``disk_margin_upper``, the disk's gain (dB) and
        phase (deg) margins from ``disk_margin``, its frequency (Hz), and whether the two bounds agree.
        """
        gm, pm = disk_gain_phase(self.alpha)
        return {"disk_margin": self.alpha, "disk_margin_upper": self.alpha_upper, "disk_gain_margin_db": gm,
                "disk_phase_margin_deg": pm, "disk_margin_hz": self.omega / (2 * math.pi), "exact": self.exact}


def _refine(evaluate: Callable[[np.ndarray], np.ndarray], w: np.ndarray, k: int) -> tuple[float, float, float]:
    """Between the grid's neighbours of point k: the frequency maximising the lower bound and both bounds there."""
    lo, hi = w[max(k - 1, 0)], w[min(k + 1, len(w) - 1)]
    if not hi > lo:
        return w[k], -math.inf, -math.inf

    def at(x: float) -> np.ndarray:
        return balanced_sensitivity(evaluate(np.array([x])))[0]

    r = minimize_scalar(lambda x: -mu_lower(at(x), polish=False)[0], bounds=(lo, hi), method="bounded",
                        options={"xatol": 1e-10 * hi})
    Mx = at(float(r.x))
    up = mu_upper(Mx, enough=-r.fun * (1 + 1e-12))[0]
    return float(r.x), mu_lower(Mx, enough=up)[0], up


def multiloop_disk_margin(Tw: np.ndarray, w: np.ndarray, evaluate: Callable[[np.ndarray], np.ndarray],
                          T_inf: np.ndarray | None = None) -> MultiLoopMargin:
    """The simultaneous balanced disk margin of the loop ``u = T u`` at its inputs.

    Parameters
    ----------
    Tw : (N, m, m) complex array
        T's response on the grid w.
    w : (N,) array
        Frequencies, rad/s, ascending.
    evaluate : callable
        T's response at other frequencies (same shape convention), for the refinement around the peak.
    T_inf : (m, m) array, optional
        A continuous T's feedthrough, its value at ω = ∞ (the end of the grid).

    Returns
    -------
    MultiLoopMargin
    """
    M = balanced_sensitivity(Tw)
    theta = _power_lower(M)
    q = np.exp(1j * theta)
    lower = np.max(np.abs(np.linalg.eigvals(M * q[:, None, :])), axis=-1)
    d = np.exp(_osborne(M))
    cheap = np.minimum(np.linalg.norm(M, 2, axis=(-2, -1)),
                       np.linalg.norm(d[..., :, None] * M / d[..., None, :], 2, axis=(-2, -1)))
    k_lo = int(np.argmax(lower))
    upper, k_up = mu_upper(M[k_lo], enough=lower[k_lo] * (1 + 1e-12))[0], k_lo
    best_lo, delta = mu_lower(M[k_lo], theta[k_lo], enough=upper)
    for k in np.argsort(-cheap):
        if cheap[k] <= upper:
            break
        u = mu_upper(M[k], enough=max(upper, lower[k] * (1 + 1e-12)))[0]
        if u > upper:
            upper, k_up = u, int(k)
    omega = float(w[k_lo])
    for k in sorted({k_lo, k_up}):
        wr, lo_r, up_r = _refine(evaluate, w, k)
        upper = max(upper, up_r)
        if lo_r > best_lo:
            best_lo, delta = mu_lower(balanced_sensitivity(evaluate(np.array([wr])))[0], enough=up_r)
            omega = wr
    if T_inf is not None:                    # ω → ∞: S = (I − D)⁻¹
        M_inf = balanced_sensitivity(np.asarray(T_inf, dtype=complex)[None])[0]
        up_inf = mu_upper(M_inf)[0]
        upper = max(upper, up_inf)
        lo_inf, d_inf = mu_lower(M_inf, enough=up_inf)
        if lo_inf > best_lo:
            best_lo, delta, omega = lo_inf, d_inf, math.inf
    upper = max(upper, best_lo)              # the optimisers' tolerance: never a guarantee above a counterexample
    return MultiLoopMargin(1.0 / upper if upper > 0 else math.inf, 1.0 / best_lo if best_lo > 0 else math.inf,
                           omega, delta, bool(best_lo >= upper * (1 - 1e-9)))
