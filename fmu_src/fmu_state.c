/* fmu_state.c -- FMU states: get, set and free copies of FmuData, and their serialisation (header,
 * checksum, validation on the way back in).  See cosimulation.h. */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include "internal.h"

/* ================================================================= FMU state */

static int state_ok(const SavedState *s) {
    return s != NULL && s->magic == STATE_MAGIC;
}

/* A new state, zeroed, in inst's list; NULL when out of memory. */
static SavedState *new_state(Instance *inst) {
    SavedState *s = (SavedState *)inst->cb.allocateMemory(1, sizeof(SavedState));
    if (s == NULL) return NULL;
    memset(s, 0, sizeof(*s));
    s->magic = STATE_MAGIC;
    s->owner = inst;
    s->next = inst->states;
    if (s->next != NULL) s->next->prev = s;
    inst->states = s;
    return s;
}

/* Out of its owner's list, and freed with the owner's allocator. */
static void release_state(SavedState *s) {
    Instance *owner = s->owner;
    if (s->prev != NULL) s->prev->next = s->next; else owner->states = s->next;
    if (s->next != NULL) s->next->prev = s->prev;
    s->magic = 0;
    owner->cb.freeMemory(s);
}

void fmu_free_all_states(Instance *inst) {
    while (inst->states != NULL) release_state(inst->states);
}

fmi2Status fmu_get_state(Instance *inst, fmi2FMUstate *state) {
    SavedState *s = (SavedState *)*state;
    if (s != NULL && !state_ok(s)) {
        return fmu_error(inst, "fmi2GetFMUstate: *FMUstate is neither NULL nor a state of this FMU");
    }
    if (s == NULL && (s = new_state(inst)) == NULL) {
        return fmu_error(inst, "fmi2GetFMUstate: out of memory");
    }
    memcpy(&s->d, &inst->d, sizeof(s->d));
    *state = s;
    return fmi2OK;
}

fmi2Status fmu_set_state(Instance *inst, fmi2FMUstate state) {
    const SavedState *s = (const SavedState *)state;
    if (!state_ok(s)) {
        return fmu_error(inst, "fmi2SetFMUstate: not a state of this FMU (NULL or freed)");
    }
    memcpy(&inst->d, &s->d, sizeof(inst->d));
    return fmi2OK;
}

fmi2Status fmu_free_state(Instance *inst, fmi2FMUstate *state) {
    SavedState *s = (SavedState *)*state;
    if (s == NULL) return fmi2OK;
    if (!state_ok(s)) {
        return fmu_error(inst, "fmi2FreeFMUstate: not a state of this FMU (already freed?)");
    }
    release_state(s);
    *state = NULL;
    return fmi2OK;
}

/* Serialized layout: magic (8 bytes) | MODEL_GUID with its NUL | payload size (uint64) |
 * FNV-1a checksum of the payload (uint64) | the FmuData bytes.  The same build (GUID) only, but across
 * platforms of one byte order and alignment: FmuData holds no pointer and no `long` (32 bits on win64),
 * so a state written by the linux64 library restores in the win64 one (tests/test_windows.py). */
static const char SERIAL_MAGIC[8] = {'F', 'L', 'X', 'S', 'T', 'A', 'T', '1'};
#define GUID_BYTES sizeof(MODEL_GUID)
#define HEADER_BYTES (sizeof(SERIAL_MAGIC) + GUID_BYTES + 2 * sizeof(uint64_t))

static uint64_t checksum(const unsigned char *p, size_t n) {
    uint64_t h = 14695981039346656037ULL;
    for (size_t i = 0; i < n; i++) {
        h ^= p[i];
        h *= 1099511628211ULL;
    }
    return h;
}

size_t fmu_serialized_size(void) {
    return HEADER_BYTES + sizeof(FmuData);
}

fmi2Status fmu_serialize(Instance *inst, fmi2FMUstate state, fmi2Byte buffer[], size_t size) {
    const SavedState *s = (const SavedState *)state;
    const uint64_t payload = sizeof(FmuData);
    uint64_t sum;
    unsigned char *b = (unsigned char *)buffer;
    if (!state_ok(s)) {
        return fmu_error(inst, "fmi2SerializeFMUstate: not a state of this FMU");
    }
    if (size < fmu_serialized_size()) {
        return fmu_error(inst, "fmi2SerializeFMUstate: buffer of %lu bytes, %lu needed", (unsigned long)size,
                         (unsigned long)fmu_serialized_size());
    }
    sum = checksum((const unsigned char *)&s->d, sizeof(s->d));
    memcpy(b, SERIAL_MAGIC, sizeof(SERIAL_MAGIC));
    b += sizeof(SERIAL_MAGIC);
    memcpy(b, MODEL_GUID, GUID_BYTES);
    b += GUID_BYTES;
    memcpy(b, &payload, sizeof(payload));
    b += sizeof(payload);
    memcpy(b, &sum, sizeof(sum));
    b += sizeof(sum);
    memcpy(b, &s->d, sizeof(s->d));
    return fmi2OK;
}

