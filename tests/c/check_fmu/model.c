/* A small FMI 2.0 model for the tests of `flexlink check` (tests/check_fmus.py builds it into FMUs with a
 * hand-written modelDescription.xml).  One skeleton for every fixture:
 *
 *   oscillator   x' = v, v' = -k x - c v + u (c = 0.5 * mode), outputs x and y = 2 x + u;
 *   NX=0         no continuous states (x and v stay at their start values);
 *   STAIR        an Integer `counter` that steps by one at every multiple of 0.2 s (time events in ME);
 *   typed        Integer n -> m = 2 n, Boolean b -> nb = !b, Enumeration mode in 1..3, String label;
 *   BALL         a bouncing ball: height x, x' = v, v' = -G + u, one event indicator z = x; when the ball
 *                reaches the floor moving down (x <= 0, v < 0) it bounces, v -> -E v (in ME at the state
 *                event, in fmi2NewDiscreteStates; in CS after the Euler step that crosses the floor).  From
 *                BALL_HEIGHT (1 m).  An importer that completes an integrator step with the ball below the
 *                floor (by more than FLOOR_TOLERANCE) has stepped over the state event, a calling sequence
 *                FMI 2.0 does not support (§3.1: the integration halts at the zero crossing); the ball says
 *                so with fmi2Error rather than go on from a state outside its model.
 *
 * Co-Simulation integrates with fixed explicit Euler steps of FIXED_STEP (as the Reference FMUs do).
 * Each DEFECT_* macro plants one defect that the harness claims to find; without them the model follows
 * the FMI 2.0 state machine and refuses what the standard forbids with fmi2Error.  NO_OPTIONAL makes the
 * FMU-state and directional-derivative functions return fmi2Error (legal when the flags say false);
 * FIXED_COMM_STEP refuses communication steps other than the default experiment's 0.01 s (legal when
 * canHandleVariableCommunicationStepSize is false).
 */
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fmi2Functions.h"

#ifndef NX
#define NX 2
#endif
#ifndef GUID
#define GUID "{check-fmu}"
#endif
#define FIXED_STEP 1e-3
#define G 9.81
#define E 0.7
#ifdef BALL
#define NZ 1
#ifndef BALL_HEIGHT
#define BALL_HEIGHT 1.0
#endif
#define FLOOR_TOLERANCE 1e-6
#else
#define NZ 0
#endif
#ifndef STEP_HANG
#define STEP_HANG 3
#endif
#define STAIR_PERIOD 0.2

enum { R_X, R_V, R_DX, R_DV, R_U, R_K, R_Y, R_TIME, NR };
enum { I_N, I_M, I_MODE, I_COUNTER, NI };
enum { B_B, B_NB, NB };

typedef enum { INSTANTIATED = 1, INIT = 2, STEP = 4, EVENT = 8, CONT = 16, TERMINATED = 32, ERROR = 64 } Mode;

typedef struct {
    double r[NR];
    int i[NI];
    int b[NB];
    char label[64];
    int steps;              /* fmi2DoStep calls since instantiation or reset (DEFECT_STEP_HANG) */
} Data;

typedef struct {
    Data d;
    Mode mode;
    int cs;
    fmi2CallbackFunctions cb;
    fmi2String name;
} Inst;

static void compute(Data *d) {
    double c = 0.5 * d->i[I_MODE];
    d->r[R_DX] = NX ? d->r[R_V] : 0.0;
#ifdef BALL
    (void)c;
    d->r[R_DV] = -G + d->r[R_U];
#else
    d->r[R_DV] = NX ? -d->r[R_K] * d->r[R_X] - c * d->r[R_V] + d->r[R_U] : 0.0;
#endif
    d->r[R_Y] = 2.0 * d->r[R_X] + d->r[R_U];
    d->i[I_M] = 2 * d->i[I_N];
    d->b[B_NB] = !d->b[B_B];
}

/* the ball's bounce: returns whether the states changed */
static int bounce(Data *d) {
#ifdef BALL
    if (d->r[R_X] <= 0.0 && d->r[R_V] < 0.0) {
        d->r[R_X] = 0.0;
        d->r[R_V] = -E * d->r[R_V];
        compute(d);
        return 1;
    }
#else
    (void)d;
#endif
    return 0;
}

/* the stair's counter changes at events only (ME: fmi2NewDiscreteStates; CS: within fmi2DoStep) */
static void update_counter(Data *d) {
#ifdef STAIR
    d->i[I_COUNTER] = (int)floor(d->r[R_TIME] / STAIR_PERIOD + 1e-9);
#else
    (void)d;
#endif
}

static fmi2Status fail(Inst *s, const char *msg) {
    if (s->cb.logger) s->cb.logger(s->cb.componentEnvironment, s->name, fmi2Error, "logError", msg);
    s->mode = ERROR;
    return fmi2Error;
}

