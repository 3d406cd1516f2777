"""``flexlink build --fmi 3``: the FMI 3.0 FMU of a scene against the FMI 2.0 FMU of the same scene (issue 17).

The references are fmpy's FMI 3.0 validation (schema and rules), fmpy's simulation of the FMI 2 FMU in the same
interface with the same settings, the FMI 2 FMU's directional derivatives, and the FMI 3.0 rules for the calls
(an Int32 set with fmi3SetInt32, an array read and set whole with nValues its size, the adjoint the transpose of
the directional derivative).  A link's elastic coordinates are arrays in FMI 3 (``arm.eta``, ``q.arm.eta``,
``der(v.arm.eta)``, ...) and scalars in FMI 2 (``arm.eta[k]``, ...): :func:`element_name` is the documented
correspondence (docs/fmi.md), element k of the array at the value reference of FMI 2's element 1."""

from __future__ import annotations

import ctypes
import json
import math
import os
import re
import shutil
import subprocess
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import fmpy
import numpy as np
import pytest
from conftest import EXAMPLES
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Model, FMU3Slave
from fmpy.validation import validate_fmu

from flexlink.export.cache import cached_fmu
from flexlink.export.cbuild import MINGW_CC, fmi_headers_dir
from flexlink.export.fmu import build_fmu

# steel_beam_raise: finite elements and built-in kinematic laws.  Its stiff elements defeat fmpy's explicit Euler
# and CVode's default step limit, so Model Exchange is compared on rotating_link only.
SCENES = ("rotating_link", "steel_beam_raise")


@pytest.fixture(scope="module")
def fmi3_fmu():
    """``fmi3_fmu(name)``: the FMI 3 FMU of examples/<name>.toml, from flexlink's build cache (only read)."""
    return lambda name: cached_fmu(EXAMPLES / f"{name}.toml", fmi_version=3)


def torque(md, stop):
    """A smooth input on every input of the scene (none for a scene driven by its laws)."""
    names = [v.name for v in md.modelVariables if v.causality == "input"]
    if not names:
        return None
    t = np.linspace(0.0, stop, 201)
    return np.array([(ti, *(0.2 * np.sin(2 * np.pi * ti / stop) for _ in names)) for ti in t],
                    dtype=[("time", float), *((n, float) for n in names)])


ELEMENT = re.compile(r"^(?P<head>.*\.eta)\[(?P<k>\d+)\](?P<tail>\)?)$")


def array_of(name2):
    """FMI 2's ``arm.eta[2]``, ``der(q.arm.eta[2])`` → (FMI 3's ``arm.eta``, ``der(q.arm.eta)``; element 2);
    any other name → (itself, None)."""
    m = ELEMENT.match(name2)
    return (m["head"] + m["tail"], int(m["k"])) if m else (name2, None)


def element_name(name3, k):
    """The FMI 2 name of element k (1-based) of the FMI 3 array ``name3``."""
    return f"{name3[:-1]}[{k}])" if name3.endswith(")") else f"{name3}[{k}]"


def scalar_columns(run):
    """A simulation result's columns by FMI 2 name: an array column (n rows × size) as its elements'."""
    out = {}
    for name in run.dtype.names:
        column = np.asarray(run[name])
        if column.ndim == 1:
            out[name] = column
        else:
            out.update({element_name(name, k + 1): column[:, k] for k in range(column.shape[1])})
    return out


def equal_runs(run3, run2, tolerance=1e-12):
    """The FMI 3 run equals the FMI 2 run, element by element: the largest difference of any recorded variable,
    against the largest magnitude of the run."""
    a, b = scalar_columns(run3), scalar_columns(run2)
    assert sorted(a) == sorted(b) and len(run3) == len(run2)
    peak = max(float(np.max(np.abs(b[n]))) for n in b)
    worst = max(float(np.max(np.abs(a[n] - b[n]))) for n in b)
    assert worst <= tolerance * peak, (worst, peak)
    return worst, peak


LINK = {"rotating_link": "arm", "steel_beam_raise": "beam"}


