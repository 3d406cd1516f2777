"""The FMU under check: unzipped, its model description, what it declares, and values it accepts.

Every check asks this module what the FMU declares before it calls anything: the interfaces present, the
capability flags of each, the variables by type.  A check of something the FMU does not declare is
skipped, not failed.

flexlink FMUs are recognised by this rule: the ``generationTool`` attribute starts with "flexlink" *and*
the FMU has the variables ``solver.step`` and ``solver.theta1`` (flexlink's SS22 solver parameters).
Only on those do the flexlink-specific parts run (setting ``solver.step``, the catalogue of parameter
range checks, the CS-solver tolerance of ME vs CS).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import tempfile

import numpy as np

from flexlink.tools.check.arrays import Elements
from flexlink.tools.check.arrays import size as array_size

OK, WARNING, DISCARD, ERROR, FATAL = range(5)
INTERFACES = {"CS": "coSimulation", "ME": "modelExchange"}
FLEXLINK_VARIABLES = ("solver.step", "solver.theta1")
#: fmpy's type names of a floating-point and of an integer variable, FMI 2.0 and FMI 3.0
REAL_TYPES = ("Real", "Float64", "Float32")
INTEGER_TYPES = ("Integer", "Int32", "Int64", "Int16", "Int8", "UInt32", "UInt64", "UInt16", "UInt8")


class Fmi3AsFmi2:
    """An fmpy FMI 3.0 instance (FMU3Slave, FMU3Model) under the FMI 2 names the checks call.

    So the checks written for FMI 2.0 drive an FMI 3.0 FMU unchanged: ``setupExperiment`` keeps its arguments for
    ``enterInitializationMode``; Real and Integer are Float64 and Int32; ``newDiscreteStates`` is
    ``updateDiscreteStates`` (its first result: whether another update is needed); the FMU state functions
    take FMI 3's spelling.  Everything else is the FMI 3 instance's own.
    """

    RENAMED = {"getReal": "getFloat64", "setReal": "setFloat64", "getInteger": "getInt32", "setInteger": "setInt32",
               "getFMUstate": "getFMUState", "setFMUstate": "setFMUState", "freeFMUstate": "freeFMUState",
               "serializeFMUstate": "serializeFMUState", "deSerializeFMUstate": "deserializeFMUState",
               "getDerivatives": "getContinuousStateDerivatives", "newDiscreteStates": "updateDiscreteStates",
               "fmi2FreeInstance": "fmi3FreeInstance"}

    def __init__(self, inst, elements=None):
        self.__dict__["inst"] = inst
        self.__dict__["experiment"] = {"startTime": 0.0}
        self.__dict__["elements"] = elements      # arrays.Elements: Float64 arrays seen as their elements

    def getReal(self, vr):
        """``getFloat64``, whole arrays read and their elements picked out when the FMU has arrays."""
        if not self.elements:
            return self.inst.getFloat64(vr)
        return self.elements.get(self.inst.getFloat64, vr)

    def setReal(self, vr, values):
        """``setFloat64``; an array element is set by writing its whole array back (FMI 3 sets arrays whole)."""
        if not self.elements:
            return self.inst.setFloat64(vr, values)
        return self.elements.set(self.inst.getFloat64, self.inst.setFloat64, vr, values)

    def getDirectionalDerivative(self, unknowns, knowns, seed):
        """FMI 3's directional derivative, its arrays' elements seen one by one as FMI 2 would list them."""
        if not self.elements:
            return self.inst.getDirectionalDerivative(unknowns, knowns, seed)
        return self.elements.directional(self.inst.getDirectionalDerivative, unknowns, knowns, seed)

    def __getattr__(self, name):
        return getattr(self.inst, self.RENAMED.get(name, name))

    def __setattr__(self, name, value):
        setattr(self.inst, name, value)

    def instantiate(self, callbacks=None, loggingOn=False):
        """FMI 2's callbacks are not FMI 3's: the messages are dropped, as the checks read statuses."""
        del callbacks
        self.inst.instantiate(loggingOn=loggingOn, logMessage=lambda *message: None)

    def setupExperiment(self, tolerance=None, startTime=0.0, stopTime=None):
        """Keep the experiment for ``enterInitializationMode``, which takes it in FMI 3 (there is no set-up call)."""
        self.__dict__["experiment"] = {"tolerance": tolerance, "startTime": startTime, "stopTime": stopTime}

    def enterInitializationMode(self):
        """FMI 3's ``enterInitializationMode`` with the experiment that ``setupExperiment`` kept."""
        self.inst.enterInitializationMode(**self.experiment)

    def doStep(self, currentCommunicationPoint, communicationStepSize, noSetFMUStatePriorToCurrentPoint=True):
        """FMI 3's ``doStep``, its event and early-return results dropped: FMI 2's answers only with a status."""
        self.inst.doStep(currentCommunicationPoint, communicationStepSize, noSetFMUStatePriorToCurrentPoint)


