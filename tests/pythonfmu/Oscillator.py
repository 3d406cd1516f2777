"""A damped oscillator as a PythonFMU 0.7.0 Co-Simulation slave, a third-party FMU for the tests of
``flexlink check`` (tests/check_third_party.py builds it): x'' = -k x - c x' + u from x = 1, x' = 0, with
k = 4 and c = 0.5 tunable, an Integer input n and its double m, a Boolean input b and its negation nb, and a
String parameter.  ``DECLARED`` False leaves out the variability and initial attributes, as PythonFMU's own
examples do, to show what PythonFMU writes by default."""

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Initial

DECLARED = True
SUBSTEP = 1e-4          # s, semi-implicit Euler inside each communication step


class Oscillator(Fmi2Slave):
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=0.01)
    description = "damped oscillator (a test fixture of flexlink check)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.x, self.v, self.u, self.k, self.c = 1.0, 0.0, 0.0, 4.0, 0.5
        self.n, self.m, self.b, self.nb, self.label = 1, 2, False, True, "oscillator"
        discrete = {"variability": Fmi2Variability.discrete} if DECLARED else {}
        exact = {"initial": Fmi2Initial.exact} if DECLARED else {}
        tunable = {"causality": Fmi2Causality.parameter, "variability": Fmi2Variability.tunable}
        self.register_variable(Real("x", causality=Fmi2Causality.output, **exact))
        self.register_variable(Real("v", causality=Fmi2Causality.output, **exact))
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("k", **tunable))
        self.register_variable(Real("c", **tunable))
        self.register_variable(Integer("n", causality=Fmi2Causality.input, **discrete))
        self.register_variable(Integer("m", causality=Fmi2Causality.output, **discrete, **exact))
        self.register_variable(Boolean("b", causality=Fmi2Causality.input, **discrete))
        self.register_variable(Boolean("nb", causality=Fmi2Causality.output, **discrete, **exact))
        self.register_variable(String("label", **tunable))

    def do_step(self, current_time, step_size):
        steps = max(1, int(round(step_size / SUBSTEP)))
        h = step_size / steps
        for _ in range(steps):
            self.v += h * (-self.k * self.x - self.c * self.v + self.u)
            self.x += h * self.v
        self.m = 2 * self.n
        self.nb = not self.b
        return True
