/* cosimulation.h -- the instance of a flexlink FMU and everything behind the FMI functions:
 * lifecycle, logging, variable access, initialisation, the communication step and FMU states.
 *
 * fmi2Functions.c (FMI 2.0) and fmi3Functions.c (FMI 3.0) check arguments and the call sequence and call
 * the functions below, which keep FMI 2's types for both (fmi3's Float64, UInt32 value references and
 * statuses are the same C types and values); these know
 * the generic model of model.h (residual form, kinematic laws, variables) and nothing of beams.
 * They are defined by concern in logging.c, instance.c, variables.c, cs_step.c, model_exchange.c,
 * derivatives.c and fmu_state.c, which share a few helpers through internal.h.
 *
 * Everything numeric of an instance sits in one plain struct (FmuData, no pointers), so that
 *   - an FMU state is a copy of it (fmi2GetFMUstate / fmi2SetFMUstate),
 *   - its serialisation is a header (magic, GUID, size, checksum) followed by its bytes,
 *   - a failed communication step is undone by copying back the FmuData of its start.
 * The rest of the instance (name, callbacks, logging switches, scratch memory) is not state. */
#ifndef FLEXLINK_COSIMULATION_H
#define FLEXLINK_COSIMULATION_H

#include <stdarg.h>
#include "fmi2Functions.h"
#include "model.h"
#include "ss22.h"

/* The FMI 2.0 states of both interfaces, one bit each so that every FMI function can name the set of
 * states it is allowed in (fmi2Functions.c).  Co-Simulation: instantiated -> initialization -> step
 * mode; a doStep that returns fmi2Discard has undone itself: the FMU stays in step mode at the
 * communication point, so no separate "step failed" state.  Model Exchange: instantiated ->
 * initialization -> event mode <-> continuous-time mode (FMI 2.0 section 3.2.3). */
typedef enum {
    PHASE_INSTANTIATED = 1 << 0,
    PHASE_INITIALIZATION = 1 << 1,   /* initialization mode                                */
    PHASE_STEP = 1 << 2,             /* Co-Simulation step mode (stepComplete)             */
    PHASE_TERMINATED = 1 << 3,
    PHASE_ERROR = 1 << 4,            /* a function returned fmi2Error: reset or set a state */
    PHASE_FATAL = 1 << 5,
    PHASE_EVENT = 1 << 6,            /* Model Exchange event mode                          */
    PHASE_CONTINUOUS = 1 << 7        /* Model Exchange continuous-time mode                */
} Phase;

#define PHASE_ANY (PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_STEP | PHASE_TERMINATED | PHASE_ERROR | \
                   PHASE_EVENT | PHASE_CONTINUOUS)
#define N_STATES (2 * N_Q)           /* Model Exchange: x = (q, v)                          */

/* Log categories (modelDescription.xml <LogCategories> lists the same names, in this order). */
typedef enum {
    LOG_EVENTS,          /* initialisation, retried steps: only when logging is on   */
    LOG_STATUS_WARNING,  /* always reported                                            */
    LOG_STATUS_DISCARD,  /* always reported                                            */
    LOG_STATUS_ERROR,    /* always reported                                            */
    LOG_STATISTICS,      /* the integrator's counters at fmi2Terminate: when switched on */
    LOG_ALL,             /* every FMI call (debugging): only when logging is on        */
    N_LOG_CATEGORIES
} LogCategory;

extern const char *const LOG_CATEGORY_NAMES[N_LOG_CATEGORIES];

#define FMU_SZ(n) ((n) > 0 ? (n) : 1)   /* C99 has no zero-length arrays */

/* The mechanical energy at one time and what the inputs' work between two such points needs (guards.c). */
typedef struct {
    int available;
    double time, kinetic, potential;
    double force[FMU_SZ(N_Q)], q[FMU_SZ(N_Q)];             /* Q of the force inputs, the coordinates */
    double v[FMU_SZ(N_Q)];                                  /* the rates (Model Exchange's work)      */
    double law_torque[FMU_SZ(N_LAWS)], law_angle[FMU_SZ(N_LAWS)], law_rate[FMU_SZ(N_LAWS)];
} EnergyPoint;

