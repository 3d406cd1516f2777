/* ss22.h -- the Zienkiewicz-Wood-Hine single-step algorithm of degree 2 (SS22) over a
 * model in residual form r(q, v, a, u, p) = 0 (model.h); seed 001 part 3, docs/integrator.md.
 *
 * On [t0, t0 + dt] the acceleration is the unknown constant alpha and
 *     q1 = q0 + dt v0 + dt^2/2 alpha,      v1 = v0 + dt alpha.
 * alpha solves the weighted residual  r(q_bar, v_bar, alpha, u_bar, p) = 0  with
 *     q_bar = q0 + theta1 dt v0 + theta2 dt^2/2 alpha,   v_bar = v0 + theta1 dt alpha,
 *     u_bar = theta1 u1 + (1 - theta1) u0,
 * which for M a + C v + K q = F is exactly the thesis's
 *     (M + dt theta1 C + dt^2/2 theta2 K) alpha = F_bar - C v0 - K (q0 + dt theta1 v0)
 * and for theta1 = theta2 = 1 evaluates the state-dependent matrices at the end of the step.
 * Nonlinear models: Newton on alpha with the matrix dr/da + theta1 dt dr/dv + theta2 dt^2/2 dr/dq
 * (model_newton_matrix), kept while it contracts well (simplified Newton). */
#ifndef FLEXLINK_SS22_H
#define FLEXLINK_SS22_H

#include <stdint.h>
#include "model.h"

/* SS22_MAX_ITERATIONS and SS22_ROUNDING_FACTOR: solver_settings.h (from flexlink/scene/solver.py) */

/* A step whose first increment, times rate/(1 - rate) for the rate its matrix showed in an earlier step (its
 * last ratio of a second increment to a first, grown with the matrix's age and doubled: SS22_DIRECTION_MARGIN
 * below; or its kept rate, if larger), at least SS22_RATE_FLOOR, then raised once to the power 0.8 (Radau5
 * raises its contraction factor so at every step, Hairer & Wanner, Solving ODEs II, IV.8; here the rate is
 * measured again instead), is below the tolerance is accepted after one iteration; so is, after two, a step
 * whose second increment times the kept rate (raised to its ratio to the first increment, if larger) is.  The
 * floor keeps a rate measured where the increments had already reached rounding, or after an input jump, from
 * accepting a large first increment (an independent review built a stiff model with an input jump where a
 * measured rate of 5e-9 accepted a step 1290 tolerances off).  After SS22_RATE_MEASURE_EVERY such steps the
 * next iterates once more and measures the rate again.  Each step's measure (its third increment with a matrix
 * from an earlier step, whatever made the step take it) that finds the rate within the one steps are accepted
 * on (the kept rate at least SS22_RATE_FLOOR, to the power 0.8: ss22.c, aged_rate) doubles that number, up to
 * SS22_RATE_CONFIRMATIONS doublings in a row; one that does not starts again from SS22_RATE_MEASURE_EVERY, and
 * so does a new matrix.
 * At the recommended step the measures were nearly all of the chains' third iterations (planar_chain_5: 815 of
 * 820 over 1 s, benchmarks/newton_trace.py: one step in ten; docs/integrator.md). */
#define SS22_RATE_MEASURE_EVERY 4
#define SS22_RATE_CONFIRMATIONS 3
/* The one-increment stop takes the last first ratio of increments, grown with the matrix's age (ss22.c,
 * one_increment_rate), times this margin: a ratio of two increments' largest entries, and what the first
 * increment leaves depends on the direction of the predictor's error.  On the six-axis arm two steps accepted
 * on a rate of 0.163 were 0.33 of their increment from their solution (benchmarks/step_audit.py), and the
 * infinity-norm of the old matrix's error J_old^-1 (J - J_old), a bound over all directions, was 1.6 to 90
 * times the step's first ratio, median 2.45, over 189 sampled steps of 3 s (benchmarks/newton_trace.py
 * --every 25, its M part): 2 is what those steps needed, not a bound.  At other tolerances 2 was not enough even with
 * ss22.c's bounds_error (the arm at 1e-9: 5 of 8000 beyond, at 1e-8: 383; with 3 none; docs/integrator.md). */
