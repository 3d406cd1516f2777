/* variables.c -- fmi2GetReal / fmi2SetReal on the variable table of model.h, the inputs as the model sees
 * them (kinematic laws filled in) and the outputs with the consistent acceleration behind them.
 * See cosimulation.h. */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "internal.h"
#include "linalg.h"

/* model_parameter_check's entries are scaled to be O(1): below -1e-12 is a broken relation, not rounding. */
#define PARAMETER_CHECK_TOLERANCE 1e-12

/* ==================================================================== variables */

double *fmu_slot(FmuData *d, const VarInfo *v) {
    switch (v->kind) {
    case VAR_PARAMETER: return &d->p[v->index];
    case VAR_START_Q: return &d->q_start[v->index];
    case VAR_START_V: return &d->v_start[v->index];
    case VAR_SOLVER: return &d->solver[v->index];
    case VAR_INPUT: return &d->u[v->index];
    case VAR_OUTPUT: return &d->y[v->index];
    case VAR_STATE_Q: return &d->q[v->index];
    case VAR_STATE_V: return &d->v[v->index];
    case VAR_DER_Q: return &d->v[v->index];
    case VAR_DER_V: return &d->acceleration[v->index];
    }
    return NULL;
}

/* ========================================================= inputs, kinematic laws */

#if N_LAWS > 0
/* Position, rate and acceleration of a built-in law at time t. */
static void law_builtin(const KinematicLaw *law, double t, double *x) {
    const LawSegment *s;
    double x0 = 0.0, x1 = 0.0, x2 = 0.0;
    x[0] = x[1] = x[2] = 0.0;
    if (law->n_segments <= 0) return;
    s = &law->segments[law->n_segments - 1];
    for (int k = 0; k < law->n_segments; k++) {
        if (t < law->segments[k].until) { s = &law->segments[k]; break; }
    }
    for (int k = s->n_poly - 1; k >= 0; k--) {     /* Horner with the first two derivatives */
        x2 = x2 * t + x1;
        x1 = x1 * t + x0;
        x0 = x0 * t + s->poly[k];
    }
    x[0] = x0;
    x[1] = x1;
    x[2] = 2.0 * x2;
    for (int j = 0; j < s->n_cos; j++) {
        const double amp = s->cos[3 * j], w = s->cos[3 * j + 1], phase = s->cos[3 * j + 2];
        const double c = cos(w * t + phase), sn = sin(w * t + phase);
        x[0] += amp * c;
        x[1] -= amp * w * sn;
        x[2] -= amp * w * w * c;
    }
}

/* The host's (x, xd, xdd) of law k, given at d->law_time[k], extended to t. */
static void law_extended(const FmuData *d, int k, double t, double *x) {
    const int o = MODEL_LAWS[k].u_offset;
    const double s = t - d->law_time[k];
    x[0] = d->u[o] + s * (d->u[o + 1] + 0.5 * s * d->u[o + 2]);
    x[1] = d->u[o + 1] + s * d->u[o + 2];
    x[2] = d->u[o + 2];
}
#endif

/* u_model(t): the host's inputs, with the kinematic-law slots filled in. */
void fmu_model_inputs(const FmuData *d, double t, double *u) {
    memcpy(u, d->u, sizeof(d->u));
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) {
        const KinematicLaw *law = &MODEL_LAWS[k];
        if (law->builtin) law_builtin(law, t, u + law->u_offset);
        else law_extended(d, k, t, u + law->u_offset);
    }
#else
    (void)t;
#endif
}

/* Before the host sets one slot of a host-driven law at time != the law's time, carry the other two
 * slots forward to now, so that (x, xd, xdd) always describe the law at law_time. */
static void rebase_law(FmuData *d, int u_index) {
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) {
        const int o = MODEL_LAWS[k].u_offset;
        if (!MODEL_LAWS[k].builtin && u_index >= o && u_index < o + 3 && d->law_time[k] != d->time) {
            double x[3];
            law_extended(d, k, d->time, x);
            memcpy(d->u + o, x, sizeof(x));
            d->law_time[k] = d->time;
        }
    }
#else
    (void)d;
    (void)u_index;
#endif
}

/* ========================================================== outputs, acceleration */

