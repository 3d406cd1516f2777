/* guards.c -- a step is refused, not returned, when its state leaves what the model can stand behind:
 * non-finite coordinates, a deflection or rotation beyond the beam model's validity (the generated
 * model_validity ratios), or a mass matrix that is no longer positive definite.  The caller discards the
 * communication step (fmi2Discard) with the message written here, before a Newton failure or a wrong
 * number can reach the importer. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "internal.h"
#include "linalg.h"

/* A pivot of the mass matrix's Cholesky factor below this fraction of its diagonal entry counts as lost
 * definiteness: ~1e-10 is where LU solves of the Newton matrix stop carrying usable digits. */
#define MASS_MATRIX_TINY 1e-10
/* The mass matrix is a sum of squares by construction (README "Why the second-order model is consistent"):
 * positive definite at small deflections.  It is factorised only once a link deflects beyond this
 * fraction of its validity limit (5 % of its length), where a wrong state would show first; below, the
 * check would cost one Newton-matrix evaluation per communication step for nothing. */
#define MASS_MATRIX_CHECK_FROM 0.25

fmi2Status fmu_guard_state(Instance *inst, double t, const double *u, int check_mass_matrix) {
    FmuData *d = &inst->d;
    if (!fmu_all_finite(d->q, N_Q) || !fmu_all_finite(d->v, N_Q)) {
        snprintf(inst->guard_reason, sizeof(inst->guard_reason), "the state is not finite at t = %.17g", t);
        return fmi2Discard;
    }
    double largest = 0.0;
#if N_VALIDITY > 0
    model_validity(d->q, u, d->p, inst->guard_g, &inst->work);
    for (int i = 0; i < N_VALIDITY; i++) {
        largest = fmax(largest, inst->guard_g[i]);
        if (!(inst->guard_g[i] <= 1.0)) {
            snprintf(inst->guard_reason, sizeof(inst->guard_reason),
                     "at t = %.17g the state left the beam model's validity: %s = %.4g (must stay <= 1: tip "
                     "deflections up to 20 %% of a link's length, tip rotations up to 0.35 rad); lower the loads "
                     "or stiffen the link", t, MODEL_VALIDITY_NAMES[i], inst->guard_g[i]);
            return fmi2Discard;
        }
    }
#endif
    if (check_mass_matrix && d->mass_matrix_guarded && (N_VALIDITY == 0 || largest > MASS_MATRIX_CHECK_FROM)) {
        const int failed = model_newton_matrix(d->q, d->v, d->alpha, u, d->p, 1.0, 0.0, 0.0, inst->guard_M,
                                               &inst->work);
        const int k = failed ? 1 : cholesky_factor(inst->guard_M, N_Q, MASS_MATRIX_TINY);
        if (k) {
            snprintf(inst->guard_reason, sizeof(inst->guard_reason),
                     "at t = %.17g the mass matrix lost positive definiteness (Cholesky pivot %d of %d): the "
                     "deflection is beyond what the link's shape functions represent", t, k, N_Q);
            return fmi2Discard;
        }
    }
    return fmi2OK;
}

/* Whether the mass matrix is guarded at all: only when it is positive definite at the start state.  A scene
 * may have massless directions by design (a twist without polar inertia, an elastic joint without motor
 * inertia): M is then singular everywhere, SS22's step matrix stays regular, and a zero pivot is not news.
 * A constant M (linear kinematics) cannot lose definiteness. */
static void energy_floor_init(Instance *inst);

void fmu_guard_init(Instance *inst, const double *u) {
    FmuData *d = &inst->d;
    d->energy_scale = 0.0;
    d->energy_last.available = 0;
    d->mass_matrix_guarded = 0;
    const int have_M = model_newton_matrix(d->q, d->v, d->alpha, u, d->p, 1.0, 0.0, 0.0, inst->guard_M,
                                           &inst->work) == 0;
    d->energy_floor = 0.0;
    if (have_M) energy_floor_init(inst);
    if (MODEL_JACOBIAN_CONSTANT) return;
    if (have_M && cholesky_factor(inst->guard_M, N_Q, MASS_MATRIX_TINY) == 0) {
        d->mass_matrix_guarded = 1;
    } else {
        fmu_log(inst, fmi2OK, LOG_EVENTS, "the mass matrix is singular at the start state (massless "
                "directions): its definiteness is not guarded");
    }
}

