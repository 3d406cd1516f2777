"""The scene's model linearised about an operating point, as a python-control ``StateSpace``.

With x = (q, q̇) the free coordinates and their rates, the linearised equations
``M δq̈ + C δq̇ + K δq = B δu`` (:func:`flexlink.mechanics.analysis.linearise`) give

    A = [[0, I], [−M⁻¹K, −M⁻¹C]],   B = [[0], [M⁻¹ B_u]]   (B_u = −∂r/∂u),

and the outputs y(q, v, a(q, v, u), u) — with the acceleration a from the residual, which is affine in
a — give C = ∂y/∂x and D = ∂y/∂u.  Outputs that depend on the acceleration (tip accelerations, the
accelerometer's specific force) have D ≠ 0.  Everything is a deviation from the operating point
(``x0``, ``u0``, ``y0`` of :class:`LinearPlant`).

**Names.** States keep the model's coordinate names (``hub.theta``, ``arm.eta[1]``, …) and their rates
are ``der(hub.theta)``, ``der(arm.eta[1])``, … (the FMI convention).  python-control 0.10 reserves "."
in *input and output* names for ``system.signal`` references in ``interconnect``, so there the FMU's
names are spelled with "_" (:func:`signal_name`: ``hub.tau`` → ``hub_tau``, ``arm.tip.v`` →
``arm_tip_v``, ``arm.eta[1]`` → ``arm_eta[1]``, which python-control also reads as element 1 of the
vector signal ``arm_eta``).  :class:`LinearPlant` keeps the FMU names beside them.
"""

from __future__ import annotations

import functools
import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.export.variables import BIG
from flexlink.mechanics.analysis import Linearisation, OperatingPoint, linearise, operating_point, static_deflection
from flexlink.mechanics.model import SymbolicModel, build_model
from flexlink.scene.loader import Scene, load_scene

if TYPE_CHECKING:      # python-control (SciPy's signal and stats, matplotlib's pyplot) only when .sys is built
    import control as ct

__all__ = ["LinearPlant", "explicit_functions", "fmu_state_space", "linear_plant", "linearize", "operating_point_at",
           "signal_name", "state_names"]


def signal_name(fmu_name: str) -> str:
    """The python-control spelling of an FMU input/output name ("." is reserved there): "." → "_"."""
    return fmu_name.replace(".", "_")


def state_names(model: SymbolicModel) -> list[str]:
    """``q`` names then ``der(q)`` names: the state x = (q, q̇)."""
    return [*model.coordinates, *(f"der({c})" for c in model.coordinates)]


@dataclass
class LinearPlant:
    """A linearised plant: its state-space matrices, the python-control system, the operating point, the names.

    The matrices come from the model alone (CasADi, numpy); ``sys``, the python-control system, is built from
    them on first use, so that a caller which only needs the numbers (``flexlink linearize``) does not import
    python-control (docs/performance.md, "Start-up").

    Attributes
    ----------
    A, B, C, D : ndarray
        ``δẋ = A δx + B δu``, ``δy = C δx + D δu``: continuous time, ``sys``'s matrices.
    name : str
        ``sys``'s name.
    model : SymbolicModel
    op : OperatingPoint
        (q, v, u, p) of the model about which ``sys`` holds.
    x0, u0, y0 : ndarray
        State, inputs and (selected) outputs at the operating point.
    inputs, outputs : list of str
        FMU names of ``sys``'s inputs and outputs, in order (``sys`` spells them with "_").
    mechanics : Linearisation
        The second-order form ``M δq̈ + C δq̇ + K δq = B δu`` (all model inputs) behind ``sys``.
    cache : dict
        Room for functions derived from the model by users of the plant (built once per plant).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    name: str
    model: SymbolicModel
    op: OperatingPoint
    x0: np.ndarray
    u0: np.ndarray
    y0: np.ndarray
    inputs: list[str]
    outputs: list[str]
    mechanics: Linearisation
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    @functools.cached_property
    def sys(self) -> ct.StateSpace:
        """The continuous-time ``control.StateSpace`` with named signals (python-control imported here)."""
        import control as ct

        return ct.ss(self.A, self.B, self.C, self.D, name=self.name, states=self.states,
                     inputs=[signal_name(s) for s in self.inputs], outputs=[signal_name(s) for s in self.outputs])

    @property
    def nstates(self) -> int:
        """The number of states, ``sys.nstates`` without building ``sys``."""
        return int(self.A.shape[0])

    @property
    def states(self) -> list[str]:
        """The state names, in the plant's order: ``q`` then ``der(q)`` (:func:`state_names`)."""
        return state_names(self.model)

    def output_row(self, name: str) -> int:
        """Index in ``sys``'s outputs of an output given by its FMU name (or python-control name)."""
        for i, n in enumerate(self.outputs):
            if name in (n, signal_name(n)):
                return i
        raise KeyError(f"{name!r} is not an output of this linearisation; outputs are {self.outputs}")

    def state_index(self, name: str) -> int:
        """The position of the state ``name``."""
        return self.states.index(name)

    def parameter(self, name: str) -> float:
        """The value of the parameter ``name`` at the operating point."""
        return float(self.op.p[self.model.parameter_index(name)])


