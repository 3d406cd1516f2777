/* Prints the SS22 trajectory of a linked model (q, v, alpha per step) for tests/test_ss22.py.
 * usage: ss22_table DT STEPS THETA1 THETA2 */
#include <stdio.h>
#include <stdlib.h>
#include "ss22.h"

int main(int argc, char **argv) {
    if (argc != 5) { fprintf(stderr, "usage: %s DT STEPS THETA1 THETA2\n", argv[0]); return 2; }
    double dt = atof(argv[1]);
    int steps = atoi(argv[2]);
    static SS22 s;
    static ModelWork work;
    ss22_init(&s, atof(argv[3]), atof(argv[4]), 1e-12);
    double q[N_Q] = {0}, v[N_Q] = {0}, alpha[N_Q] = {0};
    double u[N_U] = {1.0, 2.0}, p[N_P] = {1.0};
    for (int i = 1; i <= steps; i++) {
        SS22Status st = ss22_step(&s, dt, q, v, alpha, u, u, p, &work);
        if (st != SS22_OK) { fprintf(stderr, "%s\n", ss22_status_message(st)); return 1; }
        printf("%.17g", i * dt);
        for (int k = 0; k < N_Q; k++) printf(" %.17g %.17g %.17g", q[k], v[k], alpha[k]);
        printf("\n");
    }
    printf("# factorisations %lu\n", (unsigned long)s.factorisations);
    return 0;
}
