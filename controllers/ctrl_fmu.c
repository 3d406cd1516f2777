/* The sampled MIMO LQG of controllers.multijoint.MimoLQGLaw as a pure-C FMI 2.0 Co-Simulation FMU.
 *
 * controllers/export.py writes ctrl_data.h (the sizes, the matrices, the operating point, the torque limits,
 * the sample time and, when the controller plays a manoeuvre itself, the reference tables) next to this file
 * and compiles both.  Value references, in this order:
 *   inputs   y[NY]      the sensors (absolute)
 *            xref[NX]   the reference state (deviation from the operating point)
 *            uff[NU]    the feedforward torque (deviation)
 *            w[NX]      the reference's own step in the deviation's prediction (0 along a plant trajectory)
 *   outputs  u[NU]      the saturated torques (absolute)
 * With a built-in reference (NREF > 0) the reference inputs add to its row k (the last row held after its end).
 *
 * A sample is taken by fmi2DoStep(t_k, DT), from the inputs set at t_k (current estimator):
 *   e = z + M (y − y0 − C (xref + z)),   u = sat(u0 + uff − K e),   z ← Ad e + Bd (u − u0 − uff) − w
 * and u is the output from then on, until the next step: the torque of the sample just taken, held.  The
 * outputs thus never depend on inputs set at the same communication point (no direct feedthrough), and the
 * importer decides the delay: one that steps this FMU first at t_k and then the plant with its output (fmpy's
 * loop in controllers.export.FmuLaw) applies u_k over [t_k, t_k+1], the Python law's timing; one that steps
 * both in parallel and then exchanges (libcosim's fixed-step algorithm) applies it over [t_k+1, t_k+2], one
 * sample later.  For such an importer the FMU is built with DELAY 1: it predicts the estimate one sample
 * ahead with the torque being applied and outputs the torque of the next sample (controllers/ssp.py).
 * Before the first step the output is u0 + the feedforward of sample 0.
 *
 * Sensors read along the reference (NALONG > 0: the tip accelerometer, controllers.multijoint.MimoLQGLaw with a
 * measurement schedule; the reference is built in): sample k expects the measurement
 *   y_hat = YREF[k] + CK[k] z + DK[k] (uprev − UFP[k])
 * (the sensors linearised about the reference's state and the held feedforward, uprev the deviation torque
 * held while y_k was sampled) instead of y0 + C (xref + z), and predicts with the plant sampled along the
 * reference AK[k], BK[k] and the time-varying Kalman gain MKT[k] (NGAIN rows); w is then that model's
 * reference step (REFW).  Each table stores its rows up to its last change: its last row holds after it,
 * and after the reference (the linearisation at rest at the targets, the filter's last gain).
 *
 * Gain scheduling (NSCHED > 0 design points, controllers/schedule.py): sample k uses the matrices (M, C, K,
 * Ad, Bd) interpolated linearly between the two design points around the path parameter
 * s(t_k) = tau^3 (10 - 15 tau + 6 tau^2), tau = t_k / TMOVE clipped to [0, 1] (the quintic's; 1 after the
 * manoeuvre), as controllers.schedule.ScheduledLQGLaw does.  The schedule is a known function of time: no
 * measured signal enters it, and the estimate is not reset when the matrices change.  With DELAY 1 the
 * torque output at t_k for t_k+1 takes the gain of t_k+1 (controllers.ssp.ScheduledPredictiveLQGLaw).
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
#ifndef NSCHED
#define NSCHED 0
#endif
#ifndef NALONG
#define NALONG 0
#endif

typedef struct {
    fmi2CallbackFunctions cb;
    char *name;
    double in[NIN];
    double z[NX], e[NX], u[NU];
    double ad[NX][NX], bd[NX][NU], cy[NY][NX], mk[NX][NY], kd[NU][NX];   /* the matrices of this sample */
    double uprev[NU];       /* deviation torque held while the measurement of this sample was taken */
    double t;
    long k;                 /* samples taken since the start: the row of the built-in reference */
    enum { INSTANTIATED, INITIALISING, STEPPING, FAILED } state;   /* FMI 2.0 CS state machine (§4.2.4) */
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

/* The reference of sample k: the inputs, plus the built-in table's row k (its last row after its end). */
static void reference(const Ctrl *c, long k, double *xref, double *uff, double *w) {
    memcpy(xref, c->in + NY, NX * sizeof(double));
    memcpy(uff, c->in + NY + NX, NU * sizeof(double));
    memcpy(w, c->in + NY + NX + NU, NX * sizeof(double));
#if NREF > 0
    long r = k < NREF ? k : NREF - 1;
    for (int i = 0; i < NX; i++) { xref[i] += REFX[r][i]; w[i] += REFW[r][i]; }
    for (int i = 0; i < NU; i++) uff[i] += REFU[r][i];
#else
    (void)c; (void)k;
#endif
}

