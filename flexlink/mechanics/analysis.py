"""Equilibrium, linearisation and natural frequencies of a symbolic model (`flexlink modes`, docs/commands.md).

The operating point: the scene's initial joint angles; the first joint turning steadily at ``rate``;
torque-driven joints given the constant torque that holds them there (they stay free coordinates
with their inertia); free joints at rest, which must then be an equilibrium; position-driven joints
held by their law.  The elastic coordinates take their static (or steady-state) deflection.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.linalg

from flexlink.errors import FlexlinkError
from flexlink.mechanics.model import SymbolicModel


@dataclass
class OperatingPoint:
    """The state and inputs a model is linearised about: coordinates q, rates v, inputs u, parameters p.

    The accelerations are zero there, so this is an equilibrium (or a steady rotation of the first joint).
    """

    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    p: np.ndarray


@dataclass
class Linearisation:
    """M δq̈ + C δq̇ + K δq = B δu about an operating point (free coordinates)."""

    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    B: np.ndarray


def _elastic_and_joint_indices(model: SymbolicModel) -> tuple[list[int], list[int]]:
    """Indices of the driven joint coordinates and of the others, which take their static value.

    Driven: torque-driven or free joints (the motor side of an elastic joint); the others are the
    elastic coordinates and the link side of elastic joints.
    """
    kinds = model.coordinate_kinds
    joints = [i for i, k in enumerate(kinds) if k == "joint"]
    elastic = [i for i, k in enumerate(kinds) if k != "joint"]
    return joints, elastic


def _joint_name(coordinate: str) -> str:
    """The joint a coordinate belongs to: its name without ``.theta`` or ``.motor_theta``."""
    return coordinate.removesuffix(".motor_theta").removesuffix(".theta")


def _call(f: ca.Function, *args: object) -> np.ndarray:
    """Evaluate a CasADi function numerically and hand back a float array (CasADi returns DM)."""
    return np.asarray(f(*args), dtype=float)


def static_deflection(model: SymbolicModel, q: np.ndarray, v: np.ndarray, u: np.ndarray, p: np.ndarray,
                      coords: list[int], tol: float = 1e-12, max_iter: int = 50) -> np.ndarray:
    """Solve r_S(q, v, 0, u, p) = 0 for the coordinates S (Newton), the others held."""
    q = np.array(q, dtype=float)
    if not coords:
        return q
    newton = model.newton_matrix_function()
    a0 = np.zeros(model.n_q)
    scale = model.nominal_q[coords]
    for _ in range(max_iter):
        r = _call(model.residual, q, v, a0, u, p).ravel()[coords]
        K = _call(newton, q, v, a0, u, p, 0.0, 0.0, 1.0)[np.ix_(coords, coords)]
        dq = np.linalg.solve(K, -r)
        q[coords] += dq
        if np.all(np.abs(dq) <= tol * scale):
            return q
    raise FlexlinkError("the static equilibrium did not converge (is the structure stable under its loads?)")


def operating_point(model: SymbolicModel, rate: float = 0.0, p: np.ndarray | None = None) -> OperatingPoint:
    """The equilibrium `flexlink modes` linearises about (docs/commands.md), as (q, v, u, p).

    Raises
    ------
    FlexlinkError
        When ``rate`` is set with gravity across the first joint's axis (no steady rotation exists), or a
        free joint is not at rest at its initial angle.
    """
    scene = model.scene
    p = model.p0 if p is None else np.asarray(p, dtype=float)
    if rate != 0.0 and scene.has_gravity:
        g = np.asarray(scene.gravity, float)
        axis = np.asarray(scene.joints[0].axis, float)
        if np.linalg.norm(np.cross(g, axis)) > 1e-9 * np.linalg.norm(g):
            raise FlexlinkError("--rate needs gravity to be zero or parallel to the first joint's axis")
    q, v = model.start_state()
    u = model.default_inputs(0.0)
    joints, elastic = _elastic_and_joint_indices(model)
    # the first joint turning steadily: its rate (free coordinate) or its law (prescribed)
    first = scene.joints[0]
    if model.laws and model.laws[0].joint == first.name:
        o = model.laws[0].u_offset
        u[o + 1], u[o + 2] = rate, 0.0
        for law in model.laws[1:]:
            u[law.u_offset + 1:law.u_offset + 3] = 0.0
    else:
        for law in model.laws:
            u[law.u_offset + 1:law.u_offset + 3] = 0.0
        v[:] = 0.0
        for i, c in enumerate(model.coordinates):
            if c in (f"{first.name}.theta", f"{first.name}.motor_theta"):
                v[i] = rate
    q = static_deflection(model, q, v, u, p, elastic)
    # torque-driven joints: the constant torque that holds them; free joints: must be at rest already
    r = _call(model.residual, q, v, np.zeros(model.n_q), u, p).ravel()
    names = [s.name for s in model.inputs]
    for i in joints:
        name = _joint_name(model.coordinates[i])
        tau_name = f"{name}.tau"
        if tau_name in names:
            u[names.index(tau_name)] += r[i]   # r = … − τ: adding r cancels the joint's residual
        elif abs(r[i]) > 1e-8 * max(1.0, np.max(np.abs(r))):
            raise FlexlinkError(f'free joint "{name}" is not at an equilibrium at its initial angle '
                                f"(residual torque {r[i]:.3g} N m): start it hanging at rest")
    return OperatingPoint(q, v, u, p)


def linearise(model: SymbolicModel, op: OperatingPoint) -> Linearisation:
    """Jacobians of the residual at the operating point (acceleration zero)."""
    newton = model.newton_matrix_function()
    a0 = np.zeros(model.n_q)
    M = _call(newton, op.q, op.v, a0, op.u, op.p, 1.0, 0.0, 0.0)
    C = _call(newton, op.q, op.v, a0, op.u, op.p, 0.0, 1.0, 0.0)
    K = _call(newton, op.q, op.v, a0, op.u, op.p, 0.0, 0.0, 1.0)
    q, v, a, u, p = (ca.MX.sym(n, *model.residual.size_in(i)) for i, n in enumerate("qvaup"))
    dr_du = ca.Function("dr_du", [q, v, a, u, p], [ca.jacobian(model.residual(q, v, a, u, p), u)])
    B = -_call(dr_du, op.q, op.v, a0, op.u, op.p)
    return Linearisation(M, C, K, B)


@dataclass
class Modes:
    """What `flexlink modes` reports: frequencies (Hz) at a hub ``rate``, the divergent ones apart.

    ``rigid`` counts the rigid-body (zero-frequency) modes left out of both lists.
    """

    rate: float
    frequencies_hz: list[float]
    unstable_hz: list[float]
    rigid: int


def natural_frequencies(model: SymbolicModel, rate: float = 0.0, p: np.ndarray | None = None,
                        rigid_tol: float = 1e-12) -> Modes:
    """Undamped natural frequencies about the operating point: ascending, rigid-body zeros left out.

    Modes with ω² < 0 (divergence) are listed apart, as |ω| in Hz. A mode is rigid when |ω²| is at
    rounding level against the largest (``rigid_tol`` × max|ω²|, about 5e3 ε): stiff joints and fine
    meshes span 1e10 in ω², so a looser test would drop physical modes.
    """
    lin = linearise(model, operating_point(model, rate, p))
    M, C, K = lin.M, lin.C, lin.K
    G = 0.5 * (C - C.T)                      # gyroscopic part; dissipation is left out
    if np.linalg.norm(G) <= 1e-12 * max(1.0, float(np.linalg.norm(C))):
        w2 = np.real(scipy.linalg.eigvals(K, M))
        scale = max(1.0, float(np.max(np.abs(w2))))
        rigid = int(np.sum(np.abs(w2) <= rigid_tol * scale))
        stable = np.sort(np.sqrt(w2[w2 > rigid_tol * scale]))
        unstable = np.sort(np.sqrt(-w2[w2 < -rigid_tol * scale]))
    else:
        n = M.shape[0]
        Minv = np.linalg.inv(M)
        A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ G]])
        lam = np.linalg.eigvals(A)
        scale = max(1.0, float(np.max(np.abs(lam))))
        small = np.abs(lam) <= np.sqrt(rigid_tol) * scale
        rigid = int(np.sum(small)) // 2
        osc = lam[~small & (np.abs(lam.imag) >= np.abs(lam.real))]
        div = lam[~small & (np.abs(lam.imag) < np.abs(lam.real))]
        stable = np.sort(np.abs(osc.imag[osc.imag > 0]))
        unstable = np.sort(div.real[div.real > 0])
    to_hz = 1.0 / (2.0 * np.pi)
    return Modes(rate, [float(w * to_hz) for w in stable], [float(w * to_hz) for w in unstable], rigid)
