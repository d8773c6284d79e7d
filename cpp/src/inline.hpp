// Internal: inlining the compiler must do or must not do (GCC and Clang; elsewhere plain inline).
// IWR_FORCE_INLINE on the SIMD kernels' helpers and on the loops that must be compiled where they
// are used (with their counts constant, or for the caller's instruction set); IWR_NOINLINE on a
// kernel kept apart (its register allocation not disturbed by its neighbours').
#pragma once

#if defined(__GNUC__) || defined(__clang__)
#define IWR_FORCE_INLINE __attribute__((always_inline)) inline
#define IWR_NOINLINE __attribute__((noinline))
#else
#define IWR_FORCE_INLINE inline
#define IWR_NOINLINE
#endif
#if defined(__GNUC__) && !defined(__clang__)
#define IWR_FORCE_INLINE_LAMBDA __attribute__((always_inline))
#else
#define IWR_FORCE_INLINE_LAMBDA
#endif
