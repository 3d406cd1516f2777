/* complex_step.c -- forward (directional) derivatives of the residual and the outputs by the complex step.
 *
 * For a function f made of real-analytic operations (+, -, *, /, sin, cos, ... -- the only ones in a
 * flexlink model: flexlink.export.derivatives checks it before choosing this),
 *     f(x + i h dx) = f(x) + i h f'(x) dx + O(h^2),
 * so Im f(x + i h dx) / h is the directional derivative f'(x) dx with no difference of two values:
 * no cancellation, exact to rounding for any h small enough that the O(h^2) term is below it (Squire &
 * Trapp 1998; Martins, Sturdza & Alonso 2003).  The generated residual and outputs evaluated in
 * complex arithmetic (model_residual_complex, model_outputs_complex: the same generated code compiled
 * with casadi_real = double _Complex) therefore give what CasADi's forward mode would, without a second
 * copy of the model's code in derivative form -- on the six-axis arm that copy was half the generated C
 * (issue 15's code size).  A complex operation costs a few real ones: a derivative costs a few residuals,
 * off the Co-Simulation step (fmi2GetDirectionalDerivative, Model Exchange Jacobians, and the Newton
 * matrix's columns only where a scene asks for newton_matrix = "columns").
 *
 * The seed is scaled to a largest entry of 1 and the step is CS_STEP: the imaginary parts stay far
 * above the smallest normal double (products of two are about CS_STEP^2 = 1e-200) and the real parts
 * carry f(x) to within CS_STEP^2 relative. */
#include <math.h>
#include <string.h>
#include "model.h"

#if MODEL_HAS_COMPLEX
#include <complex.h>

#define CS_STEP 1e-100

/* The largest magnitude in a seed block (0 for an absent block); NaN if one is not finite. */
static double block_scale(const double *d, int n, double scale) {
    if (d == NULL) return scale;
    for (int i = 0; i < n; i++) {
        if (!isfinite(d[i])) return NAN;
        if (fabs(d[i]) > scale) scale = fabs(d[i]);
    }
    return scale;
}

/* x + i CS_STEP d / scale, entry by entry (d NULL: no imaginary part). */
static void perturb(double _Complex *xc, const double *x, const double *d, int n, double scale) {
    for (int i = 0; i < n; i++) xc[i] = x[i] + (d ? CS_STEP * (d[i] / scale) : 0.0) * I;
}

/* Im(fc) / CS_STEP times the seed's scale: the derivative in the unscaled direction (divided first, so that a
 * seed above 1e208 does not overflow the factor). */
static void tangent(double *out, const double _Complex *fc, int n, double scale) {
    for (int i = 0; i < n; i++) out[i] = (cimag(fc[i]) / CS_STEP) * scale;
}

int model_complex_forward(const double *q, const double *v, const double *a, const double *u, const double *p,
                          const double *dq, const double *dv, const double *da, const double *du,
                          const double *dp, double *dr, double *dy) {
    double _Complex qc[N_Q], vc[N_Q], ac[N_Q], rc[N_Q];
    double _Complex uc[N_U > 0 ? N_U : 1] = {0}, pc[N_P > 0 ? N_P : 1] = {0}, yc[N_Y > 0 ? N_Y : 1];
    double scale = 0.0;
    scale = block_scale(dq, N_Q, scale);
    scale = block_scale(dv, N_Q, scale);
    scale = block_scale(da, N_Q, scale);
    scale = block_scale(du, N_U, scale);
    scale = block_scale(dp, N_P, scale);
    if (isnan(scale)) return 1;
    if (scale == 0.0) {   /* the zero direction: the derivative is zero, and 1/scale is not */
        if (dr) memset(dr, 0, sizeof(double) * N_Q);
        if (dy && N_Y > 0) memset(dy, 0, sizeof(double) * N_Y);
        return 0;
    }
    perturb(qc, q, dq, N_Q, scale);
    perturb(vc, v, dv, N_Q, scale);
    perturb(ac, a, da, N_Q, scale);
    perturb(uc, u, du, N_U, scale);
    perturb(pc, p, dp, N_P, scale);
    if (dr) {
        if (model_residual_complex(qc, vc, ac, uc, pc, rc)) return 1;
        tangent(dr, rc, N_Q, scale);
    }
    if (dy && N_Y > 0) {
        if (model_outputs_complex(qc, vc, ac, uc, pc, yc)) return 1;
        tangent(dy, yc, N_Y, scale);
    }
    return 0;
}

#else

int model_complex_forward(const double *q, const double *v, const double *a, const double *u, const double *p,
                          const double *dq, const double *dv, const double *da, const double *du,
                          const double *dp, double *dr, double *dy) {
    (void)q; (void)v; (void)a; (void)u; (void)p; (void)dq; (void)dv; (void)da; (void)du; (void)dp;
    (void)dr; (void)dy;
    return 1;   /* no complex arithmetic, or the model's derivatives are generated code (model.c) */
}

#endif
