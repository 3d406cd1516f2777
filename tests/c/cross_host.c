/* One FMI 2.0 host for both platforms: compiled with gcc it loads a linux64 .so (dlopen), cross-compiled
 * with MinGW-w64 it loads the win64 .dll (LoadLibrary) under Wine; tests/test_windows.py runs both on the
 * same FMU and compares what they print.
 *
 * usage: cross_host cs|me LIBRARY GUID N_VARS N_STATES STOP STEP [save FILE|load FILE] [VR=VALUE ...]
 *   cs: Co-Simulation, fmi2DoStep from 0 to STOP with communication step STEP;
 *   me: Model Exchange, the host integrates the N_STATES states with classical Runge-Kutta 4 (step STEP),
 *       calling fmi2SetTime / fmi2SetContinuousStates / fmi2GetDerivatives and fmi2CompletedIntegratorStep;
 *   VR=VALUE: fmi2SetReal before initialisation (parameters, inputs);
 *   save FILE (cs): at the middle communication point, fmi2SerializeFMUstate's bytes go to FILE;
 *   load FILE (cs): after initialisation, the state is restored from FILE and the run continues from the
 *       middle point, so that its rows are those that follow the save.
 * Prints one row per communication point: the time and the N_VARS reals (value references 0..N_VARS-1), each
 * as the 16 hex digits of its IEEE 754 bits, so that no C library's decimal formatting is compared.
 * Exits 0 when every call returned fmi2OK, 1 otherwise (the failing call on stderr), 2 on bad usage. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifdef _WIN32
#include <windows.h>
#else
#include <dlfcn.h>
#endif
#include "fmi2Functions.h"

#define FUNCTIONS(X)                                                                                        \
    X(Instantiate) X(FreeInstance) X(SetupExperiment) X(EnterInitializationMode) X(ExitInitializationMode) \
    X(Terminate) X(GetReal) X(SetReal) X(DoStep) X(GetFMUstate) X(SetFMUstate) X(FreeFMUstate)             \
    X(SerializedFMUstateSize) X(SerializeFMUstate) X(DeSerializeFMUstate) X(NewDiscreteStates)             \
    X(EnterContinuousTimeMode) X(SetTime) X(SetContinuousStates) X(GetDerivatives)                         \
    X(CompletedIntegratorStep) X(GetContinuousStates)
#define DECLARE(name) fmi2##name##TYPE *name;
static struct { FUNCTIONS(DECLARE) } F;

#define CHECK(call)                                                            \
    do {                                                                       \
        if ((call) != fmi2OK) {                                                \
            fprintf(stderr, "failed at line %d: %s\n", __LINE__, #call);       \
            return 1;                                                          \
        }                                                                      \
    } while (0)

static void *symbol(const char *path, const char *name) {
#ifdef _WIN32
    static HMODULE lib = NULL;
    if (lib == NULL) lib = LoadLibraryA(path);
    return lib == NULL ? NULL : (void *)GetProcAddress(lib, name);
#else
    static void *lib = NULL;
    if (lib == NULL) lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    return lib == NULL ? NULL : dlsym(lib, name);
#endif
}

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env; (void)name; (void)category;
    if (status != fmi2OK) fprintf(stderr, "[status %d] %s\n", (int)status, message);
}

static struct {
    const char *mode, *library, *guid, *save, *load;
    size_t n_vars, n_states;
    double stop, h;
    int n_set;
    char **set;
} A;

static fmi2ValueReference *VR;
static double *VALUES;

static void print_bits(double x) {
    uint64_t bits;
    memcpy(&bits, &x, sizeof bits);
    printf(" %08x%08x", (unsigned)(bits >> 32), (unsigned)(bits & 0xffffffffu));
}

static int print_row(fmi2Component c, double t) {
    CHECK(F.GetReal(c, VR, A.n_vars, VALUES));
    print_bits(t);
    for (size_t i = 0; i < A.n_vars; i++) print_bits(VALUES[i]);
    putchar('\n');
    return 0;
}

/* instantiate, the VR=VALUE settings, initialise */
static fmi2Component start(fmi2Type type, const fmi2CallbackFunctions *cb) {
    fmi2Component c = F.Instantiate("cross_host", type, A.guid, "", cb, fmi2False, fmi2False);
    if (c == NULL) return NULL;
    for (int k = 0; k < A.n_set; k++) {
        const fmi2ValueReference vr = (fmi2ValueReference)strtoul(A.set[k], NULL, 10);
        const double value = strtod(strchr(A.set[k], '=') + 1, NULL);
        if (F.SetReal(c, &vr, 1, &value) != fmi2OK) return NULL;
    }
    if (F.SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK) return NULL;
    if (F.EnterInitializationMode(c) != fmi2OK || F.ExitInitializationMode(c) != fmi2OK) return NULL;
    return c;
}

