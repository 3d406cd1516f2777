"""Derivatives for the FMU: the forward derivatives and the structural dependencies.

The forward derivatives behind ``fmi2GetDirectionalDerivative`` come from the generated residual and
outputs themselves by the complex step (``fmu_src/complex_step.c``) wherever they are scalar code of
real-analytic operations (:func:`complex_step_applies`: every model flexlink builds today), else from
CasADi's forward mode (:func:`forward_functions`).  The complex step adds no derivative code to the FMU:
on the six-axis arm, CasADi's forward functions were 34 900 of 61 100 generated operations.  The
structural dependencies of ``<ModelStructure>`` come from CasADi's Jacobian sparsity (docs/fmi.md).

The FMU's continuous state is x = (q, v) (free coordinates and their rates); the derivatives are
ẋ = (v, a) with the acceleration a from ``M(q) a = −r(q, v, 0, u, p)``.  The generated C gets the
partial derivatives it cannot form itself — of the residual and of the outputs together, in a direction
(dq, dv, da, du, dp), and of the outputs in the acceleration alone — and eliminates the acceleration with
the factorised mass matrix (``fmu_src/model.h``: ``model_forward``, ``model_outputs_acceleration_forward``).

Dependencies are structural, from the sparsity of CasADi's Jacobians: a depends on whatever the
residual rows coupled to it through M reads (the structural inverse of M: the transitive closure of
its pattern), an output on what it reads directly and through a.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import casadi as ca
import numpy as np

from flexlink.mechanics.model import SymbolicModel
from flexlink.mechanics.points import DENSE_MAP_PREFIX

__all__ = ["COMPLEX_STEP_OPERATIONS", "Structure", "complex_step_applies", "forward_functions", "structure"]

#: The scalar operations through which the complex step differentiates exactly: real-analytic ones, whose
#: C99 complex counterparts (tgmath.h) extend them (fmu_src/complex_step.c).  Every flexlink model's residual
#: and outputs are made of these alone (the examples: +, -, *, x², 2x, −x, sin, cos).  Comparisons, fabs,
#: fmin/fmax, floor, atan2, conditionals and powers with a branch cut are not, and a model that held one would
#: keep CasADi's forward derivatives.
COMPLEX_STEP_OPERATIONS = frozenset(
    getattr(ca, f"OP_{name}") for name in (
        "CONST", "INPUT", "OUTPUT", "ASSIGN", "ADD", "SUB", "MUL", "DIV", "NEG", "SQ", "TWICE", "INV",
        "SIN", "COS", "TAN", "EXP", "LOG", "SQRT", "SINH", "COSH", "TANH",
    )
)


def _symbols(model: SymbolicModel):
    f = model.residual
    return [ca.MX.sym(n, *f.size_in(i)) for i, n in enumerate("qvaup")]


def forward_functions(model: SymbolicModel) -> tuple[ca.Function, ca.Function]:
    """The forward derivatives that ``fmi2GetDirectionalDerivative`` needs, as two functions.

    ``forward(q, v, a, u, p, dq, dv, da, du, dp) → (dr, dy)``: Jacobian-times-seed of the residual and of
    the outputs in one function.  The two share the kinematics of every body and its tangent, so that
    CSE makes one function about 30 % smaller than the residual's and the outputs' derivatives apart
    (six-axis arm: 31 900 operations against 19 100 + 26 100; issue 15's code size).

    ``outputs_acceleration_forward(q, v, a, u, p, da) → dy``: the outputs' derivative in the acceleration
    alone (about a tenth of ``forward``).  The acceleration's seed is known only after ``forward``'s dr
    has been solved with the mass matrix (``fmu_src/derivatives.c``), so it is added in a second call.
    """
    args = _symbols(model)
    seeds = [ca.MX.sym("d" + n, a.sparsity()) for n, a in zip("qvaup", args, strict=True)]
    x, dx = ca.vertcat(*args), ca.vertcat(*seeds)
    r = model.residual(*args)
    y = model.outputs_function(*args)
    names = [*"qvaup", "dq", "dv", "da", "du", "dp"]
    forward = ca.Function("forward", [*args, *seeds], [ca.jtimes(r, x, dx), ca.jtimes(y, x, dx)], names,
                          ["dr", "dy"])
    a, da = args[2], seeds[2]
    acceleration = ca.Function("outputs_acceleration_forward", [*args, da], [ca.jtimes(y, a, da)],
                               [*"qvaup", "da"], ["dy"])
    return forward, acceleration


def complex_step_applies(*functions: ca.Function) -> bool:
    """Whether the complex step gives the forward derivatives of these generated functions exactly.

    They must be scalar (SX) code, whose every operation is in COMPLEX_STEP_OPERATIONS, or a call of a
    constant linear map or of its forward or reverse derivatives (``dense_map`` in
    flexlink.mechanics.kinematics, and the maps CasADi's AD makes of it, ``fwd1_…``, ``adj1_…``: products by
    the matrix or its transpose, linear and so exact in complex arithmetic): the complex-step unit compiles
    their generated C with ``casadi_real`` complex, and a matrix graph's other helpers or a non-analytic
    operation would not carry the tangent (or not compile).
    """
    for f in functions:
        if not f.is_a("SXFunction"):
            return False
        if not all(re.sub(r"^((fwd|adj)\d+_)*", "", name).startswith(DENSE_MAP_PREFIX) for name in f.get_function()):
            return False
        allowed = COMPLEX_STEP_OPERATIONS | {ca.OP_CALL}
        if any(f.instruction_id(k) not in allowed for k in range(f.n_instructions())):
            return False
    return True


def _pattern(expr: ca.MX, wrt: ca.MX) -> np.ndarray:
    sp = ca.jacobian(expr, wrt).sparsity()
    out = np.zeros((sp.size1(), sp.size2()), dtype=bool)
    rows, cols = sp.get_triplet()
    out[rows, cols] = True
    return out


@dataclass
class Structure:
    """Structural dependencies on z = (q, v, u, p) (model vectors, all their entries).

    ``acceleration[i, k]``: a_i depends on z_k; ``outputs[j, k]``: y_j depends on z_k.
    ``n_q``, ``n_u``, ``n_p`` give the block sizes of z.
    """

    acceleration: np.ndarray
    outputs: np.ndarray
    n_q: int
    n_u: int
    n_p: int

    def block(self, which: str) -> slice:
        """The columns of ``which`` ("q", "v", "u" or "p") in the stacked arguments (q, v, u, p)."""
        n, nu = self.n_q, self.n_u
        return {"q": slice(0, n), "v": slice(n, 2 * n), "u": slice(2 * n, 2 * n + nu),
                "p": slice(2 * n + nu, 2 * n + nu + self.n_p)}[which]


def structure(model: SymbolicModel) -> Structure:
    """The structural dependencies of the acceleration and of the outputs on (q, v, u, p)."""
    q, v, a, u, p = _symbols(model)
    z = ca.vertcat(q, v, u, p)
    r = model.residual(q, v, a, u, p)
    y = model.outputs_function(q, v, a, u, p)
    n = model.n_q
    reach = _pattern(r, a) | np.eye(n, dtype=bool)          # a_i is coupled to r_j through M
    while True:
        nxt = reach | ((reach.astype(np.int64) @ reach.astype(np.int64)) > 0)
        if (nxt == reach).all():
            break
        reach = nxt
    acc = (reach.astype(np.int64) @ _pattern(r, z).astype(np.int64)) > 0
    out = _pattern(y, z) | ((_pattern(y, a).astype(np.int64) @ acc.astype(np.int64)) > 0)
    return Structure(acc, out, n, int(u.numel()), int(p.numel()))
