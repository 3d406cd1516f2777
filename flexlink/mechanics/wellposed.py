"""Whether a scene's equations can be stepped at all: the SS22 step matrix at the start state.

SS22 solves (M + θ₁Δt C + θ₂Δt²/2 K) δa = −r for the mean acceleration of every step.  A coordinate that
nothing resists -- no inertia reaches it (a massless connector at the end of the chain, a rotor of zero
inertia), no stiffness, no damping -- makes that matrix singular whatever the step, and the FMU can only
refuse its first step.  That is a property of the scene, so it is refused with the scene: before the C is
generated and compiled, naming the joint or link whose coordinate is free to take any value.

A mass matrix that is singular while the step matrix is not (a twist without polar inertia, an elastic
joint without motor inertia: stiffness holds the coordinate) is a valid scene and passes.
"""

from __future__ import annotations

import numpy as np

from flexlink.errors import SceneError
from flexlink.mechanics.symbolic import SymbolicModel

__all__ = ["check_step_matrix"]

#: A column of the step matrix whose entries are all below this fraction of the matrix's largest entry is a
#: coordinate nothing resists.  Columns, not singular values: a valid but ill-conditioned basis (polynomial
#: shape functions, condition numbers past 1e14) has tiny singular values and no empty column.
NEGLIGIBLE = 1e-14


def _where(model: SymbolicModel, coordinate: str) -> str:
    """The scene key of the joint or link that owns a coordinate ("j2.theta" → 'joint[2] "j2"')."""
    owner = coordinate.split(".", 1)[0]
    for kind, names in (("joint", [j.name for j in model.scene.joints]), ("link", [k.name for k in model.scene.links])):
        if owner in names:
            return f'{kind}[{names.index(owner) + 1}] "{owner}"'
    return f'"{owner}"'


def _free_coordinates(J: np.ndarray) -> list[int]:
    """The coordinates whose column of J is negligible.

    None if J is not finite: a non-finite model is the loader's and the guards' business.
    """
    if not np.all(np.isfinite(J)):
        return []
    scale = np.max(np.abs(J))
    return [int(k) for k in np.flatnonzero(np.max(np.abs(J), axis=0) <= NEGLIGIBLE * scale)] if scale > 0 \
        else list(range(J.shape[1]))


def check_step_matrix(model: SymbolicModel) -> None:
    """Raise a SceneError if the SS22 step matrix at the start state (the scene's step and Θ) is singular."""
    q, v = model.start_state()
    u, p = model.default_inputs(), model.p0
    # M first (its Function is built already, an evaluation is cheap); only a coordinate M leaves free asks
    # for the step matrix itself, whose Jacobian takes seconds to form on a large chain
    if not _free_coordinates(np.asarray(model.mass_matrix_function()(q, u, p))):
        return
    theta1, theta2 = model.scene.fmu.solver.theta
    dt = model.scene.fmu.solver.step
    J = np.asarray(model.newton_matrix_function()(q, v, np.zeros(model.n_q), u, p, 1.0, theta1 * dt,
                                                  theta2 * 0.5 * dt * dt))
    free = _free_coordinates(J)
    if not free:
        return
    names = [model.coordinates[i] for i in free]
    where = model.scene.path or model.scene.name
    raise SceneError(
        f"{where}: {_where(model, names[0])}: nothing resists {', '.join(names)} at the start (no inertia reaches "
        "it, no stiffness, no damping), so no step can be taken; expected a rotor inertia (joint.inertia > 0), a "
        "mass on the links it moves, or joint damping")
