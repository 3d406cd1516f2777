"""Robustness of a multi-joint design: margins at each actuator and at all of them at once.

Loop-at-a-time margins at each actuator, peak sensitivity, closed-loop poles (python-control), and the
simultaneous disk margin at all actuators (:mod:`controllers.diskmargin`).

Two loops are examined, each ``u = K_c(y)`` around the plant with the joint torques as inputs:

* ``"lqr"`` — the continuous LQR as full state feedback, ``u = −K x`` (the textbook loop: at every
  actuator ≥ 60° phase margin, gain margin unbounded upwards and −6 dB downwards);
* ``"lqg"`` — what runs: the plant sampled with a zero-order hold at the sample time (outputs at t_k with
  the previous torque still applied, as the co-simulation master reads them) and the discrete LQR on the
  Kalman filter's estimate (:func:`lqg_compensator`).

**Loop at a time.** At actuator i the loop is broken with the others closed: with ``T = K_c P`` (torques
in → torques asked for), closing the other channels gives ``T_cl = T (I − E_o T)⁻¹`` (``control.feedback``,
positive sign, ``E_o`` the selector of the other channels) and ``L_i = −T_cl[i, i]`` in the
negative-feedback convention of ``control.stability_margins``, whose bracketing of the crossovers on a dense
grid :func:`controllers.crossovers.loop_margins` follows, each crossover then refined on the loop's exact
response (python-control refines on the grid's spline, which missed a sharp phase crossover by 0.013 dB; its
polynomial method loses the digits on these high-order loops).  The phase margin is the smallest phase change,
lag or lead, that destabilises, with its sense and the loop's open-loop unstable poles that make a lead
possible (:mod:`controllers.crossovers`).  The peak sensitivity is that of the loop at each actuator,
``1/min|1 + L_i|``, and of all loops together at the plant input, ``max_ω σ̄((I − T)⁻¹)``.  The balanced disk
margin at each actuator is ``control.disk_margins`` of the same broken loop (:func:`disk_margins`, skew
:data:`DISK_SKEW`).

**Speed.** T's response is computed once per loop (:func:`response`) and each broken loop's follows by the
algebra of ``control.feedback`` at each frequency, where evaluating each broken loop's state space took
most of the six-axis arm's 16 s of margins.  The figures are python-control's own (``benchmarks/margins.py``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any, NoReturn

import control as ct
import numpy as np
from numpy.typing import ArrayLike

from controllers.crossovers import loop_margins, unstable_poles
from controllers.design import KalmanDesign, LQRDesign, torque_inputs
from controllers.diskmargin import MultiLoopMargin, multiloop_disk_margin

__all__ = ["DISK_SKEW", "broken_loop_system", "compensator", "delayed_plant", "delayed_robustness", "disk_margins",
           "loop_at_a_time", "lqg_compensator", "lqg_plant", "lu_evaluation", "predictive_compensator", "response",
           "robustness", "robustness_figures"]


def lqg_plant(lqr: LQRDesign, kalman: KalmanDesign) -> ct.StateSpace:
    """The ZOH-sampled plant from the joint torques to the Kalman sensors.

    As the master reads it: ``y_k = C x_k + D u_{k−1}`` (with D ≠ 0 the state is augmented with ``u_{k−1}``).
    """
    Ad, Bd = np.asarray(lqr.plant_d.A), np.asarray(lqr.plant_d.B)
    C, D = kalman.C, kalman.D[:, torque_inputs(lqr.plant)]
    n, m = Bd.shape
    if np.any(D != 0):
        Ad = np.block([[Ad, np.zeros((n, m))], [np.zeros((m, n + m))]])
        Bd = np.vstack([Bd, np.eye(m)])
        C = np.hstack([C, D])
    return ct.ss(Ad, Bd, C, np.zeros((C.shape[0], m)), lqr.dt)


def lqg_compensator(lqr: LQRDesign, kalman: KalmanDesign) -> ct.StateSpace:
    """The discrete LQG from the sensors' deviations to the torques' deviations.

    The discrete LQG from the sensors' deviations to the torques' deviations, ``u = K_c(y)`` (the minus
    sign of the feedback inside): the current estimator of :class:`controllers.laws.LQGLaw` for any number
    of joints, ``x̂ = (I − M C) z − M D u_{k−1} + M y``, ``u = −K_d x̂``, ``z⁺ = A_d x̂ + B_d u``.
    """
    return compensator(lqr.plant_d.A, lqr.plant_d.B, lqr.Kd, kalman.Md, kalman.C,
                       kalman.D[:, torque_inputs(lqr.plant)], lqr.dt)


def compensator(Ad: ArrayLike, Bd: ArrayLike, Kd: ArrayLike, M: ArrayLike, C: ArrayLike, D: ArrayLike,
                dt: float) -> ct.StateSpace:
    """:func:`lqg_compensator` from its matrices (a scheduled law's, interpolated between designs)."""
    Ad, Bd, Kd, M, C, D = (np.asarray(a, dtype=float) for a in (Ad, Bd, Kd, M, C, D))
    n, m = Bd.shape
    F = np.eye(n) - M @ C
    if np.any(D != 0):
        F = np.hstack([F, -M @ D])                  # x̂ from (z, u_prev)
    Acl = Ad - Bd @ Kd
    A = Acl @ F
    B = Acl @ M
    if np.any(D != 0):
        A = np.vstack([A, -Kd @ F])
        B = np.vstack([B, -Kd @ M])
    return ct.ss(A, B, -Kd @ F, -Kd @ M, dt)


def _grid(T: ct.StateSpace, n_points: int) -> np.ndarray:
    if T.isdtime():
        top = np.pi / T.dt
    else:
        p = np.abs(T.poles())
        top = 10.0 * max(float(np.max(p)) if len(p) else 1.0, 1.0)
    return np.logspace(-3, np.log10(top), n_points)[:-1]


def response(sys: ct.StateSpace, w: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Frequency response of a state space on a grid, batched in numpy.

    Frequency response of ``sys`` at w (rad/s; z = e^{jω dt} when sampled), shape (len(w), p, m):
    ``C (xI − A)⁻¹ B + D`` with one LU per frequency, python-control's own fallback evaluation
    (``StateSpace.horner`` without Slycot) batched in numpy.  Slycot's Hessenberg method, which python-control
    takes when Slycot is installed, moves these high-order loops' margins in the fourth digit.
    """
    A, B, C, D = (np.asarray(M, dtype=float) for M in (sys.A, sys.B, sys.C, sys.D))
    x = np.exp(1j * w * sys.dt) if sys.isdtime() else 1j * w
    n = A.shape[0]
    if n == 0:
        return np.broadcast_to(D.astype(complex), (len(w), *D.shape)).copy()
    out = np.empty((len(w), *D.shape), dtype=complex)
    eye = np.eye(n)
    for k in range(0, len(w), chunk):
        xk = x[k:k + chunk, None, None]
        out[k:k + chunk] = C @ np.linalg.solve(xk * eye - A, np.broadcast_to(B, (len(xk), *B.shape))) + D
    return out


def _no_laub(self: ct.StateSpace, x: Any) -> NoReturn:
    raise NotImplementedError("python-control's LU evaluation (controllers.robustness.lu_evaluation)")


@contextmanager
def lu_evaluation() -> Iterator[None]:
    """Inside: python-control's LU evaluation of frequency responses, never Slycot's.

    Inside: python-control evaluates a state space's frequency response with its own LU solve per frequency
    (``StateSpace.horner``'s fallback), not with Slycot's Hessenberg method (``tb05ad``), which it takes when
    Slycot is installed and which is off by 3e-3 relative on the six-axis arm's 88-state loops (the LU
    evaluation of the same loop in a balanced realisation agrees with it to 4e-13).
    """
    original = ct.StateSpace.slycot_laub
    ct.StateSpace.slycot_laub = _no_laub
    try:
        yield
    finally:
        ct.StateSpace.slycot_laub = original


#: The skew of every disk margin: 0, the balanced disk (S − T)/2, symmetric in gain (a gain decrease and
#: its reciprocal increase tolerated alike): the loops here have gain reduction margins as well as increase
#: margins, and neither side is favoured.
DISK_SKEW = 0.0


def broken_loop_system(T: ct.StateSpace, i: int) -> ct.StateSpace:
    """The loop broken at actuator i with the others closed, ``L_i = −T_cl[i, i]``, as a state space.

    ``control.feedback(T, E_o, sign=1)`` (``E_o`` the selector of the other channels), negative-feedback
    convention of ``control.stability_margins``; its poles are those of the loop with channel i open.
    """
    m = T.ninputs
    return -(ct.feedback(T, np.diag([0.0 if j == i else 1.0 for j in range(m)]), sign=1) if m > 1 else T)[i, i]


def disk_margins(L: ct.StateSpace, Tw: np.ndarray, w: np.ndarray, i: int) -> dict[str, float]:
    """The balanced disk margin of the loop broken at actuator i (python-control).

    ``control.disk_margins(L_i, ·, skew=0)`` of the loop broken at actuator i (the others closed; L, from
    :func:`broken_loop_system`), its worst case over the grid w (Tw: T's response on it).

    The balanced margin α tolerates every factor f at that input inside the disk α draws: gains within
    ±``disk_gain_margin_db`` together with phases within ±``disk_phase_margin_deg``.  python-control
    evaluates L_i's state space once per frequency (0.8 s a loop on the six-axis arm's 88-state loops, 24 of
    them), so it is called where the margin is smallest: the 5 grid points around the minimum of
    1/|S_i − ½| from the response already computed (the same quantity: python-control's figures, one
    LU evaluation a frequency, :func:`lu_evaluation`).
    """
    Sw = 1.0 / (1.0 - broken_loop(Tw, i)[:, 0, 0])
    k = int(np.argmin(1.0 / np.abs(Sw - 0.5)))
    near = np.arange(max(k - 2, 0), min(k + 3, len(w)))
    with lu_evaluation(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dm, dgm, dpm = ct.disk_margins(L, w[near], skew=DISK_SKEW, returnall=True)
    j = int(np.argmin(dm))
    return {"disk_margin": float(dm[j]), "disk_gain_margin_db": float(dgm[j]),
            "disk_phase_margin_deg": float(dpm[j]), "disk_margin_hz": float(w[near[j]] / (2 * np.pi))}


def loop_at_a_time(P: ct.StateSpace, Kc: ct.StateSpace | ArrayLike, names: Sequence[str] | None = None,
                   n_points: int = 4000) -> dict[str, Any]:
    """Margins at each actuator and the peak sensitivity of the loop ``u = K_c(P u)``.

    The broken loops' frequency responses come from that of ``T = K_c P`` (:func:`response`, once) by the
    algebra of ``control.feedback`` at each frequency.

    Parameters
    ----------
    P : control.StateSpace
        Plant, m inputs (the actuators).
    Kc : control.StateSpace or (m, p) array
        Controller from P's outputs to the m actuators (feedback sign inside: ``u = K_c y``).
    names : list of str, optional
        The actuators' names (default ``u[i]``).
    n_points : int
        Points of the logarithmic frequency grid (up to Nyquist when sampled).

    Returns
    -------
    dict
        ``actuators``: per actuator ``input``, ``gain_margin_db`` (smallest gain increase that destabilises,
        ``inf`` if none), ``gain_reduction_margin_db`` (largest decrease tolerated, ``-inf`` if none),
        ``phase_margin_deg`` (the smallest phase change that destabilises, ≥ 0), ``phase_margin_sense``
        (``"lag"`` or ``"lead"``), ``gain_crossover_hz``, ``phase_crossover_hz``, ``peak_sensitivity``
        (``1/min|1 + L_i|``), ``open_loop_unstable_poles`` (of L_i), ``gain_crossovers`` and
        ``phase_crossovers`` (every crossover; :func:`controllers.crossovers.loop_margins`), the balanced disk margin
        ``disk_margin``, ``disk_gain_margin_db``, ``disk_phase_margin_deg``, ``disk_margin_hz``
        (:func:`disk_margins`); ``peak_sensitivity`` (all loops, at the plant input), ``disk_skew`` (0),
        ``multiloop``: the simultaneous disk margin at all actuators (0 for an unstable loop)
        (:meth:`controllers.diskmargin.MultiLoopMargin.figures`) and ``multiloop_margin`` (the
        :class:`controllers.diskmargin.MultiLoopMargin` itself, with its destabilising perturbation),
        ``closed_loop_poles`` (s, or z with ``dt``), ``stable``, ``dt``.
    """
    if not isinstance(Kc, ct.StateSpace):
        Kc = ct.ss([], [], [], np.atleast_2d(np.asarray(Kc, dtype=float)), P.dt)
    T = ct.series(P, Kc)
    m = T.ninputs
    names = list(names) if names is not None else [f"u[{i}]" for i in range(m)]
    w = _grid(T, n_points)
    Tw = response(T, w)
    D = np.asarray(T.D, dtype=float)
    out = []
    for i in range(m):
        L = broken_loop_system(T, i)
        Lw, LD = -broken_loop(Tw, i)[:, 0, 0], -broken_loop(D[None], i)[0, 0, 0]

        def evaluate(x: np.ndarray, i: int = i) -> np.ndarray:
            return -broken_loop(response(T, x), i)[:, 0, 0]

        out.append({"input": names[i], **loop_margins(Lw, w, evaluate, LD if T.isctime() else None,
                                                      unstable_poles(L.poles(), T.dt)),
                    **disk_margins(L, Tw, w, i)})
    cl = ct.feedback(T, np.eye(m), sign=1)
    poles = cl.poles()
    stable = bool(np.all(np.abs(poles) < 1.0)) if T.isdtime() else bool(np.all(poles.real < 0))
    # an unstable loop has no margin: no perturbation is needed to destabilise it
    multi = (multiloop_disk_margin(Tw, w, lambda x: response(T, x), D if T.isctime() else None) if stable
             else MultiLoopMargin(0.0, 0.0, math.nan, np.zeros(m, dtype=complex), True))
    S = np.linalg.inv(np.eye(m)[None] - Tw)
    S_peak = float(np.max(np.linalg.svd(S, compute_uv=False)[:, 0]))
    if T.isctime():
        S_peak = max(S_peak, float(np.linalg.svd(np.linalg.inv(np.eye(m) - D), compute_uv=False)[0]))
    return {"actuators": out, "peak_sensitivity": S_peak, "closed_loop_poles": poles, "stable": stable,
            "dt": float(T.dt) if T.isdtime() else 0.0, "disk_skew": DISK_SKEW, "multiloop": multi.figures(),
            "multiloop_margin": multi}


def broken_loop(Tw: np.ndarray, i: int) -> np.ndarray:
    """The loop broken at actuator i, the other channels closed, at each frequency.

    ``T_cl[i, i]`` (shape (N, 1, 1)) of ``T_cl = T (I − E_o T)⁻¹`` at each frequency, the other channels
    closed with positive feedback (``control.feedback(T, E_o, sign=1)``, ``E_o`` their selector).
    """
    m = Tw.shape[-1]
    if m == 1:
        return Tw[:, :1, :1]
    E = np.diag([0.0 if j == i else 1.0 for j in range(m)])
    # row i of T (I − E T)⁻¹ = (I − E T)⁻ᵀ solved for T's row i
    Mt = np.swapaxes(np.eye(m)[None] - E @ Tw, -1, -2)
    row = np.linalg.solve(Mt, Tw[:, i, :, None])
    return row[:, i:i + 1, :]


def robustness(lqr: LQRDesign, kalman: KalmanDesign | None = None, n_points: int = 4000) -> dict[str, dict[str, Any]]:
    """The margins of a design's continuous LQR and sampled LQG.

    :func:`loop_at_a_time` of the continuous LQR state feedback (``"lqr"``) and, with ``kalman``, of the
    sampled LQG (``"lqg"``), the actuators named by their FMU inputs.
    """
    B = np.asarray(lqr.plant.sys.B)[:, torque_inputs(lqr.plant)]
    sys = ct.ss(np.asarray(lqr.plant.sys.A), B, np.eye(lqr.plant.sys.nstates), 0)
    out = {"lqr": loop_at_a_time(sys, -np.asarray(lqr.K), lqr.inputs, n_points)}
    if kalman is not None:
        out["lqg"] = loop_at_a_time(lqg_plant(lqr, kalman), lqg_compensator(lqr, kalman), lqr.inputs, n_points)
    return out


def delayed_plant(lqr: LQRDesign, kalman: KalmanDesign) -> ct.StateSpace:
    """The sampled plant with one sample of computation delay at its inputs.

    :func:`lqg_plant` with one sample of computation delay at its inputs, as a Jacobi master (libcosim's
    fixed-step algorithm) applies a controller FMU's output: ``x⁺ = A_d x + B_d v``, ``v⁺ = u``, ``y = C x``
    (the state augmented with the torque being applied).
    """
    P = lqg_plant(lqr, kalman)
    A, B, C = np.asarray(P.A), np.asarray(P.B), np.asarray(P.C)
    n, m = B.shape
    Aa = np.block([[A, B], [np.zeros((m, n + m))]])
    Ba = np.vstack([np.zeros((n, m)), np.eye(m)])
    return ct.ss(Aa, Ba, np.hstack([C, np.zeros((C.shape[0], m))]), np.zeros((C.shape[0], m)), lqr.dt)


def predictive_compensator(lqr: LQRDesign, kalman: KalmanDesign) -> ct.StateSpace:
    """The predictive LQG for one sample of delay, as a state space.

    The LQG made for that delay (``DELAY 1`` in ``ctrl_fmu.c``, :class:`controllers.ssp.PredictiveLQGLaw`),
    linear part: the estimate corrected with y_k, ``x̂ = F z + M y``, predicted to the next sample with the
    torque it output a sample ago, ``z⁺ = A_d x̂ + B_d v``, and the next sample's torque ``u = −K_d z⁺``,
    which it holds as ``v⁺ = u``.  State (z, v).
    """
    if np.any(kalman.D[:, torque_inputs(lqr.plant)] != 0):
        raise ValueError("the predictive law reads sensors without feedthrough (encoders, strain gauges)")
    Ad, Bd, K, M, C = (np.asarray(a, dtype=float) for a in (lqr.plant_d.A, lqr.plant_d.B, lqr.Kd, kalman.Md,
                                                             kalman.C))
    n, m = Bd.shape
    F = np.eye(n) - M @ C
    Az = np.hstack([Ad @ F, Bd])                     # z⁺ from (z, v)
    A = np.vstack([Az, -K @ Az])
    B = np.vstack([Ad @ M, -K @ Ad @ M])
    return ct.ss(A, B, -K @ Az, -K @ Ad @ M, lqr.dt)


def delayed_robustness(lqr: LQRDesign, kalman: KalmanDesign, n_points: int = 4000) -> dict[str, dict[str, Any]]:
    """The margins of the loops with one sample of computation delay.

    The loops with one sample of computation delay (:func:`delayed_plant`): ``"lqg_delay1"``, the
    predictive LQG that the SSP package's controller FMU runs; ``"lqg_delay1_unaware"``, the LQG designed
    without the delay in that loop (its verdict: what ignoring the delay costs).
    """
    P = delayed_plant(lqr, kalman)
    return {"lqg_delay1": loop_at_a_time(P, predictive_compensator(lqr, kalman), lqr.inputs, n_points),
            "lqg_delay1_unaware": loop_at_a_time(P, lqg_compensator(lqr, kalman), lqr.inputs, n_points)}


def robustness_figures(rob: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """:func:`robustness` as JSON-ready values: infinite margins as ``null``, poles as ``[re, im]``."""

    def num(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    out = {}
    for loop, r in rob.items():
        out[loop] = {
            "actuators": [{k: (num(v) if isinstance(v, float) else v) for k, v in a.items()} for a in r["actuators"]],
            "peak_sensitivity": num(r["peak_sensitivity"]),
            "stable": r["stable"],
            "sample_time_s": r["dt"] or None,
            "closed_loop_poles": [[float(p.real), float(p.imag)] for p in np.sort_complex(r["closed_loop_poles"])],
            "disk_skew": r["disk_skew"],
            "multiloop": {k: (v if isinstance(v, bool) else num(v)) for k, v in r["multiloop"].items()},
        }
    return out