@pytest.mark.parametrize("name", SCENES)
def test_fmi3_model_description_is_valid_and_matches_fmi2(fmi3_fmu, example_fmu, name):
    fmu3 = fmi3_fmu(name)
    assert validate_fmu(str(fmu3)) == []
    md3 = fmpy.read_model_description(str(fmu3))
    md2 = fmpy.read_model_description(str(example_fmu(name)))
    assert md3.fmiVersion == "3.0" and md3.instantiationToken == md2.guid
    assert md3.coSimulation is not None and md3.modelExchange is not None
    with zipfile.ZipFile(fmu3) as z:
        assert f"binaries/x86_64-linux/{md3.coSimulation.modelIdentifier}.so" in z.namelist()
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    for interface in ("ModelExchange", "CoSimulation"):     # fmpy 0.3.32 does not read these FMI 3 flags
        flags = root.find(interface).attrib
        for flag in ("canGetAndSetFMUState", "canSerializeFMUState", "providesDirectionalDerivatives",
                     "providesAdjointDerivatives"):
            assert flags[flag] == "true", (interface, flag)
    # every FMI 2 variable is an FMI 3 scalar at the same value reference, or element k of an array at the
    # reference of element 1, with the same causality, variability, unit, display unit and range; Real is
    # Float64, the one Integer (solver.order) an Enumeration
    v3 = {v.name: v for v in md3.modelVariables}
    elements: dict[str, list[int]] = {}
    for v in md2.modelVariables:
        name3, k = array_of(v.name)
        w = v3[name3]
        assert w.type == {"Real": "Float64", "Integer": "Enumeration"}[v.type], v.name
        assert w.valueReference + (k or 1) - 1 == v.valueReference, v.name
        assert (w.causality, w.variability, w.unit, w.displayUnit) == \
               (v.causality, v.variability, v.unit, v.displayUnit), v.name
        for attr in ("start", "min", "max"):
            assert (None if getattr(w, attr) is None else float(getattr(w, attr))) == \
                   (None if getattr(v, attr) is None else float(getattr(v, attr))), (v.name, attr)
        if k is None:
            assert not w.shape, v.name
        else:
            elements.setdefault(name3, []).append(k)
    # the link's elastic coordinates, their states, rates and derivatives are the arrays, and nothing else
    link = LINK[name]
    assert set(elements) == {v.name for v in md3.modelVariables if v.shape} == \
           {f"{link}.eta", f"q.{link}.eta", f"v.{link}.eta", f"der(q.{link}.eta)", f"der(v.{link}.eta)"}
    n = len(elements[f"{link}.eta"])
    for name3, ks in elements.items():
        assert ks == list(range(1, n + 1)) and v3[name3].shape == (n,), name3
    assert f"element k is FMI 2's {link}.eta[k]" in v3[f"{link}.eta"].description
    assert v3["time"].causality == "independent"
    # solver.order: its items are the values the FMU accepts, 2 and 4 (3 is refused: test_fmi3_refuses_bad_calls)
    order = v3["solver.order"].declaredType
    assert [(i.name, int(i.value)) for i in order.items] == [("SS22", 2), ("SS22_Richardson", 4)]
    assert len(md3.modelVariables) == len(md2.modelVariables) - 5 * (n - 1) + 1
    assert md3.numberOfContinuousStates == md2.numberOfContinuousStates
    # the model structure: the FMI 2 unknowns with their dependencies, an array's elements merged into one
    for s2, s3 in ((md2.outputs, md3.outputs), (md2.derivatives, md3.derivatives),
                   (md2.initialUnknowns, md3.initialUnknowns)):
        merged: dict[str, set[str]] = {}
        for u in s2:
            merged.setdefault(array_of(u.variable.name)[0], set()).update(array_of(d.name)[0] for d in u.dependencies)
        assert [u.variable.name for u in s3] == list(merged)
        assert {u.variable.name: {d.name for d in u.dependencies} for u in s3} == merged


@pytest.mark.parametrize("name, stop, settings", [
    ("rotating_link", 0.5, {"fmi_type": "CoSimulation"}),
    ("rotating_link", 0.5, {"fmi_type": "ModelExchange", "solver": "CVode", "relative_tolerance": 1e-9}),
    # fmpy's Euler takes one step per output interval: 1e-4 s is ω_max h = 0.02 on this link, a stable step
    ("rotating_link", 0.1, {"fmi_type": "ModelExchange", "solver": "Euler", "step_size": 1e-4,
                            "output_interval": 1e-4}),
    ("steel_beam_raise", 0.3, {"fmi_type": "CoSimulation"}),
], ids=["cs-rotating_link", "me-cvode-rotating_link", "me-euler-rotating_link", "cs-steel_beam_raise"])
def test_fmi3_simulates_as_the_fmi2_fmu(fmi3_fmu, example_fmu, name, stop, settings):
    fmu2 = str(example_fmu(name))
    u = torque(fmpy.read_model_description(fmu2), stop)
    interval = settings.get("output_interval", 0.01)
    runs = [fmpy.simulate_fmu(str(f), stop_time=stop, input=u, **{"output_interval": interval, **settings})
            for f in (fmi3_fmu(name), fmu2)]
    assert len(runs[0]) == round(stop / interval) + 1
    assert max(float(np.max(np.abs(runs[1][n]))) for n in runs[1].dtype.names if n != "time") > 0  # it moves
    eta = np.asarray(runs[0][f"{LINK[name]}.eta"])           # the array, recorded by fmpy as (rows, size)
    assert eta.ndim == 2 and np.max(np.abs(eta)) > 0
    equal_runs(*runs)


