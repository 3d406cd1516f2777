"""The figures of a one-joint rest-to-rest run (``flexlink control``), from its recorded series alone.

What :func:`controllers.manoeuvre.rest_to_rest` reports, and what a run from the design cache
(:mod:`controllers.design_cache`) reports without a design at hand.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from controllers.trajectory import Reference

__all__ = ["ManoeuvreResult", "manoeuvre_figures"]


@dataclass
class ManoeuvreResult:
    """One closed-loop run: named time series (``series``), its figures (``metrics``) and what produced them.

    Indexing by a series name (``result["time"]``) gives that series, as fmpy's result arrays do.
    """

    controller: str
    target: float | np.ndarray         # rad: the joint's final angle, or one per actuated joint (multi-joint)
    duration: float
    settle: float
    series: dict[str, np.ndarray]
    reference: Reference
    metrics: dict
    parameters: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.series[name]


def manoeuvre_figures(series: Mapping[str, np.ndarray], *, joint: str, link: str, torque_input: str,
                      torque_limit: float, static_tip: float, target: float, duration: float, settle: float,
                      sample_time: float, controller: str, wall_time: float | None) -> dict:
    """The figures of one rest-to-rest run, and the run's settings, as JSON-ready values.

    Final error, residual vibration (RMS of ``<link>.tip.v`` minus its static value ``static_tip`` at the
    target, over the window after the manoeuvre: the vibration the controller leaves, not the static sag),
    peak torque, realtime factor (None without ``wall_time``), largest tip deflection, saturated fraction.
    """
    t = series["time"]
    tip = series[f"{link}.tip.v"]
    window = t >= duration - 1e-12
    u = series[torque_input]
    return {
        "final_error_deg": float(np.degrees(series[f"{joint}.theta"][-1] - target)),
        "residual_vibration_rms_m": float(np.sqrt(np.mean((tip[window] - static_tip) ** 2))),
        "peak_torque_nm": float(np.max(np.abs(u))),
        "realtime_factor": float((t[-1] - t[0]) / wall_time) if wall_time else None,
        "max_tip_deflection_m": float(np.max(np.abs(tip - static_tip))),
        "saturated_fraction": float(np.mean(np.abs(u) >= torque_limit * (1 - 1e-12))),
        "controller": controller, "target_deg": math.degrees(target), "duration_s": duration, "settle_s": settle,
        "sample_time_s": sample_time, "torque_limit_nm": torque_limit,
    }
