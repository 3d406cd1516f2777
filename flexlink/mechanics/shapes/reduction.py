"""Reduction of a finite-element link to the modes a scene needs (issue 9).

The link is clamped to its joint frame, so its interface (the root nodes) is held: the fixed-interface
modes of Craig–Bampton.  Craig–Bampton's constraint modes of that interface are the rigid motions of the
frame itself, which the floating-frame model already carries as the joint coordinates, so the reduced
basis is the first N fixed-interface modes.  Degrees of freedom that carry no mass (the rotations of a
DKT plate whose mass is interpolated from w alone, the drilling rotations) are condensed statically
first: with no inertia they follow the massive ones exactly (K_ss x_s = −K_sm x_m), so the condensation
changes nothing but the size of the eigenproblem.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.linalg
import scipy.sparse

from .base import ShapeBasis, ShapeIntegrals
from .torsion import TorsionBasis, TorsionIntegrals


@dataclass(frozen=True)
class ModalBasis:
    """Ψ (n_dof × N), M-orthonormal columns, with their ω² in ascending order."""

    omega2: np.ndarray
    shapes: np.ndarray

    @property
    def frequencies_hz(self) -> np.ndarray:
        """The natural frequencies ω/2π of the modes (Hz); a round-off negative ω² counts as zero."""
        return np.sqrt(np.maximum(self.omega2, 0.0)) / (2 * np.pi)


def _dense(a: npt.ArrayLike | scipy.sparse.sparray | scipy.sparse.spmatrix) -> np.ndarray:
    """A dense float copy of a (possibly sparse) FE matrix: the condensation and eigh below need dense."""
    if isinstance(a, (scipy.sparse.sparray, scipy.sparse.spmatrix)):
        return a.toarray()
    return np.asarray(a, dtype=float)


def fixed_interface_modes(
    stiffness: npt.ArrayLike | scipy.sparse.sparray | scipy.sparse.spmatrix,
    mass: npt.ArrayLike | scipy.sparse.sparray | scipy.sparse.spmatrix,
    count: int | None = None,
) -> ModalBasis:
    """The first ``count`` (all if None) modes of K x = ω² M x on the free degrees of freedom.

    ``stiffness`` and ``mass`` are symmetric, K positive definite (the interface already removed);
    M may be singular, but only through degrees of freedom with no mass at all.
    """
    K = _dense(stiffness)
    M = _dense(mass)
    n = K.shape[0]
    if K.shape != (n, n) or M.shape != (n, n):
        raise ValueError(f"stiffness and mass must be square and of the same size, got {K.shape} and {M.shape}")
    scale = np.max(np.abs(M)) if M.size else 0.0
    massive = np.flatnonzero(np.max(np.abs(M), axis=1) > 1e-14 * scale) if scale > 0 else np.arange(0)
    massless = np.setdiff1d(np.arange(n), massive)
    if massive.size == 0:
        raise ValueError("the link has no mass")
    Kmm = K[np.ix_(massive, massive)]
    if massless.size:
        Kss = K[np.ix_(massless, massless)]
        Ksm = K[np.ix_(massless, massive)]
        recover = -scipy.linalg.cho_solve(scipy.linalg.cho_factor(Kss), Ksm)
        Kmm = Kmm + K[np.ix_(massive, massless)] @ recover
        Kmm = 0.5 * (Kmm + Kmm.T)
    m = massive.size
    count = m if count is None else int(count)
    if not 1 <= count <= m:
        raise ValueError(f"modes must be between 1 and {m} (the link's degrees of freedom with mass), got {count}")
    w2, X = scipy.linalg.eigh(Kmm, M[np.ix_(massive, massive)], subset_by_index=[0, count - 1])
    shapes = np.zeros((n, count))
    shapes[massive] = X
    if massless.size:
        shapes[massless] = recover @ X
    return ModalBasis(w2, shapes)


def _unit_peak(values: np.ndarray, shapes: np.ndarray) -> np.ndarray:
    """Scale each mode to a peak displacement of one, the sign making that peak positive.

    Then η is in metres (or radians) like the FE coordinates it replaces, whatever the density.
    """
    peak = values[np.argmax(np.abs(values), axis=0), np.arange(values.shape[1])]
    return shapes / np.where(peak != 0, peak, 1.0)


class ModalBeamBasis(ShapeBasis):
    """The first ``modes`` clamped modes of a Hermite FE beam, as a shape family of their own.

    The integrals are those of the FE basis projected on the modes (exact), so the model keeps the FE
    accuracy of those modes with far fewer coordinates.
    """

    def __init__(self, fe: ShapeBasis, modes: int):
        super().__init__(fe.count, fe.length, fe.linear_density)
        g = fe.integrals
        basis = fixed_interface_modes(g.curv, g.phi_phi, modes)
        nodes = np.linspace(0.0, fe.length, 4 * fe.count + 1)
        self.fe = fe
        self.modes = basis.shapes.shape[1]
        self.psi = _unit_peak(fe.evaluate(nodes) @ basis.shapes, basis.shapes)
        self.kind = f"{fe.kind} ({self.modes} modes)"

    @property
    def n(self) -> int:
        """Number of modal coordinates: the modes kept."""
        return self.modes

    def _evaluate(self, x: np.ndarray, derivative: int) -> np.ndarray:
        return self.fe._evaluate(x, derivative) @ self.psi

    def _quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        return self.fe._quadrature()

    def panel_edges(self) -> np.ndarray:
        """The FE nodes: the modes are piecewise cubics on the same elements."""
        return self.fe.panel_edges()

    @functools.cached_property
    def integrals(self) -> ShapeIntegrals:
        """The projected integrals, with ∫φφᵀ and ∫φ''φ''ᵀ diagonal as the modes make them.

        The modes solve the generalised eigenproblem of these very FE matrices, so both projections are diagonal
        in exact arithmetic; computed, their off-diagonal entries are the eigensolver's error (up to 1e-10 of
        √(G_ii G_jj)), which would otherwise depend on the machine's BLAS and cost an operation each in every
        generated function.
        """
        g = ShapeBasis.integrals.func(self)     # type: ignore[attr-defined]
        diagonal = {}
        for name in ("phi_phi", "curv"):
            m = np.diag(np.diag(getattr(g, name)))
            m.setflags(write=False)
            diagonal[name] = m
        return dataclasses.replace(g, **diagonal)

    def nodal_basis(self) -> tuple[ShapeBasis, np.ndarray]:
        """The Hermite elements and the modes in their nodal coordinates (φ = φ_FE Ψ)."""
        return self.fe, self.psi


class ModalTorsionBasis:
    """The first ``modes`` clamped twist modes of linear torsion elements (see ModalBeamBasis)."""

    def __init__(self, fe: TorsionBasis, modes: int):
        g = fe.integrals
        basis = fixed_interface_modes(g.stiff, g.phi_phi, min(modes, fe.n))
        self.fe, self.kind, self.count, self.length = fe, fe.kind, fe.count, fe.length
        self.psi = _unit_peak(fe.evaluate(np.linspace(0.0, fe.length, fe.count + 1)) @ basis.shapes, basis.shapes)

    @property
    def n(self) -> int:
        """Number of modal twist coordinates (at most the elements' own count)."""
        return int(self.psi.shape[1])

    def evaluate(self, x: npt.ArrayLike, derivative: int = 0) -> np.ndarray:
        """d^k φ/dx^k of the modes at ``x``: the element shapes combined by Ψ, shape (len(x), n)."""
        return self.fe.evaluate(x, derivative) @ self.psi

    @functools.cached_property
    def integrals(self) -> TorsionIntegrals:
        """The element integrals projected on the modes (exact), computed once."""
        g, P = self.fe.integrals, self.psi
        return TorsionIntegrals(phi_phi=P.T @ g.phi_phi @ P, phi=g.phi @ P, stiff=P.T @ g.stiff @ P, tip=g.tip @ P)
