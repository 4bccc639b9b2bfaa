// std::pow over arrays of floats with the C library's bits, 16 lanes at a time where the CPU has
// AVX-512 (docs/performance.md, "FLIP's powers in 16 lanes with libm's bits").
//
// The C library's powf (glibc's, from Arm's optimized-routines) is not correctly rounded: it
// rounds a double approximation whose relative error its source bounds by about
// 1.27 |y log2 x| 2^-33 + 1.69 2^-34 (the log's relative error, 1.83 2^-33, scaled by ln 2 and
// |y log2 x|, plus the exponential's). The kernel computes x^y in double far more accurately
// (relative error under 2^-46 (1 + |y log2 x|)) and rounds it to float. Where that value lies
// further from a rounding midpoint than both errors together (twice the library's bound, for a
// margin), the library's value lies on the same side and rounds to the same float; the lanes
// closer than that (about 1 % on FLIP's inputs), and every input outside positive normal x and
// finite y with |y log2 x| < 120, are computed by std::pow itself. So every output is
// std::pow's, bit for bit, on every CPU. The argument rests on the library's bound, so it holds
// for glibc's powf (Debian's); tests/core/base/test_pow_row.cpp checks every output against std::pow on
// inputs where glibc's result is not the correctly rounded one for 1 in 1,600 (a kernel that
// ignored the bound fails there), and would fail against a C library whose powf strays further.
#pragma once

#include <cstddef>
#include <cstdint>

namespace dhr {

// out[i] = std::pow(x[i], y[i]) for i < n. x and out may be the same array.
void pow_row(const float* x, const float* y, float* out, size_t n);
// out[i] = std::pow(x[i], y) for i < n.
void pow_row(const float* x, float y, float* out, size_t n);

// The lanes the wide kernel has seen since the process started (all threads), and those it left
// to the scalar path (std::pow and its two exact cases: lanes near a rounding midpoint, inputs
// outside its range, rows' last n % 16): the fallback rate bench_metrics reports. Both stay 0
// without AVX-512.
struct PowRowCounts {
  uint64_t lanes = 0;
  uint64_t fallbacks = 0;
};
PowRowCounts pow_row_counts();
// Tests and benchmarks: true makes pow_row call std::pow on every element (the path of CPUs
// without AVX-512).
void pow_row_portable_only(bool on);

}  // namespace dhr