def _model_of(scene_or_model) -> SymbolicModel:
    if isinstance(scene_or_model, SymbolicModel):
        return scene_or_model
    if isinstance(scene_or_model, Scene):
        return build_model(scene_or_model)
    if isinstance(scene_or_model, str | os.PathLike):
        return build_model(load_scene(scene_or_model))
    raise TypeError(f"expected a SymbolicModel, a Scene or a scene path, got {type(scene_or_model).__name__}")


def _parameter_vector(model: SymbolicModel, parameters: Mapping[str, float] | None) -> np.ndarray:
    """The model's parameter vector with ``parameters`` changed, each refused where the FMU refuses it.

    A linearisation of a plant the FMU would refuse (a negative stiffness: unstable poles; a zero one: a
    singular static deflection; a subnormal one: poles of 1e-154) is no answer; the message is the FMU's.
    """
    p = model.p0.copy()
    for name, value in (parameters or {}).items():
        try:
            k = model.parameter_index(name)
        except KeyError:
            known = [par.name for par in model.parameters]
            raise FlexlinkError(f"{name}: not a tunable parameter of this model; its parameters are {known}") from None
        par = model.parameters[k]
        why = outside_domain(name, float(value), par.min if math.isfinite(par.min) else -BIG, par.min_exclusive)
        if why:
            raise FlexlinkError(why)
        p[k] = float(value)
    return p


def outside_domain(name: str, x: float, lo: float, lo_exclusive: bool, hi: float = BIG) -> str | None:
    """Why a parameter's value ``x`` is refused, in the FMU's words, or None.

    The rule of the FMU's ``fmi2SetReal`` (``outside_domain`` in fmu_src/variables.c): finite, not subnormal,
    within its bounds (``BIG``, the C tables' "no bound", where it has none).
    """
    if not math.isfinite(x):
        return f"{name} = {x:g}: NaN and infinite values are refused"
    if x != 0.0 and abs(x) < sys.float_info.min:
        return f"{name} = {x:g}: subnormal values are refused (0 or magnitude >= {sys.float_info.min:g})"
    if not (x > lo if lo_exclusive else x >= lo):
        return f"{name} = {x:.15g}: must be {'>' if lo_exclusive else '>='} {lo:.15g}"
    if not x <= hi:
        return f"{name} = {x:.15g}: must be <= {hi:.15g}"
    return None


def operating_point_at(model: SymbolicModel, *, angle: float | None = None, rate: float = 0.0,
                       parameters: Mapping[str, float] | None = None) -> OperatingPoint:
    """The operating point of ``flexlink modes``, optionally moved and with parameters changed.

    That of :func:`flexlink.mechanics.analysis.operating_point`, with the first joint at ``angle`` (rad)
    instead of its initial angle if given.

    The elastic coordinates take their static (steady-state) deflection there and a torque-driven first
    joint gets the torque that holds it.
    """
    p = _parameter_vector(model, parameters)
    op = operating_point(model, rate, p)
    if angle is None:
        return op
    first = model.scene.joints[0].name + ".theta"
    if first not in model.coordinates:
        raise FlexlinkError(f"the first joint is not a free coordinate (drive = "
                            f'"{model.scene.joints[0].drive}"): its angle is set by its law')
    i = model.coordinates.index(first)
    q = op.q.copy()
    q[i] = angle
    elastic = [k for k, c in enumerate(model.coordinates) if not c.endswith(".theta")]
    u = model.default_inputs(0.0)
    q = static_deflection(model, q, op.v, u, p, elastic)
    r = np.asarray(model.residual(q, op.v, np.zeros(model.n_q), u, p), dtype=float).ravel()
    names = [s.name for s in model.inputs]
    for k, c in enumerate(model.coordinates):
        if c.endswith(".theta") and c.removesuffix(".theta") + ".tau" in names:
            u[names.index(c.removesuffix(".theta") + ".tau")] += r[k]
    return OperatingPoint(q, op.v.copy(), u, p)


