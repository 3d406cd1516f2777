"""``flexlink explain``: what a scene's model contains and why, its frequencies, and a step for SS22.

With ``--error-target``, the cheapest model level that is accurate enough (``flexlink.tools.fidelity``).
"""

from __future__ import annotations

import numpy as np

from flexlink.export.codegen import generated_functions, newton_matrix_template
from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.fidelity import (
    MAX_HALVINGS,
    STEPS_PER_PERIOD,
    check_level,
    checked_recommendation,
    run_ladder,
)

# the generated functions a Co-Simulation step evaluates (fmu_src/ss22.c, cs_step.c, guards.c), and with a
# Newton matrix of exact columns ([fmu] newton_matrix = "columns") the forward derivative it is made of; the rest
# serve the directional derivatives, or a parameter change (parameter_check)
CO_SIMULATION_STEP_FUNCTIONS = ("residual", "newton_matrix", "mass_matrix", "outputs", "model_validity")


def _fmt(vector) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in vector) + "]"


def body_lines(scene) -> list[str]:
    """One line per joint and the body it drives, base to tip.

    The joint's axis, drive and placement, the link's kind, size and mass (what the chain is made of, before
    any model is built).
    """
    lines = []
    for joint, link in zip(scene.joints, scene.links, strict=True):
        where = ""
        if any(joint.origin) or any(joint.rpy):
            where = f", at origin {_fmt(joint.origin)} rpy {_fmt(joint.rpy)}"
        elastic = f", elastic ({joint.stiffness:g} N m/rad)" if joint.is_elastic else ""
        if link.is_rigid:
            mass, centre, inertia = link.rigid_body()
            kind = f"rigid, {mass:.4g} kg, centre {_fmt(centre)}" if mass > 0 else "rigid, massless"
            if mass == 0 and np.any(inertia):
                kind = "rigid rotor (no mass, an inertia)"
            elif link.length == 0 and mass == 0:
                kind = "massless connector: joints at one point"
        elif link.is_shell:
            kind = f"{link.shapes.section} shell, {link.kinematics}"
        else:
            kind = f"beam {'+'.join(link.deformation)}, {link.kinematics}, {link.linear_density * link.length:.4g} kg"
        payload = f", payload {link.payload.mass:g} kg" if link.payload.is_present else ""
        lines.append(f'joint "{joint.name}" (axis {_fmt(joint.axis)}, {joint.drive}{elastic}{where}) -> '
                     f'link "{link.name}" ({kind}, length {link.length:g} m{payload})')
    if any(scene.tool.origin) or any(scene.tool.rpy):
        lines.append(f"tool frame: origin {_fmt(scene.tool.origin)} rpy {_fmt(scene.tool.rpy)} in the last tip frame")
    return lines


def explain(scene_path) -> dict:
    """What ``flexlink explain`` reports on a scene file, as JSON-ready data."""
    scene = load_scene(scene_path)
    model = build_model(scene)
    modes = natural_frequencies(model)
    f_max = max(modes.frequencies_hz) if modes.frequencies_hz else 0.0
    step = 1.0 / (STEPS_PER_PERIOD * f_max) if f_max > 0 else scene.fmu.solver.step
    functions = generated_functions(model)
    return {
        "scene": scene.name,
        "bodies": body_lines(scene),
        "coordinates": model.coordinates,
        "prescribed": [law.joint for law in model.laws],
        "terms": model.terms,
        "parameters": [p.name for p in model.parameters],
        "inputs": [s.name for s in model.inputs if s.fmu_variable],
        "outputs": len(model.outputs),
        "linear_in_state": model.linear_in_state,
        "jacobian_constant": model.jacobian_constant,
        "input_matrix_constant": model.input_matrix is not None,
        # the inputs that are forces (joint torques, tip loads), not a kinematic law's angle, rate, acceleration
        "force_inputs": [s.name for i, s in enumerate(model.inputs)
                         if not any(law.u_offset <= i < law.u_offset + 3 for law in model.laws)],
        "operations": {"residual": int(model.residual.expand().n_instructions()),
                       "outputs": int(model.outputs_function.expand().n_instructions())},
        "generated_operations": {name: ops for name, (_, ops) in functions.items()},
        "matrix_graph": [name for name, (f, _) in functions.items() if not f.is_a("SXFunction")],
        "newton_columns_exact": newton_matrix_template(model) == "newton_matrix_columns.c.in",
        # codegen.mass_by_differences: no generated mass matrix, M from the residual
        "mass_by_differences": (newton_matrix_template(model) == "newton_matrix_differences.c.in"
                                and "mass_matrix" not in functions),
        "directional_derivatives": ("none" if not scene.fmu.directional_derivatives else
                                    "forward mode" if "forward" in functions else "complex step"),
        "frequencies_hz": modes.frequencies_hz,
        "unstable_hz": modes.unstable_hz,
        "recommended_step": step,
        "scene_step": scene.fmu.solver.step,
    }


