// The server's ray-traced passes (paper section 3): shadow visibility per light (3.1, Fig. 1)
// and ray-traced ambient occlusion (3.2, Eq. 1-3), computed for every pixel of a G-buffer.
//
// Which passes run is derived from the scene (plan_passes): no lights -> no visibility pass;
// only point lights (Light::is_point) -> hard shadows, one deterministic ray per light; no
// ao block -> no AO pass. Per pixel no ray is traced where the answer is known: background,
// a surface facing away from the light (for a sphere light in soft mode: from the whole
// sphere), a point beyond the light's range_m. Every ray traced is counted (TraceStats).
//
// Surface points are rebuilt from the G-buffer's object id, prim id and barycentrics with the
// scene's vertices at the G-buffer's time (in double precision). Ray origins are that point
// moved along the geometric normal (oriented like the G-buffer's, i.e. towards the camera) by a
// distance d that bounds the floating-point error of everything between the double-precision
// point and Embree's float intersection test (origin_offset_m below; the error model follows
// pbrt-v4's OffsetRayOrigin with error bounds, applied to Embree's Moeller-Trumbore test), in
// double, then rounded to float once. There is no global epsilon and no floor near the world
// origin: d scales with the triangle's coordinates and with its own float error, so it is small
// for tiny scenes, for long axis-aligned slivers and near the world origin, and large where
// the float geometry is coarse (far from the origin, big tilted triangles).
// Rays are validated before Embree sees them (ray_is_valid in core/trace/rt_scene.h). An invalid
// ray is counted in TraceStats::invalid_rays and never traced; its answer is "unoccluded":
// a shadow ray counts as reaching its light (a missing shadow is the milder error, and a
// wrong dark pixel would look like a real shadow) and an AO ray as unoccluded (AO then
// falls back to "no occlusion", the composite's meaning of an absent AO pass).
//
// Special cases, documented answers:
// - A point inside a sphere light (distance to the centre <= radius_m, including a point light
//   exactly at the surface point): visible, no ray. The composite gives it the light's term
//   at distance max(d, radius) with n.l from the centre direction (0 when d == 0).
// - Geometry touching the light: shadow rays end a relative 1e-4 short of the light's surface
//   (kShadowTfarScale), so geometry within that distance of the light does not occlude it.
// - Emitter geometry never occludes shadow rays (geometry masks, see core/trace/rt_scene.h).
//
// Randomness (core/base/rng.h): soft-shadow sample s of light l at pixel p uses the key
// (seed, p, frame, s, kStreamLightBase + l); AO ray i uses (seed, p, frame, i, kStreamAo);
// dimensions 0 and 1 are the two uniforms. Results do not depend on the thread count.
#pragma once

#include "core/base/rng.h"
#include "core/buffers/gbuffer.h"
#include "core/buffers/pass_buffer.h"
#include "core/plan/trace_plan.h"
#include "core/scene/scene.h"
#include "core/trace/rt_scene.h"

#include <glm/glm.hpp>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace dhr {

// Shadow rays stop this fraction short of the light's surface (or centre for point lights).
constexpr float kShadowTfarScale = 1.0f - 1e-4f;

// Raw counts, for references that need more than 8 bits.
struct VisibilityCounts {
  int width = 0, height = 0, lights = 0;
  std::vector<int> samples;       // per light: rays per pixel (1 for hard lights)
  std::vector<uint16_t> visible;  // planar: [light][pixel], 0..samples[light]
  float fraction(int light, size_t pixel) const {
    return float(visible[size_t(light) * size_t(width) * size_t(height) + pixel]) / float(samples[size_t(light)]);
  }
};
struct AoCounts {
  int width = 0, height = 0, rays = 0;
  std::vector<uint16_t> unoccluded;  // per pixel, 0..rays (rays on background pixels)
};

// The kernels of the passes, one at a time (plan.visibility() / plan.ao must hold); statistics
// are added. trace_passes (core/pass/passes.h) runs every planned pass's kernel.
PassBuffer trace_visibility(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan, const TraceSettings& settings,
                            TraceStats& stats);
PassBuffer trace_ao(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan, const TraceSettings& settings,
                    TraceStats& stats);

// The ground truth's converged estimates of the same passes (PassType::converged, used by
// core/pass/reference.h): fractions in [0, 1], planar [channel][pixel]. `plan` is the scene's plan
// with soft shadows; the reference's own ray counts replace the plan's.
std::vector<float> converged_visibility(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan,
                                        const TraceSettings& settings, const ReferenceRays& reference,
                                        TraceStats& stats);
std::vector<float> converged_ao(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan, const TraceSettings& settings,
                                const ReferenceRays& reference, TraceStats& stats);

// Counts with any sample count: samples_per_light 1..65535 for area lights, ao_rays
// 1..65535 (the converged estimates above).
VisibilityCounts trace_visibility_counts(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan,
                                         const TraceSettings& settings, TraceStats& stats);
AoCounts trace_ao_counts(RtScene& rt, const GBuffer& gbuf, int ao_rays, float ao_radius_m,
                         const TraceSettings& settings, TraceStats& stats);