static int save_state(fmi2Component c, const char *path) {
    fmi2FMUstate state = NULL;
    size_t size = 0;
    CHECK(F.GetFMUstate(c, &state));
    CHECK(F.SerializedFMUstateSize(c, state, &size));
    fmi2Byte *bytes = malloc(size);
    CHECK(F.SerializeFMUstate(c, state, bytes, size));
    FILE *f = fopen(path, "wb");
    if (f == NULL || fwrite(bytes, 1, size, f) != size || fclose(f) != 0) return 1;
    free(bytes);
    CHECK(F.FreeFMUstate(c, &state));
    return 0;
}

static int load_state(fmi2Component c, const char *path) {
    fmi2FMUstate state = NULL;
    FILE *f = fopen(path, "rb");
    if (f == NULL) return 1;
    fseek(f, 0, SEEK_END);
    const size_t size = (size_t)ftell(f);
    fseek(f, 0, SEEK_SET);
    fmi2Byte *bytes = malloc(size);
    if (fread(bytes, 1, size, f) != size) return 1;
    fclose(f);
    CHECK(F.DeSerializeFMUstate(c, bytes, size, &state));
    CHECK(F.SetFMUstate(c, state));
    CHECK(F.FreeFMUstate(c, &state));
    free(bytes);
    return 0;
}

static int cosimulation(const fmi2CallbackFunctions *cb) {
    const long steps = (long)(A.stop / A.h + 0.5), half = steps / 2;
    long k = 0;
    fmi2Component c = start(fmi2CoSimulation, cb);
    if (c == NULL) { fprintf(stderr, "instantiation or initialisation failed\n"); return 1; }
    if (A.load != NULL) {
        if (load_state(c, A.load)) { fprintf(stderr, "cannot restore the state of %s\n", A.load); return 1; }
        k = half;
    } else if (print_row(c, 0.0)) {
        return 1;
    }
    for (; k < steps; k++) {
        if (A.save != NULL && k == half && save_state(c, A.save)) { fprintf(stderr, "cannot save\n"); return 1; }
        CHECK(F.DoStep(c, (double)k * A.h, A.h, fmi2True));
        if (print_row(c, (double)(k + 1) * A.h)) return 1;
    }
    CHECK(F.Terminate(c));
    F.FreeInstance(c);
    return 0;
}

/* dx = f(t, x) through the FMU */
static int derivatives(fmi2Component c, double t, const double *x, double *dx) {
    CHECK(F.SetTime(c, t));
    CHECK(F.SetContinuousStates(c, x, A.n_states));
    CHECK(F.GetDerivatives(c, dx, A.n_states));
    return 0;
}

