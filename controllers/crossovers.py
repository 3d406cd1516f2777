"""Classical margins of a loop at its exact crossovers: found on a frequency grid, refined by root finding.

``control.stability_margins`` of a frequency-response table (``control.frd``) finds each crossover between two
grid points and refines it by ``brentq`` on the table's spline interpolation: where the loop's phase turns
sharply (a lightly damped mode next to a crossover) the spline is not the loop, and a 4000-point grid reported
a gain margin 0.013 dB low on the two-link arm's scheduled integral loop.  Here the bracketing is the same, on
the same grid, but every root is refined on the loop itself (``evaluate``: its exact frequency response at any
frequency), so the margins are those of the loop to rounding whatever the grid, as long as the grid separates
the crossovers.

**Phase margin and its sense.**  python-control reports at each gain crossover (|L| = 1) the signed angle
``pm = ∠L + 180°`` (wrapped to [−180°, 180°)), and as *the* phase margin the one of smallest magnitude, sign
kept.  A negative value does not mean an unstable loop: when L itself has poles outside the stability region
(a loop broken at one actuator with the others closed often has: the others alone do not hold the arm), the
Nyquist curve must encircle −1 once per such pole for the loop to be stable, and then it crosses the unit circle
on both sides of −1.  At a crossover with ``pm > 0`` a phase *lag* of pm moves the curve through −1, at one with
``pm < 0`` a phase *lead* of |pm| does; either way the loop goes unstable.  So :func:`loop_margins` reports
``phase_margin_deg`` as that smallest |pm|, the phase change that destabilises, with ``phase_margin_sense``
(``"lag"`` or ``"lead"``), its crossover, the number of L's unstable poles that makes a lead possible, and every
crossover with its signed python-control figure.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.optimize import brentq, minimize_scalar

__all__ = ["BOUNDARY", "loop_margins", "unstable_poles"]

#: The loop's frequency response at an array of frequencies [rad/s] (complex, one value a frequency).
Evaluate = Callable[[np.ndarray], np.ndarray]


def _at(evaluate: Evaluate, w: float) -> complex:
    return complex(np.asarray(evaluate(np.array([w]))).ravel()[0])


def _roots(f: Callable[[float], float], w: np.ndarray, values: np.ndarray,
           is_root: Callable[[float], bool]) -> list[float]:
    """Every root of f between two grid points where its sampled values change sign, refined by ``brentq``.

    A sign change can also be a pole of the loop between the points (a lightly damped mode: L passes through
    infinity, not through the crossing), to which ``brentq`` converges as well: ``is_root`` keeps the roots.  On
    the way ``brentq`` may land on that pole exactly, where the loop's response is a singular solve: such a
    bracket holds a pole, not a crossing (L is finite at a crossing), and is passed over.
    """
    out = []
    for i in np.flatnonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0):
        try:
            x = float(brentq(f, w[i], w[i + 1], xtol=1e-13 * w[i], rtol=4 * np.finfo(float).eps))
            if is_root(x):
                out.append(x)
        except np.linalg.LinAlgError:
            continue
    out.extend(float(w[i]) for i in np.flatnonzero(values == 0.0) if is_root(float(w[i])))
    return sorted(out)


def _closest_approach(evaluate: Evaluate, Lw: np.ndarray, w: np.ndarray) -> list[float]:
    """|1 + L| at its local minima on the grid, refined between the neighbouring grid points.

    Only the five smallest minima are refined (the peak sensitivity is the smallest of all; the others,
    python-control's ``sm`` list, are not reported): on the six-axis arm's 24 loops, whose |1 + L| ripples near
    1 above the crossovers, refining every local minimum took 1.5 s.
    """
    d = np.abs(1.0 + Lw)
    out = [float(np.min(d))]
    local = np.flatnonzero((d[1:-1] <= d[:-2]) & (d[1:-1] <= d[2:])) + 1
    for i in local[np.argsort(d[local])[:5]]:
        r = minimize_scalar(lambda x: abs(1.0 + _at(evaluate, x)), bounds=(w[i - 1], w[i + 1]), method="bounded",
                            options={"xatol": 1e-12 * w[i]})
        out.append(min(float(r.fun), float(d[i])))
    return out


#: A pole this close to the stability boundary (relative) is on it: a joint's rigid-body double integrator and its
#: error integral make a triple pole at z = 1, which rounding scatters by ~1e-7 to either side.
BOUNDARY = 1e-5


def unstable_poles(poles: np.ndarray, dt: float) -> int:
    """How many of a loop's poles lie outside the stability region, those on its boundary left out.

    Sampled: ``|z| > 1 + BOUNDARY``; continuous: ``Re s > BOUNDARY max(1, |s|)``.  Poles on the boundary (a
    rigid-body joint's, an integrator's) are those the Nyquist contour goes around, not the ones it counts.
    """
    poles = np.asarray(poles)
    if dt:
        return int(np.sum(np.abs(poles) > 1.0 + BOUNDARY))
    return int(np.sum(poles.real > BOUNDARY * np.maximum(1.0, np.abs(poles))))


def loop_margins(Lw: np.ndarray, w: np.ndarray, evaluate: Evaluate, L_inf: complex | None = None,
                 open_loop_unstable: int | None = None) -> dict:
    """The gain, phase and stability margins of a SISO loop at its crossovers, refined on the loop itself.

    Parameters
    ----------
    Lw : (N,) complex array
        The loop's frequency response on the grid w, negative-feedback convention of
        ``control.stability_margins`` (the loop is unstable where ``1 + L`` vanishes).
    w : (N,) array
        The grid [rad/s], increasing; a crossover between two of its points is found, one closer to another
        than the grid's spacing may be missed.
    evaluate : callable
        The loop's exact frequency response at any frequencies, as Lw (``evaluate(w) == Lw``).
    L_inf : complex, optional
        A continuous loop's feedthrough, ``L(j∞)``: the grid's end for the peak sensitivity.
    open_loop_unstable : int, optional
        How many poles of L lie outside the stability region (:func:`unstable_poles`), reported.

    Returns
    -------
    dict
        ``gain_margin_db`` (the smallest gain increase that destabilises, ``inf`` if none),
        ``gain_reduction_margin_db`` (the largest decrease tolerated, ``-inf`` if none), ``phase_margin_deg``
        (the smallest phase change that destabilises, ≥ 0; ``inf`` without a gain crossover),
        ``phase_margin_sense`` (``"lag"`` or ``"lead"``: the change that does it, python-control's sign),
        ``gain_crossover_hz`` (where), ``phase_crossover_hz`` (where the gain margin is), ``peak_sensitivity``
        (``1/min|1 + L|``), ``open_loop_unstable_poles`` (as given, or ``None``), ``gain_crossovers`` (every
        gain crossover as ``[Hz, signed phase margin °]``) and ``phase_crossovers`` (every crossing of the
        negative real axis as ``[Hz, gain margin dB]``).
    """
    Lw, w = np.asarray(Lw, dtype=complex).ravel(), np.asarray(w, dtype=float).ravel()

    def gain(x: float) -> float:
        return math.log(abs(_at(evaluate, x)))

    def imag(x: float) -> float:
        return _at(evaluate, x).imag

    with np.errstate(divide="ignore"):
        wgc = np.array(_roots(gain, w, np.log(np.abs(Lw)), lambda x: abs(gain(x)) < 1e-6))
    def on_negative_axis(x: float) -> bool:
        L = _at(evaluate, x)                # one evaluation for both conditions
        return abs(L.imag) < 1e-6 * abs(L) and L.real < 0.0

    wpc = np.array(_roots(imag, w, Lw.imag, on_negative_axis))
    Lgc = evaluate(wgc) if len(wgc) else np.zeros(0, dtype=complex)
    Lpc = evaluate(wpc) if len(wpc) else np.zeros(0, dtype=complex)
    pm = np.remainder(np.angle(np.asarray(Lgc).ravel(), deg=True), 360.0) - 180.0    # python-control's
    with np.errstate(divide="ignore"):
        gm = 1.0 / np.abs(np.asarray(Lpc).ravel())
    up, down = np.flatnonzero(gm > 1), np.flatnonzero(gm < 1)
    k_up = int(up[np.argmin(gm[up])]) if len(up) else None
    k_dn = int(down[np.argmax(gm[down])]) if len(down) else None
    k_pm = int(np.argmin(np.abs(pm))) if len(pm) else None
    d_min = min(_closest_approach(evaluate, Lw, w))
    if L_inf is not None:                              # the grid's end: |1 + L(j∞)| = |1 + D|
        d_min = min(d_min, abs(1 + L_inf))
    hz = 1 / (2 * np.pi)
    return {
        "gain_margin_db": float(20 * np.log10(gm[k_up])) if k_up is not None else math.inf,
        "gain_reduction_margin_db": float(20 * np.log10(gm[k_dn])) if k_dn is not None else -math.inf,
        "phase_margin_deg": float(abs(pm[k_pm])) if k_pm is not None else math.inf,
        "phase_margin_sense": ("lag" if pm[k_pm] >= 0 else "lead") if k_pm is not None else None,
        "gain_crossover_hz": float(wgc[k_pm] * hz) if k_pm is not None else math.nan,
        "phase_crossover_hz": float(wpc[k_up] * hz) if k_up is not None else math.nan,
        "peak_sensitivity": 1.0 / d_min if d_min > 0 else math.inf,
        "open_loop_unstable_poles": open_loop_unstable,
        "gain_crossovers": [[float(x * hz), float(p)] for x, p in zip(wgc, pm, strict=True)],
        "phase_crossovers": [[float(x * hz), float(20 * np.log10(g))] for x, g in zip(wpc, gm, strict=True)],
    }
