/* mass_probe.c -- the FMU's own Newton matrix ca M + cv dr/dv + cq dr/dq (model_newton_matrix), compiled with an
 * FMU's sources by tests/test_mass_by_differences.py.
 * stdin: ca, cv, cq, then N_Q values of q, N_Q of v, N_Q of a, N_U of u, N_P of p; stdout: the matrix column
 * by column, one value a line.  ca = 1, cv = cq = 0 and v = a = 0 give M(q). */
#include <stdio.h>
#include "model.h"

static ModelWork work;
static double q[N_Q], v[N_Q], a[N_Q], u[N_U > 0 ? N_U : 1], p[N_P > 0 ? N_P : 1], J[N_Q * N_Q];

static int read_values(double *x, int n) {
    for (int i = 0; i < n; i++)
        if (scanf("%lf", &x[i]) != 1) return 1;
    return 0;
}

int main(void) {
    double c[3];
    if (read_values(c, 3) || read_values(q, N_Q) || read_values(v, N_Q) || read_values(a, N_Q)
        || read_values(u, N_U) || read_values(p, N_P)) return 2;
    if (model_newton_matrix(q, v, a, u, p, c[0], c[1], c[2], J, &work)) return 1;
    for (int k = 0; k < N_Q * N_Q; k++) printf("%.17g\n", J[k]);
    return 0;
}
