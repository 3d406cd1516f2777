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
 * FMI 2 function they were written for (fmi2SetReal for fmi3SetFloat64 and so on). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fmi3Functions.h"
#include "cosimulation.h"

#define TIME_VR ((fmi3ValueReference)N_VARS)   /* the independent variable "time" */

/* fmi3_layout.c (generated): values of FMI 3 value reference vr < N_VARS: 1 a scalar, n an array of the FMI 2
 * references vr .. vr+n-1, 0 a later element of an array (not an FMI 3 variable); and its FMI 3 type */
extern const int FMI3_ELEMENTS[N_VARS];
extern const unsigned char FMI3_TYPES[N_VARS];
enum { FMI3_FLOAT64, FMI3_INT32, FMI3_ENUMERATION };   /* the codes of FMI3_TYPES */
static const char *const TYPE_NAME[] = {"Float64", "Int32", "Enumeration"};
static const char *const TYPE_API[] = {"fmi3GetFloat64/fmi3SetFloat64", "fmi3GetInt32/fmi3SetInt32",
                                       "fmi3GetInt64/fmi3SetInt64"};

#define SETTABLE (PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS)
#define READABLE (PHASE_INITIALIZATION | PHASE_STEP | PHASE_TERMINATED | PHASE_ERROR | PHASE_EVENT | \
                  PHASE_CONTINUOUS)
#define ME_READABLE (PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED | PHASE_ERROR)
#define DERIVATIVES (PHASE_INITIALIZATION | PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED)

static fmi3Status s3(fmi2Status status) {
    return (fmi3Status)status;
}

#define BEGIN(function, phases)                                                     \
    Instance *inst = fmu_instance_of(instance);                                     \
    if (inst == NULL) return fmi3Error;                                             \
    if (fmu_logs(inst, LOG_ALL)) fmu_log(inst, fmi2OK, LOG_ALL, "%s", function);    \
    if (!fmu_allowed(inst, function, phases)) return fmi3Error

#define REQUIRE(condition, function, message) \
    if (!(condition)) return s3(fmu_fail(inst, function, message))

#define ME_BEGIN(function, phases)                                                          \
    BEGIN(function, phases);                                                                \
    if (!inst->d.model_exchange) {                                                          \
        return s3(fmu_fail(inst, function, "a Model Exchange function, but this instance is Co-Simulation")); \
    }

#define NOT_SUPPORTED(function, why)                     \
    Instance *inst = fmu_instance_of(instance);          \
    if (inst == NULL) return fmi3Error;                  \
    return s3(fmu_fail(inst, function, why))

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

/* ================================================================= arrays */

/* FMI 3 value references expanded into FMI 2 ones (time and unknown references pass through, one value each, for
 * the functions behind to answer); `vr` points at the caller's array when no reference is an array. */
typedef struct {
    const fmi2ValueReference *vr;
    fmi2ValueReference *owned;
    size_t n;
} Refs;

/* The number of values of reference vr, or 0 after an error message (vr is a later element of an array). */
static size_t values_of(Instance *inst, const char *function, fmi3ValueReference vr) {
    fmi3ValueReference head = vr;
    if (vr >= N_VARS || FMI3_ELEMENTS[vr] > 0) return vr >= N_VARS ? 1 : (size_t)FMI3_ELEMENTS[vr];
    while (head > 0 && FMI3_ELEMENTS[head] == 0) head--;
    fmu_error(inst, "%s: value reference %u (FMI 2's %s) is not a variable of this FMI 3.0 FMU: it is element %u of "
              "the array at value reference %u, read and set through that reference", function, (unsigned)vr,
              MODEL_VARS[vr].name, (unsigned)(vr - head + 1), (unsigned)head);
    return 0;
}

