// LDR-FLIP after Andersson et al. 2020; the steps, constants and open choices are in
// docs/metrics.md ("FLIP"). Layout: both images go through a horizontal pass (colour conversion
// fused with the row filters), then a vertical pass per output row that finishes both images'
// filters and combines them into the error of that row. All filters are separable and clamp at
// the image edge; every pixel is computed the same way whatever the thread partition, and the
// mean is summed per row and then over rows in order, so results do not depend on threads.
#include "core/metrics/flip.h"

#include "core/base/avx512.h"
#include "core/base/error.h"
#include "core/base/pow_row.h"
#include "core/base/vec8.h"
#include "core/base/workspace.h"
#include "core/metrics/flip_magma.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

namespace dhr {

namespace {

// The row loops below are built for AVX2 and the baseline and chosen at run time
// (DHR_VEC8_TARGETS, core/base/vec8.h); neither has FMA instructions, so every product and sum is
// rounded on its own on both (the same bits).

constexpr double kPi = 3.14159265358979323846;

// ---- colour spaces ----------------------------------------------------------------------
// Linear sRGB (D65) to CIE XYZ; the reference white is the matrix applied to (1, 1, 1), and the
// rows are divided by it so that x, y, z below are X/Xn, Y/Yn, Z/Zn.
struct ColourSpace {
  float to_xyz[9];    // linear RGB -> (X/Xn, Y/Yn, Z/Zn)
  float from_xyz[9];  // its inverse
  std::array<float, 256> srgb_to_linear;
};

ColourSpace make_colour_space() {
  const double m[9] = {0.4124564, 0.3575761, 0.1804375, 0.2126729, 0.7151522,
                       0.0721750, 0.0193339, 0.1191920, 0.9503041};
  double n[9];
  for (int r = 0; r < 3; ++r) {
    const double white = m[3 * r] + m[3 * r + 1] + m[3 * r + 2];
    for (int c = 0; c < 3; ++c) n[3 * r + c] = m[3 * r + c] / white;
  }
  // Inverse by the adjugate.
  const double det =
      n[0] * (n[4] * n[8] - n[5] * n[7]) - n[1] * (n[3] * n[8] - n[5] * n[6]) + n[2] * (n[3] * n[7] - n[4] * n[6]);
  const double inv[9] = {
      (n[4] * n[8] - n[5] * n[7]) / det, (n[2] * n[7] - n[1] * n[8]) / det, (n[1] * n[5] - n[2] * n[4]) / det,
      (n[5] * n[6] - n[3] * n[8]) / det, (n[0] * n[8] - n[2] * n[6]) / det, (n[2] * n[3] - n[0] * n[5]) / det,
      (n[3] * n[7] - n[4] * n[6]) / det, (n[1] * n[6] - n[0] * n[7]) / det, (n[0] * n[4] - n[1] * n[3]) / det};
  ColourSpace cs{};
  for (int i = 0; i < 9; ++i) {
    cs.to_xyz[i] = float(n[i]);
    cs.from_xyz[i] = float(inv[i]);
  }
  for (int v = 0; v < 256; ++v) {
    const double c = v / 255.0;
    cs.srgb_to_linear[size_t(v)] = float(c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4));
  }
  return cs;
}

const ColourSpace& colour_space() {
  static const ColourSpace cs = make_colour_space();
  return cs;
}

// Cube root of a positive float: a first guess from the exponent bits (within a few percent),
// then two Halley steps in double (cubic convergence: ~1e-4, then below float precision).
// glibc's cbrtf was a third of FLIP's time; this is within one float ulp of it.
inline float cbrt_positive(float t) {
  uint32_t bits;
  std::memcpy(&bits, &t, sizeof bits);
  bits = bits / 3 + 0x2a514067u;
  float guess;
  std::memcpy(&guess, &bits, sizeof guess);
  double y = guess;
  const double td = t;
  for (int i = 0; i < 2; ++i) {
    const double y3 = y * y * y;
    y = y * (y3 + 2 * td) / (2 * y3 + td);
  }
  return float(y);
}

// CIELAB's f(t), with its linear segment below (6/29)^3.
inline float lab_f(float t) {
  constexpr float kDelta3 = float((6.0 / 29) * (6.0 / 29) * (6.0 / 29));
  constexpr float kSlope = float(1.0 / (3 * (6.0 / 29) * (6.0 / 29)));
  constexpr float kOffset = float(4.0 / 29);
  return t > kDelta3 ? cbrt_positive(t) : t * kSlope + kOffset;
}

struct Lab {
  float l, a, b;
};

// lab_f over a row of values, four at a time in double (GCC's vector extension): lane for lane
// the operations of lab_f (the guess's integer division, the float -> double conversions, both
// Halley steps, the rounding back to float), each rounded on its own, so the same bits as lab_f
// (Flip.LabRowMatchesLabF). The compiler left the scalar loop unvectorized (one divsd at a time).
typedef uint32_t Vec4u __attribute__((vector_size(16)));

DHR_VEC8_TARGETS void lab_f_row(float* v, size_t n) {
  constexpr float kDelta3 = float((6.0 / 29) * (6.0 / 29) * (6.0 / 29));
  constexpr float kSlope = float(1.0 / (3 * (6.0 / 29) * (6.0 / 29)));
  constexpr float kOffset = float(4.0 / 29);
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    Vec4f t;
    std::memcpy(&t, v + i, sizeof t);
    const Vec4f delta = Vec4f{} + kDelta3;
    const Vec4f tc = t < delta ? delta : t;  // std::max(t, kDelta3), NaN kept as std::max does
    Vec4u bits;
    std::memcpy(&bits, &tc, sizeof bits);
    bits = bits / 3u + 0x2a514067u;
    Vec4f guess;
    std::memcpy(&guess, &bits, sizeof guess);
    Vec4d y = __builtin_convertvector(guess, Vec4d);
    const Vec4d td = __builtin_convertvector(tc, Vec4d);
    for (int k = 0; k < 2; ++k) {
      const Vec4d y3 = y * y * y;
      y = y * (y3 + 2 * td) / (2 * y3 + td);
    }
    const Vec4f cube_root = __builtin_convertvector(y, Vec4f);
    const Vec4f linear = t * kSlope + kOffset;
    const Vec4f out = t > delta ? cube_root : linear;
    std::memcpy(v + i, &out, sizeof out);
  }
  for (; i < n; ++i) v[i] = lab_f(v[i]);
}