@pytest.mark.parametrize("name, inputs", [("six_axis_arm", 0), ("planar_chain_5", 1)])
def test_fmi3_large_models_simulate_as_the_fmi2_fmu(fmi3_fmu, example_fmu, name, inputs):
    """The chains of the robot-scale builder (13 and 20 coordinates, spatial joints, several flexible links): fmpy's
    Co-Simulation (0.2 s) and Model Exchange with CVode (0.05 s) of the FMI 3 FMU equal the FMI 2 FMU's to 1e-12
    of the peak, every link's elastic coordinates (arrays in FMI 3) compared element by element.  A short run:
    FLEXLINK_FULL=1 runs 1 s of each."""
    full = os.environ.get("FLEXLINK_FULL") == "1"
    fmu2 = str(example_fmu(name))
    md2 = fmpy.read_model_description(fmu2)
    assert len([v for v in md2.modelVariables if v.causality == "input"]) == inputs   # six_axis_arm: its laws
    for stop, settings in ((1.0 if full else 0.2, {"fmi_type": "CoSimulation"}),
                           (1.0 if full else 0.05, {"fmi_type": "ModelExchange", "solver": "CVode",
                                                    "relative_tolerance": 1e-9})):
        u = torque(md2, stop)
        runs = [fmpy.simulate_fmu(str(f), stop_time=stop, output_interval=0.005, input=u, **settings)
                for f in (fmi3_fmu(name), fmu2)]
        arrays = [n for n in runs[0].dtype.names if np.asarray(runs[0][n]).ndim == 2]
        assert len(arrays) >= 2 and all(np.max(np.abs(runs[0][n])) > 0 for n in arrays), arrays   # links bend
        equal_runs(*runs)


# A hub driven by a built-in law with two time events: θ = 20 t² until 0.05 s, then the mirrored parabola to rest
# at θ = 0.1 rad at 0.1 s (position and rate continuous, the acceleration jumps from 40 to −40 to 0 rad/s²).
EVENT_SCENE = """name = "hub_events"
gravity = [0.0, 0.0, 0.0]
[[joint]]
name = "hub"
axis = [0.0, 0.0, 1.0]
drive = "position"
[joint.trajectory]
segments = [{ until = 0.05, poly = [0.0, 0.0, 20.0] }, { until = 0.1, poly = [-0.1, 4.0, -20.0] },
            { until = inf, poly = [0.1] }]
[[link]]
name = "arm"
length = 2.2
linear_density = 0.349
EI = 93.72
deformation = ["v"]
shapes = { kind = "clamped-free", count = 3 }
"""
EVENTS = (0.05, 0.1)


@pytest.fixture(scope="module")
def event_fmus(tmp_path_factory):
    """The FMI 3 and FMI 2 FMUs of EVENT_SCENE."""
    scene = tmp_path_factory.mktemp("events") / "hub_events.toml"
    scene.write_text(EVENT_SCENE)
    return cached_fmu(scene, fmi_version=3), cached_fmu(scene)


def states(m, n):
    x = np.zeros(n)
    m.getContinuousStates(x.ctypes.data_as(fmpy.fmi2.POINTER(fmpy.fmi2.c_double)), n)
    return x


