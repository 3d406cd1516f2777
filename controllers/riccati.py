"""LQR and Kalman gains and the zero-order-hold sampling, on SciPy's linear algebra alone (issue 22).

Why a module of its own: ``import control`` costs 1.2–1.5 s on the project's machines (SciPy's signal and
stats, matplotlib's pyplot: docs/performance.md, "Start-up of the commands"), more than a designing
``flexlink control`` may spend before its first FMU call (≤ 1 s), while the design functions it would be
imported for are thin layers over SciPy.  With ``method="scipy"`` (the method the designs have always
asked for, so that a design does not change with whether Slycot is installed), python-control 0.10 computes

* ``control.lqr``: ``scipy.linalg.solve_continuous_are``, then ``K = R⁻¹ Bᵀ X`` and the eigenvalues of
  ``A − B K``;
* ``control.dlqr``: ``scipy.linalg.solve_discrete_are`` (cross term ``N = 0``), then
  ``K = (Bᵀ X B + R)⁻¹ (Bᵀ X A + Nᵀ)`` and the eigenvalues of ``A − B K``;
* ``control.lqe`` / ``control.dlqe``: the same two on the dual problem ``(Aᵀ, Cᵀ, G QN Gᵀ, RN)``, the gain
  transposed;
* ``control.sample_system(method="zoh")``: ``scipy.signal.cont2discrete``, the exponential of the block
  matrix ``dt [[A, B], [0, 0]]``.

The functions here make the same calls on the same arrays in the same order, so that their results are
python-control's to the last bit: ``tests/test_riccati.py`` checks that against python-control on the
example plants and on random ones, an independent implementation of the same formulas.  python-control is
imported only by what needs its systems (margins, closed-loop predictions, plots, exports), after a
command's first FMU call.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:          # python-control only where its system is asked for (SampledSystem.sys)
    import control as ct

__all__ = ["SampledSystem", "dlqe", "dlqr", "lqe", "lqr", "zoh"]


def _matrix(M, n: int, m: int, name: str, symmetric: bool = False) -> np.ndarray:
    """``M`` as a float matrix of shape (n, m), refused (ValueError) otherwise or when not symmetric.

    The symmetry test is python-control's (``M − Mᵀ < ε`` entry by entry), so that a weight it refuses is
    refused here too.
    """
    M = np.array(M, ndmin=2, dtype=float)
    if M.shape != (n, m):
        raise ValueError(f"{name} must be {n}x{m}, got {M.shape[0]}x{M.shape[1]}")
    if symmetric and not ((M - M.T) < np.finfo(M.dtype).eps).all():
        raise ValueError(f"{name} must be a symmetric matrix")
    return M


def _care(A, B, Q, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, eigenvalues of A − B K, K) of the continuous algebraic Riccati equation, ``K = R⁻¹ Bᵀ X``."""
    import scipy.linalg

    A, B, Q, R = (np.array(M, ndmin=2) for M in (A, B, Q, R))
    n, m = B.shape
    _matrix(A, n, n, "A")
    _matrix(Q, n, n, "Q", symmetric=True)
    _matrix(R, m, m, "R", symmetric=True)
    X = scipy.linalg.solve_continuous_are(A, B, Q, R)
    K = np.linalg.solve(R, B.T @ X)
    E, _ = np.linalg.eig(A - B @ K)
    return X, E, K


def _dare(A, B, Q, R, S=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, eigenvalues of A − B K, K) of the discrete one, ``K = (Bᵀ X B + R)⁻¹ (Bᵀ X A + Sᵀ)``."""
    import scipy.linalg

    A, B, Q, R = (np.array(M, ndmin=2) for M in (A, B, Q, R))
    n, m = B.shape
    _matrix(A, n, n, "A")
    _matrix(Q, n, n, "Q", symmetric=True)
    _matrix(R, m, m, "R", symmetric=True)
    if S is not None:
        S = _matrix(np.array(S, ndmin=2), n, m, "N")
    X = scipy.linalg.solve_discrete_are(A, B, Q, R, e=None, s=S)
    rhs = B.T @ X @ A if S is None else B.T @ X @ A + S.T
    K = scipy.linalg.solve(B.T @ X @ B + R, rhs)
    return X, scipy.linalg.eigvals(A - B @ K), K


def lqr(A, B, Q, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous LQR ``u = −K x`` minimising ∫ xᵀQx + uᵀRu: (K, X, closed-loop poles), ``control.lqr``'s.

    Raises ValueError or ``numpy.linalg.LinAlgError`` when there is no stabilising solution (SciPy's).
    """
    A, B = np.array(A, ndmin=2, dtype=float), np.array(B, ndmin=2, dtype=float)
    X, E, K = _care(A, B, np.array(Q, ndmin=2, dtype=float), np.array(R, ndmin=2, dtype=float))
    return K, X, E


