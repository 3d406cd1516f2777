/* predictor.h -- where SS22's Newton iteration starts (predictor.c): the line or the parabola through the last
 * steps' accelerations, or the scheme's own linear recurrence.  Internal to ss22.c. */
#ifndef FLEXLINK_PREDICTOR_H
#define FLEXLINK_PREDICTOR_H

#include "ss22.h"

/* The line (returns 1) or, every step while it leads the vote and every SS22_PREDICTOR_PROBE-th otherwise, also
 * the parabola (returns 2; the one that does not start is left in other) through the accelerations this solver
 * returned last; 0 when alpha is not the last one it returned (no history to extrapolate). */
int ss22_predict(const SS22 *s, double dt, const double *alpha, double *a, double *other);

/* After a step started from one of the two (start) with the other at hand: the running vote between them. */
void ss22_choose_predictor(SS22 *s, const double *a, const double *start, const double *other);

/* Whether the recurrence can predict the next step of dt from alpha: two consecutive steps of the same size
 * behind it, their weighted inputs, and no built-in law moving over the three (the inputs' term, U times their
 * second difference, follows a host's input that changes at every communication point; a law has no column). */
int ss22_recurrence_applies(const SS22 *s, double dt, const double *alpha);

/* Whether to form the recurrence's matrices now with the kept matrix f of the step dt: once f has been kept for
 * SS22_RECURRENCE_COST steps (rent-or-buy, ss22.h), if none is formed for dt, or if f is newer than the one it
 * was formed with and its misses have grown SS22_RECURRENCE_GROWTH-fold since its first steps. */
int ss22_recurrence_due(const SS22 *s, const SS22Factor *f, double dt);

/* Forms them from f's factors, the model's velocity and position Jacobians at the weighted state (s->q_bar,
 * s->v_bar, alpha, s->u_bar), evaluated by model_newton_matrix, and its input columns (residual differences).
 * Anything but SS22_OK leaves the recurrence unformed until a newer matrix (a start is only a start: the step
 * goes on without it). */
SS22Status ss22_recurrence_form(SS22 *s, const SS22Factor *f, double dt, const double *alpha, const double *p,
                                ModelWork *work);

/* The recurrence's start for a step of dt, its own recent misses fed back, into s->rec.start; returns 0 when it
 * is not formed for dt, 1 when the vote keeps the line or parabola in a, 2 when it replaced a (the line or
 * parabola kept in s->rec.other for the vote). */
int ss22_recurrence_predict(SS22 *s, double dt, const double *alpha, double *a);

/* The size, in the Newton increments' measure (ss22.c: |delta| dt / nominal), below which the recurrence's first
 * increment is noise: a hundredth of the tolerance, or SS22_ROUNDING_FACTOR roundings of the largest acceleration
 * in that measure, of the start and of the last two steps' (the size of its products), whichever is larger.  Such
 * an increment ends the step, and a ratio to it is no rate.  The second matters where accelerations are huge
 * against the nominal rates: the test model's unresolved w dt = 10 mode leaves first increments of 3e-12 at the
 * tolerance 1e-10, whose ratios had raised the kept rate past the rate floor and kept the recurrence out. */
double ss22_recurrence_floor(const SS22 *s, double dt, const double *start);

/* J^-1 of the kept matrix f where the recurrence was formed with f (the same evaluation: its made and step size),
 * else NULL.  Formed with P and G (N_Q more solves against the recurrence's 2 (N_Q + 1) residuals), it turns the
 * Newton increment's solve into a product: 0.14 us against lu_solve's 0.53 on the 32-mode link's 33 unknowns,
 * whose steps take one increment each.  The product is not lu_solve's bits: both are the increment to rounding
 * (the inverse's columns are lu_solve's own solves), and Newton's next residual sees the iterate either gives. */
const double *ss22_recurrence_inverse(const SS22 *s, const SS22Factor *f);

/* The Newton increment delta = -J^-1 r with the kept matrix f: the product with its inverse where the recurrence
 * holds it, else f's LU solve. */
void ss22_increment(const SS22 *s, const SS22Factor *f, const double *r, double *delta);

/* After an accepted step of acceleration a: the recurrence's misses and vote (predicted: it was formed and
 * predicted this step), and the weighted inputs' history (continued: the step extrapolated this solver's own
 * history, as the line's depth counts). */
void ss22_recurrence_after_step(SS22 *s, const double *a, int predicted, int continued);

#endif
