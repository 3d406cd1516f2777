/* ss22.c -- see ss22.h. */
#include <math.h>
#include <string.h>
#include "linalg.h"
#include "mass_update.h"
#include "predictor.h"

void ss22_init(SS22 *s, double theta1, double theta2, double tolerance) {
    memset(s, 0, sizeof(*s));
    s->theta1 = theta1;
    s->theta2 = theta2;
    s->tolerance = tolerance;
    s->max_iterations = SS22_MAX_ITERATIONS;
}

void ss22_invalidate(SS22 *s) {
    for (int k = 0; k < SS22_CACHE; k++) s->cache[k].valid = 0;
    memset(&s->rec, 0, sizeof(s->rec));     /* its C and K, its misses and votes were the old parameters' */
}

const char *ss22_status_message(SS22Status status) {
    static const char *const words[] = {"ok", "the Newton iteration of the SS22 step did not converge",
        "the SS22 step produced a NaN or an infinite value", "the SS22 step matrix is singular",
        "the generated model failed to evaluate"};
    return (unsigned)status < sizeof(words) / sizeof(words[0]) ? words[status] : "unknown SS22 status";
}

void ss22_weighted_inputs(const SS22 *s, double dt, const double *u0, const double *u1, double *u_bar) {
    const double t1 = s->theta1;
    for (int i = 0; i < N_U; i++) u_bar[i] = t1 * u1[i] + (1.0 - t1) * u0[i];
#if N_LAWS > 0
    const double t2 = s->theta2;
    for (int k = 0; k < N_LAWS; k++) {
        const int o = MODEL_LAWS[k].u_offset;
        const double x0 = u0[o], xd0 = u0[o + 1], x1 = u1[o], xd1 = u1[o + 1];
        const double abar = (xd1 - xd0) / dt;
        /* the weighted angle as SS22 weights a coordinate, plus Θ2 times what the trapezoid of the rates
         * misses of the exact end angle: (x0 + x1)/2 for Θ = ½ (symmetric in time, as Richardson's
         * extrapolation needs: without it order 4 falls to 3 with a jerky law), x1 for Θ1 = Θ2 = 1 */
        u_bar[o] = x0 + t1 * dt * xd0 + t2 * 0.5 * dt * dt * abar + t2 * (x1 - x0 - 0.5 * dt * (xd0 + xd1));
        u_bar[o + 1] = xd0 + t1 * dt * abar;
        u_bar[o + 2] = abar;
    }
#else
    (void)dt;
#endif
}

