"""Small FMUs of our own for the tests of ``flexlink check`` (not flexlink FMUs): built from
tests/c/check_fmu/model.c with gcc against fmpy's FMI 2.0 headers, with a hand-written modelDescription.xml.

``build(directory, name, variant=..., interfaces=..., defects=..., capabilities=...)`` returns the FMU's path.
Variants: ``oscillator`` (2 states, Real input/outputs/tunable parameter), ``typed`` (the oscillator plus
Integer, Boolean, Enumeration and String variables), ``nostates`` (no states, no Real outputs), ``stair``
(no states; an Integer counter stepping at time events), ``ball`` (a bouncing ball: height x from 1 m,
gravity 9.81 m/s², restitution 0.7, one event indicator, the height), ``low_ball`` (the ball from
LOW_BALL_HEIGHT, so that it reaches the floor within a fuzz sequence).  ``defects`` are the DEFECT_* macros of model.c.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

from flexlink.export.cbuild import compile_shared_library

SOURCE = Path(__file__).resolve().parent / "c" / "check_fmu" / "model.c"
GUID = "{check-fmu}"
CAPABILITIES = ("canHandleVariableCommunicationStepSize", "canGetAndSetFMUstate", "canSerializeFMUstate",
                "providesDirectionalDerivative")

# (name, type, valueReference, attributes, type attributes): the index in the list + 1 is the XML index
OSCILLATOR = [
    ("x", "Real", 0, 'causality="output" variability="continuous" initial="exact"', 'start="1"'),
    ("v", "Real", 1, 'causality="local" variability="continuous" initial="exact"', 'start="0"'),
    ("der(x)", "Real", 2, 'causality="local" variability="continuous"', 'derivative="1"'),
    ("der(v)", "Real", 3, 'causality="local" variability="continuous"', 'derivative="2"'),
    ("u", "Real", 4, 'causality="input" variability="continuous"', 'start="0"'),
    ("k", "Real", 5, 'causality="parameter" variability="tunable"', 'start="4" min="0.1" max="100"'),
    ("y", "Real", 6, 'causality="output" variability="continuous"', ""),
    ("time", "Real", 7, 'causality="independent" variability="continuous"', ""),
]
TYPED = [
    ("n", "Integer", 0, 'causality="input" variability="discrete"', 'start="1" min="0" max="10"'),
    ("m", "Integer", 1, 'causality="output" variability="discrete"', ""),
    ("b", "Boolean", 0, 'causality="input" variability="discrete"', 'start="false"'),
    ("nb", "Boolean", 1, 'causality="output" variability="discrete"', ""),
    ("mode", "Enumeration", 2, 'causality="input" variability="discrete"', 'declaredType="Mode" start="1"'),
    ("label", "String", 0, 'causality="parameter" variability="fixed"', 'start="check"'),
]
NOSTATES = [("u", "Real", 4, 'causality="input" variability="continuous"', 'start="0"')] + TYPED
STAIR = [("counter", "Integer", 3, 'causality="output" variability="discrete"', "")]
VARIANTS = {"oscillator": (OSCILLATOR, 2), "typed": (OSCILLATOR + TYPED, 2), "nostates": (NOSTATES, 0),
            "stair": (STAIR, 0), "ball": (OSCILLATOR, 2)}
BALL = {"height": 1.0, "g": 9.81, "restitution": 0.7}      # as model.c's x start, G and E
LOW_BALL_HEIGHT = 0.001                                     # m: 14 ms of fall
VARIANTS["low_ball"] = ([(v[:4] + (f'start="{LOW_BALL_HEIGHT}"',) if v[0] == "x" else v) for v in OSCILLATOR], 2)


def _model_description(name: str, variant: str, interfaces, capabilities) -> str:
    variables, nx = VARIANTS[variant]
    def flags(names):
        return " ".join(f'{c}="{"true" if c in capabilities else "false"}"' for c in names)

    caps = flags(CAPABILITIES)
    interface_xml = ""
    if "ME" in interfaces:              # canHandleVariableCommunicationStepSize is Co-Simulation's only
        interface_xml += f'  <ModelExchange modelIdentifier="{name}" {flags(CAPABILITIES[1:])}/>\n'
    if "CS" in interfaces:
        interface_xml += f'  <CoSimulation modelIdentifier="{name}" {caps}/>\n'
    rows = []
    for v, typ, vr, attrs, type_attrs in variables:
        rows.append(f'    <ScalarVariable name="{v}" valueReference="{vr}" {attrs}><{typ} {type_attrs}/>'
                    f"</ScalarVariable>")
    index = {v[0]: i for i, v in enumerate(variables, 1)}
    outputs = [i for i, v in enumerate(variables, 1) if 'causality="output"' in v[3]]
    derivatives = [i for i, v in enumerate(variables, 1) if "derivative=" in v[4]]
    initial = [i for i, v in enumerate(variables, 1)
               if ('causality="output"' in v[3] and "initial" not in v[3]) or i in derivatives]
    types = ('  <TypeDefinitions><SimpleType name="Mode"><Enumeration><Item name="slow" value="1"/>'
             '<Item name="medium" value="2"/><Item name="fast" value="3"/></Enumeration></SimpleType>'
             "</TypeDefinitions>\n" if variant in ("typed", "nostates") else "")
    assert nx == len(derivatives) and (not nx or index["x"] == 1)

    def unknowns(tag, indices):
        return f"    <{tag}>" + "".join(f'<Unknown index="{i}"/>' for i in indices) + f"</{tag}>\n" if indices else ""

    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="2.0" modelName="{name}" '
            f'guid="{GUID}" generationTool="tests/check_fmus.py" '
            f'numberOfEventIndicators="{1 if variant.endswith("ball") else 0}">\n{interface_xml}'
            f"{types}"
            f'  <DefaultExperiment startTime="0" stopTime="1" stepSize="0.01"/>\n'
            f"  <ModelVariables>\n" + "\n".join(rows) + "\n  </ModelVariables>\n  <ModelStructure>\n"
            + unknowns("Outputs", outputs) + unknowns("Derivatives", derivatives)
            + unknowns("InitialUnknowns", initial) + "  </ModelStructure>\n</fmiModelDescription>\n")


def build(directory: str | os.PathLike, name: str, *, variant: str = "oscillator", interfaces=("CS", "ME"),
          defects: tuple[str, ...] = (), capabilities: tuple[str, ...] = CAPABILITIES, xml_edit=None) -> Path:
    """Compile model.c with the variant's and the defects' macros and zip it with its model description
    (``xml_edit(text) -> text`` changes that first, for a defect in the XML)."""
    import fmpy

    d = Path(directory) / name
    binaries = d / "binaries" / "linux64"
    binaries.mkdir(parents=True, exist_ok=True)
    _, nx = VARIANTS[variant]
    flags = [f"-DNX={nx}", *(["-DSTAIR"] if variant == "stair" else []),
             *(["-DBALL"] if variant.endswith("ball") else []),
             *([f"-DBALL_HEIGHT={LOW_BALL_HEIGHT}"] if variant == "low_ball" else []),
             *(f"-D{x}" for x in defects),
             # an FMU with one interface exports only its functions and the common ones, as FMI 2.0 §2.3 allows
             *(["-DNO_ME_FUNCTIONS"] if "ME" not in interfaces else []),
             *(["-DNO_CS_FUNCTIONS"] if "CS" not in interfaces else [])]
    headers = Path(fmpy.__file__).parent / "c-code"
    compile_shared_library([SOURCE], [headers], binaries / f"{name}.so", extra_cflags=flags)
    xml = _model_description(name, variant, interfaces, capabilities)
    (d / "modelDescription.xml").write_text(xml_edit(xml) if xml_edit else xml)
    fmu = Path(directory) / f"{name}.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(d.rglob("*")):
            if p.is_file():
                z.write(p, p.relative_to(d).as_posix())
    return fmu
