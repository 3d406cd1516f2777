/* internal.h -- what the C files behind cosimulation.h share among themselves; fmi2Functions.c,
 * fmi3Functions.c and hosts use cosimulation.h only.
 *
 *   calls.c           call-sequence rules of the FMI 2 and FMI 3 layers
 *   logging.c         log categories, messages through the host's logger, fmi2SetDebugLogging
 *   instance.c        instantiate, free, reset, start values, setup experiment, initialization
 *   variables.c       get/set of the variable table, inputs with kinematic laws, outputs
 *   cs_step.c         the Co-Simulation communication step (SS22 internal steps)
 *   model_exchange.c  states, derivatives, nominals and time events of Model Exchange
 *   derivatives.c     directional derivatives
 *   fmu_state.c       FMU states and their serialisation
 *   guards.c          the checks that refuse a state the model cannot stand behind
 *   consistent.c      the consistent acceleration, with a factorised mass matrix kept across calls
 *   richardson.c      when the order-4 option is stable: the highest natural frequency against the step */
#ifndef FLEXLINK_INTERNAL_H
#define FLEXLINK_INTERNAL_H

#include "cosimulation.h"

/* logging.c: a message before an instance exists (fmi2Instantiate refusing to create one). */
#ifdef __GNUC__
__attribute__((format(printf, 4, 5)))
#endif
void fmu_log_callbacks(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                       const char *format, ...);

/* variables.c */
/* Where the value of variable v lives in d. */
double *fmu_slot(FmuData *d, const VarInfo *v);
/* 1 if the n values of x are all finite. */
int fmu_all_finite(const double *x, int n);
/* u_model(t): the host's inputs, with the kinematic-law slots filled in. */
void fmu_model_inputs(const FmuData *d, double t, double *u);
/* The consistent acceleration M(q) a = -r(q, v, 0, u, p) at d->time, then the outputs, unless they are
 * up to date; function names the FMI function in messages. */
fmi2Status fmu_update_outputs(Instance *inst, const char *function);
/* The outputs without the acceleration only (d->outputs_valid 2), unless the outputs are up to date. */
fmi2Status fmu_update_static_outputs(Instance *inst, const char *function);
/* Why the values of d (parameters, solver settings, start values, inputs) are outside what fmi2SetReal
 * accepts, in why; NULL if they are all acceptable.  A deserialised FMU state passes the same gate as the
 * values a host sets one by one (inst lends its work memory to the parameter relations). */
const char *fmu_invalid_values(Instance *inst, const FmuData *d, char *why, size_t n);

/* consistent.c: d->acceleration = the a of M(q) a = -r0, r0 = r(q, v, 0, u0, p) at d's state and the model
 * inputs u0: 0, or 1 if M is singular there (or not finite), or -1 if the model failed to evaluate. */
int fmu_consistent_acceleration(Instance *inst, const double *u0, const double *r0);
/* Parameters changed: the kept mass matrix is another model's. */
void fmu_consistent_forget(FmuData *d);

/* guards.c: fmi2OK if the state d (q, v; inputs u at time t) is finite and within the model's validity
 * (and, if check_mass_matrix, its mass matrix positive definite); else fmi2Discard with the reason in
 * inst->guard_reason. */
fmi2Status fmu_guard_state(Instance *inst, double t, const double *u, int check_mass_matrix);
void fmu_guard_init(Instance *inst, const double *u);
/* The energy balance of a communication step (or, in Model Exchange, of the importer's step between two
 * completed integrator steps): the energies, the inputs' generalized forces and where they act at its ends
 * (EnergyPoint, cosimulation.h; outputs brought up to date at the current time, `function` names the caller
 * in messages), then fmi2OK or fmi2Discard with the reason in inst->guard_reason. */
fmi2Status fmu_energy_point(Instance *inst, EnergyPoint *e, const char *function);
/* The same inside a communication step, without the consistent acceleration where the model has no laws. */
fmi2Status fmu_energy_point_inside(Instance *inst, EnergyPoint *e, const char *function);
/* The energy point at the start of a communication step: fmu_energy_point's, reusing the one kept at the end
 * of the last step (fmu_energy_point_keep) when the state, time and parameters are still its own and only
 * force inputs changed (guards.c says why that is exact). */
fmi2Status fmu_energy_point_start(Instance *inst, EnergyPoint *e, const char *function);
void fmu_energy_point_keep(Instance *inst, const EnergyPoint *e);
fmi2Status fmu_guard_energy(Instance *inst, const EnergyPoint *e0, const EnergyPoint *e1, double internal_steps);

/* fmu_state.c: frees the FMU states inst handed out and the host did not free (fmi2FreeInstance). */
void fmu_free_all_states(Instance *inst);

/* richardson.c: fmi2OK if order 4 is stable at internal steps of dt (w_max dt <= RICHARDSON_MAX_OMEGA_STEP,
 * w_max found at the current state and parameters when not known), else fmi2Discard with the reason. */
fmi2Status fmu_check_richardson(Instance *inst, double dt);

#endif /* FLEXLINK_INTERNAL_H */
