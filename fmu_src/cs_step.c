/* cs_step.c -- the Co-Simulation communication step: equal internal SS22 steps, Richardson extrapolation
 * for order 4, sub-steps when SS22 fails, and a discarded step undone.  See cosimulation.h. */
#include <float.h>
#include <math.h>
#include <string.h>
#include "internal.h"

/* A communication step of many internal steps is energy-balanced every ENERGY_CHUNK_STEPS of them (an
 * energy point costs about one outputs evaluation, a sixteenth of the step's work at most): the inputs' work
 * between two points is a quadrature, exact only over a stretch a few internal steps long. */
#define ENERGY_CHUNK_STEPS 16

/* SUBSTEP_MAX and DOSTEP_MAX_INTERNAL_STEPS: solver_settings.h (from flexlink/scene/solver.py) */

/* ====================================================================== doStep */

/* One SS22 step [t0, t1]; its Newton iteration starts from start (corrected: with a miss added, ss22.h), or
 * from SS22's predictor if NULL. */
static SS22Status ss22_from(Instance *inst, double t0, double t1, const double *start, int corrected) {
    FmuData *d = &inst->d;
    fmu_model_inputs(d, t0, inst->u0);
    fmu_model_inputs(d, t1, inst->u1);
    return ss22_step_from(&d->ss22, t1 - t0, d->q, d->v, d->alpha, start, corrected, inst->u0, inst->u1, d->p,
                          &inst->work);
}

/* 0 starts order 4's steps from their bases alone (tests/test_richardson.py measures what the misses save). */
#ifndef RICHARDSON_FEEDBACK
#define RICHARDSON_FEEDBACK 1
#endif

/* Order 4's starts (cosimulation.h, RichardsonStarts): whether the misses kept are those of the internal step
 * just before this one, of the same size, on the acceleration SS22 left (no step, reset or restart between).
 * "The same size" up to the rounding of t1 - t0, which grows with t (1e4 s: 1.8e-12 s). */
static int misses_apply(const FmuData *d, double t1, double dt) {
    const RichardsonStarts *r = &d->richardson;
    const double same = 1e-9 * dt + 4.0 * DBL_EPSILON * fabs(t1);
    return RICHARDSON_FEEDBACK && r->valid && r->steps == d->ss22.steps && fabs(r->dt - dt) <= same &&
           d->ss22.depth > 0 && memcmp(d->alpha, d->ss22.alpha_last, sizeof(d->alpha)) == 0;
}

/* Step k's start: its base, plus its last miss where the vote favours that (returned: whether it added). */
static int fed_back(const RichardsonStarts *r, int k, int apply, const double *base, double *start) {
    const int add = apply && r->bias[k] < 0.0;
    for (int i = 0; i < N_Q; i++) start[i] = base[i] + (add ? r->miss[k][i] : 0.0);
    return add;
}

/* After step k accepted a: the vote between base and base + miss (when the miss was the last step's), and the
 * new miss.  Misses in the Newton increments' measure (ss22.c: |delta| dt / nominal). */
static void record_miss(RichardsonStarts *r, int k, int apply, const double *base, const double *a) {
    if (apply) {
        double alone = 0.0, added = 0.0;
        for (int i = 0; i < N_Q; i++) {
            alone = fmax(alone, fabs(a[i] - base[i]) / MODEL_NOMINAL_Q[i]);
            added = fmax(added, fabs(a[i] - base[i] - r->miss[k][i]) / MODEL_NOMINAL_Q[i]);
        }
        r->bias[k] += ((added < alone ? -1.0 : 1.0) - r->bias[k]) / SS22_PREDICTOR_MEMORY;
    }
    for (int i = 0; i < N_Q; i++) r->miss[k][i] = a[i] - base[i];
}

