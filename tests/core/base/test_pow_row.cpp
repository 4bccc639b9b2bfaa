// pow_row (core/base/pow_row.h) gives std::pow's bits on every input: its wide kernel's own value
// only where the library's is certain to round the same way, std::pow elsewhere.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <random>
#include <sstream>
#include <vector>

#include "core/base/avx512.h"
#include "core/base/pow_row.h"

namespace {

using dhr::pow_row;

// Every output of pow_row (array y, and y as one value where all y are equal) against std::pow,
// bit for bit (NaNs as NaN).
void expect_std_pow_bits(const std::vector<float>& x, const std::vector<float>& y, const char* what) {
  ASSERT_EQ(x.size(), y.size());
  std::vector<float> out(x.size());
  pow_row(x.data(), y.data(), out.data(), x.size());
  size_t bad = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    const float want = std::pow(x[i], y[i]);
    const bool same =
        std::isnan(want) ? std::isnan(out[i]) : std::bit_cast<uint32_t>(want) == std::bit_cast<uint32_t>(out[i]);
    if (!same && bad++ < 5)
      ADD_FAILURE() << what << ": pow(" << std::hexfloat << x[i] << ", " << y[i] << ") = " << out[i] << ", std::pow "
                    << want;
  }
  EXPECT_EQ(bad, 0u) << what << ": " << bad << " of " << x.size() << " differ";
}

void expect_std_pow_bits(const std::vector<float>& x, float y, const char* what) {
  std::vector<float> out(x.size());
  pow_row(x.data(), y, out.data(), x.size());
  size_t bad = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    const float want = std::pow(x[i], y);
    const bool same =
        std::isnan(want) ? std::isnan(out[i]) : std::bit_cast<uint32_t>(want) == std::bit_cast<uint32_t>(out[i]);
    if (!same && bad++ < 5)
      ADD_FAILURE() << what << ": pow(" << std::hexfloat << x[i] << ", " << y << ") = " << out[i] << ", std::pow "
                    << want;
  }
  EXPECT_EQ(bad, 0u) << what << ": " << bad << " of " << x.size() << " differ";
}

bool wide_kernel() {
#if DHR_AVX512_KERNELS
  return dhr::cpu_has_avx512dq();
#else
  return false;
#endif
}

// FLIP's two calls: a colour difference (0 to a few hundred) to the power 0.7, and an error in
// (0, 1] to a power in (0.16, 1]; plus a wide range of both, negative powers included.
TEST(PowRow, RandomInputsGiveStdPowBits) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> hd(0.0f, 300.0f), ec(0.0f, 1.0f), ye(0.16f, 1.0f), wide_y(-6.0f, 6.0f);
  std::uniform_int_distribution<int> expo(-60, 60);
  const size_t n = 1u << 21;
  std::vector<float> x(n), y(n, 0.7f);
  for (auto& v : x) v = hd(rng);
  const dhr::PowRowCounts before = dhr::pow_row_counts();
  expect_std_pow_bits(x, y, "colour difference ^ 0.7, y as an array");
  expect_std_pow_bits(x, 0.7f, "colour difference ^ 0.7");
  const dhr::PowRowCounts after = dhr::pow_row_counts();
  if (wide_kernel()) {
    // The check is not vacuous: nearly every lane takes the kernel's own value.
    ASSERT_EQ(after.lanes - before.lanes, 2 * n);
    EXPECT_LT(double(after.fallbacks - before.fallbacks), 0.05 * double(2 * n));
  }
  for (size_t i = 0; i < n; ++i) x[i] = ec(rng), y[i] = ye(rng);
  expect_std_pow_bits(x, y, "error ^ (1 - feature)");
  for (size_t i = 0; i < n; ++i) x[i] = std::ldexp(1.0f + ec(rng), expo(rng)), y[i] = wide_y(rng);
  expect_std_pow_bits(x, y, "wide range");
}