/* The mass matrix factorised at an earlier consistent acceleration, kept as the preconditioner of the next
 * (consistent.c).  Part of the state: a restored state computes the same outputs to the last bit. */
typedef struct {
    int valid;                        /* LU holds a factorised M of the current parameters        */
    double LU[N_Q * N_Q];
    int piv[N_Q];
} KeptMass;

/* The order-4 option's Newton starts (cs_step.c, richardson_step).  Each internal step is one SS22 step of dt
 * (started from the line through the last two half steps' accelerations) and two of dt/2 (started from the full
 * step's).  Those bases miss in the same direction from one internal step to the next: the half steps' mean
 * differs from the full step's by what the extrapolation corrects, and the line by the motion's curvature, both
 * smooth while every mode is resolved (w_max dt <= 0.3).  So each of the three starts may add its own last miss,
 * where a running vote says that missed less than the base alone (docs/integrator.md, "Order 4's starts"). */
typedef struct {
    int valid;                        /* misses of the internal step of dt that ended at SS22 step `steps` */
    double dt;
    uint64_t steps;
    double alpha_half[N_Q];           /* the first half step's acceleration: the full step's line starts there */
    double miss[3][N_Q];              /* accepted acceleration minus base: full step, first half, second half */
    double bias[3];                   /* running mean of +1 (the base missed less) and -1 (base + miss did)    */
} RichardsonStarts;

/* Everything numeric: an FMU state is a copy of this struct. */
typedef struct {
    int phase;                        /* Phase                                                  */
    int model_exchange;               /* 1: instantiated as Model Exchange, 0: Co-Simulation    */
    int outputs_valid;                /* 1: y and acceleration up to date; 2: y's acceleration-free
                                       * outputs only (variables.c); 0: none                   */
    int acceleration_ok;              /* acceleration is the consistent one (M(q) non-singular) */
    int stop_time_defined;
    int experiment_tolerance_defined;
    int mass_matrix_guarded;          /* M positive definite at the start state (fmu_guard_init) */
    int omega_max_known;              /* omega_max is that of the current parameters (order 4)  */
    double start_time, stop_time, experiment_tolerance;
    double time;                      /* current communication point                            */
    double last_successful_time;
    double omega_max;                 /* highest natural frequency, rad/s (richardson.c)        */
    double energy_scale;              /* the most energy one step has moved so far (guards.c)   */
    double energy_floor;              /* ½ Σ M_ii (tolerance nominal_i)² (guards.c)              */
    EnergyPoint energy_last;          /* Model Exchange: at the last completed integrator step   */
    double q[N_Q], v[N_Q];            /* state                                                  */
    double alpha[N_Q];                /* SS22 acceleration of the last step (Newton guess)      */
    double acceleration[N_Q];         /* consistent acceleration at time (outputs)              */
    double p[FMU_SZ(N_P)];                /* tunable parameters                                      */
    double u[FMU_SZ(N_U)];                /* inputs as the host set them                             */
    double q_start[N_Q], v_start[N_Q];
    double solver[N_SOLVER_SETTINGS];
    double y[FMU_SZ(N_Y)];                /* outputs at time                                         */
    double law_time[FMU_SZ(N_LAWS)];      /* host-driven law k: time at which u[offset..+2] hold      */
    SS22 ss22;                        /* integrator, with its factorisations and counters        */
    RichardsonStarts richardson;      /* order 4's starts (cs_step.c)                             */
    KeptMass mass;                    /* consistent acceleration's kept factorisation (consistent.c) */
    uint64_t mass_refreshes, mass_iterations;   /* its counters: mass matrices evaluated, residuals iterated */
} FmuData;

struct SavedState;

