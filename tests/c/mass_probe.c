/* mass_probe.c -- the FMU's own M(q): model_newton_matrix(q, v, a, u, p, 1, 0, 0), compiled with an FMU's
 * sources by tests/test_mass_by_differences.py.
 * stdin: N_Q values of q, N_U of u, N_P of p (v = a = 0); stdout: M column by column, one value a line. */
#include <stdio.h>
#include "model.h"

static ModelWork work;
static double q[N_Q], zero[N_Q], u[N_U > 0 ? N_U : 1], p[N_P > 0 ? N_P : 1], M[N_Q * N_Q];

static int read_values(double *x, int n) {
    for (int i = 0; i < n; i++)
        if (scanf("%lf", &x[i]) != 1) return 1;
    return 0;
}

int main(void) {
    if (read_values(q, N_Q) || read_values(u, N_U) || read_values(p, N_P)) return 2;
    if (model_newton_matrix(q, zero, zero, u, p, 1.0, 0.0, 0.0, M, &work)) return 1;
    for (int k = 0; k < N_Q * N_Q; k++) printf("%.17g\n", M[k]);
    return 0;
}
