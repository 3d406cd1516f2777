/* model_exchange.c -- the Model Exchange functions: time, continuous states (q, v), their derivatives
 * (v, a), nominals and the time events of the built-in kinematic laws.  See cosimulation.h. */
#include <math.h>
#include <string.h>
#include "internal.h"


/* ============================================================= Model Exchange */

fmi2Status fmu_set_time(Instance *inst, fmi2Real time) {
    if (!isfinite(time)) return fmu_error(inst, "fmi2SetTime: time = %g: must be finite", time);
    inst->d.time = time;
    inst->d.outputs_valid = 0;
    return fmi2OK;
}

static fmi2Status check_nx(Instance *inst, const char *function, size_t nx) {
    if (nx != (size_t)N_STATES) {
        return fmu_error(inst, "%s: nx = %lu, this FMU has %d continuous states", function,
                         (unsigned long)nx, N_STATES);
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
    status = fmu_update_outputs(inst, "fmi2GetDerivatives");
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

/* fmi2CompletedIntegratorStep: the importer's accepted state passes the same guards as a Co-Simulation step
 * (guards.c), the energy balance included, judged between this and the last completed step (an explicit
 * integrator at too large a step gains energy at every step).  Outside them the FMU asks the importer to
 * stop (terminateSimulation) and answers fmi2Discard with the reason, instead of letting it integrate a
 * state the model cannot stand behind. */
fmi2Status fmu_completed_integrator_step(Instance *inst, fmi2Boolean *terminate) {
    FmuData *d = &inst->d;
    EnergyPoint now;
    fmu_model_inputs(d, d->time, inst->u1);
    if (fmu_guard_state(inst, d->time, inst->u1, 1) != fmi2OK) {
        *terminate = fmi2True;
        fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2CompletedIntegratorStep: %s; terminate the "
                "simulation", inst->guard_reason);
        return fmi2Discard;
    }
    const fmi2Status status = fmu_energy_point(inst, &now, "fmi2CompletedIntegratorStep");
    if (status > fmi2Warning) return status;
    /* a step of the importer's: forward in time (an event iteration completes no step) */
    if (now.available && d->energy_last.available && now.time > d->energy_last.time &&
        fmu_guard_energy(inst, &d->energy_last, &now, 1.0) != fmi2OK) {
        *terminate = fmi2True;
        fmu_log(inst, fmi2Discard, LOG_STATUS_DISCARD, "fmi2CompletedIntegratorStep: %s; terminate the "
                "simulation", inst->guard_reason);
        return fmi2Discard;
    }
    d->energy_last = now;
    return fmi2OK;
}
