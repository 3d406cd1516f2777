/* model.c of the hand-written nonlinear test model (see config.h). */
#include <math.h>
#include "model.h"

#define BIG 1e300

const VarInfo MODEL_VARS[N_VARS] = {
    /* name             kind            idx               start    min    max   min_excl tunable integer */
    {"F",               VAR_INPUT,      0,                0.0,    -BIG,   BIG,  0, 1, 0},
    {"support1.x",      VAR_INPUT,      4,                0.0,    -BIG,   BIG,  0, 1, 0},
    {"support1.xd",     VAR_INPUT,      5,                0.0,    -BIG,   BIG,  0, 1, 0},
    {"support1.xdd",    VAR_INPUT,      6,                0.0,    -BIG,   BIG,  0, 1, 0},
    {"q0",              VAR_OUTPUT,     0,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"q1",              VAR_OUTPUT,     1,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"v0",              VAR_OUTPUT,     2,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"v1",              VAR_OUTPUT,     3,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"a0",              VAR_OUTPUT,     4,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"a1",              VAR_OUTPUT,     5,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"law0.x",          VAR_OUTPUT,     6,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"law0.xd",         VAR_OUTPUT,     7,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"law0.xdd",        VAR_OUTPUT,     8,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"law1.x",          VAR_OUTPUT,     9,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"law1.xd",         VAR_OUTPUT,     10,               0.0,    -BIG,   BIG,  0, 0, 0},
    {"law1.xdd",        VAR_OUTPUT,     11,               0.0,    -BIG,   BIG,  0, 0, 0},
    {"m",               VAR_PARAMETER,  0,                1.0,     0.0,   BIG,  1, 0, 0},
    {"c",               VAR_PARAMETER,  1,                0.5,     0.0,   BIG,  0, 1, 0},
    {"k",               VAR_PARAMETER,  2,                100.0,   0.0,   BIG,  1, 1, 0},
    {"k3",              VAR_PARAMETER,  3,                1e4,     0.0,   BIG,  0, 1, 0},
    {"g",               VAR_PARAMETER,  4,                9.81,   -BIG,   BIG,  0, 0, 0},
    {"limit",           VAR_PARAMETER,  5,                BIG,     0.0,   BIG,  1, 1, 0},
    {"max_cv",          VAR_PARAMETER,  6,                BIG,     0.0,   BIG,  1, 1, 0},
    {"q0_start",        VAR_START_Q,    0,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"q1_start",        VAR_START_Q,    1,                0.05,   -BIG,   BIG,  0, 0, 0},
    {"v0_start",        VAR_START_V,    0,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"v1_start",        VAR_START_V,    1,                0.0,    -BIG,   BIG,  0, 0, 0},
    {"solver.step",     VAR_SOLVER,     SOLVER_STEP,      0.01,    0.0,   BIG,  1, 0, 0},
    {"solver.theta1",   VAR_SOLVER,     SOLVER_THETA1,    0.5,     0.5,   1.0,  0, 0, 0},
    {"solver.theta2",   VAR_SOLVER,     SOLVER_THETA2,    0.5,     0.5,   1.0,  0, 0, 0},
    {"solver.tolerance", VAR_SOLVER,    SOLVER_TOLERANCE, 1e-10,   0.0,   BIG,  1, 0, 0},
};

/* law 0: x = 0.1 (1 - cos(pi t)) for t < 1, then 0.3 t^2 - 0.6 t + 0.5 (continued beyond t = 2) */
static const double SEG0_POLY[] = {0.1};
static const double SEG0_COS[] = {-0.1, 3.14159265358979323846, 0.0};
static const double SEG1_POLY[] = {0.5, -0.6, 0.3};
static const LawSegment LAW0[] = {
    {1.0, 1, SEG0_POLY, 1, SEG0_COS},
    {2.0, 3, SEG1_POLY, 0, 0},
};

const KinematicLaw MODEL_LAWS[N_LAWS] = {
    {1, 1, 2, LAW0},
    {4, 0, 0, 0},
};

const int MODEL_STATIC_COORDS[N_STATIC] = {0};

const double MODEL_NOMINAL_Q[N_Q] = {0.1, 0.1};
const unsigned char MODEL_OUTPUT_USES_ACCELERATION[N_Y] = {0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0};   /* a0, a1 */

enum { M, C, K, K3, G, LIMIT, MAX_CV };

