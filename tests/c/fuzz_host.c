/* Parameter and step fuzz of a flexlink FMU library (issue 21; tests/test_fmu_fuzz.py builds it with ASan/UBSan):
 * CASES runs, each from fmi2Reset with random start values of parameters and solver settings, then random
 * communication steps and inputs.  Values are drawn around each variable's start value and, one time in
 * four, from the out-of-range set (NaN, ±inf, negative, subnormal, 1e300, 0).  Checked:
 *   - every call returns within BOUND seconds of wall-clock time;
 *   - fmi2OK from fmi2DoStep implies every output finite and the kinetic energy >= 0;
 *   - a refusal (fmi2Error, fmi2Discard) leaves the instance usable: fmi2Reset answers fmi2OK.
 *
 * usage: fuzz_host LIBRARY GUID KINDS CASES SEED BOUND
 *   KINDS: one character per value reference: p parameter or solver setting (set before initialisation),
 *          i input, o output, k the kinetic-energy output, - anything else; START values follow as
 *          further arguments, one per value reference.
 * Prints counts of what happened; exit 0 if no check failed, 1 otherwise (the failing case on stderr). */
#define _POSIX_C_SOURCE 199309L
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env; (void)name; (void)status; (void)category; (void)message;
}

static unsigned long long rng_state;
static double uniform(void) {                 /* xorshift64*: reproducible from SEED */
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (double)((rng_state * 2685821657736338717ULL) >> 11) / 9007199254740992.0;
}

static double wall(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* around x (a factor 10^±1, sign kept) or, one time in four, a value out of every range */
static double fuzz_value(double x) {
    static const double special[] = {NAN, INFINITY, -INFINITY, -1.0, 5e-324, -5e-324, 1e300, -1e300, 0.0, -0.0};
    if (uniform() < 0.25) return special[(int)(uniform() * 10) % 10];
    const double scale = pow(10.0, 2.0 * uniform() - 1.0);
    return x == 0.0 ? scale - 1.0 : x * scale;
}

static double bound_s;
static int failed;
static double t_call;
#define TIMED(call) (t_call = wall(), timed_status((call), #call))
static fmi2Status timed_status(fmi2Status s, const char *what) {
    const double dt = wall() - t_call;
    if (dt > bound_s) {
        fprintf(stderr, "%s took %.3g s (bound %g s)\n", what, dt, bound_s);
        failed = 1;
    }
    return s;
}

int main(int argc, char **argv) {
    if (argc < 7) { fprintf(stderr, "usage: fuzz_host LIBRARY GUID KINDS CASES SEED BOUND START...\n"); return 2; }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
    const char *kinds = argv[3];
    const size_t n = strlen(kinds);
    const long cases = atol(argv[4]);
    rng_state = 0x9E3779B97F4A7C15ULL ^ (unsigned long long)atol(argv[5]);
    bound_s = atof(argv[6]);
    if ((size_t)argc != 7 + n) { fprintf(stderr, "one start value per variable\n"); return 2; }
    double *start = calloc(n, sizeof(double)), *values = calloc(n, sizeof(double));
    fmi2ValueReference *outs = calloc(n, sizeof(fmi2ValueReference));
    size_t n_out = 0, kinetic = (size_t)-1;
    for (size_t i = 0; i < n; i++) {
        start[i] = atof(argv[7 + i]);
        if (kinds[i] == 'o' || kinds[i] == 'k') {
            if (kinds[i] == 'k') kinetic = n_out;
            outs[n_out++] = (fmi2ValueReference)i;
        }
    }
#define LOAD(name) fmi2##name##TYPE *name = (fmi2##name##TYPE *)dlsym(lib, "fmi2" #name); \
    if (!name) { fprintf(stderr, "missing fmi2" #name "\n"); return 2; }
    LOAD(Instantiate) LOAD(FreeInstance) LOAD(Reset) LOAD(SetupExperiment) LOAD(EnterInitializationMode)
    LOAD(ExitInitializationMode) LOAD(DoStep) LOAD(SetReal) LOAD(GetReal) LOAD(Terminate)
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = Instantiate("fuzz", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
    if (!c) { fprintf(stderr, "fmi2Instantiate failed\n"); return 2; }
    long refused_init = 0, steps_ok = 0, steps_refused = 0, runs = 0;
    for (long k = 0; k < cases && !failed; k++) {
        if (TIMED(Reset(c)) != fmi2OK) { fprintf(stderr, "case %ld: fmi2Reset failed\n", k); failed = 1; break; }
        for (size_t i = 0; i < n; i++) {
            if (kinds[i] == 'p' && uniform() < 0.3) {
                const fmi2ValueReference vr = (fmi2ValueReference)i;
                const double x = fuzz_value(start[i]);
                TIMED(SetReal(c, &vr, 1, &x));          /* a refused value changes nothing */
            }
        }
        if (TIMED(SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0)) != fmi2OK ||
            TIMED(EnterInitializationMode(c)) != fmi2OK || TIMED(ExitInitializationMode(c)) > fmi2Warning) {
            refused_init++;
            continue;
        }
        runs++;
        double t = 0.0;
        for (int s = 0; s < 20 && !failed; s++) {
            for (size_t i = 0; i < n; i++) {
                if (kinds[i] == 'i' && uniform() < 0.3) {
                    const fmi2ValueReference vr = (fmi2ValueReference)i;
                    const double x = fuzz_value(start[i] == 0.0 ? 1.0 : start[i]);
                    TIMED(SetReal(c, &vr, 1, &x));
                }
            }
            const double h = uniform() < 0.1 ? fuzz_value(0.01) : pow(10.0, -4.0 + 2.5 * uniform());
            const fmi2Status st = TIMED(DoStep(c, t, h, fmi2True));
            if (st == fmi2OK) {
                steps_ok++;
                t += h;
                if (TIMED(GetReal(c, outs, n_out, values)) > fmi2Warning) {
                    fprintf(stderr, "case %ld: fmi2GetReal failed after fmi2OK\n", k);
                    failed = 1;
                }
                for (size_t j = 0; j < n_out && !failed; j++) {
                    if (!isfinite(values[j]) || (j == kinetic && values[j] < -1e-9 * fabs(values[j]))) {
                        fprintf(stderr, "case %ld (seed %s): fmi2OK at t = %g with output vr %u = %g\n", k, argv[5],
                                t, outs[j], values[j]);
                        failed = 1;
                    }
                }
            } else {
                steps_refused++;
                break;                                    /* refused: the next case starts from fmi2Reset */
            }
        }
    }
    if (!failed) TIMED(Terminate(c));
    FreeInstance(c);
    printf("cases %ld runs %ld refused_at_initialisation %ld steps_ok %ld steps_refused %ld\n", cases, runs,
           refused_init, steps_ok, steps_refused);
    free(start);
    free(values);
    free(outs);
    dlclose(lib);
    return failed;
}
