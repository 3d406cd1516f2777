"""The FMU's XML descriptions: ``modelDescription.xml`` (FMI 2.0) and ``sources/buildDescription.xml``.

The variables' attributes, units, log categories, default experiment and model structure are written here
once, for both FMI versions: :mod:`flexlink.export.fmi3` builds the FMI 3.0 model description from the same
pieces, and :mod:`flexlink.export.fmu` packages whichever one the build asks for.  Keeping the pieces apart
from the packaging is what lets the two model descriptions share them without importing each other.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

import flexlink
from flexlink.errors import BuildError
from flexlink.export.codegen import GeneratedModel
from flexlink.export.derivatives import structure
from flexlink.export.variables import FmuVariable
from flexlink.mechanics.model import SymbolicModel
from flexlink.scene.loader import Scene

# the DefaultExperiment's stop time: the length of the scene's run, e.g. flexlink bench's manoeuvre
DEFAULT_STOP_TIME = 5.0

# unit → exponents of the SI base units (FMI 2.0 BaseUnit attributes)
UNITS = {
    "rad": {"rad": 1}, "rad/s": {"rad": 1, "s": -1}, "rad/s2": {"rad": 1, "s": -2},
    "m": {"m": 1}, "m/s": {"m": 1, "s": -1}, "m/s2": {"m": 1, "s": -2}, "s": {"s": 1},
    "kg": {"kg": 1}, "kg/m": {"kg": 1, "m": -1}, "kg.m2": {"kg": 1, "m": 2},
    "N": {"kg": 1, "m": 1, "s": -2}, "N.m": {"kg": 1, "m": 2, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2},
    "N.m2": {"kg": 1, "m": 3, "s": -2}, "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "kg.m": {"kg": 1, "m": 1}, "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "kg/m3": {"kg": 1, "m": -3}, "Pa": {"kg": 1, "m": -1, "s": -2},
}
#: Display units offered with a unit (FMI 2.0 ``<DisplayUnit>``: display value = factor · value).
DISPLAY_UNITS = {
    "rad": (("deg", 180.0 / math.pi),),
    "rad/s": (("deg/s", 180.0 / math.pi), ("rpm", 30.0 / math.pi)),
    "m": (("mm", 1000.0),),
}
LOG_CATEGORIES = {
    "logEvents": "initialisation, steps and FMU state events",
    "logStatusWarning": "warnings",
    "logStatusDiscard": "steps that could not be completed",
    "logStatusError": "errors",
    "logStatistics": "at fmi2Terminate: SS22 steps, Newton iterations, factorisations (mass updates of the "
                     "Newton matrix among them) and residual evaluations of the accepted steps since "
                     "initialisation (a discarded step's work is rolled back with its state)",
    "logAll": "everything",
}


def _num(x: float) -> str:
    return repr(float(x))


def display_unit(v: FmuVariable) -> str | None:
    """The unit a tool should show a variable in, for the variables a user reads or sets.

    Angles in deg, rates in deg/s, tip deflections in mm (the value exchanged stays SI).  None for the Model
    Exchange states and everything else.
    """
    if v.causality == "local":
        return None
    if v.unit in ("rad", "rad/s"):
        return {"rad": "deg", "rad/s": "deg/s"}[v.unit]
    if v.unit == "m" and "deflection" in v.description:
        return "mm"
    return None


def declared_min(v: FmuVariable) -> float:
    """The ``min`` the model description states: what the FMU accepts.

    For an exclusive bound (a stiffness or step that must be > 0) that is the smallest double above it; above 0
    that is the smallest normal double, as the FMU refuses subnormal values of everything but inputs
    (fmu_src/variables.c), so that an importer that honours ``min`` never sends a value the FMU refuses.
    """
    if not v.min_exclusive:
        return v.min
    if v.min == 0.0 and v.causality != "input":
        return sys.float_info.min
    return math.nextafter(v.min, math.inf)


def variable_attributes(vr: int, v: FmuVariable) -> list[str]:
    """The attributes a variable has in both FMI versions' model descriptions.

    Name, value reference, causality, variability, initial and description: written once here, so that the
    FMI 2 and FMI 3 descriptions cannot disagree on them.
    """
    attrs = [f"name={quoteattr(v.name)}", f'valueReference="{vr}"', f'causality="{v.causality}"',
             f'variability="{v.variability}"']
    if v.causality == "parameter":
        attrs.append('initial="exact"')
    if v.causality == "local":
        attrs.append('initial="calculated"')
    if v.description:
        attrs.append(f"description={quoteattr(v.description)}")
    return attrs


def type_attributes(v: FmuVariable, derivative_ref_offset: int) -> list[str]:
    """The attributes of a variable's type element, the same in both FMI versions.

    The element is FMI 2's ``<Real>``/``<Integer>`` or FMI 3's ``<Float64>``/``<Int32>``.  Start (not for
    outputs and locals, which are calculated), derivative (the state's reference plus ``derivative_ref_offset``:
    FMI 2 counts from 1, FMI 3 uses value references), unit, display unit, min, max.
    """
    number = (lambda x: str(int(x))) if v.type == "Integer" else _num
    out = []
    if v.causality not in ("output", "local"):
        out.append(f'start="{number(v.start)}"')
    if v.derivative is not None:
        out.append(f'derivative="{v.derivative + derivative_ref_offset}"')
    if v.unit:
        out.append(f'unit="{v.unit}"')
    if display_unit(v):
        out.append(f'displayUnit="{display_unit(v)}"')
    if v.min > -1e299:
        out.append(f'min="{number(declared_min(v))}"')
    if v.max < 1e299:
        out.append(f'max="{number(v.max)}"')
    return out


def generation_date_and_time() -> str:
    """Now in UTC as xs:dateTime, or ``$SOURCE_DATE_EPOCH`` (seconds) for a reproducible build."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    try:
        seconds = int(epoch) if epoch else int(time.time())
    except ValueError:
        raise BuildError(f"SOURCE_DATE_EPOCH must be whole seconds since 1970, got {epoch!r}") from None
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(seconds))


