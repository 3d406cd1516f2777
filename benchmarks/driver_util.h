/* driver_util.h -- what the C benchmark drivers (step_floor.c, sample_cost.c) share: a logger that prints
 * only what is not fmi2OK, a clock, and the median of a sample (quoted figures are medians of several runs). */
#ifndef FLEXLINK_DRIVER_UTIL_H
#define FLEXLINK_DRIVER_UTIL_H

#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"

static inline void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                          fmi2String message, ...) {
    (void)env; (void)name; (void)category;
    if (status != fmi2OK) fprintf(stderr, "[status %d] %s\n", (int)status, message);
}

static inline double now(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static inline int cmp(const void *a, const void *b) {
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static inline double median(double *x, int n) {
    qsort(x, (size_t)n, sizeof(double), cmp);
    return n % 2 ? x[n / 2] : 0.5 * (x[n / 2 - 1] + x[n / 2]);
}

#endif
