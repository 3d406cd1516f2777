"""Why SS22's Newton iteration takes the iterations it takes: one line per step from an instrumented copy of the loop.

    python benchmarks/newton_trace.py SCENE.toml [--tolerance TOL] [--stop T] [--every N] [--torque TAU]
        [--set NAME=VALUE ...] [--hold] [--out TRACE.txt]

The FMU's sources are compiled with ``benchmarks/step_floor.c`` and a copy of ``fmu_src/ss22.c`` patched to
write, for every step of the scene's bench manoeuvre (``flexlink.tools.bench.default_case``) at its own step:
the iterations, the kept matrix's age in steps, the predictor's error (the converged acceleration against the
iteration's start) next to the errors other predictors would have made (holding the last acceleration, the
mean of the last two, a parabola through the last three), the matrix's kept contraction rate and the steps
accepted on it since it was last measured (``SS22Factor.rate``, ``.estimated``, after the step), and every
increment, all in the tolerance's units (Δt |δα_i| / nominal_i, largest over i), then ``= left X``: what the
accepted step has left by the FMU's own residual, one Newton increment with a matrix evaluated at it (the
figure ``benchmarks/step_audit.py`` audits, here from the FMU itself).  Every ``--every`` steps it
also splits the kept matrix's error G = J_old⁻¹ (J_now − J_old), J = M + Θ₁Δt C + Θ₂Δt²/2 K, into its M, C and
K parts (∞-norms in nominal units) and gives G's spectral radius, the rate simplified Newton contracts at.  The
summary prints geometric means and the iterations' distribution; the trace file keeps the lines.  Nothing here
ships in an FMU.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import subprocess
import sys
import tempfile
import zipfile
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import step_floor  # noqa: E402

HEAD = r'''
#include <stdio.h>
#include <stdlib.h>
static FILE *TR;
static double TR_err[64];
static int TR_n;
static double OLD_qb[SS22_CACHE][N_Q], OLD_vb[SS22_CACHE][N_Q], OLD_a[SS22_CACHE][N_Q];
static double OLD_u[SS22_CACHE][N_U > 0 ? N_U : 1];
static uint64_t OLD_step[SS22_CACHE];
/* where the kept matrix's M part was taken: its full evaluation's state, or its last mass update's */
static double OLDM_qb[SS22_CACHE][N_Q], OLDM_vb[SS22_CACHE][N_Q], OLDM_a[SS22_CACHE][N_Q];
static double OLDM_u[SS22_CACHE][N_U > 0 ? N_U : 1];
static uint64_t TR_updates;
static double TR_start[N_Q];
'''

TRACE = r'''
static double part_norm(SS22Factor *f, const double *Xn, const double *Xo, double *G) {
    double col[N_Q], worst = 0.0;
    for (int j = 0; j < N_Q; j++) {
        for (int i = 0; i < N_Q; i++) col[i] = Xn[i * N_Q + j] - Xo[i * N_Q + j];
        lu_solve(f->LU, N_Q, f->piv, col);
        for (int i = 0; i < N_Q; i++) G[i * N_Q + j] = col[i];
    }
    for (int i = 0; i < N_Q; i++) {
        double row = 0.0;
        for (int j = 0; j < N_Q; j++) row += fabs(G[i * N_Q + j]) * MODEL_NOMINAL_Q[j] / MODEL_NOMINAL_Q[i];
        worst = fmax(worst, row);
    }
    return worst;
}

static double spectral_radius(const double *G) {
    double x[N_Q], y[N_Q], lambda = 0.0;
    for (int i = 0; i < N_Q; i++) x[i] = 1.0 + 0.1 * i;
    for (int it = 0; it < 200; it++) {
        double n = 0.0;
        for (int i = 0; i < N_Q; i++) {
            y[i] = 0.0;
            for (int j = 0; j < N_Q; j++) y[i] += G[i * N_Q + j] * x[j];
            n = fmax(n, fabs(y[i]));
        }
        if (n == 0.0) return 0.0;
        lambda = n;
        for (int i = 0; i < N_Q; i++) x[i] = y[i] / n;
    }
    return lambda;
}

static void trace_step(SS22 *s, double dt, const double *q, const double *v, const double *a, const double *p,
                       ModelWork *work, SS22Factor *f) {
    static double a1[N_Q], a2[N_Q], a3[N_Q];
    static long seen;
    static double Xn[N_Q * N_Q], Xo[N_Q * N_Q], G[N_Q * N_Q], Gt[N_Q * N_Q];
    if (!TR) {
        const char *path = getenv("SS22_TRACE");
        if (!path) return;
        TR = fopen(path, "w");
        if (!TR) return;
    }
    double used = 0, hold = 0, mean = 0, parabola = 0;
    for (int i = 0; i < N_Q; i++) {
        const double w = dt / MODEL_NOMINAL_Q[i];
        used = fmax(used, fabs(a[i] - TR_start[i]) * w);
        if (seen >= 3) {
            hold = fmax(hold, fabs(a[i] - a1[i]) * w);
            mean = fmax(mean, fabs(a[i] - 0.5 * (a1[i] + a2[i])) * w);
            parabola = fmax(parabola, fabs(a[i] - (3 * a1[i] - 3 * a2[i] + a3[i])) * w);
        }
    }
    memcpy(a3, a2, sizeof(a1));
    memcpy(a2, a1, sizeof(a1));
    memcpy(a1, a, sizeof(a1));
    const int k = (int)(f - s->cache);
    fprintf(TR, "%llu %d %llu %.3e %.3e %.3e %.3e %.3e %d |", (unsigned long long)s->steps, TR_n,
            (unsigned long long)(s->steps - OLD_step[k]), used, hold, mean, parabola, f->rate, f->estimated);
    for (int i = 0; i < TR_n && i < 20; i++) fprintf(TR, " %.2e", TR_err[i]);
    {   /* what the accepted step has left by the FMU's own residual: one Newton increment with a fresh matrix */
        const double cv = s->theta1 * dt, cq = s->theta2 * 0.5 * dt * dt;
        double qb[N_Q], vb[N_Q], r[N_Q];
        int piv[N_Q];
        for (int i = 0; i < N_Q; i++) { qb[i] = q[i] + cv * v[i] + cq * a[i]; vb[i] = v[i] + cv * a[i]; }
        double left = -1.0;
        if (!model_residual(qb, vb, a, s->u_bar, p, r, work)
            && !model_newton_matrix(qb, vb, a, s->u_bar, p, 1.0, cv, cq, Xn, work) && !lu_factor(Xn, N_Q, piv)) {
            lu_solve(Xn, N_Q, piv, r);
            left = 0.0;
            for (int i = 0; i < N_Q; i++) left = fmax(left, fabs(r[i]) * dt / MODEL_NOMINAL_Q[i]);
        }
        fprintf(TR, " = left %.2e", left);
    }
    if (SS22_TRACE_EVERY > 0 && seen % SS22_TRACE_EVERY == 0) {
        const double cv = s->theta1 * dt, cq = s->theta2 * 0.5 * dt * dt;
        const double weights[3][3] = {{1, 0, 0}, {0, cv, 0}, {0, 0, cq}};
        double qb[N_Q], vb[N_Q], parts[3];
        for (int i = 0; i < N_Q; i++) { qb[i] = q[i] + cv * v[i] + cq * a[i]; vb[i] = v[i] + cv * a[i]; }
        memset(Gt, 0, sizeof(Gt));
        for (int m = 0; m < 3; m++) {
            const double *w = weights[m];
            model_newton_matrix(qb, vb, a, s->u_bar, p, w[0], w[1], w[2], Xn, work);
            if (m == 0) model_newton_matrix(OLDM_qb[k], OLDM_vb[k], OLDM_a[k], OLDM_u[k], p, 1, 0, 0, Xo, work);
            else model_newton_matrix(OLD_qb[k], OLD_vb[k], OLD_a[k], OLD_u[k], p, w[0], w[1], w[2], Xo, work);
            parts[m] = part_norm(f, Xn, Xo, G);
            for (int i = 0; i < N_Q * N_Q; i++) Gt[i] += G[i];
        }
        fprintf(TR, " | M %.3e C %.3e K %.3e rho %.3e", parts[0], parts[1], parts[2], spectral_radius(Gt));
    }
    fprintf(TR, "\n");
    seen++;
}
'''

# the state of the kept matrix's M part, after its full evaluation or a mass update (fmu_src/mass_update.c)
MASS_STATE = ("    if ({condition}) {{ const int k_ = (int)(f - s->cache); TR_updates = s->mass_updates;\n"
              "      memcpy(OLDM_qb[k_], s->q_bar, sizeof(OLDM_qb[k_]));\n"
              "      memcpy(OLDM_vb[k_], s->v_bar, sizeof(OLDM_vb[k_]));\n"
              "      memcpy(OLDM_a[k_], {acceleration}, sizeof(OLDM_a[k_]));\n"
              "      memcpy(OLDM_u[k_], s->u_bar, sizeof(OLDM_u[k_])); }}\n")

# (anchor in fmu_src/ss22.c, text to put after it); each anchor must be there exactly once
PATCHES = [
    ('#include "predictor.h"\n', HEAD),
    ("        if (ss22_mass_update_due(s, f)) ss22_mass_update(s, f, a, p, work);      /* for the next steps */\n",
     MASS_STATE.format(condition="s->mass_updates != TR_updates", acceleration="a")),
    ("    s->factorisations++;\n",
     "    { const int k_ = (int)(f - s->cache); memcpy(OLD_qb[k_], s->q_bar, sizeof(OLD_qb[k_]));\n"
     "      memcpy(OLD_vb[k_], s->v_bar, sizeof(OLD_vb[k_])); memcpy(OLD_a[k_], alpha, sizeof(OLD_a[k_]));\n"
     "      memcpy(OLD_u[k_], s->u_bar, sizeof(OLD_u[k_])); OLD_step[k_] = s->steps; }\n"
     + MASS_STATE.format(condition="1", acceleration="alpha")),
    ("                                  : corrected ? s->tolerance / SS22_DIRECTION_MARGIN : INFINITY;\n",
     "        TR_n = 0; memcpy(TR_start, a, sizeof(TR_start));\n"),
    ("            s->newton_iterations++;\n", "            if (TR_n < 64) TR_err[TR_n++] = err;\n"),
    ("        if (!converged) return SS22_NOT_CONVERGED;\n", "        trace_step(s, dt, q, v, a, p, work, f);\n"),
]


def instrument(source: str, every: int) -> str:
    """ss22.c with the trace: the functions before ss22_step, the hooks after their anchors."""
    for anchor, text in PATCHES:
        if source.count(anchor) != 1:
            raise SystemExit(f"newton_trace: fmu_src/ss22.c no longer has one {anchor.strip()!r}; update PATCHES")
        source = source.replace(anchor, anchor + text)
    marker = "SS22Status ss22_step(SS22 *s, double dt,"
    return source.replace(marker, f"#define SS22_TRACE_EVERY {every}\n{TRACE}\n{marker}", 1)


def run(scene_path: Path, tolerance: float | None, stop: float, every: int, out: Path,
        torque: float = 0.2, values: dict[str, float] | None = None, hold: bool = False) -> None:
    """Build (or reuse) the scene's FMU, compile the instrumented driver and run the manoeuvre once."""
    import fmpy

    from flexlink.export.cache import cached_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case

    scene = load_scene(scene_path)
    model = build_model(scene)
    case = default_case(model, stop=stop, torque=torque)
    if hold:        # the inputs as set from t = 0 (as benchmarks/step_audit.py holds them), no ±τ pieces
        case = dataclasses.replace(case, pieces=[], switches=[])
    fmu = Path(cached_fmu(scene, model=model))
    start = {"solver.step": scene.fmu.solver.step, **(values or {})}
    if tolerance is not None:
        start["solver.tolerance"] = tolerance
    with tempfile.TemporaryDirectory() as tmp:
        patched = Path(tmp) / "traced.fmu"
        with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(patched, "w") as zout:
            for item in zin.infolist():
                data = zin.read(item.filename)
                if item.filename == "sources/ss22.c":
                    data = instrument(data.decode(), every).encode()
                zout.writestr(item, data)
        exe = step_floor.compile_driver(patched, Path(tmp) / "build")
        tokens = step_floor.manoeuvre_tokens(fmu, case, start)
        guid = fmpy.read_model_description(str(fmu)).guid
        # one warm-up run and one timed run write the trace; keep the first run's lines
        subprocess.run([str(exe), guid, "1", *tokens], capture_output=True, text=True, check=True,
                       env=dict(os.environ, SS22_TRACE=str(out)))
    lines = out.read_text().splitlines()
    steps = round(case.stop / scene.fmu.solver.step)
    out.write_text("\n".join(lines[:steps]) + "\n")
    summarise(lines[:steps])