/* Beyond the checksum: nothing in a state may lead to an out-of-bounds access. */
/* The recurrence start's data (ss22.h, SS22Recurrence): what a corrupted state could make it read or write. */
static int invalid_recurrence(const SS22 *s) {
    const SS22Recurrence *r = &s->rec;
    if ((r->valid & ~1) || r->depth < 0 || r->depth > SS22_RECURRENCE_ORDER + 1 || r->u_depth < 0 || r->u_depth > 2 ||
        r->order < 0 || r->order > SS22_RECURRENCE_ORDER ||
        !fmu_all_finite(r->order_score, SS22_RECURRENCE_ORDER + 1) ||
        r->judged < 0 || r->judged > SS22_RECURRENCE_FRESH || !isfinite(r->log_fresh) || !isfinite(r->log_miss) ||
        !(fabs(r->bias) <= 1.0) || r->made > s->steps + 1 || !fmu_all_finite(r->u_last, N_U > 0 ? N_U : 1) ||
        !fmu_all_finite(r->u_before, N_U > 0 ? N_U : 1) || !fmu_all_finite(r->misses, N_Q * (SS22_RECURRENCE_ORDER + 1)))
        return 1;
    return r->valid && !(r->dt > 0.0 && isfinite(r->dt) && fmu_all_finite(r->P, N_Q * N_Q) &&
                         fmu_all_finite(r->G, N_Q * N_Q) && fmu_all_finite(r->U, N_Q * (N_U > 0 ? N_U : 1)) &&
                         fmu_all_finite(r->inverse, N_Q * N_Q));
}

/* Order 4's starts (cs_step.c): a vote is a running mean of +-1, a kept size is positive, a miss finite. */
static int invalid_richardson(const RichardsonStarts *r) {
    int bad = (r->valid & ~1) || (r->valid && !(r->dt > 0.0)) || !isfinite(r->dt) ||
              !fmu_all_finite(r->alpha_half, N_Q);
    for (int k = 0; k < 3; k++) bad = bad || !fmu_all_finite(r->miss[k], N_Q) || !(fabs(r->bias[k]) <= 1.0);
    return bad;
}

