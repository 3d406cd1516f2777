"""The symbolic model of a scene: energies → Lagrange equations → CasADi Functions.

The mechanics is written once, as energies (seed 000 chapter 3, generalised): kinetic energy T from
the inertia invariants of :mod:`flexlink.mechanics.kinematics`, elastic and gravitational potential V, and
Rayleigh's dissipation function R.  CasADi's automatic differentiation then gives the equations

    r(q, v, a, u, p) = d/dt ∂L/∂q̇ − ∂L/∂q + ∂R/∂q̇ − Q = M(q) a + h(q, v, u, p) = 0,

with no hand-derived Coriolis term, and ``M(q) = ∂²T/∂q̇²`` symmetric by construction.  The three
kinematic models differ only in T and V:

* ``"linear"``: first-order kinematics, T evaluated at η = 0 except for the relative motion
  (seed 000 eq. 3.7): with no gravity the equations are linear;
* ``"first-order"``: first-order kinematics, full T: the model loses stiffness with the hub rate;
* ``"second-order"``: foreshortening included; each body's kinetic and potential energy is kept to
  second order in its *own* elastic coordinates (the inertia invariants, seed 000 §3.4.2-3.4.3) and the
  bodies are composed along the chain exactly.  Nothing is truncated after differentiation, so the
  equations stay Lagrangian: M symmetric, T + V conserved by the exact flow (docs/mechanics.md).

Coordinates are split into *free* ones (integrated by the FMU) and *prescribed* ones
(position-driven joints, whose position, rate and acceleration enter as inputs u); the residual of a
prescribed joint's equation is the torque that its law needs (seed 001 §2.10), an output.

This module is the stage's front: :func:`build_model` and the data classes of
:mod:`flexlink.mechanics.symbolic`.  The chain is assembled in :mod:`flexlink.mechanics.assembly`, its
outputs in :mod:`flexlink.mechanics.outputs`.
"""

from __future__ import annotations

import numpy as np

from flexlink.errors import SceneError
from flexlink.mechanics.assembly import ChainAssembly, check_supported, structure
from flexlink.mechanics.outputs import chain_outputs, parameter_checks, validity
from flexlink.mechanics.symbolic import Law, Parameter, Signal, StartValue, SymbolicModel
from flexlink.mechanics.wellposed import check_step_matrix
from flexlink.scene.budget import allow_large_from_env, check_budget, estimate, key_value
from flexlink.scene.loader import Scene

__all__ = ["Law", "Parameter", "Signal", "StartValue", "SymbolicModel", "build_model"]


def build_model(scene: Scene, *, allow_large: bool | None = None) -> SymbolicModel:
    """Build the symbolic model of a scene's serial chain (joint i on the tip frame of link i-1 drives link i).

    Parameters
    ----------
    scene : Scene
        A validated scene (:func:`flexlink.scene.loader.load_scene`).
    allow_large : bool, optional
        Build a scene past the budgets of :mod:`flexlink.scene.budget` (None: ``$FLEXLINK_ALLOW_LARGE``,
        which ``flexlink --allow-large`` sets).

    Returns
    -------
    SymbolicModel
        The residual and output Functions with their tables.

    Raises
    ------
    FlexlinkError
        If the scene asks for something the builder does not support yet.
    SceneError
        If the scene is past a budget (before anything is allocated), or its shapes cannot fit in memory, or
        a coordinate is free of inertia, stiffness and damping (:mod:`flexlink.mechanics.wellposed`).
    """
    if not (allow_large_from_env() if allow_large is None else allow_large):
        check_budget(scene)
    check_supported(scene)
    try:
        model = _build(scene)
    except MemoryError as exc:      # numpy's ArrayMemoryError too: past the budgets, a size that cannot fit
        raise _out_of_memory(scene, exc) from None
    check_step_matrix(model)
    return model


def _out_of_memory(scene: Scene, exc: MemoryError) -> SceneError:
    """One line naming the key that sizes the largest shape stage, instead of numpy's traceback."""
    cost = estimate(scene)
    if not cost.links:
        return SceneError(f"{cost.source}: link: the model does not fit in memory ({exc})")
    big = max(cost.links, key=lambda c: c.shape_bytes)
    where = f"{cost.source}: {big.key}{key_value(scene, big.key)}"
    return SceneError(f'{where}: the model does not fit in memory ({exc}; link "{big.name}" '
                      f"needs ~{big.shape_bytes / 2**30:.3g} GiB for its shapes); expected a smaller value")


def _build(scene: Scene) -> SymbolicModel:
    """The stages in order; split from build_model so that one try covers every allocation."""
    chain = ChainAssembly(scene)
    chain.assemble_kinematics()
    chain.add_potential_and_dissipation()
    chain.add_equations()
    signals, expressions = chain_outputs(chain)
    validity_function, validity_names = validity(chain)
    check_function, check_names = parameter_checks(chain)
    start_values, static = chain.start_values()
    linear, constant, inputs = structure(chain.residual)
    free = chain.free
    return SymbolicModel(
        scene=scene, coordinates=[chain.coordinates[k] for k in free],
        nominal_q=np.array([chain.nominal[k] for k in free]), parameters=chain.P.items, inputs=chain.inputs,
        laws=chain.laws, outputs=signals, start_values=start_values, static_coordinates=static,
        residual=chain.residual, outputs_function=chain.free_function("outputs", expressions),
        linear_in_state=linear, jacobian_constant=constant, terms=chain.terms,
        input_matrix=None if chain.laws else inputs,
        coordinate_kinds=[chain.kinds[k] for k in free], validity=validity_function, validity_names=validity_names,
        mass_matrix=chain.free_mass_matrix(), parameter_check=check_function, parameter_check_names=check_names)