def test_fmi3_model_exchange_event_mode_as_the_standard_requires(event_fmus):
    """FMI 3.0 §3.2 (Model Exchange): after initialization the FMU is in Event Mode; fmi3UpdateDiscreteStates
    says that no discrete state needs another update, that the continuous states and their nominals are unchanged,
    and when the next time event is (the law's segment ends; none after the last); fmi3CompletedIntegratorStep
    never asks for event mode (no state events); fmi3EnterContinuousTimeMode and fmi3EnterEventMode switch modes
    with the states kept.  Each mode's functions are refused in the other with one message."""
    fmu3, _ = event_fmus
    messages: list[str] = []
    md, m, _ = slave(fmu3, FMU3Model, messages)
    n = md.numberOfContinuousStates
    # (discreteStatesNeedUpdate, terminateSimulation, nominalsOfContinuousStatesChanged,
    #  valuesOfContinuousStatesChanged, nextEventTimeDefined, nextEventTime)
    expected = [(False, False, False, False, True, 0.05), (False, False, False, False, True, 0.1),
                (False, False, False, False, False, 0.0)]
    try:
        m.enterInitializationMode(startTime=0.0)
        m.exitInitializationMode()
        assert m.updateDiscreteStates() == expected[0]
        m.enterContinuousTimeMode()
        for t, flags in zip(EVENTS, expected[1:], strict=True):
            x = states(m, n)
            m.setTime(t)
            assert m.completedIntegratorStep() == (False, False)
            m.enterEventMode()
            assert m.updateDiscreteStates() == flags
            assert np.array_equal(states(m, n), x)
            m.enterContinuousTimeMode()
        m.terminate()

        def refused(mode, call, text):
            m.reset()
            m.enterInitializationMode(startTime=0.0)
            m.exitInitializationMode()
            if mode == "continuous":
                m.updateDiscreteStates()
                m.enterContinuousTimeMode()
            messages.clear()
            with pytest.raises(FMICallException) as e:
                call()
            assert int(e.value.status) == 3 and len(messages) == 1 and text in messages[0], messages

        x = np.zeros(n)
        refused("event", lambda: m.setContinuousStates(x.ctypes.data_as(fmpy.fmi2.POINTER(fmpy.fmi2.c_double)),
                                                       n), "fmi3SetContinuousStates: not allowed in state")
        refused("event", lambda: m.completedIntegratorStep(), "fmi3CompletedIntegratorStep: not allowed")
        refused("continuous", lambda: m.updateDiscreteStates(), "fmi3UpdateDiscreteStates: not allowed in state")
        refused("continuous", lambda: m.enterContinuousTimeMode(), "fmi3EnterContinuousTimeMode: not allowed")
    finally:
        m.freeInstance()


def test_fmi3_model_exchange_with_time_events_simulates_as_the_fmi2_fmu(event_fmus):
    """fmpy's FMI 3 Model Exchange loop (CVode) through the two time events of the law: it stops at each (the
    recorded events), and the run equals the FMI 2 FMU's to 1e-12 of the peak; the hub follows the law."""
    runs = [fmpy.simulate_fmu(str(f), fmi_type="ModelExchange", solver="CVode", relative_tolerance=1e-9,
                              stop_time=0.2, output_interval=0.01, record_events=True) for f in event_fmus]
    for t in EVENTS:               # a row just before and one at each event
        assert np.count_nonzero(np.isclose(runs[0]["time"], t, rtol=0, atol=1e-12)) >= 2, runs[0]["time"]
    equal_runs(*runs)
    law = np.where(runs[0]["time"] < 0.05, 20 * runs[0]["time"] ** 2,
                   np.where(runs[0]["time"] < 0.1, -0.1 + 4 * runs[0]["time"] - 20 * runs[0]["time"] ** 2, 0.1))
    np.testing.assert_allclose(runs[0]["hub.theta"], law, rtol=0, atol=1e-12)
    assert np.max(np.abs(runs[0]["arm.eta"])) > 1e-6        # the link bends under the law's accelerations


def slave(fmu, cls=FMU3Slave, messages=None):
    """An instantiated fmpy FMI 3 instance; the FMU's messages appended to ``messages`` if given."""
    md = fmpy.read_model_description(str(fmu))
    kind = md.coSimulation if cls is FMU3Slave else md.modelExchange
    inst = cls(guid=md.instantiationToken, unzipDirectory=fmpy.extract(str(fmu)),
               modelIdentifier=kind.modelIdentifier, instanceName="fmi3")
    if messages is None:
        inst.instantiate()
    else:
        inst.instantiate(logMessage=lambda env, status, category, message: messages.append(message.decode()))
    return md, inst, {v.name: v.valueReference for v in md.modelVariables}


def size(v):
    return int(np.prod(v.shape)) if v.shape else 1


