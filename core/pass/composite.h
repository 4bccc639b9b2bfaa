// The composite: ONE shading function used by the client, the remote-rendering baseline, the
// local reference and the ground truth (docs/architecture.md, "The references"), so that they differ only in
// their inputs.
//
// Lambertian, per pixel with G-buffer albedo a, shading normal n and position p:
//   colour = a * (ambient * AO + sum_l V_l * colour_l * intensity_l * max(0, n.l_l) * f_l)
// - AO in [0, 1] (paper Eq. 3: N_unoccluded / N; an absent AO pass means AO = 1),
// - V_l in [0, 1]: the light's visibility bit or visible fraction (absent pass: 1),
// - sphere lights: l = direction to the centre, f = 1 / max(d^2, radius^2, 1e-6 m^2) (the clamp
//   keeps points inside or touching the light finite), f = 0 beyond range_m (when > 0);
// - distant lights: l = Light::direction (normalised), f = 1.
// Background pixels get Scene::background.
//
// Tone mapping (tonemap_srgb8): linear colour times `exposure`, clamped to [0, 1] (NaN -> 0),
// then the sRGB transfer function (IEC 61966-2-1), rounded to 8 bits. Exact: the code is found
// against the 255 code boundaries, no approximating table.
#pragma once

#include "core/buffers/gbuffer.h"
#include "core/buffers/image.h"
#include "core/buffers/pass_buffer.h"
#include "core/scene/scene.h"

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>
#include <span>

namespace dhr {

struct CompositeSettings {
  float exposure = 1.0f;  // linear scale before clamping; > 0
};

// The 8-bit sRGB code of a linear value (after exposure); see the header comment.
uint8_t tonemap_srgb8(float linear);
Rgb8 tonemap_srgb8(const glm::vec3& linear);
// The same for many values (out.size() == linear.size()), 16 at a time where the CPU has
// AVX-512, as the composite's kernel maps them.
void tonemap_srgb8(std::span<const float> linear, std::span<uint8_t> out);

// The per-pixel scalar terms of the shading, each at the value of an absent pass by default.
struct PixelTerms {
  float ao = 1.0f;
};

// Linear radiance of one pixel: the shading kernel. visible(l) gives V_l. The composite runs
// the same operations eight pixels at a time (shade_row in core/pass/composite.cpp) and must agree
// with this kernel bit for bit (tests/core/trace/test_trace.cpp, Composite.RowKernelMatchesShadeLambert).
template <class VisibleFn>
glm::vec3 shade_lambert(const Scene& scene, const glm::vec3& albedo, const glm::vec3& position, const glm::vec3& normal,
                        const PixelTerms& terms, VisibleFn&& visible);

// One received pass for the composite: its meaning picks its term (an absent pass of a meaning
// is its neutral value: fully lit, AO = 1). A null buffer counts as absent. A visibility pass
// is a bitmask or 8-bit planes with one channel per scene light; an AO pass 8-bit planes of one
// channel.
struct CompositePass {
  PassMeaning meaning = PassMeaning::Ao;
  const PassBuffer* buffer = nullptr;
};
// The composite of a pass list (at most one pass per meaning; colour and depth passes are
// displayed or read as they are, never composited: dhr::Error). Throws dhr::Error when a pass
// does not match the G-buffer's size, the scene's light count or its own byte size.
//
// A composite term is one meaning: its slot in CompositeInputs (core/pass/composite.cpp), the values
// it reads there, its member of PixelTerms, and its use in shade_lambert and shade_row.
ImageRGB8 composite(const GBuffer& gbuf, const Scene& scene, std::span<const CompositePass> passes,
                    const CompositeSettings& settings = {});

// The same for the two lighting passes the server traces today (null = absent).
ImageRGB8 composite(const GBuffer& gbuf, const Scene& scene, const PassBuffer* visibility, const PassBuffer* ao,
                    const CompositeSettings& settings = {});

// One pass as float estimates (the ground truth's converged passes, PassType::converged):
// planar [channel][pixel] in [0, 1] (visibility: a channel per light; ao: one).
struct CompositeFractions {
  PassMeaning meaning = PassMeaning::Ao;
  std::span<const float> values;  // empty: absent
};
// The composite of float estimates (at most one per meaning); the same terms as composite().
ImageRGB8 composite_fractions(const GBuffer& gbuf, const Scene& scene, std::span<const CompositeFractions> passes,
                              const CompositeSettings& settings = {});

// For tests and benchmarks: on, composite() shades every pixel on the 8-lane row path and
// tonemap_srgb8 maps every value one at a time, even where the CPU has AVX-512 (whose 16-lane
// kernels give the same bits). Process-wide.
void composite_row_path_only(bool on);

// ---- implementation of the kernel ----

template <class VisibleFn>
glm::vec3 shade_lambert(const Scene& scene, const glm::vec3& albedo, const glm::vec3& position, const glm::vec3& normal,
                        const PixelTerms& terms, VisibleFn&& visible) {
  constexpr float kMinDistance2 = 1e-6f;
  glm::vec3 light = scene.ambient * terms.ao;
  for (size_t l = 0; l < scene.lights.size(); ++l) {
    const Light& L = scene.lights[l];
    float n_dot_l = 0.0f, falloff = 1.0f;
    if (L.type == LightType::Sphere) {
      const glm::vec3 to_c = L.position - position;
      const float d2 = glm::dot(to_c, to_c);
      if (L.range_m > 0.0f && d2 > L.range_m * L.range_m) continue;
      const float d = std::sqrt(d2);
      if (!(d > 0.0f)) continue;  // at the centre: no direction, no term
      n_dot_l = glm::dot(normal, to_c) / d;
      falloff = 1.0f / std::max({d2, L.radius_m * L.radius_m, kMinDistance2});
    } else {
      const float len = glm::length(L.direction);
      if (!(len > 0.0f)) continue;
      n_dot_l = glm::dot(normal, L.direction) / len;
    }
    if (!(n_dot_l > 0.0f)) continue;
    const float v = visible(l);
    if (!(v > 0.0f)) continue;
    light += (v * L.intensity * n_dot_l * falloff) * L.colour;
  }
  return albedo * light;
}

}  // namespace dhr