// CIELAB's f of X/Xn, Y/Yn, Z/Zn -> CIELAB with the Hunt adjustment (a and b scaled by 0.01 L);
// for a float and for eight lanes (vertical_rows' rows).
template <class T>
inline void hunt_from_f(T fx, T fy, T fz, T& l, T& a, T& b) {
  l = 116.0f * fy - 16.0f;
  a = 0.01f * l * 500.0f * (fx - fy);
  b = 0.01f * l * 200.0f * (fy - fz);
}

// Linear RGB -> Hunt-adjusted CIELAB.
inline Lab hunt_lab(const ColourSpace& cs, float r, float g, float b) {
  const float* m = cs.to_xyz;
  Lab out;
  hunt_from_f(lab_f(m[0] * r + m[1] * g + m[2] * b), lab_f(m[3] * r + m[4] * g + m[5] * b),
              lab_f(m[6] * r + m[7] * g + m[8] * b), out.l, out.a, out.b);
  return out;
}

inline float hyab(const Lab& p, const Lab& q) {
  const float da = p.a - q.a, db = p.b - q.b;
  return std::abs(p.l - q.l) + std::sqrt(da * da + db * db);
}

// ---- the paper's constants --------------------------------------------------------------
// Contrast sensitivity as a sum of two Gaussians per opponent channel (a1, b1, a2, b2).
struct CsfParams {
  double a1, b1, a2, b2;
};
constexpr CsfParams kCsfAchromatic{1.0, 0.0047, 0.0, 1e-5};
constexpr CsfParams kCsfRedGreen{1.0, 0.0053, 0.0, 1e-5};
constexpr CsfParams kCsfBlueYellow{34.1, 0.04, 13.5, 0.025};
constexpr double kCsfLargestB = 0.04;
constexpr float kQc = 0.7f;                 // exponent on the colour difference
constexpr float kPc = 0.4f;                 // redistribution: breakpoint, as a fraction of the largest error
constexpr float kPt = 0.95f;                // ... and the error it maps to
constexpr double kFeatureWidthDeg = 0.082;  // w: feature detector width in degrees
// q_f, the exponent on the feature difference, is 1/2: applied as a square root below.

struct Kernel {
  int radius = 0;
  std::vector<float> w;  // 2 * radius + 1 taps, w[radius] at offset 0
};

// One Gaussian of a CSF, sampled at pixel centres kΔ (Δ = 1/ppd degrees), normalized to sum 1.
Kernel csf_gaussian(double b, int radius, double ppd, double* unnormalized_sum) {
  Kernel k{radius, std::vector<float>(size_t(2 * radius + 1))};
  std::vector<double> v(k.w.size());
  double sum = 0;
  for (int i = -radius; i <= radius; ++i) {
    const double x = i / ppd;
    v[size_t(i + radius)] = std::exp(-kPi * kPi * x * x / b);
    sum += v[size_t(i + radius)];
  }
  for (size_t i = 0; i < v.size(); ++i) k.w[i] = float(v[i] / sum);
  *unnormalized_sum = sum;
  return k;
}

// The 2D CSF kernel a1 sqrt(pi/b1) exp(-pi^2 r^2/b1) + a2 sqrt(pi/b2) exp(-pi^2 r^2/b2),
// normalized to sum 1, is exactly alpha1 g1(x) g1(y) + alpha2 g2(x) g2(y) with the normalized
// 1D Gaussians g1, g2: two separable filters and a weighted sum.
struct Csf {
  Kernel g1, g2;
  float alpha1 = 1, alpha2 = 0;
};

Csf make_csf(const CsfParams& p, int radius, double ppd) {
  Csf c;
  double s1 = 0, s2 = 0;
  c.g1 = csf_gaussian(p.b1, radius, ppd, &s1);
  if (p.a2 == 0) return c;
  c.g2 = csf_gaussian(p.b2, radius, ppd, &s2);
  const double w1 = p.a1 * std::sqrt(kPi / p.b1) * s1 * s1;
  const double w2 = p.a2 * std::sqrt(kPi / p.b2) * s2 * s2;
  c.alpha1 = float(w1 / (w1 + w2));
  c.alpha2 = float(w2 / (w1 + w2));
  return c;
}