int fmu_all_finite(const double *x, int n) {
    for (int i = 0; i < n; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

/* The consistent acceleration M(q) a = -r(q, v, 0, u, p) at d->time, then the outputs. */
fmi2Status fmu_update_outputs(Instance *inst, const char *function) {
    FmuData *d = &inst->d;
    fmi2Status status = fmi2OK;
    if (d->outputs_valid == 1) return fmi2OK;
    fmu_model_inputs(d, d->time, inst->u0);
    if (model_residual(d->q, d->v, inst->zero, inst->u0, d->p, inst->r, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", function, d->time);
    }
    const int solved = fmu_consistent_acceleration(inst, inst->u0, inst->r);
    if (solved < 0) return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", function, d->time);
    d->acceleration_ok = solved == 0;
    if (!d->acceleration_ok) {
        memcpy(d->acceleration, d->alpha, sizeof(d->acceleration));
        fmu_log(inst, fmi2Warning, LOG_STATUS_WARNING,
                "%s: the mass matrix is singular at t = %.17g: outputs use the last step's mean acceleration",
                function, d->time);
        status = fmi2Warning;
    }
    if (model_outputs(d->q, d->v, d->acceleration, inst->u0, d->p, d->y, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate its outputs at t = %.17g", function,
                         d->time);
    }
    d->outputs_valid = 1;
    return status;
}

/* The outputs that do not depend on the acceleration (MODEL_OUTPUT_USES_ACCELERATION), unless up to date:
 * evaluated at a = 0, without the consistent acceleration, its mass matrix and LU (most of what a small model's
 * communication point cost besides its step).  d->y's other entries are not valid until fmu_update_outputs
 * (outputs_valid 2: get_values never returns them, and they are values at a = 0, not stale ones). */
fmi2Status fmu_update_static_outputs(Instance *inst, const char *function) {
    FmuData *d = &inst->d;
    if (d->outputs_valid) return fmi2OK;
    fmu_model_inputs(d, d->time, inst->u0);
    if (model_outputs(d->q, d->v, inst->zero, inst->u0, d->p, d->y, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate its outputs at t = %.17g", function, d->time);
    }
    d->outputs_valid = 2;
    return fmi2OK;
}

/* The outputs a read of vr[] needs, once for all of them: none, those without the acceleration, or all with
 * the consistent acceleration (der(v) or an output MODEL_OUTPUT_USES_ACCELERATION marks).  References past
 * N_VARS (FMI 3's time) need none. */
fmi2Status fmu_update_outputs_for(Instance *inst, const char *function, const fmi2ValueReference vr[],
                                  size_t nvr) {
    int need = 0;        /* 1: outputs without the acceleration; 2: the consistent acceleration too */
    for (size_t i = 0; i < nvr; i++) {
        const VarInfo *v = vr[i] < (fmi2ValueReference)N_VARS ? &MODEL_VARS[vr[i]] : NULL;
        if (v == NULL) continue;
        if (v->kind == VAR_DER_V || (v->kind == VAR_OUTPUT && MODEL_OUTPUT_USES_ACCELERATION[v->index])) need = 2;
        else if (v->kind == VAR_OUTPUT && need == 0) need = 1;
    }
    if (need == 0) return fmi2OK;
    return need == 2 ? fmu_update_outputs(inst, function) : fmu_update_static_outputs(inst, function);
}

/* ================================================================ get and set */

/* Unknown value references are refused, and the Integer functions on a Real variable, naming the function to
 * use.  The Real functions take an Integer variable too (solver.order was a Real before it became an Integer:
 * hosts that read every variable as a Real, or set it as one, keep working; a value set so must be whole). */
static fmi2Status check_references(Instance *inst, const char *function, int integer,
                                   const fmi2ValueReference vr[], size_t nvr) {
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= (fmi2ValueReference)N_VARS) {
            return fmu_error(inst, "%s: unknown value reference %u", function, vr[i]);
        }
        if (integer && !MODEL_VARS[vr[i]].integer) {
            return fmu_error(inst, "%s: %s (value reference %u) is a Real: get and set it with fmi2GetReal/"
                             "fmi2SetReal (FMI 3: Float64)", function, MODEL_VARS[vr[i]].name, vr[i]);
        }
    }
    return fmi2OK;
}

/* Get Real or Integer values (one of real, integer). */
static fmi2Status get_values(Instance *inst, const char *function, int is_integer, const fmi2ValueReference vr[],
                             size_t nvr, fmi2Real real[], fmi2Integer integer[]) {
    if (check_references(inst, function, is_integer, vr, nvr) != fmi2OK) return fmi2Error;
    const fmi2Status status = fmu_update_outputs_for(inst, function, vr, nvr);
    if (status > fmi2Warning) return status;
    for (size_t i = 0; i < nvr; i++) {
        const double x = *fmu_slot(&inst->d, &MODEL_VARS[vr[i]]);
        if (is_integer) integer[i] = (fmi2Integer)x; else real[i] = x;
    }
    return status;
}

fmi2Status fmu_get_real(Instance *inst, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    return get_values(inst, "fmi2GetReal", 0, vr, nvr, value, NULL);
}

fmi2Status fmu_get_integer(Instance *inst, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    return get_values(inst, "fmi2GetInteger", 1, vr, nvr, NULL, value);
}

/* Why x is outside variable v's domain (finite, not subnormal, within min/max), or NULL. */
static const char *outside_domain(const VarInfo *v, double x, char *why, size_t n) {
    if (!isfinite(x)) {
        snprintf(why, n, "%s = %g: NaN and infinite values are refused", v->name, x);
    } else if (v->kind != VAR_INPUT && fpclassify(x) == FP_SUBNORMAL) {
        /* a parameter's products underflow and its quotients overflow; an input may decay that far */
        snprintf(why, n, "%s = %g: subnormal values are refused (0 or magnitude >= %g)", v->name, x, DBL_MIN);
    } else if (v->min_exclusive ? !(x > v->min) : !(x >= v->min)) {
        snprintf(why, n, "%s = %.15g: must be %s %.15g", v->name, x, v->min_exclusive ? ">" : ">=", v->min);
    } else if (!(x <= v->max)) {
        snprintf(why, n, "%s = %.15g: must be <= %.15g", v->name, x, v->max);
    } else if (v->integer && x != floor(x)) {
        snprintf(why, n, "%s = %.15g: an Integer, must be a whole number", v->name, x);
    } else if (v->kind == VAR_SOLVER && v->index == SOLVER_ORDER && x != SOLVER_ORDER_SS22 &&
               x != SOLVER_ORDER_RICHARDSON) {
        snprintf(why, n, "%s = %.15g: must be %d (SS22) or %d (SS22 with Richardson extrapolation)", v->name, x,
                 SOLVER_ORDER_SS22, SOLVER_ORDER_RICHARDSON);
    } else {
        return NULL;
    }
    return why;
}

/* Why value x cannot be given to variable v now, or NULL. */
static const char *refuse_value(const Instance *inst, const VarInfo *v, double x, char *why, size_t n) {
    const int phase = inst->d.phase;
    const int fixed = v->kind == VAR_START_Q || v->kind == VAR_START_V || v->kind == VAR_SOLVER ||
                      (v->kind == VAR_PARAMETER && !v->tunable);
    if (v->kind == VAR_OUTPUT) {
        snprintf(why, n, "%s is an output: it cannot be set", v->name);
    } else if (v->kind == VAR_STATE_Q || v->kind == VAR_STATE_V || v->kind == VAR_DER_Q || v->kind == VAR_DER_V) {
        snprintf(why, n, "%s is a continuous state or a derivative: it cannot be set with fmi2SetReal "
                 "(Model Exchange: fmi2SetContinuousStates)", v->name);
    } else if (v->kind == VAR_PARAMETER && phase == PHASE_CONTINUOUS) {
        snprintf(why, n, "%s is a tunable parameter: it can be set in event mode, not in %s", v->name,
                 fmu_phase_name(phase));
    } else if (fixed && !(phase & (PHASE_INSTANTIATED | PHASE_INITIALIZATION))) {
        snprintf(why, n, "%s is fixed after initialization: it cannot be set in %s", v->name,
                 fmu_phase_name(phase));
    } else {
        return outside_domain(v, x, why, n);
    }
    return why;
}

#if N_PARAMETER_CHECKS > 0
/* The relations between parameters (model_parameter_check) with the new values in place: refused before
 * anything is written, so that a refused call changes nothing. */
static fmi2Status check_parameter_relations(Instance *inst, const char *function, const fmi2ValueReference vr[],
                                            size_t nvr, const fmi2Real value[]) {
    double p[N_P], h[N_PARAMETER_CHECKS];
    int any = 0;
    memcpy(p, inst->d.p, sizeof(p));
    for (size_t i = 0; i < nvr; i++) {
        const VarInfo *v = &MODEL_VARS[vr[i]];
        if (v->kind == VAR_PARAMETER) { p[v->index] = value[i]; any = 1; }
    }
    if (!any) return fmi2OK;
    if (model_parameter_check(p, h, &inst->work)) {
        return fmu_error(inst, "%s: the relations between the parameters could not be evaluated", function);
    }
    for (int k = 0; k < N_PARAMETER_CHECKS; k++) {
        if (!(h[k] >= -PARAMETER_CHECK_TOLERANCE)) {
            return fmu_error(inst, "%s: refused, the parameters would break %s (%.6g); nothing was set",
                             function, MODEL_PARAMETER_CHECK_NAMES[k], h[k]);
        }
    }
    return fmi2OK;
}
#endif

const char *fmu_invalid_values(Instance *inst, const FmuData *d, char *why, size_t n) {
    for (int k = 0; k < N_VARS; k++) {
        const VarInfo *v = &MODEL_VARS[k];
        if (v->kind != VAR_PARAMETER && v->kind != VAR_SOLVER && v->kind != VAR_START_Q &&
            v->kind != VAR_START_V && v->kind != VAR_INPUT) continue;
        if (outside_domain(v, *fmu_slot((FmuData *)d, v), why, n) != NULL) return why;
    }
#if N_PARAMETER_CHECKS > 0
    {
        double h[N_PARAMETER_CHECKS];
        if (model_parameter_check(d->p, h, &inst->work)) {
            snprintf(why, n, "the relations between the parameters could not be evaluated");
            return why;
        }
        for (int k = 0; k < N_PARAMETER_CHECKS; k++) {
            if (!(h[k] >= -PARAMETER_CHECK_TOLERANCE)) {
                snprintf(why, n, "the parameters break %s (%.6g)", MODEL_PARAMETER_CHECK_NAMES[k], h[k]);
                return why;
            }
        }
    }
#else
    (void)inst;
#endif
    return NULL;
}

/* Set Real or Integer values (one of real, integer): everything is checked before anything is written,
 * so that a refused call changes nothing. */
static fmi2Status set_values(Instance *inst, const char *function, int is_integer, const fmi2ValueReference vr[],
                             size_t nvr, const fmi2Real real[], const fmi2Integer integer[]) {
    FmuData *d = &inst->d;
    int invalidate = 0, any_parameter = 0;
    char why[512];
    if (check_references(inst, function, is_integer, vr, nvr) != fmi2OK) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const double x = is_integer ? (double)integer[i] : real[i];
        if (refuse_value(inst, &MODEL_VARS[vr[i]], x, why, sizeof(why)) != NULL) {
            return fmu_error(inst, "%s: %s", function, why);
        }
    }
#if N_PARAMETER_CHECKS > 0
    /* tunable parameters are Reals: an Integer call sets none */
    if (!is_integer && check_parameter_relations(inst, function, vr, nvr, real) != fmi2OK) return fmi2Error;
#endif
    for (size_t i = 0; i < nvr; i++) {
        const VarInfo *v = &MODEL_VARS[vr[i]];
        const double x = is_integer ? (double)integer[i] : real[i];
        if (v->kind == VAR_INPUT) rebase_law(d, v->index);
        /* Model Exchange: an input or parameter that jumps at the last completed step's time */
        if ((v->kind == VAR_INPUT || v->kind == VAR_PARAMETER) && *fmu_slot(d, v) != x &&
            d->time == d->energy_last.time) {
            fmu_energy_forget(d);
        }
        *fmu_slot(d, v) = x;
        if (v->kind == VAR_START_Q) d->q[v->index] = x;       /* before initialization only */
        if (v->kind == VAR_START_V) d->v[v->index] = x;
        if (v->kind == VAR_PARAMETER && d->phase == PHASE_STEP) invalidate = 1;
        if (v->kind == VAR_PARAMETER) d->omega_max_known = 0;   /* order 4's check looks again */
        if (v->kind == VAR_PARAMETER) any_parameter = 1;
    }
    if (invalidate) {
        ss22_invalidate(&d->ss22);
        d->richardson.valid = 0;      /* order 4's misses, like SS22's own, were the old parameters' */
    }
    if (any_parameter) fmu_consistent_forget(d);
    if (nvr > 0) d->outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmu_set_real(Instance *inst, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    return set_values(inst, "fmi2SetReal", 0, vr, nvr, value, NULL);
}

fmi2Status fmu_set_integer(Instance *inst, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    return set_values(inst, "fmi2SetInteger", 1, vr, nvr, NULL, value);
}
