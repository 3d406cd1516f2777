/* cosimulation.c -- see cosimulation.h. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include "cosimulation.h"
#include "linalg.h"

const char *const LOG_CATEGORY_NAMES[N_LOG_CATEGORIES] = {
    "logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError", "logAll"};

#define STATIC_MAX_ITERATIONS 50
#define SUBSTEP_MAX 8              /* a failed internal step is retried as 2, 4, ... SUBSTEP_MAX sub-steps */

/* ====================================================================== logging */

/* The logger's message is a printf format that may reference variables as #r12#: escape '%' and '#'. */
static void escape_message(const char *in, char *out, size_t n) {
    size_t j = 0;
    for (size_t i = 0; in[i] != '\0' && j + 3 < n; i++) {
        if (in[i] == '%' || in[i] == '#') out[j++] = in[i];
        out[j++] = in[i];
    }
    out[j] = '\0';
}

static const char *status_category(fmi2Status status, LogCategory category) {
    switch (status) {
    case fmi2Warning: return LOG_CATEGORY_NAMES[LOG_STATUS_WARNING];
    case fmi2Discard: return LOG_CATEGORY_NAMES[LOG_STATUS_DISCARD];
    case fmi2Error:
    case fmi2Fatal: return LOG_CATEGORY_NAMES[LOG_STATUS_ERROR];
    default: return LOG_CATEGORY_NAMES[category];
    }
}

static void vlog_to(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                    LogCategory category, char *buf, size_t nbuf, char *escaped, size_t nescaped,
                    const char *format, va_list ap) {
    if (cb == NULL || cb->logger == NULL) return;
    vsnprintf(buf, nbuf, format, ap);
    escape_message(buf, escaped, nescaped);
    cb->logger(cb->componentEnvironment, name != NULL ? name : "?", status, status_category(status, category),
               escaped);
}

/* Before an instance exists (fmi2Instantiate refusing to create one). */
static void log_callbacks(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                          const char *format, ...) {
    char buf[1024], escaped[2048];
    va_list ap;
    va_start(ap, format);
    vlog_to(cb, name, status, LOG_STATUS_ERROR, buf, sizeof(buf), escaped, sizeof(escaped), format, ap);
    va_end(ap);
}

int fmu_logs(const Instance *inst, LogCategory category) {
    return inst->logging_on && (inst->category_on[category] || inst->category_on[LOG_ALL]);
}

void fmu_log(Instance *inst, fmi2Status status, LogCategory category, const char *format, ...) {
    va_list ap;
    if (status < fmi2Warning && !fmu_logs(inst, category)) return;
    va_start(ap, format);
    vlog_to(&inst->cb, inst->name, status, category, inst->message, sizeof(inst->message), inst->escaped,
            sizeof(inst->escaped), format, ap);
    va_end(ap);
}

fmi2Status fmu_error(Instance *inst, const char *format, ...) {
    va_list ap;
    va_start(ap, format);
    vlog_to(&inst->cb, inst->name, fmi2Error, LOG_STATUS_ERROR, inst->message, sizeof(inst->message),
            inst->escaped, sizeof(inst->escaped), format, ap);
    va_end(ap);
    return fmi2Error;
}

fmi2Status fmu_set_debug_logging(Instance *inst, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    int wanted[N_LOG_CATEGORIES] = {0};
    if (n > 0 && categories == NULL) {
        return fmu_error(inst, "fmi2SetDebugLogging: categories is NULL with nCategories = %zu", n);
    }
    for (size_t i = 0; i < n; i++) {
        int found = 0;
        if (categories[i] == NULL) {
            return fmu_error(inst, "fmi2SetDebugLogging: category %zu is NULL", i);
        }
        for (int k = 0; k < N_LOG_CATEGORIES; k++) {
            if (strcmp(categories[i], LOG_CATEGORY_NAMES[k]) == 0) { wanted[k] = 1; found = 1; }
        }
        if (!found) {
            return fmu_error(inst, "fmi2SetDebugLogging: unknown log category \"%s\" (known: logEvents, "
                             "logStatusWarning, logStatusDiscard, logStatusError, logAll)", categories[i]);
        }
    }
    inst->logging_on = on ? 1 : 0;
    for (int k = 0; k < N_LOG_CATEGORIES; k++) {
        if (n == 0 || wanted[k]) inst->category_on[k] = on ? 1 : 0;
    }
    return fmi2OK;
}

/* ==================================================================== variables */

static double *slot(FmuData *d, const VarInfo *v) {
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

/* The generated table is trusted, but one wrong index would write out of bounds: check it once. */
static int check_model_table(const char **bad) {
    for (int vr = 0; vr < N_VARS; vr++) {
        const VarInfo *v = &MODEL_VARS[vr];
        int size = 0;
        switch (v->kind) {
        case VAR_PARAMETER: size = N_P; break;
        case VAR_START_Q:
        case VAR_START_V: size = N_Q; break;
        case VAR_SOLVER: size = N_SOLVER_SETTINGS; break;
        case VAR_INPUT: size = N_U; break;
        case VAR_OUTPUT: size = N_Y; break;
        case VAR_STATE_Q:
        case VAR_STATE_V:
        case VAR_DER_Q:
        case VAR_DER_V: size = N_Q; break;
        }
        if (v->index < 0 || v->index >= size) { *bad = v->name; return 0; }
    }
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) {
        if (MODEL_LAWS[k].u_offset < 0 || MODEL_LAWS[k].u_offset + 3 > N_U) {
            *bad = "a kinematic law";
            return 0;
        }
    }
#endif
#if N_STATIC > 0
    for (int i = 0; i < N_STATIC; i++) {
        if (MODEL_STATIC_COORDS[i] < 0 || MODEL_STATIC_COORDS[i] >= N_Q) {
            *bad = "a static coordinate";
            return 0;
        }
    }
#endif
    return 1;
}