#if NSCHED > 0
/* dst = (1 − lam) a + lam b, element by element (numpy's order of operations) */
static void blend(double *dst, const double *a, const double *b, double lam, int n) {
    for (int i = 0; i < n; i++) dst[i] = (1.0 - lam) * a[i] + lam * b[i];
}
#endif

/* The matrices of sample k: the design's, or the schedule's at the path parameter of t_k. */
static void load(Ctrl *c, long k) {
#if NSCHED > 0
    double tau = (double)k * DT / TMOVE;
    tau = tau < 0.0 ? 0.0 : (tau > 1.0 ? 1.0 : tau);
    double s = pow(tau, 3.0) * (10.0 - 15.0 * tau + 6.0 * (tau * tau));
    int i = 0;
    while (i < NSCHED - 2 && s >= SSIG[i + 1]) i++;
    double lam = (s - SSIG[i]) / (SSIG[i + 1] - SSIG[i]);
    lam = lam < 0.0 ? 0.0 : (lam > 1.0 ? 1.0 : lam);
    blend(&c->ad[0][0], SAD + i * NX * NX, SAD + (i + 1) * NX * NX, lam, NX * NX);
    blend(&c->bd[0][0], SBD + i * NX * NU, SBD + (i + 1) * NX * NU, lam, NX * NU);
    blend(&c->cy[0][0], SCY + i * NY * NX, SCY + (i + 1) * NY * NX, lam, NY * NX);
    blend(&c->mk[0][0], SMK + i * NX * NY, SMK + (i + 1) * NX * NY, lam, NX * NY);
    blend(&c->kd[0][0], SKD + i * NU * NX, SKD + (i + 1) * NU * NX, lam, NU * NX);
#else
    (void)k;
    memcpy(c->ad, AD, sizeof c->ad);
    memcpy(c->bd, BD, sizeof c->bd);
    memcpy(c->cy, CY, sizeof c->cy);
    memcpy(c->mk, MK, sizeof c->mk);
    memcpy(c->kd, KD, sizeof c->kd);
#endif
}

#if NALONG > 0
/* Sample k's model along the reference (its row k, the last row after the table): the Kalman gain and the
 * sampled plant into the instance's matrices, the innovation y − y_hat (header comment). */
static void along(Ctrl *c, long k, double *innov) {
    long r = k < NALONG ? k : NALONG - 1, g = k < NGAIN ? k : NGAIN - 1;
    memcpy(c->ad, AKT[r], sizeof c->ad);
    memcpy(c->bd, BKT[r], sizeof c->bd);
    memcpy(c->mk, MKT[g], sizeof c->mk);
    for (int i = 0; i < NY; i++) {
        double s = c->in[i] - YREF[r][i];
        for (int j = 0; j < NX; j++) s -= CKT[r][i * NX + j] * c->z[j];
        for (int j = 0; j < NU; j++) s -= DKT[r][i * NU + j] * (c->uprev[j] - UFP[r][j]);
        innov[i] = s;
    }
}
#endif

/* u = sat(u0 + uff − K e) */
static void regulate(Ctrl *c, const double *uff, const double *e) {
    for (int i = 0; i < NU; i++) {
        double s = U0[i] + uff[i];
        for (int j = 0; j < NX; j++) s -= c->kd[i][j] * e[j];
        c->u[i] = s < -LIM[i] ? -LIM[i] : (s > LIM[i] ? LIM[i] : s);
    }
}

/* One sample: the estimate e from the inputs, the next prior estimate z and the torque to output.  DELAY 0:
 * the torque of this sample (z predicted with it).  DELAY 1 (for an importer that applies it one sample
 * later): z predicted with the torque being applied now (the output held), the torque of the next sample
 * from z and the next row of the reference. */
static void sample(Ctrl *c) {
    double xref[NX], uff[NU], w[NX], innov[NY], z[NX];
    if (NSCHED > 0 || c->k == 0) load(c, c->k);
    reference(c, c->k, xref, uff, w);
#if NALONG > 0
    along(c, c->k, innov);
#else
    for (int i = 0; i < NY; i++) {
        double s = c->in[i] - Y0[i];
        for (int j = 0; j < NX; j++) s -= c->cy[i][j] * (xref[j] + c->z[j]);
        innov[i] = s;
    }
#endif
    for (int i = 0; i < NX; i++) {
        double s = c->z[i];
        for (int j = 0; j < NY; j++) s += c->mk[i][j] * innov[j];
        c->e[i] = s;
    }
#if DELAY == 0
    regulate(c, uff, c->e);
#endif
    for (int i = 0; i < NX; i++) {
        double s = -w[i];
        for (int j = 0; j < NX; j++) s += c->ad[i][j] * c->e[j];
        for (int j = 0; j < NU; j++) s += c->bd[i][j] * (c->u[j] - U0[j] - uff[j]);
        z[i] = s;
    }
    memcpy(c->z, z, sizeof z);
    for (int i = 0; i < NU; i++) c->uprev[i] = c->u[i] - U0[i];   /* held while the next sample is measured */
#if DELAY == 1
    reference(c, c->k + 1, xref, uff, w);
    if (NSCHED > 0) load(c, c->k + 1);      /* the next sample's torque with the next sample's gain */
    regulate(c, uff, c->z);
#endif
}