// Feature detectors: Gaussian (sum 1), its first derivative and its second derivative, each
// derivative scaled so that its positive taps sum to 1 and its negative taps to -1.
struct FeatureKernels {
  Kernel g, d1, d2;
};

FeatureKernels make_feature_kernels(double ppd) {
  const double sigma = 0.5 * kFeatureWidthDeg * ppd;
  const int radius = int(std::ceil(3 * sigma));
  const size_t n = size_t(2 * radius + 1);
  std::vector<double> g(n), d1(n), d2(n);
  double gsum = 0;
  for (int i = -radius; i <= radius; ++i) {
    const double x = i, gi = std::exp(-x * x / (2 * sigma * sigma));
    g[size_t(i + radius)] = gi;
    d1[size_t(i + radius)] = -x / (sigma * sigma) * gi;
    d2[size_t(i + radius)] = (x * x / (sigma * sigma) - 1) / (sigma * sigma) * gi;
    gsum += gi;
  }
  auto signed_normalize = [](std::vector<double>& v) {
    double pos = 0, neg = 0;
    for (double x : v) (x > 0 ? pos : neg) += x;
    for (double& x : v) x = x > 0 ? x / pos : x < 0 ? x / -neg : 0.0;
  };
  signed_normalize(d1);
  signed_normalize(d2);
  FeatureKernels f;
  for (Kernel* k : {&f.g, &f.d1, &f.d2}) *k = Kernel{radius, std::vector<float>(n)};
  for (size_t i = 0; i < n; ++i) {
    f.g.w[i] = float(g[i] / gsum);
    f.d1.w[i] = float(d1[i]);
    f.d2.w[i] = float(d2[i]);
  }
  return f;
}

// ---- separable filtering ----------------------------------------------------------------
// Both filters keep 64 outputs in registers across all taps (eight 8-float vectors, GCC's vector
// extension) instead of reading and writing the output row once per tap: eight independent sums
// hide the adds' latency (with four, each tap waited on the previous one's adds). Every output is
// still w0 * s0, then + w1 * s1, ... in tap order, each product and sum rounded on its own
// (neither target has FMA instructions, so nothing is contracted): the same bits on every target
// and as the one-tap-at-a-time loop (Flip.SameBitsAsTheOneTapAtATimeFilters in tests/core/metrics/test_flip.cpp).

// out[x, x + 8 kVecs) of weighted_rows, the sums in registers.
template <int kVecs>
inline void weighted_block(const float* const* src, const float* w, int taps, int x, float* out) {
  Vec8 a[kVecs];
  const Vec8 w0 = splat8(w[0]);
  for (int v = 0; v < kVecs; ++v) a[v] = w0 * load8(src[0] + x + 8 * v);
  for (int t = 1; t < taps; ++t) {
    const Vec8 wt = splat8(w[t]);
    const float* r = src[t] + x;
    for (int v = 0; v < kVecs; ++v) a[v] = a[v] + wt * load8(r + 8 * v);
  }
  for (int v = 0; v < kVecs; ++v) store8(out + x + 8 * v, a[v]);
}

// out[x] = sum_t w[t] * src[t][x] for x < width, summed in tap order.
DHR_VEC8_TARGETS void weighted_rows(const float* const* src, const float* w, int taps, int width, float* out) {
  int x = 0;
  for (; x + 64 <= width; x += 64) weighted_block<8>(src, w, taps, x, out);
  for (; x + 8 <= width; x += 8) weighted_block<1>(src, w, taps, x, out);
  for (; x < width; ++x) {
    float a = w[0] * src[0][x];
    for (int t = 1; t < taps; ++t) a += w[t] * src[t][x];
    out[x] = a;
  }
}

// Two outputs a row apart: out0[x] = sum_t w[t] * src[t][x] and out1[x] = sum_t w[t] *
// src[t + 1][x] (src holds taps + 1 rows), each in tap order as weighted_rows sums it, 32
// columns of both in registers. Each source row is loaded once for both outputs: a column
// filter's rows come from L2, and its loads, not its arithmetic, set its pace.
template <int kVecs>
inline void weighted_block_pair(const float* const* src, const float* w, int taps, int x, float* out0, float* out1) {
  Vec8 a0[kVecs], a1[kVecs];
  // Source row 0 is out0's first tap, row 1 out0's second and out1's first, row t out0's tap t
  // and out1's tap t - 1, row `taps` out1's last.
  for (int v = 0; v < kVecs; ++v) a0[v] = splat8(w[0]) * load8(src[0] + x + 8 * v);
  if (taps == 1) {
    for (int v = 0; v < kVecs; ++v) a1[v] = splat8(w[0]) * load8(src[1] + x + 8 * v);
  } else {
    for (int v = 0; v < kVecs; ++v) {
      const Vec8 s = load8(src[1] + x + 8 * v);
      a0[v] = a0[v] + splat8(w[1]) * s;
      a1[v] = splat8(w[0]) * s;
    }
    for (int t = 2; t < taps; ++t) {
      const Vec8 wt = splat8(w[t]), wp = splat8(w[t - 1]);
      const float* r = src[t] + x;
      for (int v = 0; v < kVecs; ++v) {
        const Vec8 s = load8(r + 8 * v);
        a0[v] = a0[v] + wt * s;
        a1[v] = a1[v] + wp * s;
      }
    }
    for (int v = 0; v < kVecs; ++v) a1[v] = a1[v] + splat8(w[taps - 1]) * load8(src[taps] + x + 8 * v);
  }
  for (int v = 0; v < kVecs; ++v) store8(out0 + x + 8 * v, a0[v]), store8(out1 + x + 8 * v, a1[v]);
}

