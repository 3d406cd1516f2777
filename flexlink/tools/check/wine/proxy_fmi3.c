/* The FMI 3.0 functions of the call proxy: each describes its arguments to the wire (call_proxy.h).
 *
 * The instance and FMU states are the DLL's own pointers, passed back as they are.  The host's logMessage
 * stays on this side; the DLL gets the server's, which sends the messages here.  Not forwarded: the
 * intermediate update callback (the DLL gets NULL; an FMU that declares no intermediate update, as flexlink's,
 * never calls it) and Scheduled Execution, whose instantiation the proxy refuses (NULL) because its clock
 * and preemption callbacks would have to call back across the pipe.
 */
#include <stdio.h>
#include <stdlib.h>

#include "fmi3Functions.h"
#include "call_proxy.h"

#define I(instance) pointer_bits(instance)

static fmi3Status simple(const char *name, fmi3Instance instance) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, I(instance));
    return (fmi3Status)call_finish(&c);
}

const char *fmi3GetVersion(void) {
    static const char *kept;
    Call c;
    if (kept != NULL) return kept;
    call_begin(&c, "fmi3GetVersion", RET_STRING);
    return kept = (const char *)(uintptr_t)call_finish(&c);
}

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean on, size_t n, const fmi3String categories[]) {
    Call c;
    call_begin(&c, "fmi3SetDebugLogging", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, (uint64_t)on);
    call_scalar(&c, n);
    call_strings_in(&c, categories, n);
    return (fmi3Status)call_finish(&c);
}

/* the arguments every instantiation begins with; the resource path as the DLL sees it under Wine */
static char *instantiation(Call *c, const char *name, fmi3String instanceName, fmi3String token,
                           fmi3String resources, fmi3Boolean visible, fmi3Boolean loggingOn) {
    char *path = resources != NULL ? windows_path(resources) : NULL;
    call_begin(c, name, RET_POINTER);
    call_string(c, instanceName);
    call_string(c, token);
    call_string(c, path);
    call_scalar(c, (uint64_t)visible);
    call_scalar(c, (uint64_t)loggingOn);
    return path;
}

static void environment_and_logger(Call *c, fmi3InstanceEnvironment environment, fmi3LogMessageCallback logger) {
    LogRoute route = {NULL, (void (*)(void *, int, const char *, const char *))logger, environment};
    call_scalar(c, logger != NULL ? route_add(route) : 0);
    call_logger3(c, logger != NULL);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String token, fmi3String resources,
                                          fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment environment, fmi3LogMessageCallback logger) {
    Call c;
    char *path = instantiation(&c, "fmi3InstantiateModelExchange", instanceName, token, resources, visible,
                               loggingOn);
    fmi3Instance instance;
    environment_and_logger(&c, environment, logger);
    instance = (fmi3Instance)(uintptr_t)call_finish(&c);
    free(path);
    return instance;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String token, fmi3String resources,
                                         fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed, const fmi3ValueReference required[],
                                         size_t nRequired, fmi3InstanceEnvironment environment,
                                         fmi3LogMessageCallback logger,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    Call c;
    char *path = instantiation(&c, "fmi3InstantiateCoSimulation", instanceName, token, resources, visible,
                               loggingOn);
    fmi3Instance instance;
    (void)intermediateUpdate;
    call_scalar(&c, (uint64_t)eventModeUsed);
    call_scalar(&c, (uint64_t)earlyReturnAllowed);
    call_in(&c, required, nRequired * sizeof *required);
    call_scalar(&c, nRequired);
    environment_and_logger(&c, environment, logger);
    call_in(&c, NULL, 0);                                       /* intermediateUpdate: not forwarded */
    instance = (fmi3Instance)(uintptr_t)call_finish(&c);
    free(path);
    return instance;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String token, fmi3String resources,
                                               fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment environment, fmi3LogMessageCallback logger,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName, (void)token, (void)resources, (void)visible, (void)loggingOn, (void)environment;
    (void)logger, (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    fprintf(stderr, "flexlink call proxy: Scheduled Execution is not forwarded to the win64 DLL\n");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    Call c;
    call_begin(&c, "fmi3FreeInstance", RET_VOID);
    call_scalar(&c, I(instance));
    call_finish(&c);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    Call c;
    call_begin(&c, "fmi3EnterInitializationMode", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, (uint64_t)toleranceDefined);
    call_double(&c, tolerance);
    call_double(&c, startTime);
    call_scalar(&c, (uint64_t)stopTimeDefined);
    call_double(&c, stopTime);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance i) { return simple("fmi3ExitInitializationMode", i); }
fmi3Status fmi3EnterEventMode(fmi3Instance i) { return simple("fmi3EnterEventMode", i); }
fmi3Status fmi3Terminate(fmi3Instance i) { return simple("fmi3Terminate", i); }
fmi3Status fmi3Reset(fmi3Instance i) { return simple("fmi3Reset", i); }
fmi3Status fmi3EnterConfigurationMode(fmi3Instance i) { return simple("fmi3EnterConfigurationMode", i); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance i) { return simple("fmi3ExitConfigurationMode", i); }
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance i) { return simple("fmi3EvaluateDiscreteStates", i); }
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance i) { return simple("fmi3EnterContinuousTimeMode", i); }
fmi3Status fmi3EnterStepMode(fmi3Instance i) { return simple("fmi3EnterStepMode", i); }