def dlqr(A, B, Q, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete LQR ``u_k = −K x_k`` minimising Σ xᵀQx + uᵀRu: (K, X, closed-loop poles), ``control.dlqr``'s."""
    A, B = np.array(A, ndmin=2, dtype=float), np.array(B, ndmin=2, dtype=float)
    Q, R = np.array(Q, ndmin=2, dtype=float), np.array(R, ndmin=2, dtype=float)
    X, E, K = _dare(A, B, Q, R, np.zeros((Q.shape[0], R.shape[1])))
    return K, X, E


def _dual(A, G, C, QN, RN) -> tuple[np.ndarray, ...]:
    A, G, C = (np.array(M, ndmin=2, dtype=float) for M in (A, G, C))
    QN, RN = np.array(QN, ndmin=2, dtype=float), np.array(RN, ndmin=2, dtype=float)
    _matrix(QN, G.shape[1], G.shape[1], "QN")
    return A.T, C.T, G @ QN @ G.T, RN


def lqe(A, G, C, QN, RN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous Kalman gain of ``ẋ = A x + G w``, ``y = C x + v`` (covariances QN, RN): (L, P, poles of A − LC).

    ``control.lqe``'s: the LQR of the dual problem, its gain transposed.
    """
    P, E, LT = _care(*_dual(A, G, C, QN, RN))
    return LT.T, P, E


def dlqe(A, G, C, QN, RN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete (predictor) Kalman gain of ``x⁺ = A x + G w``, ``y = C x + v``: (L, P, poles), ``control.dlqe``'s."""
    P, E, LT = _dare(*_dual(A, G, C, QN, RN))
    return LT.T, P, E


def zoh(A, B, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A_d, B_d)`` of ``ẋ = A x + B u`` sampled with a zero-order hold at ``dt``.

    The upper blocks of ``expm(dt [[A, B], [0, 0]])``: ``A_d = e^{A dt}``, ``B_d = ∫₀^dt e^{Aτ} dτ B``
    (``scipy.signal.cont2discrete``'s arithmetic, which ``control.sample_system`` calls).
    """
    import scipy.linalg

    a, b = np.array(A, ndmin=2, dtype=float), np.array(B, ndmin=2, dtype=float)
    if b.shape[0] != a.shape[0]:
        b = b.reshape(a.shape[0], -1)
    n, m = b.shape
    em = np.vstack((np.hstack((a, b)), np.hstack((np.zeros((m, n)), np.zeros((m, m))))))
    ms = scipy.linalg.expm(dt * em)[:n, :]
    return np.array(ms[:, :n], dtype=float), np.array(ms[:, n:], dtype=float)


@dataclass
class SampledSystem:
    """A plant sampled at ``dt``: ``x⁺ = A x + B u``, ``y = C x + D u``, with its signal names.

    What the sampled laws, the references and the controller FMU read of a sampled plant (``A``, ``B``,
    ``dt``, ``nstates``) without python-control; ``sys`` is python-control's system with the same
    matrices and names (``control.sample_system`` of the continuous one), built on first use for the
    analyses that need it.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float
    name: str = ""
    states: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)

    @classmethod
    def sample(cls, A, B, C, D, dt: float, **names) -> SampledSystem:
        """The continuous system ``(A, B, C, D)`` sampled with a zero-order hold (:func:`zoh`), C and D kept."""
        Ad, Bd = zoh(A, B, dt)
        return cls(Ad, Bd, np.array(C, ndmin=2, dtype=float), np.array(D, ndmin=2, dtype=float), float(dt), **names)

    @property
    def nstates(self) -> int:
        """The number of states (python-control's name for it)."""
        return int(self.A.shape[0])

    @functools.cached_property
    def sys(self) -> ct.StateSpace:
        """The discrete ``control.StateSpace`` (python-control imported here), signal names kept."""
        import control as ct

        names = {k: v for k, v in (("states", self.states), ("inputs", self.inputs), ("outputs", self.outputs)) if v}
        return ct.ss(self.A, self.B, self.C, self.D, self.dt, name=self.name or None, **names)
