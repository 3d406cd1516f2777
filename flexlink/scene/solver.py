"""The SS22 solver's settings: one owner for their defaults, their bounds and their checks.

Every other place reads them from here: the scene loader (``[fmu] step``, ``theta``, ``tolerance``), the
scene reference table, the FMU's ``solver.*`` variables (start values, ``min``/``max``, descriptions), the
``<DefaultExperiment>`` step, the tools that set ``solver.*`` start values through fmpy, and the C glue,
whose limits are in ``fmu_src/solver_settings.h``, written from this module by
``python -m flexlink.export.solver_header`` (a test keeps the two equal).

Why these numbers:

* Θ1, Θ2 in [0.5, 1] with Θ1 ≤ Θ2: the SS22 scheme is unconditionally stable there (seed 001 §3.4);
  Θ = ½ is second order, larger values damp the unresolved modes.
* ``order`` 2 is SS22; 4 is the symmetric SS22 (Θ = ½) with one Richardson extrapolation per internal
  step, which amplifies unresolved modes, so a step with ω_max·Δt > :data:`RICHARDSON_MAX_OMEGA_STEP`
  is refused (an unexcited mode then grows at most 2× over one doStep's :data:`DOSTEP_MAX_INTERNAL_STEPS`).
* A failed internal step is retried as 2, 4, … :data:`SUBSTEP_MAX` sub-steps; a doStep needing more than
  :data:`DOSTEP_MAX_INTERNAL_STEPS` internal steps is refused (bounded time, no overflow of the count).
* Newton on a step's acceleration stops after :data:`NEWTON_MAX_ITERATIONS`; one that stalls within
  :data:`NEWTON_ROUNDING_FACTOR` times the tolerance has reached the residual's rounding floor and is
  accepted (a tighter tolerance than the arithmetic can meet must not sub-step forever).  The static
  equilibrium of a scene's ``static`` coordinates at initialisation gets :data:`STATIC_MAX_ITERATIONS`
  full Newton iterations (it starts from the scene's guess, farther than a step's predictor).
* The model description's default communication step is the SS22 step, but never below
  :data:`MIN_DEFAULT_COMMUNICATION_STEP`: a fine internal step does not make hosts sample every step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "DOSTEP_MAX_INTERNAL_STEPS",
    "MIN_DEFAULT_COMMUNICATION_STEP",
    "NEWTON_MAX_ITERATIONS",
    "NEWTON_ROUNDING_FACTOR",
    "ORDERS",
    "ORDER_RICHARDSON",
    "ORDER_SS22",
    "RICHARDSON_MAX_OMEGA_STEP",
    "SETTINGS",
    "STATIC_MAX_ITERATIONS",
    "SUBSTEP_MAX",
    "THETA_MAX",
    "THETA_MIN",
    "THETA_RULE",
    "SolverSetting",
    "SolverSettings",
]

THETA_MIN = 0.5
THETA_MAX = 1.0
THETA_RULE = "0.5 ≤ Θ1 ≤ Θ2 ≤ 1"
ORDER_SS22 = 2
ORDER_RICHARDSON = 4
ORDERS = (ORDER_SS22, ORDER_RICHARDSON)
RICHARDSON_MAX_OMEGA_STEP = 0.3
SUBSTEP_MAX = 8
DOSTEP_MAX_INTERNAL_STEPS = 1_000_000
NEWTON_MAX_ITERATIONS = 20
NEWTON_ROUNDING_FACTOR = 100.0
STATIC_MAX_ITERATIONS = 50
MIN_DEFAULT_COMMUNICATION_STEP = 1e-3


@dataclass(frozen=True)
class SolverSettings:
    """The settings of the SS22 integrator a scene asks for; invalid values raise ``ValueError``.

    Parameters
    ----------
    step : float
        The internal SS22 step (s); a communication step is split into steps of at most this size.
    theta : tuple of float
        (Θ1, Θ2) with ``0.5 ≤ Θ1 ≤ Θ2 ≤ 1``.
    tolerance : float
        The Newton tolerance: a step's rate change against the coordinate's nominal scale.
    order : int
        2 (SS22) or 4 (SS22 at Θ = ½ with Richardson extrapolation).
    """

    step: float = 1e-3
    theta: tuple[float, float] = (0.5, 0.5)
    tolerance: float = 1e-10
    order: int = ORDER_SS22

    def __post_init__(self) -> None:
        problem = self.problem()
        if problem is not None:
            raise ValueError(f"solver.{problem[0]}: {problem[1]}")

    def problem(self) -> tuple[str, str] | None:
        """The first invalid setting as (name, what it must be), or None.

        The same rule as the FMU's at ``fmi2ExitInitializationMode``.
        """
        th1, th2 = self.theta
        if not (math.isfinite(self.step) and self.step > 0):
            return "step", f"a positive number (s), got {self.step!r}"
        if not theta_valid(th1, th2):
            return "theta", f"[Θ1, Θ2] with {THETA_RULE}, got {list(self.theta)}"
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            return "tolerance", f"a positive number, got {self.tolerance!r}"
        if self.order not in ORDERS:
            return "order", f"2 (SS22) or 4 (SS22 with Richardson extrapolation), got {self.order!r}"
        if self.order == ORDER_RICHARDSON and self.theta != (THETA_MIN, THETA_MIN):
            return "order", f"4 extrapolates the symmetric SS22: it needs Θ1 = Θ2 = 0.5, got {list(self.theta)}"
        return None

    @property
    def default_communication_step(self) -> float:
        """The ``<DefaultExperiment stepSize>``: the SS22 step, at least MIN_DEFAULT_COMMUNICATION_STEP."""
        return max(self.step, MIN_DEFAULT_COMMUNICATION_STEP)

    def start_values(self) -> dict[str, float]:
        """The FMU start values (``solver.*`` names) that set these settings on an instance."""
        values = {"step": self.step, "theta1": self.theta[0], "theta2": self.theta[1],
                  "tolerance": self.tolerance, "order": self.order}
        return {s.name: values[s.field] for s in SETTINGS}


def theta_valid(theta1: float, theta2: float) -> bool:
    """True for SS22's unconditionally stable range ``0.5 ≤ Θ1 ≤ Θ2 ≤ 1``."""
    return THETA_MIN <= theta1 <= theta2 <= THETA_MAX