/* ------------------------------------------------------------------------------------------- get and set */

/* value references in; nValues values of one size out (get) or in (set); with_count: nValues is passed */
static fmi3Status values(const char *name, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                         void *value, size_t size, size_t count, int out, int with_count) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    if (out) call_out(&c, value, count * size);
    else call_in(&c, value, count * size);
    if (with_count) call_scalar(&c, count);
    return (fmi3Status)call_finish(&c);
}

#define GET_SET(T, type)                                                                                        \
    fmi3Status fmi3Get##T(fmi3Instance i, const fmi3ValueReference vr[], size_t n, type v[], size_t nv) {       \
        return values("fmi3Get" #T, i, vr, n, v, sizeof(type), nv, 1, 1);                                       \
    }                                                                                                           \
    fmi3Status fmi3Set##T(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const type v[], size_t nv) { \
        return values("fmi3Set" #T, i, vr, n, (void *)v, sizeof(type), nv, 0, 1);                               \
    }

GET_SET(Float32, fmi3Float32)
GET_SET(Float64, fmi3Float64)
GET_SET(Int8, fmi3Int8)
GET_SET(UInt8, fmi3UInt8)
GET_SET(Int16, fmi3Int16)
GET_SET(UInt16, fmi3UInt16)
GET_SET(Int32, fmi3Int32)
GET_SET(UInt32, fmi3UInt32)
GET_SET(Int64, fmi3Int64)
GET_SET(UInt64, fmi3UInt64)
GET_SET(Boolean, fmi3Boolean)

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t n, fmi3String v[],
                         size_t nv) {
    Call c;
    call_begin(&c, "fmi3GetString", RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_strings_out(&c, v, nv);
    call_scalar(&c, nv);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t n, const fmi3String v[],
                         size_t nv) {
    Call c;
    call_begin(&c, "fmi3SetString", RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_strings_in(&c, v, nv);
    call_scalar(&c, nv);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t n, size_t sizes[],
                         fmi3Binary v[], size_t nv) {
    Call c;
    call_begin(&c, "fmi3GetBinary", RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_out(&c, sizes, nv * sizeof *sizes);
    call_binaries_out(&c, v, nv, 3);                        /* the sizes are argument 3 */
    call_scalar(&c, nv);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t n, const size_t sizes[],
                         const fmi3Binary v[], size_t nv) {
    Call c;
    call_begin(&c, "fmi3SetBinary", RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_in(&c, sizes, nv * sizeof *sizes);
    call_binaries_in(&c, sizes, v, nv);
    call_scalar(&c, nv);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3GetClock(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3Clock v[]) {
    return values("fmi3GetClock", i, vr, n, v, sizeof *v, n, 1, 0);
}
fmi3Status fmi3SetClock(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const fmi3Clock v[]) {
    return values("fmi3SetClock", i, vr, n, (void *)v, sizeof *v, n, 0, 0);
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3Float64 v[]) {
    return values("fmi3GetShiftDecimal", i, vr, n, v, sizeof *v, n, 1, 0);
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const fmi3Float64 v[]) {
    return values("fmi3SetShiftDecimal", i, vr, n, (void *)v, sizeof *v, n, 0, 0);
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const fmi3Float64 v[]) {
    return values("fmi3SetIntervalDecimal", i, vr, n, (void *)v, sizeof *v, n, 0, 0);
}

/* clock intervals and shifts given as arrays, one element per value reference: a and b (if size_b) in or out,
 * and the interval qualifiers out (if q_out) */
static fmi3Status clock_arrays(const char *name, fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                               void *a, size_t size_a, void *b, size_t size_b, fmi3IntervalQualifier *q, int out,
                               int q_out) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    if (out) call_out(&c, a, n * size_a);
    else call_in(&c, a, n * size_a);
    if (size_b && out) call_out(&c, b, n * size_b);
    else if (size_b) call_in(&c, b, n * size_b);
    if (q_out) call_out(&c, q, n * sizeof *q);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3Float64 v[],
                                  fmi3IntervalQualifier q[]) {
    return clock_arrays("fmi3GetIntervalDecimal", i, vr, n, v, sizeof *v, NULL, 0, q, 1, 1);
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier q[]) {
    return clock_arrays("fmi3GetIntervalFraction", i, vr, n, counters, sizeof *counters, resolutions,
                        sizeof *resolutions, q, 1, 1);
}
fmi3Status fmi3GetShiftFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    return clock_arrays("fmi3GetShiftFraction", i, vr, n, counters, sizeof *counters, resolutions,
                        sizeof *resolutions, NULL, 1, 0);
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    return clock_arrays("fmi3SetIntervalFraction", i, vr, n, (void *)counters, sizeof *counters,
                        (void *)resolutions, sizeof *resolutions, NULL, 0, 0);
}
fmi3Status fmi3SetShiftFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    return clock_arrays("fmi3SetShiftFraction", i, vr, n, (void *)counters, sizeof *counters,
                        (void *)resolutions, sizeof *resolutions, NULL, 0, 0);
}

/* ------------------------------------------------------------------------------------------- dependencies */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference vr, size_t *n) {
    Call c;
    call_begin(&c, "fmi3GetNumberOfVariableDependencies", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, vr);
    call_inout(&c, n, sizeof *n);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind kinds[],
                                       size_t n) {
    Call c;
    call_begin(&c, "fmi3GetVariableDependencies", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, dependent);
    call_out(&c, elementIndicesOfDependent, n * sizeof *elementIndicesOfDependent);
    call_out(&c, independents, n * sizeof *independents);
    call_out(&c, elementIndicesOfIndependents, n * sizeof *elementIndicesOfIndependents);
    call_out(&c, kinds, n * sizeof *kinds);
    call_scalar(&c, n);
    return (fmi3Status)call_finish(&c);
}

/* ------------------------------------------------------------------------------------------- FMU state */

static fmi3Status state(const char *name, fmi3Instance instance, fmi3FMUState *s) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, I(instance));
    call_inout(&c, s, sizeof *s);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3GetFMUState(fmi3Instance i, fmi3FMUState *s) { return state("fmi3GetFMUState", i, s); }
