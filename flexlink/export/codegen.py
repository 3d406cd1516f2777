"""CasADi → C: the model half of an FMU (generated CasADi code, ``config.h``, ``model.c``).

The generic half (``fmu_src/``) sees only the contract of ``fmu_src/model.h``: sizes and flags in
``config.h``; the variable table, the kinematic laws and six functions (residual, Newton matrix,
outputs, the forward derivatives of residual and outputs of ``flexlink.export.derivatives``, and the
validity ratios of :mod:`flexlink.mechanics.outputs`) in ``model.c``,
each a thin call into the CasADi-generated code.  Work memory is passed in by the caller (CasADi never
keeps state), so instances never share anything.

Small models are expanded to scalar expressions (fastest calls); larger ones keep CasADi's matrix
graph, whose code stays compact with constant ``DM`` blocks (docs/mechanics.md).

The fixed C text of ``config.h`` and ``model.c`` lives in ``fmu_src/templates/`` (``string.Template``,
``$name`` placeholders); this module fills in sizes, the GUID, the variable and law tables and the
Newton-matrix function of the model's form.
"""

from __future__ import annotations

import hashlib
import os
import re
import uuid
from dataclasses import dataclass
from pathlib import Path
from string import Template

import casadi as ca
import numpy as np

from flexlink.export.cbuild import OPTIMISE_ENV, BuildError, fmu_src_dir
from flexlink.export.derivatives import complex_step_applies, forward_functions
from flexlink.export.variables import FmuVariable, fmu_variables
from flexlink.mechanics.model import SymbolicModel
from flexlink.scene.solver import SETTINGS

# Scalar (SX) code is fast to run.  Each generated function is its own translation unit (compiled side by
# side), at -O2 up to FULL_OPTIMISATION_MAX_OPERATIONS and -Og above.  -O1 first replaced -O2 there (as fast to
# run for large straight-line code, several times faster to compile: a 270 000-operation pendulum 195 s → 29 s
# of gcc); -Og then replaced -O1: gcc's register allocator ("LRA hard reg assignment", -ftime-report) spent
# 84 % of -O1's time on long straight-line units, and -Og skips the passes that lengthen live ranges.  Measured
# 2026-11-26: the 32-mode first-order link's 25 000-operation residual derivative 16.7 s → 2.1 s of gcc CPU at
# the same speed (4.79 vs 4.68 µs a call; -O0 0.63 s but 25.6 µs); whole builds (gcc CPU, step):
# that link 25.8 s → 7.7 s, 7.82 → 7.80 µs; examples/six_axis_arm.toml 12.6 s → 10.8 s, 6.63 → 6.50 µs.
# Above EXPAND_MAX_COORDINATES the matrix graph is kept (compact code, much slower per step).
FULL_OPTIMISATION_MAX_OPERATIONS = 5_000
EXPAND_MAX_COORDINATES = 160
# [fmu] newton_matrix = "auto" assembles the Newton matrix in C column by column from M(q), the Hessian of T,
# and forward differences of the residual (fmu_src/templates/newton_matrix_differences.c.in) at every size: the
# generated code grows like the residual's, not n times it.  "dense" (one symbolic Jacobian) is kept for a
# scene that asks.  Measured 2026-11-27 (benchmarks/step_floor.py's driver, 5 runs alternating the two builds
# of each scene in one run; the same Newton iterations and factorisations in both): two_link_payload 11.8k ->
# 4.6k operations, 1.71 -> 1.72 us a step; steel_beam_gravity 47.7k -> 20.9k, 5.71 -> 4.68 us; the 3-link
# chain 45.5k -> about 16k, 6.21 -> 6.18 us; rotating_link 6.7k -> 3.3k, 0.79 -> 0.84 us.  A matrix by
# differences costs 1.4-3.3 times the dense one to evaluate, which SS22 refreshes rarely (simplified Newton:
# 236 factorisations in 5000 steps on the chain).  Dense used to be the rule up to 12 coordinates while the
# forward derivatives were generated code the dense Jacobian could share; with the complex step they are none.
# The functions off the Co-Simulation step's iteration -- the mass matrix (at a Newton-matrix refresh, in the
# guards' definiteness check once a link deflects past a quarter of its validity limit, in Model Exchange's
# derivatives) and the forward derivatives of residual and outputs (directional derivatives, the Newton
# matrix's columns where newton_matrix = "columns") -- keep CasADi's matrix graph above this many operations:
# their dense products then compile as loops over constant arrays (at -O2) instead of one line per product.
# Measured 2026-11-26 on the 32-mode link with second-order kinematics (its mass matrix is a sum over 96 points
# of 32x32 outer products, 222k operations as scalar code): generated C 11.6 MB -> 3.0 MB and build 71 s ->
# 14 s in the same session; the step 25 -> 30 us (37 us while these loops were compiled at -Og), because the
# guards evaluate that mass matrix every communication step (docs/performance.md).  Every example's functions
# stay under it (the largest, examples/fast_two_link.toml's residual derivative, 46k): their code is unchanged.
REFRESH_EXPAND_MAX_OPERATIONS = 60_000
# The complex-step twin of a generated unit (the directional derivatives, off the step) above this many
# operations -- a unit compiled at -Og -- is compiled at -O0: complex straight-line code takes gcc about 4 times
# the real unit's time at -Og (the 32-mode second-order link's residual, 36 600 operations: 8.9 s real, 36 s
# complex at -Og, 5.5 s at -O0, measured 2026-11-27), which made that link's build 49 s and the five-link
# chain's 11 s (16 s and 6.3 s with -O0 twins, benchmarks/scaling.py --table-only).  Smaller twins compile at
# -O1: at -O2 they were most of a small model's build, gcc 10 times its real unit's time (rotating_link's twins
# 2.2 s and 1.6 s at -O2, 0.71 s and 0.50 s at -O1, its real residual 0.22 s; a one-link chain's 4.6 s and 2.3 s
# at -O2).  Measured 2026-11-27, the two levels' builds alternated 3 times (load average 3.4-4.3, so the builds
# are long): rotating_link's whole build 12.5 -> 6.6 s, two_link_payload's 8.8 -> 4.5 s, a directional derivative
# 3.4 -> 5.8 us and 4.7 -> 4.9 us (medians of 5 x 2000 calls; python benchmarks/twin_level.py).
COMPLEX_STEP_OPTIMISE_MAX_OPERATIONS = FULL_OPTIMISATION_MAX_OPERATIONS
COMPLEX_STEP_SMALL_LEVEL = "O1"
# The forward derivatives by the complex step wherever it applies (flexlink.export.derivatives); False keeps
# CasADi's forward functions for every model, as a model with a non-analytic operation does (the tests build
# both forms and compare them).
COMPLEX_STEP = True
# FLEXLINK_OPTIMISE=O0|Og|O1|O2 imposes one level on the CasADi code instead (the generic C stays at -O2): the
# test suite builds dozens of FMUs and runs each briefly, so it compiles them at O0 (docs/tests.md).
# OPTIMISE_ENV is that variable's name (flexlink.export.cbuild; part of the FMU cache key).
OPTIMISE_LEVELS = ("O0", "Og", "O1", "O2")