/* Order 4: the symmetric SS22 (Θ = ½) has an error expansion in even powers of Δt, so one step of Δt and
 * two of Δt/2 combine into q = q_half + (q_half − q_full)/3, fourth-order accurate (Richardson).  On failure
 * q, v and alpha are left as they were. */
static SS22Status richardson_step(Instance *inst, double t0, double t1) {
    FmuData *d = &inst->d;
    RichardsonStarts *r = &d->richardson;
    double q0[N_Q], v0[N_Q], a0[N_Q], q1[N_Q], v1[N_Q], a1[N_Q], base[N_Q], start[N_Q];
    const double dt = t1 - t0, tm = t0 + 0.5 * dt;
    const int apply = misses_apply(d, t1, dt);
    memcpy(q0, d->q, sizeof(q0));
    memcpy(v0, d->v, sizeof(v0));
    memcpy(a0, d->alpha, sizeof(a0));
    /* the full step: SS22's line through the last two half steps (centred dt/2 and dt/4 before t0) */
    for (int i = 0; i < N_Q; i++) base[i] = a0[i] + 1.5 * (a0[i] - r->alpha_half[i]);
    const int corrected = fed_back(r, 0, apply, base, start);
    SS22Status status = ss22_from(inst, t0, t1, corrected ? start : NULL, corrected);
    if (status == SS22_OK) {
        if (apply) record_miss(r, 0, 1, base, d->alpha);
        else memset(r->miss[0], 0, sizeof(r->miss[0]));
        memcpy(q1, d->q, sizeof(q1));
        memcpy(v1, d->v, sizeof(v1));
        memcpy(a1, d->alpha, sizeof(a1));
        memcpy(d->q, q0, sizeof(q0));
        memcpy(d->v, v0, sizeof(v0));
        memcpy(d->alpha, a0, sizeof(a0));
        /* the half steps start from the full step's acceleration a1 (the mean over [t0, t1]): the first half's
         * on the line from a0 (the last half step's, centred at t0 - dt/4) to a1 (at t0 + dt/2), the second
         * half's so that the two halves average to a1 (docs/integrator.md) */
        for (int i = 0; i < N_Q; i++) base[i] = a0[i] + (2.0 / 3.0) * (a1[i] - a0[i]);
        const int corrected_1 = fed_back(r, 1, apply, base, start);
        status = ss22_from(inst, t0, tm, start, corrected_1);
        if (status == SS22_OK) {
            record_miss(r, 1, apply, base, d->alpha);
            memcpy(r->alpha_half, d->alpha, sizeof(r->alpha_half));
            for (int i = 0; i < N_Q; i++) base[i] = 2.0 * a1[i] - d->alpha[i];
            const int corrected_2 = fed_back(r, 2, apply, base, start);
            status = ss22_from(inst, tm, t1, start, corrected_2);
            if (status == SS22_OK) record_miss(r, 2, apply, base, d->alpha);
        }
    }
    r->valid = status == SS22_OK;
    if (status != SS22_OK) {
        memcpy(d->q, q0, sizeof(q0));
        memcpy(d->v, v0, sizeof(v0));
        memcpy(d->alpha, a0, sizeof(a0));
        return status;
    }
    r->dt = dt;
    r->steps = d->ss22.steps;
    for (int i = 0; i < N_Q; i++) {
        d->q[i] += (d->q[i] - q1[i]) / 3.0;
        d->v[i] += (d->v[i] - v1[i]) / 3.0;
    }
    return SS22_OK;
}

static SS22Status one_step(Instance *inst, double t0, double t1) {
    return inst->d.solver[SOLVER_ORDER] == 4 ? richardson_step(inst, t0, t1) : ss22_from(inst, t0, t1, NULL, 0);
}

