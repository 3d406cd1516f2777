/* derivatives.c -- fmi2GetDirectionalDerivative: forward derivatives of the generated model, with the
 * acceleration eliminated through the mass matrix.  See cosimulation.h. */
#include <math.h>
#include <string.h>
#include "internal.h"
#include "linalg.h"

static const char *const F = "fmi2GetDirectionalDerivative";

#if !MODEL_DIRECTIONAL_DERIVATIVES
/* [fmu] directional_derivatives = false: the forward derivatives were not generated (the model description
 * says providesDirectionalDerivative="false"); a call is refused with the reason. */
fmi2Status fmu_directional_derivative(Instance *inst, const fmi2ValueReference unknown[], size_t n_unknown,
                                      const fmi2ValueReference known[], size_t n_known, const fmi2Real dv_known[],
                                      fmi2Real dv_unknown[]) {
    (void)unknown; (void)n_unknown; (void)known; (void)n_known; (void)dv_known; (void)dv_unknown;
    return fmu_error(inst, "%s: this FMU was built without directional derivatives ([fmu] "
                     "directional_derivatives = false: providesDirectionalDerivative is false)", F);
}
#else

/* The seeds dd_q, dd_v, dd_u, dd_p from the knowns (states, inputs, tunable parameters). */
static fmi2Status read_knowns(Instance *inst, const fmi2ValueReference known[], size_t n_known,
                              const fmi2Real dv_known[]) {
    memset(inst->dd_q, 0, sizeof(inst->dd_q));
    memset(inst->dd_v, 0, sizeof(inst->dd_v));
    memset(inst->dd_u, 0, sizeof(inst->dd_u));
    memset(inst->dd_p, 0, sizeof(inst->dd_p));
    for (size_t i = 0; i < n_known; i++) {
        const VarInfo *v;
        if (known[i] >= (fmi2ValueReference)N_VARS) return fmu_error(inst, "%s: unknown value reference %u", F,
                                                                     known[i]);
        v = &MODEL_VARS[known[i]];
        if (!isfinite(dv_known[i])) return fmu_error(inst, "%s: dvKnown[%lu] = %g: must be finite", F, (unsigned long)i,
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
    return fmi2OK;
}

/* Every unknown must be an output, a state derivative or a state; *need_y: some are outputs. */
static fmi2Status check_unknowns(Instance *inst, const fmi2ValueReference unknown[], size_t n_unknown,
                                 int *need_y) {
    *need_y = 0;
    for (size_t i = 0; i < n_unknown; i++) {
        int kind;
        if (unknown[i] >= (fmi2ValueReference)N_VARS) return fmu_error(inst, "%s: unknown value reference %u",
                                                                       F, unknown[i]);
        kind = MODEL_VARS[unknown[i]].kind;
        if (kind == VAR_OUTPUT) *need_y = 1;
        if (kind != VAR_OUTPUT && kind != VAR_DER_Q && kind != VAR_DER_V && kind != VAR_STATE_Q &&
            kind != VAR_STATE_V) {
            return fmu_error(inst, "%s: %s (value reference %u) is not an unknown: unknowns are the outputs, "
                             "the state derivatives and the states", F, MODEL_VARS[unknown[i]].name, unknown[i]);
        }
    }
    return fmi2OK;
}

/* dd_um: the input seeds as the model sees them: a host-driven law is extended from its time to now,
 * a built-in one does not depend on the inputs. */
static void model_input_seeds(Instance *inst) {
    memcpy(inst->dd_um, inst->dd_u, sizeof(inst->dd_u));
#if N_LAWS > 0
    const FmuData *d = &inst->d;
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
}

fmi2Status fmu_directional_derivative(Instance *inst, const fmi2ValueReference unknown[], size_t n_unknown,
                                      const fmi2ValueReference known[], size_t n_known, const fmi2Real dv_known[],
                                      fmi2Real dv_unknown[]) {
    FmuData *d = &inst->d;
    fmi2Status status;
    int need_y = 0;
#if MODEL_COMPLEX_STEP && !MODEL_HAS_COMPLEX
    (void)unknown; (void)n_unknown; (void)known; (void)n_known; (void)dv_known; (void)dv_unknown; (void)need_y;
    (void)status; (void)d;
    return fmu_error(inst, "%s: this binary was compiled without C99 complex arithmetic (MSVC's C compiler?), "
                     "which the directional derivatives (the complex step) need; compile the FMU's sources with "
                     "gcc, clang or MinGW-w64", F);
#endif
    if (read_knowns(inst, known, n_known, dv_known) != fmi2OK) return fmi2Error;
    if (check_unknowns(inst, unknown, n_unknown, &need_y) != fmi2OK) return fmi2Error;
    model_input_seeds(inst);
    status = fmu_update_outputs(inst, F);
    if (status > fmi2Warning) return status;
    if (!d->acceleration_ok) {
        return fmu_error(inst, "%s: no consistent acceleration at t = %.17g (singular mass matrix)", F, d->time);
    }
    memset(inst->dd_a, 0, sizeof(inst->dd_a));
    fmu_model_inputs(d, d->time, inst->u0);
    /* By the complex step the outputs' derivative is one evaluation in the whole direction, da included,
     * once da is known; CasADi's forward functions give it with dr at da = 0 and add the part in da. */
    if (model_forward(d->q, d->v, d->acceleration, inst->u0, d->p, inst->dd_q, inst->dd_v, inst->dd_a,
                      inst->dd_um, inst->dd_p, inst->dd_r, MODEL_COMPLEX_STEP ? NULL : inst->dd_y, &inst->work) ||
        model_newton_matrix(d->q, d->v, d->acceleration, inst->u0, d->p, 1.0, 0.0, 0.0, inst->J, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", F, d->time);
    }
    if (lu_factor(inst->J, N_Q, inst->piv) != 0) {
        return fmu_error(inst, "%s: singular mass matrix at t = %.17g", F, d->time);
    }
    for (int i = 0; i < N_Q; i++) inst->dd_a[i] = -inst->dd_r[i];
    lu_solve(inst->J, N_Q, inst->piv, inst->dd_a);
#if MODEL_COMPLEX_STEP
    if (need_y && model_complex_forward(d->q, d->v, d->acceleration, inst->u0, d->p, inst->dd_q, inst->dd_v,
                                        inst->dd_a, inst->dd_um, inst->dd_p, NULL, inst->dd_y)) {
        return fmu_error(inst, "%s: the model failed to evaluate its outputs at t = %.17g", F, d->time);
    }
#else
    if (need_y) {   /* dd_y holds the outputs' derivative at da = 0: add its part in da */
        if (model_outputs_acceleration_forward(d->q, d->v, d->acceleration, inst->u0, d->p, inst->dd_a,
                                               inst->dd_ya, &inst->work)) {
            return fmu_error(inst, "%s: the model failed to evaluate its outputs at t = %.17g", F, d->time);
        }
        for (int i = 0; i < N_Y; i++) inst->dd_y[i] += inst->dd_ya[i];
    }
#endif
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
    if (!fmu_all_finite(dv_unknown, (int)n_unknown)) {
        return fmu_error(inst, "%s: NaN or infinite derivative at t = %.17g", F, d->time);
    }
    return status;
}
#endif