#define SS22_DIRECTION_MARGIN 3.0
/* A matrix from an earlier step ends a step whose first increment was more than SS22_FAR_START tolerances off
 * (a start far off) only on an increment within 1/SS22_DIRECTION_MARGIN of the tolerance, whatever its ratios
 * say (and is refreshed when it cannot reach that in the iterations left).  Ratios measured on increments far
 * above the tolerance describe the directions that hold most of the start's error; a direction the old matrix
 * contracts slowly can hold a small share of it that shows only once the increments fall to its size.  A
 * margin, not a bound: in tests/c/predictor_check.c's setting a direction at rate 0.8-0.98 that holds 2-5
 * tolerances of a start 1e5 off still ends 1.3-4.8 tolerances off.  six_axis_arm_torque under a PD at every
 * 0.5 ms step (unresolved modes, a start 1e5-1e8 tolerances off after each torque): 7e-7 to 2e-4 of the first
 * increment stayed in such directions; a step ended on ratios of 3.1e-4 and 2.9e-3 had 63 tolerances left (163
 * of 2000 steps beyond; 0 with this rule, the worst 0.38, benchmarks/step_audit.py --pd).  Starts this far are
 * common: planar_chain_5 at its recommended step under a PD every 1 ms (84 % of its steps) had 28 of 2414 steps
 * beyond (worst 6.73; none now, at 2.34 -> 2.92 iterations); at the recommended step under the bench manoeuvre
 * (a third of planar_chain_3's steps) the rule saves iterations, refreshing a matrix that contracts slowly
 * sooner (docs/integrator.md, "A start far off"). */
#define SS22_FAR_START 1e3
#define SS22_RATE_FLOOR 1e-3
/* The kept contraction rate of a matrix falls by at most this factor per measured ratio of increments (ss22.c,
 * record_rate; CVODE's CRDOWN). */
#define SS22_RATE_DECAY 0.3
/* The comparisons over which the parabola's and the line's misses are weighed (ss22.c, choose_predictor), and
 * how often the parabola is formed and compared while the line leads (ss22.c, predict). */
#define SS22_PREDICTOR_MEMORY 8.0
#define SS22_PREDICTOR_PROBE 4

/* A matrix from an earlier step is refreshed, at the current iterate of a step that would need a third
 * iteration, once the iterations spent beyond two a step since it was made add up to SS22_REFRESH_COST: about
 * what a new one costs, in iterations (residual + solve).  It was measured when above 12 coordinates the Newton
 * matrix was evaluated by columns of the residual's forward derivative, about 2 N_Q residuals (benchmarks/
 * ss22_ab.py: 53 on fast_two_link, N_Q = 26; 47 on planar_chain_5, 20; 34 on six_axis_arm; 4 on rotating_link,
 * 4; 5 on the 12-coordinate planar_chain_3, not by columns).  Since "auto" takes differences of the residual
 * there, a matrix costs about N_Q residuals and the mass matrix (benchmarks/scaling.py: about 16 on the six-axis
 * arm, 23 on planar_chain_5), so the rule refreshes up to twice later than it would pay to.  Paying for a refresh once it has been paid for in wasted iterations
 * costs at most twice the best choice made with hindsight (the rent-or-buy rule).  A whipping chain's mass
 * matrix M(q) turns with the chain: the kept matrix's contraction rate grew from 2e-4 to 0.35 over 5950 steps
 * of fast_two_link, all of it from M's change
 * (docs/integrator.md), while only a rate above 0.5 refreshed it; its steps iterated 7 times. */
#define SS22_REFRESH_COST (2.0 * N_Q)

