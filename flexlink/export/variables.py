"""The FMU's variables, in value-reference order: one list for the C tables and the XML alike.

Names follow the contract of SCENE.md.  The value reference of a variable is its position here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flexlink.mechanics.model import SymbolicModel

BIG = 1e300   # "no bound" in the C tables (finite, so the glue can compare)


@dataclass(frozen=True)
class FmuVariable:
    name: str
    kind: str                 # VAR_PARAMETER | VAR_START_Q | VAR_START_V | VAR_SOLVER | VAR_INPUT | VAR_OUTPUT
    #                           | VAR_STATE_Q | VAR_STATE_V | VAR_DER_Q | VAR_DER_V (Model Exchange)
    index: int                # into p, q/v, solver settings, u or y
    start: float
    causality: str            # parameter | input | output | local
    variability: str          # tunable | fixed | continuous
    unit: str = ""
    description: str = ""
    min: float = -BIG
    max: float = BIG
    min_exclusive: bool = False
    feedthrough: tuple[int, ...] = ()   # for outputs: indices into u of the inputs it depends on directly
    derivative: int | None = None       # for der(...) variables: the value reference of the state
    type: str = "Real"                  # Real | Integer (FMI 3: Float64 | Int32); Integer values are whole

    @property
    def tunable(self) -> bool:
        return self.variability == "tunable" or self.causality == "input"


SOLVER_SETTINGS = ("SOLVER_STEP", "SOLVER_THETA1", "SOLVER_THETA2", "SOLVER_TOLERANCE", "SOLVER_ORDER")


def fmu_variables(model: SymbolicModel, feedthrough: dict[int, tuple[int, ...]] | None = None
                  ) -> list[FmuVariable]:
    """All variables of the model's FMU.  ``feedthrough`` maps output index → input indices."""
    scene = model.scene
    feedthrough = feedthrough or {}
    out: list[FmuVariable] = []
    for i, par in enumerate(model.parameters):
        lo = par.min if np.isfinite(par.min) else -BIG
        out.append(FmuVariable(par.name, "VAR_PARAMETER", i, par.value, "parameter", "tunable", par.unit,
                               par.description, min=lo, min_exclusive=par.min_exclusive))
    for s in model.start_values:
        out.append(FmuVariable(s.name, "VAR_START_V" if s.rate else "VAR_START_Q", s.coordinate, s.value,
                               "parameter", "fixed", s.unit, s.description))
    th1, th2 = scene.fmu.theta
    out += [
        FmuVariable("solver.step", "VAR_SOLVER", 0, scene.fmu.step, "parameter", "fixed", "s",
                    "SS22 internal step (communication steps are split into steps of at most this size)",
                    min=0.0, min_exclusive=True),
        FmuVariable("solver.theta1", "VAR_SOLVER", 1, th1, "parameter", "fixed", "",
                    "SS22 Theta1 (0.5: second order; larger: numerical damping)", min=0.5, max=1.0),
        FmuVariable("solver.theta2", "VAR_SOLVER", 2, th2, "parameter", "fixed", "",
                    "SS22 Theta2 (>= Theta1 for unconditional stability)", min=0.5, max=1.0),
        FmuVariable("solver.tolerance", "VAR_SOLVER", 3, scene.fmu.tolerance, "parameter", "fixed", "",
                    "Newton tolerance: a step's rate change against the coordinate's nominal scale", min=0.0,
                    min_exclusive=True),
        # an Integer: only 2 and 4 are valid (3 is refused when set, with the reason); the C table keeps it
        # as a double in the solver settings, so FMU states keep their layout
        FmuVariable("solver.order", "VAR_SOLVER", 4, 2.0, "parameter", "fixed", "",
                    "2 or 4 (3 is refused): 2: SS22; 4: SS22 (Theta = 1/2) with Richardson extrapolation, for "
                    "resolved scenes: a step with omega_max * dt > 0.3 is refused (fmi2Discard)",
                    min=2.0, max=4.0, type="Integer"),
    ]
    for i, sig in enumerate(model.inputs):
        if sig.fmu_variable:
            out.append(FmuVariable(sig.name, "VAR_INPUT", i, sig.start, "input", "continuous", sig.unit,
                                   sig.description))
    for i, sig in enumerate(model.outputs):
        out.append(FmuVariable(sig.name, "VAR_OUTPUT", i, 0.0, "output", "continuous", sig.unit,
                               sig.description, feedthrough=feedthrough.get(i, ())))
    # the Model Exchange state x = (q, v) and its derivative (v, a), after everything else so that the
    # value references above do not depend on the interface
    n = model.n_q
    first = len(out)
    for i, c in enumerate(model.coordinates):
        out.append(FmuVariable(f"q.{c}", "VAR_STATE_Q", i, 0.0, "local", "continuous", _unit(model, i, 0),
                               f"continuous state: {c}"))
    for i, c in enumerate(model.coordinates):
        out.append(FmuVariable(f"v.{c}", "VAR_STATE_V", i, 0.0, "local", "continuous", _unit(model, i, 1),
                               f"continuous state: rate of {c}"))
    for i, c in enumerate(model.coordinates):
        out.append(FmuVariable(f"der(q.{c})", "VAR_DER_Q", i, 0.0, "local", "continuous", _unit(model, i, 1),
                               f"rate of {c}", derivative=first + i))
    for i, c in enumerate(model.coordinates):
        out.append(FmuVariable(f"der(v.{c})", "VAR_DER_V", i, 0.0, "local", "continuous", _unit(model, i, 2),
                               f"acceleration of {c}", derivative=first + n + i))
    names = [v.name for v in out]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"duplicate FMU variable names: {dup}")
    return out


def _unit(model: SymbolicModel, i: int, order: int) -> str:
    """Unit of coordinate i's order-th time derivative: that of the output of the same name (rad for a
    joint angle, m for nodal FE displacements, none for modal amplitudes), per s, per s²."""
    c = model.coordinates[i]
    base = next((s.unit for s in model.outputs if s.name == c), "rad" if c.endswith(".theta") else "")
    if base not in ("m", "rad"):
        return ""
    return base + ("", "/s", "/s2")[order]
