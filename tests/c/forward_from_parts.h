/* forward_from_parts.h -- model.h's model_forward and model_outputs_acceleration_forward for the
 * hand-written test models, from their own residual_forward and outputs_forward in a full direction
 * (static functions the including model.c defines before it includes this file). */
#ifndef TESTS_FORWARD_FROM_PARTS_H
#define TESTS_FORWARD_FROM_PARTS_H
int model_forward(const double *q, const double *v, const double *a, const double *u, const double *p,
                  const double *dq, const double *dv, const double *da, const double *du, const double *dp,
                  double *dr, double *dy, ModelWork *work) {
    return residual_forward(q, v, a, u, p, dq, dv, da, du, dp, dr, work) ||
           outputs_forward(q, v, a, u, p, dq, dv, da, du, dp, dy, work);
}

int model_outputs_acceleration_forward(const double *q, const double *v, const double *a, const double *u,
                                       const double *p, const double *da, double *dy, ModelWork *work) {
    static const double zero[N_Q + N_U + N_P + 1] = {0};    /* long enough for any seed */
    return outputs_forward(q, v, a, u, p, zero, zero, da, zero, zero, dy, work);
}
#endif