static int model_exchange(const fmi2CallbackFunctions *cb) {
    const long steps = (long)(A.stop / A.h + 0.5);
    const size_t n = A.n_states;
    double *x = calloc(6 * n, sizeof(double)), *k1 = x + n, *k2 = x + 2 * n, *k3 = x + 3 * n, *k4 = x + 4 * n,
           *y = x + 5 * n;
    fmi2EventInfo info;
    fmi2Boolean enter = fmi2False, terminate = fmi2False;
    fmi2Component c = start(fmi2ModelExchange, cb);
    if (c == NULL) { fprintf(stderr, "instantiation or initialisation failed\n"); return 1; }
    memset(&info, 0, sizeof info);
    info.newDiscreteStatesNeeded = fmi2True;
    while (info.newDiscreteStatesNeeded) CHECK(F.NewDiscreteStates(c, &info));
    CHECK(F.EnterContinuousTimeMode(c));
    CHECK(F.GetContinuousStates(c, x, n));
    if (print_row(c, 0.0)) return 1;
    for (long k = 0; k < steps; k++) {
        const double t = (double)k * A.h, h = A.h;
        if (derivatives(c, t, x, k1)) return 1;
        for (size_t i = 0; i < n; i++) y[i] = x[i] + 0.5 * h * k1[i];
        if (derivatives(c, t + 0.5 * h, y, k2)) return 1;
        for (size_t i = 0; i < n; i++) y[i] = x[i] + 0.5 * h * k2[i];
        if (derivatives(c, t + 0.5 * h, y, k3)) return 1;
        for (size_t i = 0; i < n; i++) y[i] = x[i] + h * k3[i];
        if (derivatives(c, t + h, y, k4)) return 1;
        for (size_t i = 0; i < n; i++) x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        CHECK(F.SetTime(c, (double)(k + 1) * h));
        CHECK(F.SetContinuousStates(c, x, n));
        CHECK(F.CompletedIntegratorStep(c, fmi2True, &enter, &terminate));
        if (print_row(c, (double)(k + 1) * h)) return 1;
    }
    CHECK(F.Terminate(c));
    F.FreeInstance(c);
    free(x);
    return 0;
}

#define LOAD(name)                                                                       \
    if ((F.name = (fmi2##name##TYPE *)symbol(A.library, "fmi2" #name)) == NULL) {        \
        fprintf(stderr, "cannot load fmi2" #name " from %s\n", A.library);               \
        return 2;                                                                        \
    }

int main(int argc, char **argv) {
    static const fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    if (argc < 8 || (strcmp(argv[1], "cs") != 0 && strcmp(argv[1], "me") != 0)) {
        fprintf(stderr, "usage: %s cs|me LIBRARY GUID N_VARS N_STATES STOP STEP [save FILE|load FILE] "
                "[VR=VALUE ...]\n", argv[0]);
        return 2;
    }
    A.mode = argv[1]; A.library = argv[2]; A.guid = argv[3];
    A.n_vars = (size_t)atol(argv[4]); A.n_states = (size_t)atol(argv[5]);
    A.stop = atof(argv[6]); A.h = atof(argv[7]);
    int next = 8;
    if (argc >= 10 && (strcmp(argv[8], "save") == 0 || strcmp(argv[8], "load") == 0)) {
        if (argv[8][0] == 's') A.save = argv[9]; else A.load = argv[9];
        next = 10;
    }
    A.set = argv + next;
    A.n_set = argc - next;
    for (int k = 0; k < A.n_set; k++) {
        if (strchr(A.set[k], '=') == NULL) { fprintf(stderr, "not VR=VALUE: %s\n", A.set[k]); return 2; }
    }
    FUNCTIONS(LOAD)
    VR = malloc(A.n_vars * sizeof *VR);
    VALUES = malloc(A.n_vars * sizeof *VALUES);
    for (size_t i = 0; i < A.n_vars; i++) VR[i] = (fmi2ValueReference)i;
    const int status = strcmp(A.mode, "cs") == 0 ? cosimulation(&cb) : model_exchange(&cb);
    fflush(stdout);
    free(VR);
    free(VALUES);
    return status;
}