// Whether TraceSettings::wide_kernels takes effect here (with a compiler that builds the
// kernels): Embree's native 16-wide packets and a CPU with AVX-512F/DQ (the AVX-512 kernels),
// or Embree's 8-wide packets and a CPU with AVX2 (the AVX2 ones).
bool wide_kernels_available(const RtScene& rt);

// Packing counts into the canonical PassBuffer layouts (core/buffers/pass_buffer.h).
PassBuffer pack_visibility(const VisibilityCounts& counts, const PassPlan& plan);
PassBuffer pack_ao(const AoCounts& counts);

// ---- Building blocks, exposed for tests and benchmarks ----

// ---- Ray origins ----
//
// A shadow or AO ray leaves the surface point p (on the hit triangle, in double) from
//   o = float(p + d n)      (n: the unit normal on the ray's side; computed in double)
// and must not hit the triangle it starts on. Embree 3 tests a ray against a triangle in float
// (its Moeller-Trumbore intersector): with the float vertices v0, v1, v2, the edges
// e1 = v0 - v1, e2 = v2 - v0 and Ng = cross(e2, e1) are rounded to float, then C = v0 - O and
// T = dot(Ng, C) (and den = dot(Ng, D)); a hit needs T / den > tnear = 0, i.e. T of the sign
// of den. The exact T is -|Ng| times O's distance above the plane, so the ray cannot hit its
// own triangle while that distance exceeds the error of the computed T over |Ng|. d bounds, as
// a distance along n:
//  (a) rounding o to float: half an ULP per component, at most 2^-24 |o_i|, i.e. along n
//      2^-24 sum_i |n_i| |o_i| <= 2^-24 (sum_i |n_i| M_i + d), M_i = max_k |v_k,i| (p lies
//      in the triangle);
//  (b) the vertices Embree holds against the double ones: none for a static object (Embree
//      gets the very float positions); for a moving object Embree moves the ray into object
//      space with the float inverse of its float transform, off by up to about
//      gamma(8) (|O| + |t|) per component (t: the translation; bounded by moving_offset_m);
//  (c) Embree's evaluation of T (embree_plane_error): Ng_i is off by up to
//      gamma(4) (|e2_j e1_k| + |e2_k e1_j|) (two products and a difference of float edges,
//      each edge rounded once; with or without FMA), C_i by one rounding and the dot product
//      by gamma(3) (pbrt-v4's gamma(n) = n u / (1 - n u), u = 2^-24, as in its triangle
//      pError bounds). |C_i| <= ext_i + |n_i| d with ext_i the triangle's extent along axis
//      i, so the error over |Ng| is fixed_m + slope d. For an axis-aligned sliver the
//      off-axis edge components are exactly 0 and so is fixed_m: a 40 m x 3 cm wall strip
//      gets an offset of a few ULPs of its coordinates, a tilted one what it really needs.
// So d (1 - slope - u) >= 2^-24 sum_i |n_i| M_i + (b) + fixed_m, and
//   d = kOriginSafety * (2^-24 sum_i |n_i| M_i + (b) + fixed_m) / (1 - slope - 2^-24)
// with kOriginSafety = 2 for what the first-order bounds leave out (the double-precision
// rebuild of p, barycentrics a rounding outside the triangle). The denominator is held at
// >= 1/2: a triangle whose float normal is that wrong has no useful bound.
// Everything but the rounding of o is per triangle (TriangleCache in core/trace/trace_kernels.h),
// so d is one number per triangle and every kernel computes o = float(p + n d) alike.
constexpr double kUnitRoundoff = 0x1p-24;
constexpr double kOriginSafety = 2.0;
constexpr double float_gamma(int n) { return n * kUnitRoundoff / (1.0 - n * kUnitRoundoff); }

// (c): Embree's error in T = dot(Ng, v0 - O) over |Ng|, for the float vertices w Embree holds
// (in the space it intersects in): fixed_m + slope * (O's distance from the plane).
struct PlaneError {
  double fixed_m = 0.0;
  double slope = 0.0;
};
inline PlaneError embree_plane_error(const glm::dvec3 w[3]) {
  const glm::dvec3 e1 = w[0] - w[1], e2 = w[2] - w[0];
  const glm::dvec3 ng = glm::cross(e2, e1);
  const double len = glm::length(ng);
  PlaneError e;
  if (!(len > 0.0)) return e;
  for (int i = 0; i < 3; ++i) {
    const int j = (i + 1) % 3, k = (i + 2) % 3;
    const double err = float_gamma(4) * (std::abs(e2[j] * e1[k]) + std::abs(e2[k] * e1[j]));
    const double wi = err * (1.0 + float_gamma(4)) + float_gamma(4) * std::abs(ng[i]);
    const double ext = std::max({w[0][i], w[1][i], w[2][i]}) - std::min({w[0][i], w[1][i], w[2][i]});
    e.fixed_m += wi * ext;
    e.slope += wi * std::abs(ng[i]);  // |n_i| = |Ng_i| / |Ng|
  }
  e.fixed_m /= len;
  e.slope /= len * len;
  return e;
}

