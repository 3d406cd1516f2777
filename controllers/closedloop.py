"""Linear closed-loop prediction with python-control: what the FMU-in-the-loop run should give.

* :func:`sampled_plant` — the plant as a sampled-data master sees it through FMI: zero-order hold on
  the torque, outputs read at t_k while u_{k−1} is still applied (``y_k = C x_k + D u_{k−1}``).
* :func:`closed_loop` — that plant and a law's :meth:`~controllers.laws.SampledLaw.statespace`,
  connected by ``control.interconnect``; inputs ``xref[i]``, ``uff``; outputs the plant's outputs and the
  torque.
* :func:`predict` — ``control.forced_response`` of the closed loop to a reference: named time series.
* :func:`loop_transfer` — the loop broken at the torque input, ``L(z) = −C_y(z) P(z)``, for Bode plots and
  ``control.stability_margins``.
"""

from __future__ import annotations

from collections.abc import Sequence

import control as ct
import numpy as np

from controllers.laws import SampledLaw, reference_names
from controllers.trajectory import Reference
from flexlink.run.linearize import LinearPlant, signal_name

__all__ = ["closed_loop", "loop_transfer", "margins", "predict", "sampled_plant"]


def sampled_plant(plant: LinearPlant, dt: float, outputs: Sequence[str] | None = None) -> ct.StateSpace:
    """ZOH-sampled plant whose outputs at t_k see the torque held over the previous sample.

    With D ≠ 0 on the chosen outputs the state is augmented with ``u_prev`` (named ``<input>_prev``).
    """
    rows = list(range(len(plant.outputs))) if outputs is None else [plant.output_row(o) for o in outputs]
    names = [plant.outputs[r] for r in rows]
    sd = ct.sample_system(plant.sys, dt, method="zoh")
    A, B = np.asarray(sd.A), np.asarray(sd.B)
    C, D = np.asarray(sd.C)[rows], np.asarray(sd.D)[rows]
    states = list(plant.sys.state_labels)
    if np.any(D != 0):
        n, m = A.shape[0], B.shape[1]
        A = np.block([[A, np.zeros((n, m))], [np.zeros((m, n + m))]])
        B = np.vstack([B, np.eye(m)])
        C = np.hstack([C, D])
        D = np.zeros_like(D)
        states += [signal_name(i) + "_prev" for i in plant.inputs]
    return ct.ss(A, B, C, D, dt, inputs=[signal_name(i) for i in plant.inputs],
                 outputs=[signal_name(o) for o in names], states=states, name="plant")


def closed_loop(plant: LinearPlant, law: SampledLaw, outputs: Sequence[str] | None = None) -> ct.StateSpace:
    """The discrete closed loop of the unsaturated law on the sampled linear plant, as one state-space system.

    Inputs ``xref[i]``, ``uff``; outputs the plant's ``outputs`` (FMU names, default all of the plant's) then
    the torque: the linear prediction a run through the FMU is compared with.
    """
    outputs = list(plant.outputs if outputs is None else outputs)
    needed = list(dict.fromkeys([*outputs, *law.sensors]))
    P = sampled_plant(plant, law.dt, needed)
    K = law.statespace()
    u_name = signal_name(law.input)
    refs = reference_names(law.n)
    return ct.interconnect([P, K], inplist=refs, inputs=refs,
                           outlist=[f"plant.{signal_name(o)}" for o in outputs] + [f"plant.{u_name}"],
                           outputs=[signal_name(o) for o in outputs] + [u_name], name="closed_loop",
                           check_unused=False)


def predict(plant: LinearPlant, law: SampledLaw, reference: Reference, outputs: Sequence[str]) -> dict:
    """The predicted closed-loop response to ``reference`` (python-control ``forced_response``).

    A dict of named time series in absolute values (operating point added), ``time`` and the torque under
    the input's name: the same names as a run through the FMU, so that the two plot together.
    """
    cl = closed_loop(plant, law, outputs)
    U = np.vstack([reference.x.T, reference.u_ff[None, :]])
    resp = ct.forced_response(cl, T=reference.time, U=U)
    y = np.atleast_2d(resp.outputs)
    out = {"time": reference.time.copy()}
    for i, name in enumerate(outputs):
        out[name] = y[i] + plant.y0[plant.output_row(name)]
    out[law.input] = y[len(outputs)] + law.u0
    return out