fmi3Status fmi3FreeFMUState(fmi3Instance i, fmi3FMUState *s) { return state("fmi3FreeFMUState", i, s); }

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState s) {
    Call c;
    call_begin(&c, "fmi3SetFMUState", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, pointer_bits(s));
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState s, size_t *size) {
    Call c;
    call_begin(&c, "fmi3SerializedFMUStateSize", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, pointer_bits(s));
    call_inout(&c, size, sizeof *size);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState s, fmi3Byte bytes[], size_t size) {
    Call c;
    call_begin(&c, "fmi3SerializeFMUState", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, pointer_bits(s));
    call_out(&c, bytes, size);
    call_scalar(&c, size);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte bytes[], size_t size, fmi3FMUState *s) {
    Call c;
    call_begin(&c, "fmi3DeserializeFMUState", RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, bytes, size);
    call_scalar(&c, size);
    call_inout(&c, s, sizeof *s);
    return (fmi3Status)call_finish(&c);
}

/* ------------------------------------------------------------------------------------------- derivatives */

static fmi3Status derivative(const char *name, fmi3Instance instance, const fmi3ValueReference unknowns[],
                             size_t nu, const fmi3ValueReference knowns[], size_t nk, const fmi3Float64 seed[],
                             size_t ns, fmi3Float64 sensitivity[], size_t nsens) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, unknowns, nu * sizeof *unknowns);
    call_scalar(&c, nu);
    call_in(&c, knowns, nk * sizeof *knowns);
    call_scalar(&c, nk);
    call_in(&c, seed, ns * sizeof *seed);
    call_scalar(&c, ns);
    call_out(&c, sensitivity, nsens * sizeof *sensitivity);
    call_scalar(&c, nsens);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance i, const fmi3ValueReference u[], size_t nu,
                                        const fmi3ValueReference k[], size_t nk, const fmi3Float64 seed[],
                                        size_t ns, fmi3Float64 sensitivity[], size_t nsens) {
    return derivative("fmi3GetDirectionalDerivative", i, u, nu, k, nk, seed, ns, sensitivity, nsens);
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance i, const fmi3ValueReference u[], size_t nu,
                                    const fmi3ValueReference k[], size_t nk, const fmi3Float64 seed[], size_t ns,
                                    fmi3Float64 sensitivity[], size_t nsens) {
    return derivative("fmi3GetAdjointDerivative", i, u, nu, k, nk, seed, ns, sensitivity, nsens);
}

