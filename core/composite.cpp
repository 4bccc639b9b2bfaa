// The composite (see core/composite.h): decoding of the passes, the shading kernel per pixel
// and sRGB tone mapping.
#include "core/composite.h"

#include "core/error.h"
#include "core/vec8.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

namespace dhr {

namespace {

double srgb_to_linear(double v) { return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4); }

// Linear values at which the rounded 8-bit sRGB code steps from k-1 to k (k = 1..255), and for
// 128 buckets per binade of floats in [2^-13, 1) the code at the bucket's first float. The first
// boundary, 1.5e-4, lies above 2^-13 and the last, 0.99, below 1; no bucket holds more than
// kBucketSteps boundaries (checked when the table is built), and boundary[255..] is +inf.
constexpr int kBucketBits = 7;
constexpr int kBucketSteps = 2;
constexpr uint32_t kFirstBucketExponent = 127 - 13;  // biased exponent of 2^-13
struct SrgbCodes {
  std::array<float, 255 + kBucketSteps> boundary{};
  std::array<uint8_t, 13u << kBucketBits> start{};
};

const SrgbCodes& srgb_codes() {
  static const SrgbCodes table = [] {
    SrgbCodes t;
    for (int k = 1; k <= 255; ++k) t.boundary[size_t(k - 1)] = float(srgb_to_linear((k - 0.5) / 255.0));
    for (size_t k = 255; k < t.boundary.size(); ++k) t.boundary[k] = std::numeric_limits<float>::infinity();
    const auto codes = [&](float v) {
      return std::upper_bound(t.boundary.begin(), t.boundary.begin() + 255, v) - t.boundary.begin();
    };
    for (uint32_t i = 0; i < t.start.size(); ++i) {
      const uint32_t first = (i + (kFirstBucketExponent << kBucketBits)) << (23 - kBucketBits);
      t.start[i] = uint8_t(codes(std::bit_cast<float>(first)));
      const float last = std::bit_cast<float>(first + (1u << (23 - kBucketBits)) - 1);
      if (codes(last) - t.start[i] > kBucketSteps)
        fail("composite: sRGB code bucket {} ([{}, {}]) holds {} boundaries, the lookup steps over at most {}", i,
             std::bit_cast<float>(first), last, codes(last) - t.start[i], kBucketSteps);
    }
    return t;
  }();
  return table;
}

// The 8-bit sRGB code of a linear value: the number of code boundaries <= linear (what
// std::upper_bound counts); 0 for linear <= 0 and NaN. The bucket of the float's exponent and
// top mantissa bits gives the count at the bucket's start, then the bucket's own boundaries
// are stepped over without branches.
inline uint8_t srgb8_code(const SrgbCodes& t, float linear) {
  if (!(linear >= 0x1p-13f)) return 0;  // NaN, <= 0, or below the first boundary
  if (linear >= 1.0f) return 255;       // above the last
  const uint32_t bucket = (std::bit_cast<uint32_t>(linear) >> (23 - kBucketBits)) - (kFirstBucketExponent << kBucketBits);
  uint32_t code = t.start[bucket];
  for (int step = 0; step < kBucketSteps; ++step) code += t.boundary[code] <= linear ? 1u : 0u;
  return uint8_t(code);
}

// The inputs of the shading, one slot per composited meaning. A new composite term is a slot
// here (and its case in place()), the row of values it reads in composite() and
// composite_fractions() below, its member of PixelTerms and its plane in RowPlanes, and its use
// in shade_row and in shade_lambert (core/composite.h).
template <class T>
struct CompositeInputs {
  T visibility{};  // V_l per light
  T ao{};          // AO
  uint32_t seen = 0;  // bit m: a pass of meaning m was placed

