/* sample_cost.c -- what one closed-loop sample costs inside the FMU, without Python (issue 22).
 *
 * Compiled by benchmarks/closed_loop.py together with the C sources of an FMU (its sources/ folder), so the
 * FMU's own code is timed.  It replays a recorded torque sequence as the closed loop calls the FMU, per
 * sample: fmi2GetReal(outputs), fmi2SetReal(torque), fmi2DoStep(t_k, dt).  The difference to the same three
 * calls through ctypes is Python's share.
 *
 * usage: sample_cost GUID TORQUES.bin DT REPEATS VR_IN VR_OUT...
 *   TORQUES.bin  the torque of every sample, native doubles (the fast loop's recorded torque)
 * Prints one JSON object: the median over REPEATS runs (fmi2Reset and initialisation between, not timed) of
 * the time per sample of the three calls, in microseconds: the process's CPU time (what a loaded machine's
 * waits for a core do not inflate) and the wall time, both read once per run, not per call. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"
#include "driver_util.h"

#define MAX_OUT 64

static double *read_torques(const char *path, long *n) {
    FILE *f = fopen(path, "rb");
    if (f == NULL) return NULL;
    fseek(f, 0, SEEK_END);
    *n = ftell(f) / (long)sizeof(double);
    fseek(f, 0, SEEK_SET);
    double *u = malloc((size_t)(*n > 0 ? *n : 1) * sizeof(double));
    if (u != NULL && fread(u, sizeof(double), (size_t)*n, f) != (size_t)*n) { free(u); u = NULL; }
    fclose(f);
    return u;
}

int main(int argc, char **argv) {
    if (argc < 7 || argc - 6 > MAX_OUT) {
        fprintf(stderr, "usage: sample_cost GUID TORQUES.bin DT REPEATS VR_IN VR_OUT...\n");
        return 2;
    }
    long n = 0;
    double *torque = read_torques(argv[2], &n);
    const double dt = atof(argv[3]);
    const int repeats = atoi(argv[4]);
    const fmi2ValueReference vr_in = (fmi2ValueReference)strtoul(argv[5], NULL, 10);
    fmi2ValueReference vr_out[MAX_OUT];
    const int n_out = argc - 6;
    for (int i = 0; i < n_out; i++) vr_out[i] = (fmi2ValueReference)strtoul(argv[6 + i], NULL, 10);
    if (torque == NULL || n < 1 || !(dt > 0) || repeats < 1) { fprintf(stderr, "bad arguments\n"); return 2; }
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("sample_cost", fmi2CoSimulation, argv[1], "", &cb, fmi2False, fmi2False);
    if (c == NULL) { fprintf(stderr, "instantiation failed\n"); return 1; }
    double *cpu = malloc((size_t)repeats * sizeof(double)), *wall = malloc((size_t)repeats * sizeof(double));
    double y[MAX_OUT];
    for (int r = 0; r < repeats; r++) {
        if (fmi2Reset(c) > fmi2Warning || fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) > fmi2Warning ||
            fmi2EnterInitializationMode(c) > fmi2Warning || fmi2ExitInitializationMode(c) > fmi2Warning) {
            fprintf(stderr, "initialisation failed\n");
            return 1;
        }
        const double c0 = now(CLOCK_PROCESS_CPUTIME_ID), w0 = now(CLOCK_MONOTONIC);
        for (long k = 0; k < n; k++) {
            fmi2GetReal(c, vr_out, (size_t)n_out, y);
            fmi2SetReal(c, &vr_in, 1, &torque[k]);
            if (fmi2DoStep(c, (double)k * dt, dt, fmi2True) != fmi2OK) { fprintf(stderr, "doStep failed at %ld\n", k); return 1; }
        }
        cpu[r] = 1e6 * (now(CLOCK_PROCESS_CPUTIME_ID) - c0) / (double)n;
        wall[r] = 1e6 * (now(CLOCK_MONOTONIC) - w0) / (double)n;
        fmi2Terminate(c);
    }
    printf("{\"us_per_sample_cpu\": %.6g, \"us_per_sample\": %.6g, \"samples\": %ld, \"repeats\": %d}\n",
           median(cpu, repeats), median(wall, repeats), n, repeats);
    fmi2FreeInstance(c);
    free(torque);
    free(cpu);
    free(wall);
    return 0;
}
