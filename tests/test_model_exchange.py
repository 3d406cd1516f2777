"""Model Exchange in the same FMU as Co-Simulation: ME (CVODE, tight) and CS (SS22, small step) agree over
0.5 s for every example with FLEXLINK_FULL=1, for three in CI (tests/test_check.py compares every example
over 0.1 s there); the ME state machine, time events at the segment boundaries of built-in laws."""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.fmi2 import FMU2Model

from flexlink.tools.check.fmu import Fmu as _Fmu
from flexlink.tools.check.me_vs_cs import ME_VS_CS_ACCELERATION_TOLERANCE, ME_VS_CS_TOLERANCE, check_me_vs_cs

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NAMES = sorted(p.stem for p in EXAMPLES.glob("*.toml"))
FULL = os.environ.get("FLEXLINK_FULL") == "1"
# CI size: a planar link with a torque input, a built-in law with a time event, a spatial link
AGREE = NAMES if FULL else ["rotating_link", "steel_beam_raise", "spatial_cantilever"]


@pytest.fixture(scope="session")
def me_fmus(example_fmu):
    return {n: example_fmu(n) for n in sorted({*AGREE, "rotating_link", "steel_beam_raise"})}


@pytest.mark.parametrize("name", AGREE)
def test_me_and_cs_agree(me_fmus, name):
    f = _Fmu(me_fmus[name])
    try:
        r = check_me_vs_cs(f)
    finally:
        f.close()
    assert r.status == "pass", r.details
    errors = {line.split(":")[0]: float(line.split("=")[-1]) for line in r.details if "max |ME - CS|" in line}
    assert errors
    positions = [e for n, e in errors.items() if not n.startswith(("tip.a", "tip.s")) and ".reaction.f" not in n]
    assert max(positions) < ME_VS_CS_TOLERANCE
    assert max(errors.values()) < ME_VS_CS_ACCELERATION_TOLERANCE


def _model(path):
    md = fmpy.read_model_description(str(path))
    d = fmpy.extract(str(path))
    inst = FMU2Model(guid=md.guid, unzipDirectory=d, modelIdentifier=md.modelExchange.modelIdentifier,
                     instanceName="me")
    return md, inst


def test_model_description_declares_both_interfaces(me_fmus):
    md = fmpy.read_model_description(str(me_fmus["rotating_link"]))
    assert md.modelExchange.modelIdentifier == md.coSimulation.modelIdentifier
    assert md.modelExchange.providesDirectionalDerivative and md.coSimulation.providesDirectionalDerivative
    assert md.numberOfEventIndicators == 0
    assert md.numberOfContinuousStates == 8
    states = [u.variable.derivative.name for u in md.derivatives]
    assert states[:4] == ["q.hub.theta", "q.arm.eta[1]", "q.arm.eta[2]", "q.arm.eta[3]"]
    assert [u.variable.name for u in md.derivatives][4] == "der(v.hub.theta)"
    # der(q.hub.theta) = v.hub.theta exactly (constant), the acceleration depends on the input
    dq = md.derivatives[0]
    assert [v.name for v in dq.dependencies] == ["v.hub.theta"] and dq.dependenciesKind == ["constant"]
    assert "hub.tau" in [v.name for v in md.derivatives[4].dependencies]


def test_state_machine_and_time_events(me_fmus):
    """steel_beam_raise: a built-in law with a segment boundary at t = 1 s: nextEventTime says so, and
    the derivatives are (v, a) with the law's acceleration jumping there."""
    md, inst = _model(me_fmus["steel_beam_raise"])
    nx = md.numberOfContinuousStates
    inst.instantiate()
    nominal = np.zeros(nx)
    inst.getNominalsOfContinuousStates(nominal.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), nx)
    assert np.all(nominal > 0)
    inst.setupExperiment(startTime=0.0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    info = inst.newDiscreteStates()
    assert info[4] and info[5] == pytest.approx(1.0)     # nextEventTimeDefined, nextEventTime
    inst.enterContinuousTimeMode()
    x = np.zeros(nx)
    dx = np.zeros(nx)
    px, pdx = (a.ctypes.data_as(ctypes.POINTER(ctypes.c_double)) for a in (x, dx))
    inst.getContinuousStates(px, nx)
    inst.setTime(0.5)
    inst.getDerivatives(pdx, nx)
    np.testing.assert_array_equal(dx[:nx // 2], x[nx // 2:])
    tau_before = inst.getReal([md.modelVariables[[v.name for v in md.modelVariables].index("base.tau")]
                               .valueReference])[0]
    inst.setTime(1.0)
    inst.enterEventMode()
    info = inst.newDiscreteStates()
    assert not info[4]                                     # no later event
    inst.enterContinuousTimeMode()
    inst.getDerivatives(pdx, nx)
    assert np.all(np.isfinite(dx))
    assert tau_before != 0.0
    # calls out of order are refused with fmi2Error
    with pytest.raises(fmpy.fmi1.FMICallException):
        inst.newDiscreteStates()
    inst.reset()
    inst.freeInstance()


def test_me_run_with_events_matches_cs_at_the_boundary(me_fmus):
    """Across the segment boundary (t = 1 s) of steel_beam_raise the ME run (restarting CVODE at the
    time event) and CS agree."""
    import fmpy.sundials as sundials

    f = _Fmu(me_fmus["steel_beam_raise"])
    orig = sundials.CVodeSolver
    try:
        r = check_me_vs_cs(f, stop_time=1.2)
    finally:
        sundials.CVodeSolver = orig
        f.close()
    assert r.status == "pass", r.details
