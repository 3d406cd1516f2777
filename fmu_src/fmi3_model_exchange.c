/* fmi3_model_exchange.c -- the FMI 3.0 Model Exchange functions (event update, continuous-time mode, states,
 * derivatives, nominals), on model_exchange.c.  See fmi3Functions.c for the layer's rules. */
#include "fmi3_internal.h"

/* ============================================================== Model Exchange */

/* No discrete states; the next time event of a built-in kinematic law (fmu_new_discrete_states). */
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    fmi2EventInfo info;
    fmi2Status status;
    ME_BEGIN("fmi3UpdateDiscreteStates", PHASE_EVENT);
    REQUIRE(discreteStatesNeedUpdate != NULL && terminateSimulation != NULL &&
            nominalsOfContinuousStatesChanged != NULL && valuesOfContinuousStatesChanged != NULL &&
            nextEventTimeDefined != NULL && nextEventTime != NULL, "fmi3UpdateDiscreteStates", "an argument is NULL");
    status = fmu_new_discrete_states(inst, &info);
    *discreteStatesNeedUpdate = info.newDiscreteStatesNeeded != fmi2False;
    *terminateSimulation = info.terminateSimulation != fmi2False;
    *nominalsOfContinuousStatesChanged = info.nominalsOfContinuousStatesChanged != fmi2False;
    *valuesOfContinuousStatesChanged = info.valuesOfContinuousStatesChanged != fmi2False;
    *nextEventTimeDefined = info.nextEventTimeDefined != fmi2False;
    *nextEventTime = info.nextEventTime;
    return s3(fmu_finish(inst, status));
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    ME_BEGIN("fmi3EnterContinuousTimeMode", PHASE_EVENT);
    inst->d.phase = PHASE_CONTINUOUS;
    return fmi3OK;
}

/* No state events and no step events; an accepted state outside the model's validity ends the run. */
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    fmi2Boolean terminate = fmi2False;
    fmi2Status status;
    (void)noSetFMUStatePriorToCurrentPoint;
    ME_BEGIN("fmi3CompletedIntegratorStep", PHASE_CONTINUOUS);
    REQUIRE(enterEventMode != NULL && terminateSimulation != NULL, "fmi3CompletedIntegratorStep",
            "enterEventMode or terminateSimulation is NULL");
    status = fmu_completed_integrator_step(inst, &terminate);
    *enterEventMode = fmi3False;
    *terminateSimulation = terminate != fmi2False;
    return s3(fmu_finish(inst, status));
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    ME_BEGIN("fmi3SetTime", PHASE_EVENT | PHASE_CONTINUOUS);
    return s3(fmu_finish(inst, fmu_set_time(inst, time)));
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    ME_BEGIN("fmi3SetContinuousStates", PHASE_CONTINUOUS);
    REQUIRE(continuousStates != NULL, "fmi3SetContinuousStates", "continuousStates is NULL");
    return s3(fmu_finish(inst, fmu_set_states(inst, continuousStates, nContinuousStates)));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    ME_BEGIN("fmi3GetContinuousStateDerivatives", ME_READABLE);
    REQUIRE(derivatives != NULL, "fmi3GetContinuousStateDerivatives", "derivatives is NULL");
    return s3(fmu_finish(inst, fmu_get_derivatives(inst, derivatives, nContinuousStates)));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    (void)eventIndicators;
    ME_BEGIN("fmi3GetEventIndicators", ME_READABLE | PHASE_INITIALIZATION);
    REQUIRE(nEventIndicators == 0, "fmi3GetEventIndicators", "this FMU has no event indicators (must be 0)");
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    ME_BEGIN("fmi3GetContinuousStates", ME_READABLE | PHASE_INITIALIZATION);
    REQUIRE(continuousStates != NULL, "fmi3GetContinuousStates", "continuousStates is NULL");
    return s3(fmu_finish(inst, fmu_get_states(inst, continuousStates, nContinuousStates)));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[], size_t nContinuousStates) {
    ME_BEGIN("fmi3GetNominalsOfContinuousStates", PHASE_INSTANTIATED | PHASE_INITIALIZATION | ME_READABLE);
    REQUIRE(nominals != NULL, "fmi3GetNominalsOfContinuousStates", "nominals is NULL");
    return s3(fmu_finish(inst, fmu_get_nominals(inst, nominals, nContinuousStates)));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    BEGIN("fmi3GetNumberOfEventIndicators", PHASE_ANY);
    REQUIRE(nEventIndicators != NULL, "fmi3GetNumberOfEventIndicators", "nEventIndicators is NULL");
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    BEGIN("fmi3GetNumberOfContinuousStates", PHASE_ANY);
    REQUIRE(nContinuousStates != NULL, "fmi3GetNumberOfContinuousStates", "nContinuousStates is NULL");
    *nContinuousStates = (size_t)N_STATES;
    return fmi3OK;
}
