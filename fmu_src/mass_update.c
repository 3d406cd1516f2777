/* mass_update.c -- see mass_update.h and ss22.h (SS22_MASS_UPDATE).  J = M + theta1 dt C + theta2 dt^2/2 K: a
 * full evaluation takes J from the generated M and N_Q differences of the residual (model.c's
 * model_newton_matrix), the update a new M alone: on the chains about one residual, and an LU. */
#include <math.h>
#include "linalg.h"
#include "mass_update.h"

#if SS22_MASS_UPDATE
static int all_finite(const double *x, int n) {
    for (int i = 0; i < n; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

int ss22_keep_rest(SS22 *s, SS22Factor *f, const double *alpha, const double *p, ModelWork *work) {
    if (model_newton_matrix(s->q_bar, s->v_bar, alpha, s->u_bar, p, 1.0, 0.0, 0.0, f->rest, work)) return 1;
    for (int k = 0; k < N_Q * N_Q; k++) f->rest[k] = f->LU[k] - f->rest[k];
    return 0;
}

/* What the matrix wasted pays for a new M and its LU (CONSISTENT_REFRESH_COST, config.h: in residuals, about an
 * iteration each; at least one), and it is not one the recurrence start may use (ss22.h,
 * SS22_RECURRENCE_MAX_RATE): a matrix measured to contract at 1e-3 or faster gains three digits an iteration,
 * and what it wastes is the start's distance, not its age.  Updated whenever it wasted (on an earlier variant,
 * docs/integrator.md), planar_chain_3 at its recommended step under the bench manoeuvre never kept a matrix the
 * SS22_RECURRENCE_COST steps its recurrence start waits for: 1.66 -> 2.37 iterations a step; with this gate
 * 1.30. */
int ss22_mass_update_due(const SS22 *s, const SS22Factor *f) {
    return f->made != s->steps && f->waste >= fmax(1.0, CONSISTENT_REFRESH_COST) &&
           !(f->rate >= 0.0 && f->rate <= SS22_RECURRENCE_MAX_RATE);
}

/* A failed update leaves its entry invalid and first in line for the next evaluation (stamp 0: the least
 * recently used, ss22.c's step_matrix), so that no valid entry of another step size is replaced for it. */
static void failed(SS22Factor *f) {
    f->valid = 0;
    f->stamp = 0;
}

void ss22_mass_update(SS22 *s, SS22Factor *f, const double *alpha, const double *p, ModelWork *work) {
    if (model_newton_matrix(s->q_bar, s->v_bar, alpha, s->u_bar, p, 1.0, 0.0, 0.0, f->LU, work)) {
        failed(f);
        return;
    }
    for (int k = 0; k < N_Q * N_Q; k++) f->LU[k] += f->rest[k];
    s->mass_updates++;        /* as ss22.c counts a factorisation: before the checks of its matrix */
    if (!all_finite(f->LU, N_Q * N_Q) || lu_factor(f->LU, N_Q, f->piv)) {
        failed(f);
        return;
    }
    /* made at this step, as a full evaluation at its last iterate would be: an older matrix from the next step
     * on, its first ratios measured from its age one and grown with the age (ss22.c, one_increment_rate).  Taken
     * at a step's start instead, the six-axis arm's 4 s audit had 567 of 8000 steps beyond the tolerance (worst
     * 46.5) when its first ratios were judged at the full evaluation's age, and 1248 (worst 46.4) when at age
     * one: a first ratio measured in the step the M part was made in says nothing of how it grows. */
    f->made = s->steps;
    f->waste = 0.0;
    f->rate = -1.0;
    f->estimated = f->confirmed = f->confirmed_first = 0;
    for (int k = 0; k < 3; k++) f->first[k] = -1.0, f->first_age[k] = 0;
}
#else
typedef int flexlink_mass_update_unused;    /* ISO C: a translation unit declares something */
#endif
