/* fmi3_variables.c -- the FMI 3.0 getters and setters: value references expanded from FMI 3 arrays into FMI 2
 * references (FMI3_ELEMENTS), each reference read and set with its own type's functions (FMI3_TYPES), and the
 * types this FMU has no variables of.  See fmi3Functions.c for the layer's rules. */
#include <string.h>
#include "fmi3_internal.h"

static const char *const TYPE_NAME[] = {"Float64", "Int32", "Enumeration"};
static const char *const TYPE_API[] = {"fmi3GetFloat64/fmi3SetFloat64", "fmi3GetInt32/fmi3SetInt32",
                                       "fmi3GetInt64/fmi3SetInt64"};

/* ================================================================= arrays */

/* The number of values of reference vr, or 0 after an error message (vr is a later element of an array). */
static size_t values_of(Instance *inst, const char *function, fmi3ValueReference vr) {
    fmi3ValueReference head = vr;
    if (vr >= N_VARS || FMI3_ELEMENTS[vr] > 0) return vr >= N_VARS ? 1 : (size_t)FMI3_ELEMENTS[vr];
    while (head > 0 && FMI3_ELEMENTS[head] == 0) head--;
    fmu_error(inst, "%s: value reference %u (FMI 2's %s) is not a variable of this FMI 3.0 FMU: it is element %u of "
              "the array at value reference %u, read and set through that reference", function, (unsigned)vr,
              MODEL_VARS[vr].name, (unsigned)(vr - head + 1), (unsigned)head);
    return 0;
}

/* refs = vr[0..nvr) expanded; expected: the number of values the caller passed (nValues, nSeed, ...). */
fmi2Status fmu3_expand(Instance *inst, const char *function, const fmi3ValueReference vr[], size_t nvr,
                       size_t expected, Refs *refs) {
    size_t total = 0, k, j = 0;
    refs->vr = vr;
    refs->owned = NULL;
    refs->n = nvr;
    for (size_t i = 0; i < nvr; i++) {
        k = values_of(inst, function, vr[i]);
        if (k == 0) return fmu_finish(inst, fmi2Error);
        total += k;
    }
    if (total != expected) {
        fmu_error(inst, "%s: the value references hold %lu values, not %lu (an array holds as many values as its "
                  "<Dimension>)", function, (unsigned long)total, (unsigned long)expected);
        return fmu_finish(inst, fmi2Error);
    }
    if (total == nvr) return fmi2OK;
    refs->owned = (fmi2ValueReference *)calloc(total, sizeof(fmi2ValueReference));
    if (refs->owned == NULL) return fmu_fail(inst, function, "out of memory");
    for (size_t i = 0; i < nvr; i++) {
        for (k = 0; k < values_of(inst, function, vr[i]); k++) refs->owned[j++] = vr[i] + (fmi2ValueReference)k;
    }
    refs->vr = refs->owned;
    refs->n = total;
    return fmi2OK;
}

/* Every reference is of the function's type (time is a Float64; an unknown reference passes, for the functions
 * behind to refuse): the FMI 2 layer's leniency (fmi2GetReal on solver.order) is not carried into FMI 3. */
static fmi2Status of_type(Instance *inst, const char *function, const fmi3ValueReference vr[], size_t nvr, int type) {
    for (size_t i = 0; i < nvr; i++) {
        const int is = vr[i] < N_VARS ? FMI3_TYPES[vr[i]] : FMI3_FLOAT64;
        if (vr[i] > N_VARS || is == type) continue;
        fmu_error(inst, "%s: %s (value reference %u) is %s %s: read and set it with %s", function,
                  vr[i] < N_VARS ? MODEL_VARS[vr[i]].name : "time", (unsigned)vr[i],
                  is == FMI3_ENUMERATION ? "an" : "a", TYPE_NAME[is], TYPE_API[is]);
        return fmu_finish(inst, fmi2Error);
    }
    return fmi2OK;
}