def test_fmi3_fmu_state_round_trip(fmi3_fmu):
    md, s, vr = slave(fmi3_fmu("rotating_link"))
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    n_values = sum(size(v) for v in md.modelVariables if v.causality == "output") + 1
    try:
        s.setInt64([vr["solver.order"]], [4])
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()

        def run(t0, n):
            rows = []
            for k in range(n):
                s.setFloat64([vr["hub.tau"]], [0.3 * (k % 3)])
                s.doStep(t0 + 0.01 * k, 0.01)
                rows.append(s.getFloat64(outputs + [vr["time"]], nValues=n_values))
            return np.array(rows)

        run(0.0, 5)
        state = s.getFMUState()
        blob = s.serializeFMUState(state)
        first = run(0.05, 10)
        s.setFMUState(state)
        assert np.array_equal(run(0.05, 10), first)
        restored = s.deserializeFMUState(blob)
        s.setFMUState(restored)
        assert np.array_equal(run(0.05, 10), first)
        assert first[-1, -1] == pytest.approx(0.15, abs=1e-12)     # time, the independent variable
        s.freeFMUState(state)
        s.freeFMUState(restored)
    finally:
        s.freeInstance()


def test_fmi3_derivatives_equal_fmi2_and_adjoint_is_the_transpose(fmi3_fmu, example_fmu):
    """∂(state derivatives, outputs)/∂(states, input) through the arrays' value references, one seed per element,
    equal to the FMI 2 FMU's from its scalar references; a full seed in one call is J·seed; the adjoint is Jᵀ·seed."""
    from fmpy.fmi2 import FMU2Model

    md3, m3, vr = slave(fmi3_fmu("rotating_link"), FMU3Model)
    md2 = fmpy.read_model_description(str(example_fmu("rotating_link")))
    m2 = FMU2Model(guid=md2.guid, unzipDirectory=fmpy.extract(str(example_fmu("rotating_link"))),
                   modelIdentifier=md2.modelExchange.modelIdentifier, instanceName="fmi2")
    m2.instantiate()
    vr2 = {v.name: v.valueReference for v in md2.modelVariables}
    try:
        unknowns = [u.variable for u in md3.derivatives] + [u.variable for u in md3.outputs]
        knowns = [u.variable.derivative for u in md3.derivatives] + [v for v in md3.modelVariables
                                                                     if v.name == "hub.tau"]
        assert any(v.shape for v in unknowns) and any(v.shape for v in knowns)

        def fmi2_refs(variables):            # by name: element k of array X is FMI 2's X[k]
            return [vr2[v.name if not v.shape else element_name(v.name, k + 1)] for v in variables
                    for k in range(size(v))]
        u2, k2 = fmi2_refs(unknowns), fmi2_refs(knowns)
        u3, k3 = [v.valueReference for v in unknowns], [v.valueReference for v in knowns]
        x = np.array([0.3, 0.01, -0.02, 0.005, 1.0, 0.1, 0.2, -0.1])
        assert len(k2) == 9 and len(x) == md3.numberOfContinuousStates
        m2.setReal([vr["hub.tau"]], [0.4])
        m2.setupExperiment(startTime=0.0)
        m2.enterInitializationMode()
        m2.exitInitializationMode()
        m2.newDiscreteStates()
        m2.enterContinuousTimeMode()
        m2.setContinuousStates(x.ctypes.data_as(fmpy.fmi2.POINTER(fmpy.fmi2.c_double)), len(x))
        m3.setFloat64([vr["hub.tau"]], [0.4])
        m3.enterInitializationMode(startTime=0.0)
        m3.exitInitializationMode()
        m3.updateDiscreteStates()
        m3.enterContinuousTimeMode()
        m3.setContinuousStates(x.ctypes.data_as(fmpy.fmi2.POINTER(fmpy.fmi2.c_double)), len(x))
        # the state and derivative arrays read whole are the state vector's and derivative vector's elements
        dx = np.zeros(len(x))
        m3.getContinuousStateDerivatives(dx.ctypes.data_as(fmpy.fmi2.POINTER(fmpy.fmi2.c_double)), len(x))
        arrays = m3.getFloat64([vr[n] for n in ("q.arm.eta", "v.arm.eta", "der(q.arm.eta)", "der(v.arm.eta)")],
                               nValues=12)
        assert arrays == [*x[1:4], *x[5:8], *dx[1:4], *dx[5:8]] and np.any(dx[5:8] != 0)
        J = np.array([m3.getDirectionalDerivative(u3, k3, list(np.eye(len(k2))[j]), nSensitivity=len(u2))
                      for j in range(len(k2))]).T
        J2 = np.array([m2.getDirectionalDerivative(u2, [k], [1.0]) for k in k2]).T
        assert np.array_equal(J, J2) and np.any(J[:, 1:4] != 0)      # the elastic columns too
        seed = np.linspace(-1.0, 1.0, len(k2))
        np.testing.assert_allclose(m3.getDirectionalDerivative(u3, k3, list(seed), nSensitivity=len(u2)), J @ seed,
                                   rtol=1e-13, atol=1e-14 * np.abs(J).max())
        seed = np.linspace(-1.0, 1.0, len(u2))
        adjoint = np.array(m3.getAdjointDerivative(u3, k3, list(seed), nSensitivity=len(k2)))
        np.testing.assert_allclose(adjoint, J.T @ seed, rtol=1e-14, atol=1e-14 * np.abs(J).max())
    finally:
        m3.freeInstance()
        m2.freeInstance()


