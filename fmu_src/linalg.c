/* linalg.c -- see linalg.h.  Small and dependency-free: an FMU must not need LAPACK. */
#include <math.h>
#include "linalg.h"
#include "pairs.h"

int lu_factor(double *A, int n, int *piv) {
    for (int k = 0; k < n; k++) {
        int p = k;
        double amax = fabs(A[k + k * n]);
        for (int i = k + 1; i < n; i++) {
            double a = fabs(A[i + k * n]);
            if (a > amax) { amax = a; p = i; }
        }
        piv[k] = p;
        if (amax == 0.0 || !isfinite(amax)) return k + 1;
        if (p != k) {
            for (int j = 0; j < n; j++) {
                double t = A[k + j * n]; A[k + j * n] = A[p + j * n]; A[p + j * n] = t;
            }
        }
        double inv = 1.0 / A[k + k * n];
        for (int i = k + 1; i < n; i++) A[i + k * n] *= inv;
        for (int j = k + 1; j < n; j++) {
            double akj = A[k + j * n];
            if (akj != 0.0) linalg_subtract_scaled(A + j * n + k + 1, A + k * n + k + 1, akj, n - k - 1);
        }
    }
    return 0;
}

void lu_solve(const double *LU, int n, const int *piv, double *b) {
    for (int k = 0; k < n; k++) {
        int p = piv[k];
        if (p != k) { double t = b[k]; b[k] = b[p]; b[p] = t; }
    }
    for (int j = 0; j < n; j++) {           /* L y = P b, unit diagonal */
        double bj = b[j];
        if (bj != 0.0) linalg_subtract_scaled(b + j + 1, LU + j + 1 + j * n, bj, n - j - 1);
    }
    for (int j = n - 1; j >= 0; j--) {      /* U x = y */
        b[j] /= LU[j + j * n];
        double bj = b[j];
        if (bj != 0.0) linalg_subtract_scaled(b, LU + j * n, bj, j);
    }
}

int cholesky_factor(double *A, int n, double tiny) {
    for (int k = 0; k < n; k++) {
        const double akk = A[k + k * n];
        double d = akk;
        for (int j = 0; j < k; j++) d -= A[k + j * n] * A[k + j * n];
        if (!(d > tiny * fabs(akk)) || !isfinite(d)) return k + 1;
        const double l = sqrt(d);
        A[k + k * n] = l;
        for (int i = k + 1; i < n; i++) {
            double s = A[i + k * n];
            for (int j = 0; j < k; j++) s -= A[i + j * n] * A[k + j * n];
            A[i + k * n] = s / l;
        }
    }
    return 0;
}