def generated_code_optimisation(operations: int, matrix_graph: bool = False) -> str:
    """The gcc optimisation level of one generated function of ``operations`` operations.

    $FLEXLINK_OPTIMISE if set, else O2 or, for scalar code above FULL_OPTIMISATION_MAX_OPERATIONS, Og (a matrix
    graph's loops are short to compile and need -O2's loop optimisations).
    """
    level = os.environ.get(OPTIMISE_ENV, "").strip()
    if level:
        if level not in OPTIMISE_LEVELS:
            raise BuildError(f"{OPTIMISE_ENV}={level!r}: expected one of {', '.join(OPTIMISE_LEVELS)}")
        return level
    return "Og" if operations > FULL_OPTIMISATION_MAX_OPERATIONS and not matrix_graph else "O2"


#: gcc's register allocator for a unit at -Og: IRA's priority colouring instead of Chaitin-Briggs.  On a large
#: straight-line unit LRA's hard-register assignment was most of the compile (62 % of the 32-mode link's
#: residual, -ftime-report); with it the unit compiles in half the time (4.6 -> 2.1 s) and runs as fast (the
#: link's step 6.34 -> 6.30 us, planar_chain_5's 8.85 -> 8.83 us, medians of 3 alternated step_floor runs,
#: 2026-11-29).  The units' AVX twins (fmu_src/avx.h) compile the same code a second time: this pays for them.
#: Register allocation does not change what is computed: the same bits.
LARGE_UNIT_ALLOCATOR = "-fira-algorithm=priority"


def _optimise_pragma(level: str) -> str:
    """unit.c.in's $optimise: the unit's level where it is not the build's own -O2.

    At -Og with LARGE_UNIT_ALLOCATOR, from gcc 12 (the version it was measured on; the options of
    ``#pragma GCC optimize`` accumulate).
    """
    if level == "O2":
        return ""
    pragma = f'#pragma GCC optimize ("{level}")  /* large straight-line code */\n'
    if level == "Og":
        pragma += (f'#if __GNUC__ >= 12   /* its register allocator (codegen.py) */\n'
                   f'#pragma GCC optimize ("{LARGE_UNIT_ALLOCATOR}")\n#endif\n')
    return pragma


@dataclass
class GeneratedModel:
    """The model half of an FMU's C sources, as written into its build directory."""

    directory: Path
    sources: list[Path]            # the model half's C files to compile: model.c and one unit per function
    generated: list[Path]          # every generated file
    variables: list[FmuVariable]
    guid: str
    identifier: str
    matrix_graph: tuple[str, ...]  # the functions generated from CasADi's matrix graph, not as scalar code
    operations: int                # elementary operations in the generated functions


