"""Controllers for flexible-link FMUs: design on the linearised model, and closed loops through fmpy.

LQR and Kalman design on the linearised model, the joint PD baseline, and closed-loop co-simulation
through fmpy.

One module per concern (python-control's layout):

=====================  ===================================================================================
``design``             Bryson weights, ``lqr``/``dlqr`` on every torque-driven joint, ``lqe``/``dlqe`` from
                       sensors, PD pole placement
``riccati``            python-control's ``lqr``/``dlqr``/``lqe``/``dlqe`` and zero-order hold, bit for bit, on
                       SciPy alone (no ``import control`` before the first FMU call)
``trajectory``         quintic reference; minimum-jerk rest-to-rest feedforward of the flexible model
``laws``               sampled laws (LQG, PD), stepped against the FMU or as ``control.StateSpace``
``closedloop``         python-control closed loop: prediction, loop transfer, margins
``robustness``         multi-joint: loop-at-a-time classical and disk margins, peak sensitivity, poles
``cosim``              ``FmuLoop``: the FMU instantiated once with ``FMU2Slave``, reset between runs
``manoeuvre``          design everything on one plant; rest-to-rest runs and their figures
``multijoint``         every joint's rest-to-rest run: inverse-dynamics feedforward, MIMO LQG against joint PD
``integral``           integral action on the joint positions: the augmented sampled LQR, its law, margins
``sensor_model``       the model's sensor outputs as the estimator's measurement prediction (CasADi, and its C)
``plots``              time responses, closed-loop poles, loop Bode with margins
``cli``, ``demo``      ``flexlink control`` / ``flexlink linearize``; the README's control job
=====================  ===================================================================================

The linearisation itself is :mod:`flexlink.run.linearize`.  The names below are importable from the package
(loaded on first use, so that ``import controllers.cli`` stays light).

Examples
--------
>>> from controllers import design, rest_to_rest                                      # doctest: +SKIP
>>> d = design("examples/rotating_link.toml", torque_limit=8.5)                      # doctest: +SKIP
>>> d.lqr.Kd, d.kalman.Ld, d.pd.kp                                                   # doctest: +SKIP
>>> res = rest_to_rest(d, "rotating_link.fmu", math.pi / 2, duration=1.5)            # doctest: +SKIP
>>> res.metrics["residual_vibration_rms_m"]                                          # doctest: +SKIP
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "bryson_weights": "design", "design_kalman": "design", "design_lqr": "design", "design_pd": "design",
    "rigid_pair": "design", "sensor_set": "design", "SENSOR_NOISE": "design", "DesignError": "design",
    "loop_at_a_time": "robustness", "lqg_compensator": "robustness",
    "quintic": "trajectory", "min_jerk_feedforward": "trajectory", "min_jerk_reference": "trajectory",
    "LQGLaw": "laws", "PDLaw": "laws",
    "closed_loop": "closedloop", "loop_transfer": "closedloop", "margins": "closedloop", "predict": "closedloop",
    "sampled_plant": "closedloop",
    "FmuLoop": "cosim",
    "ControlDesign": "manoeuvre", "default_torque_limit": "manoeuvre", "design": "manoeuvre",
    "predict_manoeuvre": "manoeuvre", "rest_to_rest": "manoeuvre", "stability_report": "manoeuvre",
    "plot_manoeuvre": "plots", "plot_multijoint": "plots",
    "MimoLQGLaw": "multijoint", "JointPDLaw": "multijoint", "compare": "multijoint",
    "inverse_dynamics_reference": "multijoint",
    "design_integral": "integral", "IntegralLQGLaw": "integral",
    "run_control_demo": "demo",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"controllers.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'controllers' has no attribute {name!r}")
