"""CasADi → C: the model half of an FMU (generated CasADi code, ``config.h``, ``model.c``).

The generic half (``fmu_src/``) sees only the contract of ``fmu_src/model.h``: sizes and flags in
``config.h``; the variable table, the kinematic laws and five functions (residual, Newton matrix,
outputs, and the forward derivatives of residual and outputs of ``flexlink.export.derivatives``) in ``model.c``,
each a thin call into the CasADi-generated code.  Work memory is passed in by the caller (CasADi never
keeps state), so instances never share anything.

Small models are expanded to scalar expressions (fastest calls); larger ones keep CasADi's matrix
graph, whose code stays compact with constant ``DM`` blocks (DESIGN.md §2).
"""

from __future__ import annotations

import hashlib
import uuid
from dataclasses import dataclass
from pathlib import Path
from textwrap import indent

import casadi as ca
import numpy as np

from flexlink.export.derivatives import forward_functions
from flexlink.export.variables import FmuVariable, fmu_variables
from flexlink.mechanics.model import SymbolicModel

# Scalar (SX) code is fast to run; its size grows like n² for a dense Newton matrix.  Up to
# FULL_OPTIMISATION_MAX coordinates it is compiled at -O2; above, at -O1 (8 s → 2 s of gcc for 81
# coordinates, no slower to run); above EXPAND_MAX_COORDINATES the matrix graph is kept and the Newton
# matrix assembled in C from a forward derivative (compact, but much slower per step).
FULL_OPTIMISATION_MAX = 24
EXPAND_MAX_COORDINATES = 160


@dataclass
class GeneratedModel:
    directory: Path
    sources: list[Path]            # the model half's C files to compile
    generated: list[Path]          # every generated file
    variables: list[FmuVariable]
    guid: str
    identifier: str
    expanded: bool
    operations: int                # elementary operations in the generated functions


def _c(x: float) -> str:
    if np.isinf(x):
        return "1e300" if x > 0 else "-1e300"
    return repr(float(x))


def _feedthrough(model: SymbolicModel) -> dict[int, tuple[int, ...]]:
    """Output i depends directly on input j if it reads u_j, or reads the acceleration (which
    depends on every input that the residual reads)."""
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


def generate(model: SymbolicModel, directory: Path) -> GeneratedModel:
    """Write the model half of the FMU's C sources into ``directory``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    ident = model.scene.model_identifier
    expanded = model.n_q <= EXPAND_MAX_COORDINATES

    def prepare(f: ca.Function) -> ca.Function:
        name = f"{ident}_{f.name()}"    # public symbols carry the model identifier
        if expanded:
            return f.expand(name)
        args = f.mx_in()
        return ca.Function(name, args, f.call(args), f.name_in(), f.name_out())

    residual = prepare(model.residual)
    outputs = prepare(model.outputs_function)
    if expanded:
        newton = prepare(model.newton_matrix_function())
    else:
        # a full Jacobian of a large matrix graph generates enormous code: the C side builds the Newton
        # matrix column by column from one forward directional derivative of the residual instead
        newton = prepare(model.residual_forward_function())
    residual_fwd, outputs_fwd = (prepare(f) for f in forward_functions(model))
    functions = [residual, newton, outputs, residual_fwd, outputs_fwd]
    cname = f"{ident}_casadi"
    cg = ca.CodeGenerator(f"{cname}.c", {"with_header": True, "prefix": f"{ident}_", "casadi_real": "double"})
    for f in functions:
        cg.add(f)
    cg.generate(str(directory) + "/")
    # elementary operations, counted on the scalar expansion whatever the generated form
    operations = sum(int((f if expanded else f.expand()).n_instructions()) for f in functions)

    feed = _feedthrough(model)
    variables = fmu_variables(model, feed)
    sz = {k: max(int(getattr(f, f"sz_{k}")()) for f in functions) for k in ("arg", "res", "iw", "w")}

    casadi_c = (directory / f"{cname}.c").read_text()
    digest = hashlib.sha256()
    digest.update(casadi_c.encode())
    digest.update(repr([(v.name, v.kind, v.index, v.start, v.causality, v.variability) for v in variables]).encode())
    digest.update(repr([(law.joint, law.u_offset, law.trajectory) for law in model.laws]).encode())
    guid = "{" + str(uuid.UUID(bytes=digest.digest()[:16], version=5)) + "}"

    n_laws, n_static = len(model.laws), len(model.static_coordinates)
    config = f"""/* config.h -- generated by flexlink.export.codegen for scene "{model.scene.name}". Do not edit. */