def unit_definitions(units: list[str]) -> list[str]:
    """``<UnitDefinitions>``: each unit with its SI base-unit exponents and the display units it offers."""
    lines = ["  <UnitDefinitions>"]
    for u in units:
        base = " ".join(f'{k}="{e}"' for k, e in UNITS[u].items())
        shown = "".join(f'<DisplayUnit name="{d}" factor="{_num(f)}"/>' for d, f in DISPLAY_UNITS.get(u, ()))
        lines.append(f'    <Unit name="{u}"><BaseUnit {base}/>{shown}</Unit>')
    lines.append("  </UnitDefinitions>")
    return lines


def log_categories_and_experiment(scene: Scene) -> list[str]:
    """``<LogCategories>`` and ``<DefaultExperiment>`` (the same elements in FMI 2 and FMI 3)."""
    step = _num(scene.fmu.solver.default_communication_step)
    return ["  <LogCategories>", *[f'    <Category name="{k}" description="{d}"/>' for k, d in LOG_CATEGORIES.items()],
            "  </LogCategories>",
            f'  <DefaultExperiment startTime="0" stopTime="{DEFAULT_STOP_TIME:g}" stepSize="{step}"/>']


def model_description(model: SymbolicModel, gen: GeneratedModel, sources: list[str]) -> str:
    """The FMI 2.0 ``modelDescription.xml`` of a generated model, Model Exchange and Co-Simulation.

    Parameters
    ----------
    model : SymbolicModel
        The model the C was generated from (its scene names the FMU; its sparsity gives ``<ModelStructure>``).
    gen : GeneratedModel
        The generated C: identifier, GUID and the variable list, whose order is the value references.
    sources : list of str
        The C files listed under ``<SourceFiles>``, so that an importer can build the FMU from source.
    """
    scene = model.scene
    units = sorted({v.unit for v in gen.variables if v.unit})
    derivatives = "true" if scene.fmu.directional_derivatives else "false"
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<fmiModelDescription fmiVersion="2.0" modelName={quoteattr(scene.name)} guid="{gen.guid}"',
        # the scene's name, not its file: cached_fmu shares one FMU between a file and the same parsed Scene
        f'  description={quoteattr(f"flexible-link robot generated by flexlink from the scene {scene.name}")}',
        f'  generationTool="flexlink {flexlink.__version__}" generationDateAndTime="{generation_date_and_time()}"',
        '  variableNamingConvention="structured"',
        '  numberOfEventIndicators="0">',
        f'  <ModelExchange modelIdentifier="{gen.identifier}" needsExecutionTool="false"',
        '    completedIntegratorStepNotNeeded="false" canBeInstantiatedOnlyOncePerProcess="false"',
        '    canNotUseMemoryManagementFunctions="false" canGetAndSetFMUstate="true" canSerializeFMUstate="true"',
        f'    providesDirectionalDerivative="{derivatives}">',
        "    <SourceFiles>",
        *[f'      <File name="{s}"/>' for s in sources],
        "    </SourceFiles>",
        "  </ModelExchange>",
        f'  <CoSimulation modelIdentifier="{gen.identifier}" canHandleVariableCommunicationStepSize="true"',
        '    canInterpolateInputs="false" maxOutputDerivativeOrder="0" canRunAsynchronuously="false"',
        '    canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="false"',
        f'    canGetAndSetFMUstate="true" canSerializeFMUstate="true" providesDirectionalDerivative="{derivatives}">',
        "    <SourceFiles>",
        *[f'      <File name="{s}"/>' for s in sources],
        "    </SourceFiles>",
        "  </CoSimulation>",
        *unit_definitions(units),
    ]
    lines += log_categories_and_experiment(scene)
    lines.append("  <ModelVariables>")
    for vr, v in enumerate(gen.variables):
        attrs = variable_attributes(vr, v)
        lines.append(f"    <!-- {vr + 1} --><ScalarVariable {' '.join(attrs)}>"
                     f"<{v.type} {' '.join(type_attributes(v, 1))}/></ScalarVariable>")
    lines.append("  </ModelVariables>")
    lines += model_structure(model, gen)
    lines.append("</fmiModelDescription>")
    return "\n".join(lines) + "\n"