@pytest.mark.parametrize("name", ["rotating_link", "flexible_pendulum"])
def test_fmi3_display_units_against_fmpys_fmi3_schema(fmi3_fmu, name):
    """The FMI 3 model description is valid against the FMI 3.0 XML schema fmpy ships (lxml, the schema itself,
    not fmpy's reader); the variables a user reads or sets carry the display units of FMI 2 (angles deg, rates
    deg/s with rpm offered, tip deflections mm), with factors computed here; fmpy converts a start value given
    in degrees through them."""
    from lxml import etree

    schema = etree.XMLSchema(file=str(Path(fmpy.__file__).parent / "schema" / "fmi3" / "fmi3ModelDescription.xsd"))
    with zipfile.ZipFile(fmi3_fmu(name)) as z:
        root = etree.fromstring(z.read("modelDescription.xml"))
    schema.assertValid(root)
    offered = {u.get("name"): {d.get("name"): float(d.get("factor")) for d in u.findall("DisplayUnit")}
               for u in root.find("UnitDefinitions")}
    assert offered["rad"] == pytest.approx({"deg": 180.0 / math.pi}, rel=1e-15)
    assert offered["rad/s"] == pytest.approx({"deg/s": 180.0 / math.pi, "rpm": 60.0 / (2.0 * math.pi)}, rel=1e-15)
    assert offered["m"] == pytest.approx({"mm": 1000.0}, rel=1e-15)
    shown = {}
    for v in root.find("ModelVariables"):
        unit, causality = v.get("unit"), v.get("causality")
        expected = None if causality in ("local", "independent") else {"rad": "deg", "rad/s": "deg/s"}.get(unit)
        if unit == "m" and causality == "output" and "deflection" in v.get("description", ""):
            expected = "mm"
        assert v.get("displayUnit") == expected, v.get("name")
        shown[v.get("name")] = expected
    joint = next(n for n, u in shown.items() if n.endswith(".theta") and u)
    assert shown[joint] == "deg" and shown[joint.replace(".theta", ".omega")] == "deg/s" and "mm" in shown.values()
    start = joint.replace(".theta", ".initial_angle")
    run = fmpy.simulate_fmu(str(fmi3_fmu(name)), stop_time=0.01, output_interval=0.01, output=[joint],
                            start_values={start: (30.0, "deg")})
    assert run[joint][0] == pytest.approx(math.pi / 6, rel=1e-15)