def _c(x: float) -> str:
    if np.isinf(x):
        return "1e300" if x > 0 else "-1e300"
    return repr(float(x))


def _c_string(text: str) -> str:
    """A C string literal of ``text`` (names come from the scene: quotes and backslashes escaped)."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _feedthrough(model: SymbolicModel) -> dict[int, tuple[int, ...]]:
    """Output i depends directly on input j if it reads u_j, or reads the acceleration.

    The acceleration depends on every input that the residual reads.
    """
    f = model.outputs_function
    n_u = f.size1_in(3)
    if n_u == 0:
        return {}
    r = model.residual
    q, v, a, u, p = (ca.MX.sym(n, *f.size_in(i)) for i, n in enumerate("qvaup"))
    y = f(q, v, a, u, p)
    jy_u = ca.jacobian(y, u).sparsity()
    jy_a = ca.jacobian(y, a).sparsity()
    jr_u = ca.jacobian(r(q, v, a, u, p), u).sparsity()
    inputs_in_residual = {j for _, j in zip(*jr_u.get_triplet(), strict=True)}
    reads_u: dict[int, set[int]] = {}
    for i, j in zip(*jy_u.get_triplet(), strict=True):
        reads_u.setdefault(i, set()).add(j)
    for i in set(jy_a.get_triplet()[0]):
        reads_u.setdefault(i, set()).update(inputs_in_residual)
    fmu_inputs = {i for i, s in enumerate(model.inputs) if s.fmu_variable}
    return {i: tuple(sorted(js & fmu_inputs)) for i, js in reads_u.items() if js & fmu_inputs}


def _template(name: str) -> Template:
    """A C template of ``fmu_src/templates/`` (package data, so installed packages have them too)."""
    return Template((fmu_src_dir() / "templates" / name).read_text())


def dense_newton_matrix(model: SymbolicModel) -> bool:
    """Whether the Newton matrix is generated as one dense symbolic Jacobian (else assembled by columns).

    Only where the scene asks for ``newton_matrix = "dense"``: "auto" assembles it by columns at no code
    (a three-link chain's generated step: 46k operations with the dense matrix, 16k without, the same
    iterations and cost per step; the figures in the comment on [fmu] newton_matrix = "auto" above).
    """
    form = model.scene.fmu.newton_matrix
    if form == "dense" and model.n_q > EXPAND_MAX_COORDINATES:
        raise BuildError(f'[fmu] newton_matrix = "dense": at most {EXPAND_MAX_COORDINATES} coordinates (this '
                         f'model has {model.n_q}; its dense Jacobian would be n times the residual\'s code); use '
                         '"auto" or "columns"')
    return form == "dense"


def newton_matrix_template(model: SymbolicModel) -> str:
    """The C template of ``model_newton_matrix``.

    A dense symbolic Jacobian (``"dense"``); or column by column, from the mass matrix and forward
    differences of the residual (``"auto"``: a column costs one residual, the iteration matrix's √ε error is
    far below what simplified Newton tolerates), or, where the scene asks for ``"columns"`` and the
    directional derivatives are compiled, from exact directional derivatives.
    """
    if dense_newton_matrix(model):
        return "newton_matrix.c.in"
    exact = model.scene.fmu.newton_matrix == "columns" and model.scene.fmu.directional_derivatives
    return "newton_matrix_columns.c.in" if exact else "newton_matrix_differences.c.in"


@dataclass(frozen=True)
class _Generated:
    """One function as it is generated: its scalar or matrix form, and its scalar operation count."""

    function: ca.Function
    operations: int

    @property
    def matrix_graph(self) -> bool:
        """Whether it is generated from CasADi's matrix graph (MX) rather than as scalar code (SX)."""
        return not self.function.is_a("SXFunction")


def _prepare(f: ca.Function, ident: str, expanded: bool, off_step: bool = False) -> _Generated:
    """A model function named for the model, as scalar code with CSE, or as its matrix graph.

    Scalar (SX) code with common subexpressions merged: 15-45 % fewer operations on the examples, the same
    values (CasADi's cse, issue 22).  The matrix graph is kept when the model is past EXPAND_MAX_COORDINATES
    (``expanded`` false), or for an ``off_step`` function past REFRESH_EXPAND_MAX_OPERATIONS.
    """
    name = f"{ident}_{f.name()}"    # public symbols carry the model identifier
    if not all(f.sparsity_out(i).is_dense() for i in range(f.n_out())):
        # model.c hands the generated code plain arrays: a sparse output would leave entries unwritten
        raise BuildError(f"{f.name()}: a generated function's outputs must be dense")
    g = f.expand()
    if expanded:
        sx_args = g.sx_in()
        scalar = ca.Function(name, sx_args, g.call(sx_args), f.name_in(), f.name_out(), {"cse": True})
        operations = int(scalar.n_instructions())
        if not (off_step and operations > REFRESH_EXPAND_MAX_OPERATIONS):
            return _Generated(scalar, operations)
    else:
        operations = int(g.n_instructions())    # counted on the scalar expansion, which is not generated
    mx_args = f.mx_in()
    return _Generated(ca.Function(name, mx_args, f.call(mx_args), f.name_in(), f.name_out()), operations)


