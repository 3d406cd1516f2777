/* linalg.h -- dense LU with partial pivoting for the small systems of an implicit step.
 * Column-major storage, as the generated CasADi code writes its matrices. */
#ifndef FLEXLINK_LINALG_H
#define FLEXLINK_LINALG_H

/* Factorise the n x n matrix A in place (A = P L U); returns 0, or k+1 if pivot k is zero. */
int lu_factor(double *A, int n, int *piv);

/* Solve A x = b with the factors of lu_factor; b is overwritten by x. */
void lu_solve(const double *LU, int n, const int *piv, double *b);

/* Cholesky factorisation A = L Lᵀ in place (lower triangle) of a symmetric n x n matrix; returns 0 if
 * A is positive definite, else k+1 for the first pivot k that is not > tiny * A_kk (or not finite). */
int cholesky_factor(double *A, int n, double tiny);

#endif