DHR_VEC8_TARGETS void weighted_rows_pair(const float* const* src, const float* w, int taps, int width, float* out0,
                                         float* out1) {
  int x = 0;
  for (; x + 32 <= width; x += 32) weighted_block_pair<4>(src, w, taps, x, out0, out1);
  for (; x + 8 <= width; x += 8) weighted_block_pair<1>(src, w, taps, x, out0, out1);
  for (; x < width; ++x) {
    float a = w[0] * src[0][x], b = w[0] * src[1][x];
    for (int t = 1; t < taps; ++t) a += w[t] * src[t][x], b += w[t] * src[t + 1][x];
    out0[x] = a;
    out1[x] = b;
  }
}

// The largest kernel: the CSF's radius at the highest ppd flip() takes (1000) is 136.
constexpr int kMaxTaps = 2 * 160 + 1;

// out[x] = sum_k w[k] * padded[x + k], where padded holds the row with `radius` clamped
// samples on each side (padded[x + radius] is pixel x).
void filter_row(const float* padded, int pad, const Kernel& k, int width, float* out) {
  const float* base = padded + (pad - k.radius);
  const int taps = 2 * k.radius + 1;
  std::array<const float*, kMaxTaps> src;
  for (int t = 0; t < taps; ++t) src[size_t(t)] = base + t;
  weighted_rows(src.data(), k.w.data(), taps, width, out);
}

// out[r][x] = sum_k w[k] * plane[clamp(y + r + k - radius)][x] for rows y + r, r < n (1 or 2):
// two rows at once load each source row once for both (weighted_rows_pair).
void filter_columns(const float* plane, int width, int height, int y, int n, const Kernel& k, float* const* out) {
  const int taps = 2 * k.radius + 1;
  std::array<const float*, kMaxTaps + 1> src;
  for (int t = 0; t < taps + n - 1; ++t)
    src[size_t(t)] = plane + size_t(std::clamp(y + t - k.radius, 0, height - 1)) * size_t(width);
  if (n == 2)
    weighted_rows_pair(src.data(), k.w.data(), taps, width, out[0], out[1]);
  else
    weighted_rows(src.data(), k.w.data(), taps, width, out[0]);
}

// The horizontal results of one image: 4 CSF planes (Yy, Cx, Cz with g1, Cz with g2) and 3
// feature planes (luminance with g, d1, d2).
enum Plane { kY, kCx, kCz1, kCz2, kFg, kFd1, kFd2, kPlanes };

struct Filters {
  Csf y, cx, cz;
  FeatureKernels f;
  int pad = 0;  // the largest radius
};

void horizontal_pass(const ImageRGB8& image, const Filters& fl, float* const* planes) {
  const ColourSpace& cs = colour_space();
  const int w = image.width(), h = image.height(), pad = fl.pad;
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    // Opponent channels and luminance of one row, clamped `pad` samples beyond each edge.
    std::vector<float> yy(size_t(w + 2 * pad)), cx(yy.size()), cz(yy.size()), lum(yy.size());
    for (int y = rows.begin(); y < rows.end(); ++y) {
      const Rgb8* src = &image(0, y);
      for (int i = 0; i < w + 2 * pad; ++i) {
        const Rgb8 p = src[std::clamp(i - pad, 0, w - 1)];
        const float r = cs.srgb_to_linear[p.r], g = cs.srgb_to_linear[p.g], b = cs.srgb_to_linear[p.b];
        const float* m = cs.to_xyz;
        const float x = m[0] * r + m[1] * g + m[2] * b;
        const float yl = m[3] * r + m[4] * g + m[5] * b;
        const float z = m[6] * r + m[7] * g + m[8] * b;
        const float yy_v = 116.0f * yl - 16.0f;  // YyCxCz (linearized CIELAB)
        yy[size_t(i)] = yy_v;
        cx[size_t(i)] = 500.0f * (x - yl);
        cz[size_t(i)] = 200.0f * (yl - z);
        lum[size_t(i)] = (yy_v + 16.0f) / 116.0f;  // normalized achromatic channel
      }
      const size_t off = size_t(y) * size_t(w);
      filter_row(yy.data(), pad, fl.y.g1, w, planes[kY] + off);
      filter_row(cx.data(), pad, fl.cx.g1, w, planes[kCx] + off);
      filter_row(cz.data(), pad, fl.cz.g1, w, planes[kCz1] + off);
      filter_row(cz.data(), pad, fl.cz.g2, w, planes[kCz2] + off);
      filter_row(lum.data(), pad, fl.f.g, w, planes[kFg] + off);
      filter_row(lum.data(), pad, fl.f.d1, w, planes[kFd1] + off);
      filter_row(lum.data(), pad, fl.f.d2, w, planes[kFd2] + off);
    }
  });
}

