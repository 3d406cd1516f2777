/*
 * model.h -- the narrow contract between the generic half of every flexlink FMU
 * (fmi2Functions.c, the files behind cosimulation.h, ss22.c, linalg.c) and one generated model
 * (config.h + model.c, written by flexlink.export.codegen from templates/).
 *
 * Nothing here knows about links, beams or joints.  A model is a second-order
 * mechanical system in residual form
 *
 *     r(q, v, a, u, p) = M(q, p) a + h(q, v, u, p) = 0        (N_Q free coordinates)
 *
 * with inputs u (N_U), tunable parameters p (N_P) and outputs y (N_Y).  Some
 * entries of u are "kinematic laws" (position-driven coordinates): three
 * consecutive entries (position, rate, acceleration) that the glue fills either
 * from a built-in law table or from the host's inputs.
 *
 * Model Exchange uses the same contract: the continuous state is x = (q, v), its
 * derivative (v, a) with M(q) a = -r(q, v, 0, u, p); the variables VAR_STATE_* and
 * VAR_DER_* expose them.  Directional derivatives need the two forward-derivative
 * functions below (added for issue 7; hand-written models must provide them too).
 */
#ifndef FLEXLINK_MODEL_H
#define FLEXLINK_MODEL_H

#include <stddef.h>
#include "config.h"
#include "solver_settings.h"   /* SolverSetting and the solver's limits, from flexlink/scene/solver.py */

/* A model half that does not say ([fmu] directional_derivatives in config.h) provides the forward
 * derivatives of model_forward and model_outputs_acceleration_forward. */
#ifndef MODEL_DIRECTIONAL_DERIVATIVES
#define MODEL_DIRECTIONAL_DERIVATIVES 1
#endif

/* ---------------------------------------------------------------- variables */

typedef enum {
    VAR_PARAMETER,   /* tunable model parameter: p[index]                          */
    VAR_START_Q,     /* initial position of free coordinate index (fixed parameter)   */
    VAR_START_V,     /* initial rate of free coordinate index (fixed parameter)       */
    VAR_SOLVER,      /* solver setting: index is a SolverSetting                       */
    VAR_INPUT,       /* input: u[index]                                              */
    VAR_OUTPUT,      /* output: y[index], computed by model_outputs                    */
    VAR_STATE_Q,     /* continuous state: position q[index] (local; Model Exchange state)  */
    VAR_STATE_V,     /* continuous state: rate v[index] (local)                            */
    VAR_DER_Q,       /* derivative of the state q[index]: v[index]                          */
    VAR_DER_V        /* derivative of the state v[index]: the acceleration a[index]         */
} VarKind;

typedef struct {
    const char *name;     /* the FMU variable name, for messages                           */
    VarKind kind;
    int index;
    double start;
    double min, max;      /* allowed range; the glue refuses NaN/Inf always               */
    int min_exclusive;    /* 1: value must be > min (e.g. a stiffness stays > 0)          */
    int tunable;          /* 1: may be set in step mode (variability="tunable")           */
    int integer;          /* 1: an Integer (fmi2Get/SetInteger, fmi3Get/SetInt32), else a Real;
                             its value is whole and kept as a double in the same slot          */
} VarInfo;

/* MODEL_VARS[vr] describes value reference vr (0 .. N_VARS-1). */
extern const VarInfo MODEL_VARS[N_VARS];

/* ------------------------------------------------------------ kinematic laws */

/* One segment of a built-in law, valid for t < until:
 *   x(t) = sum_k poly[k] t^k + sum_j amp_j cos(w_j t + phase_j)      (t absolute) */
typedef struct {
    double until;
    int n_poly;
    const double *poly;
    int n_cos;
    const double *cos;    /* n_cos triplets (amp, w, phase) */
} LawSegment;