  // Where the pass of `meaning` goes; dhr::Error for a meaning the composite does not shade or
  // a second pass of one meaning.
  void place(PassMeaning meaning, T value) {
    T* slot = nullptr;
    switch (meaning) {
      case PassMeaning::Visibility: slot = &visibility; break;
      case PassMeaning::Ao: slot = &ao; break;
      case PassMeaning::Colour:
      case PassMeaning::Depth: break;
    }
    if (!slot) fail("composite: a {} pass is displayed or read as it is, not composited", pass_meaning_name(meaning));
    const uint32_t bit = 1u << unsigned(meaning);
    if (seen & bit) fail("composite: two {} passes", pass_meaning_name(meaning));
    seen |= bit;
    *slot = value;
  }
};

// A composited pass must be of its slot's meaning, one channel per light for visibility, and
// match the G-buffer and its own description.
void check_pass(const PassBuffer& pb, const GBuffer& g, const Scene& scene, PassMeaning meaning) {
  const std::string problem = pb.desc.validate();
  if (!problem.empty()) fail("composite: {} pass: {}", pass_kind_name(pb.desc.kind), problem);
  const PassLayout layout = pb.desc.layout();
  if (pass_meaning(pb.desc.kind) != meaning || (layout != PassLayout::Bitmask && layout != PassLayout::Planes8))
    fail("composite: got a {} pass where a {} pass was expected", pass_kind_name(pb.desc.kind),
         pass_meaning_name(meaning));
  if (pb.desc.width != g.width() || pb.desc.height != g.height())
    fail("composite: {} pass is {}x{}, the G-buffer {}x{}", pass_kind_name(pb.desc.kind), pb.desc.width,
         pb.desc.height, g.width(), g.height());
  if (meaning == PassMeaning::Visibility && size_t(pb.desc.channels) != scene.lights.size())
    fail("composite: {} pass has {} channels, the scene {} lights", pass_kind_name(pb.desc.kind), pb.desc.channels,
         scene.lights.size());
  if (pb.bytes.size() != pb.desc.byte_size())
    fail("composite: {} pass has {} bytes, its description needs {}", pass_kind_name(pb.desc.kind), pb.bytes.size(),
         pb.desc.byte_size());
}

// ---- the shading, eight pixels at a time ----
// shade_lambert (core/composite.h) over a row, written with GCC's vector extension: the same
// operations per pixel in the same order (every product, sum, square root and division rounded
// on its own; neither target has FMA instructions, so nothing is contracted), so the same bits
// as the scalar kernel on every pixel (Composite.RowKernelMatchesShadeLambert in
// tests/test_trace.cpp). A light that the scalar kernel skips for a pixel (out of range, at its
// centre, facing away, invisible) leaves that lane's sum untouched. Vec8 and the AVX2/baseline
// clones: core/vec8.h.

// One light's constants, as the scalar kernel computes them per pixel.
struct LightTerm {
  const Light* light = nullptr;
  bool sphere = true;
  bool skip = false;    // a distant light without a direction: no term
  bool ranged = false;  // range_m > 0
  float range2 = 0.0f;  // range_m * range_m
  float radius2 = 0.0f;
  float length = 1.0f;  // |direction|
};

std::vector<LightTerm> light_terms(const Scene& scene) {
  std::vector<LightTerm> out;
  for (const Light& L : scene.lights) {
    LightTerm t;
    t.light = &L;
    t.sphere = L.type == LightType::Sphere;
    t.ranged = L.range_m > 0.0f;
    t.range2 = L.range_m * L.range_m;
    t.radius2 = L.radius_m * L.radius_m;
    if (!t.sphere) {
      t.length = glm::length(L.direction);
      t.skip = !(t.length > 0.0f);
    }
    out.push_back(t);
  }
  return out;
}

// The inputs of one row, planar, `stride` floats per plane (a multiple of 8).
struct RowPlanes {
  size_t stride = 0;
  std::vector<float> data;  // p.xyz, n.xyz, albedo.xyz, ao, then one plane of V per light
  float* plane(int i) { return data.data() + size_t(i) * stride; }
  const float* plane(int i) const { return data.data() + size_t(i) * stride; }
};
constexpr int kPlaneAo = 9, kPlaneVisibility = 10;

// linear[c][x] = exposure * albedo * (ambient * AO + sum_l V_l * ...), for x < in.stride.
DHR_VEC8_TARGETS void shade_row(const RowPlanes& in, const LightTerm* lights, int light_count,
                                glm::vec3 ambient, float exposure, float* linear) {
  constexpr float kMinDistance2 = 1e-6f;
  const size_t n = in.stride;
  for (size_t i = 0; i < n; i += 8) {
    const Vec8 px = load8(in.plane(0) + i), py = load8(in.plane(1) + i), pz = load8(in.plane(2) + i);
    const Vec8 nx = load8(in.plane(3) + i), ny = load8(in.plane(4) + i), nz = load8(in.plane(5) + i);
    const Vec8 ao = load8(in.plane(kPlaneAo) + i);
    Vec8 lx = ambient.x * ao, ly = ambient.y * ao, lz = ambient.z * ao;
    for (int l = 0; l < light_count; ++l) {
      const LightTerm& L = lights[l];
      if (L.skip) continue;
      const Light& light = *L.light;
      Mask8 ok = Mask8{} == 0;  // all lanes
      Vec8 n_dot_l, falloff;
      if (L.sphere) {
        const Vec8 tx = light.position.x - px, ty = light.position.y - py, tz = light.position.z - pz;
        const Vec8 d2 = tx * tx + ty * ty + tz * tz;
        if (L.ranged) ok &= !(d2 > L.range2);
        Vec8 d;
        for (int k = 0; k < 8; ++k) d[k] = std::sqrt(d2[k]);
        ok &= d > 0.0f;
        n_dot_l = (nx * tx + ny * ty + nz * tz) / d;
        Vec8 m = d2;  // std::max({d2, radius^2, kMinDistance2}): the first largest
        m = m < L.radius2 ? splat8(L.radius2) : m;
        m = m < kMinDistance2 ? splat8(kMinDistance2) : m;
        falloff = 1.0f / m;
      } else {
        n_dot_l = (nx * light.direction.x + ny * light.direction.y + nz * light.direction.z) / L.length;
        falloff = splat8(1.0f);
      }
      const Vec8 v = load8(in.plane(kPlaneVisibility + l) + i);
      ok &= n_dot_l > 0.0f;
      ok &= v > 0.0f;
      const Vec8 s = v * light.intensity * n_dot_l * falloff;
      lx = ok ? lx + s * light.colour.x : lx;
      ly = ok ? ly + s * light.colour.y : ly;
      lz = ok ? lz + s * light.colour.z : lz;
    }
    store8(linear + i, load8(in.plane(6) + i) * lx * exposure);
    store8(linear + n + i, load8(in.plane(7) + i) * ly * exposure);
    store8(linear + 2 * n + i, load8(in.plane(8) + i) * lz * exposure);
  }
}

// Row [first, first + n) of an 8-bit one-channel pass as fractions, min(1, byte / full_scale),
// or `absent` everywhere without the pass.
void fraction_row(const PassBuffer* pass, size_t first, size_t n, float absent, float* __restrict out) {
  if (!pass) return std::fill(out, out + n, absent);
  const float scale = 1.0f / float(pass->desc.full_scale);
  const uint8_t* __restrict in = pass->bytes.data() + first;
  for (size_t i = 0; i < n; ++i) out[i] = std::min(1.0f, float(in[i]) * scale);
}

// The same from per-pixel fractions (empty: absent).
void fraction_row(std::span<const float> values, size_t first, size_t n, float absent, float* out) {
  if (values.empty()) return std::fill(out, out + n, absent);
  std::copy_n(values.begin() + std::ptrdiff_t(first), n, out);
}

// A row's G-buffer values into the first nine planes (position, normal, albedo): the geometric
// normal where the shading normal is zero or NaN. Both normals are read and the choice is a
// select, so that the loop has no branch: built for AVX2 and the baseline, it is vectorized.
DHR_VEC8_TARGETS void gbuffer_row(const float* __restrict pos, const float* __restrict nrm,
                                  const float* __restrict geo, const float* __restrict alb, int w,
                                  float* const* planes) {
  float* __restrict px = planes[0];
  float* __restrict py = planes[1];
  float* __restrict pz = planes[2];
  float* __restrict nx = planes[3];
  float* __restrict ny = planes[4];
  float* __restrict nz = planes[5];
  float* __restrict ax = planes[6];
  float* __restrict ay = planes[7];
  float* __restrict az = planes[8];
  for (int x = 0; x < w; ++x) {
    const size_t i = 3 * size_t(x);
    const float sx = nrm[i], sy = nrm[i + 1], sz = nrm[i + 2];
    const bool fallback = !(sx * sx + sy * sy + sz * sz > 0.0f);  // glm::dot's sum, in its order
    px[x] = pos[i], py[x] = pos[i + 1], pz[x] = pos[i + 2];
    nx[x] = fallback ? geo[i] : sx, ny[x] = fallback ? geo[i + 1] : sy, nz[x] = fallback ? geo[i + 2] : sz;
    ax[x] = alb[i], ay[x] = alb[i + 1], az[x] = alb[i + 2];
  }
}

// vis_row(l, first, n, out) writes V_l of the n pixels from pixel `first` on; terms_row(first,
// n, in) the planes of their PixelTerms (kPlaneAo, ...). A row's pass values are read plane by
// plane, in loops the compiler vectorizes. Uncovered pixels are shaded with whatever their
// inputs hold, and never shown (the background is).
template <class VisRow, class TermsRow>
ImageRGB8 composite_impl(const GBuffer& g, const Scene& scene, const CompositeSettings& settings, VisRow&& vis_row,
                         TermsRow&& terms_row) {
  if (!(settings.exposure > 0.0f) || !std::isfinite(settings.exposure))
    fail("composite: exposure {} must be finite and > 0", settings.exposure);
  const int w = g.width(), h = g.height();
  ImageRGB8 out(w, h);
  const Rgb8 background = tonemap_srgb8(scene.background * settings.exposure);
  const std::vector<LightTerm> lights = light_terms(scene);
  const int nl = int(lights.size());
  const size_t stride = (size_t(w) + 7) / 8 * 8;
  const SrgbCodes& b = srgb_codes();
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    RowPlanes in;
    in.stride = stride;
    in.data.assign(stride * size_t(kPlaneVisibility + nl), 0.0f);
    std::vector<float> linear(3 * stride);
    float* planes[9];
    for (int k = 0; k < 9; ++k) planes[k] = in.plane(k);
    for (int y = rows.begin(); y < rows.end(); ++y) {
      const size_t first = size_t(y) * size_t(w);
      static_assert(sizeof(glm::vec3) == 3 * sizeof(float));
      gbuffer_row(&g.position(0, y).x, &g.normal(0, y).x, &g.geo_normal(0, y).x, &g.albedo(0, y).x, w, planes);
      terms_row(first, size_t(w), in);
      for (int l = 0; l < nl; ++l) vis_row(size_t(l), first, size_t(w), in.plane(kPlaneVisibility + l));
      shade_row(in, lights.data(), nl, scene.ambient, settings.exposure, linear.data());
      const uint32_t* id = &g.object_id(0, y);
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(x);
        out(x, y) = id[i] != kBackgroundId ? Rgb8{srgb8_code(b, linear[i]), srgb8_code(b, linear[stride + i]),
                                                  srgb8_code(b, linear[2 * stride + i])}
                                           : background;
      }
    }
  });
  return out;
}

}  // namespace