// The filters' scratch rows of one thread.
struct RowScratch {
  std::vector<float> tmp[7];
  explicit RowScratch(int w) {
    for (auto& t : tmp) t.resize(size_t(w));
  }
};

// Where one row of one image's features goes (FlipFeatures: l, a, b interleaved).
struct FeatureRow {
  float* lab;
  float* edge;
  float* point;
};

// The per-pixel steps of vertical_rows, written once for a float and for eight lanes (Vec8), so
// that both run the same operations in the same order (the same bits).
inline float clamp01(float v) { return std::clamp(v, 0.0f, 1.0f); }
inline Vec8 clamp01(Vec8 v) { return clamp8(v, 0.0f, 1.0f); }
inline float root(float v) { return std::sqrt(v); }
inline Vec8 root(Vec8 v) { return sqrt8(v); }

// Filtered YyCxCz (yy, cx; cz as the weighted sum of its two Gaussians) -> (X/Xn, Y/Yn, Z/Zn)
// -> linear RGB clamped to [0, 1] -> (X/Xn, Y/Yn, Z/Zn) again, into t0, t1, t2.
template <class T>
inline void filtered_to_xyz(T& t0, T& t1, T& t2, T t3, float a1, float a2, const float* m, const float* n) {
  const T yl = (t0 + 16.0f) / 116.0f;
  const T xl = t1 / 500.0f + yl;
  const T zl = yl - (a1 * t2 + a2 * t3) / 200.0f;
  const T r = clamp01(m[0] * xl + m[1] * yl + m[2] * zl);
  const T g = clamp01(m[3] * xl + m[4] * yl + m[5] * zl);
  const T b = clamp01(m[6] * xl + m[7] * yl + m[8] * zl);
  t0 = n[0] * r + n[1] * g + n[2] * b;
  t1 = n[3] * r + n[4] * g + n[5] * b;
  t2 = n[6] * r + n[7] * g + n[8] * b;
}

// The colour step of a row: t[0..3] as filtered (t[2], t[3]: Cz by its two Gaussians) become
// X/Xn, Y/Yn, Z/Zn in t[0..2].
DHR_VEC8_TARGETS void colour_row(float* const* t, float a1, float a2, const float* m, const float* n, int w) {
  int x = 0;
  for (; x + 8 <= w; x += 8) {
    Vec8 t0 = load8(t[0] + x), t1 = load8(t[1] + x), t2 = load8(t[2] + x);
    filtered_to_xyz(t0, t1, t2, load8(t[3] + x), a1, a2, m, n);
    store8(t[0] + x, t0);
    store8(t[1] + x, t1);
    store8(t[2] + x, t2);
  }
  for (; x < w; ++x) filtered_to_xyz(t[0][x], t[1][x], t[2][x], t[3][x], a1, a2, m, n);
}

// CIELAB's f values of a row (f[0..2]) -> Hunt-adjusted CIELAB, interleaved into lab.
DHR_VEC8_TARGETS void lab_row(float* const* f, int w, float* lab) {
  int x = 0;
  for (; x + 8 <= w; x += 8) {
    Vec8 l, a, b;
    hunt_from_f(load8(f[0] + x), load8(f[1] + x), load8(f[2] + x), l, a, b);
    for (int k = 0; k < 8; ++k) {
      float* o = lab + 3 * size_t(x + k);
      o[0] = l[k];
      o[1] = a[k];
      o[2] = b[k];
    }
  }
  for (; x < w; ++x) {
    float* o = lab + 3 * size_t(x);
    hunt_from_f(f[0][x], f[1][x], f[2][x], o[0], o[1], o[2]);
  }
}

// out[x] = sqrt(p[x]^2 + q[x]^2).
DHR_VEC8_TARGETS void magnitude_row(const float* p, const float* q, int w, float* out) {
  int x = 0;
  for (; x + 8 <= w; x += 8) {
    const Vec8 a = load8(p + x), b = load8(q + x);
    store8(out + x, root(a * a + b * b));
  }
  for (; x < w; ++x) out[x] = root(p[x] * p[x] + q[x] * q[x]);
}

// Rows y .. y + n - 1 (n = 1 or 2, all < h) of one image after the vertical pass: Hunt-adjusted
// CIELAB of the filtered colour, and the edge and point feature magnitudes. Two rows share their
// column filters' loads (filter_columns); each row's per-pixel steps are its own.
void vertical_rows(const float* const* planes, const Filters& fl, int w, int h, int y, int n, RowScratch* const* s,
                   const FeatureRow* out) {
  const ColourSpace& cs = colour_space();
  float* t[2][7] = {};
  for (int r = 0; r < n; ++r)
    for (int k = 0; k < 7; ++k) t[r][k] = s[r]->tmp[k].data();
  auto column = [&](Plane plane, const Kernel& k, int slot) {
    float* const rows_out[2] = {t[0][slot], t[1][slot]};
    filter_columns(planes[plane], w, h, y, n, k, rows_out);
  };
  column(kY, fl.y.g1, 0);
  column(kCx, fl.cx.g1, 1);
  column(kCz1, fl.cz.g1, 2);
  column(kCz2, fl.cz.g2, 3);
  // Features: d/dx = d1(x) g(y), d/dy = g(x) d1(y), and the same with d2.
  column(kFd1, fl.f.g, 4);
  column(kFg, fl.f.d1, 5);
  column(kFd2, fl.f.g, 6);
  for (int r = 0; r < n; ++r) {
    colour_row(t[r], fl.cz.alpha1, fl.cz.alpha2, cs.from_xyz, cs.to_xyz, w);
    magnitude_row(t[r][4], t[r][5], w, out[r].edge);
    for (int c = 0; c < 3; ++c) lab_f_row(t[r][c], size_t(w));
    lab_row(t[r], w, out[r].lab);
  }
  // The point detector's y term needs the Gaussian-row plane with d2 vertically.
  column(kFg, fl.f.d2, 5);
  for (int r = 0; r < n; ++r) magnitude_row(t[r][6], t[r][5], w, out[r].point);
}