@dataclass(frozen=True)
class _Plan:
    """What a build generates: the CasADi functions, and whether the forward derivatives are complex steps."""

    functions: list[_Generated]
    complex_step: bool        # the forward derivatives by the complex step on residual and outputs
    mass_by_differences: bool = False   # M from differences of the residual, not generated (mass_by_differences)

    @property
    def residual(self) -> _Generated:
        return self.functions[0]

    @property
    def outputs(self) -> _Generated:
        return self.functions[1]

    @property
    def matrix(self) -> _Generated | None:
        """The generated mass matrix or dense Newton matrix (None: M by differences)."""
        return None if self.mass_by_differences else self.functions[2]


def _casadi_functions(model: SymbolicModel, ident: str, expanded: bool) -> _Plan:
    """The CasADi functions to generate, named for the model, with their operation counts.

    Residual, outputs, the validity ratios, and either the dense Newton matrix or the mass matrix (the
    columns of the Newton matrix come from it and differences of the residual, or the forward derivative:
    :func:`newton_matrix_template`); where the scene asks for the forward derivatives ([fmu]
    directional_derivatives), they are the complex step on the residual and outputs when it applies
    (:func:`flexlink.export.derivatives.complex_step_applies`: nothing more to generate), else CasADi's
    forward functions.  A generated model holds only what its scene asks for.
    """
    residual = _prepare(model.residual, ident, expanded)
    outputs = _prepare(model.outputs_function, ident, expanded)
    if dense_newton_matrix(model):
        newton = _prepare(model.newton_matrix_function(), ident, expanded)
    else:
        newton = _prepare(model.mass_matrix_function(), ident, expanded, off_step=True)
    if model.validity is None:
        raise BuildError("the model has no validity function (flexlink.mechanics.model.build_model makes one)")
    by_differences = mass_by_differences(model, newton)
    functions = [residual, outputs] + ([] if by_differences else [newton])
    derivatives = model.scene.fmu.directional_derivatives
    complex_step = derivatives and COMPLEX_STEP and complex_step_applies(residual.function, outputs.function)
    if derivatives and not complex_step:
        functions += [_prepare(f, ident, expanded, off_step=True) for f in forward_functions(model)]
    functions.append(_prepare(model.validity, ident, expanded))
    if model.parameter_check is not None:
        functions.append(_prepare(model.parameter_check, ident, expanded))
    return _Plan(functions, bool(complex_step), by_differences)


def mass_by_differences(model: SymbolicModel, mass_matrix: _Generated) -> bool:
    """Whether model_newton_matrix takes M from residuals instead of a generated mass matrix.

    Where ``"auto"`` would generate it as a matrix graph (past REFRESH_EXPAND_MAX_OPERATIONS as scalar code):
    the 32-mode second-order link's, 287 000 operations as scalar code, 0.37 MB of C in its matrix form and
    a quarter of the FMU's code, for a matrix that 33 residuals give exactly but for rounding (the residual
    is affine in the accelerations; M is ∂r/∂a at v = a = 0, ``SymbolicModel.mass_matrix_function``).  The
    Newton matrix's columns carry their M part in the residuals of their differences in q and v
    (``newton_matrix_differences.c.in``), so that a refresh costs N_Q + 1 residuals; M alone (the consistent
    acceleration's refresh, the guards' definiteness check) costs N_Q + 1 residuals, about the generated
    matrix graph's cost.

    Not for a chain's M, though its scalar code grows like the pairs of bodies and outgrows the residual
    from about five bodies: measured 2026-11-27 (``benchmarks/host_step.py``, a host stepping at the
    solver's step), M from residuals made the six-axis arm's communication step 17.2 → 36.0 µs and
    ``fast_two_link``'s 28.7 → 42.4 µs, where the consistent acceleration buys a new M nearly every step.
    """
    return (newton_matrix_template(model) == "newton_matrix_differences.c.in" and mass_matrix.matrix_graph
            and model.n_q <= EXPAND_MAX_COORDINATES)


def generated_functions(model: SymbolicModel) -> dict[str, tuple[ca.Function, int]]:
    """The functions a build generates for ``model``, as ``flexlink explain`` reports them.

    By name (without the model identifier), each with its count of elementary operations as compiled
    (scalar, after CSE).
    """
    ident = model.scene.model_identifier
    expanded = model.n_q <= EXPAND_MAX_COORDINATES
    return {g.function.name().removeprefix(f"{ident}_"): (g.function, g.operations)
            for g in _casadi_functions(model, ident, expanded).functions}