static void reset(Ctrl *c) {
    memset(c->in, 0, sizeof c->in);
    for (int i = 0; i < NY; i++) c->in[i] = Y0[i];
    memset(c->z, 0, sizeof c->z);
    memset(c->uprev, 0, sizeof c->uprev);  /* DELAY 0: u0 held while sample 0 is measured */
    double xref[NX], uff[NU], w[NX];
    c->k = 0;
    load(c, 0);
    reference(c, 0, xref, uff, w);
    regulate(c, uff, c->z);             /* u0 + the feedforward of sample 0 */
#if DELAY == 1
    /* a Jacobi importer connects that output to the plant during initialisation: held at t_0 */
    for (int i = 0; i < NU; i++) c->uprev[i] = c->u[i] - U0[i];
#endif
    c->t = 0.0;
    c->state = INSTANTIATED;
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

/* A call the state machine forbids: fmi2Error, and only fmi2Reset/fmi2FreeInstance after it (§2.1.3). */
static fmi2Status refuse(Ctrl *c, const char *call) {
    say(c, fmi2Error, "%s: not allowed in this state of the instance", call);
    c->state = FAILED;
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Ctrl *c = comp;
    if (!c) return fmi2Error;
    if (c->state != INSTANTIATED) return refuse(c, "fmi2EnterInitializationMode");
    c->state = INITIALISING;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Ctrl *c = comp;
    if (!c) return fmi2Error;
    if (c->state != INITIALISING) return refuse(c, "fmi2ExitInitializationMode");
    c->state = STEPPING;
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
    if (c->state != STEPPING) return refuse(c, "fmi2DoStep");
    if (!(fabs(h - DT) <= 1e-9 * DT) || !isfinite(t)) {      /* a NaN step fails the test too */
        say(c, fmi2Error, "fmi2DoStep: the controller samples at %.17g s; got a step of %.17g s at t = %.17g",
            DT, h, t);
        return fmi2Error;
    }
    sample(c);
    c->k++;
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

/* Model Exchange: not this FMU's interface; exported so that an importer probing them gets fmi2Error */
FMI2_Export fmi2Status fmi2EnterEventMode(fmi2Component comp) { REFUSE("fmi2EnterEventMode"); }
FMI2_Export fmi2Status fmi2NewDiscreteStates(fmi2Component comp, fmi2EventInfo *e) {
    (void)e; REFUSE("fmi2NewDiscreteStates");
}
FMI2_Export fmi2Status fmi2EnterContinuousTimeMode(fmi2Component comp) { REFUSE("fmi2EnterContinuousTimeMode"); }
FMI2_Export fmi2Status fmi2CompletedIntegratorStep(fmi2Component comp, fmi2Boolean noSet, fmi2Boolean *enter,
                                                   fmi2Boolean *term) {
    (void)noSet; (void)enter; (void)term; REFUSE("fmi2CompletedIntegratorStep");
}
FMI2_Export fmi2Status fmi2SetTime(fmi2Component comp, fmi2Real t) { (void)t; REFUSE("fmi2SetTime"); }
FMI2_Export fmi2Status fmi2SetContinuousStates(fmi2Component comp, const fmi2Real x[], size_t n) {
    (void)x; (void)n; REFUSE("fmi2SetContinuousStates");
}
FMI2_Export fmi2Status fmi2GetDerivatives(fmi2Component comp, fmi2Real dx[], size_t n) {
    (void)dx; (void)n; REFUSE("fmi2GetDerivatives");
}
FMI2_Export fmi2Status fmi2GetEventIndicators(fmi2Component comp, fmi2Real ind[], size_t n) {
    (void)ind; (void)n; REFUSE("fmi2GetEventIndicators");
}
FMI2_Export fmi2Status fmi2GetContinuousStates(fmi2Component comp, fmi2Real x[], size_t n) {
    (void)x; (void)n; REFUSE("fmi2GetContinuousStates");
}
FMI2_Export fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component comp, fmi2Real x[], size_t n) {
    (void)x; (void)n; REFUSE("fmi2GetNominalsOfContinuousStates");
}
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
