/* state_offsets.c -- where SS22's first kept factorisation's cadence fields sit in a serialised FMU state, for
 * tests/test_ss22_state.py: compiled with an FMU's own sources (its FmuData layout), prints the byte offsets
 * within FmuData of cache[0].valid, .estimated, .confirmed and .confirmed_first, SS22_RATE_MEASURE_EVERY, and the
 * offsets of the order-4 starts' richardson.bias[0] and richardson.miss[0][0], one per line. */
#include <stddef.h>
#include <stdio.h>
#include "cosimulation.h"

int main(void) {
    printf("%zu\n%zu\n%zu\n%zu\n%d\n%zu\n%zu\n", offsetof(FmuData, ss22.cache[0].valid),
           offsetof(FmuData, ss22.cache[0].estimated), offsetof(FmuData, ss22.cache[0].confirmed),
           offsetof(FmuData, ss22.cache[0].confirmed_first), SS22_RATE_MEASURE_EVERY,
           offsetof(FmuData, richardson.bias), offsetof(FmuData, richardson.miss));
    return 0;
}