def loop_transfer(plant: LinearPlant, law: SampledLaw) -> ct.StateSpace:
    """The loop broken at the torque input, where a gain or delay error of the actuator enters.

    ``L = −C_y P`` (negative-feedback convention of ``control.stability_margins``), C_y the law from the
    measurements to the torque.
    """
    P = sampled_plant(plant, law.dt, law.sensors)
    K = law.statespace()
    Ky = K[:, : len(law.sensors)]
    return ct.series(P, -Ky)


def margins(plant: LinearPlant, law: SampledLaw, n_points: int = 20000) -> dict:
    """Classical margins of the loop broken at the torque input, and closed-loop stability from the poles.

    The margins come from its frequency response on a dense logarithmic grid up to the Nyquist frequency.

    Returns a dict: ``gain_margin_db`` (smallest gain increase that destabilises, dB, ``inf`` if none),
    ``gain_reduction_margin_db`` (largest gain decrease tolerated, negative dB, ``-inf`` if none — with a
    rigid-body joint the loop is conditionally stable), ``phase_margin_deg`` (the smallest phase change that
    destabilises) and ``phase_margin_sense``, the crossover frequencies in Hz and every crossover
    (:func:`controllers.crossovers.loop_margins`, each refined on the loop's exact response),
    ``stability_margin`` (min |1 + L|, the distance of the Nyquist curve to −1) and ``stable`` (closed-loop
    poles inside the unit circle, python-control).
    """
    from controllers.crossovers import loop_margins, unstable_poles
    from controllers.robustness import response

    L = loop_transfer(plant, law)
    w = np.logspace(-3, np.log10(np.pi / law.dt), n_points)[:-1]

    def evaluate(x: np.ndarray) -> np.ndarray:
        return response(L, x)[:, 0, 0]

    Lw = evaluate(w)
    m = loop_margins(Lw, w, evaluate, open_loop_unstable=unstable_poles(L.poles(), law.dt))
    peak = m.pop("peak_sensitivity")
    cl = closed_loop(plant, law, [law.sensors[0]])
    return {**m, "stability_margin": 1.0 / peak,
            "stable": bool(np.all(np.abs(cl.poles()) < 1.0))}


def margin_entries(gms, pms, wpcs, wgcs) -> dict:
    """The margins of a loop from all its crossovers: the worst of each kind, and where they are.

    From the gains 1/|L| at the phase crossovers wpcs [rad/s] and the phase margins at the gain crossovers
    wgcs: the smallest gain increase and decrease, the smallest phase margin, and where they are [Hz];
    inf/−inf/nan where there is none.
    """
    gms, pms = np.asarray(gms, dtype=float), np.asarray(pms, dtype=float)
    up, down = np.flatnonzero(gms > 1), np.flatnonzero(gms < 1)
    k_up = up[np.argmin(gms[up])] if len(up) else None
    k_dn = down[np.argmax(gms[down])] if len(down) else None
    k_pm = int(np.argmin(np.abs(pms))) if len(pms) else None
    hz = 1 / (2 * np.pi)
    return {
        "gain_margin_db": float(20 * np.log10(gms[k_up])) if k_up is not None else float("inf"),
        "gain_reduction_margin_db": float(20 * np.log10(gms[k_dn])) if k_dn is not None else float("-inf"),
        "phase_margin_deg": float(pms[k_pm]) if k_pm is not None else float("inf"),
        "gain_crossover_hz": float(wgcs[k_pm] * hz) if k_pm is not None else float("nan"),
        "phase_crossover_hz": float(wpcs[k_up] * hz) if k_up is not None else float("nan"),
    }
