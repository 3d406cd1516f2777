/* richardson.c -- when the order-4 option (Richardson extrapolation of the symmetric SS22) is stable.
 *
 * On an undamped mode of circular frequency w, one SS22 step of h with Theta1 = Theta2 = 1/2 has spectral
 * radius 1 for every w h, but the extrapolation q = q_h/2 + (q_h/2 - q_h)/3 has a radius above 1 that grows
 * like (w h)^6 for small w h and reaches 5/3 for unresolved modes (the two SS22 solutions then oscillate in
 * opposite phase; tests/test_richardson.py computes the radius from the scheme's equations):
 *     w h = 0.1: 1 + 8.6e-10,   0.3: 1 + 6.1e-7,   0.5: 1 + 1.2e-5,   1: 1 + 6.1e-4,   3: 1.077.
 * So order 4 is used only while every mode is resolved: w_max dt <= RICHARDSON_MAX_OMEGA_STEP, where an
 * unexcited mode grows by at most 2 over the 10^6 internal steps one fmi2DoStep may take.  Beyond, the step
 * is refused (fmi2Discard) with the frequency and the largest step that would do, instead of the result
 * growing without a sign (issue: order 4 ran to a tip deflection of 8.6e40 m with fmi2OK).
 *
 * w_max^2 is the largest |eigenvalue| of M^-1 K, K = dr/dq and M = dr/da from the model's Newton matrix,
 * found by power iteration at the state of the first order-4 step and again after a parameter change.
 * Limits: a configuration or speed that raises the highest frequency later is not re-checked, and the
 * growth bound is per doStep: over a whole run of N steps at w dt = 0.3 an unexcited mode grows by
 * exp(6.1e-7 N), e.g. 450x over 1e7 steps (docs/fidelity.md). */
#include <math.h>
#include <string.h>
#include "internal.h"
#include "linalg.h"

#define POWER_ITERATIONS 200
#define TWO_PI 6.283185307179586

/* the largest |lambda| of M^-1 K by power iteration; -1 if the matrices cannot be had, -2 out of memory */
static double largest_eigenvalue(Instance *inst) {
    FmuData *d = &inst->d;
    const size_t nn = (size_t)N_Q * N_Q;
    double *M = (double *)inst->cb.allocateMemory(2 * nn, sizeof(double));
    double x[N_Q], y[N_Q], lambda = -1.0;
    int piv[N_Q];
    if (M == NULL) return -2.0;
    double *K = M + nn;
    fmu_model_inputs(d, d->time, inst->u0);
    if (model_newton_matrix(d->q, d->v, d->alpha, inst->u0, d->p, 1.0, 0.0, 0.0, M, &inst->work) ||
        model_newton_matrix(d->q, d->v, d->alpha, inst->u0, d->p, 0.0, 0.0, 1.0, K, &inst->work) ||
        !fmu_all_finite(M, (int)nn) || !fmu_all_finite(K, (int)nn) || lu_factor(M, N_Q, piv)) {
        inst->cb.freeMemory(M);
        return -1.0;
    }
    for (int i = 0; i < N_Q; i++) x[i] = 1.0 + (double)i / N_Q;     /* not orthogonal to any mode in practice */
    for (int it = 0; it < POWER_ITERATIONS; it++) {
        double norm_x = 0.0, norm_y = 0.0;
        for (int i = 0; i < N_Q; i++) norm_x += x[i] * x[i];
        for (int i = 0; i < N_Q; i++) {                 /* y = M^-1 K x, K column-major */
            double s = 0.0;
            for (int j = 0; j < N_Q; j++) s += K[(size_t)j * N_Q + i] * x[j];
            y[i] = s;
        }
        lu_solve(M, N_Q, piv, y);
        for (int i = 0; i < N_Q; i++) norm_y += y[i] * y[i];
        if (!(norm_y > 0.0) || !isfinite(norm_y)) { lambda = norm_y == 0.0 ? 0.0 : -1.0; break; }
        lambda = sqrt(norm_y / norm_x);
        for (int i = 0; i < N_Q; i++) x[i] = y[i] / sqrt(norm_y);
    }
    inst->cb.freeMemory(M);
    return lambda;
}

fmi2Status fmu_check_richardson(Instance *inst, double dt) {
    FmuData *d = &inst->d;
    if (!d->omega_max_known) {
        const double lambda = largest_eigenvalue(inst);
        if (lambda == -2.0) return fmu_error(inst, "fmi2DoStep: solver.order = %d: out of memory",
                                             SOLVER_ORDER_RICHARDSON);
        if (lambda < 0.0) {
            return fmu_error(inst, "fmi2DoStep: solver.order = %d: the highest natural frequency could not be "
                             "found (mass or stiffness matrix not finite or singular)", SOLVER_ORDER_RICHARDSON);
        }
        d->omega_max = sqrt(lambda);
        d->omega_max_known = 1;
    }
    if (d->omega_max * dt <= RICHARDSON_MAX_OMEGA_STEP) return fmi2OK;
    fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2DoStep: solver.order = %d (Richardson extrapolation) "
            "is unstable at an internal step of %g s: the highest natural frequency, %.4g Hz, is not resolved "
            "(w dt = %.3g > %g); use order %d, or internal steps of at most %.3g s (the FMU stays at "
            "t = %.17g)", SOLVER_ORDER_RICHARDSON, dt, d->omega_max / TWO_PI, d->omega_max * dt,
            RICHARDSON_MAX_OMEGA_STEP, SOLVER_ORDER_SS22, RICHARDSON_MAX_OMEGA_STEP / d->omega_max, d->time);
    return fmi2Discard;
}