static const char *solver_name(int setting) {
    static const char *const fallback[N_SOLVER_SETTINGS] = {
        "solver.step", "solver.theta1", "solver.theta2", "solver.tolerance", "solver.order"};
    for (int vr = 0; vr < N_VARS; vr++) {
        if (MODEL_VARS[vr].kind == VAR_SOLVER && MODEL_VARS[vr].index == setting) return MODEL_VARS[vr].name;
    }
    return fallback[setting];
}

static void set_start_values(FmuData *d) {
    memset(d, 0, sizeof(*d));
    d->phase = PHASE_INSTANTIATED;
    d->solver[SOLVER_THETA1] = 0.5;
    d->solver[SOLVER_THETA2] = 0.5;
    d->solver[SOLVER_TOLERANCE] = 1e-10;
    d->solver[SOLVER_ORDER] = 2;
#ifdef DEFAULT_STEP
    d->solver[SOLVER_STEP] = DEFAULT_STEP;
#endif
    for (int vr = 0; vr < N_VARS; vr++) {
        const VarInfo *v = &MODEL_VARS[vr];
        *slot(d, v) = v->start;
    }
    memcpy(d->q, d->q_start, sizeof(d->q));
    memcpy(d->v, d->v_start, sizeof(d->v));
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
static void model_inputs(const FmuData *d, double t, double *u) {
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

static int all_finite(const double *x, int n) {
    for (int i = 0; i < n; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

/* The consistent acceleration M(q) a = -r(q, v, 0, u, p) at d->time, then the outputs. */
static fmi2Status update_outputs(Instance *inst, const char *function) {
    FmuData *d = &inst->d;
    fmi2Status status = fmi2OK;
    if (d->outputs_valid) return fmi2OK;
    model_inputs(d, d->time, inst->u0);
    if (model_residual(d->q, d->v, inst->zero, inst->u0, d->p, inst->r, &inst->work) ||
        model_newton_matrix(d->q, d->v, inst->zero, inst->u0, d->p, 1.0, 0.0, 0.0, inst->J, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", function, d->time);
    }
    if (all_finite(inst->J, N_Q * N_Q) && lu_factor(inst->J, N_Q, inst->piv) == 0) {
        for (int i = 0; i < N_Q; i++) d->acceleration[i] = -inst->r[i];
        lu_solve(inst->J, N_Q, inst->piv, d->acceleration);
        d->acceleration_ok = all_finite(d->acceleration, N_Q);
    } else {
        d->acceleration_ok = 0;
    }
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

/* ================================================================ get and set */

fmi2Status fmu_get_real(Instance *inst, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    int need_outputs = 0;
    fmi2Status status = fmi2OK;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= (fmi2ValueReference)N_VARS) {
            return fmu_error(inst, "fmi2GetReal: unknown value reference %u", vr[i]);
        }
        if (MODEL_VARS[vr[i]].kind == VAR_OUTPUT || MODEL_VARS[vr[i]].kind == VAR_DER_V) need_outputs = 1;
    }
    if (need_outputs) {
        status = update_outputs(inst, "fmi2GetReal");
        if (status > fmi2Warning) return status;
    }
    for (size_t i = 0; i < nvr; i++) value[i] = *slot(&inst->d, &MODEL_VARS[vr[i]]);
    return status;
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
    } else if (!isfinite(x)) {
        snprintf(why, n, "%s = %g: NaN and infinite values are refused", v->name, x);
    } else if (v->min_exclusive ? !(x > v->min) : !(x >= v->min)) {
        snprintf(why, n, "%s = %.15g: must be %s %.15g", v->name, x, v->min_exclusive ? ">" : ">=", v->min);
    } else if (!(x <= v->max)) {
        snprintf(why, n, "%s = %.15g: must be <= %.15g", v->name, x, v->max);
    } else {
        return NULL;
    }
    return why;
}

fmi2Status fmu_set_real(Instance *inst, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    FmuData *d = &inst->d;
    int invalidate = 0;
    char why[512];
    for (size_t i = 0; i < nvr; i++) {                 /* check everything before writing anything */
        if (vr[i] >= (fmi2ValueReference)N_VARS) {
            return fmu_error(inst, "fmi2SetReal: unknown value reference %u", vr[i]);
        }
        if (refuse_value(inst, &MODEL_VARS[vr[i]], value[i], why, sizeof(why)) != NULL) {
            return fmu_error(inst, "fmi2SetReal: %s", why);
        }
    }
    for (size_t i = 0; i < nvr; i++) {
        const VarInfo *v = &MODEL_VARS[vr[i]];
        if (v->kind == VAR_INPUT) rebase_law(d, v->index);
        *slot(d, v) = value[i];
        if (v->kind == VAR_START_Q) d->q[v->index] = value[i];       /* before initialization only */
        if (v->kind == VAR_START_V) d->v[v->index] = value[i];
        if (v->kind == VAR_PARAMETER && d->phase == PHASE_STEP) invalidate = 1;
    }
    if (invalidate) ss22_invalidate(&d->ss22);
    if (nvr > 0) d->outputs_valid = 0;
    return fmi2OK;
}

/* ================================================================== lifecycle */

const char *fmu_phase_name(int phase) {
    switch (phase) {
    case PHASE_INSTANTIATED: return "instantiated";
    case PHASE_INITIALIZATION: return "initialization mode";
    case PHASE_STEP: return "step mode";
    case PHASE_TERMINATED: return "terminated";
    case PHASE_ERROR: return "error";
    case PHASE_FATAL: return "fatal";
    case PHASE_EVENT: return "event mode";
    case PHASE_CONTINUOUS: return "continuous-time mode";
    }
    return "unknown";
}

Instance *fmu_instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                          const fmi2CallbackFunctions *functions, fmi2Boolean logging_on) {
    Instance *inst;
    const char *bad = NULL;
    size_t len;
    if (functions == NULL) return NULL;                /* no logger to tell */
    if (functions->allocateMemory == NULL || functions->freeMemory == NULL) {
        log_callbacks(functions, name, fmi2Error,
                      "fmi2Instantiate: allocateMemory and freeMemory must not be NULL");
        return NULL;
    }
    if (name == NULL) {
        log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: instanceName must not be NULL");
        return NULL;
    }
    if (type != fmi2CoSimulation && type != fmi2ModelExchange) {
        log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: unknown fmuType %d", (int)type);
        return NULL;
    }
    if (guid == NULL || strcmp(guid, MODEL_GUID) != 0) {
        log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: GUID %s does not match this FMU's %s",
                      guid != NULL ? guid : "(NULL)", MODEL_GUID);
        return NULL;
    }
    if (!check_model_table(&bad)) {
        log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: the model's tables are inconsistent (%s)",
                      bad);
        return NULL;
    }
    inst = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    len = strlen(name);
    if (inst == NULL) {
        log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    memset(inst, 0, sizeof(*inst));
    inst->name = (char *)functions->allocateMemory(len + 1, 1);
    if (inst->name == NULL) {
        functions->freeMemory(inst);
        log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    memcpy(inst->name, name, len + 1);
    inst->cb = *functions;
    inst->logging_on = logging_on ? 1 : 0;
    for (int k = 0; k < N_LOG_CATEGORIES; k++) inst->category_on[k] = inst->logging_on;
    set_start_values(&inst->d);
    inst->d.model_exchange = type == fmi2ModelExchange;
    inst->magic = INSTANCE_MAGIC;
    return inst;
}

void fmu_free(Instance *inst) {
    fmi2CallbackFreeMemory free_memory = inst->cb.freeMemory;
    inst->magic = 0;
    free_memory(inst->name);
    free_memory(inst);
}

void fmu_reset(Instance *inst) {
    const int model_exchange = inst->d.model_exchange;
    set_start_values(&inst->d);
    inst->d.model_exchange = model_exchange;
}

fmi2Status fmu_setup_experiment(Instance *inst, fmi2Boolean tolerance_defined, fmi2Real tolerance,
                                fmi2Real start_time, fmi2Boolean stop_time_defined, fmi2Real stop_time) {
    FmuData *d = &inst->d;
    if (tolerance_defined && !(tolerance > 0.0 && isfinite(tolerance))) {
        return fmu_error(inst, "fmi2SetupExperiment: tolerance = %g: must be > 0", tolerance);
    }
    if (!isfinite(start_time)) {
        return fmu_error(inst, "fmi2SetupExperiment: startTime = %g: must be finite", start_time);
    }
    if (stop_time_defined && !(stop_time >= start_time && isfinite(stop_time))) {
        return fmu_error(inst, "fmi2SetupExperiment: stopTime = %g: must be finite and >= startTime = %g",
                         stop_time, start_time);
    }
    d->experiment_tolerance_defined = tolerance_defined ? 1 : 0;
    d->experiment_tolerance = tolerance_defined ? tolerance : 0.0;
    d->start_time = start_time;
    d->stop_time_defined = stop_time_defined ? 1 : 0;
    d->stop_time = stop_time_defined ? stop_time : 0.0;
    d->time = start_time;
    d->last_successful_time = start_time;
    for (int k = 0; k < N_LAWS; k++) d->law_time[k] = start_time;   /* inputs set so far hold at the start */
    d->outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmu_enter_initialization(Instance *inst) {
    inst->d.phase = PHASE_INITIALIZATION;
    inst->d.outputs_valid = 0;
    return fmi2OK;
}

#if N_STATIC > 0
/* Newton on r_S(q, v_start, a = 0, u with law accelerations 0) = 0 for the coordinates S. */
static fmi2Status static_equilibrium(Instance *inst, double tolerance) {
    FmuData *d = &inst->d;
    const int S = N_STATIC;
    model_inputs(d, d->time, inst->u0);
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) inst->u0[MODEL_LAWS[k].u_offset + 2] = 0.0;
#endif
    for (int it = 1; it <= STATIC_MAX_ITERATIONS; it++) {
        int converged = 1;
        if (model_residual(d->q, d->v, inst->zero, inst->u0, d->p, inst->r, &inst->work) ||
            model_newton_matrix(d->q, d->v, inst->zero, inst->u0, d->p, 0.0, 0.0, 1.0, inst->J,
                                &inst->work)) {
            return fmu_error(inst, "fmi2ExitInitializationMode: static equilibrium: the model failed to "
                             "evaluate");
        }
        for (int i = 0; i < S; i++) {
            inst->dq[i] = -inst->r[MODEL_STATIC_COORDS[i]];
            for (int j = 0; j < S; j++) {
                inst->Js[i + j * S] = inst->J[MODEL_STATIC_COORDS[i] + MODEL_STATIC_COORDS[j] * N_Q];
            }
        }
        if (!all_finite(inst->dq, S) || !all_finite(inst->Js, S * S)) {
            return fmu_error(inst, "fmi2ExitInitializationMode: static equilibrium: NaN or infinite residual "
                             "at iteration %d", it);
        }
        if (lu_factor(inst->Js, S, inst->piv) != 0) {
            return fmu_error(inst, "fmi2ExitInitializationMode: static equilibrium: the stiffness matrix of "
                             "the static coordinates is singular (no stiffness holds them?)");
        }
        lu_solve(inst->Js, S, inst->piv, inst->dq);
        for (int i = 0; i < S; i++) {
            const int c = MODEL_STATIC_COORDS[i];
            d->q[c] += inst->dq[i];
            if (!(fabs(inst->dq[i]) <= tolerance * MODEL_NOMINAL_Q[c])) converged = 0;
        }
        if (converged) {
            fmu_log(inst, fmi2OK, LOG_EVENTS, "static equilibrium of %d coordinates found in %d Newton "
                    "iterations", S, it);
            return fmi2OK;
        }
    }
    return fmu_error(inst, "fmi2ExitInitializationMode: static equilibrium: Newton did not converge in %d "
                     "iterations (tolerance %g)", STATIC_MAX_ITERATIONS, tolerance);
}
#endif

fmi2Status fmu_exit_initialization(Instance *inst) {
    FmuData *d = &inst->d;
    const double step = d->solver[SOLVER_STEP], theta1 = d->solver[SOLVER_THETA1];
    const double theta2 = d->solver[SOLVER_THETA2];
    double tolerance = d->solver[SOLVER_TOLERANCE];
    fmi2Status status;
    if (!(step > 0.0 && isfinite(step))) {
        return fmu_error(inst, "fmi2ExitInitializationMode: %s = %g: must be > 0",
                         solver_name(SOLVER_STEP), step);
    }
    if (!(theta1 >= 0.5 && theta2 >= theta1 && theta2 <= 1.0)) {
        return fmu_error(inst, "fmi2ExitInitializationMode: SS22 needs 0.5 <= %s <= %s <= 1 (unconditional "
                         "stability), got %g and %g", solver_name(SOLVER_THETA1), solver_name(SOLVER_THETA2),
                         theta1, theta2);
    }
    if (!(tolerance > 0.0 && isfinite(tolerance))) {
        return fmu_error(inst, "fmi2ExitInitializationMode: %s = %g: must be > 0",
                         solver_name(SOLVER_TOLERANCE), tolerance);
    }
    if (d->solver[SOLVER_ORDER] != 2 && d->solver[SOLVER_ORDER] != 4) {
        return fmu_error(inst, "fmi2ExitInitializationMode: %s = %g: must be 2 (SS22) or 4 (SS22 with "
                         "Richardson extrapolation)", solver_name(SOLVER_ORDER), d->solver[SOLVER_ORDER]);
    }
    if (d->solver[SOLVER_ORDER] == 4 && !(theta1 == 0.5 && theta2 == 0.5)) {
        return fmu_error(inst, "fmi2ExitInitializationMode: %s = 4 extrapolates the symmetric SS22: it needs "
                         "%s = %s = 0.5, got %g and %g", solver_name(SOLVER_ORDER), solver_name(SOLVER_THETA1),
                         solver_name(SOLVER_THETA2), theta1, theta2);
    }
    /* the host's experiment tolerance may tighten the Newton tolerance, never loosen it */
    if (d->experiment_tolerance_defined && d->experiment_tolerance < tolerance) {
        tolerance = d->experiment_tolerance;
    }
    memcpy(d->q, d->q_start, sizeof(d->q));
    memcpy(d->v, d->v_start, sizeof(d->v));
#if N_STATIC > 0
    if (static_equilibrium(inst, tolerance) != fmi2OK) return fmi2Error;
#endif
    ss22_init(&d->ss22, theta1, theta2, tolerance);
    memset(d->alpha, 0, sizeof(d->alpha));
    d->outputs_valid = 0;
    status = update_outputs(inst, "fmi2ExitInitializationMode");
    if (status > fmi2Warning) return status;
    memcpy(d->alpha, d->acceleration, sizeof(d->alpha));
    d->last_successful_time = d->time;
    d->phase = d->model_exchange ? PHASE_EVENT : PHASE_STEP;
    fmu_log(inst, fmi2OK, LOG_EVENTS, "initialized at t = %.17g (SS22: step %g, theta1 %g, theta2 %g, "
            "tolerance %g)",
            d->time, step, theta1, theta2, tolerance);
    return status;
}

/* ====================================================================== doStep */

static SS22Status ss22_from(Instance *inst, double t0, double t1) {
    FmuData *d = &inst->d;
    model_inputs(d, t0, inst->u0);
    model_inputs(d, t1, inst->u1);
    return ss22_step(&d->ss22, t1 - t0, d->q, d->v, d->alpha, inst->u0, inst->u1, d->p, &inst->work);
}

/* One internal step [t0, t1]; if SS22 fails, again as 2, 4, ... SUBSTEP_MAX sub-steps. */
/* Order 4: the symmetric SS22 (Θ = ½) has an error expansion in even powers of Δt, so one step of Δt and
 * two of Δt/2 combine into q = q_half + (q_half − q_full)/3, fourth-order accurate (Richardson). */
static SS22Status richardson_step(Instance *inst, double t0, double t1) {
    FmuData *d = &inst->d;
    double q0[N_Q], v0[N_Q], a0[N_Q], q1[N_Q], v1[N_Q];
    SS22Status status;
    memcpy(q0, d->q, sizeof(q0));
    memcpy(v0, d->v, sizeof(v0));
    memcpy(a0, d->alpha, sizeof(a0));
    status = ss22_from(inst, t0, t1);
    if (status == SS22_OK) {
        memcpy(q1, d->q, sizeof(q1));
        memcpy(v1, d->v, sizeof(v1));
        memcpy(d->q, q0, sizeof(q0));
        memcpy(d->v, v0, sizeof(v0));
        memcpy(d->alpha, a0, sizeof(a0));
        const double tm = t0 + 0.5 * (t1 - t0);
        status = ss22_from(inst, t0, tm);
        if (status == SS22_OK) status = ss22_from(inst, tm, t1);
    }
    if (status != SS22_OK) {
        memcpy(d->q, q0, sizeof(q0));
        memcpy(d->v, v0, sizeof(v0));
        memcpy(d->alpha, a0, sizeof(a0));
        return status;
    }
    for (int i = 0; i < N_Q; i++) {
        d->q[i] += (d->q[i] - q1[i]) / 3.0;
        d->v[i] += (d->v[i] - v1[i]) / 3.0;
    }
    return SS22_OK;
}

static SS22Status one_step(Instance *inst, double t0, double t1) {
    return inst->d.solver[SOLVER_ORDER] == 4 ? richardson_step(inst, t0, t1) : ss22_from(inst, t0, t1);
}

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
    memcpy(&inst->backup, d, sizeof(*d));
    t = d->time;
    /* n equal internal steps of at most solver.step: never overshooting, and no odd short last step.
     * SS22 with Θ1 = ½ < Θ2 is only marginally stable in unresolved modes, and alternating step sizes
     * (a regular step, then a tiny remainder) can pump energy into them: equal steps keep the step
     * constant over a run with a constant communication step (tests/test_ss22_numerics.py). */
    {
        const double ratio = h / step;
        long n = (long)ceil(ratio - 1e-9 * fmax(1.0, ratio));
        if (n < 1) n = 1;
        for (long i = 1; i <= n; i++) {
            const double t_next = (i == n) ? t_end : tc + h * ((double)i / (double)n);
            SS22Status status = internal_step(inst, t, t_next);
            if (status != SS22_OK) {
                memcpy(d, &inst->backup, sizeof(*d));
                fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD,
                        "fmi2DoStep: the SS22 step at t = %.17g failed: %s (also as %d sub-steps); the step "
                        "from %.17g to %.17g is discarded and the FMU is back at t = %.17g", t,
                        ss22_status_message(status), SUBSTEP_MAX, tc, t_end, d->time);
                return fmi2Discard;
            }
            t = t_next;
        }
    }
    d->time = t_end;
    d->last_successful_time = t_end;
    d->outputs_valid = 0;
    return fmi2OK;
}