/* refs = vr[0..nvr) expanded; expected: the number of values the caller passed (nValues, nSeed, ...). */
static fmi2Status expand(Instance *inst, const char *function, const fmi3ValueReference vr[], size_t nvr,
                         size_t expected, Refs *refs) {
    size_t total = 0, k, j = 0;
    refs->vr = vr;
    refs->owned = NULL;
    refs->n = nvr;
    for (size_t i = 0; i < nvr; i++) {
        k = values_of(inst, function, vr[i]);
        if (k == 0) return fmu_finish(inst, fmi2Error);
        total += k;
    }
    if (total != expected) {
        fmu_error(inst, "%s: the value references hold %lu values, not %lu (an array holds as many values as its "
                  "<Dimension>)", function, (unsigned long)total, (unsigned long)expected);
        return fmu_finish(inst, fmi2Error);
    }
    if (total == nvr) return fmi2OK;
    refs->owned = (fmi2ValueReference *)calloc(total, sizeof(fmi2ValueReference));
    if (refs->owned == NULL) return fmu_fail(inst, function, "out of memory");
    for (size_t i = 0; i < nvr; i++) {
        for (k = 0; k < values_of(inst, function, vr[i]); k++) refs->owned[j++] = vr[i] + (fmi2ValueReference)k;
    }
    refs->vr = refs->owned;
    refs->n = total;
    return fmi2OK;
}

/* Every reference is of the function's type (time is a Float64; an unknown reference passes, for the functions
 * behind to refuse): the FMI 2 layer's leniency (fmi2GetReal on solver.order) is not carried into FMI 3. */
static fmi2Status of_type(Instance *inst, const char *function, const fmi3ValueReference vr[], size_t nvr, int type) {
    for (size_t i = 0; i < nvr; i++) {
        const int is = vr[i] < N_VARS ? FMI3_TYPES[vr[i]] : FMI3_FLOAT64;
        if (vr[i] > N_VARS || is == type) continue;
        fmu_error(inst, "%s: %s (value reference %u) is %s %s: read and set it with %s", function,
                  vr[i] < N_VARS ? MODEL_VARS[vr[i]].name : "time", (unsigned)vr[i],
                  is == FMI3_ENUMERATION ? "an" : "a", TYPE_NAME[is], TYPE_API[is]);
        return fmu_finish(inst, fmi2Error);
    }
    return fmi2OK;
}

/* ======================================================= getting and setting values */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          fmi3Float64 values[], size_t nValues) {
    fmi2Status status = fmi2OK, one;
    Refs refs;
    BEGIN("fmi3GetFloat64", READABLE);
    REQUIRE(nValueReferences == 0 || (valueReferences != NULL && values != NULL), "fmi3GetFloat64",
            "valueReferences or values is NULL");
    if (of_type(inst, "fmi3GetFloat64", valueReferences, nValueReferences, FMI3_FLOAT64) != fmi2OK) return fmi3Error;
    if (expand(inst, "fmi3GetFloat64", valueReferences, nValueReferences, nValues, &refs) != fmi2OK) return fmi3Error;
    for (size_t i = 0; i < refs.n; i++) {
        if (refs.vr[i] == TIME_VR) {
            values[i] = inst->d.time;
            continue;
        }
        one = fmu_get_real(inst, &refs.vr[i], 1, &values[i]);   /* outputs are computed once */
        if (one > status) status = one;
        if (one > fmi2Warning) break;
    }
    free(refs.owned);
    return s3(status > fmi2Warning ? fmu_finish(inst, status) : status);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          const fmi3Float64 values[], size_t nValues) {
    fmi2Status status;
    Refs refs;
    BEGIN("fmi3SetFloat64", SETTABLE);
    REQUIRE(nValueReferences == 0 || (valueReferences != NULL && values != NULL), "fmi3SetFloat64",
            "valueReferences or values is NULL");
    for (size_t i = 0; i < nValueReferences; i++) {
        REQUIRE(valueReferences[i] != TIME_VR, "fmi3SetFloat64",
                "time is the independent variable: Co-Simulation advances it with fmi3DoStep, Model Exchange sets "
                "it with fmi3SetTime");
    }
    if (of_type(inst, "fmi3SetFloat64", valueReferences, nValueReferences, FMI3_FLOAT64) != fmi2OK) return fmi3Error;
    if (expand(inst, "fmi3SetFloat64", valueReferences, nValueReferences, nValues, &refs) != fmi2OK) return fmi3Error;
    status = fmu_set_real(inst, refs.vr, refs.n, values);
    free(refs.owned);
    return s3(fmu_finish(inst, status));
}

