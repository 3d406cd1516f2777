/* The 44 FMI 2.0 functions of the call proxy: each describes its arguments to the wire (call_proxy.h).
 *
 * The component and FMU states are the DLL's own pointers, passed back as they are.  The callbacks stay on
 * this side (the host's logger receives the DLL's messages); the DLL gets the server's, which allocate in
 * the server's process, and NULL where the host gave NULL.  An FMU state serialised here is the DLL's bytes.
 */
#include <stdlib.h>

#include "fmi2Functions.h"
#include "call_proxy.h"

#define C(c_) pointer_bits(c_)

static fmi2Status simple(const char *name, fmi2Component c_) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, C(c_));
    return (fmi2Status)call_finish(&c);
}

static const char *text(const char *name) {
    Call c;
    call_begin(&c, name, RET_STRING);
    return (const char *)(uintptr_t)call_finish(&c);
}

const char *fmi2GetTypesPlatform(void) {
    static const char *kept;
    return kept != NULL ? kept : (kept = text("fmi2GetTypesPlatform"));
}

const char *fmi2GetVersion(void) {
    static const char *kept;
    return kept != NULL ? kept : (kept = text("fmi2GetVersion"));
}

fmi2Status fmi2SetDebugLogging(fmi2Component c_, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    Call c;
    call_begin(&c, "fmi2SetDebugLogging", RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, (uint32_t)on);
    call_scalar(&c, n);
    call_strings_in(&c, categories, n);
    return (fmi2Status)call_finish(&c);
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible, fmi2Boolean loggingOn) {
    Call c;
    char *uri = windows_uri(resources);
    fmi2Component component;
    call_begin(&c, "fmi2Instantiate", RET_POINTER);
    call_string(&c, name);
    call_scalar(&c, (uint32_t)type);
    call_string(&c, guid);
    call_string(&c, uri);
    if (functions == NULL) {
        call_in(&c, NULL, 0);
    } else {
        LogRoute route = {(void (*)(void *, const char *, int, const char *, const char *, ...))functions->logger, NULL,
                          functions->componentEnvironment};
        uint64_t mask = (functions->logger != NULL ? 1u : 0u) | (functions->allocateMemory != NULL ? 2u : 0u)
                      | (functions->freeMemory != NULL ? 4u : 0u);
        call_callbacks2(&c, mask, route_add(route));
    }
    call_scalar(&c, (uint32_t)visible);
    call_scalar(&c, (uint32_t)loggingOn);
    component = (fmi2Component)(uintptr_t)call_finish(&c);
    free(uri);
    return component;
}

void fmi2FreeInstance(fmi2Component c_) {
    Call c;
    call_begin(&c, "fmi2FreeInstance", RET_VOID);
    call_scalar(&c, C(c_));
    call_finish(&c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c_, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Call c;
    call_begin(&c, "fmi2SetupExperiment", RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, (uint32_t)toleranceDefined);
    call_double(&c, tolerance);
    call_double(&c, startTime);
    call_scalar(&c, (uint32_t)stopTimeDefined);
    call_double(&c, stopTime);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return simple("fmi2EnterInitializationMode", c); }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return simple("fmi2ExitInitializationMode", c); }
fmi2Status fmi2Terminate(fmi2Component c) { return simple("fmi2Terminate", c); }
fmi2Status fmi2Reset(fmi2Component c) { return simple("fmi2Reset", c); }
fmi2Status fmi2EnterEventMode(fmi2Component c) { return simple("fmi2EnterEventMode", c); }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return simple("fmi2EnterContinuousTimeMode", c); }
fmi2Status fmi2CancelStep(fmi2Component c) { return simple("fmi2CancelStep", c); }

/* get and set: value references in, values out or in (each type its size) */
static fmi2Status values(const char *name, fmi2Component c_, const fmi2ValueReference vr[], size_t n,
                         void *value, size_t size, int out) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, C(c_));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    if (out) call_out(&c, value, n * size);
    else call_in(&c, value, n * size);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    return values("fmi2GetReal", c, vr, n, value, sizeof *value, 1);
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    return values("fmi2GetInteger", c, vr, n, value, sizeof *value, 1);
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    return values("fmi2GetBoolean", c, vr, n, value, sizeof *value, 1);
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    return values("fmi2SetReal", c, vr, n, (void *)value, sizeof *value, 0);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    return values("fmi2SetInteger", c, vr, n, (void *)value, sizeof *value, 0);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    return values("fmi2SetBoolean", c, vr, n, (void *)value, sizeof *value, 0);
}

fmi2Status fmi2GetString(fmi2Component c_, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
    Call c;
    call_begin(&c, "fmi2GetString", RET_INT);
    call_scalar(&c, C(c_));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_strings_out(&c, value, n);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2SetString(fmi2Component c_, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) {
    Call c;
    call_begin(&c, "fmi2SetString", RET_INT);
    call_scalar(&c, C(c_));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_strings_in(&c, value, n);
    return (fmi2Status)call_finish(&c);
}

/* FMU state: a pointer of the DLL's, in and out */
static fmi2Status state(const char *name, fmi2Component c_, fmi2FMUstate *s) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, C(c_));
    call_inout(&c, s, sizeof *s);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { return state("fmi2GetFMUstate", c, s); }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { return state("fmi2FreeFMUstate", c, s); }