def test_fmi3_discarded_step_keeps_the_last_communication_point(fmi3_fmu):
    """FMI 3.0 §4.2.1: a step the FMU's guards refuse (a torque that bends the link past the model's validity) is
    fmi3Discard with terminateSimulation, no early return even where allowed, and lastSuccessfulTime the
    communication point it started from, where the FMU still is: its outputs read as before the step, and the
    importer may terminate cleanly.  Accepted steps return lastSuccessfulTime = the step's end."""
    messages: list[str] = []
    fmu = fmi3_fmu("rotating_link")
    md = fmpy.read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU3Slave(guid=md.instantiationToken, unzipDirectory=fmpy.extract(str(fmu)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="fmi3")
    s.instantiate(earlyReturnAllowed=True,
                  logMessage=lambda env, status, category, message: messages.append(message.decode()))
    do_step = s.dll.fmi3DoStep          # unchecked: fmpy raises on fmi3Discard and drops the output arguments
    do_step.restype = ctypes.c_int
    watched = [vr["hub.theta"], vr["arm.tip.v"], vr["arm.eta"], vr["time"]]
    try:
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()
        s.setFloat64([vr["hub.tau"]], [200.0])
        for k in range(10):
            flags = [ctypes.c_bool() for _ in range(3)]
            last = ctypes.c_double()
            before = s.getFloat64(watched, nValues=6)
            status = do_step(s.component, ctypes.c_double(0.01 * k), ctypes.c_double(0.01), ctypes.c_bool(True),
                             *map(ctypes.byref, flags), ctypes.byref(last))
            if status != 0:
                break
            assert [f.value for f in flags] == [False, False, False] and last.value == pytest.approx(0.01 * (k + 1))
        assert k > 0 and status == 2                                               # fmi3Discard, not at once
        assert [f.value for f in flags] == [False, True, False]                    # terminateSimulation only
        assert last.value == before[-1] == pytest.approx(0.01 * k)
        assert s.getFloat64(watched, nValues=6) == before
        assert "model's validity" in messages[-1] and "discarded" in messages[-1], messages[-1]
        s.terminate()
    finally:
        s.freeInstance()


def test_fmi3_refuses_bad_calls(fmi3_fmu):
    """Bad input is fmi3Error with the reason, never a crash; the instance is revived by fmi3Reset."""
    md, s, vr = slave(fmi3_fmu("rotating_link"))
    statuses = []
    try:
        for call in (lambda: s.setInt64([vr["solver.order"]], [3]),
                     lambda: s.setInt64([vr["solver.order"]], [2**40]),        # not an Int32 behind
                     lambda: s.setInt32([vr["solver.order"]], [4]),            # an Enumeration: Int64 only
                     lambda: s.setFloat64([vr["solver.order"]], [4.0]),
                     lambda: s.setFloat64([vr["time"]], [1.0]),
                     lambda: s.setFloat64([10_000], [1.0]),
                     lambda: s.setBoolean([vr["solver.order"]], [True]),
                     lambda: s.doStep(0.0, 0.01),                       # before initialization
                     lambda: s.enterEventMode()):                      # a Model Exchange function
            with pytest.raises(FMICallException) as e:
                call()
            statuses.append(int(e.value.status))
            s.reset()
        assert statuses == [3] * 9                                  # fmi3Error
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()
        s.doStep(0.0, 0.01)
    finally:
        s.freeInstance()


def test_fmi3_arrays_are_read_whole_and_refused_otherwise(fmi3_fmu):
    """An array is read through its value reference with nValues its size, and equals its elements read as part of
    a longer request; the reference of a later element, a wrong nValues and setting an output array are
    fmi3Error with one message that says what to do, and fmi3Reset revives the instance."""
    messages: list[str] = []
    md, s, vr = slave(fmi3_fmu("rotating_link"), messages=messages)
    eta = vr["arm.eta"]

    def initialised():
        s.reset()
        s.setFloat64([vr["hub.initial_rate"]], [2.0])
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()
        s.setFloat64([vr["hub.tau"]], [0.5])
        s.doStep(0.0, 0.02)

    try:
        initialised()
        whole = s.getFloat64([eta], nValues=3)
        mixed = s.getFloat64([vr["hub.theta"], eta, vr["time"]], nValues=5)
        assert mixed[1:4] == whole and np.any(np.array(whole) != 0) and mixed[4] == pytest.approx(0.02)
        expected = {
            "element 2 of the array at value reference 15": lambda: s.getFloat64([eta + 1]),
            "hold 3 values, not 1": lambda: s.getFloat64([eta], nValues=1),
            "hold 4 values, not 5": lambda: s.getFloat64([vr["hub.theta"], eta], nValues=5),
            "arm.eta[1]": lambda: s.setFloat64([eta], [0.0, 0.0, 0.0]),       # an output: not settable
            "hold 1 values, not 3": lambda: s.setFloat64([vr["hub.tau"]], [0.0, 0.0, 0.0]),
        }
        for text, call in expected.items():
            messages.clear()
            with pytest.raises(FMICallException) as e:
                call()
            assert int(e.value.status) == 3 and len(messages) == 1 and text in messages[0], (text, messages)
            initialised()
    finally:
        s.freeInstance()


@pytest.mark.skipif(shutil.which(MINGW_CC) is None, reason=f"{MINGW_CC} is not installed")
def test_fmi3_win64_binary_exports_the_fmi3_interface(tmp_path):
    rep = build_fmu(EXAMPLES / "rotating_link.toml", tmp_path / "rl.fmu", fmi_version=3,
                    platforms="linux64,win64")
    assert validate_fmu(str(rep.fmu)) == []
    dll = "binaries/x86_64-windows/rotating_link.dll"
    with zipfile.ZipFile(rep.fmu) as z:
        z.extract(dll, tmp_path)
    dumped = subprocess.run(["x86_64-w64-mingw32-objdump", "-p", str(tmp_path / dll)], capture_output=True,
                            text=True, check=True).stdout
    exported = {w for w in dumped.split() if w.startswith("fmi")}
    # every function the FMI 3.0 header declares (its FMI3_Export lines), and nothing else
    header = fmi_headers_dir() / "fmi3Functions.h"
    declared = {line.split()[2].rstrip(";") for line in header.read_text().splitlines()
                if line.startswith("FMI3_Export")}
    assert exported == declared


def test_flexlink_check_runs_on_an_fmi3_fmu(fmi3_fmu, tmp_path, capsys):
    """``flexlink check`` on an FMI 3 FMU: fmpy's validation with every variable read back through the binary,
    both interfaces simulated and compared, legal random call sequences, FMU state and directional derivatives
    (through fmpy's FMI 3 API); the FMI 2-only checks are reported as skipped.  A value reference that the binary
    does not know is caught."""
    from flexlink.cli import main

    fmu = fmi3_fmu("rotating_link")
    assert main(["check", str(fmu), "--me-vs-cs-stop", "0.05", "--fuzz", "20", "--json"]) == 0
    results = {r["name"]: r["status"] for r in json.loads(capsys.readouterr().out)["checks"]}
    assert {name for name, status in results.items() if status == "pass"} >= \
           {"model-description", "me-vs-cs", "fuzz", "fmu-state", "directional-derivatives", "illegal-calls"}
    assert "libcosim" in {name for name, status in results.items() if status == "skip"}       # FMI 2.0 only
    bad = tmp_path / "bad.fmu"
    with zipfile.ZipFile(fmu) as z, zipfile.ZipFile(bad, "w") as out:
        for item in z.infolist():
            data = z.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'name="solver.tolerance" valueReference="8"',
                                    b'name="solver.tolerance" valueReference="9999"')
                assert b'valueReference="9999"' in data
            out.writestr(item, data)
    assert main(["check", str(bad), "--only", "model-description"]) == 1
    assert "9999" in capsys.readouterr().out
    # the harness sets and reads the Enumeration solver.order with FMI 3's Int64 functions, an array whole
    from flexlink.tools.check.fmu import Fmu, free, get_values, start

    f = Fmu(fmu)
    try:
        inst = f.instance("CS")
        start(f, inst, "CS", {"solver.order": 4})
        assert get_values(inst, [f.vars["solver.order"]]) == [4]
        assert len(get_values(inst, [f.vars["arm.eta"]])) == 3 and "arm.eta[3]" in f.outputs
        free(inst)
    finally:
        f.close()