def _derivatives_line(how: str) -> str:
    """How fmi2GetDirectionalDerivative's forward derivatives are computed, in one line."""
    if how == "none":
        return "no directional derivatives ([fmu] directional_derivatives = false)"
    if how == "complex step":
        return ("directional derivatives: the complex step on the residual and outputs (no derivative code; "
                "each costs a few residuals)")
    return "directional derivatives: CasADi's forward-mode functions (the generated \"forward\" above)"


def format_explanation(info: dict) -> str:
    """The text ``flexlink explain`` prints for :func:`explain`'s data."""
    lines = [f"{info['scene']}: joints and the bodies they drive, base to tip"]
    lines += [f"  {b}" for b in info["bodies"]]
    lines.append(f"{len(info['coordinates'])} coordinates")
    lines += [f"  {c}" for c in info["coordinates"]]
    if info["prescribed"]:
        lines.append("prescribed (position-driven) joints: " + ", ".join(info["prescribed"]))
    lines.append("terms in the model:")
    lines += [f"  - {t}" for t in info["terms"]]
    lines.append("tunable parameters: " + ", ".join(info["parameters"]))
    lines.append("inputs: " + (", ".join(info["inputs"]) or "none") + f"; {info['outputs']} outputs")
    if info.get("force_inputs"):
        lines.append("  the force inputs' generalized forces: " + (
            "a constant matrix times the inputs (the energy guard evaluates no residual for them)"
            if info.get("input_matrix_constant") else
            "residual differences in the energy guard (they depend on the state, or the model has laws)"))
    eq = ("linear in the state, constant step matrix (factorised once)" if info["jacobian_constant"] else
          "linear in the state (one solve per step)" if info["linear_in_state"] else
          "nonlinear (Newton iterations in every SS22 step)")
    lines.append(f"equations: {eq}; {info['operations']['residual']} operations per residual")
    generated = info["generated_operations"]
    lines.append(f"generated C: {sum(generated.values())} operations (scalar, after CSE) in "
                 + ", ".join(f"{name} {ops}" for name, ops in generated.items()))
    in_step = set(CO_SIMULATION_STEP_FUNCTIONS) | ({"forward"} if info.get("newton_columns_exact") else set())
    step = sum(ops for name, ops in generated.items() if name in in_step)
    if info.get("matrix_graph"):
        why = ("every function: the model has more than EXPAND_MAX_COORDINATES coordinates"
               if len(info["matrix_graph"]) == len(generated) else
               "off-step functions past REFRESH_EXPAND_MAX_OPERATIONS as scalar code")
        lines.append(f"  generated from CasADi's matrix graph (loops over constant arrays; {why}): "
                     + ", ".join(info["matrix_graph"]))
    lines.append(f"  a Co-Simulation step evaluates {step} of them (residual, Newton matrix or mass matrix and the "
                 "directional derivatives where [fmu] newton_matrix = \"columns\" asks for them, validity, outputs)")
    if info.get("mass_by_differences"):
        lines.append(f"  mass matrix: from {len(info['coordinates']) + 1} residuals (r is affine in the "
                     "accelerations; generated, it would be a large matrix graph)")
    lines.append("  " + _derivatives_line(info.get("directional_derivatives", "forward mode")))
    freqs = info["frequencies_hz"]
    lines.append("natural frequencies (Hz): " + ", ".join(f"{f:.4g}" for f in freqs[:12])
                 + (f", … ({len(freqs)} in all)" if len(freqs) > 12 else ""))
    if info["unstable_hz"]:
        lines.append("UNSTABLE modes (|ω|, Hz): " + ", ".join(f"{f:.4g}" for f in info["unstable_hz"]))
    if freqs:
        lines.append(f"recommended SS22 step: {info['recommended_step']:.3g} s ({STEPS_PER_PERIOD} steps per period of "
                     f"the highest mode, {freqs[-1]:.4g} Hz; scene: {info['scene_step']:.3g} s). Larger steps stay "
                     "bounded; with Θ > ½ they filter the unresolved modes out (seed 001 §3.4).")
        if info["scene_step"] * freqs[-1] > 0.5:
            lines.append(f"  note: the scene's step leaves modes above {0.05 / info['scene_step']:.4g} Hz unresolved "
                         f"({sum(f * info['scene_step'] <= 0.05 for f in freqs)} of {len(freqs)} resolved)")
    return "\n".join(lines)


# ------------------------------------------------------------------------- --error-target (flexlink.tools.fidelity)

