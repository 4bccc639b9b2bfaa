// <immintrin.h> and the function attribute for the AVX-512 kernels (core/trace_avx512.cpp,
// backends/predict/reprojection.cpp). Only the functions marked DHR_AVX512_TARGET are compiled
// for AVX-512F/DQ; the rest of a file keeps the baseline ISA, and the caller picks the kernel
// at run time (dhr::cpu_has_avx512dq, below). No lambdas inside those functions: a lambda does
// not inherit its enclosing function's target attribute, and clang then refuses the AVX-512
// intrinsics in it.
#pragma once

#if defined(__x86_64__) && defined(__GNUC__)
// GCC 12's AVX-512 intrinsics start from _mm512_undefined_*() and then warn, once inlined into
// a caller, that the undefined value is "used uninitialized" (a false positive, reported at
// the header's lines). The header is included with those two warnings off for its lines only;
// the including file's own code keeps them.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#if !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include <immintrin.h>
#pragma GCC diagnostic pop

#define DHR_AVX512_KERNELS 1

namespace dhr {
// Whether the CPU has AVX-512F and DQ, what the kernels are built for (checked once).
inline bool cpu_has_avx512dq() {
  static const bool has = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq");
  return has;
}
}  // namespace dhr

#if defined(__clang__)
#define DHR_AVX512_TARGET __attribute__((target("avx512f,avx512dq")))
#else
// GCC's default -ffp-contract=fast would fuse a * b + c into the FMA instructions AVX-512
// brings; off keeps every product and sum rounded separately, as in the SSE2 and scalar code.
#define DHR_AVX512_TARGET __attribute__((target("avx512f,avx512dq"), optimize("fp-contract=off")))
#endif
#else
#define DHR_AVX512_KERNELS 0
#endif
