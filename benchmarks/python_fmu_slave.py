"""The Python-based FMU of the co-simulation comparison (benchmarks/cosim_loop.py): a PythonFMU slave.

It integrates the same equations as the flexlink FMU — the scene's symbolic model, x' = (v, a) with
M(q) a = −r(q, v, 0, u, p) — with the classical explicit Runge–Kutta method (order 4): ``solver.substeps``
equal steps per communication step, all of them inside one CasADi function per ``do_step`` (generated
and saved by ``cosim_loop.build_python_fmu`` into the FMU's resources), so the Python side of a step is
one call.  This is about as fast as a Python FMU gets without writing C.

Resources: ``flexlink_py.json`` (sizes, start state, parameters, input and output names, the available
substep counts) and ``step_<k>.casadi``: (x, u, p, h) -> (x after k RK4 steps of h/k, outputs at the end).
"""

from __future__ import annotations

import json
import os

import casadi as ca
import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real


class FlexlinkPython(Fmi2Slave):
    description = "flexlink model integrated by RK4 in Python (benchmark only)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        with open(os.path.join(self.resources, "flexlink_py.json")) as f:
            meta = json.load(f)
        self.functions = {int(k): ca.Function.load(os.path.join(self.resources, f"step_{k}.casadi"))
                          for k in meta["substeps"]}
        self.x0 = np.array(meta["x0"], dtype=float)
        self.p = np.array(meta["p0"], dtype=float)
        self.u = np.array(meta["u0"], dtype=float)
        self.x = ca.DM(self.x0)
        self.y = np.zeros(len(meta["outputs"]))
        self.substeps = 1
        for i, name in enumerate(meta["inputs"]):
            self.register_variable(Real(name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                                        getter=lambda i=i: self.u[i], setter=lambda v, i=i: self._set_input(i, v)))
        self.register_variable(Integer("solver.substeps", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.tunable, getter=lambda: self.substeps,
                                       setter=self._set_substeps))
        for i, name in enumerate(meta["outputs"]):
            self.register_variable(Real(name, causality=Fmi2Causality.output, variability=Fmi2Variability.continuous,
                                        getter=lambda i=i: self.y[i]))

    def _set_input(self, i, value):
        self.u[i] = value

    def _set_substeps(self, value):
        if int(value) not in self.functions:
            raise ValueError(f"solver.substeps = {value}: one of {sorted(self.functions)}")
        self.substeps = int(value)

    def exit_initialization_mode(self):
        self.x = ca.DM(self.x0)
        _, y = self.functions[self.substeps](self.x, self.u, self.p, 0.0)
        self.y = y.full().ravel()

    def do_step(self, current_time, step_size):
        self.x, y = self.functions[self.substeps](self.x, self.u, self.p, step_size)
        self.y = y.full().ravel()
        return True
