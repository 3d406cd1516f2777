/* consistent.c -- the consistent acceleration M(q) a = -r(q, v, 0, u, p) behind the outputs, the energy
 * balance and Model Exchange's derivatives, with a factorised mass matrix kept across calls.
 *
 * Every communication point needs it, and a host that steps at the solver's step asks for it after every
 * internal step.  Forming and factorising M costs many residuals where the model has many coordinates (the
 * 32-mode second-order link of benchmarks/scaling.py: about 100 µs against 5 µs a residual), while M moves
 * little between two communication points.  So the factors of an earlier M are kept (in the FMU state, so a
 * restored state computes the same outputs to the last bit) and the residual, affine in a, is iterated on:
 *
 *     a_1 = -M_kept⁻¹ r0,    a_{k+1} = a_k - M_kept⁻¹ r(q, v, a_k, u, p),
 *
 * which converges at the rate ρ ≈ ‖I - M_kept⁻¹ M(q)‖ -- the iteration refinement of a linear solve.  It stops
 * when the remainder predicted from the measured rate is CONSISTENT_TOLERANCE of the acceleration (round-off
 * of a direct solve, which LU's backward error also leaves), or at the rounding floor; a rate above
 * CONSISTENT_MAX_RATE, or more residuals than a new M costs (or a rate that cannot reach the tolerance within
 * them), buys a new M instead: its price in residuals is CONSISTENT_REFRESH_COST (config.h, from the build's
 * operation counts: codegen.py, consistent_refresh_cost).  Where a new M costs no more than a few residuals the direct solve is taken every time, as
 * before.  docs/integrator.md, "The consistent acceleration". */
#include <math.h>
#include "internal.h"
#include "linalg.h"

/* The remainder accepted, relative to the acceleration's size in the coordinates' nominal units: at the
 * round-off a direct solve of a well-conditioned M leaves. */
#define CONSISTENT_TOLERANCE 1e-13
/* A kept M whose iteration contracts slower than this is replaced (more than 13 residuals to 1e-13). */
#define CONSISTENT_MAX_RATE 0.1
/* A model's config.h states the price (codegen.py); a hand-written model (tests/c/) may not: the direct solve. */
#ifndef CONSISTENT_REFRESH_COST
#define CONSISTENT_REFRESH_COST 0.0
#endif
/* Below this many residuals' worth a new M (and its LU) is cheaper than iterating on a kept one. */
#ifndef CONSISTENT_KEEP_MIN_COST
#define CONSISTENT_KEEP_MIN_COST 4.0
#endif

void fmu_consistent_forget(FmuData *d) {
    d->mass.valid = 0;
}

/* max_i |x_i| / nominal_i: the coordinates' own units, as the Newton tolerance measures them; NaN if any x_i
 * is (a running max with !(s <= m) let a later finite s replace a NaN m: a = (NaN, 0, ...) measured 0). */
static double scaled_size(const double *x) {
    double m = 0.0;
    for (int i = 0; i < N_Q; i++) {
        const double s = fabs(x[i]) / MODEL_NOMINAL_Q[i];
        if (isnan(s)) return s;
        if (s > m) m = s;
    }
    return m;
}

/* The iteration on the kept factors: 0 converged (d->acceleration), 1 refresh, -1 the model failed. */
static int iterate_on_kept(Instance *inst, const double *u0, const double *r0) {
    FmuData *d = &inst->d;
    double *a = d->acceleration, *delta = inst->dq;
    const int max_iterations = (int)(CONSISTENT_REFRESH_COST) - 1;
    for (int i = 0; i < N_Q; i++) a[i] = -r0[i];
    lu_solve(d->mass.LU, N_Q, d->mass.piv, a);
    double last = scaled_size(a);
    const double size = last;
    if (!isfinite(size)) return 1;
    if (size == 0.0) return 0;        /* r0 = 0: at rest in equilibrium, a = 0 exactly */
    for (int k = 0; k < max_iterations; k++) {
        if (model_residual(d->q, d->v, a, u0, d->p, delta, &inst->work)) return -1;
        d->mass_iterations++;
        lu_solve(d->mass.LU, N_Q, d->mass.piv, delta);
        for (int i = 0; i < N_Q; i++) a[i] -= delta[i];
        const double step = scaled_size(delta), rate = step / last;
        if (!isfinite(step)) return 1;
        if (step == 0.0) return 0;
        /* The first ratio, of the first correction to the acceleration itself, does not end the iteration: the
         * error it leaves lies where M moved, which the acceleration may barely touch, so the next ratio can be
         * far larger (a stop on it accepted 27 times the tolerance, tests/test_consistent_acceleration.py). */
        /* The remainder after this step: ρ/(1 - ρ) of it while the iteration contracts.  Not contracting
         * (ρ >= 1, where ρ/(1 - ρ) is negative or infinite), it is no estimate: that stop is for ρ < 1 only
         * (a kept M with an eigenvalue of M_kept⁻¹ M above 2 diverged and was accepted, 4 % off). */
        const double remainder = rate < 1.0 ? rate / (1.0 - rate) * step : step;
        if (k > 0 && rate < 1.0 && remainder <= CONSISTENT_TOLERANCE * size) return 0;
        /* No contraction left, at rounding: where a direct solve would have stopped too.  On the remainder,
         * not the step: a slow direction (ρ = 0.99) that the first ratios hid has a step 100 times smaller
         * than its error (accepted 6600 times the test's bound).  Past ρ = 1 the error left is at most the step,
         * in a direction where M_kept⁻¹ M exceeds 2 (error (1 - b)/b of the step). */
        if (k > 0 && rate > 0.5 && remainder <= 1e3 * CONSISTENT_TOLERANCE * size) return 0;
        if (rate > CONSISTENT_MAX_RATE) return 1;
        /* Out of reach within the budget (about a new M's price in residuals) at the measured rate: the new M
         * now, not after spending the budget too (at 0.05 on a price of 5.3, 4 residuals and then the M). */
        if (k > 0 && remainder * pow(rate, max_iterations - 1 - k) > CONSISTENT_TOLERANCE * size) return 1;
        last = step;
    }
    return 1;
}

int fmu_consistent_acceleration(Instance *inst, const double *u0, const double *r0) {
    FmuData *d = &inst->d;
    KeptMass *m = &d->mass;
    if (CONSISTENT_REFRESH_COST >= CONSISTENT_KEEP_MIN_COST && m->valid) {
        const int kept = iterate_on_kept(inst, u0, r0);
        if (kept <= 0) return kept;
    }
    m->valid = 0;
    d->mass_refreshes++;
    if (model_newton_matrix(d->q, d->v, inst->zero, u0, d->p, 1.0, 0.0, 0.0, m->LU, &inst->work)) return -1;
    if (!fmu_all_finite(m->LU, N_Q * N_Q) || lu_factor(m->LU, N_Q, m->piv) != 0) return 1;
    for (int i = 0; i < N_Q; i++) d->acceleration[i] = -r0[i];
    lu_solve(m->LU, N_Q, m->piv, d->acceleration);
    if (!fmu_all_finite(d->acceleration, N_Q)) return 1;
    m->valid = 1;
    return 0;
}
