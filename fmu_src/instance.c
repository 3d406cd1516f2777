/* instance.c -- an instance's life: fmi2Instantiate (with a check of the generated tables), start values,
 * reset and free, fmi2SetupExperiment and initialization (solver settings, static equilibrium).
 * See cosimulation.h. */
#include <math.h>
#include <string.h>
#include "internal.h"
#include "linalg.h"

/* STATIC_MAX_ITERATIONS and the solver's limits: solver_settings.h (from flexlink/scene/solver.py) */

/* ===================================================================== start values */

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
    d->solver[SOLVER_THETA1] = SOLVER_DEFAULT_THETA;
    d->solver[SOLVER_THETA2] = SOLVER_DEFAULT_THETA;
    d->solver[SOLVER_TOLERANCE] = SOLVER_DEFAULT_TOLERANCE;
    d->solver[SOLVER_ORDER] = SOLVER_ORDER_SS22;
#ifdef DEFAULT_STEP
    d->solver[SOLVER_STEP] = DEFAULT_STEP;
#endif
    for (int vr = 0; vr < N_VARS; vr++) {
        const VarInfo *v = &MODEL_VARS[vr];
        *fmu_slot(d, v) = v->start;
    }
    memcpy(d->q, d->q_start, sizeof(d->q));
    memcpy(d->v, d->v_start, sizeof(d->v));
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
        fmu_log_callbacks(functions, name, fmi2Error,
                          "fmi2Instantiate: allocateMemory and freeMemory must not be NULL");
        return NULL;
    }
    if (name == NULL) {
        fmu_log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: instanceName must not be NULL");
        return NULL;
    }
    if (type != fmi2CoSimulation && type != fmi2ModelExchange) {
        fmu_log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: unknown fmuType %d", (int)type);
        return NULL;
    }
    if (guid == NULL || strcmp(guid, MODEL_GUID) != 0) {
        fmu_log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: GUID %s does not match this FMU's %s",
                          guid != NULL ? guid : "(NULL)", MODEL_GUID);
        return NULL;
    }
    if (!check_model_table(&bad)) {
        fmu_log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: the model's tables are inconsistent (%s)",
                          bad);
        return NULL;
    }
    inst = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    len = strlen(name);
    if (inst == NULL) {
        fmu_log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    memset(inst, 0, sizeof(*inst));
    inst->name = (char *)functions->allocateMemory(len + 1, 1);
    if (inst->name == NULL) {
        functions->freeMemory(inst);
        fmu_log_callbacks(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
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
    fmu_free_all_states(inst);
    inst->magic = 0;
    free_memory(inst->name);
    free_memory(inst);
}

void fmu_reset(Instance *inst) {
    const int model_exchange = inst->d.model_exchange;
    set_start_values(&inst->d);
    inst->d.model_exchange = model_exchange;
    inst->step_discarded = 0;
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
    fmu_model_inputs(d, d->time, inst->u0);
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
        if (!fmu_all_finite(inst->dq, S) || !fmu_all_finite(inst->Js, S * S)) {
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
    if (!(theta1 >= SOLVER_THETA_MIN && theta2 >= theta1 && theta2 <= SOLVER_THETA_MAX)) {
        return fmu_error(inst, "fmi2ExitInitializationMode: SS22 needs %g <= %s <= %s <= %g (unconditional "
                         "stability), got %g and %g", SOLVER_THETA_MIN, solver_name(SOLVER_THETA1),
                         solver_name(SOLVER_THETA2), SOLVER_THETA_MAX, theta1, theta2);
    }
    if (!(tolerance > 0.0 && isfinite(tolerance))) {
        return fmu_error(inst, "fmi2ExitInitializationMode: %s = %g: must be > 0",
                         solver_name(SOLVER_TOLERANCE), tolerance);
    }
    if (d->solver[SOLVER_ORDER] != SOLVER_ORDER_SS22 && d->solver[SOLVER_ORDER] != SOLVER_ORDER_RICHARDSON) {
        return fmu_error(inst, "fmi2ExitInitializationMode: %s = %g: must be %d (SS22) or %d (SS22 with "
                         "Richardson extrapolation)", solver_name(SOLVER_ORDER), d->solver[SOLVER_ORDER],
                         SOLVER_ORDER_SS22, SOLVER_ORDER_RICHARDSON);
    }
    if (d->solver[SOLVER_ORDER] == SOLVER_ORDER_RICHARDSON &&
        !(theta1 == SOLVER_THETA_MIN && theta2 == SOLVER_THETA_MIN)) {
        return fmu_error(inst, "fmi2ExitInitializationMode: %s = %d extrapolates the symmetric SS22: it needs "
                         "%s = %s = %g, got %g and %g", solver_name(SOLVER_ORDER), SOLVER_ORDER_RICHARDSON,
                         solver_name(SOLVER_THETA1), solver_name(SOLVER_THETA2), SOLVER_THETA_MIN, theta1, theta2);
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
    memset(&d->richardson, 0, sizeof(d->richardson));
    d->omega_max_known = 0;
    memset(d->alpha, 0, sizeof(d->alpha));
    fmu_model_inputs(d, d->time, inst->u1);
    fmu_guard_init(inst, inst->u1);
    d->outputs_valid = 0;
    status = fmu_update_outputs(inst, "fmi2ExitInitializationMode");
    if (status > fmi2Warning) return status;
    memcpy(d->alpha, d->acceleration, sizeof(d->alpha));
    d->last_successful_time = d->time;
    d->phase = d->model_exchange ? PHASE_EVENT : PHASE_STEP;
    fmu_log(inst, fmi2OK, LOG_EVENTS, "initialized at t = %.17g (SS22: step %g, theta1 %g, theta2 %g, "
            "tolerance %g)",
            d->time, step, theta1, theta2, tolerance);
    return status;
}
