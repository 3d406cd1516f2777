/* The FMI 3.0 counterpart of cross_host.c: one host for both platforms (gcc: dlopen of the x86_64-linux .so;
 * MinGW-w64: LoadLibrary of the x86_64-windows .dll under Wine); tests/test_windows.py runs both on the same
 * FMI 3 FMU and compares what they print.
 *
 * usage: cross_host3 cs|me LIBRARY TOKEN VRS N_VALUES N_STATES STOP STEP [VR=VALUE ...]
 *   cs: Co-Simulation, fmi3DoStep from 0 to STOP with communication step STEP;
 *   me: Model Exchange, classical Runge-Kutta 4 on the N_STATES states (step STEP) through fmi3SetTime /
 *       fmi3SetContinuousStates / fmi3GetContinuousStateDerivatives and fmi3CompletedIntegratorStep;
 *   VR=VALUE: fmi3SetFloat64 before initialisation.
 * Prints one row per communication point: the time and the N_VALUES values of the value references VRS (comma-
 * separated; an array reference holds all its elements) read with one fmi3GetFloat64, each as the 16 hex digits
 * of its IEEE 754 bits.  Exits 0 when every call returned fmi3OK,
 * 1 otherwise (the failing call on stderr), 2 on bad usage. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifdef _WIN32
#include <windows.h>
#else
#include <dlfcn.h>
#endif
#include "fmi3Functions.h"

#define FUNCTIONS(X)                                                                                        \
    X(InstantiateCoSimulation) X(InstantiateModelExchange) X(FreeInstance) X(EnterInitializationMode)      \
    X(ExitInitializationMode) X(Terminate) X(GetFloat64) X(SetFloat64) X(DoStep) X(UpdateDiscreteStates)   \
    X(EnterContinuousTimeMode) X(SetTime) X(SetContinuousStates) X(GetContinuousStateDerivatives)          \
    X(CompletedIntegratorStep) X(GetContinuousStates)
#define DECLARE(name) fmi3##name##TYPE *name;
static struct { FUNCTIONS(DECLARE) } F;

#define CHECK(call)                                                            \
    do {                                                                       \
        if ((call) != fmi3OK) {                                                \
            fprintf(stderr, "failed at line %d: %s\n", __LINE__, #call);       \
            return 1;                                                          \
        }                                                                      \
    } while (0)

static struct {
    const char *mode, *library, *token;
    size_t n_vrs, n_values, n_states;
    double stop, h;
    int n_set;
    char **set;
} A;

static fmi3ValueReference *VR;
static double *VALUES;

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

static void log_message(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    (void)env; (void)category;
    if (status != fmi3OK) fprintf(stderr, "[status %d] %s\n", (int)status, message);
}

static void print_bits(double x) {
    uint64_t bits;
    memcpy(&bits, &x, sizeof bits);
    printf(" %08x%08x", (unsigned)(bits >> 32), (unsigned)(bits & 0xffffffffu));
}

static int print_row(fmi3Instance c, double t) {
    CHECK(F.GetFloat64(c, VR, A.n_vrs, VALUES, A.n_values));
    print_bits(t);
    for (size_t i = 0; i < A.n_values; i++) print_bits(VALUES[i]);
    putchar('\n');
    return 0;
}

/* the VR=VALUE settings, then initialisation */
static int initialise(fmi3Instance c) {
    for (int k = 0; k < A.n_set; k++) {
        const fmi3ValueReference vr = (fmi3ValueReference)strtoul(A.set[k], NULL, 10);
        const double value = strtod(strchr(A.set[k], '=') + 1, NULL);
        CHECK(F.SetFloat64(c, &vr, 1, &value, 1));
    }
    CHECK(F.EnterInitializationMode(c, fmi3False, 0.0, 0.0, fmi3False, 0.0));
    CHECK(F.ExitInitializationMode(c));
    return 0;
}