class Fmu:
    """The unzipped FMU, its model description, capability flags and variables by name."""

    def __init__(self, path: str | os.PathLike, interfaces: tuple[str, ...] = ("CS", "ME")):
        import fmpy

        self.path = os.fspath(path)
        self.dir = tempfile.mkdtemp(prefix="flexlink-check-")
        try:
            fmpy.extract(self.path, self.dir)
            self.md = fmpy.read_model_description(self.path, validate=False)
        except BaseException:
            shutil.rmtree(self.dir, ignore_errors=True)
            raise
        md = self.md
        self.vars = {v.name: v for v in md.modelVariables}
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.fmi3 = md.fmiVersion.startswith("3")
        # FMI 3 Float64 arrays: the numerical checks see their elements X[k] (pseudo value references that
        # Fmi3AsFmi2 turns into whole-array calls); array inputs and tunable arrays are left out of them
        self.elements = Elements(md.modelVariables if self.fmi3 else [])
        self.vr.update(self.elements.names)
        real = [v for v in md.modelVariables if v.type in REAL_TYPES and v.causality != "independent"]
        scalar = [v for v in real if array_size(v) == 1]
        # Real variables by role (the numerical checks work on these); typed_* hold every type
        self.outputs = self.elements.scalar_names([v.name for v in real if v.causality == "output"])
        self.inputs = [v.name for v in scalar if v.causality == "input"]
        self.tunable = [v.name for v in scalar if v.causality == "parameter" and v.variability == "tunable"]
        self.typed_inputs = [v for v in md.modelVariables if v.causality == "input" and array_size(v) == 1]
        self.typed_outputs = [v for v in md.modelVariables if v.causality == "output"]
        self.states = self.elements.scalar_names([u.variable.derivative.name for u in md.derivatives])
        self.derivatives = self.elements.scalar_names([u.variable.name for u in md.derivatives])
        self.nx = len(self.derivatives)
        self.nz = int(md.numberOfEventIndicators or 0)
        self.interfaces = [k for k in ("CS", "ME") if k in interfaces and getattr(md, INTERFACES[k]) is not None]
        first = getattr(md, INTERFACES[self.interfaces[0]]) if self.interfaces else (md.coSimulation or
                                                                                     md.modelExchange)
        self.identifier = first.modelIdentifier if first is not None else ""
        self.is_flexlink = (str(md.generationTool or "").lower().startswith("flexlink")
                            and all(n in self.vars for n in FLEXLINK_VARIABLES))
        if self.fmi3:
            self._fmi3_flags()

    def _fmi3_flags(self):
        """Read FMI 3's ``providesDirectionalDerivatives`` from the XML, which fmpy 0.3.32 does not.

        It is stored under FMI 2's name (``providesDirectionalDerivative``), the one the checks ask for.
        """
        import xml.etree.ElementTree as ET

        root = ET.parse(os.path.join(self.dir, "modelDescription.xml")).getroot()
        for kind, attribute in INTERFACES.items():
            element, desc = root.find({"CS": "CoSimulation", "ME": "ModelExchange"}[kind]), getattr(self.md, attribute)
            if element is not None and desc is not None:
                desc.providesDirectionalDerivative = element.get("providesDirectionalDerivatives") in ("true", "1")

    def close(self) -> None:
        """Delete the unzipped copy; instances must be freed before (their library lives in it)."""
        shutil.rmtree(self.dir, ignore_errors=True)

    def can(self, kind: str, flag: str) -> bool:
        """A capability flag of one interface (False if the interface is absent)."""
        desc = getattr(self.md, INTERFACES[kind], None)
        return bool(desc is not None and getattr(desc, flag, False))

    def instance(self, kind: str, name: str = "check"):
        """A new fmpy instance of interface ``kind`` ("CS" or "ME"), FMI 3 ones wrapped in :class:`Fmi3AsFmi2`."""
        if self.fmi3:
            from fmpy.fmi3 import FMU3Model as Model
            from fmpy.fmi3 import FMU3Slave as Slave
        else:
            from fmpy.fmi2 import FMU2Model as Model
            from fmpy.fmi2 import FMU2Slave as Slave

        cls = Model if kind == "ME" else Slave
        inst = cls(guid=self.md.instantiationToken if self.fmi3 else self.md.guid, unzipDirectory=self.dir,
                   modelIdentifier=getattr(self.md, INTERFACES[kind]).modelIdentifier, instanceName=name)
        inst._vr = self.vr
        return Fmi3AsFmi2(inst, self.elements) if self.fmi3 else inst

    # ------------------------------------------------------------------ values
    def excitation(self) -> dict[str, object]:
        """A constant, legal excitation of the inputs, to make a run differ from one at the start values.

        flexlink FMUs get 0.1 on every Real input but the prescribed-law ones (``*_ref``); other FMUs a value of
        each input's type within its declaration (``excite_value``).
        """
        if self.is_flexlink:
            return {n: 0.1 for n in self.inputs if not n.endswith("_ref")}
        out = {}
        for v in self.typed_inputs:
            value = excite_value(v)
            if value is not None:
                out[v.name] = value
        return out

    def real_excitation(self) -> dict[str, float]:
        """The floating-point part of :meth:`excitation` (the checks that compare trajectories use only it)."""
        return {k: v for k, v in self.excitation().items()
                if self.vars[k].type in REAL_TYPES and isinstance(v, float)}