typedef struct {
    unsigned long magic;              /* INSTANCE_MAGIC while alive                              */
    char *name;
    fmi2CallbackFunctions cb;
    int logging_on;
    int category_on[N_LOG_CATEGORIES];
    FmuData d;                        /* the state                                               */
    FmuData backup;                   /* d at the start of the current doStep                    */
    /* scratch, so that a step allocates nothing and nothing big sits on the stack */
    ModelWork work;
    double u0[FMU_SZ(N_U)], u1[FMU_SZ(N_U)];
    double J[N_Q * N_Q];
    double Js[FMU_SZ(N_STATIC * N_STATIC)];
    double r[N_Q], dq[N_Q];
    double zero[N_Q];                 /* always 0: the acceleration argument of statics        */
    double q_save[N_Q], v_save[N_Q], alpha_save[N_Q];   /* an internal step being retried */
    int piv[N_Q];
    /* guards.c: validity ratios, mass matrix and the reason of a refused state */
    double guard_g[FMU_SZ(N_VALIDITY)], guard_M[N_Q * N_Q];
    char guard_reason[512];
    /* guards.c, energy balance: where the model's energies and prescribed-law torques sit among its outputs
     * (-1: the model has none; found at the first step), and scratch for the inputs with the force inputs removed */
    int energy_known, energy_kinetic, energy_potential, law_torque[FMU_SZ(N_LAWS)], n_force_inputs;
    double energy_u[FMU_SZ(N_U)], energy_y[FMU_SZ(N_Y)], energy_r[N_Q];
    /* guards.c: the energy point that ended the last communication step, with the parameters and inputs it was
     * taken at and r(q, v, 0, u without force inputs) there: the next step starts from it when only force inputs
     * changed in between (fmu_energy_point_start; matched by value, so a reset, an FMU state or a parameter set
     * in between never reuses a stale one) */
    EnergyPoint energy_end;
    double energy_end_p[FMU_SZ(N_P)], energy_end_u[FMU_SZ(N_U)], energy_end_free[N_Q];
    int step_discarded;               /* 1 after fmi2DoStep returned fmi2Discard (fmi2Terminated status) */
    /* directional derivatives: seeds and results */
    double dd_q[N_Q], dd_v[N_Q], dd_a[N_Q], dd_r[N_Q];
    double dd_u[FMU_SZ(N_U)], dd_um[FMU_SZ(N_U)], dd_p[FMU_SZ(N_P)], dd_y[FMU_SZ(N_Y)],
           dd_ya[FMU_SZ(N_Y)];
    char message[1024], escaped[2048];
    struct SavedState *states;        /* the FMU states handed out: freed with the instance     */
} Instance;

#define INSTANCE_MAGIC 0x464c584cUL  /* "FLXL" */

/* A copy of the state, as handed to the host as fmi2FMUstate; the instance that made it keeps it in a
 * list, so that fmi2FreeInstance frees the states the host never freed (fmi2FreeInstance "frees all
 * memory and other resources allocated by the instance"). */
typedef struct SavedState {
    unsigned long magic;              /* STATE_MAGIC while alive */
    struct SavedState *prev, *next;   /* the owner's list of states */
    Instance *owner;
    FmuData d;                        /* the state itself: all that is serialised */
} SavedState;

#define STATE_MAGIC 0x53544154UL     /* "STAT" */

/* ------------------------------------------- call sequence (calls.c: the FMI 2 and 3 layers) */
/* The instance behind an fmi2Component / fmi3Instance, or NULL if it is not a live one. */
Instance *fmu_instance_of(void *c);
/* An fmi2Error (fmi3Error) puts the instance in the error state, fmi2Fatal in the fatal one. */
fmi2Status fmu_finish(Instance *inst, fmi2Status status);
/* Logs "function: message" and returns fmu_finish(inst, fmi2Error). */
fmi2Status fmu_fail(Instance *inst, const char *function, const char *message);
/* 1 if the instance is in one of phases (a bitmask of Phase); else logs which states would do, puts the
 * instance in the error state and returns 0. */
int fmu_allowed(Instance *inst, const char *function, int phases);

/* ------------------------------------------------------------------ lifecycle */
Instance *fmu_instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                          const fmi2CallbackFunctions *functions, fmi2Boolean logging_on);
void fmu_free(Instance *inst);
void fmu_reset(Instance *inst);
const char *fmu_phase_name(int phase);

/* -------------------------------------------------------------------- logging */
/* Errors, discards and warnings are always reported; LOG_EVENTS, LOG_STATISTICS and LOG_ALL only when switched on. */
#ifdef __GNUC__
__attribute__((format(printf, 4, 5)))
#endif
void fmu_log(Instance *inst, fmi2Status status, LogCategory category, const char *format, ...);
/* Logs an error (always reported) and returns fmi2Error. */
#ifdef __GNUC__
__attribute__((format(printf, 2, 3)))
#endif
fmi2Status fmu_error(Instance *inst, const char *format, ...);
int fmu_logs(const Instance *inst, LogCategory category);
/* The integrator's counters since initialisation (logStatistics): what a host needs to judge the cost
 * of its step size, e.g. flexlink bench's factorisations and Newton iterations per step. */
