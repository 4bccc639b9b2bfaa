// <immintrin.h> and the function attribute for the AVX-512 kernels (core/trace/trace_avx512.cpp,
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

#include "core/base/cpu_isa.h"

#include <cstdint>

#define DHR_AVX512_KERNELS 1

namespace dhr {
// Whether the CPU has AVX-512F and DQ, what the kernels are built for, and $DHR_MAX_ISA allows
// AVX-512 (core/base/cpu_isa.h; checked once).
inline bool cpu_has_avx512dq() {
  static const bool has =
      __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") && kernels_may_use(Isa::kAvx512);
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

namespace dhr {
// x, y and z of 16 consecutive vec3 (48 floats a b c, an array of glm::vec3 or of three-float
// structures): component k of element i is float 3i + k, taken from a:b by a first permute and
// from c by a second (backends/predict/reprojection.cpp, core/pass/composite.cpp).
struct Deinterleave3 {
  alignas(64) int32_t first[3][16];
  alignas(64) int32_t second[3][16];
  constexpr Deinterleave3() : first{}, second{} {
    for (int k = 0; k < 3; ++k)
      for (int i = 0; i < 16; ++i) {
        const int f = 3 * i + k;
        first[k][i] = f < 32 ? f : 0;
        second[k][i] = f < 32 ? i : 16 + f - 32;
      }
  }
};
inline constexpr Deinterleave3 kDeinterleave3{};
struct Xyz16 {
  __m512 x, y, z;
};
DHR_AVX512_TARGET inline Xyz16 load_xyz16(const float* f) {
  const __m512 a = _mm512_loadu_ps(f), b = _mm512_loadu_ps(f + 16), c = _mm512_loadu_ps(f + 32);
  __m512 out[3];
  for (int k = 0; k < 3; ++k) {
    const __m512 ab = _mm512_permutex2var_ps(a, _mm512_load_si512(kDeinterleave3.first[k]), b);
    out[k] = _mm512_permutex2var_ps(ab, _mm512_load_si512(kDeinterleave3.second[k]), c);
  }
  return {out[0], out[1], out[2]};
}
}  // namespace dhr
#else
#define DHR_AVX512_KERNELS 0
#endif
