"""Check ``model-description``: fmpy's schema and semantic validation, plus what it does not notice.

Every value reference of the XML is read back through the binary by its type, in each declared interface;
every output must be in ``<Outputs>``; every ``derivative=`` state in ``<Derivatives>``.
"""

from __future__ import annotations

import os
import time
import xml.etree.ElementTree as ET

from flexlink.tools.check import isolation
from flexlink.tools.check.arrays import size as array_size
from flexlink.tools.check.findings import CheckResult, Finding
from flexlink.tools.check.fmu import WARNING, Fmu, call, free, quiet_callbacks

_GETTER = {"Real": "getReal", "Integer": "getInteger", "Enumeration": "getInteger", "Boolean": "getBoolean",
           "String": "getString"}
# FMI 3.0: the type's own getter (Enumerations are Int64); Binary and Clock variables are not read back
_GETTER3 = {t: f"get{t}" for t in ("Float32", "Float64", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32",
                                   "Int64", "UInt64", "Boolean", "String")} | {"Enumeration": "getInt64"}


def _structure(f: Fmu) -> list[Finding]:
    found: list[Finding] = []
    root = ET.parse(os.path.join(f.dir, "modelDescription.xml")).getroot()
    variables = root.findall("ModelVariables/ScalarVariable")
    structure = root.find("ModelStructure")
    if structure is None:                   # fmpy's validation reports it
        return found
    outputs = structure.find("Outputs")
    listed = {int(u.get("index", "0")) for u in (outputs if outputs is not None else [])}
    for i, v in enumerate(variables, 1):
        if v.get("causality") == "output" and i not in listed:
            found.append(Finding("outputs-listed", f"output {v.get('name')} (index {i}) is missing from "
                                                   "<ModelStructure><Outputs>"))
    if f.md.modelExchange is None:          # "A Co- Simulation FMU does not need to expose these state derivatives."
        return found
    ders = structure.find("Derivatives")
    listed_d = {int(u.get("index", "0")) for u in (ders if ders is not None else [])}
    for i, v in enumerate(variables, 1):
        real = v.find("Real")
        if real is not None and real.get("derivative") and i not in listed_d:
            found.append(Finding("derivatives-listed", f"derivative {v.get('name')} (index {i}) is missing "
                                                       "from <ModelStructure><Derivatives>"))
    return found


def _initialised(f: Fmu, kind: str):
    inst = f.instance(kind)
    inst.instantiate(callbacks=quiet_callbacks())
    inst.setupExperiment(startTime=0.0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    return inst


def _read_back(f: Fmu, kind: str) -> list[Finding]:
    """Every variable read through the binary after initialisation, with the getter of its type.

    After a refusal (fmi2Error leaves the instance unusable, §2.1.3) the next variable gets a fresh instance.
    """
    found: list[Finding] = []
    inst = None
    getters = _GETTER3 if f.fmi3 else _GETTER
    for name, v in f.vars.items():
        if v.type not in getters or v.causality == "independent":
            continue
        if inst is None:
            try:
                inst = _initialised(f, kind)
            except Exception as e:    # a library that does not load, a GUID that differs, ...
                return found + [Finding("loads", f"{kind}: {type(e).__name__}: {e}", sequence=isolation.recent())]
        getter = getattr(inst.inst, getters[v.type]) if f.fmi3 else getattr(inst, getters[v.type])
        if call(getter, [v.valueReference], *([array_size(v)] if f.fmi3 else [])) > WARNING:   # FMI 3 arrays: whole
            found.append(Finding("value-reference", f"{kind}: value reference {v.valueReference} of {name} "
                                                    f"({v.type}) is refused by the binary",
                                 sequence=isolation.recent(3)))
            free(inst)
            inst = None
    if inst is not None:
        free(inst)
    return found


def check_model_description(f: Fmu) -> CheckResult:
    """The check: fmpy's validation, the value references through the binary, the model structure."""
    from fmpy.validation import validate_fmu

    t0 = time.perf_counter()
    found = [Finding("schema", p) for p in validate_fmu(f.path)]
    if not f.interfaces:
        found.append(Finding("schema", "no <CoSimulation> or <ModelExchange> to check (or not selected)"))
    if not f.fmi3:                  # FMI 3.0's ModelStructure: fmpy's validation only
        found += _structure(f)
    for kind in f.interfaces:
        found += _read_back(f, kind)
    return CheckResult("model-description", "modelDescription.xml", "fmpy validation; value references through "
                       "the binary; ModelStructure", f"{len(found)} problem(s)", seconds=time.perf_counter() - t0,
                       details=[x.message for x in found], findings=found)
