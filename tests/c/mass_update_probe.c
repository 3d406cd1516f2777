/* mass_update_probe.c -- the SS22 mass update (fmu_src/mass_update.c) on an FMU's own model, compiled with its
 * sources by tests/test_mass_update.py.
 * stdin: dt, theta1, theta2, then N_Q values of q1, N_Q of v1, N_Q of a1 (the full evaluation's weighted state),
 * N_Q of q2 (the update's), N_U of u, N_P of p, then right-hand sides of N_Q values each until the end.
 * stdout: SS22_MASS_UPDATE, then for each right-hand side b the solution x of J x = b with the updated
 * matrix's factors, one value a line. */
#include <stdio.h>
#include "mass_update.h"
#include "linalg.h"

static ModelWork work;
static SS22 s;
static double q1[N_Q], v1[N_Q], a1[N_Q], q2[N_Q], u[N_U > 0 ? N_U : 1], p[N_P > 0 ? N_P : 1], b[N_Q];

static int read_values(double *x, int n) {
    for (int i = 0; i < n; i++)
        if (scanf("%lf", &x[i]) != 1) return 1;
    return 0;
}

int main(void) {
    double h[3];
    if (read_values(h, 3) || read_values(q1, N_Q) || read_values(v1, N_Q) || read_values(a1, N_Q) ||
        read_values(q2, N_Q) || read_values(u, N_U) || read_values(p, N_P)) return 2;
    printf("%d\n", SS22_MASS_UPDATE);
    ss22_init(&s, h[1], h[2], 1e-10);
    SS22Factor *f = &s.cache[0];
    for (int i = 0; i < N_Q; i++) s.q_bar[i] = q1[i], s.v_bar[i] = v1[i];
    for (int i = 0; i < N_U; i++) s.u_bar[i] = u[i];
    const double cv = h[1] * h[0], cq = h[2] * 0.5 * h[0] * h[0];
    if (model_newton_matrix(q1, v1, a1, u, p, 1.0, cv, cq, f->LU, &work) || ss22_keep_rest(&s, f, a1, p, &work))
        return 1;
    f->valid = 1;             /* as ss22.c's step_matrix leaves a factorised entry */
    f->made = 0;
    s.steps = 5;
    for (int i = 0; i < N_Q; i++) s.q_bar[i] = q2[i];
    ss22_mass_update(&s, f, a1, p, &work);
    if (!f->valid || f->made != 5 || s.mass_updates != 1) return 1;
    while (!read_values(b, N_Q)) {
        lu_solve(f->LU, N_Q, f->piv, b);
        for (int i = 0; i < N_Q; i++) printf("%.17g\n", b[i]);
    }
    return 0;
}