void fmu_log_statistics(Instance *inst);
fmi2Status fmu_set_debug_logging(Instance *inst, fmi2Boolean on, size_t n, const fmi2String categories[]);

/* ------------------------------------------------------------ variable access */
/* The outputs a read of the references vr[] needs, evaluated once for all of them (variables.c). */
fmi2Status fmu_update_outputs_for(Instance *inst, const char *function, const fmi2ValueReference vr[], size_t nvr);
fmi2Status fmu_get_real(Instance *inst, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]);
fmi2Status fmu_set_real(Instance *inst, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]);
/* Integer variables (solver.order): an Integer call on a Real is an error; the Real functions take Integer
 * variables too (whole values only), as they did before solver.order became an Integer. */
fmi2Status fmu_get_integer(Instance *inst, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]);
fmi2Status fmu_set_integer(Instance *inst, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]);

/* ---------------------------------------------------------------- simulation */
fmi2Status fmu_setup_experiment(Instance *inst, fmi2Boolean tolerance_defined, fmi2Real tolerance,
                                fmi2Real start_time, fmi2Boolean stop_time_defined, fmi2Real stop_time);
fmi2Status fmu_enter_initialization(Instance *inst);
fmi2Status fmu_exit_initialization(Instance *inst);
fmi2Status fmu_do_step(Instance *inst, fmi2Real tc, fmi2Real h);

/* ----------------------------------------------------------- Model Exchange */
fmi2Status fmu_set_time(Instance *inst, fmi2Real time);
fmi2Status fmu_set_states(Instance *inst, const fmi2Real x[], size_t nx);
/* Model Exchange: the energy at the last completed integrator step no longer starts the next interval (an
 * event, or an input or parameter that jumps at its time): the next interval is not judged (guards.c).
 * New states set at that time are not a jump: an explicit integrator sets the next step's states before
 * its time. */
void fmu_energy_forget(FmuData *d);
/* the accepted state passes the guards (guards.c), else fmi2Discard and *terminate = fmi2True */
fmi2Status fmu_completed_integrator_step(Instance *inst, fmi2Boolean *terminate);
fmi2Status fmu_get_states(Instance *inst, fmi2Real x[], size_t nx);
fmi2Status fmu_get_derivatives(Instance *inst, fmi2Real dx[], size_t nx);
fmi2Status fmu_get_nominals(Instance *inst, fmi2Real x_nominal[], size_t nx);
fmi2Status fmu_new_discrete_states(Instance *inst, fmi2EventInfo *info);

/* ------------------------------------------------------ directional derivatives */
/* dvUnknown = d(unknowns)/d(knowns) dvKnown at the current point.  Knowns: states (q.*, v.*), inputs,
 * tunable parameters; unknowns: outputs, state derivatives (der(...)) and states.  The acceleration is
 * eliminated from M(q) da = -(dr/dq dq + dr/dv dv + dr/du du + dr/dp dp). */
fmi2Status fmu_directional_derivative(Instance *inst, const fmi2ValueReference unknown[], size_t n_unknown,
                                      const fmi2ValueReference known[], size_t n_known, const fmi2Real dv_known[],
                                      fmi2Real dv_unknown[]);

/* ------------------------------------------------------------------ FMU state */
fmi2Status fmu_get_state(Instance *inst, fmi2FMUstate *state);
fmi2Status fmu_set_state(Instance *inst, fmi2FMUstate state);
fmi2Status fmu_free_state(Instance *inst, fmi2FMUstate *state);
size_t fmu_serialized_size(void);
fmi2Status fmu_serialize(Instance *inst, fmi2FMUstate state, fmi2Byte buffer[], size_t size);
fmi2Status fmu_deserialize(Instance *inst, const fmi2Byte buffer[], size_t size, fmi2FMUstate *state);

#endif /* FLEXLINK_COSIMULATION_H */
