"""Flat triangular shell elements for plate and box-section links (seed 001 part 5, issue 9).

Each triangle superposes Batoz's DKT plate (bending: w, θx, θy) and the CST membrane (u, v), with a
fictitious drilling stiffness on θz (seed §5.5), in the element frame of seed §5.6 (X along side 12,
Z = V12 × V13, Y = Z × X), rotated to the link frame and assembled: 6 DOFs per node
(ux, uy, uz, rx, ry, rz), the rotations being components of the small rotation vector, so that in an
element frame θx = ∂w/∂y and θy = −∂w/∂x.

The mass interpolates the three translations linearly and neglects rotary inertia (seed §5.3, §5.4);
:class:`MassPoints` is the seed's mid-side rule (§5.7), exact for that mass and for every integral of
the floating frame (their integrands are at most quadratic in the linear fields).

The DKT is built as Batoz, Bathe & Ho (IJNME 15, 1980) define it rather than from the seed's OCR'd
coefficients: quadratic rotations β on the 6-node triangle, Kirchhoff imposed at the corners
(β = −∇w), the tangential rotation at each mid-side from the cubic w along the side, the normal one
linear along it. ``B`` is then linear, so the 3 mid-side points integrate BᵀDB exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import scipy.sparse

# Mid-side quadrature of the reference triangle (ξ, η), weight 1/6 each (seed §5.7): exact to degree 2.
_MIDSIDE = np.array([[0.5, 0.5], [0.0, 0.5], [0.5, 0.0]])
# Sides opposite corners 1, 2, 3 are the 6-node triangle's mid-side nodes 4, 5, 6: (i, j) = (2,3), (3,1), (1,2).
_SIDES = ((1, 2), (2, 0), (0, 1))
_PATTERNS = ("A", "B", "symmetric")
# Fictitious drilling stiffness per α E h A (seed §5.5): zero for a uniform θz, which rigid rotations give.
_DRILL = np.array([[1.0, -0.5, -0.5], [-0.5, 1.0, -0.5], [-0.5, -0.5, 1.0]])


@dataclass(frozen=True, eq=False)
class ShellMesh:
    """Triangles in the link frame (x along the link); ``root_nodes`` are clamped to the joint frame."""

    nodes: np.ndarray
    triangles: np.ndarray
    root_nodes: np.ndarray

    def __post_init__(self):
        nodes = np.array(self.nodes, dtype=float)
        tri = np.array(self.triangles)
        root = np.array(self.root_nodes)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or not np.all(np.isfinite(nodes)):
            raise ValueError(f"nodes must be a finite (n_nodes, 3) array, got shape {nodes.shape}")
        if tri.ndim != 2 or tri.shape[1] != 3 or tri.size == 0 or not np.issubdtype(tri.dtype, np.integer):
            raise ValueError(f"triangles must be a non-empty integer (n_tri, 3) array, got {tri.shape} {tri.dtype}")
        if tri.min() < 0 or tri.max() >= len(nodes):
            raise ValueError("triangles refer to nodes that do not exist")
        if root.ndim != 1 or (root.size and not np.issubdtype(root.dtype, np.integer)):
            raise ValueError("root_nodes must be a 1-D integer array")
        if root.size and (root.min() < 0 or root.max() >= len(nodes)):
            raise ValueError("root_nodes refer to nodes that do not exist")
        _, area = _frames(nodes, tri)
        scale = np.ptp(nodes, axis=0).max()
        if np.any(area <= 1e-12 * scale**2):
            raise ValueError(f"degenerate triangles: {np.flatnonzero(area <= 1e-12 * scale**2)[:5].tolist()}")
        for name, value in (
            ("nodes", nodes),
            ("triangles", tri.astype(np.int64)),
            ("root_nodes", root.astype(np.int64)),
        ):
            value.setflags(write=False)
            object.__setattr__(self, name, value)


def _frames(nodes: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Element frames R (rows X, Y, Z in link axes, seed §5.6) and areas."""
    p1, p2, p3 = (nodes[tri[:, a]] for a in range(3))
    v12, v13 = p2 - p1, p3 - p1
    normal = np.cross(v12, v13)
    twice_area = np.linalg.norm(normal, axis=1)
    X = v12 / np.linalg.norm(v12, axis=1, keepdims=True)
    Z = normal / np.where(twice_area > 0, twice_area, 1.0)[:, None]
    Y = np.cross(Z, X)
    return np.stack([X, Y, Z], axis=1), 0.5 * twice_area