/* ============================================================= Model Exchange */

fmi2Status fmu_set_time(Instance *inst, fmi2Real time) {
    if (!isfinite(time)) return fmu_error(inst, "fmi2SetTime: time = %g: must be finite", time);
    inst->d.time = time;
    inst->d.outputs_valid = 0;
    return fmi2OK;
}

static fmi2Status check_nx(Instance *inst, const char *function, size_t nx) {
    if (nx != (size_t)N_STATES) {
        return fmu_error(inst, "%s: nx = %zu, this FMU has %d continuous states", function, nx, N_STATES);
    }
    return fmi2OK;
}

fmi2Status fmu_set_states(Instance *inst, const fmi2Real x[], size_t nx) {
    if (check_nx(inst, "fmi2SetContinuousStates", nx) != fmi2OK) return fmi2Error;
    for (int i = 0; i < N_STATES; i++) {
        if (!isfinite(x[i])) {
            return fmu_error(inst, "fmi2SetContinuousStates: x[%d] = %g: NaN and infinite values are refused",
                             i, x[i]);
        }
    }
    memcpy(inst->d.q, x, sizeof(inst->d.q));
    memcpy(inst->d.v, x + N_Q, sizeof(inst->d.v));
    inst->d.outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmu_get_states(Instance *inst, fmi2Real x[], size_t nx) {
    if (check_nx(inst, "fmi2GetContinuousStates", nx) != fmi2OK) return fmi2Error;
    memcpy(x, inst->d.q, sizeof(inst->d.q));
    memcpy(x + N_Q, inst->d.v, sizeof(inst->d.v));
    return fmi2OK;
}

/* dx/dt = (v, a) with M(q) a = -r(q, v, 0, u(t), p): the consistent acceleration of the outputs. */
fmi2Status fmu_get_derivatives(Instance *inst, fmi2Real dx[], size_t nx) {
    fmi2Status status;
    if (check_nx(inst, "fmi2GetDerivatives", nx) != fmi2OK) return fmi2Error;
    status = update_outputs(inst, "fmi2GetDerivatives");
    if (status > fmi2Warning) return status;
    if (!inst->d.acceleration_ok) {
        fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2GetDerivatives: no acceleration at t = %.17g "
                "(singular mass matrix or NaN): try other states", inst->d.time);
        return fmi2Discard;
    }
    memcpy(dx, inst->d.v, sizeof(inst->d.v));
    memcpy(dx + N_Q, inst->d.acceleration, sizeof(inst->d.acceleration));
    return fmi2OK;
}