typedef struct {
    int u_offset;         /* u[u_offset + 0/1/2] = position, rate, acceleration            */
    int builtin;          /* 1: segments below; 0: the host sets u[u_offset..+2] as inputs
                             at each communication point and the glue extends them over
                             the step as x + xd (t - tc) + xdd (t - tc)^2 / 2              */
    int n_segments;
    const LawSegment *segments;
} KinematicLaw;

#if N_LAWS > 0
extern const KinematicLaw MODEL_LAWS[N_LAWS];
#endif

/* Free coordinates solved for static equilibrium at the end of initialization
 * (scene: initial_deformation = "static"); the others are held at their start values. */
#if N_STATIC > 0
extern const int MODEL_STATIC_COORDS[N_STATIC];
#endif

/* 1 where output y[i] depends on the acceleration (reactions, accelerations, a law's torque), structurally:
 * the others are read without the consistent acceleration (variables.c, fmu_update_static_outputs). */
extern const unsigned char MODEL_OUTPUT_USES_ACCELERATION[N_Y > 0 ? N_Y : 1];

/* Nominal magnitude of each free coordinate (Newton convergence test, ME nominals). */
extern const double MODEL_NOMINAL_Q[N_Q];

/* -------------------------------------------------------------- work memory */

/* Scratch memory for the generated functions: one per instance, never shared.
 * Sizes are the maxima over all generated functions (config.h). */
typedef struct {
    const double *arg[MODEL_SZ_ARG];
    double *res[MODEL_SZ_RES];
    long long int iw[MODEL_SZ_IW > 0 ? MODEL_SZ_IW : 1];
    double w[MODEL_SZ_W > 0 ? MODEL_SZ_W : 1];
} ModelWork;

/* ---------------------------------------------------------- model functions */
/* All return 0 on success, non-zero if the generated code failed.  Matrices are
 * dense, column-major.  None of them allocates or keeps state. */

/* r = M(q,p) a + h(q,v,u,p)  (N_Q) */
int model_residual(const double *q, const double *v, const double *a, const double *u,
                   const double *p, double *r, ModelWork *work);

/* The inputs' generalized forces Q = -B u (N_Q) where B = dr/du is a constant (mechanics.assembly.structure:
 * joint torques; never with kinematic laws): returns 1.  Else 0 and Q untouched: r(u = 0) - r(u) gives them. */
int model_input_forces(const double *u, double *force);

/* J = ca dr/da + cv dr/dv + cq dr/dq at (q, v, a, u, p)  (N_Q x N_Q).
 * SS22 uses ca = 1, cv = theta1 dt, cq = theta2 dt^2/2; (1, 0, 0) gives M(q). */
int model_newton_matrix(const double *q, const double *v, const double *a, const double *u,
                        const double *p, double ca, double cv, double cq, double *J,
                        ModelWork *work);

/* y = outputs(q, v, a, u, p)  (N_Y); a is the acceleration consistent with the state. */
int model_outputs(const double *q, const double *v, const double *a, const double *u,
                  const double *p, double *y, ModelWork *work);

/* Forward (directional) derivatives, for fmi2GetDirectionalDerivative: the derivatives of r and y
 * together at (q, v, a, u, p) in the direction (dq, dv, da, du, dp):
 *     dr = dr/dq dq + dr/dv dv + dr/da da + dr/du du + dr/dp dp    (N_Q)
 *     dy = dy/dq dq + ... + dy/dp dp                                (N_Y)
 * and the outputs' derivative in the acceleration alone, dy = dy/da da.  The glue eliminates the
 * acceleration itself: model_forward with da = 0, M(q) da = -dr, then the outputs' part in da.  dy may
 * be NULL (the Newton matrix's columns).  Either generated derivative code (CasADi's forward mode, one
 * function for r and y sharing their kinematics and its tangent) or, where MODEL_COMPLEX_STEP, a call of
 * model_complex_forward below. */
int model_forward(const double *q, const double *v, const double *a, const double *u, const double *p,
                  const double *dq, const double *dv, const double *da, const double *du, const double *dp,
                  double *dr, double *dy, ModelWork *work);