@pytest.mark.parametrize("cc", ["gcc", "clang", MINGW_CC])
def test_fmi3_sources_compile_clean_as_strict_c99(fmi3_fmu, tmp_path, cc):
    """The FMI 3 FMU's ``sources/``: every file its buildDescription.xml lists (all the C files shipped, with
    fmi3Functions.c instead of fmi2Functions.c), strict C99 with every warning an error."""
    from fmpy.model_description import read_build_description

    if shutil.which(cc) is None:
        pytest.skip(f"{cc} is not installed")
    fmu = fmi3_fmu("rotating_link")
    with zipfile.ZipFile(fmu) as z:
        z.extractall(tmp_path)
    files = read_build_description(fmu, validate=True)[0].sourceFileSets[0].sourceFiles
    assert sorted(files) == sorted(p.name for p in (tmp_path / "sources").glob("*.c"))
    assert "fmi3Functions.c" in files and "fmi2Functions.c" not in files
    flags = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O1", "-shared"] + (["-fPIC"] if cc != MINGW_CC
                                                                                          else [])
    res = subprocess.run([cc, *flags, f"-I{tmp_path / 'sources'}", *(str(tmp_path / "sources" / f) for f in files),
                          "-o", str(tmp_path / "lib"), "-lm"], capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stderr == "", res.stderr[-4000:]