/* Positions: the model's nominal magnitudes; rates: the same per second. */
fmi2Status fmu_get_nominals(Instance *inst, fmi2Real x_nominal[], size_t nx) {
    if (check_nx(inst, "fmi2GetNominalsOfContinuousStates", nx) != fmi2OK) return fmi2Error;
    for (int i = 0; i < N_Q; i++) x_nominal[i] = x_nominal[N_Q + i] = MODEL_NOMINAL_Q[i];
    return fmi2OK;
}

/* No discrete states and no state events; the only events are the time events at the segment
 * boundaries of the built-in kinematic laws (where a law's acceleration may jump). */
fmi2Status fmu_new_discrete_states(Instance *inst, fmi2EventInfo *info) {
    double next = INFINITY;
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) {
        const KinematicLaw *law = &MODEL_LAWS[k];
        if (!law->builtin) continue;
        for (int j = 0; j < law->n_segments; j++) {
            const double until = law->segments[j].until;
            if (until > inst->d.time && until < 1e299 && until < next) next = until;
        }
    }
#endif
    info->newDiscreteStatesNeeded = fmi2False;
    info->terminateSimulation = fmi2False;
    info->nominalsOfContinuousStatesChanged = fmi2False;
    info->valuesOfContinuousStatesChanged = fmi2False;
    info->nextEventTimeDefined = isfinite(next) ? fmi2True : fmi2False;
    info->nextEventTime = isfinite(next) ? next : 0.0;
    if (isfinite(next)) fmu_log(inst, fmi2OK, LOG_EVENTS, "next time event at t = %.17g", next);
    return fmi2OK;
}

