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

/* y[i] -= x[i] * a + z[i] * b for i < n */
static inline void linalg_subtract_two_scaled(double *y, const double *x, double a, const double *z, double b,
                                              int n) {
    int i = 0;
#if FLEXLINK_LINALG_PAIRS
    const linalg_pair a2 = {a, a}, b2 = {b, b};
    for (; i + 2 <= n; i += 2)
        linalg_store_pair(y + i,
                          linalg_load_pair(y + i) - (linalg_load_pair(x + i) * a2 + linalg_load_pair(z + i) * b2));
#endif
    for (; i < n; i++) y[i] -= x[i] * a + z[i] * b;
}

#endif