/* One internal step [t0, t1]; if SS22 fails, again as 2, 4, ... SUBSTEP_MAX sub-steps. */
static SS22Status internal_step(Instance *inst, double t0, double t1) {
    FmuData *d = &inst->d;
    SS22Status status = one_step(inst, t0, t1);        /* leaves q, v, alpha alone on failure */
    if (status == SS22_OK) return status;
    memcpy(inst->q_save, d->q, sizeof(d->q));
    memcpy(inst->v_save, d->v, sizeof(d->v));
    memcpy(inst->alpha_save, d->alpha, sizeof(d->alpha));
    for (int n = 2; n <= SUBSTEP_MAX; n *= 2) {
        const double dt = (t1 - t0) / n;
        fmu_log(inst, fmi2OK, LOG_EVENTS, "step [%.17g, %.17g]: %s; retrying as %d sub-steps", t0, t1,
                ss22_status_message(status), n);
        for (int j = 1; j <= n; j++) {
            const double a = t0 + (j - 1) * dt, b = j == n ? t1 : t0 + j * dt;
            status = one_step(inst, a, b);
            if (status != SS22_OK) break;
        }
        if (status == SS22_OK) return status;
        memcpy(d->q, inst->q_save, sizeof(d->q));
        memcpy(d->v, inst->v_save, sizeof(d->v));
        memcpy(d->alpha, inst->alpha_save, sizeof(d->alpha));
    }
    return status;
}

/* The energy balance from *e0 to the state reached at t inside a communication step (internal steps
 * ENERGY_CHUNK_STEPS apart); *e0 moves on to it.  A failure restores the step's start and is the step's
 * Discard. */
static fmi2Status energy_chunk(Instance *inst, double t, EnergyPoint *e0, uint64_t *steps_at_e0) {
    FmuData *d = &inst->d;
    EnergyPoint e;
    const double t_start = inst->backup.time;
    d->time = t;
    d->outputs_valid = 0;
    fmi2Status status = fmu_energy_point_inside(inst, &e, "fmi2DoStep");
    if (status <= fmi2Warning) {
        status = fmu_guard_energy(inst, e0, &e, (double)(d->ss22.steps - *steps_at_e0));
        if (status != fmi2OK) {
            fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2DoStep: %s; the step is discarded and the FMU "
                    "is back at t = %.17g", inst->guard_reason, t_start);
            status = fmi2Discard;
        }
    }
    if (status != fmi2OK) {
        memcpy(d, &inst->backup, sizeof(*d));
        return status;
    }
    *e0 = e;
    *steps_at_e0 = d->ss22.steps;
    return fmi2OK;
}

