"""The FMU's variables, in value-reference order: one list for the C tables and the XML alike.

Names follow the contract of docs/embedding.md ("Variables").  The value reference of a variable is its position here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flexlink.mechanics.model import SymbolicModel
from flexlink.scene.solver import SETTINGS

BIG = 1e300   # "no bound" in the C tables (finite, so the glue can compare)


@dataclass(frozen=True)
class FmuVariable:
    """One FMU variable: its name, where its value lives in the C tables, and its model-description attributes."""

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
        """Whether the host may set it after initialisation (a tunable parameter or an input)."""
        return self.variability == "tunable" or self.causality == "input"


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
    # the solver's settings, in their C slot order (flexlink.scene.solver, their one owner); an Integer
    # (solver.order) is kept as a double in the solver table, so FMU states keep their layout
    start = scene.fmu.solver.start_values()
    for slot, setting in enumerate(SETTINGS):
        out.append(FmuVariable(setting.name, "VAR_SOLVER", slot, float(start[setting.name]), "parameter", "fixed",
                               setting.unit, setting.description, min=max(setting.min, -BIG),
                               max=min(setting.max, BIG), min_exclusive=setting.min_exclusive,
                               type="Integer" if setting.integer else "Real"))
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
    """Unit of coordinate i's order-th time derivative.

    That of the output of the same name (rad for a joint angle, m for nodal FE displacements, none for modal
    amplitudes), per s, per s².
    """
    c = model.coordinates[i]
    base = next((s.unit for s in model.outputs if s.name == c), "rad" if c.endswith(".theta") else "")
    if base not in ("m", "rad"):
        return ""
    return base + ("", "/s", "/s2")[order]