/* ------------------------------------------------------------------------------------------- event mode */

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsChanged,
                                    fmi3Boolean *valuesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    Call c;
    call_begin(&c, "fmi3UpdateDiscreteStates", RET_INT);
    call_scalar(&c, I(instance));
    call_inout(&c, discreteStatesNeedUpdate, sizeof(fmi3Boolean));
    call_inout(&c, terminateSimulation, sizeof(fmi3Boolean));
    call_inout(&c, nominalsChanged, sizeof(fmi3Boolean));
    call_inout(&c, valuesChanged, sizeof(fmi3Boolean));
    call_inout(&c, nextEventTimeDefined, sizeof(fmi3Boolean));
    call_inout(&c, nextEventTime, sizeof(fmi3Float64));
    return (fmi3Status)call_finish(&c);
}

/* ------------------------------------------------------------------------------------------- Model Exchange */

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    Call c;
    call_begin(&c, "fmi3CompletedIntegratorStep", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, (uint64_t)noSetFMUStatePriorToCurrentPoint);
    call_inout(&c, enterEventMode, sizeof *enterEventMode);
    call_inout(&c, terminateSimulation, sizeof *terminateSimulation);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    Call c;
    call_begin(&c, "fmi3SetTime", RET_INT);
    call_scalar(&c, I(instance));
    call_double(&c, time);
    return (fmi3Status)call_finish(&c);
}

static fmi3Status reals(const char *name, fmi3Instance instance, fmi3Float64 *x, size_t n, int out) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, I(instance));
    if (out) call_out(&c, x, n * sizeof *x);
    else call_in(&c, x, n * sizeof *x);
    call_scalar(&c, n);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance i, const fmi3Float64 x[], size_t n) {
    return reals("fmi3SetContinuousStates", i, (fmi3Float64 *)x, n, 0);
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance i, fmi3Float64 dx[], size_t n) {
    return reals("fmi3GetContinuousStateDerivatives", i, dx, n, 1);
}
fmi3Status fmi3GetEventIndicators(fmi3Instance i, fmi3Float64 z[], size_t n) {
    return reals("fmi3GetEventIndicators", i, z, n, 1);
}
fmi3Status fmi3GetContinuousStates(fmi3Instance i, fmi3Float64 x[], size_t n) {
    return reals("fmi3GetContinuousStates", i, x, n, 1);
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance i, fmi3Float64 x[], size_t n) {
    return reals("fmi3GetNominalsOfContinuousStates", i, x, n, 1);
}

static fmi3Status count(const char *name, fmi3Instance instance, size_t *n) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, I(instance));
    call_inout(&c, n, sizeof *n);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance i, size_t *n) {
    return count("fmi3GetNumberOfEventIndicators", i, n);
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance i, size_t *n) {
    return count("fmi3GetNumberOfContinuousStates", i, n);
}

/* ------------------------------------------------------------------------------------------- Co-Simulation */

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
                                    const fmi3Int32 orders[], fmi3Float64 v[], size_t nv) {
    Call c;
    call_begin(&c, "fmi3GetOutputDerivatives", RET_INT);
    call_scalar(&c, I(instance));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_in(&c, orders, n * sizeof *orders);
    call_out(&c, v, nv * sizeof *v);
    call_scalar(&c, nv);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastSuccessfulTime) {
    Call c;
    call_begin(&c, "fmi3DoStep", RET_INT);
    call_scalar(&c, I(instance));
    call_double(&c, t);
    call_double(&c, h);
    call_scalar(&c, (uint64_t)noSetFMUStatePriorToCurrentPoint);
    call_inout(&c, eventHandlingNeeded, sizeof *eventHandlingNeeded);
    call_inout(&c, terminateSimulation, sizeof *terminateSimulation);
    call_inout(&c, earlyReturn, sizeof *earlyReturn);
    call_inout(&c, lastSuccessfulTime, sizeof *lastSuccessfulTime);
    return (fmi3Status)call_finish(&c);
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clock, fmi3Float64 time) {
    Call c;
    call_begin(&c, "fmi3ActivateModelPartition", RET_INT);
    call_scalar(&c, I(instance));
    call_scalar(&c, clock);
    call_double(&c, time);
    return (fmi3Status)call_finish(&c);
}
