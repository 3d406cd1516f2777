/* mass_update.h -- the mass update of a kept SS22 iteration matrix (ss22.h, SS22_MASS_UPDATE): internal to
 * ss22.c.  Where a model has none (SS22_MASS_UPDATE 0) these are no-ops that the compiler removes. */
#ifndef FLEXLINK_MASS_UPDATE_H
#define FLEXLINK_MASS_UPDATE_H

#include "ss22.h"

#if SS22_MASS_UPDATE
/* After a full evaluation of J into f->LU (not yet factorised) at (s->q_bar, s->v_bar, alpha): keeps J - M in
 * f->rest.  Nonzero when M failed to evaluate. */
int ss22_keep_rest(SS22 *s, SS22Factor *f, const double *alpha, const double *p, ModelWork *work);

/* Whether the matrix f, from an earlier step, has wasted what a mass update costs (ss22.h). */
int ss22_mass_update_due(const SS22 *s, const SS22Factor *f);

/* At the end of a step, at the weighted state of its last residual (s->q_bar; M depends on q alone) and its
 * solution alpha: f's matrix becomes M(s->q_bar) + f->rest,
 * factorised, made at this step (a new matrix to the next steps: its age, its rates and first ratios counted
 * and measured anew).  Anything that fails (the model, a value not finite, a zero pivot) leaves f invalid: the
 * next step evaluates a matrix in full. */
void ss22_mass_update(SS22 *s, SS22Factor *f, const double *alpha, const double *p, ModelWork *work);
#else
static inline int ss22_keep_rest(SS22 *s, SS22Factor *f, const double *alpha, const double *p, ModelWork *work) {
    (void)s, (void)f, (void)alpha, (void)p, (void)work;
    return 0;
}
static inline int ss22_mass_update_due(const SS22 *s, const SS22Factor *f) {
    (void)s, (void)f;
    return 0;
}
static inline void ss22_mass_update(SS22 *s, SS22Factor *f, const double *alpha, const double *p, ModelWork *work) {
    (void)s, (void)f, (void)alpha, (void)p, (void)work;
}
#endif

#endif