/* ====================================================================== energy balance
 *
 * Over a communication step [t0, t1] the mechanical energy E = T + V of the chain (its outputs
 * energy.kinetic and energy.potential) changes by the work the inputs do minus what dissipation takes:
 *     E(t1) - E(t0) = ∫ P dt - ∫ 2 R dt,   R >= 0 the Rayleigh dissipation function,
 * P the power of the inputs: every force input (a joint torque, a tip load) through the generalized force
 * Q it exerts on the free coordinates, Q = r(q, v, a, u with the force inputs zeroed) - r(q, v, a, u) (r
 * is affine in them), and every prescribed law through the torque it needs, τ, times its rate.  Its work
 * over the step is taken along the path, ½(Q0 + Q1)·(q1 - q0) + Σ ½(τ0 + τ1)(θ1 - θ0) -- exact for
 * constant forces, and blind to the velocity of a massless coordinate (an elastic joint's motor without
 * inertia), which SS22 leaves oscillating from step to step while its position follows the spring; the
 * trapezoid of Q·v in time counted that oscillation as work (-0.12 J for 0.14 mJ of energy on
 * benchmarks/hard_cases/massless_motor.toml).  A step whose
 * energy grows by more than that work plus the integrator's and the quadrature's error (the
 * tolerance below, docs/integrator.md "Energy balance") has gained energy from nowhere: SS22 went unstable
 * (order 4 beyond its bound, pumped unresolved modes) or the state is corrupt.  A negative kinetic energy
 * is never physical. */

/* The relative tolerance of the balance, against the energy that moved during the step (T0 + T1 + |ΔV| +
 * the work's magnitude) or, if more, the most any step of the run has moved: SS22's own energy error and
 * the trapezoid's quadrature error of the work over a communication step, (ω h)²/12 of it for power
 * oscillating at ω, stay below it for ω h <= 1.7; the examples' bench manoeuvres need at most 0.07
 * (docs/integrator.md "Energy balance").  Every step is judged, the first ones of a motion from rest too:
 * their error against the energy that moved is at most 3 % at 1 ms steps (a prescribed law from rest,
 * examples/aluminium_arm_smooth.toml; a torque step, examples/planar_chain_5.toml: 0.4 %).  The first
 * version skipped eight steps after a start, because a law moving with the wrong mean acceleration over each
 * step (fixed in ss22.c) made them err by 0.6 of it. */
#define ENERGY_GROWTH_TOLERANCE 0.25
/* Rounding: the energies are sums of many terms of size |T| + |V|. */
#define ENERGY_ROUNDING 1e-10
/* The energy below which the balance says nothing about stability.  SS22's Newton iteration stops when an
 * increment changes a rate by at most tolerance x nominal (ss22.c), so rates are resolved to that per internal
 * step, and a motion whose rates are smaller is mostly iteration error: the balance of a start from rest by a
 * torque ramped as t^3 (flexlink check's ME-vs-CS excitation on examples/two_link_payload.toml, 2 µs steps)
 * grew by ten times the work at 1e-27 J.  Steps that move less than the kinetic energy of rates
 * ENERGY_RESOLVED times that resolution per internal step, ½ Σ M_ii (k n tol nominal_i)² for n internal
 * steps, are not judged; an instability grows through it within a few steps and is judged from there. */
#define ENERGY_RESOLVED 10.0
/* The floor takes the Newton tolerance at most this loose: a user's solver.tolerance = 1e-4 would otherwise
 * raise it to about the whole energy of the examples' runs (tip rates of 0.1 m/s) and switch the balance
 * off.  A run that loose is judged as if its rates were resolved to 1e-8 of their nominal per second. */