uint8_t tonemap_srgb8(float linear) { return srgb8_code(srgb_codes(), linear); }

Rgb8 tonemap_srgb8(const glm::vec3& linear) {
  return {tonemap_srgb8(linear.x), tonemap_srgb8(linear.y), tonemap_srgb8(linear.z)};
}

ImageRGB8 composite(const GBuffer& g, const Scene& scene, std::span<const CompositePass> passes,
                    const CompositeSettings& settings) {
  CompositeInputs<const PassBuffer*> in;
  for (const CompositePass& p : passes)
    if (p.buffer) {
      in.place(p.meaning, p.buffer);
      check_pass(*p.buffer, g, scene, p.meaning);
    }
  const PassBuffer* visibility = in.visibility;
  const PassBuffer* ao = in.ao;
  const size_t npx = size_t(g.width()) * size_t(g.height());
  auto terms_row = [&](size_t first, size_t n, RowPlanes& rp) {
    fraction_row(ao, first, n, 1.0f, rp.plane(kPlaneAo));
  };
  if (visibility && visibility->desc.layout() == PassLayout::Bitmask) {
    const uint8_t* bytes = visibility->bytes.data();
    const size_t bpp = size_t((visibility->desc.channels + 7) / 8);
    return composite_impl(
        g, scene, settings,
        [&](size_t l, size_t first, size_t n, float* __restrict out) {
          const uint8_t* __restrict src = bytes + first * bpp + (l >> 3);
          for (size_t i = 0; i < n; ++i) out[i] = float((src[i * bpp] >> (l & 7)) & 1u);
        },
        terms_row);
  }
  // 8-bit planes, one per light, or no pass (fully lit).
  return composite_impl(
      g, scene, settings,
      [&](size_t l, size_t first, size_t n, float* out) { fraction_row(visibility, l * npx + first, n, 1.0f, out); },
      terms_row);
}

