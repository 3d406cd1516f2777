"""The FMI 3.0 model description of ``flexlink build --fmi 3``, and the layout table its C glue reads.

The FMI 2 description's variables, units, log categories and dependencies (flexlink.export.fmu) in FMI 3's
elements, with each link's elastic coordinates as arrays.

What changes against FMI 2: the root's ``instantiationToken`` (the same GUID, checked by fmi3Instantiate*),
no ``<SourceFiles>`` (``sources/buildDescription.xml`` says it), typed variable elements (``<Float64>``, and
``solver.order`` an ``<Enumeration>`` of its two valid values, read and set with fmi3Get/SetInt64) carrying
their type's attributes, the independent variable ``time`` (value
reference N_VARS, after the model's: FMI 3 requires one), ``derivative`` and ``<ModelStructure>`` by value
reference, and ``<Output>``/``<ContinuousStateDerivative>``/``<InitialUnknown>`` elements.

**Arrays.** The elastic coordinates of a link (``arm.eta[1]`` … ``arm.eta[n]`` in FMI 2) are one Float64 array
``arm.eta`` with ``<Dimension start="n"/>``, and so are their continuous states, rates and derivatives
(``q.arm.eta``, ``v.arm.eta``, ``der(q.arm.eta)``, ``der(v.arm.eta)``).  An array's value reference is the FMI 2
value reference of its first element; its element k is the FMI 2 variable at that reference plus k − 1 (the
FMI 2 references of the later elements are not FMI 3 variables: fmi3Get/SetFloat64 refuse them with the
reference to use).  So the values of all variables in value-reference order are the FMI 2 FMU's, element for
element, and a serialized FMU state of one FMU restores in the other.  The C glue learns the layout from
``fmi3_layout.c`` (:func:`write_layout`), generated next to the model.  Every other variable stays scalar.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import flexlink
from flexlink.export.codegen import GeneratedModel
from flexlink.export.description import (
    Unknown,
    dependencies,
    generation_date_and_time,
    log_categories_and_experiment,
    type_attributes,
    unit_definitions,
    variable_attributes,
)
from flexlink.export.variables import FmuVariable
from flexlink.mechanics.model import SymbolicModel

FMI3_TYPE = {"Real": "Float64", "Integer": "Int32"}
#: FMI 2 Integer variables that FMI 3 declares as an Enumeration: name → (type name, description, items
#: (name, value, description)); the values are the only ones the C glue accepts (fmu_src/variables.c)
ENUMERATIONS = {
    "solver.order": ("flexlink.SolverOrder", "order of the Co-Simulation integrator", (
        ("SS22", 2, "SS22: second order, unconditionally stable with Theta2 >= Theta1 >= 1/2"),
        ("SS22_Richardson", 4, "SS22 (Theta = 1/2) with Richardson extrapolation: fourth order, for resolved "
                               "scenes (a step with omega_max * dt > 0.3 is refused)"))),
}
#: The type codes of FMI3_TYPES in fmi3_layout.c (fmi3_internal.h: FMI3_FLOAT64, FMI3_INT32, FMI3_ENUMERATION)
TYPE_CODE = {"Float64": 0, "Int32": 1, "Enumeration": 2}
#: The generated C file that tells the FMI 3 layer (fmi3_variables.c) which value references are arrays.
LAYOUT_SOURCE = "fmi3_layout.c"
# the variable kinds that carry one value per coordinate: an elastic coordinate's output, state, rate, derivatives
_PER_COORDINATE = ("VAR_OUTPUT", "VAR_STATE_Q", "VAR_STATE_V", "VAR_DER_Q", "VAR_DER_V")
_ELEMENT = re.compile(r"^(?P<array>.*\.eta)\[(?P<k>\d+)\](?P<close>\)?)$")
_PREFIX = {"VAR_OUTPUT": ("", "elastic coordinates of"),
           "VAR_STATE_Q": ("q.", "continuous state: elastic coordinates of"),
           "VAR_STATE_V": ("v.", "continuous state: rates of the elastic coordinates of"),
           "VAR_DER_Q": ("der(q.", "rates of the elastic coordinates of"),
           "VAR_DER_V": ("der(v.", "accelerations of the elastic coordinates of")}


@dataclass(frozen=True)
class Fmi3Variable:
    """One variable of the FMI 3 model description: a scalar of the FMI 2 variable table, or an array.

    An array holds ``size`` consecutive FMI 2 variables (value references ``vr`` … ``vr + size - 1`` of the
    FMI 2 FMU), so that both FMUs hold the same values in the same order.
    """

    name: str
    vr: int
    size: int
    variable: FmuVariable          # the FMI 2 variable of the first element (kind, causality, unit, ...)
    description: str
    array: bool = False

    @property
    def type(self) -> str:
        """The FMI 3 element: Float64, Int32, or Enumeration (ENUMERATIONS)."""
        return "Enumeration" if self.name in ENUMERATIONS else FMI3_TYPE[self.variable.type]


def _link_layouts(model: SymbolicModel) -> dict[str, str]:
    """Map each link's name to which elements of its ``eta`` array are which shape functions.

    Read from the model's own account of its terms (``link "arm": 2 clamped-free coordinates for v, 2 ... for
    w``): ``1-2: v (clamped-free), 3-4: w (clamped-free)``; a shell's ``1-6: modes of a plate``.
    """
    out = {}
    for term in model.terms:
        m = re.match(r'link "(?P<link>[^"]+)": (?P<rest>.*)', term)
        if m is None:
            continue
        parts, first = [], 1
        for n, kind, field in re.findall(r"(\d+) (.+?) coordinates for (\w+)", m["rest"]):
            last = first + int(n) - 1
            parts.append(f"{first}-{last}: {field} ({kind} shape functions 1-{n})")
            first = last + 1
        shell = re.match(r"(\d+) (modes of a \w+)", m["rest"])
        if shell:
            parts.append(f"1-{shell[1]}: {shell[2]}")
        if parts:
            out[m["link"]] = ", ".join(parts)
    return out


def _element(v: FmuVariable, elastic: set[str]) -> tuple[str, int, str] | None:
    """(array name, element k, link) if ``v`` is element k of a link's elastic coordinates, else None."""
    if v.kind not in _PER_COORDINATE:
        return None
    name = v.name[len(_PREFIX[v.kind][0]):]
    m = _ELEMENT.match(name)
    if m is None or m["array"] + f"[{m['k']}]" not in elastic or bool(m["close"]) != v.kind.startswith("VAR_DER"):
        return None
    return _PREFIX[v.kind][0] + m["array"] + m["close"], int(m["k"]), m["array"].removesuffix(".eta")