#define IN(s, allowed) do { if (!(s) || !((s)->mode & (allowed))) return (s) ? fail(s, "illegal call") : fmi2Error; } while (0)
#ifdef NO_OPTIONAL
#define OPTIONAL(s) return fail(s, "not supported")
#else
#define OPTIONAL(s) (void)0
#endif
#define ANY (INSTANTIATED | INIT | STEP | EVENT | CONT | TERMINATED)
#define RUN (STEP | EVENT | CONT)

static void defaults(Data *d) {
    memset(d, 0, sizeof *d);
#ifdef BALL
    d->r[R_X] = BALL_HEIGHT;
#else
    d->r[R_X] = 1.0;
#endif
    d->r[R_K] = 4.0;
    d->i[I_N] = 1;
    d->i[I_MODE] = 1;
    strcpy(d->label, "check");
    compute(d);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    (void)on; (void)n; (void)cat; return c ? fmi2OK : fmi2Error;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    (void)res; (void)visible; (void)logging;
#ifndef DEFECT_ANY_GUID
    if (!guid || strcmp(guid, GUID) != 0) return NULL;
#else
    (void)guid;
#endif
    Inst *s = calloc(1, sizeof *s);
    if (!s) return NULL;
    s->cs = type == fmi2CoSimulation;
    if (cb) s->cb = *cb;
    s->name = name;
    s->mode = INSTANTIATED;
    defaults(&s->d);
    return s;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0, fmi2Boolean stopDef,
                               fmi2Real stop) {
    Inst *s = c; (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    IN(s, INSTANTIATED);
    s->d.r[R_TIME] = t0;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Inst *s = c; IN(s, INSTANTIATED); s->mode = INIT; return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Inst *s = c; IN(s, INIT); compute(&s->d); update_counter(&s->d); s->mode = s->cs ? STEP : EVENT; return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { Inst *s = c; IN(s, RUN); s->mode = TERMINATED; return fmi2OK; }

fmi2Status fmi2Reset(fmi2Component c) {
    Inst *s = c; if (!s) return fmi2Error; defaults(&s->d); s->mode = INSTANTIATED; return fmi2OK;
}

/* ---------------------------------------------------------------- variables */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Inst *s = c; IN(s, ANY);
    if (n && (!vr || !v)) return fail(s, "null array");
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NR) {
#ifdef DEFECT_CRASH
            raise(SIGSEGV);
#endif
            return fail(s, "unknown value reference");
        }
        v[k] = s->d.r[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Inst *s = c; IN(s, INSTANTIATED | INIT | STEP | EVENT | CONT);
    for (size_t k = 0; k < n; k++) {
        unsigned r = vr[k];
        if (r == R_U) {
            if (!isfinite(v[k])) return fail(s, "input not finite");
        } else if (r == R_K) {
            if (!(v[k] >= 0.1 && v[k] <= 100.0)) return fail(s, "k outside [0.1, 100]");
        } else if (!((r == R_X || r == R_V) && (s->mode & (INSTANTIATED | INIT)))) {
            return fail(s, "value reference not settable here");
        }
        s->d.r[r] = v[k];
    }
    compute(&s->d);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    Inst *s = c; IN(s, ANY);
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NI) return fail(s, "unknown value reference");
        v[k] = s->d.i[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    Inst *s = c; IN(s, INSTANTIATED | INIT | STEP | EVENT);
    for (size_t k = 0; k < n; k++) {
        if (vr[k] == I_N && v[k] >= 0 && v[k] <= 10) s->d.i[I_N] = v[k];
        else if (vr[k] == I_MODE && v[k] >= 1 && v[k] <= 3) s->d.i[I_MODE] = v[k];
        else return fail(s, "integer not settable or out of range");
    }
    compute(&s->d);
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    Inst *s = c; IN(s, ANY);
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NB) return fail(s, "unknown value reference");
        v[k] = s->d.b[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    Inst *s = c; IN(s, INSTANTIATED | INIT | STEP | EVENT);
    for (size_t k = 0; k < n; k++) {
        if (vr[k] != B_B) return fail(s, "boolean not settable");
        s->d.b[B_B] = v[k] != fmi2False;
    }
    compute(&s->d);
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    Inst *s = c; IN(s, ANY);
    for (size_t k = 0; k < n; k++) {
        if (vr[k] != 0) return fail(s, "unknown value reference");
        v[k] = s->d.label;
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    Inst *s = c; IN(s, INSTANTIATED | INIT);
    for (size_t k = 0; k < n; k++) {
        if (vr[k] != 0 || !v[k] || strlen(v[k]) >= sizeof s->d.label) return fail(s, "bad string");
        strcpy(s->d.label, v[k]);
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------- FMU state */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *st) {
    Inst *s = c; IN(s, ANY); OPTIONAL(s);
    if (!st) return fail(s, "null state");
    if (!*st) *st = malloc(sizeof(Inst));
    if (!*st) return fail(s, "out of memory");
    memcpy(*st, s, sizeof(Inst));
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate st) {
    Inst *s = c; IN(s, ANY); OPTIONAL(s);
    if (!st) return fail(s, "null state");
    const Inst *from = st;
#ifdef DEFECT_STATE_RESTORE
    s->d.r[R_TIME] = from->d.r[R_TIME];          /* the time only: the states keep their values */
#else
    s->d = from->d;
    s->mode = from->mode;
#endif
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st) {
    Inst *s = c; IN(s, ANY);
    if (st) { free(*st); *st = NULL; }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t *size) {
    Inst *s = c; IN(s, ANY); OPTIONAL(s); (void)st; *size = sizeof(Inst); return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte bytes[], size_t size) {
    Inst *s = c; IN(s, ANY); OPTIONAL(s);
    if (!st || size != sizeof(Inst)) return fail(s, "bad size");
    memcpy(bytes, st, sizeof(Inst));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *st) {
    Inst *s = c; IN(s, ANY); OPTIONAL(s);
    if (size != sizeof(Inst)) return fail(s, "bad size");
    Inst tmp;
    memcpy(&tmp, bytes, sizeof tmp);
    if (!(tmp.mode & ANY) || tmp.cs != s->cs) return fail(s, "not a serialized state of this model");
    if (!*st) *st = malloc(sizeof(Inst));
    memcpy(*st, &tmp, sizeof tmp);
    return fmi2OK;
}

/* ---------------------------------------------------------------- directional derivatives */

static double partial(const Data *d, unsigned unknown, unsigned known) {
    double c = 0.5 * d->i[I_MODE], k = d->r[R_K];
#ifdef BALL
    c = 0.0;
    k = 0.0;
#endif
#ifdef DEFECT_WRONG_DERIVATIVE
    k = -k;
#endif
    if (unknown == R_DX && known == R_V && NX) return 1.0;
    if (unknown == R_DV && known == R_X && NX) return -k;
    if (unknown == R_DV && known == R_V && NX) return -c;
    if (unknown == R_DV && known == R_U && NX) return 1.0;
    if (unknown == R_Y && known == R_X) return 2.0;
    if (unknown == R_Y && known == R_U) return 1.0;
    if (unknown == R_X && known == R_X) return 1.0;
    return 0.0;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference kn[], size_t nk, const fmi2Real dv[], fmi2Real du[]) {
    Inst *s = c; IN(s, INIT | RUN); OPTIONAL(s);
    for (size_t j = 0; j < nk; j++) {
        int ok = kn[j] == R_U || (!s->cs && NX && (kn[j] == R_X || kn[j] == R_V));
        if (!ok || !isfinite(dv[j])) return fail(s, "bad known");
    }
    for (size_t i = 0; i < nu; i++) {
        if (u[i] >= NR) return fail(s, "bad unknown");
        du[i] = 0.0;
        for (size_t j = 0; j < nk; j++) du[i] += partial(&s->d, u[i], kn[j]) * dv[j];
    }
    return fmi2OK;
}

#ifndef NO_CS_FUNCTIONS   /* an ME-only FMU need not export the Co-Simulation functions (FMI 2.0 §2.3) */
/* ---------------------------------------------------------------- Co-Simulation */

static void euler(Data *d, double h) {
    double dx = d->r[R_DX], dv = d->r[R_DV];
    d->r[R_X] += h * dx;
    d->r[R_V] += h * dv;
    d->r[R_TIME] += h;
    compute(d);
    bounce(d);
    update_counter(d);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Inst *s = c; (void)noSetPrior;
#ifndef DEFECT_ACCEPTS_ILLEGAL
    IN(s, STEP);
    if (!s->cs) return fail(s, "not a Co-Simulation instance");
#else
    if (!s) return fmi2Error;
#endif
    double end = t + h;
#ifdef DEFECT_STEP_HANG
    /* a legal call that never returns: the instance's STEP_HANG-th communication step sleeps for ever */
    if (++s->d.steps == STEP_HANG) for (;;) sleep(1);
#endif
#ifdef DEFECT_NAN_HANG
    /* a NaN step passes both tests and the loop never ends (as in five of the six Reference FMUs) */
    if (h <= 0.0) return fail(s, "step size not positive");
    if (fabs(t - s->d.r[R_TIME]) > 1e-9 * fmax(1.0, fabs(t))) return fail(s, "wrong communication point");
    while (!(s->d.r[R_TIME] >= end - 1e-12)) euler(&s->d, fmin(FIXED_STEP, end - s->d.r[R_TIME]));
#else
#ifdef FIXED_COMM_STEP
    if (fabs(h - 0.01) > 1e-12) return fail(s, "this FMU steps by 0.01 s only");
#endif
    if (!(h > 0.0) || !isfinite(h)) return fail(s, "step size not positive and finite");
    if (fabs(t - s->d.r[R_TIME]) > 1e-9 * fmax(1.0, fabs(t))) return fail(s, "wrong communication point");
    while (s->d.r[R_TIME] < end - 1e-12) euler(&s->d, fmin(FIXED_STEP, end - s->d.r[R_TIME]));
#endif
    s->d.r[R_TIME] = end;
    compute(&s->d);
    update_counter(&s->d);
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { Inst *s = c; IN(s, STEP); return fmi2Error; }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) {
    Inst *s = c; (void)vr; (void)n; (void)order; (void)v; IN(s, ANY); return fail(s, "not supported");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) {
    Inst *s = c; (void)vr; (void)n; (void)order; (void)v; IN(s, ANY); return fail(s, "not supported");
}
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) {
    Inst *s = c; (void)k; (void)v; IN(s, ANY); return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    Inst *s = c; IN(s, ANY);
    if (k == fmi2LastSuccessfulTime) { *v = s->d.r[R_TIME]; return fmi2OK; }
    return fmi2Discard;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) {
    Inst *s = c; (void)k; (void)v; IN(s, ANY); return fmi2Discard;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) {
    Inst *s = c; (void)k; (void)v; IN(s, ANY); return fmi2Discard;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) {
    Inst *s = c; (void)k; (void)v; IN(s, ANY); return fmi2Discard;
}

#endif

#ifndef NO_ME_FUNCTIONS   /* a CS-only FMU need not export the Model Exchange functions (FMI 2.0 §2.3) */
/* ---------------------------------------------------------------- Model Exchange */

#define ME_ONLY(s) do { if ((s)->cs) return fail(s, "not a Model Exchange instance"); } while (0)

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    Inst *s = c; IN(s, EVENT | CONT); ME_ONLY(s); s->mode = EVENT; return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) {
    Inst *s = c; IN(s, EVENT); ME_ONLY(s);
    compute(&s->d);
    update_counter(&s->d);
    memset(e, 0, sizeof *e);
    e->valuesOfContinuousStatesChanged = bounce(&s->d) ? fmi2True : fmi2False;
#ifdef STAIR
    e->nextEventTimeDefined = fmi2True;
    e->nextEventTime = (s->d.i[I_COUNTER] + 1) * STAIR_PERIOD;
#endif
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    Inst *s = c; IN(s, EVENT); ME_ONLY(s); s->mode = CONT; return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetPrior, fmi2Boolean *enter,
                                       fmi2Boolean *terminate) {
    Inst *s = c; (void)noSetPrior; IN(s, CONT); ME_ONLY(s);
    *enter = fmi2False; *terminate = fmi2False;
#ifdef BALL
    if (s->d.r[R_X] < -FLOOR_TOLERANCE) return fail(s, "the ball is below the floor: a state event was stepped over");
#endif
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) {
    Inst *s = c; IN(s, EVENT | CONT); ME_ONLY(s);
    if (!isfinite(t)) return fail(s, "time not finite");
    s->d.r[R_TIME] = t;
    compute(&s->d);
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    Inst *s = c; IN(s, CONT); ME_ONLY(s);
    if (nx != NX) return fail(s, "wrong nx");
    for (size_t k = 0; k < nx; k++) if (!isfinite(x[k])) return fail(s, "state not finite");
    for (size_t k = 0; k < nx; k++) s->d.r[R_X + k] = x[k];
    compute(&s->d);
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t nx) {
    Inst *s = c; IN(s, INIT | RUN | TERMINATED); ME_ONLY(s);
    if (nx != NX) return fail(s, "wrong nx");
    for (size_t k = 0; k < nx; k++) dx[k] = s->d.r[R_DX + k];
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t nz) {
    Inst *s = c; IN(s, INIT | RUN | TERMINATED); ME_ONLY(s);
    if (nz != NZ) return fail(s, "wrong nz");
    if (NZ) z[0] = s->d.r[R_X];
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    Inst *s = c; IN(s, INIT | RUN | TERMINATED); ME_ONLY(s);
    if (nx != NX) return fail(s, "wrong nx");
    for (size_t k = 0; k < nx; k++) x[k] = s->d.r[R_X + k];
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    Inst *s = c; IN(s, ANY); ME_ONLY(s);
    if (nx != NX) return fail(s, "wrong nx");
    for (size_t k = 0; k < nx; k++) x[k] = 1.0;
    return fmi2OK;
}
#endif
