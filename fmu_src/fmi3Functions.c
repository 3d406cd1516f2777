/* fmi3Functions.c -- the FMI 3.0 functions of a flexlink FMU built with `flexlink build --fmi 3`, and nothing
 * else: argument checks, the call sequence, and delegation to the same functions of cosimulation.h that the
 * FMI 2.0 layer (fmi2Functions.c, not compiled into an FMI 3 FMU) calls.
 *
 * The internal functions keep FMI 2's types: fmi3Float64 is fmi2Real (double), fmi3ValueReference is
 * fmi2ValueReference (32-bit unsigned), and the statuses OK..Fatal have the same values; integers are copied
 * between fmi3Int32/fmi3Int64 and fmi2Integer.  What differs is translated here: instantiation (FMI 3
 * passes a log-message callback and no memory functions: the instance gets an FMI 2 callback record whose
 * logger forwards to it and whose memory is the C library's), fmi3Boolean (a bool, fmi2Boolean an int), the
 * independent variable `time` (value reference N_VARS, after the model's variables), and the arrays of the
 * event-update and step functions.
 *
 * Arrays: a link's elastic coordinates (and their states, rates and derivatives) are Float64 arrays whose value
 * reference is the FMI 2 reference of their first element; element k is FMI 2's reference + k - 1.  The
 * generated fmi3_layout.c says how many values each reference holds (FMI3_ELEMENTS), and the functions taking
 * value references expand them into FMI 2 references before they call cosimulation.h.
 *
 * Types: each reference is read and set with its type's functions only (FMI3_TYPES): Float64, and the
 * Enumeration solver.order with fmi3GetInt64/fmi3SetInt64; no Int32 variables.
 *
 * No clocks, no event mode in Co-Simulation, no early return, no intermediate update, no configuration mode:
 * those functions answer fmi3Error with the reason.  Messages from the functions behind cosimulation.h name the
 * FMI 2 function they were written for (fmi2SetReal for fmi3SetFloat64 and so on).
 *
 * The layer is split by concern, as the functions behind it are: this file instantiates, logs, runs the life
 * cycle and the Co-Simulation step; fmi3_variables.c gets and sets values (arrays and types);
 * fmi3_model_exchange.c the Model Exchange functions; fmi3_state.c the FMU state and the directional and
 * adjoint derivatives; fmi3_unsupported.c what this FMU answers with fmi3Error.  fmi3_internal.h holds what
 * they share. */
#include "fmi3_internal.h"

/* ======================================================== instantiation, logging */

/* What an FMI 3 host passed at instantiation: the FMI 2 callback record's componentEnvironment. */
typedef struct {
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log_message;
} Host;

/* The FMI 2 logger of an FMI 3 instance.  logging.c escapes '%' and '#' for FMI 2's printf-style logger;
 * FMI 3 messages are plain text, so they are unescaped here. */
static void forward_log(fmi2ComponentEnvironment environment, fmi2String name, fmi2Status status,
                        fmi2String category, fmi2String message, ...) {
    const Host *host = (const Host *)environment;
    char text[2048];
    size_t j = 0;
    (void)name;
    for (size_t i = 0; message[i] != '\0' && j + 1 < sizeof(text); i++) {
        if ((message[i] == '%' || message[i] == '#') && message[i + 1] == message[i]) i++;
        text[j++] = message[i];
    }
    text[j] = '\0';
    host->log_message(host->environment, (fmi3Status)status, category, text);
}

static fmi3Instance instantiate(fmi3String name, fmi3String token, fmi3Boolean logging_on, fmi2Type type,
                                fmi3InstanceEnvironment environment, fmi3LogMessageCallback log_message) {
    fmi2CallbackFunctions cb;
    Instance *inst;
    Host *host = (Host *)calloc(1, sizeof(Host));
    if (host == NULL) {
        if (log_message != NULL) log_message(environment, fmi3Error, "logStatusError", "out of memory");
        return NULL;
    }
    host->environment = environment;
    host->log_message = log_message;
    cb.logger = log_message != NULL ? forward_log : NULL;
    cb.allocateMemory = calloc;
    cb.freeMemory = free;
    cb.stepFinished = NULL;
    cb.componentEnvironment = host;
    inst = fmu_instantiate(name, type, token, &cb, logging_on ? fmi2True : fmi2False);
    if (inst == NULL) free(host);
    return inst;
}

