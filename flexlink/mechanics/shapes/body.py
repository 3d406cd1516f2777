"""A finite-element link brought into the floating frame: the constant integrals of its reduced basis.

The displacement field of a shell link is u(X) = Φ(X) η over its mid-surface, Φ the fixed-interface modes
(:mod:`flexlink.mechanics.shapes.reduction`).  Everything the kinetic and gravitational energies need is then a sum
over the mesh's mass points (docs/shells.md, seed 001 §5.7), computed once here, per unit density:

    V = Σ m,  ∫X,  ∫X Xᵀ,  S = ∫Φ,  B_ab = ∫X_a Φ_b,  C_ab = ∫Φ_aᵀ Φ_b  (a, b ∈ x, y, z).

The mass points are exact for the linear interpolation of the translations, so these are the integrals of
the discrete model itself, not an approximation of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from flexlink.scene.loader import Link

from .reduction import ModalBasis, _unit_peak, fixed_interface_modes

if TYPE_CHECKING:  # shell.py is imported only when a scene has a shell link
    from .shell import ShellAssembly


@dataclass(frozen=True)
class BodyIntegrals:
    """Constant integrals of one reduced FE link, for unit density and unit Young's modulus."""

    volume: float
    first: np.ndarray            # (3,)        ∫ X dV
    second: np.ndarray           # (3, 3)      ∫ X Xᵀ dV
    modal: np.ndarray            # (3, N)      ∫ Φ dV
    x_modal: np.ndarray          # (3, 3, N)   [a, b] = ∫ X_a Φ_b dV
    pairs: np.ndarray            # (3, 3, N, N) [a, b] = ∫ Φ_aᵀ Φ_b dV
    stiffness: np.ndarray        # (N, N)      Ψᵀ K Ψ / E
    tip_point: np.ndarray        # (3,)        undeformed tip point (mid-point of the free edge / section centre)
    tip_translation: np.ndarray  # (3, N)      its displacement
    tip_rotation: np.ndarray     # (3, N)      rotation vector of the free end section (twist = component x)
    root_moment: np.ndarray      # (N,)        elastic bending moment at the root about the joint axis z, per unit E
    frequencies_hz: np.ndarray   # (N,)        of the link alone, joint held, at the scene's E and density

    @property
    def n(self) -> int:
        """Number of modal coordinates η of the link."""
        return int(self.stiffness.shape[0])

    @property
    def mass_matrix(self) -> np.ndarray:
        """∫ΦᵀΦ dV per unit density: the elastic block of the mass matrix with the joint held."""
        return self.pairs[0, 0] + self.pairs[1, 1] + self.pairs[2, 2]


def shell_assembly(link: Link) -> ShellAssembly:
    """The scene's shell mesh, assembled (seed 001 §5.2–5.6).

    The scene loader has checked that ``shapes.mesh`` holds three counts for a box and two for a plate.
    """
    from .shell import assemble_shell, box_mesh, plate_mesh

    s = link.shapes
    if s.section == "box":
        nx, nw, nh = s.mesh
        mesh = box_mesh(link.length, s.width, s.height, nx, nw, nh, pattern=s.pattern)
    else:
        nx, nw = s.mesh
        mesh = plate_mesh(link.length, s.width, nx, nw, pattern=s.pattern)
    return assemble_shell(mesh, s.thickness, link.E, link.poisson, link.density)


def _end_section(
    assembly: ShellAssembly, Psi_full: np.ndarray, section: str | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tip point (3,) and the rows (3, N) of its translation and of the end section's rotation vector.

    A rigid fit of the end nodes' displacements (the twist from the edge corners), the bending slope of a
    plate from its nodes' rotations (a flat section has no extent along its normal to fit it from).
    """
    mesh = assembly.mesh
    X = mesh.nodes
    end = np.flatnonzero(np.abs(X[:, 0] - X[:, 0].max()) < 1e-9 * max(1.0, X[:, 0].max()))
    disp = np.stack([Psi_full[[assembly.dof(k, c) for k in end]] for c in range(3)], axis=1)   # (e, 3, N)
    rot = np.stack([Psi_full[[assembly.dof(k, 3 + c) for k in end]] for c in range(3)], axis=1)
    centre = X[end].mean(axis=0)
    d = X[end] - centre
    # u_i = t + r × d_i: least squares over the end nodes, per mode
    rows = []
    for di in d:
        rows.append(np.hstack([np.eye(3), -np.array([[0, -di[2], di[1]], [di[2], 0, -di[0]], [-di[1], di[0], 0]])]))
    A = np.vstack(rows)
    spread = np.linalg.norm(A[:, 3:], axis=0) > 1e-12
    fit = np.linalg.lstsq(A[:, np.r_[0:3, 3 + np.flatnonzero(spread)]], disp.reshape(-1, disp.shape[2]), rcond=None)[0]
    rotation = rot.mean(axis=0)
    rotation[np.flatnonzero(spread)] = fit[3:]
    if section == "plate":
        mid = end[np.argsort(np.abs(X[end, 2]))]
        mid = mid[np.abs(np.abs(X[mid, 2]) - np.abs(X[mid[0], 2])) < 1e-9]      # the middle node, or the two
        point = X[mid].mean(axis=0)
        translation = np.mean([disp[list(end).index(k)] for k in mid], axis=0)
    else:
        point, translation = centre, fit[:3]
    return point, translation, rotation


def shell_body(link: Link) -> BodyIntegrals:
    """Reduce the link's shell model to ``shapes.modes`` fixed-interface modes (all if not given)."""
    assembly = shell_assembly(link)
    free = assembly.free_dofs
    K = assembly.stiffness[free][:, free]
    M = assembly.mass[free][:, free]
    basis: ModalBasis = fixed_interface_modes(K, M, link.shapes.modes)
    Psi = np.zeros((assembly.stiffness.shape[0], basis.shapes.shape[1]))
    Psi[free] = basis.shapes
    point, translation, rotation = _end_section(assembly, Psi, link.shapes.section)
    # η in metres: each mode scaled to a peak translation of one over the mesh
    trans = Psi.reshape(-1, 6, Psi.shape[1])[:, :3].reshape(-1, Psi.shape[1])
    scaled = _unit_peak(trans, np.eye(Psi.shape[1]))
    Psi, translation, rotation = Psi @ scaled, translation @ scaled, rotation @ scaled
    mp = assembly.mass_points
    m = mp.m / link.density
    U = (mp.N @ Psi).reshape(len(m), 3, -1)                       # (P, 3, N)
    Xp = mp.X
    Km = Psi.T @ (assembly.stiffness @ Psi) / link.E
    # the clamp's reactions K_rf u_f on the root nodes; their moment about z (at x = 0: m_z − y f_x) is minus
    # the elastic moment the link carries there (EI v''(0) for a beam)
    reaction = (assembly.stiffness @ Psi) / link.E
    support = sum(reaction[assembly.dof(k, 5)] - assembly.mesh.nodes[k, 1] * reaction[assembly.dof(k, 0)]
                  for k in assembly.mesh.root_nodes)
    return BodyIntegrals(
        volume=float(m.sum()),
        first=m @ Xp,
        second=(Xp * m[:, None]).T @ Xp,
        modal=np.einsum("p,pbn->bn", m, U),
        x_modal=np.einsum("p,pa,pbn->abn", m, Xp, U),
        pairs=np.einsum("p,pan,pbk->abnk", m, U, U, optimize=True),
        stiffness=0.5 * (Km + Km.T),
        tip_point=point,
        tip_translation=translation,
        tip_rotation=rotation,
        root_moment=-support,
        frequencies_hz=basis.frequencies_hz,
    )
