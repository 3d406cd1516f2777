/* model.c of the hand-written 2-DOF test model (see config.h). */
#include "model.h"

const VarInfo MODEL_VARS[N_VARS] = {
    /* name          kind            idx start  min     max       min_excl tunable integer */
    {"F1",           VAR_INPUT,      0,  1.0,  -1e300,  1e300,    0, 1, 0},
    {"F2",           VAR_INPUT,      1,  2.0,  -1e300,  1e300,    0, 1, 0},
    {"q1",           VAR_OUTPUT,     0,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"q2",           VAR_OUTPUT,     1,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"v1",           VAR_OUTPUT,     2,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"v2",           VAR_OUTPUT,     3,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"stiffness",    VAR_PARAMETER,  0,  1.0,   0.0,    1e300,    1, 1, 0},
    {"q1_start",     VAR_START_Q,    0,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"q2_start",     VAR_START_Q,    1,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"v1_start",     VAR_START_V,    0,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"v2_start",     VAR_START_V,    1,  0.0,  -1e300,  1e300,    0, 0, 0},
    {"solver.step",  VAR_SOLVER,     SOLVER_STEP,      0.5,   0.0, 1e300, 1, 0, 0},
    {"solver.theta1",VAR_SOLVER,     SOLVER_THETA1,    0.5,   0.5, 1.0,   0, 0, 0},
    {"solver.theta2",VAR_SOLVER,     SOLVER_THETA2,    0.5,   0.5, 1.0,   0, 0, 0},
    {"solver.tolerance", VAR_SOLVER, SOLVER_TOLERANCE, 1e-10, 0.0, 1e300, 1, 0, 0},
    {"energy",       VAR_OUTPUT,     0,  0.0,  -1e300,  1e300,    0, 0, 0},  /* alias of q1, unused slot */
};

const double MODEL_NOMINAL_Q[N_Q] = {1.0, 1.0};
const unsigned char MODEL_OUTPUT_USES_ACCELERATION[N_Y] = {0, 0, 0, 0};

static const double M[4] = {1, 1, 1, 2};   /* column-major, symmetric */
static const double K[4] = {1, 1, 1, 3};

int model_residual(const double *q, const double *v, const double *a, const double *u,
                   const double *p, double *r, ModelWork *work) {
    (void)work;
    for (int i = 0; i < 2; i++) {
        r[i] = -u[i];
        for (int j = 0; j < 2; j++) r[i] += M[i + 2 * j] * a[j] + p[0] * K[i + 2 * j] * (v[j] + q[j]);
    }
    return 0;
}

int model_newton_matrix(const double *q, const double *v, const double *a, const double *u,
                        const double *p, double ca, double cv, double cq, double *J, ModelWork *work) {
    (void)q; (void)v; (void)a; (void)u; (void)work;
    for (int k = 0; k < 4; k++) J[k] = ca * M[k] + (cv + cq) * p[0] * K[k];
    return 0;
}

int model_outputs(const double *q, const double *v, const double *a, const double *u,
                  const double *p, double *y, ModelWork *work) {
    (void)a; (void)u; (void)p; (void)work;
    y[0] = q[0]; y[1] = q[1]; y[2] = v[0]; y[3] = v[1];
    return 0;
}

/* dr = M da + p K (dv + dq) + dp K (v + q) - du */
static int residual_forward(const double *q, const double *v, const double *a, const double *u,
                            const double *p, const double *dq, const double *dv, const double *da,
                            const double *du, const double *dp, double *dr, ModelWork *work) {
    (void)a; (void)u; (void)work;
    for (int i = 0; i < 2; i++) {
        dr[i] = -du[i];
        for (int j = 0; j < 2; j++) {
            dr[i] += M[i + 2 * j] * da[j] + p[0] * K[i + 2 * j] * (dv[j] + dq[j]) +
                     dp[0] * K[i + 2 * j] * (v[j] + q[j]);
        }
    }
    return 0;
}

static int outputs_forward(const double *q, const double *v, const double *a, const double *u,
                           const double *p, const double *dq, const double *dv, const double *da,
                           const double *du, const double *dp, double *dy, ModelWork *work) {
    (void)q; (void)v; (void)a; (void)u; (void)p; (void)da; (void)du; (void)dp; (void)work;
    dy[0] = dq[0]; dy[1] = dq[1]; dy[2] = dv[0]; dy[3] = dv[1];
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
