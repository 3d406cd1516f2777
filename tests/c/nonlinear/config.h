/* A hand-written nonlinear test model for the generic C half (tests/c/host.c, tests/test_fmu_glue.py).
 * Two masses m, each hanging from a support that moves along a kinematic law:
 *   m a0 + c (v0 - xd0) + k d0 + k3 d0^3 + m g = F,   d0 = q0 - x0   (x0: built-in law 0, hardening spring)
 *   m a1 + c (v1 - xd1) + k d1 = 0,                  d1 = q1 - x1   (x1: law 1, driven by the host)
 * q0 starts in static equilibrium (N_STATIC = 1), q1 at its start value.
 * Two parameters exist only to make failures testable:
 *   limit:  the residual is NaN once |d0| > limit (a step that cannot be computed: fmi2Discard);
 *   max_cv: the Newton matrix fails when cv = theta1 dt > max_cv (a step that succeeds as sub-steps). */
#ifndef CONFIG_H
#define CONFIG_H
#define MODEL_IDENTIFIER nonlinear
#define MODEL_GUID "{5d1b7f3e-0c2a-4e8b-9a61-2f4c8e7d0b01}"
#define N_Q 2
#define N_U 7            /* F, law 0 (x0, xd0, xdd0), law 1 (x1, xd1, xdd1) */
#define N_P 7            /* m, c, k, k3, g, limit, max_cv */
#define N_Y 12           /* q0 q1 v0 v1 a0 a1, law 0 (x, xd, xdd), law 1 (x, xd, xdd) */
#define N_LAWS 2
#define N_STATIC 1
#define N_VARS 31
#define N_VALIDITY 0
#define N_PARAMETER_CHECKS 0
#define MODEL_LINEAR_IN_STATE 0
#define MODEL_JACOBIAN_CONSTANT 0
/* priced as a large model: the consistent acceleration iterates on kept factors (fmu_src/consistent.c), so that
 * valgrind and the sanitizers run that path too */
#define CONSISTENT_REFRESH_COST 8.0
#define MODEL_SZ_ARG 8
#define MODEL_SZ_RES 1
#define MODEL_SZ_IW 0
#define MODEL_SZ_W 0
#define DEFAULT_STEP 0.01
#define DEFAULT_STOP_TIME 3.0
#endif
