"""The one form of every scene error, and the checks that involve more than one key.

A :class:`~flexlink.errors.SceneError` reads ``FILE: KEY: expected WHAT, got VALUE`` (or ``FILE: KEY: missing;
expected WHAT``). The loader reads one key at a time; the checks here relate keys to each other (a field to
the data it needs, a mesh to its pattern, a tunable name to the joints and links). The loader calls each at
the point of its single pass where the keys involved have been read, so that of several mistakes the first
one in reading order is the one reported.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
from typing import Any

import numpy as np

from flexlink.errors import SceneError
from flexlink.scene.schema import AXIS_TOLERANCE, JOINT_TUNABLE, LINK_TUNABLE, Joint, Link

INERTIA_TOLERANCE = 1e-12    # relative: a tensor's eigenvalues and triangle inequalities, against its largest moment
# Keys of a beam link that mean nothing for a rigid one (initial_deformation only when "static").
NOT_RIGID = ("EI", "EI_out", "GJ", "kelvin_voigt", "shapes", "kinematics")

MISSING: Any = object()   # a key that is absent (distinct from every TOML value)


def show(value: Any, limit: int = 60) -> str:
    """The offending value in TOML spelling, shortened, so that the message stays one line."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, float):
        text = "nan" if math.isnan(value) else ("inf" if value == math.inf else
                                                 "-inf" if value == -math.inf else repr(value))
    elif isinstance(value, int):
        text = repr(value)
    elif isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)  # TOML basic-string escapes: one line, always
    elif isinstance(value, list | tuple):
        text = "[" + ", ".join(show(v, limit) for v in value) + "]"
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{k} = {show(v, limit)}" for k, v in value.items()) + "}"
    else:
        text = f"a {type(value).__name__}"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def is_number(value: Any) -> bool:
    """Whether a TOML value is a number: an int or a float, but not a bool (``true`` is an int to Python)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def error(source: str, key: str, expected: str, value: Any = MISSING) -> SceneError:
    """The scene error in its one form, ``FILE: KEY: expected WHAT, got VALUE``, for the caller to raise.

    Parameters
    ----------
    source : str
        The scene file's name (or ``<string>``), first in the message.
    key : str
        The key's dotted path with 1-based table indices (``link[2].EI``).
    expected : str
        What the key accepts, in words.
    value : Any, optional
        The offending value, shown in TOML spelling; absent (:data:`MISSING`) for a missing key.

    Returns
    -------
    SceneError
        Returned rather than raised, so that ``raise error(...)`` shows the raise at the check.
    """
    if value is MISSING:
        return SceneError(f"{source}: {key}: missing; expected {expected}")
    return SceneError(f"{source}: {key}: expected {expected}, got {show(value)}")


# ---------------------------------------------------------------------------------------------- chain


def same_count(source: str, n_joints: int, n_links: int) -> None:
    """Refuse a chain whose joints and links do not pair up: link i is driven by joint i, so the counts match."""
    if n_joints != n_links:
        raise SceneError(
            f"{source}: joint, link: expected as many [[joint]] as [[link]] (link i is driven by "
            f"joint i), got {n_joints} [[joint]] and {n_links} [[link]]")


def unique_names(source: str, joints: tuple[Joint, ...], links: tuple[Link, ...]) -> None:
    """Joint and link names share one namespace: both prefix FMU variable names."""
    seen: dict[str, str] = {}
    groups: tuple[tuple[str, tuple[Joint | Link, ...]], ...] = (("joint", joints), ("link", links))
    for kind, items in groups:
        for i, item in enumerate(items):
            key = f"{kind}[{i + 1}].name"
            if item.name in seen:
                raise error(source, key, f"a name not already used (by {seen[item.name]})", item.name)
            seen[item.name] = key.removesuffix(".name")


def joint_axes(source: str, joint_data: list[dict[str, Any]], joints: tuple[Joint, ...], links: tuple[Link, ...]
               ) -> tuple[Joint, ...]:
    """Refuse a flexible link's joint axis that is not normal to the link, and clean the axes that are.

    A flexible link (beam or shell) bends in the plane normal to its joint's axis, so that axis must be normal
    to the link's x axis [1, 0, 0]; it is then stored with x exactly 0, so that round-off within
    ``AXIS_TOLERANCE`` does not couple the planes.  A rigid link turns about any axis.  Returns the joints,
    cleaned.
    """
    out = []
    for i, (joint, link) in enumerate(zip(joints, links, strict=True)):
        if not link.is_rigid:
            if abs(joint.axis[0]) > AXIS_TOLERANCE:
                raise error(source, f"joint[{i + 1}].axis", "a vector normal to the link's x axis [1, 0, 0] "
                            f'(x component 0) — link "{link.name}" is flexible; a rigid link turns about any '
                            "axis, or orient the joint frame with rpy", joint_data[i].get("axis", joint.axis))
            joint = dataclasses.replace(joint, axis=(0.0, joint.axis[1], joint.axis[2]))
        out.append(joint)
    return tuple(out)


def trajectory_needs_position(source: str, key: str, drive: str) -> None:
    """Refuse a trajectory on a joint not driven in position: only a position drive follows a prescribed angle."""
    if drive != "position":
        raise SceneError(f'{source}: {key}.trajectory: expected only with drive = "position", '
                         f'got drive = "{drive}"')


# ----------------------------------------------------------------------------------------------- link


def no_shell_material(source: str, key: str, t: dict[str, Any]) -> None:
    """Refuse E and poisson on a beam: a beam's section stiffness is EI, and a second source could disagree."""
    for k in ("E", "poisson"):
        if k in t:
            raise error(source, f"{key}.{k}", 'no value: E and poisson are for shell links (shapes.kind = "shell"); '
                        "a beam takes EI", t[k])