@dataclass
class Unknown:
    """One entry of ``<ModelStructure>``: a variable and what it depends on.

    As 1-based positions in the variable list (FMI 2's indices; FMI 3 writes the value references, one less).
    """

    index: int
    dependencies: list[int]
    kinds: list[str]


def dependencies(model: SymbolicModel, gen: GeneratedModel) -> tuple[list[Unknown], list[Unknown], list[Unknown]]:
    """The content of ``<ModelStructure>`` in both FMI versions: outputs, derivatives and initial unknowns.

    The outputs and state derivatives with their dependencies on states and inputs (structural, from CasADi's
    sparsity: flexlink.export.derivatives), and the initial unknowns (outputs, states, derivatives) with their
    dependencies on inputs and parameters.  Structural dependencies let an importer skip what cannot change.
    """
    st = structure(model)
    n = model.n_q
    index = {(v.kind, v.index): vr + 1 for vr, v in enumerate(gen.variables)}   # 1-based XML indices
    state = [index[("VAR_STATE_Q", i)] for i in range(n)] + [index[("VAR_STATE_V", i)] for i in range(n)]
    # an input the FMU does not export (None) is a column no XML index stands for
    z_var: list[int | None] = [*state, *[index.get(("VAR_INPUT", j)) for j in range(st.n_u)],
                               *[index[("VAR_PARAMETER", k)] for k in range(st.n_p)]]
    inputs = {index[("VAR_INPUT", j)] for j in range(st.n_u) if ("VAR_INPUT", j) in index}
    params = {index[("VAR_PARAMETER", k)] for k in range(st.n_p)}
    start = {(v.kind, v.index): vr + 1 for vr, v in enumerate(gen.variables)
             if v.kind in ("VAR_START_Q", "VAR_START_V")}
    # at initialization a state is its start value (a coordinate held in static equilibrium: anything)
    init_of: dict[int, set[int]] = {}
    for i in range(n):
        init_of[state[i]] = {start[("VAR_START_Q", i)]} if ("VAR_START_Q", i) in start else set()
        init_of[state[n + i]] = {start[("VAR_START_V", i)]} if ("VAR_START_V", i) in start else set()
    if model.static_coordinates:
        everything = inputs | params | set(start.values())
        for i in model.static_coordinates:
            init_of[state[i]] = everything

    def deps(row: np.ndarray) -> set[int]:
        return {var for k in np.flatnonzero(row) if (var := z_var[k]) is not None}

    def unknown(vr: int, direct: set[int], kinds: dict[int, str] | None = None, initial: bool = False) -> Unknown:
        if initial:
            known: set[int] = set()
            for d in direct:
                known |= init_of.get(d, {d})
            direct = known
        else:
            direct = {d for d in direct if d not in params}
        ds = sorted(direct)
        return Unknown(vr, ds, [(kinds or {}).get(d, "dependent") for d in ds])

    unknowns: dict[int, set[int]] = {}
    for vr, v in enumerate(gen.variables):
        if v.kind == "VAR_OUTPUT":
            unknowns[vr + 1] = deps(st.outputs[v.index])
        elif v.kind == "VAR_DER_Q":
            unknowns[vr + 1] = {state[n + v.index]}
        elif v.kind == "VAR_DER_V":
            unknowns[vr + 1] = deps(st.acceleration[v.index])
        elif v.kind in ("VAR_STATE_Q", "VAR_STATE_V"):
            unknowns[vr + 1] = {vr + 1}
    outputs = [unknown(vr + 1, unknowns[vr + 1]) for vr, v in enumerate(gen.variables) if v.kind == "VAR_OUTPUT"]
    derivatives = []
    for vr, v in enumerate(gen.variables):
        if v.kind in ("VAR_DER_Q", "VAR_DER_V"):
            kinds = {state[n + v.index]: "constant"} if v.kind == "VAR_DER_Q" else None
            derivatives.append(unknown(vr + 1, unknowns[vr + 1], kinds))
    initial = [unknown(vr, unknowns[vr], initial=True) for vr in sorted(unknowns)]
    return outputs, derivatives, initial


