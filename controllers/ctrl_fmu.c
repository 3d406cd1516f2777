/* The sampled MIMO LQG of controllers.multijoint.MimoLQGLaw as a pure-C FMI 2.0 Co-Simulation FMU.
 *
 * controllers/export.py writes ctrl_data.h (the sizes, the matrices, the operating point, the torque limits
 * and the sample time) next to this file and compiles both.  Value references, in this order:
 *   inputs   y[NY]      the sensors (absolute)
 *            xref[NX]   the reference state (deviation from the operating point)
 *            uff[NU]    the feedforward torque (deviation)
 *            w[NX]      the reference's own step in the deviation's prediction (0 along a plant trajectory)
 *   outputs  u[NU]      the saturated torques (absolute)
 * At a communication point the outputs follow the inputs set there (current estimator, direct feedthrough):
 *   e = z + M (y − y0 − C (xref + z)),   u = sat(u0 + uff − K e)
 * and fmi2DoStep(t, DT) advances the prior estimate:  z ← Ad e + Bd (u − u0 − uff) − w.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "ctrl_data.h"

#define NIN (NY + NX + NU + NX)
#define NVAR (NIN + NU)

typedef struct {
    fmi2CallbackFunctions cb;
    char *name;
    double in[NIN];
    double z[NX], e[NX], u[NU];
    double t;
    int initialising;
} Ctrl;

static void say(Ctrl *c, fmi2Status s, const char *fmt, ...) {
    char buf[512];
    va_list ap;
    if (!c || !c->cb.logger) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    c->cb.logger(c->cb.componentEnvironment, c->name, s, s == fmi2OK ? "logAll" : "logStatusError", "%s", buf);
}

static void outputs(Ctrl *c) {
    const double *y = c->in, *xref = c->in + NY, *uff = c->in + NY + NX;
    double innov[NY];
    for (int i = 0; i < NY; i++) {
        double s = y[i] - Y0[i];
        for (int j = 0; j < NX; j++) s -= CY[i][j] * (xref[j] + c->z[j]);
        innov[i] = s;
    }
    for (int i = 0; i < NX; i++) {
        double s = c->z[i];
        for (int j = 0; j < NY; j++) s += MK[i][j] * innov[j];
        c->e[i] = s;
    }
    for (int i = 0; i < NU; i++) {
        double s = U0[i] + uff[i];
        for (int j = 0; j < NX; j++) s -= KD[i][j] * c->e[j];
        c->u[i] = s < -LIM[i] ? -LIM[i] : (s > LIM[i] ? LIM[i] : s);
    }
}

static void reset(Ctrl *c) {
    memset(c->in, 0, sizeof c->in);
    for (int i = 0; i < NY; i++) c->in[i] = Y0[i];
    memset(c->z, 0, sizeof c->z);
    c->t = 0.0;
    c->initialising = 0;
}

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

FMI2_Export fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                                          const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean log) {
    (void)location; (void)visible; (void)log;
    if (!cb || !cb->allocateMemory || !cb->freeMemory) return NULL;
    if (type != fmi2CoSimulation || !guid || strcmp(guid, GUID) != 0) {
        if (cb->logger) cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                                   "fmi2Instantiate: a Co-Simulation FMU with GUID %s", GUID);
        return NULL;
    }
    Ctrl *c = cb->allocateMemory(1, sizeof(Ctrl));
    if (!c) return NULL;
    c->cb = *cb;
    size_t len = strlen(name ? name : "") + 1;
    c->name = cb->allocateMemory(len, 1);
    if (c->name) memcpy(c->name, name ? name : "", len);
    reset(c);
    return c;
}

FMI2_Export void fmi2FreeInstance(fmi2Component comp) {
    Ctrl *c = comp;
    if (!c) return;
    void (*release)(void *) = c->cb.freeMemory;
    release(c->name);
    release(c);
}

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean tolDefined, fmi2Real tol,
                                           fmi2Real start, fmi2Boolean stopDefined, fmi2Real stop) {
    (void)tolDefined; (void)tol; (void)stopDefined; (void)stop;
    if (!comp) return fmi2Error;
    ((Ctrl *)comp)->t = start;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    ((Ctrl *)comp)->initialising = 1;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    ((Ctrl *)comp)->initialising = 0;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component comp) { (void)comp; return fmi2OK; }

FMI2_Export fmi2Status fmi2Reset(fmi2Component comp) {
    if (!comp) return fmi2Error;
    reset(comp);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Ctrl *c = comp;
    if (!c) return fmi2Error;
    outputs(c);
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NVAR) {
            say(c, fmi2Error, "fmi2GetReal: no variable with value reference %u", (unsigned)vr[k]);
            return fmi2Error;
        }
        value[k] = vr[k] < NIN ? c->in[vr[k]] : c->u[vr[k] - NIN];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                   const fmi2Real value[]) {
    Ctrl *c = comp;
    if (!c) return fmi2Error;
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NIN) {
            say(c, fmi2Error, "fmi2SetReal: value reference %u is not an input", (unsigned)vr[k]);
            return fmi2Error;
        }
        if (!isfinite(value[k])) {
            say(c, fmi2Error, "fmi2SetReal: input %u is not finite", (unsigned)vr[k]);
            return fmi2Error;
        }
    }
    for (size_t k = 0; k < n; k++) c->in[vr[k]] = value[k];
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Ctrl *c = comp;
    if (!c) return fmi2Error;
    (void)noSetPrior;
    if (fabs(h - DT) > 1e-9 * DT) {
        say(c, fmi2Error, "fmi2DoStep: the controller samples at %.17g s; got a step of %.17g s", DT, h);
        return fmi2Error;
    }
    const double *uff = c->in + NY + NX, *w = c->in + NY + NX + NU;
    double du[NU], z[NX];
    outputs(c);
    for (int i = 0; i < NU; i++) du[i] = c->u[i] - U0[i] - uff[i];
    for (int i = 0; i < NX; i++) {
        double s = -w[i];
        for (int j = 0; j < NX; j++) s += AD[i][j] * c->e[j];
        for (int j = 0; j < NU; j++) s += BD[i][j] * du[j];
        z[i] = s;
    }
    memcpy(c->z, z, sizeof z);
    c->t = t + h;
    return fmi2OK;
}

/* not supported: integers, booleans, strings, FMU state, derivatives, asynchronous steps */
#define REFUSE(what) do { say((Ctrl *)comp, fmi2Error, "%s is not supported by this controller FMU", what); \
                          return fmi2Error; } while (0)

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                      fmi2Integer v[]) { (void)vr; (void)v; if (n == 0) return fmi2OK;
                                                         REFUSE("fmi2GetInteger"); }
FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                      fmi2Boolean v[]) { (void)vr; (void)v; if (n == 0) return fmi2OK;
                                                         REFUSE("fmi2GetBoolean"); }
FMI2_Export fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                     fmi2String v[]) { (void)vr; (void)v; if (n == 0) return fmi2OK;
                                                       REFUSE("fmi2GetString"); }
FMI2_Export fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Integer v[]) { (void)vr; (void)v; if (n == 0) return fmi2OK;
                                                               REFUSE("fmi2SetInteger"); }
FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Boolean v[]) { (void)vr; (void)v; if (n == 0) return fmi2OK;
                                                               REFUSE("fmi2SetBoolean"); }
FMI2_Export fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                     const fmi2String v[]) { (void)vr; (void)v; if (n == 0) return fmi2OK;
                                                             REFUSE("fmi2SetString"); }
FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *s) { (void)s; REFUSE("fmi2GetFMUstate"); }
FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate s) { (void)s; REFUSE("fmi2SetFMUstate"); }
FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *s) { (void)s; REFUSE("fmi2FreeFMUstate"); }
FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate s, size_t *n) {
    (void)s; (void)n; REFUSE("fmi2SerializedFMUstateSize");
}
FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)s; (void)b; (void)n; REFUSE("fmi2SerializeFMUstate");
}
FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    (void)s; (void)b; (void)n; REFUSE("fmi2DeSerializeFMUstate");
}
FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                                    fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz; REFUSE("fmi2GetDirectionalDerivative");
}
FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer order[], const fmi2Real v[]) {
    (void)vr; (void)n; (void)order; (void)v; REFUSE("fmi2SetRealInputDerivatives");
}
FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer order[], fmi2Real v[]) {
    (void)vr; (void)n; (void)order; (void)v; REFUSE("fmi2GetRealOutputDerivatives");
}
FMI2_Export fmi2Status fmi2CancelStep(fmi2Component comp) { REFUSE("fmi2CancelStep"); }
FMI2_Export fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind k, fmi2Status *v) {
    (void)k; (void)v; REFUSE("fmi2GetStatus");
}
FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind k, fmi2Real *v) {
    if (k == fmi2LastSuccessfulTime) { *v = ((Ctrl *)comp)->t; return fmi2OK; }
    REFUSE("fmi2GetRealStatus");
}
FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind k, fmi2Integer *v) {
    (void)k; (void)v; REFUSE("fmi2GetIntegerStatus");
}
FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind k, fmi2Boolean *v) {
    (void)k; (void)v; REFUSE("fmi2GetBooleanStatus");
}
FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind k, fmi2String *v) {
    (void)k; (void)v; REFUSE("fmi2GetStringStatus");
}
