#include "core/metrics/metrics.h"

#include "core/base/error.h"
#include "core/base/vec8.h"
#include "core/base/workspace.h"

#include <emmintrin.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

namespace dhr {

namespace {

constexpr int kRadius = 5;  // 11x11 window
constexpr double kC1 = (0.01 * 255) * (0.01 * 255);
constexpr double kC2 = (0.03 * 255) * (0.03 * 255);
constexpr int kBlock = 256;  // columns per block of SSIM's vertical pass (double moments on the stack)

std::array<float, 2 * kRadius + 1> gaussian_weights() {
  std::array<float, 2 * kRadius + 1> w{};
  double sum = 0;
  for (int i = -kRadius; i <= kRadius; ++i) sum += std::exp(-(i * i) / (2.0 * 1.5 * 1.5));
  for (int i = -kRadius; i <= kRadius; ++i) w[i + kRadius] = float(std::exp(-(i * i) / (2.0 * 1.5 * 1.5)) / sum);
  return w;
}

// Reflect-101 index (…2 1 | 0 1 2 … n-1 | n-2 …) for any size >= 1.
inline int reflect101(int i, int n) {
  if (n == 1) return 0;
  while (i < 0 || i >= n) {
    if (i < 0) i = -i;
    if (i >= n) i = 2 * n - 2 - i;
  }
  return i;
}

// The horizontal taps of column x of a row of w values into the five moment planes, the taps in
// window order, reflected at the row's ends (reflect101): the border columns' taps, and the
// scalar tail of horizontal_taps (whose windows need no reflection, so the same values).
inline void column_taps(const float* ra, const float* rb, const float* g, int x, int w, float* p0, float* p1, float* p2,
                        float* p3, float* p4) {
  float s[5] = {0, 0, 0, 0, 0};
  for (int k = -kRadius; k <= kRadius; ++k) {
    const int xx = reflect101(x + k, w);
    const float wa = ra[xx], wb = rb[xx], gk = g[k + kRadius];
    s[0] += gk * wa;
    s[1] += gk * wb;
    s[2] += gk * wa * wa;
    s[3] += gk * wb * wb;
    s[4] += gk * wa * wb;
  }
  p0[x] = s[0], p1[x] = s[1], p2[x] = s[2], p3[x] = s[3], p4[x] = s[4];
}

// The horizontal taps of columns [i0, i1) of one row (no reflection needed there) into the
// five moment planes: per column the taps in window order, as the border loop does them, the
// five sums of eight columns in registers.
inline void horizontal_taps(const float* __restrict ra, const float* __restrict rb, const float* __restrict g, int i0,
                            int i1, int w, float* __restrict p0, float* __restrict p1, float* __restrict p2,
                            float* __restrict p3, float* __restrict p4) {
  int x = i0;
  for (; x + 8 <= i1; x += 8) {
    const Vec8 zero{};
    Vec8 s0 = zero, s1 = zero, s2 = zero, s3 = zero, s4 = zero;
    for (int k = -kRadius; k <= kRadius; ++k) {
      const Vec8 gk = splat8(g[k + kRadius]);
      const Vec8 wa = load8(ra + x + k), wb = load8(rb + x + k);
      s0 = s0 + gk * wa;
      s1 = s1 + gk * wb;
      s2 = s2 + gk * wa * wa;
      s3 = s3 + gk * wb * wb;
      s4 = s4 + gk * wa * wb;
    }
    store8(p0 + x, s0), store8(p1 + x, s1), store8(p2 + x, s2), store8(p3 + x, s3), store8(p4 + x, s4);
  }
  for (; x < i1; ++x) column_taps(ra, rb, g, x, w, p0, p1, p2, p3, p4);
}

// The vertical taps of one moment plane: out[i] = sum over the window's rows k of g[k] * rows[k][i]
// in double, in window order from 0, sixteen columns' sums in registers.
inline void vertical_taps(const float* const* rows, const float* g, int n, double* __restrict out) {
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    const Vec4d zero{};
    Vec4d s0 = zero, s1 = zero, s2 = zero, s3 = zero;
    for (int k = 0; k < 2 * kRadius + 1; ++k) {
      const Vec4d gk = zero + double(g[k]);
      const float* p = rows[k] + i;
      s0 = s0 + gk * load4f_as_double(p);
      s1 = s1 + gk * load4f_as_double(p + 4);
      s2 = s2 + gk * load4f_as_double(p + 8);
      s3 = s3 + gk * load4f_as_double(p + 12);
    }
    store4d(out + i, s0), store4d(out + i + 4, s1), store4d(out + i + 8, s2), store4d(out + i + 12, s3);
  }
  for (; i < n; ++i) {
    double sum = 0.0;
    for (int k = 0; k < 2 * kRadius + 1; ++k) sum += double(g[k]) * rows[k][i];
    out[i] = sum;
  }
}

// vertical_taps for two output rows at once: rows[0..2 kRadius + 1], out0 from rows[0..2 kRadius]
// and out1 from rows[1..2 kRadius + 1], each sum in window order from 0 as vertical_taps does
// it. Each row's values are loaded and widened once for both outputs: the ring's rows come from
// L2, and the loads set the pace.
inline void vertical_taps_pair(const float* const* rows, const float* g, int n, double* __restrict out0,
                               double* __restrict out1) {
  constexpr int kTaps = 2 * kRadius + 1;
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    const Vec4d zero{};
    Vec4d a[4] = {zero, zero, zero, zero}, b[4] = {zero, zero, zero, zero};
    for (int k = 0; k <= kTaps; ++k) {
      const float* p = rows[k] + i;
      const Vec4d v[4] = {load4f_as_double(p), load4f_as_double(p + 4), load4f_as_double(p + 8),
                          load4f_as_double(p + 12)};
      if (k < kTaps) {
        const Vec4d gk = zero + double(g[k]);
        for (int j = 0; j < 4; ++j) a[j] = a[j] + gk * v[j];
      }
      if (k > 0) {
        const Vec4d gp = zero + double(g[k - 1]);
        for (int j = 0; j < 4; ++j) b[j] = b[j] + gp * v[j];
      }
    }
    for (int j = 0; j < 4; ++j) store4d(out0 + i + 4 * j, a[j]), store4d(out1 + i + 4 * j, b[j]);
  }
  for (; i < n; ++i) {
    double s0 = 0.0, s1 = 0.0;
    for (int k = 0; k < kTaps; ++k) s0 += double(g[k]) * rows[k][i], s1 += double(g[k]) * rows[k + 1][i];
    out0[i] = s0;
    out1[i] = s1;
  }
}