fmi2Status fmi2SetFMUstate(fmi2Component c_, fmi2FMUstate s) {
    Call c;
    call_begin(&c, "fmi2SetFMUstate", RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, pointer_bits(s));
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c_, fmi2FMUstate s, size_t *size) {
    Call c;
    call_begin(&c, "fmi2SerializedFMUstateSize", RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, pointer_bits(s));
    call_inout(&c, size, sizeof *size);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c_, fmi2FMUstate s, fmi2Byte bytes[], size_t size) {
    Call c;
    call_begin(&c, "fmi2SerializeFMUstate", RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, pointer_bits(s));
    call_out(&c, bytes, size);
    call_scalar(&c, size);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c_, const fmi2Byte bytes[], size_t size, fmi2FMUstate *s) {
    Call c;
    call_begin(&c, "fmi2DeSerializeFMUstate", RET_INT);
    call_scalar(&c, C(c_));
    call_in(&c, bytes, size);
    call_scalar(&c, size);
    call_inout(&c, s, sizeof *s);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c_, const fmi2ValueReference unknown[], size_t nu,
                                        const fmi2ValueReference known[], size_t nk, const fmi2Real dv_known[],
                                        fmi2Real dv_unknown[]) {
    Call c;
    call_begin(&c, "fmi2GetDirectionalDerivative", RET_INT);
    call_scalar(&c, C(c_));
    call_in(&c, unknown, nu * sizeof *unknown);
    call_scalar(&c, nu);
    call_in(&c, known, nk * sizeof *known);
    call_scalar(&c, nk);
    call_in(&c, dv_known, nk * sizeof *dv_known);
    call_out(&c, dv_unknown, nu * sizeof *dv_unknown);
    return (fmi2Status)call_finish(&c);
}

/* ------------------------------------------------------------------------------------------- Model Exchange */

fmi2Status fmi2NewDiscreteStates(fmi2Component c_, fmi2EventInfo *info) {
    Call c;
    call_begin(&c, "fmi2NewDiscreteStates", RET_INT);
    call_scalar(&c, C(c_));
    call_inout(&c, info, sizeof *info);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c_, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    Call c;
    call_begin(&c, "fmi2CompletedIntegratorStep", RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, (uint32_t)noSetFMUStatePriorToCurrentPoint);
    call_inout(&c, enterEventMode, sizeof *enterEventMode);
    call_inout(&c, terminateSimulation, sizeof *terminateSimulation);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2SetTime(fmi2Component c_, fmi2Real time) {
    Call c;
    call_begin(&c, "fmi2SetTime", RET_INT);
    call_scalar(&c, C(c_));
    call_double(&c, time);
    return (fmi2Status)call_finish(&c);
}

/* an array of reals and its length: in (set) or out (get) */
static fmi2Status reals(const char *name, fmi2Component c_, fmi2Real *x, size_t n, int out) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, C(c_));
    if (out) call_out(&c, x, n * sizeof *x);
    else call_in(&c, x, n * sizeof *x);
    call_scalar(&c, n);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    return reals("fmi2SetContinuousStates", c, (fmi2Real *)x, n, 0);
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    return reals("fmi2GetDerivatives", c, dx, n, 1);
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) {
    return reals("fmi2GetEventIndicators", c, z, n, 1);
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    return reals("fmi2GetContinuousStates", c, x, n, 1);
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    return reals("fmi2GetNominalsOfContinuousStates", c, x, n, 1);
}

/* ------------------------------------------------------------------------------------------- Co-Simulation */

static fmi2Status input_derivatives(const char *name, fmi2Component c_, const fmi2ValueReference vr[], size_t n,
                                    const fmi2Integer order[], fmi2Real *value, int out) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, C(c_));
    call_in(&c, vr, n * sizeof *vr);
    call_scalar(&c, n);
    call_in(&c, order, n * sizeof *order);
    if (out) call_out(&c, value, n * sizeof *value);
    else call_in(&c, value, n * sizeof *value);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    return input_derivatives("fmi2SetRealInputDerivatives", c, vr, n, order, (fmi2Real *)value, 0);
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    return input_derivatives("fmi2GetRealOutputDerivatives", c, vr, n, order, value, 1);
}

fmi2Status fmi2DoStep(fmi2Component c_, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Call c;
    call_begin(&c, "fmi2DoStep", RET_INT);
    call_scalar(&c, C(c_));
    call_double(&c, t);
    call_double(&c, h);
    call_scalar(&c, (uint32_t)noSetFMUStatePriorToCurrentPoint);
    return (fmi2Status)call_finish(&c);
}

/* a status query: one value of the kind's size out */
static fmi2Status status(const char *name, fmi2Component c_, fmi2StatusKind kind, void *value, size_t size) {
    Call c;
    call_begin(&c, name, RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, (uint32_t)kind);
    call_inout(&c, value, size);
    return (fmi2Status)call_finish(&c);
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    return status("fmi2GetStatus", c, s, value, sizeof *value);
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    return status("fmi2GetRealStatus", c, s, value, sizeof *value);
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    return status("fmi2GetIntegerStatus", c, s, value, sizeof *value);
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    return status("fmi2GetBooleanStatus", c, s, value, sizeof *value);
}

fmi2Status fmi2GetStringStatus(fmi2Component c_, const fmi2StatusKind s, fmi2String *value) {
    Call c;
    call_begin(&c, "fmi2GetStringStatus", RET_INT);
    call_scalar(&c, C(c_));
    call_scalar(&c, (uint32_t)s);
    call_strings_out(&c, value, 1);
    return (fmi2Status)call_finish(&c);
}