def fmi3_variables(model: SymbolicModel, variables: list[FmuVariable]) -> list[Fmi3Variable]:
    """The FMI 3 variables in value-reference order, each link's elastic coordinates as one array.

    Runs ``X.eta[1]`` … ``X.eta[n]`` of one kind, at consecutive value references, become the array
    ``X.eta``; everything else is the FMI 2 scalar.
    """
    elastic = {c for c, kind in zip(model.coordinates, model.coordinate_kinds, strict=True) if kind == "elastic"}
    layouts = _link_layouts(model)
    out: list[Fmi3Variable] = []
    vr = 0
    while vr < len(variables):
        v = variables[vr]
        head = _element(v, elastic)
        if head is None or head[1] != 1:
            out.append(Fmi3Variable(v.name, vr, 1, v, v.description))
            vr += 1
            continue
        size = 1
        while vr + size < len(variables) and _element(variables[vr + size], elastic) == (head[0], size + 1, head[2]):
            size += 1
        link = head[2]
        what = layouts.get(link, f"1-{size}")
        description = (f"{_PREFIX[v.kind][1]} link {link}: element k is FMI 2's "
                       f"{v.name.replace('[1]', '[k]')}; elements {what}")
        out.append(Fmi3Variable(head[0], vr, size, v, description, array=True))
        vr += size
    return out


