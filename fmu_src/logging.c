/* logging.c -- the log categories, messages through the host's logger, fmi2SetDebugLogging.
 * See cosimulation.h. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include "internal.h"

const char *const LOG_CATEGORY_NAMES[N_LOG_CATEGORIES] = {
    "logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError", "logStatistics", "logAll"};

/* ====================================================================== logging */

/* The logger's message is a printf format that may reference variables as #r12#: escape '%' and '#'. */
static void escape_message(const char *in, char *out, size_t n) {
    size_t j = 0;
    for (size_t i = 0; in[i] != '\0' && j + 3 < n; i++) {
        if (in[i] == '%' || in[i] == '#') out[j++] = in[i];
        out[j++] = in[i];
    }
    out[j] = '\0';
}

static const char *status_category(fmi2Status status, LogCategory category) {
    switch (status) {
    case fmi2Warning: return LOG_CATEGORY_NAMES[LOG_STATUS_WARNING];
    case fmi2Discard: return LOG_CATEGORY_NAMES[LOG_STATUS_DISCARD];
    case fmi2Error:
    case fmi2Fatal: return LOG_CATEGORY_NAMES[LOG_STATUS_ERROR];
    default: return LOG_CATEGORY_NAMES[category];
    }
}

static void vlog_to(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                    LogCategory category, char *buf, size_t nbuf, char *escaped, size_t nescaped,
                    const char *format, va_list ap) {
    if (cb == NULL || cb->logger == NULL) return;
    vsnprintf(buf, nbuf, format, ap);
    escape_message(buf, escaped, nescaped);
    cb->logger(cb->componentEnvironment, name != NULL ? name : "?", status, status_category(status, category),
               escaped);
}

/* Before an instance exists (fmi2Instantiate refusing to create one). */
void fmu_log_callbacks(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                       const char *format, ...) {
    char buf[1024], escaped[2048];
    va_list ap;
    va_start(ap, format);
    vlog_to(cb, name, status, LOG_STATUS_ERROR, buf, sizeof(buf), escaped, sizeof(escaped), format, ap);
    va_end(ap);
}

int fmu_logs(const Instance *inst, LogCategory category) {
    return inst->logging_on && (inst->category_on[category] || inst->category_on[LOG_ALL]);
}

void fmu_log(Instance *inst, fmi2Status status, LogCategory category, const char *format, ...) {
    va_list ap;
    if (status < fmi2Warning && !fmu_logs(inst, category)) return;
    va_start(ap, format);
    vlog_to(&inst->cb, inst->name, status, category, inst->message, sizeof(inst->message), inst->escaped,
            sizeof(inst->escaped), format, ap);
    va_end(ap);
}

fmi2Status fmu_error(Instance *inst, const char *format, ...) {
    va_list ap;
    va_start(ap, format);
    vlog_to(&inst->cb, inst->name, fmi2Error, LOG_STATUS_ERROR, inst->message, sizeof(inst->message),
            inst->escaped, sizeof(inst->escaped), format, ap);
    va_end(ap);
    return fmi2Error;
}

fmi2Status fmu_set_debug_logging(Instance *inst, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    int wanted[N_LOG_CATEGORIES] = {0};
    if (n > 0 && categories == NULL) {
        return fmu_error(inst, "fmi2SetDebugLogging: categories is NULL with nCategories = %lu", (unsigned long)n);
    }
    for (size_t i = 0; i < n; i++) {
        int found = 0;
        if (categories[i] == NULL) {
            return fmu_error(inst, "fmi2SetDebugLogging: category %lu is NULL", (unsigned long)i);
        }
        for (int k = 0; k < N_LOG_CATEGORIES; k++) {
            if (strcmp(categories[i], LOG_CATEGORY_NAMES[k]) == 0) { wanted[k] = 1; found = 1; }
        }
        if (!found) {
            return fmu_error(inst, "fmi2SetDebugLogging: unknown log category \"%s\" (known: logEvents, "
                             "logStatusWarning, logStatusDiscard, logStatusError, logStatistics, logAll)", categories[i]);
        }
    }
    inst->logging_on = on ? 1 : 0;
    for (int k = 0; k < N_LOG_CATEGORIES; k++) {
        if (n == 0 || wanted[k]) inst->category_on[k] = on ? 1 : 0;
    }
    return fmi2OK;
}

void fmu_log_statistics(Instance *inst) {
    const SS22 *s = &inst->d.ss22;
    if (!fmu_logs(inst, LOG_STATISTICS)) return;
    fmu_log(inst, fmi2OK, LOG_STATISTICS,
            "statistics at t = %.17g: %.0f SS22 steps, %.0f Newton iterations, %.0f factorisations, "
            "%.0f residual evaluations; consistent accelerations: %.0f mass matrices, %.0f residual iterations; "
            "mass updates among the factorisations: %.0f; the model's AVX code: %d",
            inst->d.time, (double)s->steps, (double)s->newton_iterations,
            (double)(s->factorisations + s->mass_updates), (double)s->residual_evaluations,
            (double)inst->d.mass_refreshes, (double)inst->d.mass_iterations,
            (double)s->mass_updates, model_avx_code());   /* %lu is 32 bits on win64 */
}