static const char *invalid_data(const FmuData *d) {
    const int phases[] = {PHASE_INSTANTIATED, PHASE_INITIALIZATION, PHASE_STEP, PHASE_TERMINATED, PHASE_ERROR,
                          PHASE_FATAL, PHASE_EVENT, PHASE_CONTINUOUS};
    int phase_ok = 0;
    for (size_t k = 0; k < sizeof(phases) / sizeof(phases[0]); k++) phase_ok |= d->phase == phases[k];
    if (!phase_ok) return "state machine";
    if ((d->acceleration_ok | d->stop_time_defined | d->experiment_tolerance_defined | d->model_exchange |
         d->mass_matrix_guarded | d->omega_max_known) & ~1 || d->outputs_valid < 0 || d->outputs_valid > 2)
        return "flags";
    if (d->ss22.max_iterations < 0 || d->ss22.max_iterations > 1000) return "solver settings";
    if (!(d->energy_scale >= 0.0 && isfinite(d->energy_scale)) || (d->energy_last.available & ~1) ||
        !(d->energy_floor >= 0.0 && isfinite(d->energy_floor)))
        return "energy balance";
    if (d->ss22.depth < 0 || d->ss22.depth > 3 ||
        (d->ss22.depth > 0 && !(d->ss22.dt_last > 0.0 && d->ss22.dt_before > 0.0 &&
                                isfinite(d->ss22.dt_last + d->ss22.dt_before) &&
                                fmu_all_finite(d->ss22.alpha_last, N_Q) && fmu_all_finite(d->ss22.alpha_before, N_Q))))
        return "solver history";
    if ((d->ss22.parabola & ~1) || !(fabs(d->ss22.predictor_bias) <= 1.0) ||
        (d->ss22.depth == 3 && !(d->ss22.dt_older > 0.0 && isfinite(d->ss22.dt_older) &&
                                 fmu_all_finite(d->ss22.alpha_older, N_Q))))
        return "solver history";
    for (int k = 0; k < SS22_CACHE; k++) {
        const SS22Factor *f = &d->ss22.cache[k];
        if (f->valid & ~1) return "solver cache";
        if (f->valid && !((f->rate == -1.0 || (f->rate >= 0.0 && isfinite(f->rate))) &&
                          f->confirmed >= 0 && f->confirmed <= SS22_RATE_CONFIRMATIONS && f->estimated >= 0 &&
                          f->confirmed_first >= 0 && f->confirmed_first <= SS22_RATE_CONFIRMATIONS &&
                          f->estimated <= SS22_RATE_MEASURE_EVERY << (f->confirmed > f->confirmed_first ?
                                                                      f->confirmed : f->confirmed_first) &&
                          f->waste >= 0.0 && isfinite(f->waste) && f->waste_full >= 0.0 && isfinite(f->waste_full) &&
                          (f->first[0] == -1.0 || (f->first[0] >= 0.0 && isfinite(f->first[0]))) &&
                          (f->first[1] == -1.0 || (f->first[1] >= 0.0 && isfinite(f->first[1]))) &&
                          (f->first[2] == -1.0 || (f->first[2] >= 0.0 && isfinite(f->first[2]))) &&
                          f->made <= d->ss22.steps))
            return "solver cache";
        for (int i = 0; i < N_Q && f->valid; i++) {
            if (f->piv[i] < i || f->piv[i] >= N_Q) return "solver cache";
        }
#if SS22_MASS_UPDATE
        if (f->valid && !fmu_all_finite(f->rest, N_Q * N_Q)) return "solver cache";   /* J - M (mass_update.c) */
#endif
    }
    if (invalid_recurrence(&d->ss22)) return "solver recurrence";
    if (invalid_richardson(&d->richardson)) return "order-4 starts";
    if (d->mass.valid & ~1) return "kept mass matrix";
    for (int i = 0; i < N_Q && d->mass.valid; i++) {
        if (d->mass.piv[i] < i || d->mass.piv[i] >= N_Q) return "kept mass matrix";
    }
    if (!isfinite(d->time) || !fmu_all_finite(d->q, N_Q) || !fmu_all_finite(d->v, N_Q)) return "time or state";
    if (d->omega_max_known && !(d->omega_max >= 0.0 && isfinite(d->omega_max))) return "highest frequency";
    return NULL;
}

fmi2Status fmu_deserialize(Instance *inst, const fmi2Byte buffer[], size_t size, fmi2FMUstate *state) {
    const unsigned char *b = (const unsigned char *)buffer;
    uint64_t payload, sum;
    SavedState *s, *target = (SavedState *)*state;
    const char *bad;
    char why[512];
    if (target != NULL && !state_ok(target)) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: *FMUstate is neither NULL nor a state of "
                         "this FMU");
    }
    if (size != fmu_serialized_size()) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: %lu bytes, a state of this FMU has %lu",
                         (unsigned long)size, (unsigned long)fmu_serialized_size());
    }
    if (memcmp(b, SERIAL_MAGIC, sizeof(SERIAL_MAGIC)) != 0) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: not a serialized flexlink FMU state");
    }
    b += sizeof(SERIAL_MAGIC);
    if (memcmp(b, MODEL_GUID, GUID_BYTES) != 0) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state belongs to another FMU "
                         "(GUID differs from %s)", MODEL_GUID);
    }
    b += GUID_BYTES;
    memcpy(&payload, b, sizeof(payload));
    b += sizeof(payload);
    memcpy(&sum, b, sizeof(sum));
    b += sizeof(sum);
    if (payload != sizeof(FmuData)) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state was written by another build "
                         "of this FMU (payload size differs)");
    }
    if (checksum(b, sizeof(FmuData)) != sum) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state is corrupted (checksum)");
    }
    s = target != NULL ? target : new_state(inst);      /* reuse the host's state, as fmi2GetFMUstate does */
    if (s == NULL) {
        return fmu_error(inst, "fmi2DeSerializeFMUstate: out of memory");
    }
    /* validated in the doStep backup (scratch outside fmi2DoStep) before it replaces anything */
    memcpy(&inst->backup, b, sizeof(inst->backup));
    if ((bad = invalid_data(&inst->backup)) != NULL ||
        (bad = fmu_invalid_values(inst, &inst->backup, why, sizeof(why))) != NULL) {
        if (target == NULL) release_state(s);
        return fmu_error(inst, "fmi2DeSerializeFMUstate: the state is invalid (%s)", bad);
    }
    memcpy(&s->d, &inst->backup, sizeof(s->d));
    *state = s;
    return fmi2OK;
}