#define ENERGY_FLOOR_TOLERANCE_MAX 1e-8
/* Model Exchange: the importer's tolerance, not SS22's, resolves the rates, and the FMU does not know it.
 * The floor takes 1e-4, fmpy's and most importers' default relative tolerance, applied to the nominal
 * values as their absolute tolerance is (CVODE at rtol 1e-9 gained 9× the work at 1e-15 J on
 * examples/fast_two_link.toml's t³ ramp from rest; explicit Euler blowing up at 1e-3 J is still judged). */
#define ENERGY_FLOOR_TOLERANCE_ME 1e-4

static int is_law_slot(int i) {
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) if (i >= MODEL_LAWS[k].u_offset && i < MODEL_LAWS[k].u_offset + 3) return 1;
#endif
    (void)i;
    return 0;
}

static int output_named(const char *name) {
    for (int k = 0; k < N_VARS; k++) {
        if (MODEL_VARS[k].kind == VAR_OUTPUT && strcmp(MODEL_VARS[k].name, name) == 0) return MODEL_VARS[k].index;
    }
    return -1;
}

/* The energy outputs and, law by law, the output of the torque it needs ("<joint>.tau", in the order of the
 * laws: both follow the joints).  A model without them (a hand-written one) is not energy-guarded. */
static void energy_init(Instance *inst) {
    int n_torques = 0;
    inst->energy_known = 1;
    inst->energy_kinetic = output_named("energy.kinetic");
    inst->energy_potential = output_named("energy.potential");
    for (int k = 0; k < N_VARS; k++) {
        const size_t n = strlen(MODEL_VARS[k].name);
        if (MODEL_VARS[k].kind == VAR_OUTPUT && n > 4 && strcmp(MODEL_VARS[k].name + n - 4, ".tau") == 0) {
            if (n_torques < N_LAWS) inst->law_torque[n_torques] = MODEL_VARS[k].index;
            n_torques++;
        }
    }
    if (n_torques != N_LAWS) inst->energy_kinetic = -1;
    inst->n_force_inputs = 0;
    for (int i = 0; i < N_U; i++) inst->n_force_inputs += !is_law_slot(i);
    if (inst->energy_kinetic < 0 || inst->energy_potential < 0) {
        inst->energy_kinetic = -1;
        fmu_log(inst, fmi2OK, LOG_EVENTS, "the model has no energy outputs: its energy balance is not guarded");
    }
}

/* The generalized forces of the force inputs and the laws' torques at the current state, with the outputs
 * d->y up to date.  r is affine in the acceleration and the force inputs enter it without it (a force does no
 * work through the inertia), so Q = r(q, v, a, u without force inputs) - r(q, v, a, u) is the same at every a:
 * both are taken at a = 0, where r_fresh says inst->r already holds r(q, v, 0, u) (fmu_update_outputs has
 * just computed it for the consistent acceleration).  inst->energy_r keeps r(q, v, 0, u without force
 * inputs), which fmu_energy_point_keep remembers.  Where B = dr/du is a constant, Q = -B u (model.h): no residual. */
static int input_forces(Instance *inst, EnergyPoint *e, int r_fresh) {
    FmuData *d = &inst->d;
    const double *y = d->y;
    memset(e->force, 0, sizeof(e->force));
    memcpy(e->q, d->q, sizeof(d->q));
    memcpy(e->v, d->v, sizeof(d->v));
    fmu_model_inputs(d, d->time, inst->u0);
    if (inst->n_force_inputs > 0 && !model_input_forces(inst->u0, e->force)) {
        memcpy(inst->energy_u, inst->u0, sizeof(inst->energy_u));
        for (int i = 0; i < N_U; i++) {
            if (!is_law_slot(i)) inst->energy_u[i] = 0.0;
        }
        if ((!r_fresh && model_residual(d->q, d->v, inst->zero, inst->u0, d->p, inst->r, &inst->work)) ||
            model_residual(d->q, d->v, inst->zero, inst->energy_u, d->p, inst->energy_r, &inst->work)) {
            return 1;
        }
        for (int i = 0; i < N_Q; i++) e->force[i] = inst->energy_r[i] - inst->r[i];
        /* a law's torque includes the reaction of the force inputs on its joint: its work is τ's without them */
        if (N_LAWS > 0) {
            if (model_outputs(d->q, d->v, d->acceleration, inst->energy_u, d->p, inst->energy_y, &inst->work)) {
                return 1;
            }
            y = inst->energy_y;
        }
    }
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) {
        e->law_torque[k] = y[inst->law_torque[k]];
        e->law_angle[k] = inst->u0[MODEL_LAWS[k].u_offset];
        e->law_rate[k] = inst->u0[MODEL_LAWS[k].u_offset + 1];
    }