const char *fmi3GetVersion(void) {
    return fmi3Version;
}

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    BEGIN("fmi3SetDebugLogging", PHASE_ANY);
    return s3(fmu_finish(inst, fmu_set_debug_logging(inst, loggingOn ? fmi2True : fmi2False, nCategories,
                                                     categories)));
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath;
    (void)visible;
    return instantiate(instanceName, instantiationToken, loggingOn, fmi2ModelExchange, instanceEnvironment,
                       logMessage);
}

/* Co-Simulation without event mode and without early return (hasEventMode, canReturnEarlyAfterIntermediateUpdate
 * are false): a host asking for event mode is refused; earlyReturnAllowed only permits, and the FMU never
 * returns early. */
fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed; (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        if (logMessage != NULL) {
            logMessage(instanceEnvironment, fmi3Error, "logStatusError", eventModeUsed
                       ? "fmi3InstantiateCoSimulation: eventModeUsed: this FMU has no event mode (hasEventMode=false)"
                       : "fmi3InstantiateCoSimulation: no intermediate variables (providesIntermediateUpdate=false)");
        }
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, loggingOn, fmi2CoSimulation, instanceEnvironment,
                       logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage != NULL) {
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: this FMU has no Scheduled Execution interface");
    }
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    Instance *inst = fmu_instance_of(instance);
    Host *host;
    if (inst == NULL) return;
    host = (Host *)inst->cb.componentEnvironment;
    fmu_free(inst);
    free(host);
}

/* ============================================================ life cycle */

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    fmi2Status status;
    BEGIN("fmi3EnterInitializationMode", PHASE_INSTANTIATED);
    status = fmu_setup_experiment(inst, toleranceDefined ? fmi2True : fmi2False, tolerance, startTime,
                                  stopTimeDefined ? fmi2True : fmi2False, stopTime);
    if (status > fmi2Warning) return s3(fmu_finish(inst, status));
    return s3(fmu_finish(inst, fmu_enter_initialization(inst)));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    BEGIN("fmi3ExitInitializationMode", PHASE_INITIALIZATION);
    return s3(fmu_finish(inst, fmu_exit_initialization(inst)));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    ME_BEGIN("fmi3EnterEventMode", PHASE_EVENT | PHASE_CONTINUOUS);
    inst->d.phase = PHASE_EVENT;
    fmu_energy_forget(&inst->d);
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    BEGIN("fmi3Terminate", PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS);
    fmu_log_statistics(inst);
    inst->d.phase = PHASE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    BEGIN("fmi3Reset", PHASE_ANY);
    fmu_reset(inst);
    return fmi3OK;
}

/* ================================================================ Co-Simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    NOT_SUPPORTED("fmi3EnterStepMode", "this FMU has no event mode in Co-Simulation (hasEventMode is false)");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)orders; (void)values; (void)nValues;
    NOT_SUPPORTED("fmi3GetOutputDerivatives", "not provided (maxOutputDerivativeOrder is 0)");
}

/* A discarded step has undone itself (the FMU stays at the communication point) and asks the importer to
 * end the run (terminateSimulation): the step was already retried as sub-steps (cs_step.c). */
fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    fmi2Status status;
    (void)noSetFMUStatePriorToCurrentPoint;
    BEGIN("fmi3DoStep", PHASE_STEP);
    REQUIRE(eventHandlingNeeded != NULL && terminateSimulation != NULL && earlyReturn != NULL &&
            lastSuccessfulTime != NULL, "fmi3DoStep", "an output argument is NULL");
    status = fmu_do_step(inst, currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = fmi3False;
    *earlyReturn = fmi3False;
    *terminateSimulation = status == fmi2Discard && inst->step_discarded;
    *lastSuccessfulTime = inst->d.time;
    return s3(fmu_finish(inst, status));
}
