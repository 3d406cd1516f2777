/* A generic full run of any flexlink FMU library, for valgrind and AddressSanitizer
 * (tests/test_fmu_memory.py): instantiate, initialise, step, read every variable, FMU state
 * get/set/serialize/deserialize, reset, run again, terminate, free.
 *
 * usage: fmu_run LIBRARY GUID N_VARS STOP_TIME COMM_STEP
 * Exit 0 if every call returned fmi2OK (prints the last values of all variables). */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env; (void)name; (void)category;
    if (status != fmi2OK) fprintf(stderr, "[status %d] %s\n", (int)status, message);
}

#define LOAD(name) \
    fmi2##name##TYPE *name = (fmi2##name##TYPE *)dlsym(lib, "fmi2" #name); \
    if (!name) { fprintf(stderr, "missing fmi2" #name "\n"); return 2; }
#define CHECK(call) \
    do { if ((call) != fmi2OK) { fprintf(stderr, "failed: %s\n", #call); return 1; } } while (0)

/* communication steps k0 .. k1-1 of size h (times computed as k h, as a host would) */
static int run(fmi2Component c, fmi2DoStepTYPE *DoStep, fmi2GetRealTYPE *GetReal, long k0, long k1, double h,
               fmi2ValueReference *vr, double *values, size_t n) {
    for (long k = k0; k < k1; k++) {
        if (DoStep(c, (double)k * h, h, fmi2True) != fmi2OK) return 1;
        if (GetReal(c, vr, n, values) != fmi2OK) return 1;
    }
    return 0;
}

int main(int argc, char **argv) {
    if (argc != 6) {
        fprintf(stderr, "usage: %s LIBRARY GUID N_VARS STOP_TIME COMM_STEP\n", argv[0]);
        return 2;
    }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
    const size_t n = (size_t)atol(argv[3]);
    const double stop = atof(argv[4]), h = atof(argv[5]);
    const long steps = (long)(stop / h + 0.5), half = steps / 2;
    LOAD(Instantiate) LOAD(FreeInstance) LOAD(SetupExperiment) LOAD(EnterInitializationMode)
    LOAD(ExitInitializationMode) LOAD(DoStep) LOAD(GetReal) LOAD(Terminate) LOAD(Reset)
    LOAD(GetFMUstate) LOAD(SetFMUstate) LOAD(FreeFMUstate) LOAD(SerializedFMUstateSize)
    LOAD(SerializeFMUstate) LOAD(DeSerializeFMUstate)
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2ValueReference *vr = malloc(n * sizeof(*vr));
    double *values = malloc(n * sizeof(*values)), *again = malloc(n * sizeof(*again));
    for (size_t i = 0; i < n; i++) vr[i] = (fmi2ValueReference)i;

    fmi2Component c = Instantiate("run", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
    if (!c) { fprintf(stderr, "instantiate failed\n"); return 1; }
    CHECK(SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0));
    CHECK(EnterInitializationMode(c));
    CHECK(ExitInitializationMode(c));
    CHECK(GetReal(c, vr, n, values));
    if (run(c, DoStep, GetReal, 0, half, h, vr, values, n)) return 1;

    /* FMU state: take, serialize, run on, restore from the serialized copy, run on again: equal */
    fmi2FMUstate state = NULL, restored = NULL;
    size_t size = 0;
    CHECK(GetFMUstate(c, &state));
    CHECK(SerializedFMUstateSize(c, state, &size));
    fmi2Byte *bytes = malloc(size);
    CHECK(SerializeFMUstate(c, state, bytes, size));
    if (run(c, DoStep, GetReal, half, steps, h, vr, values, n)) return 1;
    CHECK(DeSerializeFMUstate(c, bytes, size, &restored));
    CHECK(SetFMUstate(c, restored));
    if (run(c, DoStep, GetReal, half, steps, h, vr, again, n)) return 1;
    if (memcmp(values, again, n * sizeof(double)) != 0) { fprintf(stderr, "state restore differs\n"); return 1; }
    CHECK(FreeFMUstate(c, &state));
    CHECK(FreeFMUstate(c, &restored));

    /* states a careless importer never frees: fmi2FreeInstance must free them (valgrind and LeakSanitizer
     * report the leak otherwise), and freeing one of the others in between keeps the owner's list whole */
    fmi2FMUstate forgotten[3] = {NULL, NULL, NULL};
    CHECK(GetFMUstate(c, &forgotten[0]));
    CHECK(DeSerializeFMUstate(c, bytes, size, &forgotten[1]));
    CHECK(GetFMUstate(c, &forgotten[2]));
    CHECK(FreeFMUstate(c, &forgotten[1]));
    free(bytes);

    /* reset and a second full run */
    CHECK(Reset(c));
    CHECK(SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0));
    CHECK(EnterInitializationMode(c));
    CHECK(ExitInitializationMode(c));
    if (run(c, DoStep, GetReal, 0, steps, h, vr, values, n)) return 1;
    CHECK(Terminate(c));
    FreeInstance(c);
    for (size_t i = 0; i < n; i++) printf("%zu %.17g\n", i, values[i]);
    free(vr); free(values); free(again);
    return 0;
}
