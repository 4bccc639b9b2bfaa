// Eight floats as one value (GCC's and clang's vector extension) for the core's bit-exact row
// kernels (core/metrics/flip.cpp, core/pass/composite.cpp, core/metrics/metrics.cpp, core/metrics/temporal.cpp): lane for lane
// the same operations as the scalar code, every product and sum rounded on its own.
// DHR_VEC8_TARGETS clones a kernel for AVX2 and the baseline and picks one at run time; neither
// target has FMA instructions, so nothing is contracted and both give the same bits. (The
// denoisers have their own lane types: backends/denoise/filters_simd.h.)
#pragma once

#include <xmmintrin.h>

#include <cstdint>
#include <cstring>

// -Wpsabi off for the rest of the including file: the 32-byte vectors pass by value between
// inline helpers of one translation unit only, never across a library boundary, and GCC
// reports it at the end of the translation unit, after any diagnostic pop.
#pragma GCC diagnostic ignored "-Wpsabi"

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__AVX2__) && \
    !defined(__SANITIZE_ADDRESS__)
#define DHR_VEC8_TARGETS __attribute__((target_clones("avx2", "default")))
#else
#define DHR_VEC8_TARGETS
#endif

namespace dhr {

typedef float Vec8 __attribute__((vector_size(32)));
typedef int32_t Mask8 __attribute__((vector_size(32)));  // a comparison's lanes: -1 true, 0 false
typedef double Vec4d __attribute__((vector_size(32)));   // four doubles
typedef float Vec4f __attribute__((vector_size(16)));    // four floats, to convert to Vec4d

inline Vec8 load8(const float* p) {
  Vec8 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void store8(float* p, Vec8 v) { std::memcpy(p, &v, sizeof v); }
inline Vec8 splat8(float x) { return Vec8{} + x; }
// Four floats at p as doubles (exact).
inline Vec4d load4f_as_double(const float* p) {
  Vec4f v;
  std::memcpy(&v, p, sizeof v);
  return __builtin_convertvector(v, Vec4d);
}
inline void store4d(double* p, Vec4d v) { std::memcpy(p, &v, sizeof v); }

// std::sqrt lane by lane (correctly rounded, as sqrtss): SSE's sqrtps on each half, which both
// targets have (std::sqrt's errno path keeps the compiler from vectorizing it).
inline Vec8 sqrt8(Vec8 v) {
  __m128 lo, hi;
  std::memcpy(&lo, &v, sizeof lo);
  std::memcpy(&hi, reinterpret_cast<const char*>(&v) + sizeof lo, sizeof hi);
  lo = _mm_sqrt_ps(lo);
  hi = _mm_sqrt_ps(hi);
  std::memcpy(&v, &lo, sizeof lo);
  std::memcpy(reinterpret_cast<char*>(&v) + sizeof lo, &hi, sizeof hi);
  return v;
}

// std::clamp(v, lo, hi) lane by lane: v < lo ? lo : hi < v ? hi : v (a NaN stays NaN).
inline Vec8 clamp8(Vec8 v, float lo, float hi) {
  const Vec8 l = splat8(lo), h = splat8(hi);
  return v < l ? l : (h < v ? h : v);
}

}  // namespace dhr
