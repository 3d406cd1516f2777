/* A hand-written model for testing the generic C half: the thesis's 2-DOF system
 * (seed 001 part 3.3, after Bathe):  M a + C v + K q = F  with
 *   M = [1 1; 1 2],  C = K = [1 1; 1 3],  F = (u0, u1)  (the thesis: F = (1, 2), q0 = v0 = 0).
 * The exact solution (figure 3.6) pins these matrices down; see tests/test_ss22.py. */
#ifndef CONFIG_H
#define CONFIG_H
#define MODEL_IDENTIFIER twodof
#define MODEL_GUID "{8c4e810f-3df3-4a00-8276-176fa3c9f000}"
#define N_Q 2
#define N_U 2
#define N_P 1            /* p[0] scales K (a tunable stiffness, to test parameter checks) */
#define N_Y 4            /* q1, q2, v1, v2 */
#define N_LAWS 0
#define N_STATIC 0
#define N_VARS 16
#define N_VALIDITY 0
#define N_PARAMETER_CHECKS 0
#define MODEL_LINEAR_IN_STATE 1
#define MODEL_JACOBIAN_CONSTANT 1
#define MODEL_SZ_ARG 8
#define MODEL_SZ_RES 1
#define MODEL_SZ_IW 0
#define MODEL_SZ_W 0
#define DEFAULT_STEP 0.5
#define DEFAULT_STOP_TIME 15.0
#endif