int model_outputs_acceleration_forward(const double *q, const double *v, const double *a, const double *u,
                                       const double *p, const double *da, double *dy, ModelWork *work);

/* MODEL_COMPLEX_STEP (config.h): the forward derivatives come from the generated residual and outputs
 * themselves, evaluated in complex arithmetic at x + i h dx (the complex step, complex_step.c), instead of
 * generated derivative code.  The two functions below are the same generated code compiled with
 * casadi_real = double _Complex (one small unit each, which includes the real unit).  A C compiler without
 * C99 complex arithmetic (any with _MSC_VER: MSVC, clang-cl, whose Windows complex.h has no complex
 * operators) leaves them out: model_forward then fails, and fmi2GetDirectionalDerivative answers fmi2Error
 * with the reason, as does a step whose Newton matrix is by exact columns ([fmu] newton_matrix = "columns");
 * the default Newton matrix needs no derivative. */
#ifndef MODEL_COMPLEX_STEP
#define MODEL_COMPLEX_STEP 0
#endif
#if MODEL_COMPLEX_STEP && !defined(__STDC_NO_COMPLEX__) && !defined(_MSC_VER)
#define MODEL_HAS_COMPLEX 1   /* double _Complex is a keyword type: no complex.h (and its I) here */
int model_residual_complex(const double _Complex *q, const double _Complex *v, const double _Complex *a,
                           const double _Complex *u, const double _Complex *p, double _Complex *r);
int model_outputs_complex(const double _Complex *q, const double _Complex *v, const double _Complex *a,
                          const double _Complex *u, const double _Complex *p, double _Complex *y);
#else
#define MODEL_HAS_COMPLEX 0
#endif
/* model_forward and model_outputs_acceleration_forward by the complex step (complex_step.c); dy may be
 * NULL (the Newton matrix's columns need dr alone).  Non-zero if the model failed to evaluate, or without
 * complex arithmetic. */
int model_complex_forward(const double *q, const double *v, const double *a, const double *u, const double *p,
                          const double *dq, const double *dv, const double *da, const double *du,
                          const double *dp, double *dr, double *dy);

/* g = model_validity(q, u, p): the model's assumptions hold while every g[i] <= 1 (ratios of tip
 * deflections and rotations to the limits the beam model is meant for); MODEL_VALIDITY_NAMES[i] says
 * what g[i] measures, for the message that refuses a step leaving that range. */
extern const char *const MODEL_VALIDITY_NAMES[N_VALIDITY > 0 ? N_VALIDITY : 1];
int model_validity(const double *q, const double *u, const double *p, double *g, ModelWork *work);

/* h = model_parameter_check(p): the parameters describe a physical system while every h[i] >= 0 (to
 * -1e-12: the entries are scaled to be of order one; e.g. a rigid link's inertia tensor is a body's: its second moments positive
 * semi-definite).  Relations between parameters, which a variable's own min/max cannot state: fmi2SetReal
 * refuses values that break one.  MODEL_PARAMETER_CHECK_NAMES[i] says what h[i] measures. */
extern const char *const MODEL_PARAMETER_CHECK_NAMES[N_PARAMETER_CHECKS > 0 ? N_PARAMETER_CHECKS : 1];
int model_parameter_check(const double *p, double *h, ModelWork *work);

/* 1 if model.c calls the AVX twins of the model's Newton-iteration units on this processor (avx.h: the build
 * has twins and the processor has AVX), for the statistics log; 0 for a model without twins. */
int model_avx_code(void);

/* MODEL_LINEAR_IN_STATE (config.h): 1 if r is affine in (q, v, a): one linear solve
 * per step, no Newton iteration.  MODEL_JACOBIAN_CONSTANT: 1 if moreover the Newton
 * matrix depends on p (and the step) only: factorised only when they change. */

#endif /* FLEXLINK_MODEL_H */
