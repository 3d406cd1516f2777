"""``flexlink explain``: what a scene's model contains and why, its frequencies, and a step for SS22."""

from __future__ import annotations

from flexlink.analysis import natural_frequencies
from flexlink.model import build_model
from flexlink.scene import load_scene

STEPS_PER_PERIOD = 20     # Θ = ½: phase error per period ≈ (2π/20)²/12 · 2π ≈ 0.5 %


def explain(scene_path) -> dict:
    scene = load_scene(scene_path)
    model = build_model(scene)
    modes = natural_frequencies(model)
    f_max = max(modes.frequencies_hz) if modes.frequencies_hz else 0.0
    step = 1.0 / (STEPS_PER_PERIOD * f_max) if f_max > 0 else scene.fmu.step
    return {
        "scene": scene.name,
        "coordinates": model.coordinates,
        "prescribed": [law.joint for law in model.laws],
        "terms": model.terms,
        "parameters": [p.name for p in model.parameters],
        "inputs": [s.name for s in model.inputs if s.fmu_variable],
        "outputs": len(model.outputs),
        "linear_in_state": model.linear_in_state,
        "jacobian_constant": model.jacobian_constant,
        "operations": {"residual": int(model.residual.expand().n_instructions()),
                       "outputs": int(model.outputs_function.expand().n_instructions())},
        "frequencies_hz": modes.frequencies_hz,
        "unstable_hz": modes.unstable_hz,
        "recommended_step": step,
        "scene_step": scene.fmu.step,
    }


def format_explanation(info: dict) -> str:
    lines = [f"{info['scene']}: {len(info['coordinates'])} coordinates"]
    lines += [f"  {c}" for c in info["coordinates"]]
    if info["prescribed"]:
        lines.append("prescribed (position-driven) joints: " + ", ".join(info["prescribed"]))
    lines.append("terms in the model:")
    lines += [f"  - {t}" for t in info["terms"]]
    lines.append("tunable parameters: " + ", ".join(info["parameters"]))
    lines.append("inputs: " + (", ".join(info["inputs"]) or "none") + f"; {info['outputs']} outputs")
    eq = ("linear in the state, constant step matrix (factorised once)" if info["jacobian_constant"] else
          "linear in the state (one solve per step)" if info["linear_in_state"] else
          "nonlinear (Newton iterations in every SS22 step)")
    lines.append(f"equations: {eq}; {info['operations']['residual']} operations per residual")
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