def summarise(lines: list[str]) -> None:
    """Geometric means of the predictors' errors and the first increment, and the iterations' distribution."""
    rows = [line.split("|")[0].split() for line in lines]
    body = [r for r in rows[4:] if all(float(x) > 0 for x in r[3:7])]

    def gmean(col: int) -> float:
        return math.exp(sum(math.log(float(r[col])) for r in body) / max(len(body), 1))

    iterations = Counter(int(r[1]) for r in rows)
    print(f"steps {len(rows)}, iterations a step {sum(int(r[1]) for r in rows) / max(len(rows), 1):.2f}, "
          f"distribution {dict(sorted(iterations.items()))}")
    print(f"predictor error (geometric mean): the start used (the line through the last two, or the parabola "
          f"through three while it has missed by less) {gmean(3):.2e}, hold the last "
          f"{gmean(4):.2e}, mean of the last two {gmean(5):.2e}, parabola through three {gmean(6):.2e}")
    split = [line.split("|")[2].split() for line in lines if line.count("|") == 2]
    for s in split[:: max(1, len(split) // 10)]:
        print("kept matrix error: " + " ".join(s))


def _name_value(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` as (name, float), or argparse's one-line error."""
    name, sep, value = text.partition("=")
    try:
        if not (sep and name):
            raise ValueError
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with a number, got {text!r}") from None


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--tolerance", type=float, help="solver.tolerance (default: the scene's)")
    parser.add_argument("--stop", type=float, default=2.0)
    parser.add_argument("--every", type=int, default=50, help="steps between matrix-error splits (0: none)")
    parser.add_argument("--torque", type=float, default=0.2,
                        help="the manoeuvre's torque on a torque-driven first joint, N m (default 0.2, the bench's)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", type=_name_value,
                        help="a start value or held input (e.g. elbow.tau=5, as benchmarks/step_audit.py takes them)")
    parser.add_argument("--hold", action="store_true",
                        help="hold the inputs at their start values (--set) instead of the bench's ±τ pieces "
                             "(--torque is then not used)")
    parser.add_argument("--out", default="/tmp/newton_trace.txt")
    args = parser.parse_args(argv)
    values = dict(args.set)
    run(Path(args.scene), args.tolerance, args.stop, args.every, Path(args.out), args.torque, values, args.hold)


if __name__ == "__main__":
    main()
