/* fmi2Functions.c -- the FMI 2.0 functions of every flexlink FMU, and nothing else: argument checks,
 * the call-sequence state machine and delegation to the functions of cosimulation.h.
 *
 * Each function names the states it may be called in (a bitmask of Phase, after the state table of
 * FMI 2.0 section 4.2.4).  A call out of sequence, a bad argument or any other error returns
 * fmi2Error with a message through the logger and puts the instance in the error state, from which
 * fmi2Reset or fmi2SetFMUstate bring it back.  fmi2Discard (a communication step that could not be
 * computed) leaves the instance in step mode at the communication point.  Model Exchange functions
 * called on a Co-Simulation instance (and fmi2DoStep on a Model Exchange one, which never reaches step
 * mode) are refused.  A NULL instance gives
 * fmi2Error and nothing else (there is no logger to tell).  The call-sequence helpers (fmu_allowed,
 * fmu_finish, ...) are shared with the FMI 3.0 layer, fmi3Functions.c (calls.c). */
#include "cosimulation.h"

#define SETTABLE (PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS)
#define READABLE (PHASE_INITIALIZATION | PHASE_STEP | PHASE_TERMINATED | PHASE_ERROR | PHASE_EVENT | \
                  PHASE_CONTINUOUS)
#define ME_READABLE (PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED | PHASE_ERROR)
#define DERIVATIVES (PHASE_INITIALIZATION | PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED)
#define STATUS_QUERY (PHASE_STEP | PHASE_TERMINATED)

#define BEGIN(function, phases)                                            \
    Instance *inst = fmu_instance_of(c);                                       \
    if (inst == NULL) return fmi2Error;                                    \
    if (fmu_logs(inst, LOG_ALL)) fmu_log(inst, fmi2OK, LOG_ALL, "%s", function); \
    if (!fmu_allowed(inst, function, phases)) return fmi2Error

#define REQUIRE(condition, function, message) \
    if (!(condition)) return fmu_fail(inst, function, message)

/* ============================================================ common functions */

const char *fmi2GetTypesPlatform(void) {
    return fmi2TypesPlatform;
}

const char *fmi2GetVersion(void) {
    return fmi2Version;
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    BEGIN("fmi2SetDebugLogging", PHASE_ANY);
    return fmu_finish(inst, fmu_set_debug_logging(inst, loggingOn, nCategories, categories));
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)fmuResourceLocation;
    (void)visible;
    return (fmi2Component)fmu_instantiate(instanceName, fmuType, fmuGUID, functions, loggingOn);
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = fmu_instance_of(c);
    if (inst != NULL) fmu_free(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    BEGIN("fmi2SetupExperiment", PHASE_INSTANTIATED);
    const fmi2Status status =
        fmu_setup_experiment(inst, toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime);
    return fmu_finish(inst, status);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN("fmi2EnterInitializationMode", PHASE_INSTANTIATED);
    return fmu_finish(inst, fmu_enter_initialization(inst));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN("fmi2ExitInitializationMode", PHASE_INITIALIZATION);
    return fmu_finish(inst, fmu_exit_initialization(inst));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN("fmi2Terminate", PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS);
    fmu_log_statistics(inst);
    inst->d.phase = PHASE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN("fmi2Reset", PHASE_ANY);
    fmu_reset(inst);
    return fmi2OK;
}

/* ====================================================== getting and setting values */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    BEGIN("fmi2GetReal", READABLE);
    REQUIRE(nvr == 0 || (vr != NULL && value != NULL), "fmi2GetReal", "vr or value is NULL");
    return fmu_finish(inst, fmu_get_real(inst, vr, nvr, value));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    BEGIN("fmi2SetReal", SETTABLE);
    REQUIRE(nvr == 0 || (vr != NULL && value != NULL), "fmi2SetReal", "vr or value is NULL");
    return fmu_finish(inst, fmu_set_real(inst, vr, nvr, value));
}

