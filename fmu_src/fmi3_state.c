/* fmi3_state.c -- the FMI 3.0 FMU state (get, set, free, serialize) and the directional and adjoint derivatives,
 * on the functions of cosimulation.h (fmu_state.c, derivatives.c).  See fmi3Functions.c for the layer's rules. */
#include <math.h>
#include "fmi3_internal.h"

/* ============================================================ FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    BEGIN("fmi3GetFMUState", PHASE_ANY);
    REQUIRE(FMUState != NULL, "fmi3GetFMUState", "FMUState is NULL");
    return s3(fmu_finish(inst, fmu_get_state(inst, FMUState)));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    BEGIN("fmi3SetFMUState", PHASE_ANY);
    return s3(fmu_finish(inst, fmu_set_state(inst, FMUState)));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    BEGIN("fmi3FreeFMUState", PHASE_ANY);
    REQUIRE(FMUState != NULL, "fmi3FreeFMUState", "FMUState is NULL");
    return s3(fmu_finish(inst, fmu_free_state(inst, FMUState)));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    BEGIN("fmi3SerializedFMUStateSize", PHASE_ANY);
    REQUIRE(size != NULL, "fmi3SerializedFMUStateSize", "size is NULL");
    REQUIRE(FMUState != NULL && ((const SavedState *)FMUState)->magic == STATE_MAGIC,
            "fmi3SerializedFMUStateSize", "not a state of this FMU");
    *size = fmu_serialized_size();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    BEGIN("fmi3SerializeFMUState", PHASE_ANY);
    REQUIRE(serializedState != NULL, "fmi3SerializeFMUState", "serializedState is NULL");
    return s3(fmu_finish(inst, fmu_serialize(inst, FMUState, (fmi2Byte *)serializedState, size)));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    BEGIN("fmi3DeserializeFMUState", PHASE_ANY);
    REQUIRE(serializedState != NULL && FMUState != NULL, "fmi3DeserializeFMUState",
            "serializedState or FMUState is NULL");
    return s3(fmu_finish(inst, fmu_deserialize(inst, (const fmi2Byte *)serializedState, size, FMUState)));
}

/* ====================================================== directional and adjoint derivatives */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    fmi2Status status;
    Refs u, k;
    BEGIN("fmi3GetDirectionalDerivative", DERIVATIVES);
    REQUIRE((nUnknowns == 0 || (unknowns != NULL && sensitivity != NULL)) &&
            (nKnowns == 0 || (knowns != NULL && seed != NULL)), "fmi3GetDirectionalDerivative",
            "a value reference or value array is NULL");
    if (fmu3_expand(inst, "fmi3GetDirectionalDerivative (unknowns, nSensitivity)", unknowns, nUnknowns, nSensitivity,
                    &u) != fmi2OK) {
        return fmi3Error;
    }
    status = fmu3_expand(inst, "fmi3GetDirectionalDerivative (knowns, nSeed)", knowns, nKnowns, nSeed, &k);
    if (status == fmi2OK) status = fmu_directional_derivative(inst, u.vr, u.n, k.vr, k.n, seed, sensitivity);
    free(u.owned);
    free(k.owned);
    return s3(fmu_finish(inst, status));
}

/* sensitivity = J^T seed with J = d(unknowns)/d(knowns), one column of J per known element from the forward
 * derivative (the model has no reverse-mode function): one forward evaluation per known element, exact, not
 * faster than the directional derivative. */
fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    const fmi2Real one = 1.0;
    fmi2Status status;
    double *column = NULL;
    Refs u, k;
    BEGIN("fmi3GetAdjointDerivative", DERIVATIVES);
    REQUIRE((nUnknowns == 0 || (unknowns != NULL && seed != NULL)) &&
            (nKnowns == 0 || (knowns != NULL && sensitivity != NULL)), "fmi3GetAdjointDerivative",
            "a value reference or value array is NULL");
    for (size_t i = 0; i < nSeed; i++) {
        REQUIRE(isfinite(seed[i]), "fmi3GetAdjointDerivative", "a seed is NaN or infinite");
    }
    if (fmu3_expand(inst, "fmi3GetAdjointDerivative (unknowns, nSeed)", unknowns, nUnknowns, nSeed, &u) != fmi2OK) {
        return fmi3Error;
    }
    status = fmu3_expand(inst, "fmi3GetAdjointDerivative (knowns, nSensitivity)", knowns, nKnowns, nSensitivity, &k);
    if (status == fmi2OK) {
        column = (double *)calloc(u.n > 0 ? u.n : 1, sizeof(double));
        if (column == NULL) status = fmu_fail(inst, "fmi3GetAdjointDerivative", "out of memory");
    }
    for (size_t j = 0; j < k.n && status <= fmi2Warning; j++) {
        fmi2Status s = fmu_directional_derivative(inst, u.vr, u.n, &k.vr[j], 1, &one, column);
        if (s > status) status = s;
        sensitivity[j] = 0.0;
        for (size_t i = 0; i < u.n; i++) sensitivity[j] += seed[i] * column[i];
    }
    free(column);
    free(u.owned);
    free(k.owned);
    return s3(fmu_finish(inst, status));
}