ImageRGB8 composite(const GBuffer& g, const Scene& scene, const PassBuffer* visibility, const PassBuffer* ao,
                    const CompositeSettings& settings) {
  const CompositePass passes[] = {{PassMeaning::Visibility, visibility}, {PassMeaning::Ao, ao}};
  return composite(g, scene, passes, settings);
}

ImageRGB8 composite(const GBuffer& g, const Scene& scene, const TracedPasses& traced, const CompositeSettings& settings) {
  std::vector<CompositePass> inputs;
  for (const TracedPass& p : traced.passes) inputs.push_back({p.meaning, &p.buffer});
  return composite(g, scene, inputs, settings);
}

ImageRGB8 composite_fractions(const GBuffer& g, const Scene& scene, std::span<const CompositeFractions> passes,
                              const CompositeSettings& settings) {
  CompositeInputs<std::span<const float>> in;
  for (const CompositeFractions& p : passes)
    if (!p.values.empty()) in.place(p.meaning, p.values);
  const std::span<const float> visibility = in.visibility, ao = in.ao;
  const size_t npx = size_t(g.width()) * size_t(g.height());
  if (!visibility.empty() && visibility.size() != npx * scene.lights.size())
    fail("composite: {} visibility values for {} pixels x {} lights", visibility.size(), npx, scene.lights.size());
  if (!ao.empty() && ao.size() != npx) fail("composite: {} AO values for {} pixels", ao.size(), npx);
  return composite_impl(
      g, scene, settings,
      [&](size_t l, size_t first, size_t n, float* out) { fraction_row(visibility, l * npx + first, n, 1.0f, out); },
      [&](size_t first, size_t n, RowPlanes& rp) { fraction_row(ao, first, n, 1.0f, rp.plane(kPlaneAo)); });
}

}  // namespace dhr
