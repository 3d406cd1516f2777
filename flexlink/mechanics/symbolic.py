"""What a symbolic model is: the residual and output Functions of a scene and the tables that name them.

This is the hand-over between the mechanics stage and everything after it (export, analysis, reference
simulation, linearisation): plain data, CasADi Functions and numpy arrays, nothing that refers back to the
builder that made it (:mod:`flexlink.mechanics.assembly`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from flexlink.scene.loader import Scene, Trajectory


@dataclass(frozen=True)
class Parameter:
    """A tunable physical parameter of the generated model (an FMU parameter)."""

    name: str
    value: float
    unit: str
    description: str
    min: float = -np.inf
    min_exclusive: bool = False


@dataclass(frozen=True)
class Signal:
    """A named entry of the model's input vector u or output vector y."""

    name: str
    unit: str
    description: str
    start: float = 0.0
    fmu_variable: bool = True      # False for the slots of a built-in law (no FMU input)
    feedthrough: bool = False      # output depends directly on inputs (through the acceleration)


@dataclass(frozen=True)
class Law:
    """A position-driven joint: u[u_offset : u_offset + 3] = (θ, θ̇, θ̈)."""

    joint: str
    u_offset: int
    trajectory: Trajectory | None   # None: the host sets <joint>.theta_ref/omega_ref/alpha_ref


@dataclass(frozen=True)
class StartValue:
    """A fixed FMU parameter giving the initial position or rate of a free coordinate."""

    name: str
    coordinate: int
    rate: bool
    value: float
    unit: str
    description: str


@dataclass
class SymbolicModel:
    """Everything code generation, analysis and the reference simulation need about a scene."""

    scene: Scene
    coordinates: list[str]
    nominal_q: np.ndarray
    parameters: list[Parameter]
    inputs: list[Signal]
    laws: list[Law]
    outputs: list[Signal]
    start_values: list[StartValue]
    static_coordinates: list[int]
    residual: ca.Function          # (q, v, a, u, p) -> r
    outputs_function: ca.Function  # (q, v, a, u, p) -> y
    linear_in_state: bool
    jacobian_constant: bool
    terms: list[str] = field(default_factory=list)   # what the model contains and why (explain)
    coordinate_kinds: list[str] = field(default_factory=list)   # "joint" | "link_angle" | "elastic"
    validity: ca.Function | None = None   # (q, u, p) -> g: the model's assumptions hold while every g <= 1
    validity_names: list[str] = field(default_factory=list)   # what each entry of g measures
    mass_matrix: ca.Function | None = None   # (q, u, p) -> M, if the builder forms it more cheaply than ∂r/∂a
    parameter_check: ca.Function | None = None   # p -> h: the parameters are physical while every h >= 0
    parameter_check_names: list[str] = field(default_factory=list)
    # B = ∂r/∂u where constant (mechanics.assembly.structure; None with kinematic laws, whose slots are not
    # forces): the inputs' generalized forces are −B u
    input_matrix: np.ndarray | None = None

    @property
    def n_q(self) -> int:
        """The number of free coordinates."""
        return len(self.coordinates)

    @property
    def p0(self) -> np.ndarray:
        """The parameters' values from the scene, in parameter order."""
        return np.array([par.value for par in self.parameters], dtype=float)

    def parameter_index(self, name: str) -> int:
        """The position of the parameter ``name`` (KeyError if the model has none of that name)."""
        for i, par in enumerate(self.parameters):
            if par.name == name:
                return i
        raise KeyError(name)

    def output_index(self, name: str) -> int:
        """The position of the output ``name`` (KeyError if the model has none of that name)."""
        for i, sig in enumerate(self.outputs):
            if sig.name == name:
                return i
        raise KeyError(name)

    def newton_matrix_function(self) -> ca.Function:
        """J = ca ∂r/∂a + cv ∂r/∂v + cq ∂r/∂q as one directional Jacobian (what an implicit step needs)."""
        q, v, a, u, p = (ca.MX.sym(n, *self.residual.size_in(i)) for i, n in enumerate("qvaup"))
        c = [ca.MX.sym(n) for n in ("ca", "cv", "cq")]
        d = ca.MX.sym("d", self.n_q)
        r = self.residual(q + c[2] * d, v + c[1] * d, a + c[0] * d, u, p)
        J = ca.jacobian(r, d)
        J = ca.substitute(J, d, ca.DM.zeros(self.n_q))
        return ca.Function("newton_matrix", [q, v, a, u, p, *c], [ca.densify(J)],
                           ["q", "v", "a", "u", "p", "ca", "cv", "cq"], ["J"])

    def mass_matrix_function(self) -> ca.Function:
        """M(q, u, p) = ∂r/∂a: the builder's own form if it gave one, else the residual's Jacobian."""
        if self.mass_matrix is not None:
            return self.mass_matrix
        q, v, a, u, p = (ca.MX.sym(n, *self.residual.size_in(i)) for i, n in enumerate("qvaup"))
        M = ca.jacobian(self.residual(q, v, a, u, p), a)
        M = ca.substitute(M, ca.vertcat(v, a), ca.DM.zeros(2 * self.n_q))
        return ca.Function("mass_matrix", [q, u, p], [ca.densify(M)], ["q", "u", "p"], ["M"])

    def default_inputs(self, t: float = 0.0) -> np.ndarray:
        """Model inputs at time t: input start values, built-in laws evaluated."""
        u = np.array([s.start for s in self.inputs], dtype=float)
        for law in self.laws:
            if law.trajectory is not None:
                u[law.u_offset:law.u_offset + 3] = law.trajectory.evaluate(t)
        return u

    def start_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) at the start: zero but for the scene's start values."""
        q = np.zeros(self.n_q)
        v = np.zeros(self.n_q)
        for s in self.start_values:
            (v if s.rate else q)[s.coordinate] = s.value
        return q, v
