"""flexlink.run.host.FmuHost: one instance from extraction to clean-up, refusals as one error with the FMU's
reason.  The refusals asserted are the FMU's own rules (fmu_src: the doStep bound of
flexlink.scene.solver.DOSTEP_MAX_INTERNAL_STEPS, the declared range of solver.theta1), and the counters of
logStatistics are checked against the step count the settings imply."""

from __future__ import annotations

import os

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from flexlink.errors import FlexlinkError
from flexlink.run.host import FmuCallError, FmuHost, pointer
from flexlink.scene import solver


@pytest.fixture(scope="module")
def fmu(example_fmu):
    return example_fmu("rotating_link")


def test_a_discarded_step_is_one_error_with_the_fmu_reason(fmu) -> None:
    step = 1e-9
    with FmuHost(fmu) as host:
        host.initialize({"solver.step": step})
        with pytest.raises(FmuCallError) as info:
            host.call("fmi2DoStep", host.instance.doStep, 0.0, 1e-2)
        e = info.value
        assert e.status == 2 and e.function == "fmi2DoStep"
        assert f"at most {solver.DOSTEP_MAX_INTERNAL_STEPS}" in e.reason
        assert isinstance(e, FlexlinkError) and isinstance(e, FMICallException)
        assert str(e).startswith(f"{os.path.basename(fmu)}: fmi2DoStep failed with status 2 (discard): ")
        host.call("fmi2DoStep", host.instance.doStep, 0.0, 100 * step)    # the instance goes on


def test_a_value_outside_the_declared_range_is_refused_with_its_name(fmu) -> None:
    with FmuHost(fmu) as host, pytest.raises(FmuCallError) as info:
        host.initialize({"solver.theta1": solver.THETA_MIN - 0.1})
    assert info.value.status == 3 and "solver.theta1" in info.value.reason


def test_an_unknown_name_is_refused_with_the_closest_names(fmu) -> None:
    with FmuHost(fmu) as host, pytest.raises(FlexlinkError, match="did you mean .*solver.step"):
        host.value_reference("solver.stepp")


def test_the_statistics_count_the_steps_the_settings_imply(fmu) -> None:
    with FmuHost(fmu) as host:
        for run in range(2):                         # the second run resets the instance
            host.initialize({"solver.step": 5e-4})
            for k in range(10):
                host.call("fmi2DoStep", host.instance.doStep, k * 1e-2, 1e-2)
            stats = host.solver_statistics()
            assert stats["steps"] == 200, run        # 0.1 s in steps of 0.5 ms
            assert stats["newton_iterations"] >= stats["steps"]


def test_model_exchange_and_clean_up(fmu) -> None:
    with FmuHost(fmu, interface="ModelExchange", instance_name="me") as host:
        host.initialize()
        extracted = host._unzipdir
        assert extracted is not None and os.path.isdir(extracted)
        host.call("fmi2NewDiscreteStates", host.instance.newDiscreteStates)
        host.call("fmi2EnterContinuousTimeMode", host.instance.enterContinuousTimeMode)
        assert host.get_real(["hub.theta"]) == [0.0]
    assert not os.path.exists(extracted)
    with pytest.raises(ValueError, match="interface"):
        FmuHost(fmu, interface="Scheduled")


def test_the_raw_calls_of_a_loop_and_their_refusal(fmu) -> None:
    """The functions a closed loop calls each sample (cffi, on pointers): the values fmpy's wrapper reads, the
    status the FMU returns, and the refusal built from it carries the FMU's reason and the loop's place."""
    import ctypes

    step = 1e-9
    with FmuHost(fmu) as host:
        host.initialize({"solver.step": 1e-3})
        get_real, do_step = host.raw("fmi2GetReal"), host.raw("fmi2DoStep")
        comp = pointer(host.instance.component, "void")
        assert do_step(comp, 0.0, 0.01, 1) == 0
        refs = (ctypes.c_uint * 2)(host.vr["hub.theta"], host.vr["hub.omega"])
        values = np.zeros(3)
        at = pointer(values.ctypes.data, "double")
        assert get_real(comp, pointer(ctypes.addressof(refs), "unsigned int"), 2, at + 1) == 0
        assert list(values) == [0.0, *host.get_real(["hub.theta", "hub.omega"])]
        host.initialize({"solver.step": step})
        status = host.raw("fmi2DoStep")(pointer(host.instance.component, "void"), 0.0, 1e-2, 1)
        assert status == 2
        e = host.refusal("fmi2DoStep", status, where="step 0 (t = 0 s)")
        assert f"at most {solver.DOSTEP_MAX_INTERNAL_STEPS}" in e.reason
        assert str(e).startswith(f"{os.path.basename(fmu)}: step 0 (t = 0 s) failed (fmi2DoStep failed with "
                                 "status 2 (discard)): ")
        with pytest.raises(ValueError, match="fmi2DoStep"):
            host.raw("fmi2GetFMUstate")


def test_the_library_is_freed_once(fmu, monkeypatch) -> None:
    """fmpy's freeInstance unloads the library itself: the host's clean-up must not unload it again."""
    import fmpy.fmi1

    closed = []
    unload = fmpy.fmi1.freeLibrary
    monkeypatch.setattr(fmpy.fmi1, "freeLibrary", lambda handle: (closed.append(handle), unload(handle)))
    host = FmuHost(fmu)
    host.initialize()
    host.close()
    host.close()
    assert len(closed) == 1