def explicit_functions(model: SymbolicModel) -> tuple[ca.Function, ca.Function]:
    """The explicit first-order form ``f(x, u, p) = ẋ`` and ``h(x, u, p) = y`` (all the model's outputs).

    The acceleration comes from the residual (affine in it).  ``u`` is the model's whole input vector.
    """
    n = model.n_q
    q, v, a = ca.MX.sym("q", n), ca.MX.sym("v", n), ca.MX.sym("a", n)
    u = ca.MX.sym("u", model.residual.size1_in(3))
    p = ca.MX.sym("p", model.residual.size1_in(4))
    r = model.residual(q, v, a, u, p)
    zero = ca.DM.zeros(n)
    M = ca.substitute(ca.jacobian(r, a), a, zero)
    acc = -ca.solve(M, ca.substitute(r, a, zero))
    x = ca.vertcat(q, v)
    return (ca.Function("f", [x, u, p], [ca.vertcat(v, acc)], ["x", "u", "p"], ["xdot"]),
            ca.Function("h", [x, u, p], [model.outputs_function(q, v, acc, u, p)], ["x", "u", "p"], ["y"]))


def _output_functions(model: SymbolicModel):
    """(x, u, p) → (∂ẋ/∂x, ∂ẋ/∂u, y, ∂y/∂x, ∂y/∂u) of the explicit first-order form."""
    f, h = explicit_functions(model)
    x = ca.MX.sym("x", f.size1_in(0))
    u = ca.MX.sym("u", f.size1_in(1))
    p = ca.MX.sym("p", f.size1_in(2))
    xd, y = f(x, u, p), h(x, u, p)
    return ca.Function("lin", [x, u, p], [ca.jacobian(xd, x), ca.jacobian(xd, u), y, ca.jacobian(y, x),
                                          ca.jacobian(y, u)])


def _output_jacobians(model: SymbolicModel, op: OperatingPoint, A: np.ndarray, B: np.ndarray):
    """(y, ∂y/∂x, ∂y/∂u) at the operating point by the chain rule through the acceleration.

    The outputs' own partial derivatives in (q, v, a, u), the acceleration's rows of A and B.  The same
    numbers as differentiating the explicit form (:func:`_output_functions`), without differentiating
    through ``M⁻¹`` symbolically: on the six-axis arm that took 70 s, this takes well under one.
    """
    n = model.n_q
    q, v, a, u, p = (ca.MX.sym(k, *model.residual.size_in(i)) for i, k in enumerate("qvaup"))
    y = model.outputs_function(q, v, a, u, p)
    J = ca.Function("outputs_jac", [q, v, a, u, p],
                    [y, ca.jacobian(y, q), ca.jacobian(y, v), ca.jacobian(y, a), ca.jacobian(y, u)])
    acc = np.zeros(n)          # the operating point is an equilibrium (held joints, static deflection)
    y0, Jq, Jv, Ja, Ju = (np.asarray(m, dtype=float) for m in J(op.q, op.v, acc, op.u, op.p))
    Cy = np.hstack([Jq + Ja @ A[n:, :n], Jv + Ja @ A[n:, n:]])
    return y0.ravel(), Cy, Ju + Ja @ B[n:]


def linear_plant(scene_or_model, *, rate: float = 0.0, angle: float | None = None,
                 parameters: Mapping[str, float] | None = None, outputs: Sequence[str] | None = None,
                 name: str | None = None) -> LinearPlant:
    """Linearise a scene's model about an operating point.

    Parameters
    ----------
    scene_or_model : SymbolicModel, Scene or path
        The model (built from the scene if needed).
    rate : float, optional
        Steady rate of the first joint, rad/s (``flexlink modes --rate``, docs/commands.md).
    angle : float, optional
        Angle of the first joint, rad (default: its initial angle).
    parameters : dict, optional
        Tunable parameters changed from the scene's values, by FMU name (``{"arm.payload.mass": 0.65}``).
    outputs : list of str, optional
        FMU output names to keep (default: all the model's outputs).
    name : str, optional
        python-control system name (default: the scene's model identifier).

    Returns
    -------
    LinearPlant
        ``.sys`` is the continuous-time ``control.StateSpace``.

    See Also
    --------
    linearize : the ``StateSpace`` alone.
    """
    model = _model_of(scene_or_model)
    op = operating_point_at(model, angle=angle, rate=rate, parameters=parameters)
    lin = linearise(model, op)
    n = model.n_q
    Minv = np.linalg.inv(lin.M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ lin.K, -Minv @ lin.C]])
    B = np.vstack([np.zeros((n, lin.B.shape[1])), Minv @ lin.B])
    x0 = np.concatenate([op.q, op.v])
    y0, Cy, Dy = _output_jacobians(model, op, A, B)
    all_outputs = [s.name for s in model.outputs]
    if outputs is None:
        outputs = all_outputs
    unknown = [o for o in outputs if o not in all_outputs]
    if unknown:
        raise FlexlinkError(f"{unknown}: not outputs of the model; its outputs are {all_outputs}")
    rows = [all_outputs.index(o) for o in outputs]
    # inputs the host sets (built-in laws have no FMU input)
    cols = [k for k, s in enumerate(model.inputs) if s.fmu_variable]
    inputs = [model.inputs[k].name for k in cols]
    ident = name or model.scene.model_identifier
    Bu = B[:, cols].reshape(2 * n, len(cols))
    Du = Dy[np.ix_(rows, cols)].reshape(len(rows), len(cols))
    return LinearPlant(A, Bu, Cy[rows], Du, ident, model, op, x0, op.u[cols], y0.ravel()[rows], inputs, list(outputs),
                       lin)