/* The model has Real and Integer variables only. */
static fmi2Status no_variables(Instance *inst, const char *function, const fmi2ValueReference vr[],
                               size_t nvr, const void *value) {
    if (nvr == 0) return fmi2OK;
    if (vr == NULL || value == NULL) return fmu_fail(inst, function, "vr or value is NULL");
    fmu_error(inst, "%s: unknown value reference %u (this FMU has Real and Integer variables only)", function,
              vr[0]);
    return fmu_finish(inst, fmi2Error);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    BEGIN("fmi2GetInteger", READABLE);
    REQUIRE(nvr == 0 || (vr != NULL && value != NULL), "fmi2GetInteger", "vr or value is NULL");
    return fmu_finish(inst, fmu_get_integer(inst, vr, nvr, value));
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    BEGIN("fmi2GetBoolean", READABLE);
    return no_variables(inst, "fmi2GetBoolean", vr, nvr, value);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    BEGIN("fmi2GetString", READABLE);
    return no_variables(inst, "fmi2GetString", vr, nvr, value);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    BEGIN("fmi2SetInteger", SETTABLE);
    REQUIRE(nvr == 0 || (vr != NULL && value != NULL), "fmi2SetInteger", "vr or value is NULL");
    return fmu_finish(inst, fmu_set_integer(inst, vr, nvr, value));
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    BEGIN("fmi2SetBoolean", SETTABLE);
    return no_variables(inst, "fmi2SetBoolean", vr, nvr, value);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    BEGIN("fmi2SetString", SETTABLE);
    return no_variables(inst, "fmi2SetString", vr, nvr, value);
}

