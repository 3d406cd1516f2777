/* step_floor.c -- cost of one SS22 internal step against its floor, in one process (issue 6).
 *
 * Compiled by benchmarks/step_floor.py together with the C sources of an FMU (its sources/ folder:
 * the generated model and the generic fmu_src), so the FMU's own code is timed, not a copy of it.
 *
 *   floor  = one evaluation of the generated residual (forces, M a + h) and of the generated Newton
 *            matrix (mass matrix plus step terms) and one dense LU of the same size, at a state of the run;
 *   step   = the run through fmi2DoStep (one call per input segment, so no host loop is charged) divided
 *            by the number of internal SS22 steps it took, from the integrator's own counters.
 *
 * usage: step_floor GUID REPEATS TOKENS...
 *   set VR VALUE          fmi2SetReal before initialisation (solver.step, solver.order, ...)
 *   seg UNTIL VR VALUE    hold input VR at VALUE until time UNTIL (segments in order, from t = 0);
 *                         VR "-": no input (an FMU driven by its built-in laws)
 *   host H                the host steps: every segment is walked in fmi2DoStep calls of H (equal pieces,
 *                         as a host stepping at H), each followed by fmi2GetReal of the `out` variables
 *   out VR                an output the host reads after every step (repeatable)
 * Prints one JSON object: medians over REPEATS of CPU seconds, counters of one run, and the parts of
 * the floor timed separately.  Exit 0 on success. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <math.h>
#include <string.h>
#include <time.h>
#include "cosimulation.h"
#include "linalg.h"
#include "driver_util.h"

#define MAX_TOKENS 64
#define MAX_OUTPUTS 4096

#define NO_INPUT 0xffffffffu   /* a segment that sets no input */
typedef struct { int n_set, n_seg; unsigned set_vr[MAX_TOKENS]; double set_val[MAX_TOKENS];
                 double until[MAX_TOKENS]; unsigned seg_vr[MAX_TOKENS]; double seg_val[MAX_TOKENS];
                 double host; int n_out; unsigned out_vr[MAX_OUTPUTS]; long communication_steps; } Plan;

typedef struct { unsigned long steps, newton_iterations, factorisations, residual_evaluations, mass_refreshes,
                 mass_iterations, recurrences, mass_updates; } Counters;

/* one segment from t to until: one fmi2DoStep, or the host's equal steps of at most plan->host */
static void walk(fmi2Component c, Plan *plan, double t, double until) {
    const long n = plan->host > 0.0 ? (long)ceil((until - t) / plan->host - 1e-9) : 1;
    static double y[MAX_OUTPUTS];
    for (long k = 0; k < n; k++) {
        const double t0 = t + (until - t) * (double)k / (double)n, t1 = t + (until - t) * (double)(k + 1) / (double)n;
        if (fmi2DoStep(c, t0, t1 - t0, fmi2True) != fmi2OK) { fprintf(stderr, "doStep failed\n"); exit(1); }
        if (plan->n_out > 0 && fmi2GetReal(c, plan->out_vr, (size_t)plan->n_out, y) != fmi2OK) {
            fprintf(stderr, "getReal failed\n");
            exit(1);
        }
    }
    plan->communication_steps += n;
}

/* one run of the plan from a reset instance; returns CPU seconds of the doStep calls, fills counters */
static double run(fmi2Component c, Plan *plan, Counters *cnt) {
    Instance *inst = (Instance *)c;
    if (fmi2Reset(c) != fmi2OK) { fprintf(stderr, "reset failed\n"); exit(1); }
    for (int k = 0; k < plan->n_set; k++) {
        if (fmi2SetReal(c, &plan->set_vr[k], 1, &plan->set_val[k]) != fmi2OK) { fprintf(stderr, "set\n"); exit(1); }
    }
    if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
        fmi2EnterInitializationMode(c) != fmi2OK || fmi2ExitInitializationMode(c) != fmi2OK) {
        fprintf(stderr, "initialisation failed\n");
        exit(1);
    }
    const SS22 before = inst->d.ss22;
    plan->communication_steps = 0;
    const uint64_t refreshes = inst->d.mass_refreshes, iterations = inst->d.mass_iterations;
    double t = 0.0, cpu = 0.0;
    for (int k = 0; k < plan->n_seg; k++) {
        if (plan->seg_vr[k] != NO_INPUT) fmi2SetReal(c, &plan->seg_vr[k], 1, &plan->seg_val[k]);
        const double t0 = now(CLOCK_PROCESS_CPUTIME_ID);
        walk(c, plan, t, plan->until[k]);
        cpu += now(CLOCK_PROCESS_CPUTIME_ID) - t0;
        t = plan->until[k];
    }
    const SS22 *s = &inst->d.ss22;
    cnt->steps = s->steps - before.steps;
    cnt->newton_iterations = s->newton_iterations - before.newton_iterations;
    cnt->factorisations = s->factorisations - before.factorisations;