#else
    (void)y;
#endif
    return 0;
}

/* The inputs' work from e0 to e1 and its magnitude (the sum of its terms' absolute values).  Force inputs:
 * along the path, the trapezoid in the forces.  Laws: their angle and rate are known exactly at both ends, so
 * Simpson's rule on τ θ' with τ linear in time and θ the cubic Hermite of its ends, exact for both (a law
 * starting from rest, τ ~ t and θ ~ t³, is where the trapezoids are 7-20 % off). */
static double input_work(const EnergyPoint *e0, const EnergyPoint *e1, int model_exchange, double *magnitude) {
    double work = 0.0, size = 0.0;
    for (int i = 0; i < N_Q; i++) {
        /* Model Exchange: the trapezoid of the power Q·v in time.  An explicit integrator moves q one step
         * after v (explicit Euler from rest: v grows in the first step, q in the next), so the path's
         * ½(Q0 + Q1)·Δq sees no work where the energy grew, and would refuse every start from rest; the
         * power trapezoid is Euler's own energy balance for a constant force (m h² a² (k + ½) both).
         * There is no massless coordinate in Model Exchange (fmi2GetDerivatives needs M regular). */
        const double w = model_exchange
                             ? 0.5 * (e0->force[i] * e0->v[i] + e1->force[i] * e1->v[i]) * (e1->time - e0->time)
                             : 0.5 * (e0->force[i] + e1->force[i]) * (e1->q[i] - e0->q[i]);
        work += w;
        size += fabs(w);
    }
#if N_LAWS > 0
    for (int k = 0; k < N_LAWS; k++) {
        const double h = e1->time - e0->time;
        const double rate_mid = 1.5 * (e1->law_angle[k] - e0->law_angle[k]) / h -
                                0.25 * (e0->law_rate[k] + e1->law_rate[k]);
        const double w = h / 6.0 * (e0->law_torque[k] * e0->law_rate[k] +
                                    2.0 * (e0->law_torque[k] + e1->law_torque[k]) * rate_mid +
                                    e1->law_torque[k] * e1->law_rate[k]);
        work += w;
        size += fabs(w);
    }
#endif
    *magnitude = size;
    return work;
}

fmi2Status fmu_energy_point(Instance *inst, EnergyPoint *e, const char *function) {
    FmuData *d = &inst->d;
    e->available = 0;
    if (!inst->energy_known) energy_init(inst);
    if (inst->energy_kinetic < 0) return fmi2OK;
    /* T(q, v), V(q) need no acceleration (unless the build marked them so); a law's torque, a reaction, does */
    const int full = N_LAWS > 0 || MODEL_OUTPUT_USES_ACCELERATION[inst->energy_kinetic] ||
                     MODEL_OUTPUT_USES_ACCELERATION[inst->energy_potential];
    const int r_fresh = full && d->outputs_valid != 1;             /* the full update evaluates r(q, v, 0, u) */
    const fmi2Status status = (full ? fmu_update_outputs : fmu_update_static_outputs)(inst, function);
    if (status > fmi2Warning) return status;
    e->time = d->time;
    e->kinetic = d->y[inst->energy_kinetic];
    e->potential = d->y[inst->energy_potential];
    if (input_forces(inst, e, r_fresh)) {
        return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", function, d->time);
    }
    e->available = 1;
    return fmi2OK;
}

/* An energy point inside a communication step, for a model without built-in laws: the energies need no
 * acceleration (T(q, v), V(q): tests/test_energy_guard.py checks every example's generated outputs) and the force
 * inputs' forces are -B u or residual differences at a = 0, so the outputs are evaluated at the step's mean
 * acceleration into a scratch array, without the consistent acceleration; d->y is left as it was (the step's end
 * evaluates it, fmu_energy_point).  A law's torque is a reaction, a function of the acceleration: with laws the
 * full point is taken. */
