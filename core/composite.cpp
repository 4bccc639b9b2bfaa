// The composite (see core/composite.h): decoding of the passes, the shading kernel per pixel
// and sRGB tone mapping.
#include "core/composite.h"

#include "core/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <array>
#include <cmath>

namespace dhr {

namespace {

double srgb_to_linear(double v) { return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4); }

// Linear values at which the rounded 8-bit sRGB code steps from k-1 to k (k = 1..255).
const std::array<float, 255>& code_boundaries() {
  static const std::array<float, 255> table = [] {
    std::array<float, 255> t{};
    for (int k = 1; k <= 255; ++k) t[size_t(k - 1)] = float(srgb_to_linear((k - 0.5) / 255.0));
    return t;
  }();
  return table;
}

// The 8-bit sRGB code of a linear value: the number of code boundaries <= linear (what
// std::upper_bound counts), by a binary search without branches (8 conditional moves over the
// 255 sorted boundaries); 0 for linear <= 0 and NaN.
inline uint8_t srgb8_code(const std::array<float, 255>& b, float linear) {
  if (!(linear > 0.0f)) return 0;
  const float* base = b.data();
  size_t n = b.size();
  while (n > 1) {
    const size_t half = n / 2;
    base = base[half] <= linear ? base + half : base;
    n -= half;
  }
  return uint8_t((base - b.data()) + (*base <= linear ? 1 : 0));
}

// The inputs of the shading, one slot per composited meaning. A new composite term is a slot
// here (and its case in slot()), the layouts it reads in composite() and composite_fractions()
// below, and its use in shade_lambert (core/composite.h).
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

template <class VisAt, class AoAt>
ImageRGB8 composite_impl(const GBuffer& g, const Scene& scene, const CompositeSettings& settings, VisAt&& vis_at,
                         AoAt&& ao_at) {
  if (!(settings.exposure > 0.0f) || !std::isfinite(settings.exposure))
    fail("composite: exposure {} must be finite and > 0", settings.exposure);
  const int w = g.width(), h = g.height();
  ImageRGB8 out(w, h);
  const Rgb8 background = tonemap_srgb8(scene.background * settings.exposure);
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      for (int x = 0; x < w; ++x) {
        if (!g.covered(x, y)) {
          out(x, y) = background;
          continue;
        }
        const size_t pixel = size_t(y) * size_t(w) + size_t(x);
        glm::vec3 n = g.normal(x, y);
        if (!(glm::dot(n, n) > 0.0f)) n = g.geo_normal(x, y);
        const glm::vec3 c = shade_lambert(scene, g.albedo(x, y), g.position(x, y), n, ao_at(pixel),
                                          [&](size_t l) { return vis_at(l, pixel); });
        const glm::vec3 linear = c * settings.exposure;
        const auto& b = code_boundaries();
        out(x, y) = {srgb8_code(b, linear.x), srgb8_code(b, linear.y), srgb8_code(b, linear.z)};
      }
    }
  });
  return out;
}

}  // namespace

uint8_t tonemap_srgb8(float linear) { return srgb8_code(code_boundaries(), linear); }

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
  const float ao_scale = ao ? 1.0f / float(ao->desc.full_scale) : 0.0f;
  auto ao_at = [&](size_t pixel) { return ao ? std::min(1.0f, float(ao->bytes[pixel]) * ao_scale) : 1.0f; };
  if (!visibility) return composite_impl(g, scene, settings, [](size_t, size_t) { return 1.0f; }, ao_at);
  const uint8_t* bytes = visibility->bytes.data();
  if (visibility->desc.layout() == PassLayout::Bitmask) {
    const size_t bpp = size_t((visibility->desc.channels + 7) / 8);
    return composite_impl(
        g, scene, settings,
        [&](size_t l, size_t pixel) { return float((bytes[pixel * bpp + (l >> 3)] >> (l & 7)) & 1u); }, ao_at);
  }
  const float vis_scale = 1.0f / float(visibility->desc.full_scale);
  return composite_impl(
      g, scene, settings,
      [&](size_t l, size_t pixel) { return std::min(1.0f, float(bytes[l * npx + pixel]) * vis_scale); }, ao_at);
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
      [&](size_t l, size_t pixel) { return visibility.empty() ? 1.0f : visibility[l * npx + pixel]; },
      [&](size_t pixel) { return ao.empty() ? 1.0f : ao[pixel]; });
}

}  // namespace dhr
