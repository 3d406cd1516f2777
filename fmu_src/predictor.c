/* predictor.c -- where SS22's Newton iteration starts (see predictor.h): an extrapolation of the accelerations
 * the solver returned (the line, the parabola), or the scheme's own linear recurrence (ss22.h, SS22Recurrence).
 * The nearer the start, the fewer iterations: a step whose first increment is small enough stops after it
 * (ss22.c), so the start decides between one residual a step and two or three. */
#include <float.h>
#include <math.h>
#include <string.h>
#include "linalg.h"
#include "pairs.h"
#include "predictor.h"

static int finite_all(const double *x, int n) {
    for (int i = 0; i < n; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

/* the largest miss of x against the solution a, in the coordinates' nominal scales */
static double miss(const double *a, const double *x) {
    double m = 0.0;
    for (int i = 0; i < N_Q; i++) {
        const double e = fabs(a[i] - x[i]) / MODEL_NOMINAL_Q[i];
        m = e > m ? e : m;              /* not fmax: a library call in this loop (the values are finite) */
    }
    return m;
}

/* The Newton iteration's start: the caller's acceleration alpha, moved along the line through the last two
 * steps' (constant) accelerations, each taken at its step's middle; returns whether it did.  Only when alpha
 * is the one this solver returned last: the order-4 option's re-step from the start of a step and the
 * sub-steps after a failed step start from the given alpha.  (An FMU state carries the history with it: a
 * restored state continues exactly as the original did.)
 * After three consecutive steps the parabola through their accelerations is formed too (into parabola; it
 * returns 2: every step while it leads, every SS22_PREDICTOR_PROBE-th while the line does, so that a chain
 * whose line leads pays little for the comparison), and starts the iteration while it has missed the steps'
 * solutions by less than the line (a running vote: s->parabola, set by ss22_choose_predictor).  Where the motion
 * is smooth and resolved it is the better extrapolation (fewer increments, and a kept matrix's age costs
 * less); where a step leaves modes unresolved they ring near its Nyquist frequency, which the parabola's
 * weights 3, -3, 1 amplify more than the line's 2, -1: the line keeps those (docs/integrator.md). */
int ss22_predict(const SS22 *s, double dt, const double *alpha, double *a, double *parabola) {
    if (s->depth == 0 || memcmp(alpha, s->alpha_last, sizeof(double) * N_Q) != 0) return 0;
    const double ratio = (dt + s->dt_last) / (s->dt_last + s->dt_before);
    for (int i = 0; i < N_Q; i++) a[i] = alpha[i] + ratio * (alpha[i] - s->alpha_before[i]);
    if (s->depth < 3 || (!s->parabola && s->steps % SS22_PREDICTOR_PROBE != 0)) return 1;
    /* Lagrange's parabola through the step middles tl = 0, tb, to, at the next step's middle tn */
    const double tb = -0.5 * (s->dt_last + s->dt_before), to = tb - 0.5 * (s->dt_before + s->dt_older);
    const double tn = 0.5 * (s->dt_last + dt);
    const double wl = (tn - tb) * (tn - to) / (tb * to), wb = tn * (tn - to) / (tb * (tb - to));
    const double wo = tn * (tn - tb) / (to * (to - tb));
    for (int i = 0; i < N_Q; i++) parabola[i] = wl * alpha[i] + wb * s->alpha_before[i] + wo * s->alpha_older[i];
    if (!finite_all(parabola, N_Q)) return 1;
    if (s->parabola) {
        double line[N_Q];
        memcpy(line, a, sizeof(line));
        memcpy(a, parabola, sizeof(line));
        memcpy(parabola, line, sizeof(line));      /* the other one, for ss22_choose_predictor */
    }
    return 2;
}

/* After a step started from one of two predictions (start) with the other one at hand (other): the parabola
 * starts the next steps while it has missed the solutions by less than the line more often than not, over
 * about the last SS22_PREDICTOR_MEMORY steps (s->predictor_bias, a running mean of +1 for the line's wins and
 * -1 for the parabola's; < 0: the parabola).  One step's comparison is noise where modes ring unresolved
 * (planar_chain_5: choosing on the last step alone made the start 1.54e-3 off on average, worse than the
 * line's 1.24e-3). */
void ss22_choose_predictor(SS22 *s, const double *a, const double *start, const double *other) {
    const double miss_start = miss(a, start), miss_other = miss(a, other);
    const int parabola_won = s->parabola ? miss_start < miss_other : miss_other < miss_start;
    s->predictor_bias += ((parabola_won ? -1.0 : 1.0) - s->predictor_bias) / SS22_PREDICTOR_MEMORY;
    s->parabola = s->predictor_bias < 0.0;
}

/* ---- the recurrence start (ss22.h, SS22Recurrence) ----
 * Why: where a step leaves modes unresolved (a reduced FE link's upper modes, a chain's third modes at the
 * recommended step) they ring from step to step and no extrapolation of the history follows them: the line
 * starts 10^6 tolerances off (32-mode link at 0.1 ms: 5.3e6 median), so every step takes a second residual
 * to confirm its first increment.  Those modes are nearly linear, and SS22's linear recurrence follows them
 * exactly; what the nonlinear model adds (the chain turning, gravity) is smooth in time, so the recurrence's
 * own misses extrapolate (docs/integrator.md: 32-mode link 0.56 tolerances, 3-link chain at its recommended
 * step 81, median). */

static int same_step(double a, double b) {
    return fabs(a - b) <= 1e-9 * b;     /* steps from differences of absolute times differ in the last bits */
}

/* Whether input k is a slot of a built-in law (its position, rate or acceleration), not a host's input. */
static int law_slot(int k) {
#if N_LAWS > 0
    for (int l = 0; l < N_LAWS; l++) if (k >= MODEL_LAWS[l].u_offset && k < MODEL_LAWS[l].u_offset + 3) return 1;
#endif
    (void)k;
    return 0;
}

/* The second difference of weighted input k over this step and the last two (u_depth >= 2). */
static double input_bend(const SS22 *s, int k) {
    return s->u_bar[k] - 2.0 * s->rec.u_last[k] + s->rec.u_before[k];
}

int ss22_recurrence_applies(const SS22 *s, double dt, const double *alpha) {
    const SS22Recurrence *r = &s->rec;
    if (s->depth < 2 || r->u_depth < 2 || memcmp(alpha, s->alpha_last, sizeof(double) * N_Q) != 0) return 0;
    if (!same_step(s->dt_last, dt) || !same_step(s->dt_before, dt)) return 0;
    for (int k = 0; k < N_U; k++) if (law_slot(k) && input_bend(s, k) != 0.0) return 0;   /* (no U column, below) */
    return 1;
}

int ss22_recurrence_due(const SS22 *s, const SS22Factor *f, double dt) {
    const SS22Recurrence *r = &s->rec;
    if (s->steps - f->made < (uint64_t)SS22_RECURRENCE_COST || r->made == f->made + 1) return 0;
    if (!(r->valid && same_step(r->dt, dt))) return 1;
    /* a newer matrix than it was formed with, once its misses have grown SS22_RECURRENCE_GROWTH-fold over its
     * first steps' (the chain has turned away from where it was formed) */
    return f->made + 1 > r->made && r->judged >= SS22_RECURRENCE_FRESH &&
           r->log_miss > r->log_fresh + log2(SS22_RECURRENCE_GROWTH);
}

/* B = dr/du at the weighted state for the host's inputs (a law's columns are zero: the recurrence waits while a
 * law moves), column k by the central difference of the residual in input k: exact to rounding where the
 * residual is affine in it (a joint's torque), second-order accurate where it is not, which the misses fed back
 * absorb as they do the rest of the nonlinear model.  Non-zero if the model failed.
 * (Laws moving: the six-axis arm at the tolerance 1e-8 had 541 of 8000 steps beyond it, the worst 5.1, with the
 * recurrence started while its laws moved; a law's angle enters through the kinematics, and its second
 * difference is never zero, so its misses are never fed back, below.) */
static int input_columns(const SS22 *s, const double *alpha, const double *p, ModelWork *work, double *B) {
    double u[N_U > 0 ? N_U : 1], plus[N_Q], minus[N_Q];
    memcpy(u, s->u_bar, sizeof(u));
    memset(B, 0, sizeof(double) * N_Q * N_U);
    for (int k = 0; k < N_U; k++) {
        if (law_slot(k)) continue;
        const double h = SS22_INPUT_DIFFERENCE * fmax(1.0, fabs(u[k]));
        u[k] = s->u_bar[k] + h;
        if (model_residual(s->q_bar, s->v_bar, alpha, u, p, plus, work)) return 1;
        u[k] = s->u_bar[k] - h;
        if (model_residual(s->q_bar, s->v_bar, alpha, u, p, minus, work)) return 1;
        u[k] = s->u_bar[k];
        for (int i = 0; i < N_Q; i++) B[(size_t)k * N_Q + i] = (plus[i] - minus[i]) / (2.0 * h);
    }
    return 0;
}

SS22Status ss22_recurrence_form(SS22 *s, const SS22Factor *f, double dt, const double *alpha, const double *p,
                                ModelWork *work) {
    SS22Recurrence *r = &s->rec;
    double *P = r->P, *G = r->G;
    r->valid = 0;
    r->made = f->made + 1;
    r->depth = 0;                       /* the misses of other matrices say nothing of these */
    r->judged = 0;
    if (model_newton_matrix(s->q_bar, s->v_bar, alpha, s->u_bar, p, 0.0, 1.0, 0.0, P, work) ||
        model_newton_matrix(s->q_bar, s->v_bar, alpha, s->u_bar, p, 0.0, 0.0, 1.0, G, work)) {
        return SS22_MODEL_FAILED;
    }
    if (input_columns(s, alpha, p, work, r->U)) return SS22_MODEL_FAILED;
    for (int j = 0; j < N_Q; j++) {
        lu_solve(f->LU, N_Q, f->piv, P + (size_t)j * N_Q);
        lu_solve(f->LU, N_Q, f->piv, G + (size_t)j * N_Q);
    }
    for (int k = 0; k < N_U; k++) lu_solve(f->LU, N_Q, f->piv, r->U + (size_t)k * N_Q);
    memset(r->inverse, 0, sizeof(r->inverse));
    for (int j = 0; j < N_Q; j++) {
        r->inverse[(size_t)j * N_Q + j] = 1.0;
        lu_solve(f->LU, N_Q, f->piv, r->inverse + (size_t)j * N_Q);
    }
    const double c = 0.5 + s->theta1;
    for (int k = 0; k < N_Q * N_Q; k++) {
        G[k] *= dt * dt;
        P[k] = dt * P[k] + c * G[k];
    }
    if (!finite_all(P, N_Q * N_Q) || !finite_all(G, N_Q * N_Q) || !finite_all(r->U, N_Q * N_U) ||
        !finite_all(r->inverse, N_Q * N_Q))
        return SS22_NOT_FINITE;
    r->valid = 1;
    r->dt = dt;
    return SS22_OK;
}

/* Its misses of the last steps extrapolated to the next: held (order 0 is none), along the line through the last
 * two (1), along the parabola through the last three (2).  Where they come from smooth nonlinear forces the higher
 * orders follow them (planar_chain_3 at its recommended step: 1200, 81, 24 tolerances, medians); where they are
 * the Newton error's noise (the 32-mode link: 0.56, 1.35, 2.3) they amplify it.  So each order's misses are kept
 * as a running mean of their logarithms and the least one is used (ss22_recurrence_after_step). */
static double fed_back(const SS22Recurrence *r, int order, int i) {
    const double *m = r->misses;
    switch (order) {
    case 1: return 2.0 * m[i] - m[N_Q + i];
    case 2: return 3.0 * m[i] - 3.0 * m[N_Q + i] + m[2 * N_Q + i];
    default: return 0.0;
    }
}

/* the larger of two numbers that are not NaN: fmax without its NaN rule, which gcc leaves to a call of libm's */
static double larger(double a, double b) { return a > b ? a : b; }

double ss22_recurrence_floor(const SS22 *s, double dt, const double *start) {
    double scale = 0.0;
    for (int i = 0; i < N_Q; i++) {     /* the start, and the accelerations it was formed from (its products' size);
                                           all finite: the start is checked, the others were accepted */
        const double largest = larger(fabs(start[i]), larger(fabs(s->alpha_last[i]), fabs(s->alpha_before[i])));
        scale = larger(scale, largest * dt / MODEL_NOMINAL_Q[i]);
    }
    return fmax(s->tolerance / SS22_ROUNDING_FACTOR, SS22_ROUNDING_FACTOR * DBL_EPSILON * scale);
}

int ss22_recurrence_predict(SS22 *s, double dt, const double *alpha, double *a) {
    SS22Recurrence *r = &s->rec;
    if (!r->valid || !same_step(r->dt, dt)) return 0;
    const double *before = s->alpha_before;
    double d[N_Q];
    for (int i = 0; i < N_Q; i++) {
        r->raw[i] = 2.0 * alpha[i] - before[i];
        d[i] = alpha[i] - before[i];
    }
    linalg_subtract_products(r->raw, r->P, d, r->G, before, N_Q);     /* - P d - G a- */
    for (int k = 0; k < N_U; k++) {                     /* - U (u+ - 2u + u-): nothing for held inputs */
        const double d2u = input_bend(s, k);
        const double *Uk = r->U + (size_t)k * N_Q;
        if (d2u != 0.0) linalg_subtract_scaled(r->raw, Uk, d2u, N_Q);
    }
    int order = r->order;
    while (order > 0 && r->depth < order + 1) order--;     /* an order k needs k + 1 misses */
    for (int i = 0; i < N_Q; i++) r->start[i] = r->raw[i] + fed_back(r, order, i);
    if (!finite_all(r->start, N_Q)) return 0;
    memcpy(r->other, a, sizeof(r->other));
    if (r->bias < 0.0) return 1;
    memcpy(a, r->start, sizeof(r->start));
    return 2;
}

const double *ss22_recurrence_inverse(const SS22 *s, const SS22Factor *f) {
    const SS22Recurrence *r = &s->rec;
    return r->valid && r->made == f->made + 1 && same_step(r->dt, f->dt) ? r->inverse : NULL;
}

void ss22_increment(const SS22 *s, const SS22Factor *f, const double *r, double *delta) {
    const double *inverse = ss22_recurrence_inverse(s, f);
    if (inverse != NULL) {
        memset(delta, 0, sizeof(double) * N_Q);
        linalg_subtract_products(delta, inverse, r, NULL, NULL, N_Q);
        return;
    }
    for (int i = 0; i < N_Q; i++) delta[i] = -r[i];
    lu_solve(f->LU, N_Q, f->piv, delta);
}

/* Whether the weighted inputs bent at this step: a host's new input at a communication point, in the two steps
 * that follow it */
static int inputs_bent(const SS22 *s) {
    for (int k = 0; k < N_U; k++) if (input_bend(s, k) != 0.0) return 1;
    return 0;
}

void ss22_recurrence_after_step(SS22 *s, const double *a, int predicted, int continued) {
    SS22Recurrence *r = &s->rec;
    const double missed = predicted ? miss(a, r->start) : 0.0;
    if (predicted) r->bias += ((missed < miss(a, r->other) ? 1.0 : -1.0) - r->bias) / SS22_PREDICTOR_MEMORY;
    if (predicted && !inputs_bent(s)) {
        for (int k = 0; k <= SS22_RECURRENCE_ORDER && (k == 0 || k < r->depth); k++) {   /* each order's miss */
            double worst = 0.0;
            for (int i = 0; i < N_Q; i++) {
                const double e = fabs(a[i] - r->raw[i] - fed_back(r, k, i)) / MODEL_NOMINAL_Q[i];
                worst = e > worst ? e : worst;
            }
            r->order_score[k] += (log2(fmax(worst, 1e-300)) - r->order_score[k]) / SS22_PREDICTOR_MEMORY;
        }
        r->order = 0;
        for (int k = 1; k <= SS22_RECURRENCE_ORDER; k++) if (r->order_score[k] < r->order_score[r->order]) r->order = k;
        memmove(r->misses + N_Q, r->misses, sizeof(double) * N_Q * SS22_RECURRENCE_ORDER);
        for (int i = 0; i < N_Q; i++) r->misses[i] = a[i] - r->raw[i];
        r->depth = r->depth <= SS22_RECURRENCE_ORDER ? r->depth + 1 : SS22_RECURRENCE_ORDER + 1;
        const double logged = log2(fmax(missed, 1e-300));
        if (r->judged < SS22_RECURRENCE_FRESH) {        /* its first steps' misses: the mean of their logs */
            r->judged++;
            r->log_fresh += (logged - r->log_fresh) / r->judged;
            r->log_miss = r->log_fresh;
        } else {
            r->log_miss += (logged - r->log_miss) / SS22_PREDICTOR_MEMORY;
        }
    } else {
        /* no misses of its own, or those of a step whose inputs bent: U's error (the kept matrix's age times the
         * inputs' jump: planar_chain_3 under a sampled PD, 1e3 times a smooth step's) is no trend to extrapolate,
         * nor a measure of how far the model has turned since the recurrence was formed */
        r->depth = 0;
    }
    if (continued) {
        memcpy(r->u_before, r->u_last, sizeof(r->u_last));
        r->u_depth = r->u_depth < 2 ? r->u_depth + 1 : 2;
    } else {
        r->u_depth = 1;
    }
    memcpy(r->u_last, s->u_bar, sizeof(r->u_last));
}