def _orient(nodes: np.ndarray, tri: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """Triangles reordered so that V12 × V13 points along ``outward`` (one vector per triangle)."""
    p1, p2, p3 = (nodes[tri[:, a]] for a in range(3))
    flip = np.einsum("ij,ij->i", np.cross(p2 - p1, p3 - p1), outward) < 0
    tri = tri.copy()
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


def _split(a, b, c, d, rising: np.ndarray) -> np.ndarray:
    """Two triangles per quad a=(i,j), b=(i+1,j), c=(i+1,j+1), d=(i,j+1): diagonal a–c if rising, else b–d."""
    first = np.where(rising[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    second = np.where(rising[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return np.concatenate([first, second])


def _rising(pattern: str, across: int, count: int, name: str) -> np.ndarray:
    """Diagonal direction of each of the ``across`` strips (repeated along x, ``count`` quads each).

    "A": every diagonal from (x_i, s_j) to (x_i+1, s_j+1); "B": the other one; "symmetric": the strips
    below the mid-line rise towards it and those above fall towards it, so the diagonals of a section form
    a chevron ">" pointing to the free end, mirror-symmetric about the mid-line.
    """
    if pattern not in _PATTERNS:
        raise ValueError(f"pattern must be one of {_PATTERNS}, got {pattern!r}")
    if pattern == "symmetric":
        if across % 2:
            raise ValueError(f"a symmetric mesh needs an even {name}, got {across} (or use pattern 'A' or 'B')")
        strips = np.arange(across) < across // 2
    else:
        strips = np.full(across, pattern == "A")
    return np.tile(strips, count)


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _positive(value, name: str) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be positive and finite, got {value!r}")
    return value


def plate_mesh(length, width, nx, nw, pattern="symmetric") -> ShellMesh:
    """Flat plate x ∈ [0, length], z ∈ [−width/2, width/2] (normal +y), nx × nw quads of 2 triangles.

    Nodes are numbered section by section (x-major), z ascending within a section, so that with
    nx = 5, nw = 2 node k of seed 001 §5.8 is index k − 1 (its free-edge nodes 16, 17, 18 are 15, 16, 17).
    The seed's fig. 5.5 is lost in the OCR; these layouts reproduce its table of tip deflections to the
    printed digit: "A" its column A, "symmetric" (the ">" chevron) its column SYM, which the mirror "<"
    chevron does not (−0.12803e-3 at the edges instead of −0.12795e-3, with g = 9.81).
    """
    length, width = _positive(length, "length"), _positive(width, "width")
    nx, nw = _positive_int(nx, "nx"), _positive_int(nw, "nw")
    x = np.linspace(0.0, length, nx + 1)
    z = np.linspace(-width / 2, width / 2, nw + 1)
    X, Z = np.meshgrid(x, z, indexing="ij")
    nodes = np.column_stack([X.ravel(), np.zeros(X.size), Z.ravel()])
    i_grid, j_grid = np.meshgrid(np.arange(nx), np.arange(nw), indexing="ij")
    i, j = i_grid.ravel(), j_grid.ravel()
    a = i * (nw + 1) + j
    tri = _split(a, a + nw + 1, a + nw + 2, a + 1, _rising(pattern, nw, nx, "nw"))
    tri = _orient(nodes, tri, np.tile([0.0, 1.0, 0.0], (len(tri), 1)))
    return ShellMesh(nodes, tri, np.arange(nw + 1))


def box_mesh(length, width, height, nx, nw, nh, pattern="symmetric") -> ShellMesh:
    """Thin-walled rectangular tube along x: walls (mid-surfaces) at y = ±height/2 and z = ±width/2.

    A section's nodes go round the perimeter from the corner (y, z) = (−h/2, −w/2): along y = −h/2
    (nw elements), up z = +w/2 (nh), back along y = +h/2, down z = −w/2; sections are numbered along x.
    The pattern is applied to each wall about its own mid-line; normals point outwards.
    """
    length, width, height = _positive(length, "length"), _positive(width, "width"), _positive(height, "height")
    nx, nw, nh = _positive_int(nx, "nx"), _positive_int(nw, "nw"), _positive_int(nh, "nh")
    w2, h2 = width / 2, height / 2
    s_w = np.linspace(-w2, w2, nw + 1)[:-1]
    s_h = np.linspace(-h2, h2, nh + 1)[:-1]
    ring = np.concatenate(
        [
            np.column_stack([np.full(nw, -h2), s_w]),
            np.column_stack([s_h, np.full(nh, w2)]),
            np.column_stack([np.full(nw, h2), -s_w]),
            np.column_stack([-s_h, np.full(nh, -w2)]),
        ]
    )
    n_p = len(ring)
    x = np.linspace(0.0, length, nx + 1)
    nodes = np.column_stack([np.repeat(x, n_p), np.tile(ring[:, 0], nx + 1), np.tile(ring[:, 1], nx + 1)])
    wall = np.concatenate([_rising(pattern, nw, 1, "nw"), _rising(pattern, nh, 1, "nh")] * 2)
    i_grid, p_grid = np.meshgrid(np.arange(nx), np.arange(n_p), indexing="ij")
    i, p = i_grid.ravel(), p_grid.ravel()
    a = i * n_p + p
    d = i * n_p + (p + 1) % n_p
    tri = _split(a, a + n_p, d + n_p, d, np.tile(wall, nx))
    centre = nodes[tri].mean(axis=1)
    tri = _orient(nodes, tri, centre * [0.0, 1.0, 1.0])
    return ShellMesh(nodes, tri, np.arange(n_p))


# ---------------------------------------------------------------------------------------------------------
# Element matrices, batched over triangles: xy (m, 3, 2) corner coordinates in the element frames.


def _plate_rigidity(E, nu, h) -> np.ndarray:
    return E * h**3 / (12 * (1 - nu**2)) * np.array([[1, nu, 0], [nu, 1, 0], [0, 0, (1 - nu) / 2]])


def _dkt_batch(xy: np.ndarray, D: np.ndarray) -> np.ndarray:
    """DKT stiffness (m, 9, 9), DOFs (w, θx, θy) per corner."""
    m = len(xy)
    # β = (βx, βy) of Batoz (u = z βx, v = z βy) at the 6 nodes of the quadratic triangle, as a
    # linear map of the 9 DOFs. Corners: β = −∇w = (θy, −θx).
    C = np.zeros((m, 6, 2, 9))
    for a in range(3):
        C[:, a, 0, 3 * a + 2] = 1.0
        C[:, a, 1, 3 * a + 1] = -1.0
    for k, (i, j) in enumerate(_SIDES):
        d = xy[:, j] - xy[:, i]
        l = np.linalg.norm(d, axis=1)
        s = d / l[:, None]
        n = np.column_stack([s[:, 1], -s[:, 0]])
        # w cubic along the side: −∂w/∂s at mid-side = 3/(2l)(w_i − w_j) − ¼ s·(β_i + β_j);
        # the normal rotation is linear along it: ½ n·(β_i + β_j).
        Q = -0.25 * np.einsum("mi,mj->mij", s, s) + 0.5 * np.einsum("mi,mj->mij", n, n)
        Cm = Q @ (C[:, i] + C[:, j])
        Cm[:, :, 3 * i] += 1.5 * s / l[:, None]
        Cm[:, :, 3 * j] -= 1.5 * s / l[:, None]
        C[:, 3 + k] = Cm
    x21, y21 = xy[:, 1, 0] - xy[:, 0, 0], xy[:, 1, 1] - xy[:, 0, 1]
    x31, y31 = xy[:, 2, 0] - xy[:, 0, 0], xy[:, 2, 1] - xy[:, 0, 1]
    det = x21 * y31 - x31 * y21
    K = np.zeros((m, 9, 9))
    for xi, eta in _MIDSIDE:
        dxi = np.array([4 * xi + 4 * eta - 3, 4 * xi - 1, 0, 4 * eta, -4 * eta, 4 - 8 * xi - 4 * eta])
        deta = np.array([4 * xi + 4 * eta - 3, 0, 4 * eta - 1, 4 * xi, 4 - 4 * xi - 8 * eta, -4 * xi])
        b_xi = np.einsum("a,maci->mci", dxi, C)
        b_eta = np.einsum("a,maci->mci", deta, C)
        b_x = (y31[:, None, None] * b_xi - y21[:, None, None] * b_eta) / det[:, None, None]
        b_y = (-x31[:, None, None] * b_xi + x21[:, None, None] * b_eta) / det[:, None, None]
        B = np.stack([b_x[:, 0], b_y[:, 1], b_y[:, 0] + b_x[:, 1]], axis=1)
        K += (np.abs(det) / 6)[:, None, None] * np.einsum("mki,kl,mlj->mij", B, D, B)
    return K


def _cst_batch(xy: np.ndarray, E, nu, h) -> np.ndarray:
    """CST membrane stiffness (m, 6, 6), DOFs (u, v) per corner."""
    x, y = xy[..., 0], xy[..., 1]
    y23, y31, y12 = y[:, 1] - y[:, 2], y[:, 2] - y[:, 0], y[:, 0] - y[:, 1]
    x32, x13, x21 = x[:, 2] - x[:, 1], x[:, 0] - x[:, 2], x[:, 1] - x[:, 0]
    twice_area = x21 * y31 - x13 * y12
    zero = np.zeros_like(x21)
    B = (
        np.stack(
            [
                np.stack([y23, zero, y31, zero, y12, zero], 1),
                np.stack([zero, x32, zero, x13, zero, x21], 1),
                np.stack([x32, y23, x13, y31, x21, y12], 1),
            ],
            1,
        )
        / twice_area[:, None, None]
    )
    Dm = E * h / (1 - nu**2) * np.array([[1, nu, 0], [nu, 1, 0], [0, 0, (1 - nu) / 2]])
    return (0.5 * np.abs(twice_area))[:, None, None] * np.einsum("mki,kl,mlj->mij", B, Dm, B)


def _check_element(xy, E, nu, h) -> np.ndarray:
    xy = np.asarray(xy, dtype=float)
    if xy.shape != (3, 2):
        raise ValueError(f"xy must be the (3, 2) corner coordinates, got shape {xy.shape}")
    d = xy[1:] - xy[0]
    if (
        not np.all(np.isfinite(xy))
        or abs(d[0, 0] * d[1, 1] - d[0, 1] * d[1, 0]) <= 1e-12 * np.ptp(xy, axis=0).max() ** 2
    ):
        raise ValueError("the triangle is degenerate")
    _check_material(E, nu, h)
    return xy[None]


def _check_material(E, nu, h, density=1.0):
    _positive(E, "E")
    _positive(h, "thickness")
    _positive(density, "density")
    if not -1.0 < float(nu) < 0.5:
        raise ValueError(f"Poisson's ratio must be in (−1, 0.5), got {nu!r}")


def dkt_stiffness(xy, E, nu, h) -> np.ndarray:
    """DKT plate stiffness (9, 9) in the element frame, DOFs (w, θx, θy) per corner, θx = ∂w/∂y, θy = −∂w/∂x."""
    return _dkt_batch(_check_element(xy, E, nu, h), _plate_rigidity(E, nu, h))[0]


def cst_stiffness(xy, E, nu, h) -> np.ndarray:
    """CST membrane stiffness (6, 6) in the element frame, DOFs (u, v) per corner."""
    return _cst_batch(_check_element(xy, E, nu, h), E, nu, h)[0]


# ---------------------------------------------------------------------------------------------------------
# Assembly.


@dataclass
class MassPoints:
    """Point masses reproducing the consistent mass exactly: Nᵀ diag(m ⊗ 1₃) N = mass.

    One point per mesh edge (the mid-sides of the triangles; an edge shared by two triangles carries
    both their ρhA/3), rows 3k..3k+2 of N interpolating (ux, uy, uz) there.
    """

    X: np.ndarray
    m: np.ndarray
    N: scipy.sparse.csr_matrix


@dataclass
class ShellAssembly:
    """Link-frame stiffness and mass of a shell mesh, 6 DOFs per node (ux, uy, uz, rx, ry, rz)."""

    mesh: ShellMesh
    thickness: float
    E: float
    nu: float
    density: float
    stiffness: scipy.sparse.csr_matrix
    mass: scipy.sparse.csr_matrix
    mass_points: MassPoints
    drilling: float = field(default=1e-10)

    @property
    def n_dof(self) -> int:
        """Number of degrees of freedom of the whole mesh, root included: six per node."""
        return 6 * len(self.mesh.nodes)

    def dof(self, node: int | np.integer, component: int) -> int:
        """Global index of ``component`` (0–2 translations, 3–5 rotations) of ``node``, checked.

        Raises
        ------
        ValueError
            When the node is not in the mesh or the component is not one of the six.
        """
        if not 0 <= node < len(self.mesh.nodes) or not 0 <= component < 6:
            raise ValueError(f"no DOF ({node}, {component}) on a mesh of {len(self.mesh.nodes)} nodes")
        return 6 * int(node) + int(component)

    @property
    def free_dofs(self) -> np.ndarray:
        """Indices of the degrees of freedom off the clamped root nodes: those the modes are computed on."""
        free = np.setdiff1d(np.arange(len(self.mesh.nodes)), self.mesh.root_nodes)
        return (6 * free[:, None] + np.arange(6)).ravel()

    def gravity_load(self, g: npt.ArrayLike) -> np.ndarray:
        """Consistent nodal forces of the weight ρ h g per unit area (g in the link frame); no moments."""
        g = np.asarray(g, dtype=float)
        if g.shape != (3,):
            raise ValueError(f"g must be a 3-vector in the link frame, got shape {g.shape}")
        _, area = _frames(self.mesh.nodes, self.mesh.triangles)
        per_node = np.zeros(len(self.mesh.nodes))
        np.add.at(per_node, self.mesh.triangles, np.repeat(area[:, None] / 3, 3, axis=1))
        load = np.zeros((len(self.mesh.nodes), 6))
        load[:, :3] = self.density * self.thickness * per_node[:, None] * g
        return load.ravel()


def _local_18(Kb: np.ndarray, Km: np.ndarray, Kd: np.ndarray) -> np.ndarray:
    """DKT (w, θx, θy), CST (u, v) and drilling (θz) matrices placed in (u, v, w, θx, θy, θz) per node."""
    K = np.zeros((len(Kb), 18, 18))
    bend = (6 * np.arange(3)[:, None] + [2, 3, 4]).ravel()
    memb = (6 * np.arange(3)[:, None] + [0, 1]).ravel()
    drill = 6 * np.arange(3) + 5
    K[:, bend[:, None], bend] = Kb
    K[:, memb[:, None], memb] = Km
    K[:, drill[:, None], drill] = Kd
    return K


def assemble_shell(mesh: ShellMesh, thickness, E, nu, density, drilling=1e-10) -> ShellAssembly:
    """Global stiffness, consistent mass and mass points of a DKT + CST shell in the link frame."""
    _check_material(E, nu, thickness, density)
    h, E, nu, rho = float(thickness), float(E), float(nu), float(density)
    drilling = float(drilling)
    if not np.isfinite(drilling) or drilling < 0:
        raise ValueError(f"drilling must be non-negative, got {drilling!r}")
    nodes, tri = mesh.nodes, mesh.triangles
    m = len(tri)
    R, area = _frames(nodes, tri)
    xy = np.einsum("mij,maj->mai", R[:, :2], nodes[tri] - nodes[tri[:, :1]])
    drill = drilling * E * h * np.einsum("m,ij->mij", area, _DRILL)
    K_local = _local_18(_dkt_batch(xy, _plate_rigidity(E, nu, h)), _cst_batch(xy, E, nu, h), drill)
    T = np.einsum("ab,mij->maibj", np.eye(6), R).reshape(m, 18, 18)
    K_el = np.transpose(T, (0, 2, 1)) @ K_local @ T
    dofs = (6 * np.repeat(tri, 6, axis=1) + np.tile(np.arange(6), 3)).reshape(m, 18)
    n_dof = 6 * len(nodes)
    K = scipy.sparse.coo_matrix(
        (K_el.ravel(), (np.repeat(dofs, 18, axis=1).ravel(), np.tile(dofs, 18).ravel())), shape=(n_dof, n_dof)
    ).tocsr()
    K = 0.5 * (K + K.T)
    # Consistent mass of the linear interpolation, the same on each translation: isotropic, so frame-free.
    M3 = np.array([[2.0, 1.0, 1.0], [1.0, 2.0, 1.0], [1.0, 1.0, 2.0]]) / 12
    M_el = rho * h * np.einsum("m,ab->mab", area, M3)
    shape = (m, 3, 3, 3)  # (element, row corner, column corner, translation component)
    rows = np.broadcast_to(6 * tri[:, :, None, None] + np.arange(3), shape)
    cols = np.broadcast_to(6 * tri[:, None, :, None] + np.arange(3), shape)
    vals = np.broadcast_to(M_el[..., None], shape)
    M = scipy.sparse.coo_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(n_dof, n_dof)).tocsr()
    return ShellAssembly(mesh, h, E, nu, rho, K.tocsr(), M, _mass_points(nodes, tri, rho * h * area), drilling)


def _mass_points(nodes: np.ndarray, tri: np.ndarray, element_mass: np.ndarray) -> MassPoints:
    """Mid-side rule of seed §5.7, merged per edge (each mid-side carries m_e/3 of each of its triangles)."""
    sides = np.sort(np.stack([tri[:, [1, 2]], tri[:, [2, 0]], tri[:, [0, 1]]], axis=1).reshape(-1, 2), axis=1)
    edges, which = np.unique(sides, axis=0, return_inverse=True)
    m = np.zeros(len(edges))
    np.add.at(m, which.ravel(), np.repeat(element_mass / 3, 3))
    X = 0.5 * (nodes[edges[:, 0]] + nodes[edges[:, 1]])
    P = len(edges)
    rows = np.repeat(3 * np.arange(P)[:, None] + np.arange(3), 2, axis=1).ravel()
    cols = (6 * edges[:, None, :] + np.arange(3)[None, :, None]).reshape(P, 6).ravel()
    N = scipy.sparse.csr_matrix((np.full(6 * P, 0.5), (rows, cols)), shape=(3 * P, 6 * len(nodes)))
    return MassPoints(X, m, N)