/* ======================================================= getting and setting values */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          fmi3Float64 values[], size_t nValues) {
    fmi2Status status = fmi2OK, one;
    Refs refs;
    BEGIN("fmi3GetFloat64", READABLE);
    REQUIRE(nValueReferences == 0 || (valueReferences != NULL && values != NULL), "fmi3GetFloat64",
            "valueReferences or values is NULL");
    if (of_type(inst, "fmi3GetFloat64", valueReferences, nValueReferences, FMI3_FLOAT64) != fmi2OK) return fmi3Error;
    if (fmu3_expand(inst, "fmi3GetFloat64", valueReferences, nValueReferences, nValues, &refs) != fmi2OK) {
        return fmi3Error;
    }
    status = fmu_update_outputs_for(inst, "fmi3GetFloat64", refs.vr, refs.n);    /* once for all references */
    for (size_t i = 0; i < refs.n && status <= fmi2Warning; i++) {
        if (refs.vr[i] == TIME_VR) {
            values[i] = inst->d.time;
            continue;
        }
        one = fmu_get_real(inst, &refs.vr[i], 1, &values[i]);
        if (one > status) status = one;
        if (one > fmi2Warning) break;
    }
    free(refs.owned);
    return s3(status > fmi2Warning ? fmu_finish(inst, status) : status);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          const fmi3Float64 values[], size_t nValues) {
    fmi2Status status;
    Refs refs;
    BEGIN("fmi3SetFloat64", SETTABLE);
    REQUIRE(nValueReferences == 0 || (valueReferences != NULL && values != NULL), "fmi3SetFloat64",
            "valueReferences or values is NULL");
    for (size_t i = 0; i < nValueReferences; i++) {
        REQUIRE(valueReferences[i] != TIME_VR, "fmi3SetFloat64",
                "time is the independent variable: Co-Simulation advances it with fmi3DoStep, Model Exchange sets "
                "it with fmi3SetTime");
    }
    if (of_type(inst, "fmi3SetFloat64", valueReferences, nValueReferences, FMI3_FLOAT64) != fmi2OK) return fmi3Error;
    if (fmu3_expand(inst, "fmi3SetFloat64", valueReferences, nValueReferences, nValues, &refs) != fmi2OK) {
        return fmi3Error;
    }
    status = fmu_set_real(inst, refs.vr, refs.n, values);
    free(refs.owned);
    return s3(fmu_finish(inst, status));
}

/* Int32 and Int64 (the Enumeration solver.order): one value per reference, kept as fmi2Integer behind. */
static fmi3Status get_integers(Instance *inst, const char *function, int type, const fmi3ValueReference vr[],
                               size_t nvr, fmi3Int32 *values32, fmi3Int64 *values64, size_t nValues) {
    fmi2Integer one;
    fmi2Status status;
    REQUIRE(nvr == 0 || (vr != NULL && (values32 != NULL || values64 != NULL)), function,
            "valueReferences or values is NULL");
    REQUIRE(nValues == nvr, function, "nValues must equal nValueReferences (no integer arrays)");
    if (of_type(inst, function, vr, nvr, type) != fmi2OK) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) {
        status = fmu_get_integer(inst, &vr[i], 1, &one);
        if (status > fmi2Warning) return s3(fmu_finish(inst, status));
        if (values32 != NULL) values32[i] = (fmi3Int32)one;
        else values64[i] = (fmi3Int64)one;
    }
    return fmi3OK;
}