// SSIM of n <= kBlock pixels from their blurred moments, in three loops that run on vectors
// (the square roots through SSE2: std::sqrt's errno path keeps the compiler from it), each
// pixel's operations as in one scalar expression.
inline void ssim_from_moments(const double* __restrict m_a, const double* __restrict m_b, const double* __restrict m_aa,
                              const double* __restrict m_bb, const double* __restrict m_ab, double* __restrict v,
                              int n) {
  double var_a[kBlock], var_b[kBlock], bound[kBlock];
  for (int i = 0; i < n; ++i) {
    const double mu_a = m_a[i], mu_b = m_b[i];
    var_a[i] = std::max(0.0, m_aa[i] - mu_a * mu_a);
    var_b[i] = std::max(0.0, m_bb[i] - mu_b * mu_b);
    bound[i] = var_a[i] * var_b[i];
  }
  int i = 0;
  for (; i + 2 <= n; i += 2) _mm_storeu_pd(bound + i, _mm_sqrt_pd(_mm_loadu_pd(bound + i)));
  for (; i < n; ++i) bound[i] = std::sqrt(bound[i]);
  for (i = 0; i < n; ++i) {
    const double mu_a = m_a[i], mu_b = m_b[i];
    // Rounding can push the moments slightly outside what they can be: clamp the variances at
    // 0 (above) and the covariance to |cov| <= sqrt(var_a var_b) (Cauchy-Schwarz), so that
    // identical images score exactly 1 and flat regions never go negative.
    const double c = m_ab[i] - mu_a * mu_b;  // std::clamp(c, -bound, bound), spelled out
    const double cov = c < -bound[i] ? -bound[i] : (bound[i] < c ? bound[i] : c);
    v[i] =
        ((2 * mu_a * mu_b + kC1) * (2 * cov + kC2)) / ((mu_a * mu_a + mu_b * mu_b + kC1) * (var_a[i] + var_b[i] + kC2));
  }
}

// What one band of rows of ssim_plane reads and writes.
struct SsimBand {
  const float* a;
  const float* b;
  int w, h;
  int x0, x1;  // the columns computed
  bool valid;
  ImageF* map;
  const float* g;    // the window's weights
  double* row_sums;  // per image row
};