/* ==================================================== directional derivatives */

fmi2Status fmu_directional_derivative(Instance *inst, const fmi2ValueReference unknown[], size_t n_unknown,
                                      const fmi2ValueReference known[], size_t n_known, const fmi2Real dv_known[],
                                      fmi2Real dv_unknown[]) {
    static const char *const F = "fmi2GetDirectionalDerivative";
    FmuData *d = &inst->d;
    fmi2Status status;
    int need_y = 0;
    memset(inst->dd_q, 0, sizeof(inst->dd_q));
    memset(inst->dd_v, 0, sizeof(inst->dd_v));
    memset(inst->dd_u, 0, sizeof(inst->dd_u));
    memset(inst->dd_p, 0, sizeof(inst->dd_p));
    for (size_t i = 0; i < n_known; i++) {
        const VarInfo *v;
        if (known[i] >= (fmi2ValueReference)N_VARS) return fmu_error(inst, "%s: unknown value reference %u", F,
                                                                     known[i]);
        v = &MODEL_VARS[known[i]];
        if (!isfinite(dv_known[i])) return fmu_error(inst, "%s: dvKnown[%zu] = %g: must be finite", F, i,
                                                     dv_known[i]);
        switch (v->kind) {
        case VAR_STATE_Q: inst->dd_q[v->index] += dv_known[i]; break;
        case VAR_STATE_V: inst->dd_v[v->index] += dv_known[i]; break;
        case VAR_INPUT: inst->dd_u[v->index] += dv_known[i]; break;
        case VAR_PARAMETER: inst->dd_p[v->index] += dv_known[i]; break;
        default:
            return fmu_error(inst, "%s: %s (value reference %u) is not a known: knowns are the continuous "
                             "states, the inputs and the tunable parameters", F, v->name, known[i]);
        }
    }
    for (size_t i = 0; i < n_unknown; i++) {
        int kind;
        if (unknown[i] >= (fmi2ValueReference)N_VARS) return fmu_error(inst, "%s: unknown value reference %u",
                                                                       F, unknown[i]);
        kind = MODEL_VARS[unknown[i]].kind;
        if (kind == VAR_OUTPUT) need_y = 1;
        if (kind != VAR_OUTPUT && kind != VAR_DER_Q && kind != VAR_DER_V && kind != VAR_STATE_Q &&
            kind != VAR_STATE_V) {
            return fmu_error(inst, "%s: %s (value reference %u) is not an unknown: unknowns are the outputs, "
                             "the state derivatives and the states", F, MODEL_VARS[unknown[i]].name, unknown[i]);
        }
    }
    /* the inputs as the model sees them: a host-driven law is extended from its time to now */
    memcpy(inst->dd_um, inst->dd_u, sizeof(inst->dd_u));
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) {
        const int o = MODEL_LAWS[k].u_offset;
        const double s = d->time - d->law_time[k];
        if (MODEL_LAWS[k].builtin) {
            inst->dd_um[o] = inst->dd_um[o + 1] = inst->dd_um[o + 2] = 0.0;
        } else {
            inst->dd_um[o] = inst->dd_u[o] + s * (inst->dd_u[o + 1] + 0.5 * s * inst->dd_u[o + 2]);
            inst->dd_um[o + 1] = inst->dd_u[o + 1] + s * inst->dd_u[o + 2];
        }
    }