fmi2Status fmu_energy_point_inside(Instance *inst, EnergyPoint *e, const char *function) {
    FmuData *d = &inst->d;
    if (N_LAWS > 0) return fmu_energy_point(inst, e, function);
    e->available = 0;
    if (!inst->energy_known) energy_init(inst);
    if (inst->energy_kinetic < 0) return fmi2OK;
    /* input_forces evaluates the inputs at d->time into inst->u0 first; the outputs take the same */
    if (input_forces(inst, e, 0) ||
        model_outputs(d->q, d->v, d->alpha, inst->u0, d->p, inst->energy_y, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", function, d->time);
    }
    e->time = d->time;
    e->kinetic = inst->energy_y[inst->energy_kinetic];
    e->potential = inst->energy_y[inst->energy_potential];
    e->available = 1;
    return fmi2OK;
}

void fmu_energy_point_keep(Instance *inst, const EnergyPoint *e) {
    FmuData *d = &inst->d;
    inst->energy_end = *e;
    if (!e->available) return;
    memcpy(inst->energy_end_p, d->p, sizeof(inst->energy_end_p));
    memcpy(inst->energy_end_u, inst->u0, sizeof(inst->energy_end_u));     /* u(t) that input_forces used */
    memcpy(inst->energy_end_free, inst->energy_r, sizeof(inst->energy_end_free));
}

/* The kept end point describes the current time, state and parameters: bit for bit, whatever happened in
 * between (new inputs, a reset, an FMU state set, a parameter set and set back). */
static int at_energy_end(const Instance *inst) {
    const FmuData *d = &inst->d;
    const EnergyPoint *k = &inst->energy_end;
    return k->available && k->time == d->time && memcmp(k->q, d->q, sizeof(d->q)) == 0 &&
           memcmp(k->v, d->v, sizeof(d->v)) == 0 && memcmp(inst->energy_end_p, d->p, sizeof(inst->energy_end_p)) == 0;
}

/* The start of a communication step.  A host in a loop reads the outputs, sets new torques and steps again:
 * from the state where the last step ended, with only force inputs changed.  The energies are functions of
 * the coordinates, the rates, the parameters and the laws' slots, never of the acceleration or the force
 * inputs (T(q, v), V(q); tests/test_energy_guard.py checks every example's generated outputs), so they are
 * the kept point's, and only the forces of the new inputs are evaluated: one residual instead of the
 * outputs, the mass matrix and two residuals.  The same inputs reuse the point whole; a model with laws
 * whose force inputs changed (a law's torque depends on them through the acceleration), or anything else
 * that changed, takes the full fmu_energy_point. */
fmi2Status fmu_energy_point_start(Instance *inst, EnergyPoint *e, const char *function) {
    FmuData *d = &inst->d;
    if (!at_energy_end(inst)) return fmu_energy_point(inst, e, function);
    fmu_model_inputs(d, d->time, inst->u0);
    if (memcmp(inst->u0, inst->energy_end_u, sizeof(inst->energy_end_u)) == 0) {
        *e = inst->energy_end;
        return fmi2OK;
    }
    if (N_LAWS > 0) return fmu_energy_point(inst, e, function);
    *e = inst->energy_end;
    if (model_input_forces(inst->u0, e->force)) return fmi2OK;
    if (model_residual(d->q, d->v, inst->zero, inst->u0, d->p, inst->r, &inst->work)) {
        return fmu_error(inst, "%s: the model failed to evaluate at t = %.17g", function, d->time);
    }
    for (int i = 0; i < N_Q; i++) e->force[i] = inst->energy_end_free[i] - inst->r[i];
    return fmi2OK;
}

/* ½ Σ M_ii (tol nominal_i)² with M at the start state (inst->guard_M, before its factorisation): a scale,
 * not recomputed when parameters change. */
static void energy_floor_init(Instance *inst) {
    FmuData *d = &inst->d;
    double floor = 0.0;
    for (int i = 0; i < N_Q; i++) {
        const double tol = d->model_exchange ? ENERGY_FLOOR_TOLERANCE_ME
                                             : fmin(d->ss22.tolerance, ENERGY_FLOOR_TOLERANCE_MAX);
        const double rate = tol * MODEL_NOMINAL_Q[i];
        floor += 0.5 * fabs(inst->guard_M[i * N_Q + i]) * rate * rate;
    }
    d->energy_floor = isfinite(floor) ? floor : 0.0;
    fmu_log(inst, fmi2OK, LOG_EVENTS, "energy balance: a communication step of n internal steps that moves "
            "less than %g J x n^2 is not judged (what the Newton tolerance resolves)",
            d->energy_floor * ENERGY_RESOLVED * ENERGY_RESOLVED);
}

#define GUARDS_TEXT(x) #x
#define GUARDS_NUMBER(x) GUARDS_TEXT(x)   /* a generated limit of solver_settings.h spelled in a message */

/* What to change when the balance fails: the FMU's own integrator in Co-Simulation, the importer's in Model
 * Exchange. */
static const char *energy_advice(const Instance *inst) {
    return inst->d.model_exchange ? "a smaller step or a tighter tolerance of the importer's integrator (an "
                                    "implicit one for stiff models), or fewer shape functions"
                                  : "a smaller solver.step, solver.order = " GUARDS_NUMBER(SOLVER_ORDER_SS22)
                                    " or fewer shape functions";
}

void fmu_energy_forget(FmuData *d) {
    d->energy_last.available = 0;
}

fmi2Status fmu_guard_energy(Instance *inst, const EnergyPoint *e0, const EnergyPoint *e1, double internal_steps) {
    if (!e0->available || !e1->available) return fmi2OK;
    const double growth = (e1->kinetic + e1->potential) - (e0->kinetic + e0->potential);
    double work_size;
    const double work = input_work(e0, e1, inst->d.model_exchange, &work_size);
    const double moved = fabs(e0->kinetic) + fabs(e1->kinetic) + fabs(e1->potential - e0->potential) + work_size;
    const double rounding = ENERGY_ROUNDING * (fabs(e0->kinetic) + fabs(e1->kinetic) + fabs(e0->potential) +
                                               fabs(e1->potential));
    FmuData *d = &inst->d;
    const double scale = fmax(moved, d->energy_scale);
    const double bound = work + ENERGY_GROWTH_TOLERANCE * scale + rounding;
    d->energy_scale = scale;
    if (!isfinite(growth) || !isfinite(work) || !isfinite(moved)) {
        snprintf(inst->guard_reason, sizeof(inst->guard_reason), "at t = %.17g the energy balance has NaN or "
                 "infinite terms (energy.kinetic = %g J, energy.potential = %g J, the inputs' work %g J): a "
                 "coordinate, a rate or a force is not finite, the state is corrupt", e1->time, e1->kinetic,
                 e1->potential, work);
        return fmi2Discard;
    }
    if (!(e1->kinetic >= -rounding)) {
        snprintf(inst->guard_reason, sizeof(inst->guard_reason), "at t = %.17g the kinetic energy is negative "
                 "(energy.kinetic = %.6g J): the mass matrix is no longer a body's; use %s", e1->time, e1->kinetic,
                 energy_advice(inst));
        return fmi2Discard;
    }
    /* below what the Newton iteration resolves over this step's internal steps, nothing is judged */
    const double resolved = ENERGY_RESOLVED * fmax(internal_steps, 1.0);
    if (moved <= d->energy_floor * resolved * resolved) return fmi2OK;
    if (!(growth <= bound)) {
        snprintf(inst->guard_reason, sizeof(inst->guard_reason), "the energy balance failed over [%.17g, %.17g]: "
                 "the energy energy.kinetic + energy.potential grew by %.6g J where the inputs did %.6g J of work "
                 "(bound %.6g J, tolerance %g of the %.6g J that moved): the integrator gained energy; use %s",
                 e0->time, e1->time, growth, work, bound, ENERGY_GROWTH_TOLERANCE, moved, energy_advice(inst));
        return fmi2Discard;
    }
    return fmi2OK;
}
