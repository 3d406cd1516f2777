/* fmi3_internal.h -- what the files of the FMI 3.0 layer share (fmi3Functions.c and the fmi3_*.c beside it):
 * the call prologue (instance, logging of the call, phase check), the phases each kind of call is allowed in,
 * the status translation, the generated array layout (fmi3_layout.c) and the expansion of FMI 3 value
 * references into FMI 2 ones.  Compiled into an FMI 3 FMU only; see fmi3Functions.c for the layer's rules. */
#ifndef FLEXLINK_FMI3_INTERNAL_H
#define FLEXLINK_FMI3_INTERNAL_H

#include <stdlib.h>
#include "fmi3Functions.h"
#include "cosimulation.h"

#define TIME_VR ((fmi3ValueReference)N_VARS)   /* the independent variable "time" */

/* fmi3_layout.c (generated): values of FMI 3 value reference vr < N_VARS: 1 a scalar, n an array of the FMI 2
 * references vr .. vr+n-1, 0 a later element of an array (not an FMI 3 variable); and its FMI 3 type */
extern const int FMI3_ELEMENTS[N_VARS];
extern const unsigned char FMI3_TYPES[N_VARS];
enum { FMI3_FLOAT64, FMI3_INT32, FMI3_ENUMERATION };   /* the codes of FMI3_TYPES */

#define SETTABLE (PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS)
#define READABLE (PHASE_INITIALIZATION | PHASE_STEP | PHASE_TERMINATED | PHASE_ERROR | PHASE_EVENT | \
                  PHASE_CONTINUOUS)
#define ME_READABLE (PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED | PHASE_ERROR)
#define DERIVATIVES (PHASE_INITIALIZATION | PHASE_STEP | PHASE_EVENT | PHASE_CONTINUOUS | PHASE_TERMINATED)

static inline fmi3Status s3(fmi2Status status) {
    return (fmi3Status)status;
}

#define BEGIN(function, phases)                                                     \
    Instance *inst = fmu_instance_of(instance);                                     \
    if (inst == NULL) return fmi3Error;                                             \
    if (fmu_logs(inst, LOG_ALL)) fmu_log(inst, fmi2OK, LOG_ALL, "%s", function);    \
    if (!fmu_allowed(inst, function, phases)) return fmi3Error

#define REQUIRE(condition, function, message) \
    if (!(condition)) return s3(fmu_fail(inst, function, message))

#define ME_BEGIN(function, phases)                                                          \
    BEGIN(function, phases);                                                                \
    if (!inst->d.model_exchange) {                                                          \
        return s3(fmu_fail(inst, function, "a Model Exchange function, but this instance is Co-Simulation")); \
    }

#define NOT_SUPPORTED(function, why)                     \
    Instance *inst = fmu_instance_of(instance);          \
    if (inst == NULL) return fmi3Error;                  \
    return s3(fmu_fail(inst, function, why))

/* FMI 3 value references expanded into FMI 2 ones (time and unknown references pass through, one value each, for
 * the functions behind to answer); `vr` points at the caller's array when no reference is an array. */
typedef struct {
    const fmi2ValueReference *vr;
    fmi2ValueReference *owned;
    size_t n;
} Refs;

/* refs = vr[0..nvr) expanded; expected: the number of values the caller passed (nValues, nSeed, ...); the
 * caller frees refs->owned. */
fmi2Status fmu3_expand(Instance *inst, const char *function, const fmi3ValueReference vr[], size_t nvr,
                       size_t expected, Refs *refs);

#endif /* FLEXLINK_FMI3_INTERNAL_H */