def _interfaces(identifier: str, derivatives: bool) -> list[str]:
    """``<ModelExchange>`` and ``<CoSimulation>``, with the capabilities the C glue implements.

    FMU state and both derivative kinds (unless the scene left them out: [fmu] directional_derivatives); no
    event mode, no early return, no intermediate update in Co-Simulation.
    """
    provided = "true" if derivatives else "false"
    common = (f'canGetAndSetFMUState="true" canSerializeFMUState="true" providesDirectionalDerivatives="{provided}" '
              f'providesAdjointDerivatives="{provided}"')
    return [
        f'  <ModelExchange modelIdentifier="{identifier}" needsCompletedIntegratorStep="true"',
        f'    providesEvaluateDiscreteStates="false" {common}/>',
        f'  <CoSimulation modelIdentifier="{identifier}" canHandleVariableCommunicationStepSize="true"',
        '    maxOutputDerivativeOrder="0" hasEventMode="false" providesIntermediateUpdate="false"',
        f'    canReturnEarlyAfterIntermediateUpdate="false" {common}/>',
    ]


def _variables(layout: list[Fmi3Variable], n_vars: int) -> list[str]:
    """``<ModelVariables>``: the FMI 2 FMU's variables at the same value references, then ``time``.

    Arrays sit at their first element's value reference.
    """
    lines = ["  <ModelVariables>"]
    for f in layout:
        v = dataclasses.replace(f.variable, name=f.name, description=f.description)
        declared = [f'declaredType="{ENUMERATIONS[f.name][0]}"'] if f.type == "Enumeration" else []
        attrs = variable_attributes(f.vr, v) + declared + type_attributes(v, 0)
        element = f.type
        if f.array:
            lines.append(f'    <{element} {" ".join(attrs)}><Dimension start="{f.size}"/></{element}>')
        else:
            lines.append(f"    <{element} {' '.join(attrs)}/>")
    lines.append(f'    <Float64 name="time" valueReference="{n_vars}" causality="independent" '
                 'variability="continuous" description="simulation time" unit="s"/>')
    lines.append("  </ModelVariables>")
    return lines


def _type_definitions() -> list[str]:
    """``<TypeDefinitions>``: the enumeration types of ENUMERATIONS."""
    lines = ["  <TypeDefinitions>"]
    for name, description, items in ENUMERATIONS.values():
        lines.append(f"    <EnumerationType name={quoteattr(name)} description={quoteattr(description)}>")
        lines += [f'      <Item name={quoteattr(n)} value="{value}" description={quoteattr(d)}/>'
                  for n, value, d in items]
        lines.append("    </EnumerationType>")
    lines.append("  </TypeDefinitions>")
    return lines


def _grouped(unknowns: list[Unknown], owner: dict[int, int]) -> list[tuple[int, list[int], list[str]]]:
    """FMI 2 unknowns (1-based indices) as FMI 3 ones, by value reference.

    An array's elements are merged into one unknown by its value reference, the dependencies mapped to the
    variables that hold them; a dependency is ``constant`` only if every element's is.
    """
    merged: dict[int, dict[int, str]] = {}
    for u in unknowns:
        deps = merged.setdefault(owner[u.index - 1], {})
        for d, kind in zip(u.dependencies, u.kinds, strict=True):
            held = owner[d - 1]
            deps[held] = kind if deps.get(held, kind) == kind else "dependent"
    return [(vr, sorted(deps), [deps[d] for d in sorted(deps)]) for vr, deps in merged.items()]


