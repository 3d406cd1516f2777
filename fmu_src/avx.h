/* avx.h -- the AVX twins of the generated units of the Newton iteration (the residual, and the mass matrix or
 * Newton matrix where one is generated): the same C compiled a second time for processors with AVX, and the
 * choice between the two made on every call from what the processor has.
 *
 * Why: CasADi's units are long runs of scalar operations on named temporaries.  In SSE2's two-operand
 * instructions a temporary that is still needed after an operation is first copied to another register;
 * AVX's three-operand (VEX) encoding of the same scalar operations needs no copy.  Measured 2026-11-29
 * (benchmarks/step_floor.py, the unit alone compiled with -mavx): planar_chain_5's residual 2.36 -> 1.90 us,
 * the 32-mode link's 3.88 -> 3.28 us.  The twin runs the same operations in the same order on the same
 * doubles: its values are the same to the bit (tests/test_avx_units.py compares whole runs of both builds).
 * With gcc no 256-bit register is used (the units are scalar code; its vectoriser is told to prefer 128 bits),
 * so the 32-byte stack alignment that 64-bit Windows does not give is never needed (tests/test_avx_units.py
 * reads the MinGW-w64 assembly); clang may vectorise with them, and realigns the stack where it does.
 *
 * GCC 8 or later (prefer-vector-width) and clang, on x86-64, outside the MSVC ABI (clang-cl would need
 * compiler-rt's __cpu_model, which it does not link); elsewhere, with another compiler (an importer building
 * the sources/ of the FMU), or with FLEXLINK_NO_AVX defined, the twins are empty units and the baseline units
 * run.  A baseline x86-64 processor, or an emulator without AVX, runs the baseline units: the choice is the
 * processor's (libgcc's, which also asks whether the operating system saves the AVX registers), not the
 * build's. */
#ifndef FLEXLINK_AVX_H
#define FLEXLINK_AVX_H

#if (defined(__clang__) || (defined(__GNUC__) && __GNUC__ >= 8)) && defined(__x86_64__) && !defined(_MSC_VER) && \
    !defined(FLEXLINK_NO_AVX)
#define FLEXLINK_AVX 1
/* whether this processor (and its operating system, which must save the AVX registers) has AVX */
#define flexlink_avx_processor() (__builtin_cpu_supports("avx"))
#if defined(__clang__)
#define FLEXLINK_AVX_BEGIN _Pragma("clang attribute push (__attribute__((target(\"avx\"))), apply_to = function)")
#define FLEXLINK_AVX_END _Pragma("clang attribute pop")
#else
#define FLEXLINK_AVX_BEGIN _Pragma("GCC push_options") _Pragma("GCC target (\"avx\", \"prefer-vector-width=128\")")
#define FLEXLINK_AVX_END _Pragma("GCC pop_options")
#endif
#else
#define FLEXLINK_AVX 0
#define flexlink_avx_processor() 0
#endif

#endif