/* ================================================================== FMU state */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2GetFMUstate", PHASE_ANY);
    REQUIRE(FMUstate != NULL, "fmi2GetFMUstate", "FMUstate is NULL");
    return fmu_finish(inst, fmu_get_state(inst, FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    BEGIN("fmi2SetFMUstate", PHASE_ANY);
    return fmu_finish(inst, fmu_set_state(inst, FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2FreeFMUstate", PHASE_ANY);
    REQUIRE(FMUstate != NULL, "fmi2FreeFMUstate", "FMUstate is NULL");
    return fmu_finish(inst, fmu_free_state(inst, FMUstate));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN("fmi2SerializedFMUstateSize", PHASE_ANY);
    REQUIRE(size != NULL, "fmi2SerializedFMUstateSize", "size is NULL");
    REQUIRE(FMUstate != NULL && ((const SavedState *)FMUstate)->magic == STATE_MAGIC,
            "fmi2SerializedFMUstateSize", "not a state of this FMU");
    *size = fmu_serialized_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    BEGIN("fmi2SerializeFMUstate", PHASE_ANY);
    REQUIRE(serializedState != NULL, "fmi2SerializeFMUstate", "serializedState is NULL");
    return fmu_finish(inst, fmu_serialize(inst, FMUstate, serializedState, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    BEGIN("fmi2DeSerializeFMUstate", PHASE_ANY);
    REQUIRE(serializedState != NULL && FMUstate != NULL, "fmi2DeSerializeFMUstate",
            "serializedState or FMUstate is NULL");
    return fmu_finish(inst, fmu_deserialize(inst, serializedState, size, FMUstate));
}

/* ==================================================== directional derivatives */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    BEGIN("fmi2GetDirectionalDerivative", DERIVATIVES);
    REQUIRE((nUnknown == 0 || (vUnknown_ref != NULL && dvUnknown != NULL)) &&
            (nKnown == 0 || (vKnown_ref != NULL && dvKnown != NULL)), "fmi2GetDirectionalDerivative",
            "a value reference or value array is NULL");
    return fmu_finish(inst, fmu_directional_derivative(inst, vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown,
                                                   dvUnknown));
}

/* ============================================================= Model Exchange */

#define ME_BEGIN(function, phases)                                                          \
    BEGIN(function, phases);                                                                \
    if (!inst->d.model_exchange) {                                                          \
        return fmu_fail(inst, function, "a Model Exchange function, but this instance is Co-Simulation"); \
    }

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    ME_BEGIN("fmi2EnterEventMode", PHASE_EVENT | PHASE_CONTINUOUS);
    inst->d.phase = PHASE_EVENT;
    fmu_energy_forget(&inst->d);
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *fmi2eventInfo) {
    ME_BEGIN("fmi2NewDiscreteStates", PHASE_EVENT);
    REQUIRE(fmi2eventInfo != NULL, "fmi2NewDiscreteStates", "fmi2eventInfo is NULL");
    return fmu_finish(inst, fmu_new_discrete_states(inst, fmi2eventInfo));
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    ME_BEGIN("fmi2EnterContinuousTimeMode", PHASE_EVENT);
    inst->d.phase = PHASE_CONTINUOUS;
    return fmi2OK;
}

/* No state events and no step events: the integrator never has to stop here. */
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    ME_BEGIN("fmi2CompletedIntegratorStep", PHASE_CONTINUOUS);
    REQUIRE(enterEventMode != NULL && terminateSimulation != NULL, "fmi2CompletedIntegratorStep",
            "enterEventMode or terminateSimulation is NULL");
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmu_finish(inst, fmu_completed_integrator_step(inst, terminateSimulation));
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    ME_BEGIN("fmi2SetTime", PHASE_EVENT | PHASE_CONTINUOUS);
    return fmu_finish(inst, fmu_set_time(inst, time));
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    ME_BEGIN("fmi2SetContinuousStates", PHASE_CONTINUOUS);
    REQUIRE(x != NULL, "fmi2SetContinuousStates", "x is NULL");
    return fmu_finish(inst, fmu_set_states(inst, x, nx));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    ME_BEGIN("fmi2GetDerivatives", ME_READABLE);
    REQUIRE(derivatives != NULL, "fmi2GetDerivatives", "derivatives is NULL");
    return fmu_finish(inst, fmu_get_derivatives(inst, derivatives, nx));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    ME_BEGIN("fmi2GetEventIndicators", ME_READABLE);
    REQUIRE(ni == 0, "fmi2GetEventIndicators", "this FMU has no event indicators (ni must be 0)");
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    ME_BEGIN("fmi2GetContinuousStates", ME_READABLE);
    REQUIRE(x != NULL, "fmi2GetContinuousStates", "x is NULL");
    return fmu_finish(inst, fmu_get_states(inst, x, nx));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    ME_BEGIN("fmi2GetNominalsOfContinuousStates", PHASE_INSTANTIATED | ME_READABLE);
    REQUIRE(x_nominal != NULL, "fmi2GetNominalsOfContinuousStates", "x_nominal is NULL");
    return fmu_finish(inst, fmu_get_nominals(inst, x_nominal, nx));
}

/* ======================================================= not supported */

#define NOT_SUPPORTED(function, why)                \
    Instance *inst = fmu_instance_of(c);                \
    if (inst == NULL) return fmi2Error;             \
    return fmu_fail(inst, function, why)

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    NOT_SUPPORTED("fmi2SetRealInputDerivatives", "not supported (canInterpolateInputs is false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    NOT_SUPPORTED("fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder is 0)");
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    NOT_SUPPORTED("fmi2CancelStep", "no step to cancel: fmi2DoStep never returns fmi2Pending");
}

/* =================================================================== Co-Simulation */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    BEGIN("fmi2DoStep", PHASE_STEP);
    return fmu_finish(inst, fmu_do_step(inst, currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    BEGIN("fmi2GetStatus", STATUS_QUERY);
    return fmu_fail(inst, "fmi2GetStatus", "no status to query: fmi2DoStep never returns fmi2Pending");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN("fmi2GetRealStatus", STATUS_QUERY);
    REQUIRE(value != NULL, "fmi2GetRealStatus", "value is NULL");
    REQUIRE(s == fmi2LastSuccessfulTime, "fmi2GetRealStatus", "only fmi2LastSuccessfulTime is a Real status");
    *value = inst->d.last_successful_time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    BEGIN("fmi2GetIntegerStatus", STATUS_QUERY);
    return fmu_fail(inst, "fmi2GetIntegerStatus", "there is no Integer status");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN("fmi2GetBooleanStatus", STATUS_QUERY);
    REQUIRE(value != NULL, "fmi2GetBooleanStatus", "value is NULL");
    REQUIRE(s == fmi2Terminated, "fmi2GetBooleanStatus", "only fmi2Terminated is a Boolean status");
    /* After a discarded step the FMU asks the master to end: it has already retried the step as 8 sub-steps,
     * and a master that retries the same step (fmpy does, while this is false) would never return. */
    *value = inst->step_discarded ? fmi2True : fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    BEGIN("fmi2GetStringStatus", STATUS_QUERY);
    return fmu_fail(inst, "fmi2GetStringStatus", "no pending status: fmi2DoStep never returns fmi2Pending");
}