/* The mass update (mass_update.c).  Where a chain's mass matrix M(q) turns with its motion, a kept matrix's
 * error is mostly its M part: planar_chain_5 at its scene's 1 ms step (benchmarks/newton_trace.py) had the
 * infinity-norms of J_old^-1 (J - J_old)'s M, C and K parts at 0.02-0.49, 8e-4-1.5e-2 and 1e-5-3e-3.  A model
 * whose M is generated apart from the rest of J (config.h, MODEL_MASS_UPDATE; codegen.py, mass_update) keeps
 * J - M of each full evaluation, and at the end of a step whose kept matrix has wasted (iterations beyond two a
 * step) what a new M and its LU cost (CONSISTENT_REFRESH_COST residuals, at least one), unless it contracts at
 * SS22_RECURRENCE_MAX_RATE or faster, the matrix becomes M(q_bar) + (J - M)_kept, factorised, made at that
 * step: to every rule (its age, rates and first ratios, the far-start rule) a matrix evaluated there.  A full
 * evaluation is then bought by the iterations beyond SS22_MASS_UPDATE_FLOOR a step, once they add up to
 * SS22_REFRESH_COST (a start far off takes three even from a matrix that contracts at 1e-4: the far-start
 * rule's last increment within a third of the tolerance), or by poor contraction, as before.
 * docs/integrator.md, "The mass update". */
#ifndef MODEL_MASS_UPDATE
#define MODEL_MASS_UPDATE 0          /* a hand-written model (tests/c/) */
#endif
#define SS22_MASS_UPDATE (MODEL_MASS_UPDATE && !MODEL_LINEAR_IN_STATE && !MODEL_JACOBIAN_CONSTANT)
#define SS22_MASS_UPDATE_FLOOR 3

/* The recurrence start (predictor.c) is formed with a kept matrix once that has been kept for as many steps as
 * forming it costs residuals (the velocity and position Jacobians by differences, N_Q + 1 residuals each, and
 * the host inputs' columns by central differences, two residuals each; a law's three slots have none):
 * it saves at most about one residual a step, so forming it then costs at most twice what the best choice
 * made with hindsight would (rent-or-buy, as SS22_REFRESH_COST); a matrix refreshed every few steps (a
 * whipping chain) never pays for one. */
#define SS22_RECURRENCE_COST (2 * (N_Q + 1 + N_U - 3 * N_LAWS))
/* The relative step of the central differences that give its input columns B (predictor.c, input_columns). */
#define SS22_INPUT_DIFFERENCE 1e-6
/* It is formed again, with a newer kept matrix, once its misses (the running mean of their logarithms over about
 * SS22_PREDICTOR_MEMORY steps: their geometric mean) have grown SS22_RECURRENCE_GROWTH-fold over those of its
 * first SS22_RECURRENCE_FRESH steps:
 * where the motion turns the model away from the state it was formed at (fast_two_link at 0.1 ms: 46 forms in
 * 20 000 steps, against 139 when every newer matrix formed it; planar_chain_5 at 1 ms: 2, where forming it
 * again brought nothing).  docs/integrator.md. */
#define SS22_RECURRENCE_FRESH 8
#define SS22_RECURRENCE_GROWTH 8.0
/* ... and it starts no step whose kept matrix has no measured rate or contracts slower than this: ratios of
 * increments judge the steps, and from a start this close they see only the directions the matrix contracts fast
 * in (six_axis_arm_torque at 0.5 ms under 5 N m, rates 0.007-0.06: a step 5 tolerances off after increments of
 * 3.8e3, 116, 5.7 tolerances; docs/integrator.md).  The rate floor. */
#define SS22_RECURRENCE_MAX_RATE 1e-3
/* The highest order of the extrapolation of its misses that is fed back (predictor.c, fed_back). */
#define SS22_RECURRENCE_ORDER 2

#define SS22_CACHE 4     /* factorisations kept: the regular step, a shortened last one, and the Δt/2 of the
                            order-4 option (2 entries thrashed: 1800 LUs in 15000 steps); steps within 1e-6 of
                            one size share its entry (ss22.c, cached_factor) */

