/* A small FMI 2.0 Co-Simulation host that loads an FMU library and drives the generic C half through
 * everything a host may do, right and wrong (tests/test_fmu_glue.py runs it plainly, under valgrind
 * and against an -fsanitize=address,undefined build).
 *
 * usage: host twodof|nonlinear LIBRARY [-v]
 *   twodof:    tests/c/twodof (the thesis's 2-DOF system): prints "TRAJ t q1 q2 v1 v2" at every
 *              communication point of a run with step 0.5 to t = 15, then checks instances side by side,
 *              FMU states, serialization, reset, and the catalogue of bad calls;
 *   nonlinear: tests/c/nonlinear: static equilibrium, consistent acceleration, kinematic laws,
 *              sub-step retries and fmi2Discard with the state restored.
 * Exits 0 when every check passed, 1 otherwise (each failure is printed on stderr). */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

/* ------------------------------------------------------------- the 44 functions */

#define FMI2_FUNCTIONS(X)                                                                                  \
    X(GetTypesPlatform) X(GetVersion) X(SetDebugLogging) X(Instantiate) X(FreeInstance) X(SetupExperiment) \
    X(EnterInitializationMode) X(ExitInitializationMode) X(Terminate) X(Reset) X(GetReal) X(GetInteger)    \
    X(GetBoolean) X(GetString) X(SetReal) X(SetInteger) X(SetBoolean) X(SetString) X(GetFMUstate)          \
    X(SetFMUstate) X(FreeFMUstate) X(SerializedFMUstateSize) X(SerializeFMUstate) X(DeSerializeFMUstate)   \
    X(GetDirectionalDerivative) X(EnterEventMode) X(NewDiscreteStates) X(EnterContinuousTimeMode)          \
    X(CompletedIntegratorStep) X(SetTime) X(SetContinuousStates) X(GetDerivatives) X(GetEventIndicators)   \
    X(GetContinuousStates) X(GetNominalsOfContinuousStates) X(SetRealInputDerivatives)                     \
    X(GetRealOutputDerivatives) X(DoStep) X(CancelStep) X(GetStatus) X(GetRealStatus) X(GetIntegerStatus)  \
    X(GetBooleanStatus) X(GetStringStatus)

#define DECLARE(name) fmi2##name##TYPE *name;
static struct { FMI2_FUNCTIONS(DECLARE) } F;

/* ---------------------------------------------------------------- bookkeeping */

static int CHECKS, FAILURES, VERBOSE;

#define CHECK(condition, ...)                                               \
    do {                                                                    \
        CHECKS++;                                                           \
        if (!(condition)) {                                                 \
            FAILURES++;                                                     \
            fprintf(stderr, "FAIL %s:%d: ", __FILE__, __LINE__);            \
            fprintf(stderr, __VA_ARGS__);                                   \
            fputc('\n', stderr);                                            \
        }                                                                   \
    } while (0)

/* what the FMU logged */
static struct {
    int count, ok_count, retries;
    fmi2Status status;
    char category[64], message[2048];
} LOG;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    va_list ap;
    (void)env;
    va_start(ap, message);
    vsnprintf(LOG.message, sizeof(LOG.message), message, ap);
    va_end(ap);
    snprintf(LOG.category, sizeof(LOG.category), "%s", category != NULL ? category : "(NULL)");
    LOG.count++;
    LOG.status = status;
    if (status == fmi2OK) LOG.ok_count++;
    if (strstr(LOG.message, "retrying as") != NULL) LOG.retries++;
    if (VERBOSE) fprintf(stderr, "  [%s] %s: %s\n", LOG.category, name, LOG.message);
}

static long ALLOCATIONS;  /* live blocks of the FMU: 0 at the end */

static void *allocate(size_t n, size_t size) {
    void *p = calloc(n, size);
    if (p != NULL) ALLOCATIONS++;
    return p;
}

static void release(void *p) {
    if (p != NULL) ALLOCATIONS--;
    free(p);
}

static const fmi2CallbackFunctions CALLBACKS = {logger, allocate, release, NULL, NULL};