#ifndef CONFIG_H
#define CONFIG_H
#define MODEL_IDENTIFIER {ident}
#define MODEL_GUID "{guid}"
#define N_Q {model.n_q}
#define N_U {len(model.inputs)}
#define N_P {len(model.parameters)}
#define N_Y {len(model.outputs)}
#define N_LAWS {n_laws}
#define N_STATIC {n_static}
#define N_VARS {len(variables)}
#define MODEL_LINEAR_IN_STATE {int(model.linear_in_state)}
#define MODEL_JACOBIAN_CONSTANT {int(model.jacobian_constant)}
#define MODEL_SZ_ARG {sz['arg']}
#define MODEL_SZ_RES {sz['res']}
#define MODEL_SZ_IW {sz['iw']}
#define MODEL_SZ_W {sz['w']}
#endif
"""
    (directory / "config.h").write_text(config)

    rows = []
    for v in variables:
        index = ["SOLVER_STEP", "SOLVER_THETA1", "SOLVER_THETA2", "SOLVER_TOLERANCE", "SOLVER_ORDER"][v.index] \
            if v.kind == "VAR_SOLVER" else str(v.index)
        rows.append(f'    {{"{v.name}", {v.kind}, {index}, {_c(v.start)}, {_c(v.min)}, {_c(v.max)}, '
                    f"{int(v.min_exclusive)}, {int(v.variability == 'tunable' or v.causality == 'input')}}},")
    laws_c = []
    law_rows = []
    for k, law in enumerate(model.laws):
        if law.trajectory is None:
            law_rows.append(f"    {{{law.u_offset}, 0, 0, NULL}},")
            continue
        seg_rows = []
        for j, seg in enumerate(law.trajectory.segments):
            poly = ", ".join(_c(c) for c in seg.poly) or "0.0"
            cos = ", ".join(_c(x) for trip in seg.cos for x in trip) or "0.0"
            laws_c.append(f"static const double law{k}_poly{j}[] = {{{poly}}};")
            laws_c.append(f"static const double law{k}_cos{j}[] = {{{cos}}};")
            seg_rows.append(f"    {{{_c(seg.until)}, {len(seg.poly)}, law{k}_poly{j}, {len(seg.cos)}, "
                            f"law{k}_cos{j}}},")
        laws_c.append(f"static const LawSegment law{k}_segments[] = {{\n" + "\n".join(seg_rows) + "\n};")
        law_rows.append(f"    {{{law.u_offset}, 1, {len(law.trajectory.segments)}, law{k}_segments}},")
    static_c = ""
    if n_static:
        static_c = ("const int MODEL_STATIC_COORDS[N_STATIC] = {"
                    + ", ".join(str(i) for i in model.static_coordinates) + "};\n")
    laws_block = ""
    if n_laws:
        laws_block = ("\n".join(laws_c) + "\nconst KinematicLaw MODEL_LAWS[N_LAWS] = {\n"
                      + "\n".join(law_rows) + "\n};\n")

    def call(name, args, res):
        a = "\n".join(f"    work->arg[{i}] = {x};" for i, x in enumerate(args))
        return (f"{a}\n    work->res[0] = {res};\n"
                f"    return {ident}_{name}(work->arg, work->res, work->iw, work->w, 0);")

    if expanded:
        newton_c = f"""int model_newton_matrix(const double *q, const double *v, const double *a, const double *u,
                        const double *p, double ca, double cv, double cq, double *J, ModelWork *work) {{
{call("newton_matrix", ["q", "v", "a", "u", "p", "&ca", "&cv", "&cq"], "J")}
}}"""
    else:
        newton_c = f"""/* Column j of J is the residual's derivative in the direction (cq e_j, cv e_j, ca e_j). */