def _model_structure(model: SymbolicModel, gen: GeneratedModel, layout: list[Fmi3Variable]) -> list[str]:
    """``<ModelStructure>`` by value references, arrays as one unknown each."""
    owner = {f.vr + k: f.vr for f in layout for k in range(f.size)}

    def lines(element: str, unknowns: list[Unknown]) -> list[str]:
        return [f'    <{element} valueReference="{vr}" dependencies="{" ".join(map(str, deps))}" '
                f'dependenciesKind="{" ".join(kinds)}"/>' for vr, deps, kinds in _grouped(unknowns, owner)]

    outputs, derivatives, initial = dependencies(model, gen)
    return ["  <ModelStructure>", *lines("Output", outputs), *lines("ContinuousStateDerivative", derivatives),
            *lines("InitialUnknown", initial), "  </ModelStructure>"]


def write_layout(model: SymbolicModel, gen: GeneratedModel, directory: Path) -> str:
    """Write ``fmi3_layout.c`` in ``directory``, the table by which the generic C glue knows the arrays.

    FMI3_ELEMENTS[vr] is the number of values of FMI 3 value reference vr (1: a scalar; n: an array of the
    FMI 2 references vr … vr + n − 1; 0: an element of an array, not a variable of the FMI 3 FMU), and
    FMI3_TYPES[vr] its TYPE_CODE (which fmi3Get/Set functions take it).  The glue stays generic: only this
    table depends on the scene.

    Returns
    -------
    str
        The file's name, for the build's source list.
    """
    counts = [0] * len(gen.variables)
    types = [0] * len(gen.variables)
    for f in fmi3_variables(model, gen.variables):
        counts[f.vr] = f.size
        types[f.vr:f.vr + f.size] = [TYPE_CODE[f.type]] * f.size

    def rows(values: list[int]) -> str:
        return ",\n".join("    " + ", ".join(map(str, values[i:i + 20])) for i in range(0, len(values), 20))

    (Path(directory) / LAYOUT_SOURCE).write_text(
        f"/* {LAYOUT_SOURCE} -- generated by flexlink.export.fmi3 for the scene {model.scene.name}: the number of\n"
        " * values of each FMI 3.0 value reference (1: scalar; n: an array of n consecutive FMI 2 variables; 0: not\n"
        " * an FMI 3 variable but a later element of an array) and its type (0: Float64, 1: Int32, 2: Enumeration,\n"
        " * read and set as Int64).  Read by fmi3_variables.c. */\n"
        '#include "model.h"\n\n'
        "extern const int FMI3_ELEMENTS[N_VARS];\n"
        "extern const unsigned char FMI3_TYPES[N_VARS];\n"
        f"const int FMI3_ELEMENTS[N_VARS] = {{\n{rows(counts)}\n}};\n"
        f"const unsigned char FMI3_TYPES[N_VARS] = {{\n{rows(types)}\n}};\n")
    return LAYOUT_SOURCE


def model_description_fmi3(model: SymbolicModel, gen: GeneratedModel) -> str:
    """The FMI 3.0 ``modelDescription.xml`` of the generated model.

    The same variables, values and dependencies as the FMI 2 description, so that one scene's FMUs in either
    version behave alike (``<SourceFiles>`` aside: FMI 3 lists them in ``sources/buildDescription.xml``).
    """
    scene = model.scene
    units = sorted({v.unit for v in gen.variables if v.unit} | {"s"})
    layout = fmi3_variables(model, gen.variables)
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<fmiModelDescription fmiVersion="3.0" modelName={quoteattr(scene.name)} '
        f'instantiationToken="{gen.guid}"',
        f'  description={quoteattr(f"flexible-link robot generated by flexlink from the scene {scene.name}")}',
        f'  generationTool="flexlink {flexlink.__version__}" generationDateAndTime="{generation_date_and_time()}"',
        '  variableNamingConvention="structured">',
        *_interfaces(gen.identifier, scene.fmu.directional_derivatives),
        *unit_definitions(units),
        *_type_definitions(),
        *log_categories_and_experiment(scene),
        *_variables(layout, len(gen.variables)),
        *_model_structure(model, gen, layout),
        "</fmiModelDescription>",
    ]
    return "\n".join(lines) + "\n"