// The per-pixel steps of flip()'s rows before and between its powers, each as one scalar
// expression would round it (AVX-512, fp-contract off: the same bits; Flip's pinned digests
// hold on both paths). Rows' last n % 16 pixels and CPUs without AVX-512 take the scalar loops.
struct ErrorTerms {
  float knee, slope, cmax_minus_knee;  // slope = kPt / knee
};

// dc[i] = hyab(reference lab i, test lab i) for i < n16 (a multiple of 16).
#if DHR_AVX512_KERNELS
DHR_AVX512_TARGET void hyab_rows16(const float* rlab, const float* tlab, size_t n16, float* dc) {
  for (size_t i = 0; i < n16; i += 16) {
    const Xyz16 r = load_xyz16(rlab + 3 * i), t = load_xyz16(tlab + 3 * i);
    const __m512 da = _mm512_sub_ps(r.y, t.y), db = _mm512_sub_ps(r.z, t.z);
    const __m512 chroma = _mm512_sqrt_ps(_mm512_add_ps(_mm512_mul_ps(da, da), _mm512_mul_ps(db, db)));
    _mm512_storeu_ps(dc + i, _mm512_add_ps(_mm512_abs_ps(_mm512_sub_ps(r.x, t.x)), chroma));
  }
}

// The colour error redistributed (dc in place), the feature term ef and the power 1 - ef.
DHR_AVX512_TARGET void error_terms16(const ErrorTerms& k, const float* redge, const float* tedge, const float* rpoint,
                                     const float* tpoint, size_t n16, float* dc, float* ef, float* ey) {
  const __m512 knee = _mm512_set1_ps(k.knee), slope = _mm512_set1_ps(k.slope);
  const __m512 span = _mm512_set1_ps(k.cmax_minus_knee), pt = _mm512_set1_ps(kPt), rest = _mm512_set1_ps(1.0f - kPt);
  const __m512 inv_sqrt2 = _mm512_set1_ps(float(1.0 / std::sqrt(2.0))), one = _mm512_set1_ps(1.0f);
  for (size_t i = 0; i < n16; i += 16) {
    const __m512 c = _mm512_loadu_ps(dc + i);
    const __m512 low = _mm512_mul_ps(slope, c);
    const __m512 high = _mm512_add_ps(pt, _mm512_mul_ps(_mm512_div_ps(_mm512_sub_ps(c, knee), span), rest));
    _mm512_storeu_ps(dc + i, _mm512_mask_blend_ps(_mm512_cmp_ps_mask(c, knee, _CMP_LT_OQ), high, low));
    const __m512 de = _mm512_abs_ps(_mm512_sub_ps(_mm512_loadu_ps(redge + i), _mm512_loadu_ps(tedge + i)));
    const __m512 dp = _mm512_abs_ps(_mm512_sub_ps(_mm512_loadu_ps(rpoint + i), _mm512_loadu_ps(tpoint + i)));
    const __m512 fd = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(de, dp, _CMP_LT_OQ), de, dp);  // std::max(de, dp)
    const __m512 f = _mm512_sqrt_ps(_mm512_mul_ps(fd, inv_sqrt2));
    _mm512_storeu_ps(ef + i, f);
    _mm512_storeu_ps(ey + i, _mm512_sub_ps(one, f));
  }
}
#endif

// The largest colour error: Hunt-adjusted HyAB between pure green and pure blue, to the q_c.
float max_colour_error() {
  const ColourSpace& cs = colour_space();
  return std::pow(hyab(hunt_lab(cs, 0, 1, 0), hunt_lab(cs, 0, 0, 1)), kQc);
}

}  // namespace

double pixels_per_degree(const FlipViewing& v) {
  if (!(std::isfinite(v.distance_m) && v.distance_m > 0) ||
      !(std::isfinite(v.display_width_m) && v.display_width_m > 0) || v.display_width_px <= 0)
    fail("FLIP viewing setup: distance_m ({}), display_width_m ({}) and display_width_px ({}) must be positive",
         v.distance_m, v.display_width_m, v.display_width_px);
  return v.distance_m * (v.display_width_px / v.display_width_m) * (kPi / 180.0);
}