def _guid(casadi_c: str, variables: list[FmuVariable], model: SymbolicModel) -> str:
    """A name-based UUID of the generated code, the variables and the kinematic laws."""
    digest = hashlib.sha256()
    digest.update(casadi_c.encode())
    digest.update(repr([(v.name, v.kind, v.index, v.start, v.causality, v.variability) for v in variables]).encode())
    digest.update(repr([(law.joint, law.u_offset, law.trajectory) for law in model.laws]).encode())
    return "{" + str(uuid.UUID(bytes=digest.digest()[:16], version=5)) + "}"


def consistent_refresh_cost(n_q: int, residual_operations: int, matrix_operations: int) -> float:
    """What a new mass matrix and its LU cost, in residuals: CONSISTENT_REFRESH_COST (fmu_src/consistent.c).

    The generated function that gives M (the mass matrix, or the dense Newton matrix where the scene asks for
    it) plus the LU's ⅔ n³ operations, over the residual's operations.  The consistent acceleration iterates
    on a kept factorised M only where this buys more than a few residuals.
    """
    return (matrix_operations + 2.0 * n_q ** 3 / 3.0) / max(residual_operations, 1)


def mass_update(model: SymbolicModel, plan: _Plan) -> bool:
    """Whether SS22 may update the mass part of a kept iteration matrix alone (MODEL_MASS_UPDATE, fmu_src/ss22.h).

    J = M + Θ₁Δt C + Θ₂Δt²/2 K; the update takes a new M(q) and keeps the velocity and position parts of the
    matrix's last full evaluation.  It pays where M comes from a generated mass matrix and the rest from N_Q
    columns, differences of the residual (``newton_matrix_differences.c.in``) or its forward derivatives
    (``newton_matrix_columns.c.in``): M and its LU cost about a residual on the chains, a full evaluation N_Q
    residuals or derivatives more.  Not where M itself comes from residuals (``mass_by_differences``), the
    dense Newton matrix is generated whole, or the matrix never changes.
    """
    return (not model.linear_in_state and not model.jacobian_constant and not plan.mass_by_differences
            and newton_matrix_template(model) in ("newton_matrix_differences.c.in", "newton_matrix_columns.c.in"))


def _config_h(model: SymbolicModel, guid: str, variables: list[FmuVariable], sz: dict[str, int],
              complex_step: bool, refresh_cost: float, update: bool) -> str:
    """``config.h``: sizes, GUID and flags of the model."""
    return _template("config.h.in").substitute(
        scene=model.scene.name, identifier=model.scene.model_identifier, guid=guid, n_q=model.n_q,
        n_u=len(model.inputs), n_p=len(model.parameters), n_y=len(model.outputs), n_laws=len(model.laws),
        n_static=len(model.static_coordinates), n_vars=len(variables), n_validity=len(model.validity_names),
        n_parameter_checks=len(model.parameter_check_names),
        linear_in_state=int(model.linear_in_state), jacobian_constant=int(model.jacobian_constant),
        directional_derivatives=int(model.scene.fmu.directional_derivatives), complex_step=int(complex_step),
        consistent_refresh_cost=f"{refresh_cost:.3g}", mass_update=int(update),
        **{f"sz_{k}": v for k, v in sz.items()},
    )


def _variable_rows(variables: list[FmuVariable]) -> str:
    """The rows of ``MODEL_VARS``: name, kind, index, start, min, max, min_exclusive, tunable, integer."""
    rows = []
    for v in variables:
        index = SETTINGS[v.index].c_name if v.kind == "VAR_SOLVER" else str(v.index)
        rows.append(f'    {{"{v.name}", {v.kind}, {index}, {_c(v.start)}, {_c(v.min)}, {_c(v.max)}, '
                    f"{int(v.min_exclusive)}, {int(v.variability == 'tunable' or v.causality == 'input')}, "
                    f"{int(v.type == 'Integer')}}},")
    return "\n".join(rows)


def _law_tables(model: SymbolicModel) -> str:
    """``MODEL_LAWS`` with the segment and coefficient arrays of the built-in laws ("" without laws)."""
    if not model.laws:
        return ""
    arrays, law_rows = [], []
    for k, law in enumerate(model.laws):
        if law.trajectory is None:
            law_rows.append(f"    {{{law.u_offset}, 0, 0, NULL}},")
            continue
        seg_rows = []
        for j, seg in enumerate(law.trajectory.segments):
            poly = ", ".join(_c(c) for c in seg.poly) or "0.0"
            cos = ", ".join(_c(x) for trip in seg.cos for x in trip) or "0.0"
            arrays.append(f"static const double law{k}_poly{j}[] = {{{poly}}};")
            arrays.append(f"static const double law{k}_cos{j}[] = {{{cos}}};")
            seg_rows.append(f"    {{{_c(seg.until)}, {len(seg.poly)}, law{k}_poly{j}, {len(seg.cos)}, "
                            f"law{k}_cos{j}}},")
        arrays.append(f"static const LawSegment law{k}_segments[] = {{\n" + "\n".join(seg_rows) + "\n};")
        law_rows.append(f"    {{{law.u_offset}, 1, {len(law.trajectory.segments)}, law{k}_segments}},")
    return "\n".join(arrays) + "\nconst KinematicLaw MODEL_LAWS[N_LAWS] = {\n" + "\n".join(law_rows) + "\n};\n"