int model_newton_matrix(const double *q, const double *v, const double *a, const double *u,
                        const double *p, double ca, double cv, double cq, double *J, ModelWork *work) {{
    double dq[N_Q] = {{0}}, dv[N_Q] = {{0}}, da[N_Q] = {{0}};
    for (int j = 0; j < N_Q; j++) {{
        int status;
        dq[j] = cq; dv[j] = cv; da[j] = ca;
{indent(call("residual_forward", ["q", "v", "a", "u", "p", "dq", "dv", "da"], "J + (size_t)j * N_Q")
         .replace("return ", "status = "), "    ")}
        dq[j] = 0.0; dv[j] = 0.0; da[j] = 0.0;
        if (status) return status;
    }}
    return 0;
}}"""
    large = model.n_q > FULL_OPTIMISATION_MAX
    optimise_push = ('#pragma GCC push_options\n#pragma GCC optimize ("O1")  /* large straight-line code */\n'
                     if large else "")
    optimise_pop = "#pragma GCC pop_options\n" if large else ""
    model_c = f"""/* model.c -- generated by flexlink.export.codegen for scene "{model.scene.name}". Do not edit.
 * The model half of the FMU: variable table, kinematic laws, and the functions of
 * fmu_src/model.h as calls into the CasADi-generated {cname}.c. */
#include "model.h"

/* The CasADi-generated code is compiled as part of this file, with the few warnings it is known
 * to raise silenced here only, so that the rest of the FMU builds with -Wall -Wextra -Werror. */
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wunused-variable"
#pragma GCC diagnostic ignored "-Wunused-function"
{optimise_push}#endif
#include "{cname}.c"
#if defined(__GNUC__)
{optimise_pop}#pragma GCC diagnostic pop
#endif

const VarInfo MODEL_VARS[N_VARS] = {{
    /* name, kind, index, start, min, max, min_exclusive, tunable */
{chr(10).join(rows)}
}};

const double MODEL_NOMINAL_Q[N_Q] = {{{", ".join(_c(x) for x in model.nominal_q)}}};

{static_c}{laws_block}
int model_residual(const double *q, const double *v, const double *a, const double *u,
                   const double *p, double *r, ModelWork *work) {{
{call("residual", ["q", "v", "a", "u", "p"], "r")}
}}

{newton_c}

int model_outputs(const double *q, const double *v, const double *a, const double *u,
                  const double *p, double *y, ModelWork *work) {{
{call("outputs", ["q", "v", "a", "u", "p"], "y")}
}}

int model_residual_forward(const double *q, const double *v, const double *a, const double *u,
                           const double *p, const double *dq, const double *dv, const double *da,
                           const double *du, const double *dp, double *dr, ModelWork *work) {{
{call("residual_forward_all", ["q", "v", "a", "u", "p", "dq", "dv", "da", "du", "dp"], "dr")}
}}

int model_outputs_forward(const double *q, const double *v, const double *a, const double *u,
                          const double *p, const double *dq, const double *dv, const double *da,
                          const double *du, const double *dp, double *dy, ModelWork *work) {{
{call("outputs_forward", ["q", "v", "a", "u", "p", "dq", "dv", "da", "du", "dp"], "dy")}
}}
"""
    (directory / "model.c").write_text(model_c)
    sources = [directory / "model.c"]          # includes the CasADi file
    generated = [directory / "model.c", directory / f"{cname}.c", directory / f"{cname}.h"]
    return GeneratedModel(directory, sources, generated, variables, guid, ident, expanded, operations)
