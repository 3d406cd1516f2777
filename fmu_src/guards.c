/* guards.c -- a step is refused, not returned, when its state leaves what the model can stand behind:
 * non-finite coordinates, a deflection or rotation beyond the beam model's validity (the generated
 * model_validity ratios), or a mass matrix that is no longer positive definite.  The caller discards the
 * communication step (fmi2Discard) with the message written here, before a Newton failure or a wrong
 * number can reach the importer. */
#include <math.h>
#include <stdio.h>
#include "internal.h"
#include "linalg.h"

/* A pivot of the mass matrix's Cholesky factor below this fraction of its diagonal entry counts as lost
 * definiteness: ~1e-10 is where LU solves of the Newton matrix stop carrying usable digits. */
#define MASS_MATRIX_TINY 1e-10
/* The mass matrix is a sum of squares by construction (README "Why the second-order model is consistent"):
 * positive definite at small deflections.  It is factorised only once a link deflects beyond this
 * fraction of its validity limit (5 % of its length), where a wrong state would show first; below, the
 * check would cost one Newton-matrix evaluation per communication step for nothing. */
#define MASS_MATRIX_CHECK_FROM 0.25

fmi2Status fmu_guard_state(Instance *inst, double t, const double *u, int check_mass_matrix) {
    FmuData *d = &inst->d;
    if (!fmu_all_finite(d->q, N_Q) || !fmu_all_finite(d->v, N_Q)) {
        snprintf(inst->guard_reason, sizeof(inst->guard_reason), "the state is not finite at t = %.17g", t);
        return fmi2Discard;
    }
    double largest = 0.0;
#if N_VALIDITY > 0
    model_validity(d->q, u, d->p, inst->guard_g, &inst->work);
    for (int i = 0; i < N_VALIDITY; i++) {
        largest = fmax(largest, inst->guard_g[i]);
        if (!(inst->guard_g[i] <= 1.0)) {
            snprintf(inst->guard_reason, sizeof(inst->guard_reason),
                     "at t = %.17g the state left the beam model's validity: %s = %.4g (must stay <= 1: tip "
                     "deflections up to 20 %% of a link's length, tip rotations up to 0.35 rad); lower the loads "
                     "or stiffen the link", t, MODEL_VALIDITY_NAMES[i], inst->guard_g[i]);
            return fmi2Discard;
        }
    }
#endif
    if (check_mass_matrix && d->mass_matrix_guarded && (N_VALIDITY == 0 || largest > MASS_MATRIX_CHECK_FROM)) {
        const int failed = model_newton_matrix(d->q, d->v, d->alpha, u, d->p, 1.0, 0.0, 0.0, inst->guard_M,
                                               &inst->work);
        const int k = failed ? 1 : cholesky_factor(inst->guard_M, N_Q, MASS_MATRIX_TINY);
        if (k) {
            snprintf(inst->guard_reason, sizeof(inst->guard_reason),
                     "at t = %.17g the mass matrix lost positive definiteness (Cholesky pivot %d of %d): the "
                     "deflection is beyond what the link's shape functions represent", t, k, N_Q);
            return fmi2Discard;
        }
    }
    return fmi2OK;
}

/* Whether the mass matrix is guarded at all: only when it is positive definite at the start state.  A scene
 * may have massless directions by design (a twist without polar inertia, an elastic joint without motor
 * inertia): M is then singular everywhere, SS22's step matrix stays regular, and a zero pivot is not news.
 * A constant M (linear kinematics) cannot lose definiteness. */
void fmu_guard_init(Instance *inst, const double *u) {
    FmuData *d = &inst->d;
    d->mass_matrix_guarded = 0;
    if (MODEL_JACOBIAN_CONSTANT) return;
    if (model_newton_matrix(d->q, d->v, d->alpha, u, d->p, 1.0, 0.0, 0.0, inst->guard_M, &inst->work) == 0 &&
        cholesky_factor(inst->guard_M, N_Q, MASS_MATRIX_TINY) == 0) {
        d->mass_matrix_guarded = 1;
    } else {
        fmu_log(inst, fmi2OK, LOG_EVENTS, "the mass matrix is singular at the start state (massless "
                "directions): its definiteness is not guarded");
    }
}