#ifdef SS22_MASS_UPDATE     /* a mass update's LU counts (fmu_src/mass_update.c; not before 2026-11-29) */
    cnt->mass_updates = s->mass_updates - before.mass_updates;
    cnt->factorisations += cnt->mass_updates;
#endif
    cnt->residual_evaluations = s->residual_evaluations - before.residual_evaluations;
#ifdef SS22_RECURRENCE_COST     /* the recurrence start's matrices formed (fmu_src/predictor.c; not before 2026-11-28) */
    cnt->recurrences = s->recurrences - before.recurrences;
#endif
    cnt->mass_refreshes = inst->d.mass_refreshes - refreshes;
    cnt->mass_iterations = inst->d.mass_iterations - iterations;
    return cpu;
}

/* the parts of the floor, at the instance's current state, with the SS22 weights of step dt */
enum { PART_FLOOR, PART_RESIDUAL, PART_NEWTON_MATRIX, PART_LU, PART_SOLVE, PART_SS22_STEP, N_PARTS };
static const char *PART_NAMES[N_PARTS] = {"floor", "residual", "newton_matrix", "lu_factor", "lu_solve",
                                          "ss22_step_direct"};

static volatile double sink;

static double time_part(Instance *inst, int part, double dt, long iterations) {
    FmuData *d = &inst->d;
    const double th1 = d->ss22.theta1, th2 = d->ss22.theta2;
    const double cv = th1 * dt, cq = th2 * 0.5 * dt * dt;
    double qb[N_Q], vb[N_Q], a[N_Q], r[N_Q], J[N_Q * N_Q], LU[N_Q * N_Q], b[N_Q];
    int piv[N_Q];
    double u[FMU_SZ(N_U)];
    memcpy(u, d->u, sizeof(u));
    memcpy(a, d->alpha, sizeof(a));
    for (int i = 0; i < N_Q; i++) { qb[i] = d->q[i] + cv * d->v[i] + cq * a[i]; vb[i] = d->v[i] + cv * a[i]; }
    model_newton_matrix(qb, vb, a, u, d->p, 1.0, cv, cq, LU, &inst->work);
    lu_factor(LU, N_Q, piv);
    SS22 s = d->ss22;                     /* a private copy: the instance is not advanced */
    double q[N_Q], v[N_Q], al[N_Q];
    double t0 = now(CLOCK_PROCESS_CPUTIME_ID);
    for (long it = 0; it < iterations; it++) {
        switch (part) {
        case PART_FLOOR:
            model_residual(qb, vb, a, u, d->p, r, &inst->work);
            model_newton_matrix(qb, vb, a, u, d->p, 1.0, cv, cq, J, &inst->work);
            lu_factor(J, N_Q, piv);
            sink += r[0] + J[0];
            break;
        case PART_RESIDUAL:
            model_residual(qb, vb, a, u, d->p, r, &inst->work);
            sink += r[0];
            break;
        case PART_NEWTON_MATRIX:
            model_newton_matrix(qb, vb, a, u, d->p, 1.0, cv, cq, J, &inst->work);
            sink += J[0];
            break;
        case PART_LU:
            memcpy(J, LU, sizeof(J));      /* a factorisable matrix each time (the copy is charged: n^2 moves) */
            lu_factor(J, N_Q, piv);
            sink += J[0];
            break;
        case PART_SOLVE:
            memcpy(b, r, sizeof(b));
            lu_solve(LU, N_Q, piv, b);
            sink += b[0];
            break;
        case PART_SS22_STEP:
            memcpy(q, d->q, sizeof(q));
            memcpy(v, d->v, sizeof(v));
            memcpy(al, d->alpha, sizeof(al));
            ss22_step(&s, dt, q, v, al, u, u, d->p, &inst->work);
            sink += q[0];
            break;
        }
    }
    return (now(CLOCK_PROCESS_CPUTIME_ID) - t0) / (double)iterations;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s GUID REPEATS [set VR VALUE | seg UNTIL VR VALUE]...\n", argv[0]);
        return 2;
    }
    const int repeats = atoi(argv[2]);
    if (repeats < 1 || repeats > 1000) { fprintf(stderr, "REPEATS: 1..1000\n"); return 2; }
    Plan plan = {0};
    for (int k = 3; k < argc;) {
        if (!strcmp(argv[k], "set") && k + 2 < argc && plan.n_set < MAX_TOKENS) {
            plan.set_vr[plan.n_set] = (unsigned)atol(argv[k + 1]);
            plan.set_val[plan.n_set++] = atof(argv[k + 2]);
            k += 3;
        } else if (!strcmp(argv[k], "seg") && k + 3 < argc && plan.n_seg < MAX_TOKENS) {
            plan.until[plan.n_seg] = atof(argv[k + 1]);
            plan.seg_vr[plan.n_seg] = strcmp(argv[k + 2], "-") ? (unsigned)atol(argv[k + 2]) : NO_INPUT;
            plan.seg_val[plan.n_seg++] = atof(argv[k + 3]);
            k += 4;
        } else if (!strcmp(argv[k], "host") && k + 1 < argc) {
            plan.host = atof(argv[k + 1]);
            k += 2;
        } else if (!strcmp(argv[k], "out") && k + 1 < argc && plan.n_out < MAX_OUTPUTS) {
            plan.out_vr[plan.n_out++] = (unsigned)atol(argv[k + 1]);
            k += 2;
        } else {
            fprintf(stderr, "bad argument %s\n", argv[k]);
            return 2;
        }
    }
    if (plan.n_seg == 0) { fprintf(stderr, "no segment\n"); return 2; }
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("floor", fmi2CoSimulation, argv[1], "", &cb, fmi2False, fmi2False);
    if (!c) { fprintf(stderr, "instantiate failed\n"); return 1; }
    Instance *inst = (Instance *)c;

    Counters cnt = {0};
    double *runs = malloc((size_t)repeats * sizeof(double));
    run(c, &plan, &cnt);                                   /* warm-up */
    for (int k = 0; k < repeats; k++) runs[k] = run(c, &plan, &cnt);
    const double run_cpu = median(runs, repeats);
    const int order = (int)inst->d.solver[SOLVER_ORDER];
    const double internal = order == 4 ? (double)cnt.steps / 3.0 : (double)cnt.steps;   /* 3 SS22 steps each */
    const double dt = plan.until[plan.n_seg - 1] / (internal > 0 ? internal : 1.0);

    /* the parts, at the end state of the last run; batches of about 5 ms, median over repeats */
    double part_s[N_PARTS];
    for (int p = 0; p < N_PARTS; p++) {
        long iterations = 16;
        while (time_part(inst, p, dt, iterations) * (double)iterations < 5e-3 && iterations < (1L << 26))
            iterations *= 2;
        for (int k = 0; k < repeats; k++) runs[k] = time_part(inst, p, dt, iterations);
        part_s[p] = median(runs, repeats);
    }
    printf("{\"n_q\": %d, \"linear_in_state\": %d, \"jacobian_constant\": %d, \"order\": %d, \"repeats\": %d, "
           "\"run_cpu_s\": %.9g, \"simulated_s\": %.9g, \"ss22_steps\": %lu, \"internal_steps\": %.9g, "
           "\"newton_iterations\": %lu, \"factorisations\": %lu, \"residual_evaluations\": %lu, "
           "\"step_s\": %.9g, \"ss22_step_s\": %.9g, \"communication_steps\": %ld, "
           "\"mass_refreshes\": %lu, \"mass_iterations\": %lu, \"recurrences\": %lu, \"mass_updates\": %lu",
           N_Q, MODEL_LINEAR_IN_STATE, MODEL_JACOBIAN_CONSTANT, order, repeats, run_cpu,
           plan.until[plan.n_seg - 1], cnt.steps, internal, cnt.newton_iterations, cnt.factorisations,
           cnt.residual_evaluations, run_cpu / internal, run_cpu / (double)(cnt.steps ? cnt.steps : 1),
           plan.communication_steps, cnt.mass_refreshes, cnt.mass_iterations, cnt.recurrences, cnt.mass_updates);
    for (int p = 0; p < N_PARTS; p++) printf(", \"%s_s\": %.9g", PART_NAMES[p], part_s[p]);
    printf("}\n");
    free(runs);
    fmi2FreeInstance(c);
    return 0;
}