def _model_c(model: SymbolicModel, variables: list[FmuVariable], units: list[str], plan: _Plan) -> str:
    """``model.c``: the variable table, the kinematic laws and the functions of ``fmu_src/model.h``."""
    complex_step = plan.complex_step
    # model_newton_matrix's M (newton_matrix_differences.c.in): from the residual (mass_by_differences), or
    # the generated mass matrix
    mass = _template("mass_matrix_differences.c.in" if plan.mass_by_differences else "mass_matrix_generated.c.in")
    ident = model.scene.model_identifier
    static = ""
    if model.static_coordinates:
        static = ("const int MODEL_STATIC_COORDS[N_STATIC] = {"
                  + ", ".join(str(i) for i in model.static_coordinates) + "};\n")
    newton = _template(newton_matrix_template(model))
    return _template("model.c.in").substitute(
        scene=model.scene.name, identifier=ident, casadi_units=", ".join(f"{u}.c" for u in units),
        casadi_includes="\n".join(f'#include "{u}.h"' for u in units) + "\n" + _avx_dispatch(avx_units(plan)),
        variables=_variable_rows(variables), nominal_q=", ".join(_c(x) for x in model.nominal_q),
        static_coordinates=static, laws=_law_tables(model),
        output_uses_acceleration=", ".join(str(int(x)) for x in outputs_using_acceleration(model)) or "0",
        newton_matrix=newton.substitute(identifier=ident, mass_matrix=mass.substitute(identifier=ident).rstrip("\n"))
        .rstrip("\n"),
        validity_names="\n".join(f"    {_c_string(name)}," for name in model.validity_names) or '    ""',
        parameter_check_names="\n".join(f"    {_c_string(n)}," for n in model.parameter_check_names) or '    ""',
        parameter_check_body=_parameter_check_body(model), input_forces_body=_input_forces_body(model),
        forward_body=_forward_body(model, "forward", ("q", "v", "a", "u", "p", "dq", "dv", "da", "du", "dp"),
                                   ("dr", "dy"), complex_step),
        outputs_acceleration_forward_body=_forward_body(model, "outputs_acceleration_forward",
                                                        ("q", "v", "a", "u", "p", "da"), ("dy",), complex_step),
    )


def _forward_body(model: SymbolicModel, function: str, arguments: tuple[str, ...], results: tuple[str, ...],
                  complex_step: bool) -> str:
    """The body of model_forward or model_outputs_acceleration_forward.

    A call of the generated function, or of the complex step (fmu_src/complex_step.c) with the seeds the
    function takes, or a failure where the scene left the derivatives out (derivatives.c refuses before,
    from MODEL_DIRECTIONAL_DERIVATIVES).
    """
    if not model.scene.fmu.directional_derivatives:
        return "    " + " ".join(f"(void){x};" for x in (*arguments, *results, "work")) + "\n    return 1;"
    if complex_step:
        seeds = ", ".join(f"d{x}" if f"d{x}" in arguments else "NULL" for x in "qvaup")
        out = ", ".join(x if x in results else "NULL" for x in ("dr", "dy"))
        return f"    (void)work;\n    return model_complex_forward(q, v, a, u, p, {seeds}, {out});"
    ident = model.scene.model_identifier
    lines = [f"    work->arg[{i}] = {x};" for i, x in enumerate(arguments)]
    lines += [f"    work->res[{i}] = {x};" for i, x in enumerate(results)]
    lines.append(f"    return {ident}_{function}(work->arg, work->res, work->iw, work->w, 0);")
    return "\n".join(lines)


def outputs_using_acceleration(model: SymbolicModel) -> list[bool]:
    """Which outputs depend on the acceleration (structurally: the Jacobian's sparsity, which is conservative).

    MODEL_OUTPUT_USES_ACCELERATION: the FMU evaluates the others without the consistent acceleration, the
    mass matrix and its LU a host's read of positions, rates, deflections or energies would otherwise cost.
    """
    rows = model.outputs_function.sparsity_jac(2, 0).get_triplet()[0]
    uses = [False] * len(model.outputs)
    for i in rows:
        uses[i] = True
    return uses


def _input_forces_body(model: SymbolicModel) -> str:
    """model_input_forces' body: Q = −B u, one sum per coordinate over B's non-zero entries.

    Where B = ∂r/∂u is a constant (a joint torque: −1 on its joint); ``return 0`` where not (the energy guard
    then takes residual differences, fmu_src/guards.c).
    """
    B = model.input_matrix
    if B is None or B.size == 0:
        return "    (void)u;\n    (void)force;\n    return 0;"
    lines = []
    for i, row in enumerate(B):
        terms = [f"{'' if b == -1.0 else '-' if b == 1.0 else _c(-b) + ' * '}u[{k}]" for k, b in enumerate(row)
                 if b != 0.0]
        lines.append(f"    force[{i}] = {' + '.join(terms) if terms else '0.0'};")
    return "\n".join([*lines, "    return 1;"])