// Where x^y lies exactly on, or within a hair of, the midpoint between two floats, the
// library's approximation may round either way: the kernel must leave those lanes to it.
// (1 + k 2^-12)^2 = 1 + k 2^-11 + k^2 2^-24 is a midpoint for odd k; its square root and
// neighbouring x are as hard.
TEST(PowRow, MidpointsAndExactCasesGiveStdPowBits) {
  std::vector<float> x, y;
  for (int k = 1; k < 4096; k += 2) {
    const float base = 1.0f + float(k) * 0x1p-12f;
    for (float b : {base, std::nextafter(base, 0.0f), std::nextafter(base, 2.0f)}) {
      x.push_back(b), y.push_back(2.0f);
      x.push_back(b * b), y.push_back(0.5f);
      x.push_back(b), y.push_back(3.0f);
      x.push_back(b), y.push_back(1.0f);
    }
  }
  // Exact powers, both signs of zero, subnormals, negatives, infinities, NaN, |y log2 x| past
  // the kernel's range.
  const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  const float specials[] = {0.0f,  -0.0f, 0x1p-149f, 0x1.8p-130f, 0x1p-126f, 0.5f, 1.0f, 2.0f, 4.0f,
                            1e30f, 3e38f, -1.0f,     -2.0f,       -0.5f,     inf,  -inf, nan};
  const float powers[] = {0.0f, -0.0f,  0.5f,   0.7f,    1.0f, 2.0f, -1.0f, -0.5f,
                          3.0f, 1e-30f, 200.0f, -200.0f, inf,  -inf, nan};
  for (float a : specials)
    for (float b : powers) x.push_back(a), y.push_back(b);
  expect_std_pow_bits(x, y, "midpoints and special cases");
}

// Every length's tail, the same array for x and out, and the path without the wide kernel.
TEST(PowRow, TailsInPlaceAndPortablePathGiveStdPowBits) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 2.0f);
  for (size_t n = 0; n <= 40; ++n) {
    std::vector<float> x(n), y(n), out(n);
    for (size_t i = 0; i < n; ++i) x[i] = u(rng), y[i] = u(rng);
    for (bool portable : {false, true}) {
      // Reset however the loop ends (an ASSERT returns), so later tests run the wide kernel.
      struct Reset {
        ~Reset() { dhr::pow_row_portable_only(false); }
      } reset;
      dhr::pow_row_portable_only(portable);
      std::vector<float> in_place = x;
      pow_row(in_place.data(), y.data(), in_place.data(), n);
      pow_row(x.data(), 0.7f, out.data(), n);
      for (size_t i = 0; i < n; ++i) {
        ASSERT_EQ(std::bit_cast<uint32_t>(in_place[i]), std::bit_cast<uint32_t>(std::pow(x[i], y[i])))
            << "n " << n << " portable " << portable;
        ASSERT_EQ(std::bit_cast<uint32_t>(out[i]), std::bit_cast<uint32_t>(std::pow(x[i], 0.7f)))
            << "n " << n << " portable " << portable;
      }
    }
  }
}

// Every positive float x (2^31 values, about a minute) for each power in DHR_POW_EXHAUSTIVE
// (e.g. "0.7 0.16 0.5"): the one-off check docs/performance.md reports; skipped by default.
TEST(PowRow, EveryPositiveFloatWhenAsked) {
  const char* list = std::getenv("DHR_POW_EXHAUSTIVE");
  if (!list) GTEST_SKIP() << "set DHR_POW_EXHAUSTIVE to a list of powers";
  std::istringstream in(list);
  float y;
  while (in >> y) {
    const size_t chunk = 1u << 24;
    std::vector<float> x(chunk), out(chunk);
    uint64_t bad = 0;
    for (uint64_t start = 0; start < (uint64_t(1) << 31); start += chunk) {
      for (size_t i = 0; i < chunk; ++i) x[i] = std::bit_cast<float>(uint32_t(start + i));
      pow_row(x.data(), y, out.data(), chunk);
      for (size_t i = 0; i < chunk; ++i) {
        const float want = std::pow(x[i], y);
        const bool same =
            std::isnan(want) ? std::isnan(out[i]) : std::bit_cast<uint32_t>(want) == std::bit_cast<uint32_t>(out[i]);
        if (!same && bad++ < 5) ADD_FAILURE() << std::hexfloat << "pow(" << x[i] << ", " << y << ")";
      }
    }
    EXPECT_EQ(bad, 0u) << "y = " << y;
    const dhr::PowRowCounts c = dhr::pow_row_counts();
    std::printf(
        "y = %g: %llu of 2^31 positive floats differ from std::pow; lanes so far %llu, left to the scalar "
        "path %llu\n",
        double(y), static_cast<unsigned long long>(bad), static_cast<unsigned long long>(c.lanes),
        static_cast<unsigned long long>(c.fallbacks));
  }
}

}  // namespace