def mass_per_length_given_once(source: str, key: str, t: dict[str, Any]) -> bool:
    """Exactly one way to give the mass per length, so that the two can never disagree; True: linear_density."""
    has_lin = "linear_density" in t
    has_vol = "density" in t or "area" in t
    if has_lin and has_vol:
        extra = "density" if "density" in t else "area"
        raise error(source, f"{key}.{extra}", "either linear_density (kg/m) or density and area, not both", t[extra])
    if not has_lin and not has_vol:
        raise error(source, f"{key}.linear_density", "a positive number (kg/m), or density (kg/m³) and area (m²)")
    return has_lin


def only_for_rigid(source: str, key: str, t: dict[str, Any], body_keys: tuple[str, ...]) -> None:
    """A flexible link's mass is its linear density: a body's mass, centre and inertia are refused."""
    for k in body_keys:
        if k in t:
            raise error(source, f"{key}.{k}", "no value: only for a rigid link (deformation = []); a flexible "
                        "link's mass is its linear_density", t[k])


def not_for_rigid(source: str, key: str, t: dict[str, Any]) -> None:
    """Stiffness, damping, shape functions, kinematics and a static start mean nothing for a rigid link."""
    for k in NOT_RIGID:
        if k in t:
            raise error(source, f"{key}.{k}", "no value: not used by a rigid link (deformation = []); remove it",
                        t[k])
    if t.get("initial_deformation") == "static":
        raise error(source, f"{key}.initial_deformation", 'no value other than "undeformed": not used by a '
                    "rigid link (deformation = []); remove it", t["initial_deformation"])