def _parameter_check_body(model: SymbolicModel) -> str:
    """The body of model_parameter_check: a call of the generated function, or nothing to check."""
    if model.parameter_check is None:
        return "    (void)p; (void)h; (void)work;\n    return 0;"
    ident = model.scene.model_identifier
    return ("    work->arg[0] = p;\n    work->res[0] = h;\n"
            f"    return {ident}_parameter_check(work->arg, work->res, work->iw, work->w, 0);")


def _write_unit(generated: _Generated, model: SymbolicModel, directory: Path) -> tuple[Path, int]:
    """One generated function as its own C file (and header); returns the file and its operation count.

    CasADi's code behind unit.c.in's preamble, at the optimisation level its size calls for.
    """
    f, operations = generated.function, generated.operations   # counted on the scalar form whatever is written
    name = f.name()
    cg = ca.CodeGenerator(f"{name}.c", {"with_header": True, "prefix": f"{name}_", "casadi_real": "double"})
    cg.add(f)
    cg.generate(str(directory) + "/")
    path = directory / f"{name}.c"
    level = generated_code_optimisation(operations, generated.matrix_graph)
    preamble = _template("unit.c.in").substitute(unit=name, scene=model.scene.name, optimise=_optimise_pragma(level))
    code = path.read_text()
    path.write_text(preamble + _inline_helpers(_dense_product(code, level)))
    return path, operations


#: CasADi's scalar helpers (its codegen's casadi_sq, casadi_fabs), defined in each unit
_SCALAR_HELPER = re.compile(r"^casadi_real (casadi_(?:sq|fabs))\(casadi_real x\) \{", re.M)


def _inline_helpers(code: str) -> str:
    """CasADi's scalar helpers inlined at any level (FLEXLINK_SCALAR_HELPER, unit.c.in).

    At -Og gcc inlines no function that is not always_inline, and a call in straight-line code costs more than
    its jump: every floating-point temporary live across it is spilled and reloaded, SSE registers being
    caller-saved.  The 32-mode link's residual called casadi_sq 193 times; inlined, its code held 5 385 stack
    accesses instead of 6 618, and it ran in 2.34 µs instead of 2.58 (the step 4.75 → 4.46 µs, step-floor
    driver, 2026-11-29).  The same x*x: the same bits.
    """
    return _SCALAR_HELPER.sub(r"FLEXLINK_SCALAR_HELPER casadi_real \1(casadi_real x) {", code)


#: CasADi's dense product loop in generated code (the constant maps that stay calls, points.dense_map)
_DENSE_LOOP = "\nvoid casadi_mtimes_dense("
_PUSH_O2 = ('#if defined(__GNUC__) && !defined(__clang__)\n#pragma GCC push_options\n'
            '#pragma GCC optimize ("O2")\n#endif\n')
_POP = "#if defined(__GNUC__) && !defined(__clang__)\n#pragma GCC pop_options\n#endif\n"


def _dense_product(code: str, level: str) -> str:
    """CasADi's dense product loop replaced by dense_product.c.in, at -O2 in a unit of a lower level.

    The replacement gives the same values to the bit (the same sums in the same order,
    tests/test_dense_product.py against CasADi's own loop) with the partial sums in registers: CasADi's loop
    adds each row in memory, a chain of dependent loads and stores whose speed also depended on where the
    loop landed (the 32-mode link's residual 4.3 µs in one build, 5.2 µs in another with the same residual
    code).  Measured 2026-11-27 on that link (step-floor driver, medians of 3 runs, three placements each):
    the step 11.9-13.5 µs → 9.6-9.7 µs, the residual 4.4-5.3 → 3.5-3.6 µs.  A large unit's straight-line
    code compiles at -Og, as fast to run and several times faster to compile; a loop is not (at -Og that
    link's step went 11 → 23 µs).  ``push_options`` keeps the rest of the unit at its level.
    """
    start = code.find(_DENSE_LOOP)
    if start < 0:
        return code
    end = code.index("\n}\n", start) + 3
    ours = (fmu_src_dir() / "templates" / "dense_product.c.in").read_text()
    if level != "O2" and not os.environ.get(OPTIMISE_ENV, "").strip():     # an imposed level holds everywhere
        ours = _PUSH_O2 + ours + _POP
    return code[:start + 1] + ours + code[end:]