int model_residual(const double *q, const double *v, const double *a, const double *u,
                   const double *p, double *r, ModelWork *work) {
    const double d0 = q[0] - u[1], d1 = q[1] - u[4];
    (void)work;
    r[0] = p[M] * a[0] + p[C] * (v[0] - u[2]) + p[K] * d0 + p[K3] * d0 * d0 * d0 + p[M] * p[G] - u[0];
    r[1] = p[M] * a[1] + p[C] * (v[1] - u[5]) + p[K] * d1;
    if (fabs(d0) > p[LIMIT]) r[0] = NAN;
    return 0;
}

int model_newton_matrix(const double *q, const double *v, const double *a, const double *u,
                        const double *p, double ca, double cv, double cq, double *J, ModelWork *work) {
    const double d0 = q[0] - u[1];
    (void)v; (void)a; (void)work;
    if (cv > p[MAX_CV]) return 1;
    J[0] = ca * p[M] + cv * p[C] + cq * (p[K] + 3.0 * p[K3] * d0 * d0);
    J[1] = 0.0;
    J[2] = 0.0;
    J[3] = ca * p[M] + cv * p[C] + cq * p[K];
    return 0;
}

int model_outputs(const double *q, const double *v, const double *a, const double *u,
                  const double *p, double *y, ModelWork *work) {
    (void)p; (void)work;
    y[0] = q[0]; y[1] = q[1]; y[2] = v[0]; y[3] = v[1]; y[4] = a[0]; y[5] = a[1];
    for (int i = 0; i < 3; i++) { y[6 + i] = u[1 + i]; y[9 + i] = u[4 + i]; }
    return 0;
}

static int residual_forward(const double *q, const double *v, const double *a, const double *u,
                            const double *p, const double *dq, const double *dv, const double *da,
                            const double *du, const double *dp, double *dr, ModelWork *work) {
    const double d0 = q[0] - u[1], d1 = q[1] - u[4];
    const double dd0 = dq[0] - du[1], dd1 = dq[1] - du[4];
    (void)work;
    dr[0] = p[M] * da[0] + p[C] * (dv[0] - du[2]) + (p[K] + 3.0 * p[K3] * d0 * d0) * dd0 - du[0] +
            dp[M] * (a[0] + p[G]) + dp[C] * (v[0] - u[2]) + dp[K] * d0 + dp[K3] * d0 * d0 * d0 + p[M] * dp[G];
    dr[1] = p[M] * da[1] + p[C] * (dv[1] - du[5]) + p[K] * dd1 +
            dp[M] * a[1] + dp[C] * (v[1] - u[5]) + dp[K] * d1;
    if (fabs(d0) > p[LIMIT]) dr[0] = NAN;
    return 0;
}

static int outputs_forward(const double *q, const double *v, const double *a, const double *u,
                           const double *p, const double *dq, const double *dv, const double *da,
                           const double *du, const double *dp, double *dy, ModelWork *work) {
    (void)q; (void)v; (void)a; (void)u; (void)p; (void)dp; (void)work;
    dy[0] = dq[0]; dy[1] = dq[1]; dy[2] = dv[0]; dy[3] = dv[1]; dy[4] = da[0]; dy[5] = da[1];
    for (int i = 0; i < 3; i++) { dy[6 + i] = du[1 + i]; dy[9 + i] = du[4 + i]; }
    return 0;
}

/* model.h's two forward derivatives, from the residual's and the outputs' in a full direction */
#include "../forward_from_parts.h"

/* No validity limits: the generic guards still refuse non-finite states. */
const char *const MODEL_VALIDITY_NAMES[1] = {""};

int model_validity(const double *q, const double *u, const double *p, double *g, ModelWork *work) {
    (void)q; (void)u; (void)p; (void)g; (void)work;
    return 0;
}

/* No relations between parameters to check. */
const char *const MODEL_PARAMETER_CHECK_NAMES[1] = {""};

/* the guard's residual differences, as for a model whose input matrix is not constant */
int model_input_forces(const double *u, double *force) {
    (void)u; (void)force;
    return 0;
}

int model_parameter_check(const double *p, double *h, ModelWork *work) {
    (void)p; (void)h; (void)work;
    return 0;
}

int model_avx_code(void) {   /* hand-written: no AVX twins (fmu_src/avx.h) */
    return 0;
}