def rigid_mass_form(source: str, key: str, t: dict[str, Any], body_keys: tuple[str, ...]) -> bool:
    """Which single form a rigid link's mass properties take; True: a body.

    They come from exactly one form, so that two can never disagree: a uniform rod (linear_density, or density
    and area) or a body (mass, with center_of_mass and inertia).
    """
    body = [k for k in body_keys if k in t]
    rod = [k for k in ("linear_density", "density", "area") if k in t]
    if body and rod:
        raise error(source, f"{key}.{body[0]}", f"no value: {rod[0]} makes this rigid link a uniform rod; give "
                    "either linear_density (or density and area) or mass, center_of_mass and inertia, not both",
                    t[body[0]])
    if not body and not rod:
        raise error(source, f"{key}.mass", "a number ≥ 0 (kg), with center_of_mass and inertia, or linear_density "
                    "(kg/m) for a uniform rod: a rigid link needs its mass")
    if body and "mass" not in t:
        raise error(source, f"{key}.mass", f"a number ≥ 0 (kg) because {body[0]} is given (a rigid body)")
    return bool(body)


def no_polar_inertia_with_body(source: str, key: str, t: dict[str, Any]) -> None:
    """Refuse polar_inertia on a rigid body given by mass: its inertia tensor already holds that moment."""
    if "polar_inertia" in t:
        raise error(source, f"{key}.polar_inertia", "no value: the polar inertia of a uniform rod "
                    "(linear_density); a rigid body given by mass takes inertia", t["polar_inertia"])