// The offset d along unit n (above) for a triangle with world vertices v (double), given the
// terms (b) (vertex_m: 0 for a static object) and (c) (e, as a world distance).
inline double origin_offset_m(const glm::dvec3 v[3], const glm::dvec3& n, double vertex_m, const PlaneError& e) {
  double coords = 0.0;
  for (int i = 0; i < 3; ++i)
    coords += std::abs(n[i]) * std::max({std::abs(v[0][i]), std::abs(v[1][i]), std::abs(v[2][i])});
  const double denominator = std::max(0.5, 1.0 - e.slope - kUnitRoundoff);
  return kOriginSafety * (kUnitRoundoff * coords + vertex_m + e.fixed_m) / denominator;
}

// (b) for a moving object: Embree's float transform of the origin into object space, about
// gamma(8) (|O| + |t|) per component (O <= the vertices' largest |coordinate|, t the
// translation), times 3 components (a rigid or mildly scaled transform).
inline double moving_offset_m(const glm::dvec3 v[3], const glm::dvec3& translation) {
  double m = 0.0;
  for (int k = 0; k < 3; ++k) m = std::max({m, std::abs(v[k].x), std::abs(v[k].y), std::abs(v[k].z)});
  const double t = std::max({std::abs(translation.x), std::abs(translation.y), std::abs(translation.z)});
  return 3.0 * float_gamma(8) * (m + t);
}

// A point with no known triangle (a G-buffer position whose triangle cannot be rebuilt): term
// (a) with the point's own coordinates, times kOriginSafety and 4 for the unknown rest.
inline double point_offset_m(const glm::dvec3& p, const glm::dvec3& n) {
  return 4.0 * kOriginSafety * kUnitRoundoff *
         (std::abs(n.x) * std::abs(p.x) + std::abs(n.y) * std::abs(p.y) + std::abs(n.z) * std::abs(p.z));
}

// o = float(p + n d), in double, rounded once (every kernel: the same operations, no FMA).
inline glm::vec3 offset_ray_origin(const glm::dvec3& p, const glm::dvec3& n, double d) { return glm::vec3(p + n * d); }

// Duff, Burgess, Christensen, Hery, Kensler, Liani, Villemin, "Building an Orthonormal Basis,
// Revisited" (JCGT 6(1), 2017), Listing 3: t, b such that (t, b, n) is right-handed
// orthonormal, for unit n, with no branch but the sign.
inline void orthonormal_basis(const glm::vec3& n, glm::vec3& t, glm::vec3& b) {
  const float sign = std::copysign(1.0f, n.z);
  const float a = -1.0f / (sign + n.z);
  const float c = n.x * n.y * a;
  t = glm::vec3(1.0f + sign * n.x * n.x * a, sign * c, -sign * n.x);
  b = glm::vec3(c, sign + n.y * n.y * a, -n.y);
}

// rng_uniform(RngKey{seed, pixel, frame, sample, stream}, dim) for dims 0 and 1, with the
// per-pixel part of the hash computed once (bit-identical to core/base/rng.h; tested).
struct PixelRng {
  uint64_t h = 0;
  PixelRng(uint64_t seed, uint32_t pixel, uint32_t frame) : h(mix64(mix64(seed) ^ ((uint64_t(pixel) << 32) | frame))) {}
  void uniform2(uint32_t sample, uint32_t stream, float& u0, float& u1) const {
    const uint64_t k = mix64(h ^ ((uint64_t(sample) << 32) | stream));
    u0 = float(mix64(k ^ 0u) >> 40) * (1.0f / 16777216.0f);
    u1 = float(mix64(k ^ 1u) >> 40) * (1.0f / 16777216.0f);
  }
};

// The lattice of TraceSettings::lattice: sample k of a pixel (and light) is the point
// k (a0, a1) mod 1 of Roberts' R2 sequence (a0 = 1/p, a1 = 1/p^2, p the plastic number: a
// low-discrepancy set for any count), shifted mod 1 by a random offset of the pixel and stream
// (Cranley-Patterson rotation: each sample is uniform on its own, so the estimate stays
// unbiased, while a pixel's samples cover the square evenly). In 32-bit fixed point, integers
// only, so every kernel gives the same bits: the offset is sample 0's key of PixelRng::uniform2.
constexpr uint32_t kLatticeA0 = 3242174889u;  // round(2^32 / 1.32471795724474602596)
constexpr uint32_t kLatticeA1 = 2447445414u;  // round(2^32 / 1.32471795724474602596^2)
inline void lattice_shift(uint64_t pixel_hash, uint32_t stream, uint32_t& s0, uint32_t& s1) {
  const uint64_t k = mix64(pixel_hash ^ uint64_t(stream));
  s0 = uint32_t(mix64(k ^ 0u) >> 32);
  s1 = uint32_t(mix64(k ^ 1u) >> 32);
}
// The top 24 bits of (sample a + shift) mod 2^32, as a float in [0, 1) (exact).
inline float lattice_uniform(uint32_t sample, uint32_t a, uint32_t shift) {
  return float((sample * a + shift) >> 8) * (1.0f / 16777216.0f);
}

}  // namespace dhr