/* Int32 and Int64 (the Enumeration solver.order): one value per reference, kept as fmi2Integer behind. */
static fmi3Status get_integers(Instance *inst, const char *function, int type, const fmi3ValueReference vr[],
                               size_t nvr, fmi3Int32 *values32, fmi3Int64 *values64, size_t nValues) {
    fmi2Integer one;
    fmi2Status status;
    REQUIRE(nvr == 0 || (vr != NULL && (values32 != NULL || values64 != NULL)), function,
            "valueReferences or values is NULL");
    REQUIRE(nValues == nvr, function, "nValues must equal nValueReferences (no integer arrays)");
    if (of_type(inst, function, vr, nvr, type) != fmi2OK) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) {
        status = fmu_get_integer(inst, &vr[i], 1, &one);
        if (status > fmi2Warning) return s3(fmu_finish(inst, status));
        if (values32 != NULL) values32[i] = (fmi3Int32)one;
        else values64[i] = (fmi3Int64)one;
    }
    return fmi3OK;
}

static fmi3Status set_integers(Instance *inst, const char *function, int type, const fmi3ValueReference vr[],
                               size_t nvr, const fmi3Int32 *values32, const fmi3Int64 *values64, size_t nValues) {
    fmi2Integer *values;
    fmi2Status status;
    REQUIRE(nvr == 0 || (vr != NULL && (values32 != NULL || values64 != NULL)), function,
            "valueReferences or values is NULL");
    REQUIRE(nValues == nvr, function, "nValues must equal nValueReferences (no integer arrays)");
    if (of_type(inst, function, vr, nvr, type) != fmi2OK) return fmi3Error;
    values = (fmi2Integer *)calloc(nvr > 0 ? nvr : 1, sizeof(fmi2Integer));
    REQUIRE(values != NULL, function, "out of memory");
    for (size_t i = 0; i < nvr; i++) {
        const fmi3Int64 x = values32 != NULL ? (fmi3Int64)values32[i] : values64[i];
        if (x < -2147483647 - 1 || x > 2147483647) {
            free(values);
            fmu_error(inst, "%s: %s = %lld: not a value of its type", function,
                      vr[i] < N_VARS ? MODEL_VARS[vr[i]].name : "?", (long long)x);
            return s3(fmu_finish(inst, fmi2Error));
        }
        values[i] = (fmi2Integer)x;
    }
    status = fmu_set_integer(inst, vr, nvr, values);
    free(values);
    return s3(fmu_finish(inst, status));
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Int32 values[], size_t nValues) {
    BEGIN("fmi3GetInt32", READABLE);
    return get_integers(inst, "fmi3GetInt32", FMI3_INT32, valueReferences, nValueReferences, values, NULL, nValues);
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Int32 values[], size_t nValues) {
    BEGIN("fmi3SetInt32", SETTABLE);
    return set_integers(inst, "fmi3SetInt32", FMI3_INT32, valueReferences, nValueReferences, values, NULL, nValues);
}

fmi3Status fmi3GetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Int64 values[], size_t nValues) {
    BEGIN("fmi3GetInt64", READABLE);
    return get_integers(inst, "fmi3GetInt64", FMI3_ENUMERATION, valueReferences, nValueReferences, NULL, values,
                        nValues);
}

fmi3Status fmi3SetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Int64 values[], size_t nValues) {
    BEGIN("fmi3SetInt64", SETTABLE);
    return set_integers(inst, "fmi3SetInt64", FMI3_ENUMERATION, valueReferences, nValueReferences, NULL, values,
                        nValues);
}

/* The types this FMU has no variable of: any value reference is unknown. */
static fmi3Status no_variables(Instance *inst, const char *function, const fmi3ValueReference vr[], size_t nvr) {
    if (nvr == 0) return fmi3OK;
    if (vr == NULL) return s3(fmu_fail(inst, function, "valueReferences is NULL"));
    fmu_error(inst, "%s: unknown value reference %u (this FMU has Float64 and Enumeration variables only)", function,
              (unsigned)vr[0]);
    return s3(fmu_finish(inst, fmi2Error));
}