namespace {

void check_ppd(double ppd) {
  if (!(std::isfinite(ppd) && ppd > 0 && ppd <= 1000))
    fail("FLIP: pixels per degree {} is not valid (must be in (0, 1000]; the paper's setup is 67)", ppd);
}

Filters make_filters(double ppd) {
  Filters fl;
  const int csf_radius = int(std::ceil(3 * std::sqrt(kCsfLargestB / (2 * kPi * kPi)) * ppd));
  fl.y = make_csf(kCsfAchromatic, csf_radius, ppd);
  fl.cx = make_csf(kCsfRedGreen, csf_radius, ppd);
  fl.cz = make_csf(kCsfBlueYellow, csf_radius, ppd);
  fl.f = make_feature_kernels(ppd);
  fl.pad = std::max(csf_radius, fl.f.g.radius);
  if (2 * fl.pad + 1 > kMaxTaps)
    fail("FLIP: a kernel of radius {} at {} pixels per degree exceeds the filters' {} taps", fl.pad, ppd, kMaxTaps);
  return fl;
}

// FLIP's scratch planes of one call (kPlanes floats per pixel: 58 MB at 1920x1080), kept by the
// calling thread between calls (core/base/workspace.h) instead of taking fresh pages every call.
struct FlipWorkspace {
  PixelVector<float> planes[kPlanes];  // not zeroed: first touched by the parallel pass
};

// The horizontal pass of one image into the workspace's planes, each grown to the image's size
// when smaller; the pass overwrites every value it reads back.
std::array<float*, kPlanes> horizontal_planes(const ImageRGB8& image, const Filters& fl, FlipWorkspace& ws) {
  std::array<float*, kPlanes> planes;
  for (int k = 0; k < kPlanes; ++k) {
    PixelVector<float>& p = ws.planes[k];
    if (p.size() < image.size()) p = PixelVector<float>(image.size());
    planes[size_t(k)] = p.data();
  }
  horizontal_pass(image, fl, planes.data());
  return planes;
}

}  // namespace

FlipFeatures flip_features(const ImageRGB8& image, double ppd) {
  if (image.empty()) fail("FLIP: cannot compute the features of an empty image");
  check_ppd(ppd);
  const Filters fl = make_filters(ppd);
  WorkspaceLease<FlipWorkspace> ws;
  const std::array<float*, kPlanes> planes = horizontal_planes(image, fl, *ws);
  const int w = image.width(), h = image.height();
  FlipFeatures f;
  f.width = w;
  f.height = h;
  f.ppd = ppd;
  f.lab.resize(3 * image.size());  // left unwritten (PixelVector): the rows below write every value
  f.edge.resize(image.size());
  f.point.resize(image.size());
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    RowScratch s0(w), s1(w);
    RowScratch* const s[2] = {&s0, &s1};
    auto row = [&](int y) -> FeatureRow {
      const size_t off = size_t(y) * size_t(w);
      return {&f.lab[3 * off], &f.edge[off], &f.point[off]};
    };
    for (int y = rows.begin(); y < rows.end(); y += 2) {  // two rows at a time, the last alone
      const int n = std::min(2, rows.end() - y);
      const FeatureRow out[2] = {row(y), n == 2 ? row(y + 1) : FeatureRow{}};
      vertical_rows(planes.data(), fl, w, h, y, n, s, out);
    }
  });
  return f;
}

FlipResult flip(const ImageRGB8& reference, const ImageRGB8& test, double ppd) {
  if (reference.width() != test.width() || reference.height() != test.height())
    fail("FLIP: images differ in size: {}x{} against {}x{}", reference.width(), reference.height(), test.width(),
         test.height());
  if (reference.empty()) fail("FLIP: cannot compare empty images");
  check_ppd(ppd);
  return flip(flip_features(reference, ppd), test);
}

