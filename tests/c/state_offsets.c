/* state_offsets.c -- where SS22's first kept factorisation's cadence fields sit in a serialised FMU state, for
 * tests/test_ss22_state.py: compiled with an FMU's own sources (its FmuData layout), prints the byte offsets
 * within FmuData of cache[0].valid, .estimated, .confirmed and .confirmed_first, SS22_RATE_MEASURE_EVERY, and the
 * offsets of the order-4 starts' richardson.bias[0], .miss[0][0], .valid, .dt, .alpha_half[0] and .miss[2][0],
 * and of cache[0].first[2] (corrected starts' first ratio), one per line. */
#include <stddef.h>
#include <stdio.h>
#include "cosimulation.h"

int main(void) {
    printf("%zu\n%zu\n%zu\n%zu\n%d\n", offsetof(FmuData, ss22.cache[0].valid),
           offsetof(FmuData, ss22.cache[0].estimated), offsetof(FmuData, ss22.cache[0].confirmed),
           offsetof(FmuData, ss22.cache[0].confirmed_first), SS22_RATE_MEASURE_EVERY);
    printf("%zu\n%zu\n%zu\n%zu\n%zu\n%zu\n", offsetof(FmuData, richardson.bias), offsetof(FmuData, richardson.miss),
           offsetof(FmuData, richardson.valid), offsetof(FmuData, richardson.dt),
           offsetof(FmuData, richardson.alpha_half), offsetof(FmuData, richardson.miss[2]));
    printf("%zu\n", offsetof(FmuData, ss22.cache[0].first[2]));
    return 0;
}