// The rows two output rows read lie within 12 consecutive image rows (reflect101 maps the
// windows into [y - 5, y + 6] clipped to the image), so 16 ring slots never collide.
constexpr int kRing = 16;
constexpr int kBandRows = 32;

// Rows [ya, yb) of ssim_plane; `ring`: 16 rows x 5 planes of w floats.
DHR_VEC8_TARGETS void ssim_band(const SsimBand& p, int ya, int yb, float* ring) {
  const int w = p.w, x0 = p.x0, x1 = p.x1;
  const size_t ws = size_t(w);
  int tag[kRing];
  std::fill(tag, tag + kRing, -1);
  auto horizontal = [&](int y) -> const float* {
    const int slot = y % kRing;
    float* out = &ring[size_t(slot) * 5 * ws];
    if (tag[slot] == y) return out;
    tag[slot] = y;
    const float* ra = p.a + size_t(y) * ws;
    const float* rb = p.b + size_t(y) * ws;
    float* p0 = out;
    float* p1 = out + ws;
    float* p2 = out + 2 * ws;
    float* p3 = out + 3 * ws;
    float* p4 = out + 4 * ws;
    // Columns whose window needs no reflection.
    const int i0 = std::max(x0, kRadius), i1 = std::min(x1, w - kRadius);
    if (i0 < i1) horizontal_taps(ra, rb, p.g, i0, i1, w, p0, p1, p2, p3, p4);
    // The border columns (and every column of an image narrower than one window).
    for (int x = x0; x < x1; ++x) {
      if (x >= i0 && x < i1) {
        x = i1 - 1;
        continue;
      }
      column_taps(ra, rb, p.g, x, w, p0, p1, p2, p3, p4);
    }
    return out;
  };
  // The rows of one output row's window (two output rows': one more), and one plane's of them.
  const float* rows[2 * kRadius + 2];
  const float* plane_rows[2 * kRadius + 2];
  double s[2][5][kBlock];
  double v[kBlock];
  // SSIM of n pixels of output row y from moments m, into the map and the row's sum.
  auto finish = [&](int y, int bx, int n, const double(&m)[5][kBlock], double& row) {
    ssim_from_moments(m[0], m[1], m[2], m[3], m[4], v, n);
    if (p.map)
      for (int i = 0; i < n; ++i) (*p.map)(bx + i, y) = float(v[i]);
    for (int i = 0; i < n; ++i)  // in column order, as one sum per row
      if (!p.valid || (bx + i >= kRadius && bx + i < w - kRadius)) row += v[i];
  };
  int y = ya;
  // Two output rows at a time: their windows share 10 of their 12 rows (vertical_taps_pair).
  for (; y + 1 < yb; y += 2) {
    for (int k = -kRadius; k <= kRadius + 1; ++k) rows[k + kRadius] = horizontal(reflect101(y + k, p.h));
    double row0 = 0, row1 = 0;
    for (int bx = x0; bx < x1; bx += kBlock) {
      const int n = std::min(kBlock, x1 - bx);
      for (int c = 0; c < 5; ++c) {
        for (int k = 0; k < 2 * kRadius + 2; ++k) plane_rows[k] = rows[k] + size_t(c) * ws + size_t(bx);
        vertical_taps_pair(plane_rows, p.g, n, s[0][c], s[1][c]);
      }
      finish(y, bx, n, s[0], row0);
      finish(y + 1, bx, n, s[1], row1);
    }
    p.row_sums[size_t(y)] = row0;
    p.row_sums[size_t(y) + 1] = row1;
  }
  for (; y < yb; ++y) {
    for (int k = -kRadius; k <= kRadius; ++k) rows[k + kRadius] = horizontal(reflect101(y + k, p.h));
    double row = 0;
    for (int bx = x0; bx < x1; bx += kBlock) {
      const int n = std::min(kBlock, x1 - bx);
      for (int c = 0; c < 5; ++c) {
        for (int k = 0; k < 2 * kRadius + 1; ++k) plane_rows[k] = rows[k] + size_t(c) * ws + size_t(bx);
        vertical_taps(plane_rows, p.g, n, s[0][c]);
      }
      finish(y, bx, n, s[0], row);
    }
    p.row_sums[size_t(y)] = row;
  }
}

