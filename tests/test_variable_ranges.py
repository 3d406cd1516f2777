"""What the model description declares is what the FMU accepts (issue 17): ``solver.order`` is an Integer whose
only valid values are 2 and 4, and each declared ``min``/``max`` is a value the FMU takes while the next double
beyond it is refused.  The expectations come from the FMI 2.0 rules (a value outside [min, max] is illegal, an
Integer is set with fmi2SetInteger) and from the model description itself, not from earlier runs."""

from __future__ import annotations

import math
import shutil

import fmpy
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from flexlink.errors import FlexlinkError
from flexlink.run.simulate import logging_callbacks, simulate


class Slave:
    """An FMU2Slave of ``fmu`` whose FMU messages are kept (the reason of a refusal)."""

    def __init__(self, fmu):
        self.md = fmpy.read_model_description(str(fmu))
        self.dir = fmpy.extract(str(fmu))
        self.messages: list[str] = []
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=self.dir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName="ranges")
        self.callbacks = logging_callbacks(lambda *m: self.messages.append(
            m[-1].decode() if isinstance(m[-1], bytes) else str(m[-1])))
        self.slave.instantiate(callbacks=self.callbacks)

    def refused(self, call, *args) -> str | None:
        """The FMU's message if ``call`` returns fmi2Error (the instance is then reset), else None."""
        try:
            call(*args)
            return None
        except FMICallException:
            self.slave.reset()
            return self.messages[-1]

    def close(self):
        self.slave.freeInstance()
        shutil.rmtree(self.dir, ignore_errors=True)


def test_solver_order_is_an_integer_that_takes_2_and_4(example_fmu):
    s = Slave(example_fmu("rotating_link"))
    try:
        order = s.vars["solver.order"]
        assert (order.type, order.start, order.min, order.max) == ("Integer", "2", "2", "4")
        vr = [order.valueReference]
        why = s.refused(s.slave.setInteger, vr, [3])
        assert why is not None and "solver.order = 3: must be 2" in why
        # the Real functions still take it, as before it was an Integer, with whole values only
        assert s.refused(s.slave.setReal, vr, [4.0]) is None
        why = s.refused(s.slave.setReal, vr, [2.5])
        assert why is not None and "must be a whole number" in why
        # set as an Integer, order 4 runs (SS22 with Richardson extrapolation needs Theta = 1/2: the default)
        s.slave.setInteger(vr, [4])
        s.slave.setupExperiment(startTime=0.0)
        s.slave.enterInitializationMode()
        assert s.slave.getInteger(vr) == [4] and s.slave.getReal(vr) == [4.0]
        why = s.refused(s.slave.getInteger, [s.vars["solver.step"].valueReference])
        assert why is not None and "is a Real" in why
        s.slave.setInteger(vr, [4])
        s.slave.setupExperiment(startTime=0.0)
        s.slave.enterInitializationMode()
        s.slave.exitInitializationMode()
        s.slave.doStep(0.0, 0.01)
    finally:
        s.close()


def test_simulate_sets_solver_order_as_an_integer(example_fmu):
    """The command line's ``--set solver.order=4`` path: fmpy sets an Integer; 3 and 4.5 are one clear line."""
    fmu = example_fmu("rotating_link")
    assert len(simulate(fmu, 0.02, step=0.01, start_values={"solver.order": 4.0})) == 3
    with pytest.raises(FlexlinkError, match="solver.order = 3: must be 2"):
        simulate(fmu, 0.02, step=0.01, start_values={"solver.order": 3.0})
    with pytest.raises(FlexlinkError, match="solver.order is an Integer"):
        simulate(fmu, 0.02, step=0.01, start_values={"solver.order": 4.5})


@pytest.mark.parametrize("name", ["rotating_link", "flexible_pendulum"])
def test_declared_bounds_are_what_the_fmu_accepts(example_fmu, name):
    """Every declared min (max) is accepted, the next double below (above) refused.  A relation between
    parameters (an inertia tensor's, a density's) may refuse a bound that no single min can state: then the
    message says which relation."""
    s = Slave(example_fmu(name))
    try:
        checked = 0
        for v in s.md.modelVariables:
            if v.type != "Real" or v.causality not in ("parameter", "input"):
                continue
            for bound, outward in ((v.min, -math.inf), (v.max, math.inf)):
                if bound is None:
                    continue
                x = float(bound)
                why = s.refused(s.slave.setReal, [v.valueReference], [x])
                assert why is None or "would break" in why, (v.name, x, why)
                beyond = math.nextafter(x, outward)
                why = s.refused(s.slave.setReal, [v.valueReference], [beyond])
                assert why is not None and v.name in why, (v.name, beyond)
                checked += 1
        assert checked >= 6        # the stiffnesses, densities and solver settings at least
    finally:
        s.close()