typedef enum {
    SS22_OK = 0,
    SS22_NOT_CONVERGED,
    SS22_NOT_FINITE,
    SS22_SINGULAR,
    SS22_MODEL_FAILED
} SS22Status;

typedef struct {
    double dt, theta1, theta2;   /* key of the cached factorisation */
    int valid;
    uint64_t stamp;              /* last use, for replacement */
    double rate;                 /* kept contraction rate of the simplified Newton iteration with this matrix
                                    (ss22.c, record_rate), or -1 before a measure */
    int estimated;               /* steps accepted since on that rate without measuring it again */
    int confirmed;               /* steps' measures in a row that found the rate within the one accepted on */
    int confirmed_first;         /* the same for first ratios, against what one-increment stops were accepted on */
    uint64_t made;               /* SS22.steps when it was evaluated: its age is SS22.steps - made */
    /* the last ratio of a step's second increment to its first with it, or -1, and its age at that step: [0] for
     * steps started from the line or parabola, [1] from the recurrence (predictor.c), [2] from a corrected start
     * (order 4's, ss22_step_from), whose misses lie in other directions (what a stale matrix misses of a start
     * depends on the start's error: ss22.c, one_increment_rate) */
    double first[3];
    uint64_t first_age[3];
    double waste;                /* iterations spent beyond two a step since it was evaluated or updated */
    double waste_full;           /* ... beyond SS22_MASS_UPDATE_FLOOR a step since it was evaluated */
    double LU[N_Q * N_Q];
    int piv[N_Q];
#if SS22_MASS_UPDATE
    double rest[N_Q * N_Q];      /* J - M at its last full evaluation: theta1 dt C + theta2 dt^2/2 K */
#endif
} SS22Factor;

/* SS22's own linear recurrence as the Newton start (predictor.c).  For M a + C v + K q + B u = 0, three
 * consecutive steps of dt obey exactly
 *     J (a+ - 2a + a-) = -dt C d - dt^2 K (a- + (1/2 + theta1) d) - B (u+ - 2u + u-),   d = a - a-,
 * with J the Newton matrix (u: the weighted inputs), so a+ = 2a - a- - P d - G a- - U (u+ - 2u + u-).  P, G
 * and U come from the kept matrix's factors and C, K, B at the state where they are formed; what the nonlinear
 * model adds is fed back as an extrapolation of the recurrence's last misses. */
typedef struct {
    int valid;                   /* P and G formed, for steps of dt */
    double dt;
    uint64_t made;               /* SS22Factor.made of the matrix they were formed with (or tried with) */
    int depth;                   /* consecutive steps it predicted (0 to SS22_RECURRENCE_ORDER + 1): misses kept */
    double bias;                 /* running mean of its wins (+1) and losses (-1) against the line or parabola */
    int judged;                  /* steps it predicted since formed, up to SS22_RECURRENCE_FRESH */
    double log_fresh, log_miss;  /* mean log2 of its misses over those first steps; running mean since */
    int u_depth;                 /* consecutive steps' weighted inputs in u_last, u_before (0 to 2) */
    double u_last[N_U > 0 ? N_U : 1], u_before[N_U > 0 ? N_U : 1];
    int order;                   /* the order its misses are fed back at (predictor.c, fed_back) */
    double order_score[SS22_RECURRENCE_ORDER + 1];     /* running means of log2 of each order's misses */
    double misses[N_Q * (SS22_RECURRENCE_ORDER + 1)];  /* a - its prediction before the feedback, last steps */
    double raw[N_Q], start[N_Q], other[N_Q];     /* this step's prediction before and after the feedback, and
                                                    the line's or parabola's start */
    double P[N_Q * N_Q], G[N_Q * N_Q];           /* J^-1 (dt C + (1/2 + theta1) dt^2 K) and J^-1 dt^2 K,
                                                    column-major */
    double U[N_Q * (N_U > 0 ? N_U : 1)];         /* J^-1 B, column-major: a host's input that moves (a law's
                                                    columns are zero) */
    double inverse[N_Q * N_Q];   /* J^-1 itself, column-major: the Newton increments' solve while J is the kept
                                    matrix it was formed with (ss22_recurrence_inverse) */
} SS22Recurrence;

