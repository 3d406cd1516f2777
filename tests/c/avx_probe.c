/* avx_probe.c -- a generated unit against its AVX twin (fmu_src/avx.h), compiled with an FMU's sources by
 * tests/test_avx_units.py with -DUNIT=<the unit's name>.
 * argv[1]: the number of random argument sets.  Each input of the unit gets values uniform in (-1, 1), times 10
 * for the third (a residual's accelerations), and in (0.5, 2) for the last (the parameters: densities and
 * stiffnesses stay positive).  stdout: "values V differ D nonfinite N": of the V result values compared, D
 * differ from the unit's in any bit and N are not finite. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define CAT(a, b) a##b
#define JOIN(a, b) CAT(a, b)
typedef long long int casadi_int;
int UNIT(const double **arg, double **res, casadi_int *iw, double *w, int mem);
int JOIN(UNIT, _avx)(const double **arg, double **res, casadi_int *iw, double *w, int mem);
int JOIN(UNIT, _work)(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w);
casadi_int JOIN(UNIT, _n_in)(void);
casadi_int JOIN(UNIT, _n_out)(void);
const casadi_int *JOIN(UNIT, _sparsity_in)(casadi_int i);
const casadi_int *JOIN(UNIT, _sparsity_out)(casadi_int i);

static unsigned long long state = 88172645463325252ULL;
static double uniform(double lo, double hi) {           /* xorshift64 */
    state ^= state << 13, state ^= state >> 7, state ^= state << 17;
    return lo + (hi - lo) * (double)(state >> 11) / 9007199254740992.0;
}

/* CasADi's compact sparsity: {nrow, ncol, 1} for a dense pattern, else {nrow, ncol, colind[0] = 0, ...} */
static casadi_int nonzeros(const casadi_int *sp) { return sp[2] == 1 ? sp[0] * sp[1] : sp[2 + sp[1]]; }

int main(int argc, char **argv) {
    const long sets = argc > 1 ? atol(argv[1]) : 1000;
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    JOIN(UNIT, _work)(&sz_arg, &sz_res, &sz_iw, &sz_w);
    const casadi_int n_in = JOIN(UNIT, _n_in)(), n_out = JOIN(UNIT, _n_out)();
    const double **arg = calloc((size_t)sz_arg + 1, sizeof *arg);
    double **res = calloc((size_t)sz_res + 1, sizeof *res), **res_avx = calloc((size_t)sz_res + 1, sizeof *res);
    casadi_int *iw = calloc((size_t)sz_iw + 1, sizeof *iw);
    double *w = calloc((size_t)sz_w + 1, sizeof *w);
    double *in[16], *out[16], *out_avx[16];
    if (n_in > 16 || n_out > 16) return 2;
    for (casadi_int i = 0; i < n_in; i++) in[i] = calloc((size_t)nonzeros(JOIN(UNIT, _sparsity_in)(i)) + 1, 8);
    for (casadi_int i = 0; i < n_out; i++) {
        const size_t n = (size_t)nonzeros(JOIN(UNIT, _sparsity_out)(i)) + 1;
        out[i] = calloc(n, 8), out_avx[i] = calloc(n, 8);
    }
    long values = 0, differ = 0, nonfinite = 0;
    for (long k = 0; k < sets; k++) {
        for (casadi_int i = 0; i < n_in; i++) {
            const casadi_int n = nonzeros(JOIN(UNIT, _sparsity_in)(i));
            for (casadi_int j = 0; j < n; j++)
                in[i][j] = i == n_in - 1 ? uniform(0.5, 2.0) : (i == 2 ? 10.0 : 1.0) * uniform(-1.0, 1.0);
            arg[i] = in[i];
        }
        for (casadi_int i = 0; i < n_out; i++) res[i] = out[i], res_avx[i] = out_avx[i];
        if (UNIT(arg, res, iw, w, 0) || JOIN(UNIT, _avx)(arg, res_avx, iw, w, 0)) return 1;
        for (casadi_int i = 0; i < n_out; i++) {
            const casadi_int n = nonzeros(JOIN(UNIT, _sparsity_out)(i));
            for (casadi_int j = 0; j < n; j++) {
                values++;
                differ += memcmp(&out[i][j], &out_avx[i][j], sizeof(double)) != 0;
                nonfinite += !isfinite(out[i][j]);
            }
        }
    }
    printf("values %ld differ %ld nonfinite %ld\n", values, differ, nonfinite);
    return 0;
}