fmi2Status fmu_do_step(Instance *inst, fmi2Real tc, fmi2Real h) {
    FmuData *d = &inst->d;
    const double step = d->solver[SOLVER_STEP];
    double t, t_end;
    if (!(h > 0.0 && isfinite(h))) {
        return fmu_error(inst, "fmi2DoStep: communicationStepSize = %g: must be > 0 and finite", h);
    }
    if (!(fabs(tc - d->time) <= 1e-9 * fmax(1.0, fabs(d->time)))) {
        return fmu_error(inst, "fmi2DoStep: currentCommunicationPoint = %.17g differs from the FMU's time "
                         "%.17g", tc, d->time);
    }
    t_end = tc + h;
    if (d->stop_time_defined && t_end > d->stop_time + 1e-9 * fmax(1.0, fabs(d->stop_time))) {
        return fmu_error(inst, "fmi2DoStep: the step to t = %.17g goes beyond stopTime = %.17g",
                         t_end, d->stop_time);
    }
    if (!(h / step <= DOSTEP_MAX_INTERNAL_STEPS)) {
        fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2DoStep: a communication step of %g s needs %.3g "
                "internal steps of solver.step = %g s; at most %.0f are taken in one fmi2DoStep: use a larger "
                "solver.step or shorter communication steps (the FMU stays at t = %.17g)", h, h / step, step,
                DOSTEP_MAX_INTERNAL_STEPS, d->time);
        inst->step_discarded = 1;                      /* fmi2Terminated: retrying the same step cannot help */
        return fmi2Discard;
    }
    EnergyPoint e0, e1;
    {
        /* where the last step ended, unless more than force inputs changed since (guards.c) */
        const fmi2Status status = fmu_energy_point_start(inst, &e0, "fmi2DoStep");
        if (status > fmi2Warning) return status;
    }
    memcpy(&inst->backup, d, sizeof(*d));
    uint64_t steps_at_e0 = d->ss22.steps;
    inst->step_discarded = 1;                          /* until the step below succeeds */
    t = d->time;
    /* n equal internal steps of at most solver.step: never overshooting, and no odd short last step.
     * SS22 with Θ1 = ½ < Θ2 is only marginally stable in unresolved modes, and alternating step sizes
     * (a regular step, then a tiny remainder) can pump energy into them: equal steps keep the step
     * constant over a run with a constant communication step (tests/test_ss22_numerics.py). */
    {
        const double ratio = h / step;
        long n = (long)ceil(ratio - 1e-9 * fmax(1.0, ratio));
        if (n < 1) n = 1;
        if (d->solver[SOLVER_ORDER] == 4) {
            const fmi2Status stable = fmu_check_richardson(inst, h / (double)n);
            if (stable != fmi2OK) return stable;       /* nothing was attempted: the FMU is where it was */
        }
        for (long i = 1; i <= n; i++) {
            const double t_next = (i == n) ? t_end : tc + h * ((double)i / (double)n);
            SS22Status status = internal_step(inst, t, t_next);
            if (status == SS22_OK && fmu_guard_state(inst, t_next, inst->u1, i == n) != fmi2OK) {
                memcpy(d, &inst->backup, sizeof(*d));
                fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2DoStep: %s; the step from %.17g to %.17g "
                        "is discarded and the FMU is back at t = %.17g", inst->guard_reason, tc, t_end, d->time);
                return fmi2Discard;
            }
            if (status != SS22_OK) {
                memcpy(d, &inst->backup, sizeof(*d));
                fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD,
                        "fmi2DoStep: the SS22 step at t = %.17g failed: %s (also as %d sub-steps); the step "
                        "from %.17g to %.17g is discarded and the FMU is back at t = %.17g", t,
                        ss22_status_message(status), SUBSTEP_MAX, tc, t_end, d->time);
                return fmi2Discard;
            }
            t = t_next;
            if (i < n && i % ENERGY_CHUNK_STEPS == 0) {
                /* a long communication step is balanced in chunks: the inputs' work is a quadrature between
                 * two energy points (Simpson on a law's τθ', the path trapezoid of the forces), exact over
                 * a few internal steps, not over a whole 5 s law in one fmi2DoStep (refused before) */
                const fmi2Status chunk = energy_chunk(inst, t, &e0, &steps_at_e0);
                if (chunk != fmi2OK) return chunk;
            }
        }
    }
    d->time = t_end;
    d->outputs_valid = 0;
    {   /* the outputs at t_end, which the host reads next, and with them the step's energy balance */
        fmi2Status status = fmu_energy_point(inst, &e1, "fmi2DoStep");
        if (status > fmi2Warning) {
            memcpy(d, &inst->backup, sizeof(*d));
            return status;
        }
        /* the SS22 steps taken, sub-steps and order 4's three solves a step included */
        const double taken = (double)(d->ss22.steps - steps_at_e0);
        if (fmu_guard_energy(inst, &e0, &e1, taken) != fmi2OK) {
            memcpy(d, &inst->backup, sizeof(*d));
            fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2DoStep: %s; the step is discarded and the FMU is "
                    "back at t = %.17g", inst->guard_reason, d->time);
            return fmi2Discard;
        }
    }
    fmu_energy_point_keep(inst, &e1);                  /* the next step starts from it */
    d->last_successful_time = t_end;
    inst->step_discarded = 0;
    return fmi2OK;
}