// SSIM map of two float planes (values in 0..255), returns the mean over all pixels (Mirrored)
// or over the valid interior (Valid). The five local moments (a, b, a^2, b^2, ab) are blurred
// separably, fused per band of rows: each row's horizontal pass goes into a ring of row planes
// (float, the taps in window order), the vertical pass of a row then reads its 11 rows from the
// ring (double, in window order) -- the same operations in the same order per pixel as one
// horizontal pass over the whole image followed by one vertical pass, so the same bits, without
// the image-sized intermediate. Without a map, Valid skips the pixels it does not average
// (their windows would only be needed for the map). The taps of both passes run on vectors
// (core/base/vec8.h: AVX2 or the baseline, no FMA), their sums kept in registers.
double ssim_plane(const float* a, const float* b, int w, int h, ImageF* map, SsimBorder border) {
  const bool valid = border == SsimBorder::Valid;
  // Columns and rows whose SSIM is computed: all, or the interior when nothing else needs them.
  const int x0 = valid && !map ? kRadius : 0, x1 = valid && !map ? w - kRadius : w;
  const int y0 = valid && !map ? kRadius : 0, y1 = valid && !map ? h - kRadius : h;
  static const auto g = gaussian_weights();
  std::vector<double> row_sums(size_t(h), 0.0);
  if (map) map->resize(w, h);
  const SsimBand band_args{a, b, w, h, x0, x1, valid, map, g.data(), row_sums.data()};
  const int bands = (y1 - y0 + kBandRows - 1) / kBandRows;
  tbb::parallel_for(0, bands, [&](int band) {
    // Per thread, reused across calls: 16 rows x 5 planes of w floats.
    static thread_local std::vector<float> ring;
    ring.resize(size_t(kRing) * 5 * size_t(w));
    const int ya = y0 + band * kBandRows, yb = std::min(y1, ya + kBandRows);
    ssim_band(band_args, ya, yb, ring.data());
  });
  double total = 0;
  if (!valid) {
    for (double r : row_sums) total += r;  // fixed order: independent of thread count
    return total / (double(w) * h);
  }
  for (int y = kRadius; y < h - kRadius; ++y) total += row_sums[size_t(y)];
  return total / (double(w - 2 * kRadius) * double(h - 2 * kRadius));
}

void check_border(int w, int h, SsimBorder border) {
  if (border == SsimBorder::Valid && (w < kSsimWindow || h < kSsimWindow))
    fail(
        "SSIM over the valid interior needs images of at least {}x{} pixels (one window), got {}x{}; "
        "SsimBorder::Mirrored accepts any size",
        kSsimWindow, kSsimWindow, w, h);
}

void check_pair(int wa, int ha, int wb, int hb) {
  if (wa != wb || ha != hb) fail("images differ in size: {}x{} against {}x{}", wa, ha, wb, hb);
  if (wa <= 0 || ha <= 0) fail("cannot compare empty images");
}

}  // namespace

namespace {

// luma's rounding of n pixels, built for AVX2 and the baseline: the compiler vectorizes the
// plain loop (2.5x faster than building four-lane vectors by hand, which was tried), every pixel
// the same operations.
DHR_VEC8_TARGETS void luma_pixels(const Rgb8* in, uint8_t* out, size_t n) {
  for (size_t i = 0; i < n; ++i) out[i] = uint8_t(int(0.299 * in[i].r + 0.587 * in[i].g + 0.114 * in[i].b + 0.5));
}

// The sums of squared and of absolute differences of all channels. Integers, summed exactly
// in 64 bits: the same values as summing them in double, whose partial sums stay integers
// below 2^53 (at most 3 x 255^2 per pixel).
struct DifferenceSums {
  int64_t squared = 0, absolute = 0;
};
DHR_VEC8_TARGETS DifferenceSums difference_sums(const Rgb8* a, const Rgb8* b, size_t n) {
  DifferenceSums s;
  for (size_t i = 0; i < n; ++i) {
    const int dr = a[i].r - b[i].r, dg = a[i].g - b[i].g, db = a[i].b - b[i].b;
    s.squared += dr * dr + dg * dg + db * db;
    s.absolute += std::abs(dr) + std::abs(dg) + std::abs(db);
  }
  return s;
}

double psnr_from(int64_t squared_sum, size_t pixels) {
  const double se = double(squared_sum);
  if (se == 0) return std::numeric_limits<double>::infinity();
  const double mse = se / (3.0 * double(pixels));
  return 10.0 * std::log10(255.0 * 255.0 / mse);
}

// ssim_u8's planes as floats, kept per thread between calls (core/base/workspace.h).
struct SsimInputs {
  std::vector<float> a, b;
};

}  // namespace