@dataclass(frozen=True)
class SolverSetting:
    """One setting as the FMU exposes it: a ``solver.*`` variable and the C enumerator of its slot.

    Parameters
    ----------
    field : str
        The key in :meth:`SolverSettings.start_values`' source (``step``, ``theta1``, ...).
    c_name : str
        The ``SolverSetting`` enumerator in ``fmu_src/solver_settings.h``; the position in :data:`SETTINGS`
        is its value.
    unit, description : str
        The FMU variable's unit and description.
    min, max : float
        The declared range; ``min_exclusive`` makes the lower bound strict.
    integer : bool
        An Integer variable (``solver.order``), else a Real.
    """

    field: str
    c_name: str
    unit: str
    description: str
    min: float = -math.inf
    max: float = math.inf
    min_exclusive: bool = False
    integer: bool = False

    @property
    def name(self) -> str:
        """The FMU variable's name."""
        return f"solver.{self.field}"


#: The settings in their C slot order (``d->solver[SOLVER_STEP]``, ...), which is also their value-reference
#: order in the FMU.
SETTINGS: tuple[SolverSetting, ...] = (
    SolverSetting("step", "SOLVER_STEP", "s",
                  "SS22 internal step (communication steps are split into steps of at most this size)",
                  min=0.0, min_exclusive=True),
    SolverSetting("theta1", "SOLVER_THETA1", "", "SS22 Theta1 (0.5: second order; larger: numerical damping)",
                  min=THETA_MIN, max=THETA_MAX),
    SolverSetting("theta2", "SOLVER_THETA2", "", "SS22 Theta2 (>= Theta1 for unconditional stability)",
                  min=THETA_MIN, max=THETA_MAX),
    SolverSetting("tolerance", "SOLVER_TOLERANCE", "",
                  "Newton tolerance: a step's rate change against the coordinate's nominal scale",
                  min=0.0, min_exclusive=True),
    SolverSetting("order", "SOLVER_ORDER", "",
                  f"{ORDER_SS22} or {ORDER_RICHARDSON} (3 is refused): {ORDER_SS22}: SS22; {ORDER_RICHARDSON}: "
                  "SS22 (Theta = 1/2) with Richardson extrapolation, for resolved scenes: a step with "
                  f"omega_max * dt > {RICHARDSON_MAX_OMEGA_STEP:g} is refused (fmi2Discard); pair order 4 with "
                  "solver.tolerance 1e-4 to 1e-6 where errors above 1e-6 suffice (the default 1e-10 took 2-3 times "
                  "the CPU time for the same error on a 3-link chain)",
                  min=float(ORDER_SS22), max=float(ORDER_RICHARDSON), integer=True),
)