def fidelity(scene_path, error_target: float, *, quick: bool = False, progress=None) -> dict:
    """The fidelity ladder of the scene and the cheapest level that meets ``error_target``.

    The level must meet it on the ladder's manoeuvre and again when its FMU is checked directly against the
    truth on a second manoeuvre (a level whose model and integration errors cancelled on the first is not
    recommended on that luck).
    """
    from flexlink.scene.loader import load_scene

    scene = load_scene(scene_path)
    ladder = run_ladder(scene, target=error_target, quick=quick, progress=progress)
    candidates = [r for r in ladder.rungs if r.model_error < error_target and r.error < error_target]
    best, checks = checked_recommendation(candidates, lambda rung: check_level(
        scene, rung, ladder.truth.level, ladder.stop_time, error_target, progress))
    recommendation = None
    if best is not None:
        recommendation = {**best.as_dict(), "checked_error": checks[-1].error, "check": checks[-1].as_dict()}
    return {"error_target": error_target, "outputs": ladder.outputs, "stop_time": ladder.stop_time,
            "reference_error": ladder.reference_error, "ladder": [r.as_dict() for r in ladder.rungs],
            "recommendation": recommendation, "checks": [c.as_dict() for c in checks], "notes": ladder.notes}


def _format_checks(info: dict) -> list[str]:
    """The candidates the direct check turned down (their ladder errors had cancelled)."""
    errors = {r["level"]: r["error"] for r in info["ladder"]}
    return [f"  not recommended: {c['level']}: error {errors[c['level']]:.2e} on the ladder's manoeuvre but "
            f"{c['error']:.2e} on the check manoeuvre ({c['manoeuvre']}): its errors cancelled on the first"
            for c in info["checks"] if not c["passed"]]


def format_fidelity(info: dict) -> str:
    """The text ``flexlink explain --error-target`` prints for the ladder and its recommendation."""
    target = info["error_target"]
    rows = info["ladder"]
    best = info["recommendation"]
    width = max(len(r["level"]) for r in rows)
    lines = [f"fidelity ladder, cheapest first (relative RMS error of {', '.join(info['outputs'])} against the truth "
             f"over {info['stop_time']:g} s of the bench manoeuvre; truth: the top level under CVODES, accurate to "
             f"{info['reference_error']:.1e}):",
             f"  {'level':{width}s}  coords  model err  SS22 step  integr. err      error  CPU s/sim s"]
    for r in rows:
        marks = (["<- recommended"] if best is not None and r["level"] == best["level"] else []) \
            + (["truth"] if r["truth"] else []) + (["the scene's"] if r["scene_level"] else [])
        lines.append(f"  {r['level']:{width}s}  {r['coordinates']:6d}  {r['model_error']:9.2e}  {r['step']:9.3g}  "
                     f"{r['integration_error']:11.2e}  {r['error']:9.2e}  {r['cpu_s_per_simulated_s']:11.3g}"
                     + (f"  ({', '.join(marks)})" if marks else ""))
    lines += ["  model err: the level's equations against the truth's, both under CVODES (truncation alone);",
              "  integr. err: its FMU at the SS22 step shown against its own equations; error: the FMU against the "
              "truth. The step is explain's (20 per period of the level's highest mode), halved (at most "
              f"{MAX_HALVINGS} times) while the model error meets the target and the error does not."]
    lines += [f"  note: {n}" for n in info["notes"]]
    lines += _format_checks(info)
    if best is None and info["checks"]:
        lines.append(f"no level meets the error target {target:g} when checked directly (the cheapest "
                     f"{len(info['checks'])} that met it on the ladder's manoeuvre were checked)")
        return "\n".join(lines)
    if best is None:
        closest = min(rows, key=lambda r: max(r["model_error"], r["error"]))
        lines.append(f"no level meets the error target {target:g}: the closest is {closest['level']} "
                     f"(model error {closest['model_error']:.2e}, error {closest['error']:.2e} at step "
                     f"{closest['step']:.3g} s)")
        return "\n".join(lines)
    lines.append(f"recommended for an error target of {target:g}: {best['level']} ({best['coordinates']} "
                 f"coordinates) at SS22 step {best['step']:.3g} s: error {best['error']:.2e} (model "
                 f"{best['model_error']:.2e}), {best['cpu_s_per_simulated_s']:.3g} CPU s per simulated s")
    check = best["check"]
    lines.append(f"  checked directly: its FMU at that step against the truth under CVODES on a second manoeuvre "
                 f"({check['manoeuvre']}): error {check['error']:.2e} ("
                 + ", ".join(f"{n} {e:.2e}" for n, e in check["errors"].items()) + ")")
    if best["truth"]:
        lines.append("  that is the truth itself: its own error against a finer model is not measured here")
    own = next((r for r in rows if r["scene_level"]), None)
    if own is not None and own["level"] != best["level"]:
        lines.append(f"  the scene's own level ({own['level']}): error {own['error']:.2e} at step "
                     f"{own['step']:.3g} s, {own['cpu_s_per_simulated_s']:.3g} CPU s per simulated s")
    return "\n".join(lines)
