/* calls.c -- the call-sequence rules that the FMI 2 and FMI 3 layers (fmi2Functions.c, fmi3Functions.c) share:
 * which pointer is a live instance, which state a function may be called in, and the error state an error
 * leaves (FMI 2.0 section 2.1.3; FMI 3.0 section 2.3.1: the same in both).  See cosimulation.h. */
#include <string.h>
#include "internal.h"

Instance *fmu_instance_of(void *c) {
    Instance *inst = (Instance *)c;
    return inst != NULL && inst->magic == INSTANCE_MAGIC ? inst : NULL;
}

fmi2Status fmu_finish(Instance *inst, fmi2Status status) {
    if (status == fmi2Error) inst->d.phase = PHASE_ERROR;
    else if (status == fmi2Fatal) inst->d.phase = PHASE_FATAL;
    return status;
}

fmi2Status fmu_fail(Instance *inst, const char *function, const char *message) {
    fmu_error(inst, "%s: %s", function, message);
    return fmu_finish(inst, fmi2Error);
}

int fmu_allowed(Instance *inst, const char *function, int phases) {
    static const int all[] = {PHASE_INSTANTIATED, PHASE_INITIALIZATION, PHASE_STEP, PHASE_EVENT,
                              PHASE_CONTINUOUS, PHASE_TERMINATED, PHASE_ERROR};
    char list[200] = "";
    if (inst->d.phase & phases) return 1;
    for (size_t k = 0; k < sizeof(all) / sizeof(all[0]); k++) {
        if (phases & all[k]) {
            if (list[0] != '\0') strcat(list, ", ");
            strcat(list, fmu_phase_name(all[k]));
        }
    }
    fmu_error(inst, "%s: not allowed in state %s (allowed in: %s)", function, fmu_phase_name(inst->d.phase),
              list);
    fmu_finish(inst, fmi2Error);
    return 0;
}