def _number(x) -> float | None:
    try:
        return float(x)
    except (TypeError, ValueError):
        return None


def excite_value(v):
    """A value of the variable's type that moves it away from its start and stays legal.

    Real: start + 0.1 clipped to [min, max]; Integer start + 1 within [min, max]; Enumeration another item of its type
    (or the start when there is only one); Boolean the negated start; String: None (left alone).
    """
    start = v.start
    if v.type in REAL_TYPES:
        x = (_number(start) or 0.0) + 0.1
        lo, hi = _number(v.min), _number(v.max)
        return float(np.clip(x, lo if lo is not None else -np.inf, hi if hi is not None else np.inf))
    if v.type in INTEGER_TYPES:
        x = int(_number(start) or 0) + 1
        lo, hi = _number(v.min), _number(v.max)
        if hi is not None and x > hi:
            x = int(hi)
        return max(x, int(lo)) if lo is not None else x
    if v.type == "Enumeration":
        items = [int(i.value) for i in (v.declaredType.items if v.declaredType is not None else [])]
        s = int(_number(start) or (items[0] if items else 1))
        others = [i for i in items if i != s]
        return others[0] if others else s
    if v.type == "Boolean":
        return str(start).lower() not in ("true", "1")
    return None


def _fmi3_integer(inst, v, verb: str):
    """An FMI 3 instance's own function for an integer variable (an Enumeration is an Int64), else None."""
    if not isinstance(inst, Fmi3AsFmi2) or v.type not in ("Enumeration", *INTEGER_TYPES):
        return None
    return getattr(inst.inst, verb + ("Int64" if v.type == "Enumeration" else v.type))


def set_value(inst, v, value) -> None:
    """fmi2Set<type> for one variable, by its type (FMI 3: the integer type's own)."""
    vr = [v.valueReference]
    if _fmi3_integer(inst, v, "set") is not None:
        _fmi3_integer(inst, v, "set")(vr, [int(value)])
    elif v.type in REAL_TYPES:
        inst.setReal(vr, [float(value)])
    elif v.type in ("Enumeration", *INTEGER_TYPES):
        inst.setInteger(vr, [int(value)])
    elif v.type == "Boolean":
        inst.setBoolean(vr, [bool(value)])
    else:
        inst.setString(vr, [str(value)])


def get_values(inst, variables) -> list:
    """fmi2Get<type> for each variable, one call per type."""
    out = []
    for v in variables:
        vr = [v.valueReference]
        if _fmi3_integer(inst, v, "get") is not None:
            out += _fmi3_integer(inst, v, "get")(vr)
        elif v.type in REAL_TYPES:
            out += inst.getReal(vr)
        elif v.type in ("Enumeration", *INTEGER_TYPES):
            out += inst.getInteger(vr)
        elif v.type == "Boolean":
            out += inst.getBoolean(vr)
        else:
            out += inst.getString(vr)
    return out


def quiet_callbacks():
    """fmi2 callbacks that drop the FMU's messages: the checks read statuses, not log lines.

    They go through flexlink's one logger router: fmpy's native logger proxy is process-wide, and a logger of our own
    registered there would be called after it is freed by whichever FMU logs next (a segfault).
    """
    from flexlink.run.simulate import logging_callbacks

    return logging_callbacks(lambda *message: None)


def call(fn, *args) -> int:
    """Status of an fmpy call (fmpy raises on error and discard)."""
    from fmpy.fmi1 import FMICallException

    try:
        fn(*args)
        return OK
    except FMICallException as e:
        return int(e.status)


def start(f: Fmu, inst, kind: str, values: dict | None = None, stop: float | None = None) -> None:
    """Instantiate, set start values (by type), initialise; ME: to continuous-time mode."""
    inst.instantiate(callbacks=quiet_callbacks())
    for name, value in (values or {}).items():
        set_value(inst, f.vars[name], value)
    inst.setupExperiment(startTime=0.0, stopTime=stop)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    if kind == "ME":
        for _ in range(100):                    # event iteration (a tuple; [0]: newDiscreteStatesNeeded)
            if not inst.newDiscreteStates()[0]:
                break
        inst.enterContinuousTimeMode()


def free(inst) -> None:
    """Free the instance but keep the library loaded (fmpy's freeInstance also unloads it)."""
    inst.fmi2FreeInstance(inst.component)      # fmi3FreeInstance through Fmi3AsFmi2
    inst.component = None


def c_doubles(x: np.ndarray):
    """A C ``double*`` to a float64 array's data, for fmpy's raw ctypes calls (the array must outlive it)."""
    return x.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
