/* solver_settings.h -- the SS22 solver's settings as the C glue sees them: their slots and their limits.
 * Written by `python -m flexlink.export.solver_header` from flexlink/scene/solver.py, the one owner of these
 * numbers (the scene loader, the FMU's variables and the tools read them there); tests/test_solver_settings.py
 * keeps this file equal to what that module writes.  Do not edit by hand. */
#ifndef FLEXLINK_SOLVER_SETTINGS_H
#define FLEXLINK_SOLVER_SETTINGS_H

/* The slots of FmuData.solver, in value-reference order of the solver.* variables.  SOLVER_ORDER (an Integer
 * variable): SOLVER_ORDER_SS22 (SS22) or SOLVER_ORDER_RICHARDSON (SS22 with Θ = ½ and one Richardson
 * extrapolation per internal step: fourth order for resolved modes, but unresolved ones are amplified, so
 * only for non-stiff scenes). */
typedef enum {
    SOLVER_STEP, SOLVER_THETA1, SOLVER_THETA2, SOLVER_TOLERANCE, SOLVER_ORDER, N_SOLVER_SETTINGS
} SolverSetting;

/* SS22 is unconditionally stable for SOLVER_THETA_MIN <= Θ1 <= Θ2 <= SOLVER_THETA_MAX. */
#define SOLVER_THETA_MIN 0.5
#define SOLVER_THETA_MAX 1.0
#define SOLVER_ORDER_SS22 2
#define SOLVER_ORDER_RICHARDSON 4

/* The defaults of an instance whose model lists no solver.* variable (the generated ones always do). */
#define SOLVER_DEFAULT_THETA 0.5
#define SOLVER_DEFAULT_TOLERANCE 1e-10

/* Order 4 only while every mode is resolved: w_max dt <= RICHARDSON_MAX_OMEGA_STEP (richardson.c). */
#define RICHARDSON_MAX_OMEGA_STEP 0.3
/* A failed internal step is retried as 2, 4, ... SUBSTEP_MAX sub-steps. */
#define SUBSTEP_MAX 8
/* The most internal steps one fmi2DoStep takes: its time stays bounded (about 10 s at 10 µs a step) and the
 * step count cannot overflow (solver.step = 1e-300 once made it one step).  A doStep that needs more is
 * refused (fmi2Discard, the FMU unchanged): a larger solver.step or shorter communication steps. */
#define DOSTEP_MAX_INTERNAL_STEPS 1000000.0
/* Newton iterations of one SS22 step before it counts as not converged (then sub-stepped). */
#define SS22_MAX_ITERATIONS 20
/* A Newton iteration that stalls (a fresh matrix no longer contracts) within this factor of the tolerance
 * has reached the rounding floor of the residual and is accepted (ss22.c). */
#define SS22_ROUNDING_FACTOR 100.0
/* Full Newton iterations of the static equilibrium of the scene's static coordinates at
 * fmi2ExitInitializationMode (instance.c). */
#define STATIC_MAX_ITERATIONS 50

#endif /* FLEXLINK_SOLVER_SETTINGS_H */