ImageU8 luma(const ImageRGB8& image) {
  ImageU8 out(image.width(), image.height());
  // Truncating x + 0.5 gives std::lround(x) for every (r, g, b) (all 2^24 checked by
  // tests/core/metrics/test_metrics.cpp), without the library call.
  luma_pixels(image.data(), out.data(), image.size());
  return out;
}

double ssim_u8(const ImageU8& a, const ImageU8& b, ImageF* ssim_map, SsimBorder border) {
  check_pair(a.width(), a.height(), b.width(), b.height());
  check_border(a.width(), a.height(), border);
  WorkspaceLease<SsimInputs> ws;
  ws->a.assign(a.pixels().begin(), a.pixels().end());
  ws->b.assign(b.pixels().begin(), b.pixels().end());
  return ssim_plane(ws->a.data(), ws->b.data(), a.width(), a.height(), ssim_map, border);
}

double psnr_db(const ImageRGB8& a, const ImageRGB8& b) {
  check_pair(a.width(), a.height(), b.width(), b.height());
  return psnr_from(difference_sums(a.data(), b.data(), a.size()).squared, a.size());
}

QualityScores compare_images(const ImageRGB8& a, const ImageRGB8& b, SsimChannel channel, ImageF* ssim_map,
                             SsimBorder border) {
  check_pair(a.width(), a.height(), b.width(), b.height());
  check_border(a.width(), a.height(), border);
  QualityScores q;
  if (channel == SsimChannel::Luma) {
    q.ssim = ssim_u8(luma(a), luma(b), ssim_map, border);
  } else {
    const size_t n = a.size();
    std::vector<float> pa(n), pb(n);
    double sum = 0;
    ImageF channel_map;
    if (ssim_map) ssim_map->resize(a.width(), a.height(), 0.0f);
    for (int c = 0; c < 3; ++c) {
      for (size_t i = 0; i < n; ++i) {
        pa[i] = c == 0 ? a[i].r : c == 1 ? a[i].g : a[i].b;
        pb[i] = c == 0 ? b[i].r : c == 1 ? b[i].g : b[i].b;
      }
      sum += ssim_plane(pa.data(), pb.data(), a.width(), a.height(), ssim_map ? &channel_map : nullptr, border);
      if (ssim_map)
        for (size_t i = 0; i < n; ++i) (*ssim_map)[i] += channel_map[i] / 3.0f;
    }
    q.ssim = sum / 3.0;
  }
  const DifferenceSums d = difference_sums(a.data(), b.data(), a.size());
  q.psnr_db = psnr_from(d.squared, a.size());
  q.mean_abs_error = double(d.absolute) / (3.0 * double(a.size()));
  return q;
}

ImageF abs_luma_difference(const ImageRGB8& a, const ImageRGB8& b) {
  check_pair(a.width(), a.height(), b.width(), b.height());
  const ImageU8 la = luma(a), lb = luma(b);
  ImageF out(a.width(), a.height());
  for (size_t i = 0; i < out.size(); ++i) out[i] = float(std::abs(int(la[i]) - int(lb[i])));
  return out;
}

ImageRGB8 error_map(const ImageF& error, float max_value, bool with_colour_bar) {
  // Control points of a perceptually ordered ramp (approximating viridis).
  static const std::array<glm::vec3, 5> ramp = {glm::vec3(0.267f, 0.005f, 0.329f), glm::vec3(0.231f, 0.322f, 0.545f),
                                                glm::vec3(0.129f, 0.569f, 0.549f), glm::vec3(0.369f, 0.788f, 0.384f),
                                                glm::vec3(0.993f, 0.906f, 0.144f)};
  auto colour = [&](float t) -> Rgb8 {
    if (!std::isfinite(t)) t = 1.0f;
    t = std::clamp(t, 0.0f, 1.0f) * 4.0f;
    const int i = std::min(int(t), 3);
    const glm::vec3 c = glm::mix(ramp[size_t(i)], ramp[size_t(i) + 1], t - float(i));
    return {uint8_t(c.x * 255), uint8_t(c.y * 255), uint8_t(c.z * 255)};
  };
  const int w = error.width(), h = error.height();
  const int bar = with_colour_bar ? std::max(4, h / 24) : 0;
  ImageRGB8 out(w, h + bar);
  const float scale = max_value > 0 ? 1.0f / max_value : 0.0f;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) out(x, y) = colour(error(x, y) * scale);
  for (int y = h; y < h + bar; ++y)
    for (int x = 0; x < w; ++x) out(x, y) = colour(w > 1 ? float(x) / float(w - 1) : 0.0f);
  return out;
}

}  // namespace dhr