def _write_complex_unit(generated: _Generated, model: SymbolicModel, directory: Path, wrapper: str) -> Path:
    """The complex-arithmetic twin of one generated unit (complex_unit.c.in): it includes the real unit."""
    f = generated.function
    unit = f.name()
    path = directory / f"{unit}_complex.c"
    optimise = ""
    if not os.environ.get(OPTIMISE_ENV, "").strip():
        level = "O0" if generated.operations > COMPLEX_STEP_OPTIMISE_MAX_OPERATIONS else COMPLEX_STEP_SMALL_LEVEL
        optimise = (f'#if defined(__GNUC__) && !defined(__clang__)   /* a complex unit: -{level} (codegen.py) */\n'
                    f'#pragma GCC optimize ("{level}")\n#define FLEXLINK_UNIT_LEVEL_SET 1\n#endif\n')
    path.write_text(_template("complex_unit.c.in").substitute(
        unit=unit, scene=model.scene.name, wrapper=wrapper, indent=" " * (4 + len(wrapper)), optimise=optimise,
        sz_arg=max(int(f.sz_arg()), 5), sz_res=max(int(f.sz_res()), 1), sz_iw=max(int(f.sz_iw()), 1),
        sz_w=max(int(f.sz_w()), 1)))
    return path


def avx_units(plan: _Plan) -> list[str]:
    """The units of the Newton iteration, which get an AVX twin (fmu_src/avx.h).

    The residual, and the mass matrix or dense Newton matrix where one is generated; not the outputs, which
    run once a communication step.
    """
    return [g.function.name() for g in (plan.residual, plan.matrix) if g is not None]


def _write_avx_unit(unit: str, model: SymbolicModel, directory: Path) -> Path:
    """The AVX twin of one generated unit (avx_unit.c.in): it includes the unit, at the unit's own level."""
    path = directory / f"{unit}_avx.c"
    path.write_text(_template("avx_unit.c.in").substitute(unit=unit, scene=model.scene.name))
    return path


def _avx_dispatch(units: list[str]) -> str:
    """model.c's calls of the AVX twins: each unit's name a macro that calls its twin where the processor has AVX.

    A function-like macro does not expand its own name again, so the macro's body calls the unit itself; the
    templates' calls stay as they are (fmu_src/avx.h).
    """
    lines = ['#include "avx.h"', "#if FLEXLINK_AVX   /* the Newton iteration's units in AVX (avx.h) */",
             f"#define MODEL_AVX_UNITS {len(units)}"]
    for u in units:
        lines += [f"int {u}_avx(const casadi_real **arg, casadi_real **res, casadi_int *iw, casadi_real *w, int mem);",
                  f"#define {u}(arg, res, iw, w, mem) \\",
                  f"    (flexlink_avx_processor() ? {u}_avx(arg, res, iw, w, mem) : {u}(arg, res, iw, w, mem))"]
    return "\n".join([*lines, "#else", "#define MODEL_AVX_UNITS 0", "#endif"])


def generate(model: SymbolicModel, directory: Path) -> GeneratedModel:
    """Write the model half of the FMU's C sources into ``directory``.

    model.c, and one unit per generated function (compiled side by side,
    :func:`flexlink.export.cbuild.compile_shared_library`), with the AVX twins of the Newton iteration's
    units (:func:`avx_units`) and the complex-step twins of the residual's and the outputs' units where the
    forward derivatives are taken so.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    ident = model.scene.model_identifier
    expanded = model.n_q <= EXPAND_MAX_COORDINATES
    plan = _casadi_functions(model, ident, expanded)
    prepared = plan.functions
    functions = [g.function for g in prepared]
    units = [_write_unit(g, model, directory) for g in prepared]
    operations = sum(ops for _, ops in units)
    variables = fmu_variables(model, _feedthrough(model))
    sz = {k: max(int(getattr(f, f"sz_{k}")()) for f in functions) for k in ("arg", "res", "iw", "w")}
    guid = _guid("".join(path.read_text() for path, _ in units), variables, model)
    matrix_operations = (model.n_q + 1) * plan.residual.operations if plan.matrix is None else \
        plan.matrix.operations
    refresh = consistent_refresh_cost(model.n_q, plan.residual.operations, matrix_operations)
    (directory / "config.h").write_text(_config_h(model, guid, variables, sz, plan.complex_step, refresh,
                                                  mass_update(model, plan)))
    names = [f.name() for f in functions]
    (directory / "model.c").write_text(_model_c(model, variables, names, plan))
    twins = [_write_avx_unit(u, model, directory) for u in avx_units(plan)]
    if plan.complex_step:
        twins += [_write_complex_unit(plan.residual, model, directory, "model_residual_complex"),
                  _write_complex_unit(plan.outputs, model, directory, "model_outputs_complex")]
    sources = [directory / "model.c", *(path for path, _ in units), *twins]
    generated = [*sources, *(directory / f"{n}.h" for n in names)]
    matrix_graph = tuple(g.function.name().removeprefix(f"{ident}_") for g in prepared if g.matrix_graph)
    return GeneratedModel(directory, sources, generated, variables, guid, ident, matrix_graph, operations)