def linearize(scene_or_model, *, rate: float = 0.0, angle: float | None = None,
              parameters: Mapping[str, float] | None = None, outputs: Sequence[str] | None = None) -> ct.StateSpace:
    """The linearised model as a continuous-time ``control.StateSpace`` with named signals.

    Same parameters as :func:`linear_plant`; the operating point is lost (use :func:`linear_plant`
    to keep it).

    Examples
    --------
    >>> sys = linearize("examples/rotating_link.toml", outputs=["hub.theta", "arm.tip.v"])  # doctest: +SKIP
    >>> sys.input_labels, sys.output_labels                                               # doctest: +SKIP
    (['hub_tau'], ['hub_theta', 'arm_tip_v'])
    """
    return linear_plant(scene_or_model, rate=rate, angle=angle, parameters=parameters, outputs=outputs).sys


def fmu_state_space(fmu: str | os.PathLike, *, outputs: Sequence[str] | None = None,
                    start_values: Mapping[str, float] | None = None, name: str | None = None) -> ct.StateSpace:
    """The linearisation of an FMU about its initial state, from the FMU alone.

    The FMU is instantiated for Model Exchange with fmpy and initialised (``start_values`` set before
    initialization: parameters, inputs); then ``fmi2GetDirectionalDerivative`` gives, one known at a
    time, ``A = ∂ẋ/∂x``, ``B = ∂ẋ/∂u``, ``C = ∂y/∂x``, ``D = ∂y/∂u`` with x the continuous states (the
    state derivatives and their states as ``<ModelStructure><Derivatives>`` lists them) and u the inputs.

    Parameters
    ----------
    fmu : path
        An FMI 2.0 FMU with Model Exchange and ``providesDirectionalDerivative="true"``.
    outputs : list of str, optional
        FMU output names to keep (default: all outputs).
    start_values : dict, optional
        Values set before initialization, by FMU name.
    name : str, optional
        python-control system name (default: the model name).

    Returns
    -------
    control.StateSpace
        Named like :func:`linear_plant`'s: flexlink FMUs' states ``q.hub.theta``/``v.hub.theta`` become
        ``hub.theta``/``der(hub.theta)``; inputs and outputs with "." spelled "_".

    See Also
    --------
    linear_plant : the same from the CasADi model.
    """
    import control as ct
    import fmpy

    from flexlink.run.host import FmuHost

    md = fmpy.read_model_description(os.fspath(fmu))
    if md.modelExchange is None or not md.modelExchange.providesDirectionalDerivative:
        raise FlexlinkError(f"{fmu}: needs Model Exchange with directional derivatives (a flexlink FMU has them "
                            "unless its scene sets [fmu] directional_derivatives = false)")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    all_outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    outputs = list(all_outputs if outputs is None else outputs)
    unknown = [o for o in outputs if o not in all_outputs]
    if unknown:
        raise FlexlinkError(f"{unknown}: not outputs of the FMU; its outputs are {all_outputs}")
    inputs = [v.name for v in md.modelVariables if v.causality == "input"]
    ders = [u.variable.name for u in md.derivatives]
    states = [u.variable.derivative.name for u in md.derivatives]
    with FmuHost(fmu, interface="ModelExchange", instance_name="linearize") as host:
        inst = host.instance
        host.initialize(start_values)
        host.call("fmi2NewDiscreteStates", inst.newDiscreteStates)
        host.call("fmi2EnterContinuousTimeMode", inst.enterContinuousTimeMode)
        unknowns = [vr[n] for n in ders + outputs]
        cols = [np.asarray(host.call("fmi2GetDirectionalDerivative", inst.getDirectionalDerivative, unknowns,
                                     [vr[k]], [1.0]), dtype=float)
                for k in states + inputs]
    J = np.array(cols).T.reshape(len(ders) + len(outputs), len(states) + len(inputs))
    nx = len(states)
    A, B, C, D = J[:nx, :nx], J[:nx, nx:], J[nx:, :nx], J[nx:, nx:]

    def state_label(s: str) -> str:
        if s.startswith("q."):
            return s[2:]
        if s.startswith("v."):
            return f"der({s[2:]})"
        return s

    return ct.ss(A, B, C, D, name=name or md.modelName, states=[state_label(s) for s in states],
                 inputs=[signal_name(s) for s in inputs], outputs=[signal_name(s) for s in outputs])