typedef struct {
    double theta1, theta2, tolerance;
    int max_iterations;
    SS22Factor cache[SS22_CACHE];
    uint64_t clock;              /* fixed-width: an FMU state has one layout on every 64-bit platform */
    /* the last accelerations this solver returned and their steps: the Newton iteration starts from their
     * extrapolation when the caller passes the last one back unchanged (else from the caller's): the line
     * through the last two, or the parabola through the last three while it has missed by less (a vote)
     * (ss22.c, predict).  depth: how many of last, before, older are consecutive steps' own (0 to 3; 0: no
     * history yet) */
    int depth, parabola;
    double alpha_last[N_Q], alpha_before[N_Q], alpha_older[N_Q], dt_last, dt_before, dt_older;
    double predictor_bias;       /* running mean of the line's (+1) and the parabola's (-1) wins */
    SS22Recurrence rec;
    /* scratch, kept here so that a step allocates nothing (start, other_start: the two predictions) */
    double q_bar[N_Q], v_bar[N_Q], r[N_Q], u_bar[N_U > 0 ? N_U : 1], start[N_Q], other_start[N_Q];
    /* counters, for benchmarks and logging */
    uint64_t steps, newton_iterations, factorisations, residual_evaluations, recurrences;
    uint64_t mass_updates;       /* factorisations of mass-updated matrices (not in factorisations) */
} SS22;

void ss22_init(SS22 *s, double theta1, double theta2, double tolerance);

/* Parameters changed: the constant Newton matrix of a linear model must be rebuilt. */
void ss22_invalidate(SS22 *s);

/* Weighted inputs over the step; kinematic-law slots (MODEL_LAWS) of u0 hold the law's
 * (position, rate, acceleration) at t0 and those of u1 at t0 + dt.  The law's coordinate
 * moves as SS22 would move it with the law's mean acceleration over the step, (rate1 - rate0)/dt: its
 * weighted rate is then the average of its exact rates, as the free coordinates' is, and a law whose jerk
 * is not zero keeps the scheme second-order (landing on the end position instead is off the mean
 * acceleration by dt x'''/6 at every step: first order, docs/integrator.md); its weighted angle is
 * (x0 + x1)/2 for theta = 1/2, symmetric in time as order 4's extrapolation needs. */
void ss22_weighted_inputs(const SS22 *s, double dt, const double *u0, const double *u1, double *u_bar);

/* One step of size dt from (q, v).  alpha: in, an initial guess (e.g. the previous step's);
 * out, the solution.  On anything but SS22_OK, q and v are left untouched. */
SS22Status ss22_step(SS22 *s, double dt, double *q, double *v, double *alpha,
                     const double *u0, const double *u1, const double *p, ModelWork *work);

/* ss22_step with the Newton iteration started from start instead of the predictor (the order-4 option's
 * steps, which know the full step's acceleration: cs_step.c); alpha is the last step's acceleration, as
 * for ss22_step, and the predictor's line continues through it.  corrected: the start adds a miss measured
 * on the step before, a closer start than an extrapolation, whose first increment can undercut what is left
 * where the old matrix's error cancels it (as the parabola's did): with an older matrix that increment ends
 * the step by its size only within 1/SS22_DIRECTION_MARGIN of the tolerance, and by the matrix's rate only on
 * the first ratios of corrected starts (SS22Factor.first[2]; ss22.c). */
SS22Status ss22_step_from(SS22 *s, double dt, double *q, double *v, double *alpha, const double *start,
                          int corrected, const double *u0, const double *u1, const double *p, ModelWork *work);

const char *ss22_status_message(SS22Status status);

#endif