/* fmi3Get<T> and fmi3Set<T> of the types without variables. */
#define NO_VARIABLES(T, CT)                                                                                        \
    fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                      \
                          size_t nValueReferences, CT values[], size_t nValues) {                                  \
        (void)values; (void)nValues;                                                                               \
        BEGIN("fmi3Get" #T, READABLE);                                                                             \
        return no_variables(inst, "fmi3Get" #T, valueReferences, nValueReferences);                               \
    }                                                                                                              \
    fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                      \
                          size_t nValueReferences, const CT values[], size_t nValues) {                            \
        (void)values; (void)nValues;                                                                               \
        BEGIN("fmi3Set" #T, SETTABLE);                                                                             \
        return no_variables(inst, "fmi3Set" #T, valueReferences, nValueReferences);                               \
    }

NO_VARIABLES(Float32, fmi3Float32)
NO_VARIABLES(Int8, fmi3Int8)
NO_VARIABLES(UInt8, fmi3UInt8)
NO_VARIABLES(Int16, fmi3Int16)
NO_VARIABLES(UInt16, fmi3UInt16)
NO_VARIABLES(UInt32, fmi3UInt32)
NO_VARIABLES(UInt64, fmi3UInt64)
NO_VARIABLES(Boolean, fmi3Boolean)
NO_VARIABLES(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    BEGIN("fmi3GetBinary", READABLE);
    return no_variables(inst, "fmi3GetBinary", valueReferences, nValueReferences);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    BEGIN("fmi3SetBinary", SETTABLE);
    return no_variables(inst, "fmi3SetBinary", valueReferences, nValueReferences);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Clock values[]) {
    (void)values;
    BEGIN("fmi3GetClock", READABLE);
    return no_variables(inst, "fmi3GetClock", valueReferences, nValueReferences);
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Clock values[]) {
    (void)values;
    BEGIN("fmi3SetClock", SETTABLE);
    return no_variables(inst, "fmi3SetClock", valueReferences, nValueReferences);
}

/* ============================================================ FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    BEGIN("fmi3GetFMUState", PHASE_ANY);
    REQUIRE(FMUState != NULL, "fmi3GetFMUState", "FMUState is NULL");
    return s3(fmu_finish(inst, fmu_get_state(inst, FMUState)));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    BEGIN("fmi3SetFMUState", PHASE_ANY);
    return s3(fmu_finish(inst, fmu_set_state(inst, FMUState)));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    BEGIN("fmi3FreeFMUState", PHASE_ANY);
    REQUIRE(FMUState != NULL, "fmi3FreeFMUState", "FMUState is NULL");
    return s3(fmu_finish(inst, fmu_free_state(inst, FMUState)));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    BEGIN("fmi3SerializedFMUStateSize", PHASE_ANY);
    REQUIRE(size != NULL, "fmi3SerializedFMUStateSize", "size is NULL");
    REQUIRE(FMUState != NULL && ((const SavedState *)FMUState)->magic == STATE_MAGIC,
            "fmi3SerializedFMUStateSize", "not a state of this FMU");
    *size = fmu_serialized_size();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    BEGIN("fmi3SerializeFMUState", PHASE_ANY);
    REQUIRE(serializedState != NULL, "fmi3SerializeFMUState", "serializedState is NULL");
    return s3(fmu_finish(inst, fmu_serialize(inst, FMUState, (fmi2Byte *)serializedState, size)));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    BEGIN("fmi3DeserializeFMUState", PHASE_ANY);
    REQUIRE(serializedState != NULL && FMUState != NULL, "fmi3DeserializeFMUState",
            "serializedState or FMUState is NULL");
    return s3(fmu_finish(inst, fmu_deserialize(inst, (const fmi2Byte *)serializedState, size, FMUState)));
}

/* ====================================================== directional and adjoint derivatives */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    fmi2Status status;
    Refs u, k;
    BEGIN("fmi3GetDirectionalDerivative", DERIVATIVES);
    REQUIRE((nUnknowns == 0 || (unknowns != NULL && sensitivity != NULL)) &&
            (nKnowns == 0 || (knowns != NULL && seed != NULL)), "fmi3GetDirectionalDerivative",
            "a value reference or value array is NULL");
    if (expand(inst, "fmi3GetDirectionalDerivative (unknowns, nSensitivity)", unknowns, nUnknowns, nSensitivity,
               &u) != fmi2OK) {
        return fmi3Error;
    }
    status = expand(inst, "fmi3GetDirectionalDerivative (knowns, nSeed)", knowns, nKnowns, nSeed, &k);
    if (status == fmi2OK) status = fmu_directional_derivative(inst, u.vr, u.n, k.vr, k.n, seed, sensitivity);
    free(u.owned);
    free(k.owned);
    return s3(fmu_finish(inst, status));
}

/* sensitivity = J^T seed with J = d(unknowns)/d(knowns), one column of J per known element from the forward
 * derivative (the model has no reverse-mode function): one forward evaluation per known element, exact, not
 * faster than the directional derivative. */
fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    const fmi2Real one = 1.0;
    fmi2Status status;
    double *column = NULL;
    Refs u, k;
    BEGIN("fmi3GetAdjointDerivative", DERIVATIVES);
    REQUIRE((nUnknowns == 0 || (unknowns != NULL && seed != NULL)) &&
            (nKnowns == 0 || (knowns != NULL && sensitivity != NULL)), "fmi3GetAdjointDerivative",
            "a value reference or value array is NULL");
    for (size_t i = 0; i < nSeed; i++) {
        REQUIRE(isfinite(seed[i]), "fmi3GetAdjointDerivative", "a seed is NaN or infinite");
    }
    if (expand(inst, "fmi3GetAdjointDerivative (unknowns, nSeed)", unknowns, nUnknowns, nSeed, &u) != fmi2OK) {
        return fmi3Error;
    }
    status = expand(inst, "fmi3GetAdjointDerivative (knowns, nSensitivity)", knowns, nKnowns, nSensitivity, &k);
    if (status == fmi2OK) {
        column = (double *)calloc(u.n > 0 ? u.n : 1, sizeof(double));
        if (column == NULL) status = fmu_fail(inst, "fmi3GetAdjointDerivative", "out of memory");
    }
    for (size_t j = 0; j < k.n && status <= fmi2Warning; j++) {
        fmi2Status s = fmu_directional_derivative(inst, u.vr, u.n, &k.vr[j], 1, &one, column);
        if (s > status) status = s;
        sensitivity[j] = 0.0;
        for (size_t i = 0; i < u.n; i++) sensitivity[j] += seed[i] * column[i];
    }
    free(column);
    free(u.owned);
    free(k.owned);
    return s3(fmu_finish(inst, status));
}

/* ==================================================== not supported: clocks, configuration, dependencies */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    NOT_SUPPORTED("fmi3GetNumberOfVariableDependencies",
                  "not provided (providesPerElementDependencies is false): see <ModelStructure>");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents; (void)elementIndicesOfIndependents;
    (void)dependencyKinds; (void)nDependencies;
    NOT_SUPPORTED("fmi3GetVariableDependencies",
                  "not provided (providesPerElementDependencies is false): see <ModelStructure>");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    NOT_SUPPORTED("fmi3EnterConfigurationMode", "this FMU has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    NOT_SUPPORTED("fmi3ExitConfigurationMode", "this FMU has no structural parameters");
}

#define NO_CLOCKS(function) NOT_SUPPORTED(function, "this FMU has no clocks")

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    NO_CLOCKS("fmi3GetIntervalDecimal");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions; (void)qualifiers;
    NO_CLOCKS("fmi3GetIntervalFraction");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    NO_CLOCKS("fmi3GetShiftDecimal");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    NO_CLOCKS("fmi3GetShiftFraction");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    NO_CLOCKS("fmi3SetIntervalDecimal");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    NO_CLOCKS("fmi3SetIntervalFraction");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    NO_CLOCKS("fmi3SetShiftDecimal");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    NO_CLOCKS("fmi3SetShiftFraction");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    NOT_SUPPORTED("fmi3EvaluateDiscreteStates", "not provided (providesEvaluateDiscreteStates is false)");
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    NOT_SUPPORTED("fmi3ActivateModelPartition", "this FMU has no Scheduled Execution interface");
}

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