#endif
    status = update_outputs(inst, F);
    if (status > fmi2Warning) return status;
    if (!d->acceleration_ok) {
        return fmu_error(inst, "%s: no consistent acceleration at t = %.17g (singular mass matrix)", F, d->time);
    }
    memset(inst->dd_a, 0, sizeof(inst->dd_a));
    model_inputs(d, d->time, inst->u0);
    if (model_residual_forward(d->q, d->v, d->acceleration, inst->u0, d->p, inst->dd_q, inst->dd_v, inst->dd_a,
                               inst->dd_um, inst->dd_p, inst->dd_r, &inst->work) ||
        model_newton_matrix(d->q, d->v, d->acceleration, inst->u0, d->p, 1.0, 0.0, 0.0, inst->J, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", F, d->time);
    }
    if (lu_factor(inst->J, N_Q, inst->piv) != 0) {
        return fmu_error(inst, "%s: singular mass matrix at t = %.17g", F, d->time);
    }
    for (int i = 0; i < N_Q; i++) inst->dd_a[i] = -inst->dd_r[i];
    lu_solve(inst->J, N_Q, inst->piv, inst->dd_a);
    if (need_y && model_outputs_forward(d->q, d->v, d->acceleration, inst->u0, d->p, inst->dd_q, inst->dd_v,
                                        inst->dd_a, inst->dd_um, inst->dd_p, inst->dd_y, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate its outputs at t = %.17g", F, d->time);
    }
    for (size_t i = 0; i < n_unknown; i++) {
        const VarInfo *v = &MODEL_VARS[unknown[i]];
        switch (v->kind) {
        case VAR_OUTPUT: dv_unknown[i] = inst->dd_y[v->index]; break;
        case VAR_DER_Q:
        case VAR_STATE_V: dv_unknown[i] = inst->dd_v[v->index]; break;
        case VAR_DER_V: dv_unknown[i] = inst->dd_a[v->index]; break;
        case VAR_STATE_Q: dv_unknown[i] = inst->dd_q[v->index]; break;
        default: dv_unknown[i] = 0.0; break;
        }
    }
    if (!all_finite(dv_unknown, (int)n_unknown)) {
        return fmu_error(inst, "%s: NaN or infinite derivative at t = %.17g", F, d->time);
    }
    return status;
}

/* ================================================================= FMU state */

static int state_ok(const SavedState *s) {
    return s != NULL && s->magic == STATE_MAGIC;
}

fmi2Status fmu_get_state(Instance *inst, fmi2FMUstate *state) {
    SavedState *s = (SavedState *)*state;
    if (s != NULL && !state_ok(s)) {
        return fmu_error(inst, "fmi2GetFMUstate: *FMUstate is neither NULL nor a state of this FMU");
    }
    if (s == NULL) {
        s = (SavedState *)inst->cb.allocateMemory(1, sizeof(SavedState));
        if (s == NULL) {
            return fmu_error(inst, "fmi2GetFMUstate: out of memory");
        }
        memset(s, 0, sizeof(*s));
        s->magic = STATE_MAGIC;
    }
    memcpy(&s->d, &inst->d, sizeof(s->d));
    *state = s;
    return fmi2OK;
}

fmi2Status fmu_set_state(Instance *inst, fmi2FMUstate state) {
    const SavedState *s = (const SavedState *)state;
    if (!state_ok(s)) {
        return fmu_error(inst, "fmi2SetFMUstate: not a state of this FMU (NULL or freed)");
    }
    memcpy(&inst->d, &s->d, sizeof(inst->d));
    return fmi2OK;
}

fmi2Status fmu_free_state(Instance *inst, fmi2FMUstate *state) {
    SavedState *s = (SavedState *)*state;
    if (s == NULL) return fmi2OK;
    if (!state_ok(s)) {
        return fmu_error(inst, "fmi2FreeFMUstate: not a state of this FMU (already freed?)");
    }
    s->magic = 0;
    inst->cb.freeMemory(s);
    *state = NULL;
    return fmi2OK;
}

/* Serialized layout: magic (8 bytes) | MODEL_GUID with its NUL | payload size (uint64) |
 * FNV-1a checksum of the payload (uint64) | the FmuData bytes.  Same machine and build only. */
static const char SERIAL_MAGIC[8] = {'F', 'L', 'X', 'S', 'T', 'A', 'T', '1'};
#define GUID_BYTES sizeof(MODEL_GUID)
#define HEADER_BYTES (sizeof(SERIAL_MAGIC) + GUID_BYTES + 2 * sizeof(uint64_t))

static uint64_t checksum(const unsigned char *p, size_t n) {
    uint64_t h = 14695981039346656037ULL;
    for (size_t i = 0; i < n; i++) {
        h ^= p[i];
        h *= 1099511628211ULL;
    }
    return h;
}

size_t fmu_serialized_size(void) {
    return HEADER_BYTES + sizeof(FmuData);
}

fmi2Status fmu_serialize(Instance *inst, fmi2FMUstate state, fmi2Byte buffer[], size_t size) {
    const SavedState *s = (const SavedState *)state;
    const uint64_t payload = sizeof(FmuData);
    uint64_t sum;
    unsigned char *b = (unsigned char *)buffer;
    if (!state_ok(s)) {
        return fmu_error(inst, "fmi2SerializeFMUstate: not a state of this FMU");
    }
    if (size < fmu_serialized_size()) {
        return fmu_error(inst, "fmi2SerializeFMUstate: buffer of %zu bytes, %zu needed", size,
                         fmu_serialized_size());
    }
    sum = checksum((const unsigned char *)&s->d, sizeof(s->d));
    memcpy(b, SERIAL_MAGIC, sizeof(SERIAL_MAGIC));
    b += sizeof(SERIAL_MAGIC);
    memcpy(b, MODEL_GUID, GUID_BYTES);
    b += GUID_BYTES;
    memcpy(b, &payload, sizeof(payload));
    b += sizeof(payload);
    memcpy(b, &sum, sizeof(sum));
    b += sizeof(sum);
    memcpy(b, &s->d, sizeof(s->d));
    return fmi2OK;
}

/* Beyond the checksum: nothing in a state may lead to an out-of-bounds access. */
static const char *invalid_data(const FmuData *d) {
    const int phases[] = {PHASE_INSTANTIATED, PHASE_INITIALIZATION, PHASE_STEP, PHASE_TERMINATED, PHASE_ERROR,
                          PHASE_FATAL, PHASE_EVENT, PHASE_CONTINUOUS};
    int phase_ok = 0;
    for (size_t k = 0; k < sizeof(phases) / sizeof(phases[0]); k++) phase_ok |= d->phase == phases[k];
    if (!phase_ok) return "state machine";
    if ((d->outputs_valid | d->acceleration_ok | d->stop_time_defined | d->experiment_tolerance_defined |
         d->model_exchange) & ~1)
        return "flags";
    if (d->ss22.max_iterations < 0 || d->ss22.max_iterations > 1000) return "solver settings";
    for (int k = 0; k < SS22_CACHE; k++) {
        const SS22Factor *f = &d->ss22.cache[k];
        if (f->valid & ~1) return "solver cache";
        for (int i = 0; i < N_Q && f->valid; i++) {
            if (f->piv[i] < i || f->piv[i] >= N_Q) return "solver cache";
        }
    }
    if (!isfinite(d->time) || !all_finite(d->q, N_Q) || !all_finite(d->v, N_Q)) return "time or state";
    return NULL;
}

fmi2Status fmu_deserialize(Instance *inst, const fmi2Byte buffer[], size_t size, fmi2FMUstate *state) {
    const unsigned char *b = (const unsigned char *)buffer;
    uint64_t payload, sum;
    SavedState *s, *target = (SavedState *)*state;
    const char *bad;
    if (target != NULL && !state_ok(target)) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: *FMUstate is neither NULL nor a state of "
                         "this FMU");
    }
    if (size != fmu_serialized_size()) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: %zu bytes, a state of this FMU has %zu", size,
                         fmu_serialized_size());
    }
    if (memcmp(b, SERIAL_MAGIC, sizeof(SERIAL_MAGIC)) != 0) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: not a serialized flexlink FMU state");
    }
    b += sizeof(SERIAL_MAGIC);
    if (memcmp(b, MODEL_GUID, GUID_BYTES) != 0) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state belongs to another FMU "
                         "(GUID differs from %s)", MODEL_GUID);
    }
    b += GUID_BYTES;
    memcpy(&payload, b, sizeof(payload));
    b += sizeof(payload);
    memcpy(&sum, b, sizeof(sum));
    b += sizeof(sum);
    if (payload != sizeof(FmuData)) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state was written by another build "
                         "of this FMU (payload size differs)");
    }
    if (checksum(b, sizeof(FmuData)) != sum) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state is corrupted (checksum)");
    }
    s = (SavedState *)inst->cb.allocateMemory(1, sizeof(SavedState));
    if (s == NULL) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: out of memory");
    }
    memset(s, 0, sizeof(*s));
    memcpy(&s->d, b, sizeof(s->d));
    if ((bad = invalid_data(&s->d)) != NULL) {
        inst->cb.freeMemory(s);
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state is invalid (%s)", bad);
    }
    if (target != NULL) {                              /* reuse the host's state, as fmi2GetFMUstate does */
        memcpy(&target->d, &s->d, sizeof(target->d));
        inst->cb.freeMemory(s);
        return fmi2OK;
    }
    s->magic = STATE_MAGIC;
    *state = s;
    return fmi2OK;
}