def physical_inertia(source: str, key: str, raw: Any, values: tuple[float, ...]) -> None:
    """Refuse an inertia (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) about the centre of mass that no body has.

    A body's tensor is positive semi-definite and its principal moments satisfy the triangle inequalities
    (I1 ≤ I2 + I3 …; equivalently ∫ρ r rᵀ is positive semi-definite), to a tolerance relative to the largest
    moment.  An unphysical tensor would give a mass matrix that is positive definite and yet wrong, or a model
    that gains energy.
    """
    scale = max(abs(v) for v in values)
    if scale == 0.0:
        return
    ixx, iyy, izz, ixy, ixz, iyz = (v / scale for v in values)          # in units of the largest entry: no overflow
    moments = np.linalg.eigvalsh(np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
    tol = INERTIA_TOLERANCE * float(np.max(np.abs(moments)))
    shown = ", ".join(f"{m * scale:.6g}" for m in moments)
    if moments[0] < -tol:
        raise error(source, key, f"a positive semi-definite inertia tensor (principal moments {shown} kg m²)", raw)
    diagonal = (ixx, iyy, izz)
    if not any(values[3:]):                     # principal axes: say which inequality fails
        for i, rule in enumerate(("Ixx ≤ Iyy + Izz", "Iyy ≤ Ixx + Izz", "Izz ≤ Ixx + Iyy")):
            if diagonal[i] > sum(diagonal) - diagonal[i] + tol:
                raise error(source, key, f"the inertia tensor of a body: {rule} (the triangle inequalities)", raw)
    elif moments[2] > moments[0] + moments[1] + tol:
        raise error(source, key, f"the inertia tensor of a body: its principal moments (here {shown} kg m²) "
                    "satisfying the triangle inequalities, the largest ≤ the sum of the other two", raw)


def density_times_area(source: str, key: str, t: dict[str, Any], density: float, area: float) -> float:
    """The mass per length ρA, refused when the product overflows or vanishes although each factor passed."""
    rho_a = density * area
    if not (rho_a > 0 and math.isfinite(rho_a)):
        raise error(source, f"{key}.area", "density·area to be a positive finite number (kg/m)", t["area"])
    return rho_a


def deformation_data(source: str, key: str, deformation: tuple[str, ...], given: dict[str, float]) -> None:
    """Each deformation field needs its stiffness (and torsion its section's polar inertia)."""
    if "w" in deformation and "EI_out" not in given:
        raise error(source, f"{key}.EI_out", 'a positive number (N m²) because deformation includes "w"')
    if "alpha" in deformation:
        for k, what in (("GJ", "a positive number (N m²)"), ("polar_inertia", "a number ≥ 0 (kg m)")):
            if k not in given:
                raise error(source, f"{key}.{k}", f'{what} because deformation includes "alpha"')


def beam_modes(source: str, key: str, kind: str, count: int, modes: int | None) -> None:
    """Refuse ``modes`` on a basis that is not reduced, or more modes than the finite elements have coordinates."""
    if modes is not None and kind != "fe":
        raise error(source, f"{key}.modes", 'no value: only finite-element links (kind = "fe" or "shell") are '
                    "reduced to modes", modes)
    if modes is not None and modes > 2 * count:
        raise error(source, f"{key}.modes", f"at most {2 * count} (2 coordinates per element)", modes)


# ---------------------------------------------------------------------------------------------- shell


def plate_has_no_height(source: str, key: str, t: dict[str, Any]) -> None:
    """Refuse a height on a plate section: only a box has one, and an ignored key would hide a mistake."""
    if "height" in t:
        raise error(source, f"{key}.height", 'no value: a plate has no height (section = "box" has)', t["height"])


def thin_wall(source: str, key: str, thickness: float, width: float, height: float | None) -> None:
    """Refuse a wall thicker than half the section: the shell model holds for thin walls only."""
    if not thickness < min(width, height or width) / 2:
        raise error(source, f"{key}.thickness", "a thickness below half the width and height (a thin wall)",
                    thickness)


def symmetric_mesh(source: str, key: str, what: str, mesh: list[int], pattern: str) -> None:
    """Refuse an odd count across a symmetric mesh: its pattern mirrors the diagonals about the mid-line."""
    if pattern == "symmetric" and any(m % 2 for m in mesh[1:]):
        raise error(source, f"{key}.mesh", f"{what} with even counts across (the symmetric pattern mirrors the "
                    'diagonals about the mid-line), or pattern = "A" or "B"', mesh)


def shell_modes(source: str, key: str, section: str, mesh: list[int], modes: int | None) -> None:
    """Refuse more modes than the shell mesh has translational degrees of freedom off the root."""
    nx, nw = mesh[0], mesh[1]
    with_mass = 3 * nx * (2 * (nw + mesh[2]) if section == "box" else nw + 1)   # translations off the root
    if modes is not None and modes > with_mass:
        raise error(source, f"{key}.modes", f"at most {with_mass} (the mesh's translational degrees of freedom "
                    "off the root)", modes)


# ------------------------------------------------------------------------------------------------ fmu


def tunable_names(source: str, value: Any, joints: tuple[Joint, ...], links: tuple[Link, ...]) -> tuple[str, ...]:
    """Check that ``[fmu] tunable`` names parameters of this scene's joints and links, once each.

    A misspelt name is refused with the closest valid one, rather than exported as a parameter nothing reads.
    Returns the names, in the order given.
    """
    allowed = ["gravity"]
    allowed += [f"{link.name}.{p}" for link in links for p in LINK_TUNABLE
                if not (link.is_rigid and p == "kelvin_voigt")]          # a rigid link has no damping
    allowed += [f"{joint.name}.{p}" for joint in joints for p in JOINT_TUNABLE]
    forms = ("<link>.kelvin_voigt, <link>.payload.mass, <link>.payload.inertia, <joint>.stiffness, "
             "<joint>.damping or gravity")
    if not isinstance(value, list):
        raise error(source, "fmu.tunable", f"a list of FMU parameter names ({forms})", value)
    out: list[str] = []
    for i, item in enumerate(value):
        key = f"fmu.tunable[{i + 1}]"
        if not isinstance(item, str) or item not in allowed:
            close = difflib.get_close_matches(item, allowed, n=1) if isinstance(item, str) else []
            hint = f' (did you mean "{close[0]}"?)' if close else ""
            raise error(source, key, f"a parameter name of this scene: {forms}{hint}", item)
        if item in out:
            raise error(source, key, "a parameter not already listed", item)
        out.append(item)
    return tuple(out)