static int cosimulation(void) {
    const long steps = (long)(A.stop / A.h + 0.5);
    fmi3Boolean event = fmi3False, terminate = fmi3False, early = fmi3False;
    double last = 0.0;
    fmi3Instance c = F.InstantiateCoSimulation("cross_host3", A.token, "", fmi3False, fmi3False, fmi3False,
                                               fmi3False, NULL, 0, NULL, log_message, NULL);
    if (c == NULL || initialise(c) || print_row(c, 0.0)) return 1;
    for (long k = 0; k < steps; k++) {
        CHECK(F.DoStep(c, (double)k * A.h, A.h, fmi3True, &event, &terminate, &early, &last));
        if (print_row(c, (double)(k + 1) * A.h)) return 1;
    }
    CHECK(F.Terminate(c));
    F.FreeInstance(c);
    return 0;
}

/* dx = f(t, x) through the FMU */
static int derivatives(fmi3Instance c, double t, const double *x, double *dx) {
    CHECK(F.SetTime(c, t));
    CHECK(F.SetContinuousStates(c, x, A.n_states));
    CHECK(F.GetContinuousStateDerivatives(c, dx, A.n_states));
    return 0;
}

static int model_exchange(void) {
    const long steps = (long)(A.stop / A.h + 0.5);
    const size_t n = A.n_states;
    double *x = calloc(6 * n, sizeof(double)), *k1 = x + n, *k2 = x + 2 * n, *k3 = x + 3 * n, *k4 = x + 4 * n,
           *y = x + 5 * n;
    fmi3Boolean update = fmi3True, terminate = fmi3False, nominals = fmi3False, values = fmi3False,
                defined = fmi3False, enter = fmi3False;
    double next = 0.0;
    fmi3Instance c = F.InstantiateModelExchange("cross_host3", A.token, "", fmi3False, fmi3False, NULL, log_message);
    if (c == NULL || initialise(c)) return 1;
    while (update) CHECK(F.UpdateDiscreteStates(c, &update, &terminate, &nominals, &values, &defined, &next));
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
        CHECK(F.CompletedIntegratorStep(c, fmi3True, &enter, &terminate));
        if (print_row(c, (double)(k + 1) * h)) return 1;
    }
    CHECK(F.Terminate(c));
    F.FreeInstance(c);
    free(x);
    return 0;
}

#define LOAD(name)                                                                       \
    if ((F.name = (fmi3##name##TYPE *)symbol(A.library, "fmi3" #name)) == NULL) {        \
        fprintf(stderr, "cannot load fmi3" #name " from %s\n", A.library);               \
        return 2;                                                                        \
    }

int main(int argc, char **argv) {
    const char *list;
    char *end;
    if (argc < 9 || (strcmp(argv[1], "cs") != 0 && strcmp(argv[1], "me") != 0)) {
        fprintf(stderr, "usage: %s cs|me LIBRARY TOKEN VRS N_VALUES N_STATES STOP STEP [VR=VALUE ...]\n", argv[0]);
        return 2;
    }
    A.mode = argv[1]; A.library = argv[2]; A.token = argv[3];
    list = argv[4];
    A.n_values = (size_t)atol(argv[5]); A.n_states = (size_t)atol(argv[6]);
    A.stop = atof(argv[7]); A.h = atof(argv[8]);
    A.set = argv + 9;
    A.n_set = argc - 9;
    for (int k = 0; k < A.n_set; k++) {
        if (strchr(A.set[k], '=') == NULL) { fprintf(stderr, "not VR=VALUE: %s\n", A.set[k]); return 2; }
    }
    FUNCTIONS(LOAD)
    VR = malloc((strlen(list) + 1) * sizeof *VR);      /* at most one reference per character */
    VALUES = malloc((A.n_values > 0 ? A.n_values : 1) * sizeof *VALUES);
    for (A.n_vrs = 0; *list != '\0'; A.n_vrs++) {
        VR[A.n_vrs] = (fmi3ValueReference)strtoul(list, &end, 10);
        if (end == list || (*end != ',' && *end != '\0')) { fprintf(stderr, "VRS: not a list: %s\n", argv[4]); return 2; }
        list = *end == ',' ? end + 1 : end;
    }
    const int status = strcmp(A.mode, "cs") == 0 ? cosimulation() : model_exchange();
    fflush(stdout);
    free(VR);
    free(VALUES);
    return status;
}