FlipResult flip(const FlipFeatures& reference, const ImageRGB8& test) {
  const int w = reference.width, h = reference.height;
  if (w != test.width() || h != test.height())
    fail("FLIP: images differ in size: {}x{} against {}x{}", w, h, test.width(), test.height());
  if (test.empty()) fail("FLIP: cannot compare empty images");
  if (reference.lab.size() != 3 * test.size() || reference.edge.size() != test.size() ||
      reference.point.size() != test.size())
    fail("FLIP: the reference's features hold {} values for {}x{} pixels (5 per pixel)",
         reference.lab.size() + reference.edge.size() + reference.point.size(), w, h);
  check_ppd(reference.ppd);
  const Filters fl = make_filters(reference.ppd);
  WorkspaceLease<FlipWorkspace> ws;
  const std::array<float*, kPlanes> test_planes = horizontal_planes(test, fl, *ws);

  const float cmax = max_colour_error();
  const float knee = kPc * cmax;
  const ErrorTerms terms{knee, kPt / knee, cmax - knee};
  FlipResult result;
  result.map.resize_for_overwrite(w, h);  // every value written below
  std::vector<double> row_sums(size_t(h), 0.0);
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    RowScratch s0(w), s1(w);
    RowScratch* const s[2] = {&s0, &s1};
    const size_t wn = size_t(w);
    // The test's features of two rows.
    std::vector<float> lab[2] = {std::vector<float>(3 * wn), std::vector<float>(3 * wn)};
    std::vector<float> edge[2] = {std::vector<float>(wn), std::vector<float>(wn)};
    std::vector<float> point[2] = {std::vector<float>(wn), std::vector<float>(wn)};
    const FeatureRow features[2] = {{lab[0].data(), edge[0].data(), point[0].data()},
                                    {lab[1].data(), edge[1].data(), point[1].data()}};
    // The row's colour differences (then their powers), feature terms and error powers.
    std::vector<float> dc(wn), ef(wn), ey(wn), e(wn);
    // Row y's errors from the test's features `f` of that row.
    auto score_row = [&](int y, const FeatureRow& f) {
      const size_t off = size_t(y) * size_t(w);
      const float* rlab = &reference.lab[3 * off];
      const float* redge = &reference.edge[off];
      const float* rpoint = &reference.point[off];
      float* out = &result.map(0, y);
      // Per pixel, in three passes over the row so that pow runs on whole rows (core/base/pow_row.h:
      // libm's bits, 16 lanes at a time with AVX-512):
      //   colour: HyAB on Hunt-adjusted CIELAB, compressed (to the power q_c), then redistributed
      //   to [0, 1];
      //   features: the larger of the edge and point differences, normalized to [0, 1];
      //   the error: colour to the power 1 - features.
      // pow's exact cases (a fifth of a run's pixels, where the test matches the reference) cost
      // no libm call: pow_row gives 0 to a positive power as +0, and x to the power 1 (ef = 0)
      // is taken as x below (libm's powf is within 0.82 ULP, so it returns a representable
      // result exactly: Flip.PowfExactCasesAsSkipped checks both).
      size_t i0 = 0;  // the pixels before i0 went through the AVX-512 kernels
#if DHR_AVX512_KERNELS
      if (cpu_has_avx512dq()) {
        i0 = wn - wn % 16;
        hyab_rows16(rlab, f.lab, i0, dc.data());
      }
#endif
      for (size_t i = i0; i < wn; ++i) {
        const Lab rl{rlab[3 * i], rlab[3 * i + 1], rlab[3 * i + 2]},
            tl{f.lab[3 * i], f.lab[3 * i + 1], f.lab[3 * i + 2]};
        dc[i] = hyab(rl, tl);
      }
      pow_row(dc.data(), kQc, dc.data(), wn);  // 0^q_c is +0
#if DHR_AVX512_KERNELS
      if (i0) error_terms16(terms, redge, f.edge, rpoint, f.point, i0, dc.data(), ef.data(), ey.data());
#endif
      for (size_t i = i0; i < wn; ++i) {
        const float c = dc[i];
        dc[i] = c < terms.knee ? terms.slope * c : kPt + (c - terms.knee) / terms.cmax_minus_knee * (1.0f - kPt);
        const float fd = std::max(std::abs(redge[i] - f.edge[i]), std::abs(rpoint[i] - f.point[i]));
        ef[i] = std::sqrt(fd * float(1.0 / std::sqrt(2.0)));  // to the power q_f = 1/2
        ey[i] = 1.0f - ef[i];
      }
      pow_row(dc.data(), ey.data(), e.data(), wn);
      double row = 0;
      for (size_t i = 0; i < wn; ++i) {
        const float v = ef[i] == 0.0f ? dc[i] : e[i];
        out[i] = v;
        row += v;
      }
      row_sums[size_t(y)] = row;
    };
    for (int y = rows.begin(); y < rows.end(); y += 2) {  // two rows at a time, the last alone
      const int n = std::min(2, rows.end() - y);
      vertical_rows(test_planes.data(), fl, w, h, y, n, s, features);
      for (int r = 0; r < n; ++r) score_row(y + r, features[r]);
    }
  });
  double total = 0;
  for (double r : row_sums) total += r;  // fixed order: independent of thread count
  result.mean = total / double(test.size());
  return result;
}

float flip_detail::lab_f_value(float t) { return lab_f(t); }
void flip_detail::lab_f_values(float* v, size_t n) { lab_f_row(v, n); }

int flip_detail::test_half_taps(double ppd) {
  check_ppd(ppd);
  const Filters fl = make_filters(ppd);
  auto taps = [](const Kernel& k) { return 2 * k.radius + 1; };
  // horizontal_pass: Yy, Cx, Cz (both Gaussians) and the luminance by g, d1 and d2;
  const int across =
      taps(fl.y.g1) + taps(fl.cx.g1) + taps(fl.cz.g1) + taps(fl.cz.g2) + taps(fl.f.g) + taps(fl.f.d1) + taps(fl.f.d2);
  // vertical_rows: the four colour planes by their own kernels, then g, d1, g and d2 down.
  const int down = taps(fl.y.g1) + taps(fl.cx.g1) + taps(fl.cz.g1) + taps(fl.cz.g2) + 2 * taps(fl.f.g) + taps(fl.f.d1) +
                   taps(fl.f.d2);
  return across + down;
}

ImageRGB8 flip_colour_map(const ImageF& flip_map) {
  ImageRGB8 out(flip_map.width(), flip_map.height());
  for (size_t i = 0; i < flip_map.size(); ++i) {
    float e = flip_map[i];
    if (!(e >= 0.0f)) e = std::isnan(e) ? 1.0f : 0.0f;  // NaN saturates to the top
    e = std::min(e, 1.0f);
    out[i] = kMagma[size_t(std::lround(255.0f * e))];
  }
  return out;
}

}  // namespace dhr