static int all_finite(const double *x, int n) {
    for (int i = 0; i < n; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

/* The cache entry of (dt, theta), or NULL.  There is at most one: a refreshed matrix replaces the entry of its
 * own step size (below), so simplified Newton always continues from the newest matrix.  dt comes from differences
 * of absolute times: equal steps differ by their rounding (1e-9 of 0.1 ms at t = 1000 s; 1e-12 split them: one
 * rate went stale, fast_two_link under a sampled PD).  Newton's iterates end at the step's own solution from a
 * matrix 1e-6 off; a linear model's one solve needs its own matrix. */
static SS22Factor *cached_factor(SS22 *s, double dt) {
    const double window = (MODEL_LINEAR_IN_STATE ? 1e-12 : 1e-6) * dt;
    for (int k = 0; k < SS22_CACHE; k++) {
        SS22Factor *c = &s->cache[k];
        if (c->valid && fabs(c->dt - dt) <= window && c->theta1 == s->theta1 && c->theta2 == s->theta2) return c;
    }
    return NULL;
}

/* Steps accepted on f's kept rate before one more iteration measures it again: SS22_RATE_MEASURE_EVERY, doubled
 * for each measure in a row that found the rate held (ss22.h).  For a one-increment stop (first) also the
 * measures of the first ratio that held (confirmed_first) count; they never lengthen the interval of the
 * two-increment stops, which only a third increment measures. */
static int measure_interval_of(const SS22Factor *f, int first) {
    const int held = first && f->confirmed_first > f->confirmed ? f->confirmed_first : f->confirmed;
    return SS22_RATE_MEASURE_EVERY << held;
}

/* The factorised step matrix for (dt, theta): from the cache when the model's Newton matrix is
 * constant or when simplified Newton reuses the latest one (reuse), else evaluated at the current
 * iterate into the entry of this step size (or the least recently used one). */
static SS22Status step_matrix(SS22 *s, double dt, const double *alpha, const double *p, ModelWork *work,
                              int reuse, SS22Factor **out) {
    const double cv = s->theta1 * dt, cq = s->theta2 * 0.5 * dt * dt;
    SS22Factor *f = cached_factor(s, dt);
#if MODEL_JACOBIAN_CONSTANT
    reuse = 1;
#endif
    if (reuse && f != NULL) {
        /* its rate ages by the steps taken with other matrices since its last use, up to a measure's being due
         * (the longest interval: what an FMU state may hold, fmu_state.c) */
        f->estimated = (int)fmin((double)f->estimated + (double)(s->clock - f->stamp), measure_interval_of(f, 1));
        f->stamp = ++s->clock;
        *out = f;
        return SS22_OK;
    }
    if (f == NULL) {                                    /* replace the least recently used */
        f = &s->cache[0];
        for (int k = 1; k < SS22_CACHE; k++) if (s->cache[k].stamp < f->stamp) f = &s->cache[k];
    }
    if (model_newton_matrix(s->q_bar, s->v_bar, alpha, s->u_bar, p, 1.0, cv, cq, f->LU, work) ||
        ss22_keep_rest(s, f, alpha, p, work)) {
        f->valid = 0;
        return SS22_MODEL_FAILED;
    }
    s->factorisations++;
    f->rate = -1.0; f->waste = f->waste_full = 0.0;
    f->estimated = f->confirmed = f->confirmed_first = 0;
    f->made = s->steps; for (int k = 0; k < 3; k++) f->first[k] = -1.0, f->first_age[k] = 0;
    if (!all_finite(f->LU, N_Q * N_Q)) { f->valid = 0; return SS22_NOT_FINITE; }
    if (lu_factor(f->LU, N_Q, f->piv)) { f->valid = 0; return SS22_SINGULAR; }
    f->dt = dt; f->theta1 = s->theta1; f->theta2 = s->theta2; f->valid = 1; f->stamp = ++s->clock;
    *out = f;
    return SS22_OK;
}

static void weighted_state(SS22 *s, double dt, const double *q, const double *v, const double *alpha) {
    const double cv = s->theta1 * dt, cq = s->theta2 * 0.5 * dt * dt;
    for (int i = 0; i < N_Q; i++) {
        s->q_bar[i] = q[i] + cv * v[i] + cq * alpha[i];
        s->v_bar[i] = v[i] + cv * alpha[i];
    }
}

#if !MODEL_LINEAR_IN_STATE
/* The rate a step is accepted on without measuring it, from the kept or seen one: at least SS22_RATE_FLOOR,
 * raised once to the power 0.8 (ss22.h). */
static double aged_rate(double rate) {
    return pow(fmax(rate, SS22_RATE_FLOOR), 0.8);
}

/* The kept contraction rate of a matrix from an earlier step, given the ratio of two successive increments
 * (rate) and whether it is one that only raises the kept rate (raise_only).  A ratio of increments is not a
 * rate: with an old matrix it alternates between small and large from one increment to the next, and a ratio
 * to an increment at the rounding floor is noise; judged on the latest ratio, steps were accepted up to 1e5
 * tolerances off (docs/integrator.md).  So the kept rate rises to any larger ratio and falls by at most
 * SS22_RATE_DECAY a ratio (CVODE's crate = max(0.3 crate, ratio)); a step's first ratio (mostly the stiff
 * linear part, which any matrix of the step size solves: fast_two_link, a matrix 5000 steps old, 0.009 then
 * 0.18, 0.18, 0.18) and a ratio to an increment already below the tolerance only raise it. */
static double record_rate(SS22Factor *f, double rate, int raise_only) {
    if (f->rate < 0.0) f->rate = rate;
    else f->rate = fmax(rate, raise_only ? f->rate : SS22_RATE_DECAY * f->rate);
    f->estimated = 0;
    return f->rate;
}

/* A measure of a matrix from an earlier step against the rate the steps since the last one were accepted on
 * (bound): within it, the measures in a row that held (*confirmed) grow; beyond, they start again, unless the
 * ratio's denominator is within SS22_ROUNDING_FACTOR tolerances (noisy: it confirms but does not undo). */
static void confirm(int *confirmed, double ratio, double bound, double denominator, double tolerance) {
    if (ratio <= bound) {
        if (*confirmed < SS22_RATE_CONFIRMATIONS) (*confirmed)++;
    } else if (denominator > SS22_ROUNDING_FACTOR * tolerance) {
        *confirmed = 0;
    }
}

/* A step's third increment measures the kept rate (aged_rate of it: what two-increment stops are accepted on),
 * once a step; called before the rate is recorded.  Such ratios to a second increment near the rounding floor
 * only raise the kept rate. */
static void confirm_rate(SS22Factor *f, double rate, double second, double tolerance) {
    confirm(&f->confirmed, rate, f->rate >= 0.0 ? aged_rate(f->rate) : -1.0, second, tolerance);
}

/* What a step's own ratios of increments say of the next one: within a step an older matrix's ratios rise
 * towards its slowest contraction, so the next ratio is taken as at least the last one before this and, where
 * they rise, as rising twice more by the same factor (extrapolate: only on an increment above
 * SS22_ROUNDING_FACTOR tolerances, where its ratio is not rounding noise).  What is needed, not a bound
 * (planar_chain_5 at 1 ms: 11 of 2000 steps beyond on the last ratio alone, none so; docs/integrator.md). */
static double in_step_rate(double rate, double before, int extrapolate) {
    if (before <= 0.0) return 0.0;
    return rate > before && extrapolate ? rate * (rate / before) * (rate / before) : before;
}

/* Whether an increment err below the tolerance bounds what is left: with a matrix from an earlier step (judged),
 * only if its ratio to the step's previous increment (aged_rate; not when that one was SS22_ROUNDING_FACTOR below
 * the tolerance: noise) leaves rate/(1-rate) times err within it.  Six-axis arm, 4 s at 1e-8: 450 of 8000 steps
 * beyond without this and margin 3, 531 with the margin alone, 383 with this alone (docs/integrator.md). */
static int bounds_error(const SS22 *s, double err, double previous, int judged) {
    if (!judged || previous <= s->tolerance / SS22_ROUNDING_FACTOR) return 1;
    const double rate = aged_rate(err / previous);
    return rate < 1.0 && rate / (1.0 - rate) * err <= s->tolerance;
}

/* What one increment with f leaves of this step's error, per unit of that increment: its last first ratio of
 * increments grown to this step's age (or its kept rate, if larger), times SS22_DIRECTION_MARGIN (ss22.h).  The
 * first ratio says how much of the predictor's error the old matrix misses, and so how much it leaves after
 * one increment (the kept rate, which later ratios lower, says how fast it contracts after that).  It misses
 * the change of J since it was made, which in a smooth motion grows in proportion to the time since: on the
 * six-axis arm the first ratio is 3.1e-3 at age 1, 0.019 at 6, 0.026 at 8 (its ratio to the age 0.012 +-
 * 0.002 over the first 0.25 s, benchmarks/newton_trace.py), and a rate measured at age 1 accepted the steps of
 * ages 2-5 after one increment up to 2 tolerances off (benchmarks/step_audit.py).  A ratio measured in the
 * matrix's own step says nothing of its growth: no one-increment stop before one is measured at age >= 1.
 * slot: the start's kind, judged on its own first ratios: 0 the line or parabola, 1 the recurrence (predictor.c),
 * 2 a corrected start (ss22.h); the recurrence leaves the errors the old matrix misses most (six_axis_arm_torque
 * at 0.5 ms under 5 N m: 110 of 2000 steps beyond their tolerance, the worst 4.97, judged on the line's). */
static double one_increment_rate(const SS22 *s, const SS22Factor *f, int slot) {
    if (f->first[slot] < 0.0 || f->first_age[slot] == 0) return INFINITY;
    const double grown = f->first[slot] * fmax(1.0, (double)(s->steps - f->made) / (double)f->first_age[slot]);
    return SS22_DIRECTION_MARGIN * fmax(f->rate, grown);
}
#endif

#if !MODEL_LINEAR_IN_STATE
/* The recurrence's start (predictor.c), formed first when due: 0 none, 1 the vote keeps the line, 2 it starts. */
static int recurrence_start(SS22 *s, double dt, const double *q, const double *v, const double *alpha,
                            const double *p, ModelWork *work, double *a) {
    const SS22Factor *f = cached_factor(s, dt);
    /* only on a matrix measured to contract fast: from a start this close the ratios see no other (ss22.h) */
    if (f == NULL || !(f->rate >= 0.0 && f->rate <= SS22_RECURRENCE_MAX_RATE) ||
        !ss22_recurrence_applies(s, dt, alpha)) return 0;
    if (ss22_recurrence_due(s, f, dt)) {
        weighted_state(s, dt, q, v, alpha);
        if (ss22_recurrence_form(s, f, dt, alpha, p, work) == SS22_OK) s->recurrences++;
    }
    return ss22_recurrence_predict(s, dt, alpha, a);
}
#endif

SS22Status ss22_step(SS22 *s, double dt, double *q, double *v, double *alpha,
                     const double *u0, const double *u1, const double *p, ModelWork *work) {
    return ss22_step_from(s, dt, q, v, alpha, NULL, 0, u0, u1, p, work);
}

SS22Status ss22_step_from(SS22 *s, double dt, double *q, double *v, double *alpha, const double *start,
                          int corrected, const double *u0, const double *u1, const double *p, ModelWork *work) {
    double a[N_Q];
    SS22Factor *f = NULL;
    SS22Status st;
    int predicted = 0, recurrence = 0;

    ss22_weighted_inputs(s, dt, u0, u1, s->u_bar);
    memcpy(a, alpha, sizeof(a));
#if MODEL_LINEAR_IN_STATE
    (void)start, (void)corrected, (void)recurrence;
    /* r is affine in (q, v, a): r(alpha) = r(0) + J alpha, one solve, no iteration. */
    memset(a, 0, sizeof(a));
    weighted_state(s, dt, q, v, a);
    if (model_residual(s->q_bar, s->v_bar, a, s->u_bar, p, s->r, work)) return SS22_MODEL_FAILED;
    s->residual_evaluations++;
    if ((st = step_matrix(s, dt, a, p, work, MODEL_JACOBIAN_CONSTANT, &f)) != SS22_OK) return st;
    for (int i = 0; i < N_Q; i++) a[i] = -s->r[i];
    lu_solve(f->LU, N_Q, f->piv, a);
    if (!all_finite(a, N_Q)) return SS22_NOT_FINITE;
#else
    {
        double delta[N_Q];
        const uint64_t used = s->factorisations;
        if (start != NULL) { memcpy(a, start, sizeof(a)); predicted = 1; }
        else predicted = ss22_predict(s, dt, alpha, a, s->other_start);
        if (predicted == 2) memcpy(s->start, a, sizeof(a));
        recurrence = start == NULL && predicted ? recurrence_start(s, dt, q, v, alpha, p, work, a) : 0;
        /* below what a first increment with an older matrix ends the step by its size: a parabola's or the
         * recurrence's never (the rate's one-increment stop, below, still may), a corrected start's (ss22.h) */
        const double first_ends = (predicted == 2 && s->parabola) || recurrence == 2 ? -1.0
                                  : corrected ? s->tolerance / SS22_DIRECTION_MARGIN : INFINITY;
        const int kind = recurrence == 2;       /* the recurrence's start */
        const int slot = kind ? 1 : corrected ? 2 : 0;   /* which start's first ratios judge a one-increment stop */
        const double rounding = kind ? ss22_recurrence_floor(s, dt, a) : 0.0;   /* its first increment's noise floor */
        int converged = 0, far = 0;    /* far: the start more than SS22_FAR_START tolerances off (ss22.h) */
        int fresh = -1;          /* increments made with a matrix evaluated in this step; -1: an older one */
        double previous = INFINITY, ratio_before = -1.0;  /* ratio_before: last ratio with f here, -1 none */
        int with_f = 0;          /* iterations made with the current matrix f */
        for (int it = 0; it < s->max_iterations; it++) {
            weighted_state(s, dt, q, v, a);
            if (model_residual(s->q_bar, s->v_bar, a, s->u_bar, p, s->r, work)) return SS22_MODEL_FAILED;
            s->residual_evaluations++;
            if (!all_finite(s->r, N_Q)) return SS22_NOT_FINITE;
            if (f == NULL) {
                /* first iteration: the matrix of an earlier step (simplified Newton across steps) */
                if ((st = step_matrix(s, dt, a, p, work, it == 0, &f)) != SS22_OK) return st;
                if (it > 0 || s->factorisations != used) fresh = 0;
                with_f = 0;
            }
            with_f++;
            ss22_increment(s, f, s->r, delta);
            /* the increment's effect on the end-of-step rate, against the coordinate's nominal scale */
            double err = 0.0;
            for (int i = 0; i < N_Q; i++) {
                a[i] += delta[i];
                const double e = fabs(delta[i]) * dt / MODEL_NOMINAL_Q[i];
                if (!(e <= err)) err = e;        /* a NaN increment makes err NaN: refused below */
            }
            s->newton_iterations++;
            if (fresh >= 0) fresh++;
            if (!isfinite(err)) return SS22_NOT_FINITE;
            const int older = f->made != s->steps;   /* a matrix from an earlier step */
            if (it == 0) far = err > SS22_FAR_START * s->tolerance;
            /* after a far start (ss22.h) such a matrix ends the step only on an increment within this */
            const double within = far && older ? s->tolerance / SS22_DIRECTION_MARGIN : INFINITY;
            /* a ratio to the recurrence's first increment at its noise floor is noise (on a linear model) */
            const int noise = it == 1 && kind && previous <= rounding;
            double in_force = INFINITY;    /* the rate this step's one-increment stop would have used */
            if (it == 1 && fresh < 0 && !noise) {
                in_force = one_increment_rate(s, f, slot);
                f->first[slot] = err / previous;
                f->first_age[slot] = s->steps - f->made;
            }
            /* (a first increment of zero, or the recurrence's at its noise floor: the start is the solution) */
            if (err <= s->tolerance && err <= within &&
                bounds_error(s, err, previous, it > 0 && older) &&
                (it > 0 || fresh >= 0 || err <= first_ends || err == 0.0 || (kind && err <= rounding))) {
                /* a ratio to an increment below the tolerance, perhaps at the rounding floor: it only raises.
                 * (Not on a parabola's first increment with an older matrix: what that leaves is not bounded by
                 * its size; docs/integrator.md) */
                if (it == 2 && older) confirm_rate(f, err / previous, previous, s->tolerance);
                /* a second increment measures what the recurrence's one-increment stops are accepted on */
                if (kind && isfinite(in_force))
                    confirm(&f->confirmed_first, err / previous, aged_rate(in_force), previous, s->tolerance);
                if (it > 0 && fresh < 0 && !noise) record_rate(f, err / previous, 1);
                converged = 1;
                break;
            }
            if (it <= 1 && fresh < 0 && err <= within && f->rate >= 0.0 &&
                f->estimated < measure_interval_of(f, it == 0 && kind)) {
                /* an earlier step's matrix and its last measured rate: what is left is about
                 * rate/(1-rate) times this increment, the first or the second (ss22.h,
                 * SS22_RATE_MEASURE_EVERY); the second's ratio to the first still raises the kept rate */
                const double seen = it == 1 ? fmax(f->rate, err / previous) : one_increment_rate(s, f, slot);
                const double aged = aged_rate(seen);
                if (aged < 0.5 && aged / (1.0 - aged) * err <= s->tolerance) {
                    if (it == 1) f->rate = seen;
                    f->estimated++;
                    converged = 1;
                    break;
                }
            }
            if (it == 0 || fresh == 1) {
                /* no rate yet, or a new matrix's first increment: a ratio to the old matrix's says nothing */
                previous = err, ratio_before = -1.0;
                continue;
            }
            const double rate = err / previous, second = previous;
            previous = err;
            const int clear = err > SS22_ROUNDING_FACTOR * s->tolerance;   /* not a ratio of rounding noise */
            const double rising = in_step_rate(rate, ratio_before, clear);
            ratio_before = rate;
            /* an older matrix is judged on its kept rate, never on a step's first ratio (record_rate); a new
             * one's is Newton's own, kept once judged as older (below).  Both aged as in the early stops: ratios
             * can jump 10-200x after two that agreed (fast_two_link, 20 and 5 N m: 5.9e-5, 6.9e-5, then 0.011;
             * a new matrix 0.035, 0.22, 2.6e-5), and on the bare rate steps ended up to 7.1 tolerances off
             * (planar_chain_3 at 1 ms, 0.5 N m: 1.72; benchmarks/step_audit.py; docs/integrator.md) */
            const int first = it == 1 && fresh < 0;
            if (it == 2 && older) confirm_rate(f, rate, second, s->tolerance);
            const double kept = fresh < 0 ? record_rate(f, rate, first) : rate;
            const double judged = first ? INFINITY : aged_rate(fmax(kept, rising));
            /* linear convergence at rate < 1: what is left is about rate/(1-rate) times this increment */
            if (err <= within && judged < 0.5 && judged / (1.0 - judged) * err <= s->tolerance) {
                converged = 1;
                break;
            }
            /* an older matrix that at this rate cannot reach the tolerance (or within) in time, or in its last three */
            const int too_slow = fresh < 0 && (it + 3 >= s->max_iterations ||
                                 err * pow(rate, s->max_iterations - 1 - it) > fmin(s->tolerance, within));
            /* an old matrix whose extra iterations have paid for a new one (ss22.h, SS22_REFRESH_COST) */
            const int stale = fresh < 0 && (SS22_MASS_UPDATE ? f->waste_full : f->waste) >= SS22_REFRESH_COST;
            /* below the tolerance, not bounding the error: increments (cheaper than a matrix) while within reach */
            const int near = err <= s->tolerance && rate < 0.9 && aged_rate(rate) / (1.0 - aged_rate(rate)) * err
                             * pow(rate, s->max_iterations - 1 - it) <= s->tolerance;     /* pow: only when below */
            if ((rate <= 0.5 || near) && !too_slow && !stale) {
                fresh = -1;      /* contracting: judged as an older matrix from here on */
                continue;
            }
            if (fresh >= 2 && rate >= 0.9) {
                /* a fresh matrix no longer contracts: either rounding stops us just above the
                 * tolerance (accept), or the iteration diverges (fail) */
                if (err <= SS22_ROUNDING_FACTOR * s->tolerance) { converged = 1; break; }
                return SS22_NOT_CONVERGED;
            }
            f = NULL;   /* simplified Newton: refresh the matrix when it contracts poorly, too slowly or stale */
        }
        if (!converged) return SS22_NOT_CONVERGED;
        if (with_f > 2) f->waste += with_f - 2;
        if (with_f > SS22_MASS_UPDATE_FLOOR) f->waste_full += with_f - SS22_MASS_UPDATE_FLOOR;
        if (ss22_mass_update_due(s, f)) ss22_mass_update(s, f, a, p, work);      /* for the next steps */
    }
#endif
    for (int i = 0; i < N_Q; i++) {
        q[i] += dt * v[i] + 0.5 * dt * dt * a[i];
        v[i] += dt * a[i];
    }
#if !MODEL_LINEAR_IN_STATE
    if (predicted == 2) ss22_choose_predictor(s, a, s->start, s->other_start);
    ss22_recurrence_after_step(s, a, recurrence, predicted && start == NULL);
#endif
    /* three consecutive steps' own accelerations for the parabola: only along predictions from the last one */
    if (predicted && start == NULL) {
        memcpy(s->alpha_older, s->alpha_before, sizeof(a));
        s->dt_older = s->dt_before;
        s->depth = s->depth < 3 ? s->depth + 1 : 3;
    } else {
        s->depth = 1;
    }
    if (predicted) { memcpy(s->alpha_before, alpha, sizeof(a)); s->dt_before = s->dt_last; }
    else { memcpy(s->alpha_before, a, sizeof(a)); s->dt_before = dt; }     /* the line starts again here */
    memcpy(s->alpha_last, a, sizeof(a));
    s->dt_last = dt;
    memcpy(alpha, a, sizeof(a));
    s->steps++;
    return SS22_OK;
}