/* status expected, a message logged for anything but fmi2OK, and it contains `text` */
#define EXPECT(call, expected, text)                                                                   \
    do {                                                                                               \
        const int before_ = LOG.count;                                                                 \
        const fmi2Status status_ = (call);                                                             \
        CHECK(status_ == (expected), "%s returned %d, expected %d (last log: %s)", #call, (int)status_, \
              (int)(expected), LOG.message);                                                           \
        if ((expected) != fmi2OK) {                                                                    \
            CHECK(LOG.count > before_, "%s: no message logged", #call);                                \
            CHECK(LOG.count > before_ && LOG.status == (expected), "%s: logged with status %d", #call, \
                  (int)LOG.status);                                                                    \
            CHECK((text) == NULL || strstr(LOG.message, (text) != NULL ? (text) : "") != NULL,         \
                  "%s: logged \"%s\", expected it to mention \"%s\"", #call, LOG.message,              \
                  (text) != NULL ? (text) : "");                                                       \
        }                                                                                              \
    } while (0)

#define OK(call) EXPECT(call, fmi2OK, NULL)
#define ERROR(call, text) EXPECT(call, fmi2Error, text)

static const char *GUID;

static fmi2Component instantiate(const char *name) {
    fmi2Component c = F.Instantiate(name, fmi2CoSimulation, GUID, "", &CALLBACKS, fmi2False, fmi2False);
    CHECK(c != NULL, "fmi2Instantiate(%s) returned NULL (last log: %s)", name, LOG.message);
    return c;
}

static void initialize(fmi2Component c, double start) {
    OK(F.SetupExperiment(c, fmi2False, 0.0, start, fmi2False, 0.0));
    OK(F.EnterInitializationMode(c));
    OK(F.ExitInitializationMode(c));
}

static double get(fmi2Component c, fmi2ValueReference vr) {
    double x = NAN;
    OK(F.GetReal(c, &vr, 1, &x));
    return x;
}

static void set(fmi2Component c, fmi2ValueReference vr, double x) {
    OK(F.SetReal(c, &vr, 1, &x));
}

static int same(const double *a, const double *b, int n) {  /* bit for bit */
    return memcmp(a, b, (size_t)n * sizeof(double)) == 0;
}

/* ============================================================== the 2-DOF model */

enum { F1, F2, Q1, Q2, V1, V2, STIFFNESS, Q1_START, Q2_START, V1_START, V2_START, STEP, THETA1, THETA2,
       TOLERANCE, ENERGY, N_TWODOF_VARS };
#define N_POINTS 31                       /* t = 0, 0.5, ..., 15 */
static const fmi2ValueReference QV[4] = {Q1, Q2, V1, V2};

typedef double Trajectory[N_POINTS][4];

/* Steps of h from the FMU's time, recording q1 q2 v1 v2 after each into out[first + i]. */
static void run(fmi2Component c, double t0, double h, int steps, Trajectory out, int first) {
    double t = t0;
    for (int i = 0; i < steps; i++) {
        OK(F.DoStep(c, t, h, fmi2True));
        t += h;
        OK(F.GetReal(c, QV, 4, out[first + i]));
    }
}

static void reference_run(Trajectory a) {
    fmi2Component c = instantiate("reference");
    double t = 0.0;
    initialize(c, 0.0);
    OK(F.GetReal(c, QV, 4, a[0]));
    run(c, 0.0, 0.5, N_POINTS - 1, a, 1);
    for (int i = 1; i < N_POINTS; i++) {
        t = 0.5 * i;
        printf("TRAJ %.17g %.17g %.17g %.17g %.17g\n", t, a[i][0], a[i][1], a[i][2], a[i][3]);
    }
    {
        double last = NAN;
        fmi2Boolean terminated = fmi2True;
        OK(F.GetRealStatus(c, fmi2LastSuccessfulTime, &last));
        CHECK(last == 15.0, "last successful time %.17g, expected 15", last);
        OK(F.GetBooleanStatus(c, fmi2Terminated, &terminated));
        CHECK(terminated == fmi2False, "fmi2Terminated status is true");
    }
    OK(F.Terminate(c));
    F.FreeInstance(c);
}

static void side_by_side(Trajectory a) {
    static Trajectory b, c2, alone;
    fmi2Component d = instantiate("stiff alone"), x = instantiate("x"), y = instantiate("y");
    set(d, STIFFNESS, 2.0);
    initialize(d, 0.0);
    run(d, 0.0, 0.5, N_POINTS - 1, alone, 1);
    F.FreeInstance(d);

    set(y, STIFFNESS, 2.0);                          /* y differs from x: shared state would show */
    initialize(x, 0.0);
    initialize(y, 0.0);
    for (int i = 1; i < N_POINTS; i++) {
        run(x, 0.5 * (i - 1), 0.5, 1, b, i);
        run(y, 0.5 * (i - 1), 0.5, 1, c2, i);
    }
    CHECK(same(b[1], a[1], 4 * (N_POINTS - 1)), "side by side: the first differs from alone");
    CHECK(same(c2[1], alone[1], 4 * (N_POINTS - 1)), "side by side: the second differs from alone");
    F.FreeInstance(x);
    F.FreeInstance(y);
}

static void fmu_states(Trajectory a) {
    static Trajectory r1, r2, r3, r4;
    fmi2Component c = instantiate("states"), other = instantiate("other");
    fmi2FMUstate s = NULL, s2 = NULL, s3 = NULL, again;
    size_t size = 0;
    fmi2Byte *buffer, *bad;
    double now[4];

    initialize(c, 0.0);
    run(c, 0.0, 0.5, 10, r1, 1);                     /* to t = 5 */
    OK(F.GetFMUstate(c, &s));
    run(c, 5.0, 0.5, 10, r1, 11);
    OK(F.SetFMUstate(c, s));
    OK(F.GetReal(c, QV, 4, now));
    CHECK(same(now, a[10], 4), "after fmi2SetFMUstate the outputs differ from t = 5");
    run(c, 5.0, 0.5, 10, r2, 11);
    CHECK(same(r1[11], r2[11], 40) && same(r2[11], a[11], 40), "get state, step, set state, step: differ");

    again = s;                                       /* a state handed back is reused */
    OK(F.GetFMUstate(c, &again));
    CHECK(again == s, "fmi2GetFMUstate did not reuse the state it was given");
    OK(F.SetFMUstate(c, s));                         /* (s now holds t = 10) */
    run(c, 10.0, 0.5, 10, r3, 21);
    CHECK(same(r3[21], a[21], 40), "reused state: not bit-equal");

    /* serialization, into this instance and into another one */
    OK(F.SerializedFMUstateSize(c, s, &size));
    CHECK(size > 0, "serialized size 0");
    buffer = malloc(size);
    bad = malloc(size);
    OK(F.SerializeFMUstate(c, s, buffer, size));
    OK(F.DeSerializeFMUstate(c, buffer, size, &s2));
    OK(F.SetFMUstate(c, s2));
    run(c, 10.0, 0.5, 10, r3, 21);
    CHECK(same(r3[21], a[21], 40), "serialize, deserialize, set: not bit-equal");
    OK(F.DeSerializeFMUstate(other, buffer, size, &s3));   /* other is only instantiated */
    OK(F.SetFMUstate(other, s3));
    run(other, 10.0, 0.5, 10, r4, 21);
    CHECK(same(r4[21], a[21], 40), "a state moved to another instance: not bit-equal");

    /* corrupted buffers are refused, and the instance comes back with fmi2SetFMUstate */
    {
        const size_t where[] = {0, 10, size / 2, size - 1};
        const char *why[] = {"not a serialized", "another FMU", "corrupted", "corrupted"};
        for (int k = 0; k < 4; k++) {
            fmi2FMUstate s4 = NULL;
            memcpy(bad, buffer, size);
            bad[where[k]] ^= 0x5a;
            ERROR(F.DeSerializeFMUstate(c, bad, size, &s4), why[k]);
            CHECK(s4 == NULL, "a refused state was returned");
            ERROR(F.DoStep(c, 10.0, 0.5, fmi2True), "not allowed in state error");
            OK(F.SetFMUstate(c, s));
        }
        ERROR(F.DeSerializeFMUstate(c, buffer, size - 1, &s3), "bytes");
        OK(F.SetFMUstate(c, s));
        ERROR(F.SerializeFMUstate(c, s, bad, size - 1), "needed");
        OK(F.SetFMUstate(c, s));
        ERROR(F.SetFMUstate(c, NULL), "not a state");
        OK(F.SetFMUstate(c, s));
    }
    run(c, 10.0, 0.5, 10, r3, 21);
    CHECK(same(r3[21], a[21], 40), "after refused states: not bit-equal");

    /* reset, then run again */
    OK(F.Reset(c));
    initialize(c, 0.0);
    run(c, 0.0, 0.5, N_POINTS - 1, r3, 1);
    CHECK(same(r3[1], a[1], 4 * (N_POINTS - 1)), "reset and rerun: not bit-equal");

    OK(F.FreeFMUstate(c, &s));
    CHECK(s == NULL, "fmi2FreeFMUstate did not clear the pointer");
    OK(F.FreeFMUstate(c, &s));                       /* freeing NULL is fine */
    OK(F.FreeFMUstate(c, &s2));
    OK(F.FreeFMUstate(other, &s3));
    free(buffer);
    free(bad);
    F.FreeInstance(c);
    F.FreeInstance(other);
}

static void communication_steps(Trajectory a) {
    static Trajectory r;
    fmi2Component c = instantiate("steps");
    double t = NAN, x[4], y[4];
    initialize(c, 0.0);
    for (int i = 1; i <= 15; i++) run(c, 1.0 * (i - 1), 1.0, 1, r, 2 * i);   /* 2 internal steps each */
    for (int i = 1; i <= 15; i++) CHECK(same(r[2 * i], a[2 * i], 4), "1.0 and 2 x 0.5 differ at t = %d", i);
    OK(F.Reset(c));
    initialize(c, 0.0);
    OK(F.DoStep(c, 0.0, 0.25, fmi2True));            /* shortened internal steps, variable comm. steps */
    OK(F.DoStep(c, 0.25, 1.25, fmi2True));
    OK(F.GetRealStatus(c, fmi2LastSuccessfulTime, &t));
    CHECK(t == 1.5, "time %.17g after 0.25 + 1.25", t);
    F.FreeInstance(c);

    /* a remainder below 1e-9 step is absorbed: step 0.1 over 0.3 is three steps, landing on 0.3 */
    c = instantiate("remainder");
    set(c, STEP, 0.1);
    initialize(c, 0.0);
    OK(F.DoStep(c, 0.0, 0.3, fmi2True));
    OK(F.GetRealStatus(c, fmi2LastSuccessfulTime, &t));
    CHECK(t == 0.3, "time %.17g, expected 0.3", t);
    OK(F.GetReal(c, QV, 4, x));
    OK(F.Reset(c));
    set(c, STEP, 0.1);
    initialize(c, 0.0);
    OK(F.DoStep(c, 0.0, 0.1, fmi2True));
    OK(F.DoStep(c, 0.1, 0.1, fmi2True));
    OK(F.DoStep(c, 0.2, 0.1, fmi2True));
    OK(F.GetReal(c, QV, 4, y));
    for (int i = 0; i < 4; i++) CHECK(fabs(x[i] - y[i]) < 1e-14, "3 x 0.1 in one doStep and in three differ");
    F.FreeInstance(c);
}

/* A parameter changed in step mode: the cached step matrix must be rebuilt. */
static void tunable_parameter(void) {
    static Trajectory r, s;
    fmi2Component c = instantiate("tuned"), d = instantiate("fresh");
    initialize(c, 0.0);
    run(c, 0.0, 0.5, 10, r, 1);
    set(c, STIFFNESS, 2.0);
    run(c, 5.0, 0.5, 10, r, 11);

    set(d, STIFFNESS, 2.0);
    set(d, Q1_START, r[10][0]);
    set(d, Q2_START, r[10][1]);
    set(d, V1_START, r[10][2]);
    set(d, V2_START, r[10][3]);
    initialize(d, 5.0);
    run(d, 5.0, 0.5, 10, s, 11);
    for (int i = 11; i <= 20; i++) {
        for (int k = 0; k < 4; k++) {
            CHECK(fabs(r[i][k] - s[i][k]) <= 1e-13, "stiffness changed at t = 5: t = %g differs by %g",
                  0.5 * i, r[i][k] - s[i][k]);
        }
    }
    F.FreeInstance(c);
    F.FreeInstance(d);
}

static void initialization_mode_and_logging(void) {
    fmi2Component c = instantiate("init");
    const fmi2String events[] = {"logEvents"}, bogus[] = {"logEvents", "logBogus"};
    int ok_before = LOG.ok_count;
    OK(F.SetupExperiment(c, fmi2True, 1e-6, 0.0, fmi2True, 15.0));
    OK(F.EnterInitializationMode(c));
    set(c, Q1_START, 0.3);
    CHECK(get(c, Q1) == 0.3, "in initialization mode q1 follows q1_start");
    OK(F.SetDebugLogging(c, fmi2True, 1, events));
    OK(F.ExitInitializationMode(c));
    CHECK(LOG.ok_count > ok_before && strstr(LOG.message, "initialized") != NULL,
          "no event logged at initialization with logEvents on (last: %s)", LOG.message);
    CHECK(get(c, Q1) == 0.3, "q1 at t = 0 after initialization");
    OK(F.SetDebugLogging(c, fmi2False, 0, NULL));
    ok_before = LOG.ok_count;
    OK(F.DoStep(c, 0.0, 0.5, fmi2True));
    CHECK(LOG.ok_count == ok_before, "messages logged with logging off");
    ERROR(F.DoStep(c, 0.5, 15.0, fmi2True), "stopTime");       /* beyond the stop time */
    OK(F.Reset(c));
    ERROR(F.SetDebugLogging(c, fmi2True, 2, bogus), "logBogus");
    OK(F.Reset(c));
    ERROR(F.SetDebugLogging(c, fmi2True, 1, NULL), "NULL");
    OK(F.Reset(c));
    ERROR(F.SetupExperiment(c, fmi2False, 0.0, 1.0, fmi2True, 0.5), "stopTime");
    OK(F.Reset(c));
    /* unstable or meaningless solver settings are refused when initialization ends */
    set(c, THETA1, 0.8);
    set(c, THETA2, 0.6);
    OK(F.EnterInitializationMode(c));
    ERROR(F.ExitInitializationMode(c), "theta");
    ERROR(F.DoStep(c, 0.0, 0.5, fmi2True), "state error");
    OK(F.Reset(c));
    initialize(c, 0.0);
    OK(F.DoStep(c, 0.0, 0.5, fmi2True));
    /* terminated: outputs still readable, nothing else but reset */
    OK(F.Terminate(c));
    CHECK(isfinite(get(c, Q1)), "q1 after fmi2Terminate");
    ERROR(F.DoStep(c, 0.5, 0.5, fmi2True), "terminated");
    ERROR(F.Terminate(c), "error");
    OK(F.Reset(c));
    F.FreeInstance(c);
}

/* Every bad call returns fmi2Error with a message and puts the instance in the error state, from which
 * fmi2SetFMUstate brings it back: the run must then go on exactly as if nothing had happened. */
static void bad_calls(Trajectory a) {
    static Trajectory r;
    fmi2Component c = instantiate("bad");
    fmi2FMUstate s = NULL;
    fmi2ValueReference vr[2] = {F1, STIFFNESS}, unknown = N_TWODOF_VARS;
    double x[2] = {5.0, -1.0}, value = 0.0;
    fmi2Integer i_value = 0;
    fmi2Boolean b_value = fmi2False;
    fmi2String s_value = NULL;
    fmi2Status status_value = fmi2OK;

    ERROR(F.DoStep(c, 0.0, 0.5, fmi2True), "fmi2DoStep: not allowed in state instantiated");
    OK(F.Reset(c));
    ERROR(F.ExitInitializationMode(c), "instantiated");
    OK(F.Reset(c));
    ERROR(F.GetReal(c, QV, 1, &value), "instantiated");
    OK(F.Reset(c));
    initialize(c, 0.0);
    run(c, 0.0, 0.5, 2, r, 1);
    OK(F.GetFMUstate(c, &s));                       /* t = 1 */

#define RECOVER() OK(F.SetFMUstate(c, s))
    value = NAN;
    ERROR(F.SetReal(c, vr, 1, &value), "F1");
    CHECK(get(c, F1) == 1.0, "a refused input was written");  /* readable in the error state */
    RECOVER();
    value = INFINITY;
    ERROR(F.SetReal(c, vr, 1, &value), "infinite");
    RECOVER();
    value = -1.0;
    ERROR(F.SetReal(c, &vr[1], 1, &value), "stiffness = -1: must be > 0");
    RECOVER();
    value = 0.0;
    ERROR(F.SetReal(c, &vr[1], 1, &value), "stiffness = 0: must be > 0");
    RECOVER();
    ERROR(F.SetReal(c, vr, 2, x), "stiffness");     /* F1 = 5 is fine, stiffness is not: nothing written */
    CHECK(get(c, F1) == 1.0 && get(c, STIFFNESS) == 1.0, "a refused fmi2SetReal changed a value");
    RECOVER();
    ERROR(F.DoStep(c, 1.0, 0.0, fmi2True), "communicationStepSize");
    RECOVER();
    ERROR(F.DoStep(c, 1.0, -0.5, fmi2True), "communicationStepSize");
    RECOVER();
    ERROR(F.DoStep(c, 1.0, NAN, fmi2True), "communicationStepSize");
    RECOVER();
    ERROR(F.DoStep(c, 1.0, INFINITY, fmi2True), "communicationStepSize");
    RECOVER();
    ERROR(F.DoStep(c, 1.5, 0.5, fmi2True), "differs");
    RECOVER();
    ERROR(F.DoStep(c, NAN, 0.5, fmi2True), "differs");
    RECOVER();
    ERROR(F.ExitInitializationMode(c), "not allowed in state step mode");
    RECOVER();
    ERROR(F.EnterInitializationMode(c), "step mode");
    RECOVER();
    ERROR(F.SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), "step mode");
    RECOVER();
    ERROR(F.GetReal(c, &unknown, 1, &value), "unknown value reference 16");
    RECOVER();
    ERROR(F.SetReal(c, &unknown, 1, &value), "unknown value reference");
    RECOVER();
    ERROR(F.GetInteger(c, QV, 1, &i_value), "is a Real");
    RECOVER();
    ERROR(F.SetBoolean(c, QV, 1, &b_value), "unknown value reference");
    RECOVER();
    ERROR(F.GetString(c, QV, 1, &s_value), "unknown value reference");
    RECOVER();
    OK(F.GetInteger(c, NULL, 0, NULL));
    OK(F.SetString(c, NULL, 0, NULL));
    OK(F.GetReal(c, NULL, 0, NULL));
    ERROR(F.GetReal(c, NULL, 1, &value), "NULL");
    RECOVER();
    ERROR(F.GetReal(c, QV, 1, NULL), "NULL");
    RECOVER();
    ERROR(F.SetReal(c, NULL, 1, &value), "NULL");
    RECOVER();
    ERROR(F.SetReal(c, QV, 1, NULL), "NULL");
    RECOVER();
    ERROR(F.SetInteger(c, NULL, 1, &i_value), "NULL");
    RECOVER();
    value = 0.1;
    ERROR(F.SetReal(c, QV, 1, &value), "q1 is an output");
    RECOVER();
    {
        fmi2ValueReference step = STEP;
        ERROR(F.SetReal(c, &step, 1, &value), "fixed after initialization");
        RECOVER();
    }
    ERROR(F.GetFMUstate(c, NULL), "NULL");
    RECOVER();
    ERROR(F.FreeFMUstate(c, NULL), "NULL");
    RECOVER();
    ERROR(F.SerializedFMUstateSize(c, s, NULL), "NULL");
    RECOVER();
    /* directional derivatives: an output is not a known */
    ERROR(F.GetDirectionalDerivative(c, QV, 1, QV, 1, &value, &value), "not a known");
    RECOVER();
    /* capabilities this FMU does not have */
    RECOVER();
    ERROR(F.SetRealInputDerivatives(c, vr, 1, &i_value, &value), "not supported");
    RECOVER();
    ERROR(F.GetRealOutputDerivatives(c, QV, 1, &i_value, &value), "not supported");
    RECOVER();
    ERROR(F.CancelStep(c), "fmi2Pending");
    RECOVER();
    ERROR(F.GetStatus(c, fmi2DoStepStatus, &status_value), "fmi2Pending");
    RECOVER();
    ERROR(F.GetStringStatus(c, fmi2PendingStatus, &s_value), "fmi2Pending");
    RECOVER();
    ERROR(F.GetIntegerStatus(c, fmi2LastSuccessfulTime, &i_value), "Integer");
    RECOVER();
    ERROR(F.GetRealStatus(c, fmi2DoStepStatus, &value), "fmi2LastSuccessfulTime");
    RECOVER();
    ERROR(F.GetRealStatus(c, fmi2LastSuccessfulTime, NULL), "NULL");
    RECOVER();
    ERROR(F.EnterEventMode(c), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.NewDiscreteStates(c, NULL), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.EnterContinuousTimeMode(c), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.CompletedIntegratorStep(c, fmi2True, &b_value, &b_value), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.SetTime(c, 1.0), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.SetContinuousStates(c, x, 2), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.GetDerivatives(c, x, 2), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.GetEventIndicators(c, x, 0), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.GetContinuousStates(c, x, 2), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    ERROR(F.GetNominalsOfContinuousStates(c, x, 2), "not allowed in state step mode");   /* Model Exchange only */
    RECOVER();
    /* in the error state only reading, states, reset and freeing are allowed */
    ERROR(F.EnterEventMode(c), "not allowed in state step mode");
    ERROR(F.SetReal(c, vr, 1, &value), "not allowed in state error");
    ERROR(F.Terminate(c), "not allowed in state error");
    CHECK(get(c, Q1) == r[2][0], "outputs in the error state");
    RECOVER();
#undef RECOVER
    run(c, 1.0, 0.5, N_POINTS - 3, r, 3);
    CHECK(same(r[1], a[1], 4 * (N_POINTS - 1)), "the run after the bad calls differs from the reference");
    OK(F.FreeFMUstate(c, &s));
    F.FreeInstance(c);

    /* fmi2Instantiate refuses what it cannot work with, with a message where a logger exists */
    {
        fmi2CallbackFunctions no_alloc = CALLBACKS;
        const int before = LOG.count;
        no_alloc.allocateMemory = NULL;
        CHECK(F.Instantiate("x", fmi2CoSimulation, "{wrong}", "", &CALLBACKS, fmi2False, fmi2False) == NULL,
              "wrong GUID accepted");
        CHECK(LOG.count > before && strstr(LOG.message, "GUID") != NULL, "wrong GUID: %s", LOG.message);
        {   /* Model Exchange instantiates; doStep is refused there */
            fmi2Component me = F.Instantiate("x", fmi2ModelExchange, GUID, "", &CALLBACKS, fmi2False, fmi2False);
            CHECK(me != NULL, "Model Exchange refused: %s", LOG.message);
            if (me != NULL) {
                CHECK(F.DoStep(me, 0.0, 0.1, fmi2True) == fmi2Error, "doStep on a Model Exchange instance");
                F.FreeInstance(me);
            }
        }
        CHECK(F.Instantiate(NULL, fmi2CoSimulation, GUID, "", &CALLBACKS, fmi2False, fmi2False) == NULL,
              "NULL instance name accepted");
        CHECK(strstr(LOG.message, "instanceName") != NULL, "NULL name: %s", LOG.message);
        CHECK(F.Instantiate("x", fmi2CoSimulation, NULL, "", &CALLBACKS, fmi2False, fmi2False) == NULL,
              "NULL GUID accepted");
        CHECK(F.Instantiate("x", fmi2CoSimulation, GUID, "", &no_alloc, fmi2False, fmi2False) == NULL,
              "allocateMemory NULL accepted");
        CHECK(strstr(LOG.message, "allocateMemory") != NULL, "no allocator: %s", LOG.message);
        CHECK(F.Instantiate("x", fmi2CoSimulation, GUID, "", NULL, fmi2False, fmi2False) == NULL,
              "NULL callbacks accepted");
        no_alloc = CALLBACKS;
        no_alloc.logger = NULL;                      /* no logger: silent, but works */
        c = F.Instantiate("silent", fmi2CoSimulation, GUID, "", &no_alloc, fmi2False, fmi2False);
        CHECK(c != NULL, "an instance without logger");
        if (c != NULL) {
            const int quiet = LOG.count;
            CHECK(F.DoStep(c, 0.0, 0.5, fmi2True) == fmi2Error, "doStep before initialization");
            CHECK(LOG.count == quiet, "an instance without logger logged");
            F.FreeInstance(c);
        }
    }

    /* a NULL instance: fmi2Error, no crash */
    {
        fmi2Component z = NULL;
        fmi2FMUstate zs = NULL;
        size_t n = 0;
        CHECK(strcmp(F.GetTypesPlatform(), "default") == 0, "types platform %s", F.GetTypesPlatform());
        CHECK(strcmp(F.GetVersion(), "2.0") == 0, "version %s", F.GetVersion());
        F.FreeInstance(NULL);
        CHECK(F.SetDebugLogging(z, fmi2True, 0, NULL) == fmi2Error, "NULL instance");
        CHECK(F.SetupExperiment(z, fmi2False, 0, 0, fmi2False, 0) == fmi2Error, "NULL instance");
        CHECK(F.EnterInitializationMode(z) == fmi2Error, "NULL instance");
        CHECK(F.ExitInitializationMode(z) == fmi2Error, "NULL instance");
        CHECK(F.Terminate(z) == fmi2Error, "NULL instance");
        CHECK(F.Reset(z) == fmi2Error, "NULL instance");
        CHECK(F.GetReal(z, QV, 1, &value) == fmi2Error, "NULL instance");
        CHECK(F.SetReal(z, QV, 1, &value) == fmi2Error, "NULL instance");
        CHECK(F.GetInteger(z, QV, 1, &i_value) == fmi2Error, "NULL instance");
        CHECK(F.SetInteger(z, QV, 1, &i_value) == fmi2Error, "NULL instance");
        CHECK(F.GetBoolean(z, QV, 1, &b_value) == fmi2Error, "NULL instance");
        CHECK(F.SetBoolean(z, QV, 1, &b_value) == fmi2Error, "NULL instance");
        CHECK(F.GetString(z, QV, 1, &s_value) == fmi2Error, "NULL instance");
        CHECK(F.SetString(z, QV, 1, &s_value) == fmi2Error, "NULL instance");
        CHECK(F.GetFMUstate(z, &zs) == fmi2Error, "NULL instance");
        CHECK(F.SetFMUstate(z, zs) == fmi2Error, "NULL instance");
        CHECK(F.FreeFMUstate(z, &zs) == fmi2Error, "NULL instance");
        CHECK(F.SerializedFMUstateSize(z, zs, &n) == fmi2Error, "NULL instance");
        CHECK(F.SerializeFMUstate(z, zs, (fmi2Byte *)x, 1) == fmi2Error, "NULL instance");
        CHECK(F.DeSerializeFMUstate(z, (fmi2Byte *)x, 1, &zs) == fmi2Error, "NULL instance");
        CHECK(F.GetDirectionalDerivative(z, QV, 1, QV, 1, &value, &value) == fmi2Error, "NULL instance");
        CHECK(F.EnterEventMode(z) == fmi2Error, "NULL instance");
        CHECK(F.NewDiscreteStates(z, NULL) == fmi2Error, "NULL instance");
        CHECK(F.EnterContinuousTimeMode(z) == fmi2Error, "NULL instance");
        CHECK(F.CompletedIntegratorStep(z, fmi2True, &b_value, &b_value) == fmi2Error, "NULL instance");
        CHECK(F.SetTime(z, 0.0) == fmi2Error, "NULL instance");
        CHECK(F.SetContinuousStates(z, x, 2) == fmi2Error, "NULL instance");
        CHECK(F.GetDerivatives(z, x, 2) == fmi2Error, "NULL instance");
        CHECK(F.GetEventIndicators(z, x, 0) == fmi2Error, "NULL instance");
        CHECK(F.GetContinuousStates(z, x, 2) == fmi2Error, "NULL instance");
        CHECK(F.GetNominalsOfContinuousStates(z, x, 2) == fmi2Error, "NULL instance");
        CHECK(F.SetRealInputDerivatives(z, QV, 1, &i_value, &value) == fmi2Error, "NULL instance");
        CHECK(F.GetRealOutputDerivatives(z, QV, 1, &i_value, &value) == fmi2Error, "NULL instance");
        CHECK(F.DoStep(z, 0.0, 0.5, fmi2True) == fmi2Error, "NULL instance");
        CHECK(F.CancelStep(z) == fmi2Error, "NULL instance");
        CHECK(F.GetStatus(z, fmi2DoStepStatus, &status_value) == fmi2Error, "NULL instance");
        CHECK(F.GetRealStatus(z, fmi2LastSuccessfulTime, &value) == fmi2Error, "NULL instance");
        CHECK(F.GetIntegerStatus(z, fmi2LastSuccessfulTime, &i_value) == fmi2Error, "NULL instance");
        CHECK(F.GetBooleanStatus(z, fmi2Terminated, &b_value) == fmi2Error, "NULL instance");
        CHECK(F.GetStringStatus(z, fmi2PendingStatus, &s_value) == fmi2Error, "NULL instance");
    }
}

static void twodof(void) {
    static Trajectory a;
    GUID = "{8c4e810f-3df3-4a00-8276-176fa3c9f000}";
    reference_run(a);
    side_by_side(a);
    fmu_states(a);
    communication_steps(a);
    tunable_parameter();
    initialization_mode_and_logging();
    bad_calls(a);
}

/* =========================================================== the nonlinear model */

enum { FORCE, X1, XD1, XDD1, OQ0, OQ1, OV0, OV1, OA0, OA1, L0X, L0XD, L0XDD, L1X, L1XD, L1XDD, M, C, K, K3, G,
       LIMIT, MAX_CV, Q0_START, Q1_START_NL, V0_START, V1_START_NL, STEP_NL };
static const fmi2ValueReference STATE[4] = {OQ0, OQ1, OV0, OV1};

static void law0(double t, double *x) {            /* tests/c/nonlinear/model.c, written out */
    const double pi = 3.14159265358979323846;
    if (t < 1.0) {
        x[0] = 0.1 - 0.1 * cos(pi * t);
        x[1] = 0.1 * pi * sin(pi * t);
        x[2] = 0.1 * pi * pi * cos(pi * t);
    } else {
        x[0] = 0.3 * t * t - 0.6 * t + 0.5;
        x[1] = 0.6 * t - 0.6;
        x[2] = 0.6;
    }
}

static void nonlinear(void) {
    fmi2Component c = instantiate("nonlinear");
    fmi2FMUstate s = NULL;
    const fmi2ValueReference law0_vr[3] = {L0X, L0XD, L0XDD}, law1_vr[3] = {L1X, L1XD, L1XDD};
    const fmi2ValueReference host_law[3] = {X1, XD1, XDD1};
    const double m = 1.0, k = 100.0, k3 = 1e4, g = 9.81;
    double x[4], y[4], expected[3], got[3], h = 0.25, t = 0.0, d0;

    initialize(c, 0.0);
    /* static equilibrium of q0 (law 0 at 0), q1 held at its start value, consistent acceleration */
    d0 = get(c, OQ0);
    CHECK(fabs(k * d0 + k3 * d0 * d0 * d0 + m * g) < 1e-6, "static equilibrium: residual %g",
          k * d0 + k3 * d0 * d0 * d0 + m * g);
    CHECK(d0 < -0.01, "static deflection %g", d0);
    CHECK(get(c, OQ1) == 0.05, "q1 moved during initialization");
    CHECK(fabs(get(c, OA0)) < 1e-6, "acceleration at static equilibrium %g", get(c, OA0));
    CHECK(fabs(get(c, OA1) + 100.0 * 0.05) < 1e-12, "consistent acceleration a1 = %g, not -5", get(c, OA1));

    /* built-in law 0, and law 1 extended by the FMU from what the host gives at each communication point */
    for (int i = 0; i < 12; i++) {
        double given[3] = {sin(t), cos(t), -sin(t)};
        if (i == 6) {                                  /* only x given: xd, xdd carried forward from before */
            double before[3];
            OK(F.GetReal(c, law1_vr, 3, before));
            given[1] = before[1];
            given[2] = before[2];
            OK(F.SetReal(c, host_law, 1, given));
        } else {
            OK(F.SetReal(c, host_law, 3, given));
        }
        OK(F.DoStep(c, t, h, fmi2True));
        t += h;
        law0(t, expected);
        OK(F.GetReal(c, law0_vr, 3, got));
        for (int j = 0; j < 3; j++) {
            CHECK(fabs(got[j] - expected[j]) < 1e-12, "law 0 at t = %g: %g, not %g", t, got[j], expected[j]);
        }
        expected[0] = given[0] + h * given[1] + 0.5 * h * h * given[2];
        expected[1] = given[1] + h * given[2];
        expected[2] = given[2];
        OK(F.GetReal(c, law1_vr, 3, got));
        for (int j = 0; j < 3; j++) {
            CHECK(fabs(got[j] - expected[j]) < 1e-14, "law 1 at t = %g: %g, not %g", t, got[j], expected[j]);
        }
    }
    OK(F.GetReal(c, STATE, 4, x));
    CHECK(isfinite(x[0]) && isfinite(x[1]), "nonlinear run");

    /* FMU state: the Newton start (alpha) is part of it */
    OK(F.GetFMUstate(c, &s));
    OK(F.DoStep(c, t, 0.5, fmi2True));
    OK(F.GetReal(c, STATE, 4, x));
    OK(F.SetFMUstate(c, s));
    OK(F.DoStep(c, t, 0.5, fmi2True));
    OK(F.GetReal(c, STATE, 4, y));
    CHECK(same(x, y, 4), "nonlinear: get state, step, set state, step: not bit-equal");
    ERROR(F.SetReal(c, (const fmi2ValueReference[]){M}, 1, (const double[]){2.0}), "fixed");
    OK(F.SetFMUstate(c, s));
    OK(F.FreeFMUstate(c, &s));
    F.FreeInstance(c);

    /* a step that cannot be computed: |d0| crosses `limit` inside the communication step */
    {
        fmi2Component probe = instantiate("probe"), failing = instantiate("failing");
        fmi2Component plain = instantiate("plain");
        double start = 0.0, worst = 0.0, before[4], after[4], last = NAN;
        initialize(probe, 0.0);
        start = fabs(get(probe, OQ0) - get(probe, L0X));
        for (int i = 0; i < 20; i++) {
            OK(F.DoStep(probe, 0.05 * i, 0.05, fmi2True));
            d0 = fabs(get(probe, OQ0) - get(probe, L0X));
            if (d0 > worst) worst = d0;
        }
        CHECK(worst > 1.01 * start, "the support does not stretch the spring (%g, %g)", start, worst);
        initialize(failing, 0.0);
        set(failing, LIMIT, 0.5 * (start + worst));   /* after the static Newton, which overshoots */
        initialize(plain, 0.0);
        OK(F.GetReal(failing, STATE, 4, before));
        {
            const int discards = LOG.count;
            OK(F.SetDebugLogging(failing, fmi2True, 0, NULL));
            LOG.retries = 0;
            EXPECT(F.DoStep(failing, 0.0, 1.0, fmi2True), fmi2Discard, "discarded");
            CHECK(LOG.count > discards && strcmp(LOG.category, "logStatusDiscard") == 0,
                  "discard category %s", LOG.category);
            CHECK(LOG.retries == 3, "%d sub-step retries logged, expected 3 (2, 4, 8)", LOG.retries);
            OK(F.SetDebugLogging(failing, fmi2False, 0, NULL));
        }
        OK(F.GetRealStatus(failing, fmi2LastSuccessfulTime, &last));
        CHECK(last == 0.0, "last successful time %g after a discarded step from 0", last);
        OK(F.GetReal(failing, STATE, 4, after));
        CHECK(same(before, after, 4), "a discarded step did not restore the state");
        set(failing, LIMIT, 1e300);                   /* the host fixes the cause and retries */
        OK(F.DoStep(failing, 0.0, 1.0, fmi2True));
        OK(F.DoStep(plain, 0.0, 1.0, fmi2True));
        OK(F.GetReal(failing, STATE, 4, x));
        OK(F.GetReal(plain, STATE, 4, y));
        CHECK(same(x, y, 4), "the retried step differs from a step that never failed");
        F.FreeInstance(probe);
        F.FreeInstance(failing);
        F.FreeInstance(plain);
    }

    /* a step that succeeds only as sub-steps, and one that does not even then */
    {
        fmi2Component split = instantiate("split"), fine = instantiate("fine");
        set(split, MAX_CV, 0.004);                    /* theta1 dt = 0.005 fails, 0.0025 works */
        set(fine, STEP_NL, 0.005);
        initialize(split, 0.0);
        initialize(fine, 0.0);
        OK(F.SetDebugLogging(split, fmi2True, 1, (const fmi2String[]){"logEvents"}));
        LOG.retries = 0;
        OK(F.DoStep(split, 0.0, 0.5, fmi2True));
        CHECK(LOG.retries == 50, "%d sub-step retries logged, expected 50", LOG.retries);
        OK(F.SetDebugLogging(split, fmi2False, 0, NULL));
        OK(F.DoStep(fine, 0.0, 0.5, fmi2True));
        OK(F.GetReal(split, STATE, 4, x));
        OK(F.GetReal(fine, STATE, 4, y));
        for (int i = 0; i < 4; i++) CHECK(fabs(x[i] - y[i]) < 1e-12, "sub-steps: %g", x[i] - y[i]);
        set(split, MAX_CV, 1e-5);                     /* not even 8 sub-steps help */
        EXPECT(F.DoStep(split, 0.5, 0.5, fmi2True), fmi2Discard, "model failed");
        OK(F.GetReal(split, STATE, 4, y));
        CHECK(same(x, y, 4), "a discarded step did not restore the state");
        F.FreeInstance(split);
        F.FreeInstance(fine);
    }
}

/* ========================================================================== main */

int main(int argc, char **argv) {
    void *library;
    int missing = 0;
    if (argc < 3) {
        fprintf(stderr, "usage: %s twodof|nonlinear LIBRARY [-v]\n", argv[0]);
        return 2;
    }
    VERBOSE = argc > 3 && strcmp(argv[3], "-v") == 0;
    library = dlopen(argv[2], RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (library == NULL) {
        fprintf(stderr, "cannot load %s: %s\n", argv[2], dlerror());
        return 2;
    }
#define RESOLVE(name)                                                       \
    *(void **)(&F.name) = dlsym(library, "fmi2" #name);                      \
    if (F.name == NULL) {                                                   \
        fprintf(stderr, "FAIL: %s does not export fmi2" #name "\n", argv[2]); \
        missing++;                                                          \
    }
    FMI2_FUNCTIONS(RESOLVE)
    if (missing > 0) return 1;
    setvbuf(stdout, NULL, _IOLBF, 0);

    if (strcmp(argv[1], "twodof") == 0) twodof();
    else if (strcmp(argv[1], "nonlinear") == 0) {
        GUID = "{5d1b7f3e-0c2a-4e8b-9a61-2f4c8e7d0b01}";
        nonlinear();
    }
    else { fprintf(stderr, "unknown model %s\n", argv[1]); return 2; }

    CHECK(ALLOCATIONS == 0, "%ld blocks allocated by the FMU were not freed", ALLOCATIONS);
    dlclose(library);
    fprintf(stderr, "host %s: %d checks, %d failed\n", argv[1], CHECKS, FAILURES);
    return FAILURES == 0 ? 0 : 1;
}