static fmi3Status set_integers(Instance *inst, const char *function, int type, const fmi3ValueReference vr[],
                               size_t nvr, const fmi3Int32 *values32, const fmi3Int64 *values64, size_t nValues) {
    fmi2Integer *values;
    fmi2Status status;
    REQUIRE(nvr == 0 || (vr != NULL && (values32 != NULL || values64 != NULL)), function,
            "valueReferences or values is NULL");
    REQUIRE(nValues == nvr, function, "nValues must equal nValueReferences (no integer arrays)");
    if (of_type(inst, function, vr, nvr, type) != fmi2OK) return fmi3Error;
    values = (fmi2Integer *)calloc(nvr > 0 ? nvr : 1, sizeof(fmi2Integer));
    REQUIRE(values != NULL, function, "out of memory");
    for (size_t i = 0; i < nvr; i++) {
        const fmi3Int64 x = values32 != NULL ? (fmi3Int64)values32[i] : values64[i];
        if (x < -2147483647 - 1 || x > 2147483647) {
            free(values);
            fmu_error(inst, "%s: %s = %lld: not a value of its type", function,
                      vr[i] < N_VARS ? MODEL_VARS[vr[i]].name : "?", (long long)x);
            return s3(fmu_finish(inst, fmi2Error));
        }
        values[i] = (fmi2Integer)x;
    }
    status = fmu_set_integer(inst, vr, nvr, values);
    free(values);
    return s3(fmu_finish(inst, status));
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Int32 values[], size_t nValues) {
    BEGIN("fmi3GetInt32", READABLE);
    return get_integers(inst, "fmi3GetInt32", FMI3_INT32, valueReferences, nValueReferences, values, NULL, nValues);
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Int32 values[], size_t nValues) {
    BEGIN("fmi3SetInt32", SETTABLE);
    return set_integers(inst, "fmi3SetInt32", FMI3_INT32, valueReferences, nValueReferences, values, NULL, nValues);
}

fmi3Status fmi3GetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Int64 values[], size_t nValues) {
    BEGIN("fmi3GetInt64", READABLE);
    return get_integers(inst, "fmi3GetInt64", FMI3_ENUMERATION, valueReferences, nValueReferences, NULL, values,
                        nValues);
}

fmi3Status fmi3SetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Int64 values[], size_t nValues) {
    BEGIN("fmi3SetInt64", SETTABLE);
    return set_integers(inst, "fmi3SetInt64", FMI3_ENUMERATION, valueReferences, nValueReferences, NULL, values,
                        nValues);
}

/* The types this FMU has no variable of: any value reference is unknown. */
static fmi3Status no_variables(Instance *inst, const char *function, const fmi3ValueReference vr[], size_t nvr) {
    if (nvr == 0) return fmi3OK;
    if (vr == NULL) return s3(fmu_fail(inst, function, "valueReferences is NULL"));
    fmu_error(inst, "%s: unknown value reference %u (this FMU has Float64 and Enumeration variables only)", function,
              (unsigned)vr[0]);
    return s3(fmu_finish(inst, fmi2Error));
}

/* fmi3Get<T> and fmi3Set<T> of the types without variables. */
#define NO_VARIABLES(T, CT)                                                                                        \
    fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                      \
                          size_t nValueReferences, CT values[], size_t nValues) {                                  \
        (void)values; (void)nValues;                                                                               \
        BEGIN("fmi3Get" #T, READABLE);                                                                             \
        return no_variables(inst, "fmi3Get" #T, valueReferences, nValueReferences);                               \
    }                                                                                                              \
    fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                      \
                          size_t nValueReferences, const CT values[], size_t nValues) {                            \
        (void)values; (void)nValues;                                                                               \
        BEGIN("fmi3Set" #T, SETTABLE);                                                                             \
        return no_variables(inst, "fmi3Set" #T, valueReferences, nValueReferences);                               \
    }

NO_VARIABLES(Float32, fmi3Float32)
NO_VARIABLES(Int8, fmi3Int8)
NO_VARIABLES(UInt8, fmi3UInt8)
NO_VARIABLES(Int16, fmi3Int16)
NO_VARIABLES(UInt16, fmi3UInt16)
NO_VARIABLES(UInt32, fmi3UInt32)
NO_VARIABLES(UInt64, fmi3UInt64)
NO_VARIABLES(Boolean, fmi3Boolean)
NO_VARIABLES(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    BEGIN("fmi3GetBinary", READABLE);
    return no_variables(inst, "fmi3GetBinary", valueReferences, nValueReferences);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    BEGIN("fmi3SetBinary", SETTABLE);
    return no_variables(inst, "fmi3SetBinary", valueReferences, nValueReferences);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Clock values[]) {
    (void)values;
    BEGIN("fmi3GetClock", READABLE);
    return no_variables(inst, "fmi3GetClock", valueReferences, nValueReferences);
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Clock values[]) {
    (void)values;
    BEGIN("fmi3SetClock", SETTABLE);
    return no_variables(inst, "fmi3SetClock", valueReferences, nValueReferences);
}