def model_structure(model: SymbolicModel, gen: GeneratedModel) -> list[str]:
    """FMI 2's ``<ModelStructure>`` (:func:`dependencies`), by 1-based indices."""
    def line(u: Unknown) -> str:
        return (f'      <Unknown index="{u.index}" dependencies="{" ".join(map(str, u.dependencies))}" '
                f'dependenciesKind="{" ".join(u.kinds)}"/>')

    outputs, derivatives, initial = dependencies(model, gen)
    return ["  <ModelStructure>", "    <Outputs>", *map(line, outputs), "    </Outputs>", "    <Derivatives>",
            *map(line, derivatives), "    </Derivatives>", "    <InitialUnknowns>", *map(line, initial),
            "    </InitialUnknowns>", "  </ModelStructure>"]


def build_description(identifier: str, c_files: list[str]) -> str:
    """The text of ``sources/buildDescription.xml``, so that an importer can compile the FMU's sources itself.

    The FMI 3.0 format, which FMI 2.0.4 adopts for 2.0 FMUs: one build configuration, C99, every source file;
    the headers sit next to them in ``sources/``.
    """
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<fmiBuildDescription fmiVersion="3.0">',
             f'  <BuildConfiguration modelIdentifier="{identifier}">', '    <SourceFileSet language="C99">',
             *[f'      <SourceFile name="{f}"/>' for f in c_files],
             '    </SourceFileSet>', '  </BuildConfiguration>', '</fmiBuildDescription>']
    return "\n".join(lines) + "\n"

