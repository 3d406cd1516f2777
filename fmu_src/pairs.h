/* pairs.h -- the generic C's updates of long runs of doubles (the LU's columns, the recurrence's products), two
 * doubles at a time where GCC or clang targets SSE2 or NEON (their vector extensions), one at a time elsewhere.
 *
 * gcc 12 at -O2 vectorises only loops it needs no remainder loop for: a column of 33 coordinates, or the rows
 * below a pivot, stay scalar.  Each entry gets the same operations in the same order as the scalar loop (a
 * product, then a subtraction), so a build gives the same bits as the scalar loops would: only entries side by
 * side share an instruction.  (gcc in ISO C mode, the FMU's builds, never fuses them into a multiply-add; clang
 * may where the target has FMA, in both forms alike.)  An independent review compared them with the scalar
 * loops on 20 000 random systems of 1 to 40 unknowns under gcc and clang, -O2 and -O3: identical.  Measured
 * (benchmarks/step_floor.py, the 32-mode link): lu_solve of 33 unknowns 0.72 -> 0.54 us. */
#ifndef FLEXLINK_PAIRS_H
#define FLEXLINK_PAIRS_H

#include <stddef.h>

#if (defined(__GNUC__) || defined(__clang__)) && (defined(__SSE2__) || defined(__ARM_NEON) || defined(__aarch64__))
#define FLEXLINK_LINALG_PAIRS 1
typedef double linalg_pair __attribute__((vector_size(16)));
static inline linalg_pair linalg_load_pair(const double *p) {
    linalg_pair v;
    __builtin_memcpy(&v, p, sizeof v);
    return v;
}
static inline void linalg_store_pair(double *p, linalg_pair v) { __builtin_memcpy(p, &v, sizeof v); }
#else
#define FLEXLINK_LINALG_PAIRS 0
#endif

/* y[i] -= x[i] * a for i < n */
static inline void linalg_subtract_scaled(double *y, const double *x, double a, int n) {
    int i = 0;
#if FLEXLINK_LINALG_PAIRS
    const linalg_pair a2 = {a, a};
    for (; i + 2 <= n; i += 2) linalg_store_pair(y + i, linalg_load_pair(y + i) - linalg_load_pair(x + i) * a2);
#endif
    for (; i < n; i++) y[i] -= x[i] * a;
}

/* y[i] -= sum_j (A[i + j n] x[j] + B[i + j n] z[j]) over the n columns of A and B (column-major; B may be NULL):
 * a matrix-vector product in the bits of the column updates it replaced in the recurrence's prediction, one
 * column after the other (each entry's terms in the order of j, the two products added before they are
 * subtracted; the column update of y[i] -= x[i] a + z[i] b was removed with its last caller), with eight entries
 * carried in registers across the columns.  The column updates load and store y at every column: on the
 * 32-mode link's 33 x 33 matrices the recurrence's two products took 0.32 us by columns and 0.26 us so, and
 * the kept inverse's product (predictor.c) 0.14 us against lu_solve's 0.53 (a micro-benchmark of 2026-11-29). */
static inline void linalg_subtract_products(double *y, const double *A, const double *x, const double *B,
                                            const double *z, int n) {
    int i = 0;
#if FLEXLINK_LINALG_PAIRS
    for (; i + 8 <= n; i += 8) {
        linalg_pair y0 = linalg_load_pair(y + i), y1 = linalg_load_pair(y + i + 2);
        linalg_pair y2 = linalg_load_pair(y + i + 4), y3 = linalg_load_pair(y + i + 6);
        if (B != NULL) {                /* (two loops: the test is not made at every column) */
            for (int j = 0; j < n; j++) {
                const double *a = A + (size_t)j * n + i, *b = B + (size_t)j * n + i;
                const linalg_pair xj = {x[j], x[j]}, zj = {z[j], z[j]};
                y0 -= linalg_load_pair(a) * xj + linalg_load_pair(b) * zj;
                y1 -= linalg_load_pair(a + 2) * xj + linalg_load_pair(b + 2) * zj;
                y2 -= linalg_load_pair(a + 4) * xj + linalg_load_pair(b + 4) * zj;
                y3 -= linalg_load_pair(a + 6) * xj + linalg_load_pair(b + 6) * zj;
            }
        } else {
            for (int j = 0; j < n; j++) {
                const double *a = A + (size_t)j * n + i;
                const linalg_pair xj = {x[j], x[j]};
                y0 -= linalg_load_pair(a) * xj;
                y1 -= linalg_load_pair(a + 2) * xj;
                y2 -= linalg_load_pair(a + 4) * xj;
                y3 -= linalg_load_pair(a + 6) * xj;
            }
        }
        linalg_store_pair(y + i, y0);
        linalg_store_pair(y + i + 2, y1);
        linalg_store_pair(y + i + 4, y2);
        linalg_store_pair(y + i + 6, y3);
    }
#endif
    for (; i < n; i++) {                /* the same statements as the column updates (a compiler that
                                           contracts one contracts the other alike) */
        double s = y[i];
        if (B != NULL) {
            for (int j = 0; j < n; j++) s -= A[(size_t)j * n + i] * x[j] + B[(size_t)j * n + i] * z[j];
        } else {
            for (int j = 0; j < n; j++) s -= A[(size_t)j * n + i] * x[j];
        }
        y[i] = s;
    }
}

#endif
