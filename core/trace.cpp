// Shadow visibility (paper section 3.1) and ray-traced AO (section 3.2, Eq. 1-3) with Embree
// packets. See core/trace.h for the rules (which rays are traced, offsets, validation).
//
// Speed (bench_trace compares every pass with a bare Embree loop over the same rays):
// - rays go straight into SoA packets (Batch) traced with rtcOccluded16 where Embree has native
//   16-wide kernels (AVX-512), else rtcOccluded8; Embree marks an occluded ray by setting tfar
//   to -inf. Neighbouring pixels reuse the last triangle's rebuild (TriangleCache).
// - random numbers: 8 keys at a time (uniforms_chunk / uniforms_pixels, an AVX-512 clone with
//   64-bit vector multiplies where the CPU has it; integer arithmetic only, same bits).
// - directions: SSE2 kernels (sincos_2pi_x4, cone_x4, ...) doing the scalar code's IEEE
//   operations in the same order, 4 lanes at a time, so results are bit-identical to it.
// - the AO pass, where the CPU has AVX-512: a row's tracing pixels are gathered first, then
//   ao_rays_x16 makes 16 rays at a time (hashes, uniforms, cosine directions: the same
//   operations again) straight into the packet and adds each pixel's unoccluded lanes by
//   popcount. bench_trace: 0.95-1.01 of the ceiling (0.85 on living-room, where Embree's
//   incoherent streams beat its packets).
// - the visibility pass works a row at a time in stages (surfaces; each light over the row,
//   compacted to the pairs that trace; rays in pixel order) so the square-root and division
//   chains of neighbouring pixels overlap instead of running one after the other.
// The rays, their order and every result are the same as the straightforward per-ray code's.
#if defined(__x86_64__) && defined(__GNUC__)
// GCC 12's AVX-512 intrinsics start from _mm512_undefined_*() and then warn, once inlined into
// a caller, that the undefined value is "used uninitialized" (a false positive, reported at
// the header's lines). The header is included first, with those two warnings off for its
// lines only; this file's own code keeps them.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#if !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include <immintrin.h>
#pragma GCC diagnostic pop
#endif
#include "core/trace.h"

#include "core/error.h"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
// The AO pass's AVX-512 ray generator (ao_rays_x16) is compiled for AVX-512F/DQ by a target
// attribute and chosen at run time; the rest of the file keeps the baseline ISA.
#if defined(__x86_64__) && defined(__GNUC__)
#define DHR_TRACE_AVX512 1  // <immintrin.h>: included first, above
#if defined(__clang__)
#define DHR_TRACE_TARGET_AVX512 __attribute__((target("avx512f,avx512dq")))
#else
// GCC's default -ffp-contract=fast would fuse a * b + c into the FMA instructions AVX-512
// brings; off keeps every product and sum rounded separately, as in the SSE2 and scalar code.
#define DHR_TRACE_TARGET_AVX512 __attribute__((target("avx512f,avx512dq"), optimize("fp-contract=off")))
#endif
#else
#define DHR_TRACE_AVX512 0
#endif

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>

namespace dhr {

namespace {


double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// A surface point rebuilt from the G-buffer (core/trace.h: "Surface points").
struct Surface {
  glm::vec3 p{0.0f};       // on the triangle
  glm::vec3 n{0.0f};       // unit geometric normal, oriented like the G-buffer's (camera side)
  glm::vec3 origin{0.0f};  // p offset along n (Waechter-Binder)
  glm::vec3 t{0.0f}, b{0.0f};  // orthonormal basis around n (AO only)
};

// The last triangle rebuilt (object id, prim id -> world vertices and unit normal, before
// orientation): neighbouring pixels mostly see the same triangle, and the double-precision
// transform, cross product and normalisation are then done once. Bit-identical to recomputing.
struct TriangleCache {
  uint32_t id = kBackgroundId;
  uint32_t prim = 0;
  bool resolved = false;
  glm::dvec3 v[3];
  glm::dvec3 n{0.0};
};

// False for background pixels. Unresolvable ids fall back to the G-buffer's position and
// geometric normal (counted); a non-finite result then fails ray validation downstream.
bool surface_at(const RtScene& rt, const GBuffer& g, int x, int y, Surface& s, uint64_t& unresolved,
                TriangleCache& cache) {
  const uint32_t id = g.object_id(x, y);
  if (id == kBackgroundId) return false;
  const uint32_t prim = g.prim_id(x, y);
  if (id != cache.id || prim != cache.prim) {
    cache.id = id;
    cache.prim = prim;
    const int oi = rt.object_index(id);
    cache.resolved = oi >= 0 && rt.triangle_world(oi, prim, cache.v);
    if (cache.resolved) {
      const glm::dvec3* v = cache.v;
      glm::dvec3 n = glm::cross(v[1] - v[0], v[2] - v[0]);
      n /= glm::length(n);  // non-degenerate: degenerate triangles were skipped at build
      cache.n = n;
    }
  }
  const glm::vec3 gn = g.geo_normal(x, y);
  if (cache.resolved) {
    const glm::dvec3* v = cache.v;
    const glm::dvec2 bc(g.bary(x, y));
    const glm::dvec3 p = (1.0 - bc.x - bc.y) * v[0] + bc.x * v[1] + bc.y * v[2];
    glm::dvec3 n = cache.n;
    // Orient towards the camera side, as the G-buffer's geometric normal is; without a usable
    // G-buffer normal, towards the camera itself.
    double side = glm::dot(n, glm::dvec3(gn));
    if (!(std::abs(side) > 0.0)) side = glm::dot(n, glm::dvec3(g.camera.position) - p);
    if (side < 0.0) n = -n;
    s.p = glm::vec3(p);
    s.n = glm::vec3(n);
  } else {
    ++unresolved;
    s.p = g.position(x, y);
    const float len = glm::length(gn);
    s.n = gn / len;  // NaN for a zero normal: the rays then fail validation (counted)
  }
  s.origin = offset_ray_origin(s.p, s.n);
  return true;
}

struct LightInfo {
  bool sphere = true;
  bool soft = false;
  int samples = 1;
  glm::vec3 centre{0.0f};     // sphere
  glm::dvec3 centre_d{0.0};
  float radius = 0.0f;
  float range = 0.0f;
  glm::vec3 dir{0.0f, 1.0f, 0.0f};  // distant: unit, towards the light
  float one_minus_cos = 0.0f;       // distant: 1 - cos(angular radius)
  float sin_alpha = 0.0f;           // distant: sin(angular radius)
  glm::vec3 t{0.0f}, b{0.0f};       // distant: orthonormal basis around dir (cone sampling)
};

std::vector<LightInfo> light_infos(const Scene& scene, const PassPlan& plan) {
  std::vector<LightInfo> out;
  for (size_t l = 0; l < scene.lights.size(); ++l) {
    const Light& L = scene.lights[l];
    LightInfo li;
    li.sphere = L.type == LightType::Sphere;
    li.soft = plan.light_soft[l] != 0;
    li.samples = li.soft ? plan.samples_per_light : 1;
    li.centre = L.position;
    li.centre_d = glm::dvec3(L.position);
    li.radius = std::max(0.0f, L.radius_m);
    li.range = L.range_m;
    const float dl = glm::length(L.direction);
    li.dir = dl > 0.0f ? L.direction / dl : glm::vec3(0.0f, 1.0f, 0.0f);
    const double alpha = glm::radians(double(std::max(0.0f, L.angular_radius_deg)));
    li.one_minus_cos = float(2.0 * std::sin(alpha / 2) * std::sin(alpha / 2));  // exact near 0
    li.sin_alpha = float(std::sin(alpha));
    orthonormal_basis(li.dir, li.t, li.b);
    out.push_back(li);
  }
  return out;
}

// (cos 2 pi u, sin 2 pi u) for u in [0, 1) without libm: the quadrant from 4u, then
// polynomials on [0, pi/2] (Taylor to degree 8/9; the truncation error is largest at pi/2:
// (pi/2)^10 / 10! = 2.5e-5 for the cosine, (pi/2)^11 / 11! = 3.6e-6 for the sine -- a
// direction off by at most 2.5e-5 rad, far below what a ray needs; c^2 + s^2 = 1 within 1e-5;
// tests/test_trace.cpp pins directions to a double-precision reference within 3e-5). Deterministic: no
// library or ISA dependence. Branch-free (the quarter turn is a swap and two sign flips, not
// a table lookup) so that the loops below vectorize.
// The scalar form is what the SSE2 code below reproduces lane by lane; it runs where SSE2 is absent.
[[maybe_unused]] inline void sincos_2pi(float u, float& c, float& s) {
  const float x = 4.0f * u;
  const int q = std::min(3, int(x));
  const float a = (x - float(q)) * (std::numbers::pi_v<float> / 2.0f);  // [0, pi/2)
  const float a2 = a * a;
  const float sa = a * (1.0f + a2 * (-1.0f / 6 + a2 * (1.0f / 120 + a2 * (-1.0f / 5040 + a2 * (1.0f / 362880)))));
  const float ca = 1.0f + a2 * (-0.5f + a2 * (1.0f / 24 + a2 * (-1.0f / 720 + a2 * (1.0f / 40320))));
  // Rotate by q quarter turns: (c, s) = (ca, sa), (-sa, ca), (-ca, -sa), (sa, -ca).
  const bool odd = (q & 1) != 0;
  const float c0 = odd ? sa : ca;
  const float s0 = odd ? ca : sa;
  c = ((q + 1) & 2) != 0 ? -c0 : c0;
  s = (q & 2) != 0 ? -s0 : s0;
}

// Rays are generated in chunks of up to kChunk samples of one pixel (and light): the hashes,
// directions and validity of a chunk are computed in straight loops over arrays.
constexpr int kChunk = 8;

// u0[j], u1[j] = PixelRng::uniform2(first + j, stream) for j < kChunk (core/rng.h dimensions 0
// and 1), bit-identical to it. Integer hashing and exact conversions only (no float arithmetic
// that a wider ISA could contract or reorder), so the AVX-512 clone -- 64-bit vector multiplies,
// 8 keys at once -- gives the same bits as the baseline one.
__attribute__((target_clones("default", "arch=x86-64-v4"))) void uniforms_chunk(uint64_t h, uint32_t first,
                                                                                uint32_t stream, float* u0,
                                                                                float* u1) {
  for (int j = 0; j < kChunk; ++j) {
    const uint64_t k = mix64(h ^ ((uint64_t(first + uint32_t(j)) << 32) | stream));
    u0[j] = float(mix64(k ^ 0u) >> 40) * (1.0f / 16777216.0f);
    u1[j] = float(mix64(k ^ 1u) >> 40) * (1.0f / 16777216.0f);
  }
}

#if defined(__SSE2__)
// Four lanes of the scalar helpers above, with the same IEEE operations in the same order
// (bit-identical results): GCC does not vectorize std::sqrt while errno is on, so the hot
// ray-generation loops use these SSE2 versions.
struct Vec3x4 {
  __m128 x, y, z;
};

inline __m128 select_ps(__m128 mask, __m128 a, __m128 b) {  // mask ? a : b
  return _mm_or_ps(_mm_and_ps(mask, a), _mm_andnot_ps(mask, b));
}

inline void sincos_2pi_x4(__m128 u, __m128& c, __m128& s) {
  const __m128 one = _mm_set1_ps(1.0f);
  const __m128i three = _mm_set1_epi32(3), one_i = _mm_set1_epi32(1), two_i = _mm_set1_epi32(2);
  const __m128 sign = _mm_castsi128_ps(_mm_set1_epi32(int32_t(0x80000000u)));
  const __m128 x = _mm_mul_ps(_mm_set1_ps(4.0f), u);
  __m128i q = _mm_cvttps_epi32(x);
  const __m128i gt = _mm_cmpgt_epi32(q, three);
  q = _mm_or_si128(_mm_and_si128(gt, three), _mm_andnot_si128(gt, q));
  const __m128 a = _mm_mul_ps(_mm_sub_ps(x, _mm_cvtepi32_ps(q)), _mm_set1_ps(std::numbers::pi_v<float> / 2.0f));
  const __m128 a2 = _mm_mul_ps(a, a);
  __m128 sa = _mm_add_ps(_mm_set1_ps(-1.0f / 5040), _mm_mul_ps(a2, _mm_set1_ps(1.0f / 362880)));
  sa = _mm_add_ps(_mm_set1_ps(1.0f / 120), _mm_mul_ps(a2, sa));
  sa = _mm_add_ps(_mm_set1_ps(-1.0f / 6), _mm_mul_ps(a2, sa));
  sa = _mm_add_ps(one, _mm_mul_ps(a2, sa));
  sa = _mm_mul_ps(a, sa);
  __m128 ca = _mm_add_ps(_mm_set1_ps(-1.0f / 720), _mm_mul_ps(a2, _mm_set1_ps(1.0f / 40320)));
  ca = _mm_add_ps(_mm_set1_ps(1.0f / 24), _mm_mul_ps(a2, ca));
  ca = _mm_add_ps(_mm_set1_ps(-0.5f), _mm_mul_ps(a2, ca));
  ca = _mm_add_ps(one, _mm_mul_ps(a2, ca));
  const __m128 odd = _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(q, one_i), one_i));
  const __m128 c0 = select_ps(odd, sa, ca);
  const __m128 s0 = select_ps(odd, ca, sa);
  const __m128 neg_c = _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(_mm_add_epi32(q, one_i), two_i), two_i));
  const __m128 neg_s = _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(q, two_i), two_i));
  c = _mm_xor_ps(c0, _mm_and_ps(neg_c, sign));
  s = _mm_xor_ps(s0, _mm_and_ps(neg_s, sign));
}

// orthonormal_basis (Duff et al., Listing 3), four normals at once.
inline void orthonormal_basis_x4(const Vec3x4& n, Vec3x4& t, Vec3x4& b) {
  const __m128 signbit = _mm_castsi128_ps(_mm_set1_epi32(int32_t(0x80000000u)));
  const __m128 sign = _mm_or_ps(_mm_and_ps(n.z, signbit), _mm_set1_ps(1.0f));  // copysign(1, n.z)
  const __m128 neg_sign = _mm_xor_ps(sign, signbit);
  const __m128 a = _mm_div_ps(_mm_set1_ps(-1.0f), _mm_add_ps(sign, n.z));
  const __m128 c = _mm_mul_ps(_mm_mul_ps(n.x, n.y), a);
  t.x = _mm_add_ps(_mm_set1_ps(1.0f), _mm_mul_ps(_mm_mul_ps(_mm_mul_ps(sign, n.x), n.x), a));
  t.y = _mm_mul_ps(sign, c);
  t.z = _mm_mul_ps(neg_sign, n.x);
  b.x = c;
  b.y = _mm_add_ps(sign, _mm_mul_ps(_mm_mul_ps(n.y, n.y), a));
  b.z = _mm_xor_ps(n.y, signbit);
}

// sample_cone's direction, four at once: normalize(t * (c sin) + b * (s sin) + w * cos).
inline Vec3x4 cone_x4(const Vec3x4& t, const Vec3x4& b, const Vec3x4& w, __m128 omc_max, __m128 u0, __m128 u1) {
  const __m128 omc = _mm_mul_ps(u0, omc_max);
  const __m128 cos_t = _mm_sub_ps(_mm_set1_ps(1.0f), omc);
  const __m128 sin_t =
      _mm_sqrt_ps(_mm_max_ps(_mm_mul_ps(omc, _mm_sub_ps(_mm_set1_ps(2.0f), omc)), _mm_setzero_ps()));
  __m128 c, s;
  sincos_2pi_x4(u1, c, s);
  const __m128 cs = _mm_mul_ps(c, sin_t), ss = _mm_mul_ps(s, sin_t);
  const __m128 vx = _mm_add_ps(_mm_add_ps(_mm_mul_ps(t.x, cs), _mm_mul_ps(b.x, ss)), _mm_mul_ps(w.x, cos_t));
  const __m128 vy = _mm_add_ps(_mm_add_ps(_mm_mul_ps(t.y, cs), _mm_mul_ps(b.y, ss)), _mm_mul_ps(w.y, cos_t));
  const __m128 vz = _mm_add_ps(_mm_add_ps(_mm_mul_ps(t.z, cs), _mm_mul_ps(b.z, ss)), _mm_mul_ps(w.z, cos_t));
  const __m128 dot = _mm_add_ps(_mm_add_ps(_mm_mul_ps(vx, vx), _mm_mul_ps(vy, vy)), _mm_mul_ps(vz, vz));
  const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), _mm_sqrt_ps(dot));
  return {_mm_mul_ps(vx, inv), _mm_mul_ps(vy, inv), _mm_mul_ps(vz, inv)};
}

// The sphere shadow ray's tfar (see the scalar code in visibility_rows): nearest root of the
// sphere along d, or the closest approach when rounding leaves none; times kShadowTfarScale.
inline __m128 sphere_tfar_x4(const Vec3x4& d, const Vec3x4& oc, __m128 r2) {
  const __m128 b = _mm_add_ps(_mm_add_ps(_mm_mul_ps(d.x, oc.x), _mm_mul_ps(d.y, oc.y)), _mm_mul_ps(d.z, oc.z));
  const __m128 qx = _mm_sub_ps(oc.x, _mm_mul_ps(b, d.x));
  const __m128 qy = _mm_sub_ps(oc.y, _mm_mul_ps(b, d.y));
  const __m128 qz = _mm_sub_ps(oc.z, _mm_mul_ps(b, d.z));
  const __m128 disc =
      _mm_sub_ps(r2, _mm_add_ps(_mm_add_ps(_mm_mul_ps(qx, qx), _mm_mul_ps(qy, qy)), _mm_mul_ps(qz, qz)));
  const __m128 t_hit = select_ps(_mm_cmpgt_ps(disc, _mm_setzero_ps()), _mm_sub_ps(b, _mm_sqrt_ps(disc)), b);
  return _mm_max_ps(_mm_mul_ps(t_hit, _mm_set1_ps(kShadowTfarScale)), _mm_setzero_ps());
}
#endif

// Cosine-weighted hemisphere directions around the basis (t, b, n) for kChunk uniforms
// (Malley's method: the cosine of Eq. 1 is in the density, so O = N_unoccluded / N, Eq. 2-3):
// dir = t * (r c) + b * (r s) + n * z with r = sqrt(u0), z = sqrt(1 - u0), (c, s) =
// sincos_2pi(u1). The SSE2 version does the same IEEE operations in the same order four lanes
// at a time (bit-identical to the scalar one); it exists because GCC does not vectorize
// std::sqrt while errno is on.
inline void cosine_dirs_chunk(const glm::vec3& t, const glm::vec3& b, const glm::vec3& n, const float* u0,
                              const float* u1, float* dx, float* dy, float* dz) {
#if defined(__SSE2__)
  static_assert(kChunk % 4 == 0);
  const __m128 one = _mm_set1_ps(1.0f);
  for (int j = 0; j < kChunk; j += 4) {
    const __m128 v0 = _mm_load_ps(u0 + j), v1 = _mm_load_ps(u1 + j);
    const __m128 r = _mm_sqrt_ps(v0);
    const __m128 z = _mm_sqrt_ps(_mm_sub_ps(one, v0));
    __m128 c, s;
    sincos_2pi_x4(v1, c, s);
    const __m128 rc = _mm_mul_ps(r, c), rs = _mm_mul_ps(r, s);
    auto comp = [&](float tk, float bk, float nk) {
      return _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_set1_ps(tk), rc), _mm_mul_ps(_mm_set1_ps(bk), rs)),
                        _mm_mul_ps(_mm_set1_ps(nk), z));
    };
    _mm_store_ps(dx + j, comp(t.x, b.x, n.x));
    _mm_store_ps(dy + j, comp(t.y, b.y, n.y));
    _mm_store_ps(dz + j, comp(t.z, b.z, n.z));
  }
#else
  for (int j = 0; j < kChunk; ++j) {
    float c, sn;
    const float r = std::sqrt(u0[j]);
    const float z = std::sqrt(1.0f - u0[j]);  // u0 < 1
    sincos_2pi(u1[j], c, sn);
    const float rc = r * c, rs = r * sn;
    dx[j] = t.x * rc + b.x * rs + n.x * z;
    dy[j] = t.y * rc + b.y * rs + n.y * z;
    dz[j] = t.z * rc + b.z * rs + n.z * z;
  }
#endif
}

// Ray validity (ray_is_valid in core/rt_scene.h) for a direction and tfar, the origin being
// checked once per pixel: every component finite (|x| <= FLT_MAX is false for inf and NaN),
// not the zero vector, 0 <= tfar (false for NaN). Branch-free, to vectorize.
inline bool direction_valid(float dx, float dy, float dz, float tfar) {
  constexpr float kMax = std::numeric_limits<float>::max();
  // Branch-free on purpose: unsigned & keeps the three tests from short-circuiting.
  const bool finite = (unsigned(std::abs(dx) <= kMax) & unsigned(std::abs(dy) <= kMax) & unsigned(std::abs(dz) <= kMax)) != 0;
  const bool nonzero = (unsigned(dx != 0.0f) | unsigned(dy != 0.0f) | unsigned(dz != 0.0f)) != 0;
  return finite & nonzero & (tfar >= 0.0f);
}
inline bool origin_valid(const glm::vec3& o) {
  // !(|x| < max) also rejects NaN.
  return (unsigned(std::abs(o.x) < kMaxCoordinate) & unsigned(std::abs(o.y) < kMaxCoordinate) &
          unsigned(std::abs(o.z) < kMaxCoordinate)) != 0;
}

// Directions in the cone around unit w (basis t, b, w) with 1 - cos(half angle) = omc_max,
// uniform in solid angle (paper 3.1: "a circular cone distribution that covers the entire
// light"), for kChunk uniforms. Same arithmetic, in the same order, as
// glm::normalize(t * (c * sin_t) + b * (s * sin_t) + w * cos_t).
inline void sample_cone_chunk(const glm::vec3& t, const glm::vec3& b, const glm::vec3& w, float omc_max,
                              const float* u0, const float* u1, float* dx, float* dy, float* dz) {
#if defined(__SSE2__)
  const Vec3x4 tv{_mm_set1_ps(t.x), _mm_set1_ps(t.y), _mm_set1_ps(t.z)};
  const Vec3x4 bv{_mm_set1_ps(b.x), _mm_set1_ps(b.y), _mm_set1_ps(b.z)};
  const Vec3x4 wv{_mm_set1_ps(w.x), _mm_set1_ps(w.y), _mm_set1_ps(w.z)};
  for (int j = 0; j < kChunk; j += 4) {
    const Vec3x4 d = cone_x4(tv, bv, wv, _mm_set1_ps(omc_max), _mm_load_ps(u0 + j), _mm_load_ps(u1 + j));
    _mm_store_ps(dx + j, d.x);
    _mm_store_ps(dy + j, d.y);
    _mm_store_ps(dz + j, d.z);
  }
#else
  for (int j = 0; j < kChunk; ++j) {
    const float omc = u0[j] * omc_max;  // 1 - cos(theta), precise for small cones
    const float cos_t = 1.0f - omc;
    const float sin_t = std::sqrt(std::max(0.0f, omc * (2.0f - omc)));
    float c, s;
    sincos_2pi(u1[j], c, s);
    const float cs = c * sin_t, ss = s * sin_t;
    const float vx = t.x * cs + b.x * ss + w.x * cos_t;
    const float vy = t.y * cs + b.y * ss + w.y * cos_t;
    const float vz = t.z * cs + b.z * ss + w.z * cos_t;
    const float inv = 1.0f / std::sqrt(vx * vx + vy * vy + vz * vz);
    dx[j] = vx * inv;
    dy[j] = vy * inv;
    dz[j] = vz * inv;
  }
#endif
}

// Embree's packet type and call for a packet width.
template <int W>
struct Packet;
template <>
struct Packet<8> {
  using Ray = RTCRay8;
  static void occluded(const int* valid, RTCScene scene, RTCIntersectContext* ctx, Ray* rays) {
    rtcOccluded8(valid, scene, ctx, rays);
  }
};
template <>
struct Packet<16> {
  using Ray = RTCRay16;
  static void occluded(const int* valid, RTCScene scene, RTCIntersectContext* ctx, Ray* rays) {
    rtcOccluded16(valid, scene, ctx, rays);
  }
};

// Set bits of a 16-bit mask. Not std::popcount: the baseline x86-64 target has no POPCNT
// instruction, and GCC then calls libgcc's __popcountdi2 (1.4 % of a hard-shadow pass).
constexpr int popcount16(uint32_t v) {
  v = v - ((v >> 1) & 0x5555u);
  v = (v & 0x3333u) + ((v >> 2) & 0x3333u);
  v = (v + (v >> 4)) & 0x0f0fu;
  return int((v + (v >> 8)) & 0x1fu);
}
static_assert(popcount16(0xffffu) == 16 && popcount16(0x8001u) == 2 && popcount16(0) == 0 && popcount16(0x7ffeu) == 14);

// A packet of up to W occlusion rays and the counters they increment when unoccluded.
// Rays are written straight into Embree's SoA layout and traced with rtcOccluded8/16 (W = 16
// where Embree has native 16-wide kernels, i.e. AVX-512): packets of consecutive rays (the N AO
// rays of neighbouring pixels, or neighbouring pixels' shadow rays) beat rtcOccluded1 and, on
// most scenes, rtcOccluded1M streams (see bench_trace). Lanes never mix in Embree's traversal,
// so a ray's answer does not depend on its packet.
// Consecutive rays of one counter (a pixel's AO rays, a light's samples) form a run; a flush
// adds each run's unoccluded lanes with one popcount instead of one read-modify-write of the
// same counter per lane (no measurable speed difference on its own; it removes a dependency
// chain through memory).
template <int W>
struct Batch {
  alignas(64) typename Packet<W>::Ray packet;
  std::array<uint16_t*, W> run_counter{};  // run k: lanes [run_start[k], run_start[k + 1])
  std::array<uint8_t, W + 1> run_start{};
  unsigned runs = 0;
  unsigned n = 0;
  RTCScene scene = nullptr;
  unsigned mask = 0;
  RTCIntersectContext ctx;
  uint64_t traced = 0;
  std::vector<RTCRay>* record = nullptr;  // collect_*_rays: keep the rays, trace nothing

  Batch(RTCScene scene_, unsigned mask_) : scene(scene_), mask(mask_) {
    rtcInitIntersectContext(&ctx);
    // Occlusion queries write only tfar: the other fields are set once.
    for (int k = 0; k < W; ++k) {
      packet.tnear[k] = 0.0f;
      packet.time[k] = 0.0f;
      packet.mask[k] = mask;
      packet.id[k] = unsigned(k);
      packet.flags[k] = 0;
    }
  }
  void flush() {
    if (n == 0) return;
    alignas(64) int valid[W];
    for (unsigned k = 0; k < unsigned(W); ++k) valid[k] = k < n ? -1 : 0;
    Packet<W>::occluded(valid, scene, &ctx, &packet);
    // Embree sets tfar = -inf on an occluded ray; anything else (tfar untouched) reached.
    uint32_t reached = 0;
    for (unsigned k = 0; k < unsigned(W); ++k) reached |= uint32_t(!(packet.tfar[k] < 0.0f)) << k;
    run_start[runs] = uint8_t(n);
    for (unsigned k = 0; k < runs; ++k) {
      const uint32_t lanes = ((1u << run_start[k + 1]) - 1u) & ~((1u << run_start[k]) - 1u);
      *run_counter[k] = uint16_t(*run_counter[k] + popcount16(reached & lanes));
    }
    traced += n;
    n = 0;
    runs = 0;
  }
  void begin_lane(uint16_t* count) {
    if (runs == 0 || run_counter[runs - 1] != count) {
      run_counter[runs] = count;
      run_start[runs] = uint8_t(n);
      ++runs;
    }
  }
  void push(const glm::vec3& o, float dx, float dy, float dz, float tfar, uint16_t* count) {
    if (record) {
      RTCRay& r = record->emplace_back();
      r.org_x = o.x, r.org_y = o.y, r.org_z = o.z, r.tnear = 0.0f;
      r.dir_x = dx, r.dir_y = dy, r.dir_z = dz, r.time = 0.0f;
      r.tfar = tfar, r.mask = mask, r.id = 0, r.flags = 0;
      return;
    }
    begin_lane(count);
    packet.org_x[n] = o.x;
    packet.org_y[n] = o.y;
    packet.org_z[n] = o.z;
    packet.dir_x[n] = dx;
    packet.dir_y[n] = dy;
    packet.dir_z[n] = dz;
    packet.tfar[n] = tfar;
    if (++n == unsigned(W)) flush();
  }
  // m <= kChunk rays of one counter from one origin with one tfar (a pixel's AO chunk).
  void push_chunk(const glm::vec3& o, const float* dx, const float* dy, const float* dz, float tfar, int m,
                  uint16_t* count) {
    if (record || n + unsigned(m) > unsigned(W)) {
      for (int j = 0; j < m; ++j) push(o, dx[j], dy[j], dz[j], tfar, count);
      return;
    }
    begin_lane(count);
    for (int j = 0; j < m; ++j) {
      packet.org_x[n + unsigned(j)] = o.x;
      packet.org_y[n + unsigned(j)] = o.y;
      packet.org_z[n + unsigned(j)] = o.z;
      packet.dir_x[n + unsigned(j)] = dx[j];
      packet.dir_y[n + unsigned(j)] = dy[j];
      packet.dir_z[n + unsigned(j)] = dz[j];
      packet.tfar[n + unsigned(j)] = tfar;
    }
    n += unsigned(m);
    if (n == unsigned(W)) flush();
  }
};

// Native 16-wide packets (Embree's AVX-512 kernels) when the device has them.
bool wide_packets(const RtScene& rt) {
  return rtcGetDeviceProperty(rt.device(), RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) != 0;
}

template <class F>
void run_in_arena(RtScene& rt, const TraceSettings& settings, F&& f) {
  if (settings.threads > 0 && settings.threads != rt.threads()) {
    tbb::task_arena arena(settings.threads);
    arena.execute(f);
  } else {
    rt.arena().execute(f);
  }
}

void check_gbuffer(const GBuffer& g) {
  const int w = g.width(), h = g.height();
  if (!g.object_id.same_size(w, h) || !g.prim_id.same_size(w, h) || !g.bary.same_size(w, h) ||
      !g.position.same_size(w, h) || !g.geo_normal.same_size(w, h))
    fail("trace: G-buffer layers differ in size from its depth layer ({}x{})", w, h);
}

}  // namespace

const char* shadow_mode_name(ShadowMode mode) {
  switch (mode) {
    case ShadowMode::None: return "none";
    case ShadowMode::Hard: return "hard";
    case ShadowMode::SoftBit: return "soft_bit";
    case ShadowMode::SoftFraction: return "soft_fraction";
  }
  return "unknown";
}

int PassPlan::visibility_full_scale() const {
  return shadow == ShadowMode::SoftFraction ? std::min(samples_per_light, 255) : 1;
}

PassDesc PassPlan::visibility_desc(int width, int height) const {
  PassDesc d;
  d.kind = visibility_kind();
  d.width = width;
  d.height = height;
  d.channels = lights;
  d.full_scale = shadow == ShadowMode::SoftFraction ? visibility_full_scale() : 255;
  return d;
}

PassDesc PassPlan::ao_desc(int width, int height) const {
  PassDesc d;
  d.kind = PassKind::Ao;
  d.width = width;
  d.height = height;
  d.channels = 1;
  d.full_scale = ao_rays;
  return d;
}

std::string PassPlan::describe() const {
  std::string s;
  for (const auto& r : reasons) {
    if (!s.empty()) s += "; ";
    s += r;
  }
  return s;
}

void TraceStats::add(const TraceStats& o) {
  pixels += o.pixels;
  covered_pixels += o.covered_pixels;
  shadow_rays += o.shadow_rays;
  ao_rays += o.ao_rays;
  invalid_rays += o.invalid_rays;
  unresolved_pixels += o.unresolved_pixels;
  shadow_skipped_facing += o.shadow_skipped_facing;
  shadow_skipped_range += o.shadow_skipped_range;
  shadow_inside_light += o.shadow_inside_light;
  shadow_ms += o.shadow_ms;
  ao_ms += o.ao_ms;
}

PassPlan plan_passes(const Scene& scene, const TraceSettings& s) {
  if (s.ao_rays < 0 || s.ao_rays > 255) fail("trace settings: ao_rays {} out of range 1..255 (0 = the scene's)", s.ao_rays);
  if (!(s.ao_radius_m >= 0.0f) || !std::isfinite(s.ao_radius_m))
    fail("trace settings: ao_radius_m {} must be finite and > 0 (0 = the scene's)", s.ao_radius_m);
  if (s.samples_per_light < 1 || s.samples_per_light > 1024)
    fail("trace settings: samples_per_light {} out of range 1..1024", s.samples_per_light);
  if (s.threads < 0) fail("trace settings: threads {} must be >= 0 (0 = the scene's arena)", s.threads);
  if (scene.lights.size() > 64) fail("scene '{}': {} lights, at most 64 are supported", scene.name, scene.lights.size());

  PassPlan plan;
  plan.lights = int(scene.lights.size());
  if (scene.lights.empty()) {
    plan.reasons.push_back("no lights: no visibility pass");
  } else if (!s.visibility_pass) {
    plan.reasons.push_back("visibility pass switched off by the run's settings");
  } else {
    bool any_area = false;
    for (const Light& l : scene.lights) {
      const bool soft = s.soft_shadows && !l.is_point();
      plan.light_soft.push_back(soft ? 1 : 0);
      any_area = any_area || !l.is_point();
    }
    if (!any_area) {
      plan.shadow = ShadowMode::Hard;
      plan.samples_per_light = 1;
      plan.reasons.push_back(fmt::format("{} point light(s) only: hard shadows, one ray per light", plan.lights));
    } else if (!s.soft_shadows) {
      plan.shadow = ShadowMode::Hard;
      plan.samples_per_light = 1;
      plan.reasons.push_back("soft shadows off: hard shadows, one ray to each light's centre");
    } else if (s.samples_per_light == 1) {
      plan.shadow = ShadowMode::SoftBit;
      plan.samples_per_light = 1;
      plan.reasons.push_back("area light(s): soft shadows, one jittered ray per light (bitmask)");
    } else {
      plan.shadow = ShadowMode::SoftFraction;
      plan.samples_per_light = s.samples_per_light;
      plan.reasons.push_back(fmt::format("area light(s): soft shadows, {} rays per light (8-bit fraction)",
                                         s.samples_per_light));
    }
  }
  if (!scene.ao) {
    plan.reasons.push_back("no ao block: no AO pass");
  } else if (!s.ao_pass) {
    plan.reasons.push_back("AO pass switched off by the run's settings");
  } else {
    plan.ao = true;
    plan.ao_rays = s.ao_rays > 0 ? s.ao_rays : scene.ao->rays;
    plan.ao_radius_m = s.ao_radius_m > 0.0f ? s.ao_radius_m : scene.ao->radius_m;
    if (plan.ao_rays < 1 || plan.ao_rays > 255)
      fail("scene '{}': ao.rays {} out of range 1..255", scene.name, plan.ao_rays);
    if (!(plan.ao_radius_m > 0.0f) || !std::isfinite(plan.ao_radius_m))
      fail("scene '{}': ao.radius_m {} must be finite and > 0", scene.name, plan.ao_radius_m);
    plan.reasons.push_back(fmt::format("ao: {} rays, radius {} m", plan.ao_rays, plan.ao_radius_m));
  }
  return plan;
}

namespace {

// uniforms_chunk for one sample of n pixels: u0[x], u1[x] from the per-pixel hashes h[x].
__attribute__((target_clones("default", "arch=x86-64-v4"))) void uniforms_pixels(const uint64_t* h, int n,
                                                                                 uint32_t sample, uint32_t stream,
                                                                                 float* u0, float* u1) {
  const uint64_t key = (uint64_t(sample) << 32) | stream;
  for (int x = 0; x < n; ++x) {
    const uint64_t k = mix64(h[x] ^ key);
    u0[x] = float(mix64(k ^ 0u) >> 40) * (1.0f / 16777216.0f);
    u1[x] = float(mix64(k ^ 1u) >> 40) * (1.0f / 16777216.0f);
  }
}

// What a (pixel, light) pair does (core/trace.h): trace ray(s), or a known answer.
enum PairCode : uint8_t { kPairRays = 0, kPairRange = 1, kPairInside = 2, kPairFacing = 3 };

// Per-row working arrays of the visibility pass, by pixel (x) and by light and pixel
// (l * w + x). The pass works a row at a time in stages -- surfaces, then one light at a time
// over the whole row, then the rays in pixel order -- so that the long chains of square roots
// and divisions of neighbouring pixels overlap (and vectorize) instead of running one after
// the other. Values of uncovered pixels are computed on zeros and never used.
struct VisibilityRow {
  int w = 0;
  std::vector<uint8_t> covered, origin_ok;
  std::vector<float> px, py, pz, nx, ny, nz, ox, oy, oz;
  std::vector<uint64_t> h;   // PixelRng hash per pixel
  std::vector<int> idx;       // compacted pixel indices (sphere_light_row)
  // Temporaries of the light stages, by compacted index (sphere) or pixel (distant); kChunk
  // lanes of padding so that 4- and 8-lane loads and stores past the end stay inside.
  std::vector<float> t0, t1, t2, t3, t4, t5, t6, t7, t8, t9, t10, t11, t12;
  std::vector<float> u0, u1;  // one sample's uniforms per pixel
  // Per light and pixel.
  std::vector<uint8_t> code, ok;
  std::vector<float> dx, dy, dz, tfar;  // the ray (hard, or soft with one sample)
  std::vector<float> wx, wy, wz, ocx, ocy, ocz, omc;  // sphere cone (soft with S > 1)

  VisibilityRow(int width, int lights) : w(width) {
    const size_t n = size_t(width), nl = n * size_t(lights);
    for (auto* v : {&covered, &origin_ok}) v->assign(n, 0);
    for (auto* v : {&px, &py, &pz, &nx, &ny, &nz, &ox, &oy, &oz}) v->assign(n, 0.0f);
    for (auto* v : {&u0, &u1, &t0, &t1, &t2, &t3, &t4, &t5, &t6, &t7, &t8, &t9, &t10, &t11, &t12})
      v->assign(n + size_t(kChunk), 0.0f);
    h.assign(n, 0);
    idx.assign(n, 0);
    for (auto* v : {&code, &ok}) v->assign(nl, 0);
    for (auto* v : {&dx, &dy, &dz, &tfar, &wx, &wy, &wz, &ocx, &ocy, &ocz, &omc}) v->assign(nl, 0.0f);
  }
};

// Stage 2 for a sphere light over a row: classification in double precision (as the scalar
// rules in core/trace.h), then the hard ray, the single jittered ray (S = 1) or the cone
// (S > 1). Branch-free: every pixel computes everything, the code picks.
void sphere_light_row(VisibilityRow& r, const LightInfo& li, size_t base, bool one_sample) {
  const int w = r.w;
  const double cx = li.centre_d.x, cy = li.centre_d.y, cz = li.centre_d.z;
  const double range = double(li.range), radius = double(li.radius);
  const bool has_range = li.range > 0.0f;
  const float r2 = li.radius * li.radius;
  uint8_t* __restrict code = &r.code[base];
  uint8_t* __restrict ok = &r.ok[base];
  float* __restrict dx = &r.dx[base];
  float* __restrict dy = &r.dy[base];
  float* __restrict dz = &r.dz[base];
  float* __restrict tfar = &r.tfar[base];
  // Classification of every pixel (one double square root each), then the rays only for the
  // covered pairs that trace (compacted: out-of-range and facing-away pairs cost nothing more).
  int* __restrict idx = r.idx.data();
  int m = 0;
  for (int x = 0; x < w; ++x) {
    const double tx = cx - double(r.px[size_t(x)]), ty = cy - double(r.py[size_t(x)]), tz = cz - double(r.pz[size_t(x)]);
    const double d = std::sqrt(tx * tx + ty * ty + tz * tz);
    const double n_dot = double(r.nx[size_t(x)]) * tx + double(r.ny[size_t(x)]) * ty + double(r.nz[size_t(x)]) * tz;
    const bool out_of_range = has_range && d > range;
    const bool inside = !(d > radius) && d == d;
    // Hard: facing away from the centre. Soft: the whole sphere below the horizon.
    const bool facing = li.soft ? n_dot <= -radius : n_dot <= 0.0;
    const uint8_t c = out_of_range ? kPairRange : inside ? kPairInside : facing ? kPairFacing : kPairRays;
    code[x] = c;
    idx[m] = x;
    m += (c == kPairRays) & (r.covered[size_t(x)] != 0);
  }
  // The rays of the compacted pairs, in short loops (loop fission): each keeps only a few
  // dependent square roots and divisions per pair, so that the out-of-order core overlaps
  // many pairs instead of waiting on one long chain.
  float* __restrict ocx = r.t0.data();
  float* __restrict ocy = r.t1.data();
  float* __restrict ocz = r.t2.data();
  for (int k = 0; k < m; ++k) {
    const int x = idx[k];
    ocx[k] = li.centre.x - r.ox[size_t(x)];
    ocy[k] = li.centre.y - r.oy[size_t(x)];
    ocz[k] = li.centre.z - r.oz[size_t(x)];
  }
  if (!li.soft) {
    for (int k = 0; k < m; ++k) {
      const int x = idx[k];
      const float dist_o = std::sqrt(ocx[k] * ocx[k] + ocy[k] * ocy[k] + ocz[k] * ocz[k]);
      dx[x] = ocx[k] / dist_o;
      dy[x] = ocy[k] / dist_o;
      dz[x] = ocz[k] / dist_o;
      tfar[x] = std::max(0.0f, (dist_o - li.radius) * kShadowTfarScale);
      ok[x] = direction_valid(dx[x], dy[x], dz[x], tfar[x]) && r.origin_ok[size_t(x)] != 0;
    }
    return;
  }
  // Cone subtended by the sphere from p: sin^2 = R^2 / d^2 (double precision).
  float* __restrict omc = r.t3.data();
  float* __restrict wx = r.t4.data();
  float* __restrict wy = r.t5.data();
  float* __restrict wz = r.t6.data();
  for (int k = 0; k < m; ++k) {
    const int x = idx[k];
    const double tx = cx - double(r.px[size_t(x)]), ty = cy - double(r.py[size_t(x)]), tz = cz - double(r.pz[size_t(x)]);
    const double d = std::sqrt(tx * tx + ty * ty + tz * tz);
    const double s2 = radius * li.radius / (d * d);
    omc[k] = float(s2 / (1.0 + std::sqrt(1.0 - s2)));
    wx[k] = float(tx / d);
    wy[k] = float(ty / d);
    wz[k] = float(tz / d);
  }
  if (!one_sample) {
    for (int k = 0; k < m; ++k) {
      const size_t i = base + size_t(idx[k]);
      r.wx[i] = wx[k], r.wy[i] = wy[k], r.wz[i] = wz[k];
      r.ocx[i] = ocx[k], r.ocy[i] = ocy[k], r.ocz[i] = ocz[k];
      r.omc[i] = omc[k];
    }
    return;
  }
  float* __restrict u0 = r.t7.data();
  float* __restrict u1 = r.t8.data();
  for (int k = 0; k < m; ++k) {
    u0[k] = r.u0[size_t(idx[k])];
    u1[k] = r.u1[size_t(idx[k])];
  }
  float* __restrict ex = r.t9.data();
  float* __restrict ey = r.t10.data();
  float* __restrict ez = r.t11.data();
  float* __restrict et = r.t12.data();
#if defined(__SSE2__)
  // Lanes past m (up to the next multiple of 4) compute on stale finite values, unused.
  for (int k = 0; k < m; k += 4) {
    const Vec3x4 wv{_mm_loadu_ps(wx + k), _mm_loadu_ps(wy + k), _mm_loadu_ps(wz + k)};
    Vec3x4 tv, bv;
    orthonormal_basis_x4(wv, tv, bv);
    const Vec3x4 d = cone_x4(tv, bv, wv, _mm_loadu_ps(omc + k), _mm_loadu_ps(u0 + k), _mm_loadu_ps(u1 + k));
    const Vec3x4 oc{_mm_loadu_ps(ocx + k), _mm_loadu_ps(ocy + k), _mm_loadu_ps(ocz + k)};
    _mm_storeu_ps(ex + k, d.x);
    _mm_storeu_ps(ey + k, d.y);
    _mm_storeu_ps(ez + k, d.z);
    _mm_storeu_ps(et + k, sphere_tfar_x4(d, oc, _mm_set1_ps(r2)));
  }
#else
  for (int k = 0; k < m; ++k) {
    const glm::vec3 wd(wx[k], wy[k], wz[k]);
    glm::vec3 tb, bb;
    orthonormal_basis(wd, tb, bb);
    float a0[kChunk] = {u0[k]}, a1[kChunk] = {u1[k]}, cx_[kChunk], cy_[kChunk], cz_[kChunk];
    sample_cone_chunk(tb, bb, wd, omc[k], a0, a1, cx_, cy_, cz_);
    const glm::vec3 d(cx_[0], cy_[0], cz_[0]);
    ex[k] = d.x, ey[k] = d.y, ez[k] = d.z;
    // Distance from the origin to the sphere along dir (nearest root); rounding at the cone's
    // rim can leave no root: then the closest approach.
    const float b = d.x * ocx[k] + d.y * ocy[k] + d.z * ocz[k];
    const float qx = ocx[k] - b * d.x, qy = ocy[k] - b * d.y, qz = ocz[k] - b * d.z;
    const float disc = r2 - (qx * qx + qy * qy + qz * qz);
    const float t_hit = disc > 0.0f ? b - std::sqrt(disc) : b;
    et[k] = std::max(0.0f, t_hit * kShadowTfarScale);
  }
#endif
  for (int k = 0; k < m; ++k) {
    const int x = idx[k];
    dx[x] = ex[k], dy[x] = ey[k], dz[x] = ez[k], tfar[x] = et[k];
    ok[x] = direction_valid(ex[k], ey[k], ez[k], et[k]) && r.origin_ok[size_t(x)] != 0;
  }
}

// Stage 2 for a distant light over a row.
void distant_light_row(VisibilityRow& r, const LightInfo& li, size_t base, bool one_sample) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const int w = r.w;
  for (int x = 0; x < w; ++x) {
    const size_t i = base + size_t(x);
    const float n_dot = r.nx[size_t(x)] * li.dir.x + r.ny[size_t(x)] * li.dir.y + r.nz[size_t(x)] * li.dir.z;
    r.code[i] = (li.soft ? n_dot <= -li.sin_alpha : n_dot <= 0.0f) ? kPairFacing : kPairRays;
    r.dx[i] = li.dir.x, r.dy[i] = li.dir.y, r.dz[i] = li.dir.z;
    r.tfar[i] = kInf;
  }
  if (li.soft && one_sample) {
    // One jittered ray per pixel (all pixels of the row; uncovered ones are never used).
    for (int x = 0; x < w; x += kChunk)
      sample_cone_chunk(li.t, li.b, li.dir, li.one_minus_cos, &r.u0[size_t(x)], &r.u1[size_t(x)], &r.t9[size_t(x)],
                        &r.t10[size_t(x)], &r.t11[size_t(x)]);
    for (int x = 0; x < w; ++x) {
      const size_t i = base + size_t(x);
      r.dx[i] = r.t9[size_t(x)], r.dy[i] = r.t10[size_t(x)], r.dz[i] = r.t11[size_t(x)];
    }
  }
  if (li.soft && !one_sample) return;
  for (int x = 0; x < w; ++x) {
    const size_t i = base + size_t(x);
    r.ok[i] = direction_valid(r.dx[i], r.dy[i], r.dz[i], kInf) && r.origin_ok[size_t(x)] != 0;
  }
}

template <int W>
void visibility_rows(RtScene& rt, const GBuffer& g, const TraceSettings& settings, const std::vector<LightInfo>& lights,
                     VisibilityCounts& out, std::vector<std::vector<RTCRay>>* rows_out, int y0, int y1,
                     TraceStats& st) {
  const int w = g.width();
  const size_t npx = size_t(w) * size_t(g.height());
  const int nl = int(lights.size());
  Batch<W> batch(rt.handle(), kMaskShadow);
  TriangleCache cache;
  VisibilityRow r(w, nl);
  bool any_soft = false;  // hard lights need no random numbers
  for (const LightInfo& li : lights) any_soft = any_soft || li.soft;
  uint64_t invalid = 0, unres = 0, facing = 0, range = 0, inside = 0, cov = 0;
  alignas(64) float u0[kChunk], u1[kChunk], dx[kChunk], dy[kChunk], dz[kChunk], tfar[kChunk];
  alignas(64) bool ok[kChunk];
  constexpr float kInf = std::numeric_limits<float>::infinity();
  for (int y = y0; y < y1; ++y) {
    if (rows_out) batch.record = &(*rows_out)[size_t(y)];
    // Stage 1: surfaces.
    bool any = false;
    for (int x = 0; x < w; ++x) {
      Surface s;
      const size_t i = size_t(x);
      r.covered[i] = surface_at(rt, g, x, y, s, unres, cache) ? 1 : 0;
      if (!r.covered[i]) {
        s = Surface{};
      } else {
        any = true;
        ++cov;
      }
      r.px[i] = s.p.x, r.py[i] = s.p.y, r.pz[i] = s.p.z;
      r.nx[i] = s.n.x, r.ny[i] = s.n.y, r.nz[i] = s.n.z;
      r.ox[i] = s.origin.x, r.oy[i] = s.origin.y, r.oz[i] = s.origin.z;
      r.origin_ok[i] = origin_valid(s.origin) ? 1 : 0;
      if (any_soft) r.h[i] = PixelRng(settings.seed, uint32_t(size_t(y) * size_t(w) + i), settings.frame).h;
    }
    if (!any) continue;
    // Stage 2: each light over the row.
    for (int l = 0; l < nl; ++l) {
      const LightInfo& li = lights[size_t(l)];
      const bool one_sample = li.samples == 1;
      if (li.soft && one_sample) uniforms_pixels(r.h.data(), w, 0, kStreamLightBase + uint32_t(l), r.u0.data(), r.u1.data());
      if (li.sphere) sphere_light_row(r, li, size_t(l) * size_t(w), one_sample);
      else distant_light_row(r, li, size_t(l) * size_t(w), one_sample);
    }
    // Stage 3: answers and rays in pixel order (pixel, light, sample).
    for (int x = 0; x < w; ++x) {
      if (!r.covered[size_t(x)]) continue;
      const size_t pixel = size_t(y) * size_t(w) + size_t(x);
      const glm::vec3 origin(r.ox[size_t(x)], r.oy[size_t(x)], r.oz[size_t(x)]);
      const bool origin_ok = r.origin_ok[size_t(x)] != 0;
      for (int l = 0; l < nl; ++l) {
        const LightInfo& li = lights[size_t(l)];
        const size_t i = size_t(l) * size_t(w) + size_t(x);
        uint16_t* count = &out.visible[size_t(l) * npx + pixel];
        switch (r.code[i]) {
          case kPairRange: ++range; continue;
          case kPairInside: *count = uint16_t(li.samples), ++inside; continue;
          case kPairFacing: ++facing; continue;
          default: break;
        }
        if (li.samples == 1) {
          if (r.ok[i]) {
            batch.push(origin, r.dx[i], r.dy[i], r.dz[i], r.tfar[i], count);
          } else {
            ++invalid;
            ++*count;
          }
          continue;
        }
        const uint32_t stream = kStreamLightBase + uint32_t(l);
        const glm::vec3 w_dir = li.sphere ? glm::vec3(r.wx[i], r.wy[i], r.wz[i]) : li.dir;
        glm::vec3 tb = li.t, bb = li.b;
        if (li.sphere) orthonormal_basis(w_dir, tb, bb);
        const float omc_max = li.sphere ? r.omc[i] : li.one_minus_cos;
        const float ocx = r.ocx[i], ocy = r.ocy[i], ocz = r.ocz[i];
        const float r2 = li.radius * li.radius;
        for (int k0 = 0; k0 < li.samples; k0 += kChunk) {
          const int n = std::min(kChunk, li.samples - k0);
          uniforms_chunk(r.h[size_t(x)], uint32_t(k0), stream, u0, u1);
          sample_cone_chunk(tb, bb, w_dir, omc_max, u0, u1, dx, dy, dz);
          if (li.sphere) {
            for (int j = 0; j < n; ++j) {
              const float b = dx[j] * ocx + dy[j] * ocy + dz[j] * ocz;
              const float qx = ocx - b * dx[j], qy = ocy - b * dy[j], qz = ocz - b * dz[j];
              const float disc = r2 - (qx * qx + qy * qy + qz * qz);
              const float t_hit = disc > 0.0f ? b - std::sqrt(disc) : b;
              tfar[j] = std::max(0.0f, t_hit * kShadowTfarScale);
            }
          } else {
            for (int j = 0; j < n; ++j) tfar[j] = kInf;
          }
          for (int j = 0; j < n; ++j) ok[j] = direction_valid(dx[j], dy[j], dz[j], tfar[j]);
          for (int j = 0; j < n; ++j) {
            if (origin_ok && ok[j]) {
              batch.push(origin, dx[j], dy[j], dz[j], tfar[j], count);
            } else {
              ++invalid;
              ++*count;
            }
          }
        }
      }
    }
  }
  batch.flush();
  if (rows_out)
    for (int y = y0; y < y1; ++y) batch.traced += (*rows_out)[size_t(y)].size();
  st.shadow_rays = batch.traced;
  st.invalid_rays = invalid;
  st.unresolved_pixels = unres;
  st.shadow_skipped_facing = facing;
  st.shadow_skipped_range = range;
  st.shadow_inside_light = inside;
  st.covered_pixels = cov;
}

// Sums per-chunk statistics (integer sums: the totals do not depend on the partition).
struct AtomicStats {
  std::atomic<uint64_t> shadow_rays{0}, ao_rays{0}, invalid{0}, unres{0}, facing{0}, range{0}, inside{0}, cov{0};
  void add(const TraceStats& s) {
    shadow_rays += s.shadow_rays;
    ao_rays += s.ao_rays;
    invalid += s.invalid_rays;
    unres += s.unresolved_pixels;
    facing += s.shadow_skipped_facing;
    range += s.shadow_skipped_range;
    inside += s.shadow_inside_light;
    cov += s.covered_pixels;
  }
};

// Runs rows(y0, y1, stats) over blocks of the image's rows in the pass's thread arena and
// returns the counts of every block summed (times are the caller's).
template <class Rows>
TraceStats trace_rows(RtScene& rt, const TraceSettings& settings, int w, int h, Rows&& rows) {
  AtomicStats acc;
  run_in_arena(rt, settings, [&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& r) {
      TraceStats st;
      rows(r.begin(), r.end(), st);
      acc.add(st);
    });
  });
  TraceStats st;
  st.pixels = size_t(w) * size_t(h);
  st.covered_pixels = acc.cov;
  st.shadow_rays = acc.shadow_rays;
  st.ao_rays = acc.ao_rays;
  st.invalid_rays = acc.invalid;
  st.unresolved_pixels = acc.unres;
  st.shadow_skipped_facing = acc.facing;
  st.shadow_skipped_range = acc.range;
  st.shadow_inside_light = acc.inside;
  return st;
}

VisibilityCounts visibility_impl(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                                 TraceStats& stats, std::vector<std::vector<RTCRay>>* rows_out) {
  if (!plan.visibility()) fail("trace_visibility: the plan has no visibility pass ({})", plan.describe());
  if (plan.lights != int(rt.scene().lights.size()))
    fail("trace_visibility: plan for {} lights, scene has {}", plan.lights, rt.scene().lights.size());
  if (plan.samples_per_light < 1 || plan.samples_per_light > 65535)
    fail("trace_visibility: samples_per_light {} out of range 1..65535", plan.samples_per_light);
  check_gbuffer(g);
  const auto t0 = std::chrono::steady_clock::now();
  rt.set_time(g.time_s);
  const int w = g.width(), h = g.height();
  const size_t npx = size_t(w) * size_t(h);
  const auto lights = light_infos(rt.scene(), plan);
  const int nl = int(lights.size());
  VisibilityCounts out;
  out.width = w;
  out.height = h;
  out.lights = nl;
  for (const auto& li : lights) out.samples.push_back(li.samples);
  out.visible.assign(npx * size_t(nl), 0);
  const bool wide = wide_packets(rt);
  TraceStats st = trace_rows(rt, settings, w, h, [&](int y0, int y1, TraceStats& rs) {
    if (wide) visibility_rows<16>(rt, g, settings, lights, out, rows_out, y0, y1, rs);
    else visibility_rows<8>(rt, g, settings, lights, out, rows_out, y0, y1, rs);
  });
  st.shadow_ms = ms_since(t0);
  stats.add(st);
  return out;
}

// The AO pixels of one row that trace rays, compacted (stage 1 of ao_rows_x16): origin, basis
// (t, b, n), per-pixel hash and counter. Arrays padded by 16 so that any 16-pixel window loads.
struct AoPixels {
  enum { kOx, kOy, kOz, kTx, kTy, kTz, kBx, kBy, kBz, kNx, kNy, kNz, kComponents };
  std::array<std::vector<float>, kComponents> c;
  std::vector<uint64_t> h;
  std::vector<uint16_t*> count;
  int n = 0;
  explicit AoPixels(int width) : h(size_t(width) + 16, 0), count(size_t(width) + 16, nullptr) {
    for (auto& v : c) v.assign(size_t(width) + 16, 0.0f);
  }
};

#if DHR_TRACE_AVX512
bool cpu_has_avx512dq() {
  static const bool has = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq");
  return has;
}

DHR_TRACE_TARGET_AVX512 inline __m512i mix64_x8(__m512i z) {  // core/rng.h's mix64, 8 lanes
  z = _mm512_add_epi64(z, _mm512_set1_epi64(int64_t(0x9E3779B97F4A7C15ull)));
  z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64(z, 30)), _mm512_set1_epi64(int64_t(0xBF58476D1CE4E5B9ull)));
  z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64(z, 27)), _mm512_set1_epi64(int64_t(0x94D049BB133111EBull)));
  return _mm512_xor_si512(z, _mm512_srli_epi64(z, 31));
}

// float(bits >> 40) / 2^24 for 16 keys given as two halves of 8 (exact: the values fit 24 bits).
DHR_TRACE_TARGET_AVX512 inline __m512 uniform_x16(__m512i lo, __m512i hi) {
  const __m256 a = _mm512_cvtepi64_ps(_mm512_srli_epi64(lo, 40));
  const __m256 b = _mm512_cvtepi64_ps(_mm512_srli_epi64(hi, 40));
  return _mm512_mul_ps(_mm512_insertf32x8(_mm512_castps256_ps512(a), b, 1), _mm512_set1_ps(1.0f / 16777216.0f));
}

// sincos_2pi_x4 on 16 lanes: the same IEEE operations in the same order.
DHR_TRACE_TARGET_AVX512 inline void sincos_2pi_x16(__m512 u, __m512& c, __m512& s) {
  const __m512 one = _mm512_set1_ps(1.0f);
  const __m512 sign = _mm512_castsi512_ps(_mm512_set1_epi32(int32_t(0x80000000u)));
  const __m512 x = _mm512_mul_ps(_mm512_set1_ps(4.0f), u);
  const __m512i q = _mm512_min_epi32(_mm512_cvttps_epi32(x), _mm512_set1_epi32(3));
  const __m512 a = _mm512_mul_ps(_mm512_sub_ps(x, _mm512_cvtepi32_ps(q)), _mm512_set1_ps(std::numbers::pi_v<float> / 2.0f));
  const __m512 a2 = _mm512_mul_ps(a, a);
  __m512 sa = _mm512_add_ps(_mm512_set1_ps(-1.0f / 5040), _mm512_mul_ps(a2, _mm512_set1_ps(1.0f / 362880)));
  sa = _mm512_add_ps(_mm512_set1_ps(1.0f / 120), _mm512_mul_ps(a2, sa));
  sa = _mm512_add_ps(_mm512_set1_ps(-1.0f / 6), _mm512_mul_ps(a2, sa));
  sa = _mm512_add_ps(one, _mm512_mul_ps(a2, sa));
  sa = _mm512_mul_ps(a, sa);
  __m512 ca = _mm512_add_ps(_mm512_set1_ps(-1.0f / 720), _mm512_mul_ps(a2, _mm512_set1_ps(1.0f / 40320)));
  ca = _mm512_add_ps(_mm512_set1_ps(1.0f / 24), _mm512_mul_ps(a2, ca));
  ca = _mm512_add_ps(_mm512_set1_ps(-0.5f), _mm512_mul_ps(a2, ca));
  ca = _mm512_add_ps(one, _mm512_mul_ps(a2, ca));
  const __m512i one_i = _mm512_set1_epi32(1), two_i = _mm512_set1_epi32(2);
  const __mmask16 odd = _mm512_test_epi32_mask(q, one_i);
  const __m512 c0 = _mm512_mask_blend_ps(odd, ca, sa);  // odd ? sa : ca
  const __m512 s0 = _mm512_mask_blend_ps(odd, sa, ca);
  const __mmask16 neg_c = _mm512_test_epi32_mask(_mm512_add_epi32(q, one_i), two_i);
  const __mmask16 neg_s = _mm512_test_epi32_mask(q, two_i);
  c = _mm512_mask_xor_ps(c0, neg_c, c0, sign);
  s = _mm512_mask_xor_ps(s0, neg_s, s0, sign);
}

// Component comp of each lane's pixel: lane l reads pixel p0 + pick[l].
DHR_TRACE_TARGET_AVX512 inline __m512 lane_values(const AoPixels& px, int comp, int p0, __m512i pick) {
  return _mm512_permutexvar_ps(pick, _mm512_loadu_ps(px.c[size_t(comp)].data() + p0));
}

// One component of cosine_dirs_chunk's direction, t * (r c) + b * (r s) + n * z, for the
// axis whose t component is comp_t (b's and n's follow at +3 and +6).
DHR_TRACE_TARGET_AVX512 inline __m512 cosine_dir_x16(const AoPixels& px, int comp_t, int p0, __m512i pick, __m512 rc,
                                                     __m512 rs, __m512 z) {
  const __m512 t = lane_values(px, comp_t, p0, pick), b = lane_values(px, comp_t + 3, p0, pick);
  const __m512 n = lane_values(px, comp_t + 6, p0, pick);
  return _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(t, rc), _mm512_mul_ps(b, rs)), _mm512_mul_ps(n, z));
}

// Stage 2 of ao_rows_x16: every ray of the row's compacted pixels, in pixel then sample order,
// 16 rays per packet (a packet may hold the end of one pixel's rays and the start of the next
// ones). Lane l of the packet starting at ray r0 = p0 rays + s0 is ray s0 + l of the window
// starting at pixel p0: pixel p0 + (s0 + l) / rays, sample (s0 + l) % rays. Per lane the pixel's
// values are picked from a 16-pixel window; hashes, uniforms and cosine directions are
// uniforms_chunk's and cosine_dirs_chunk's operations in the same order (bit-identical rays),
// computed 16 at a time and stored straight into the packet. Each pixel's unoccluded lanes are
// added with one popcount.
DHR_TRACE_TARGET_AVX512 void ao_rays_x16(const AoPixels& px, int rays, float radius_m, Batch<16>& batch) {
  const int total = px.n * rays;
  const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i rays_i = _mm512_set1_epi32(rays);
  const __m512 rays_f = _mm512_set1_ps(float(rays));
  const __m512i stream = _mm512_set1_epi64(kStreamAo);
  const __m512 one = _mm512_set1_ps(1.0f);
  auto& pk = batch.packet;
  alignas(64) int valid[16];
  for (int r0 = 0; r0 < total; r0 += 16) {
    const int p0 = r0 / rays, s0 = r0 % rays;
    const int live = std::min(16, total - r0);
    // (s0 + l) / rays by float division: exact here (s0 + l < 2^17, quotient <= 16: the
    // rounding error stays far below the 1 / rays that separates a quotient from the next).
    const __m512i v = _mm512_add_epi32(_mm512_set1_epi32(s0), iota);
    const __m512i pick = _mm512_cvttps_epi32(_mm512_div_ps(_mm512_cvtepi32_ps(v), rays_f));
    const __m512i sample = _mm512_sub_epi32(v, _mm512_mullo_epi32(pick, rays_i));
    const __m512i pick_lo = _mm512_cvtepi32_epi64(_mm512_castsi512_si256(pick));
    const __m512i pick_hi = _mm512_cvtepi32_epi64(_mm512_extracti64x4_epi64(pick, 1));
    // key = (sample << 32) | stream, as PixelRng::uniform2
    const __m512i key_lo = _mm512_or_si512(_mm512_slli_epi64(_mm512_cvtepu32_epi64(_mm512_castsi512_si256(sample)), 32), stream);
    const __m512i key_hi =
        _mm512_or_si512(_mm512_slli_epi64(_mm512_cvtepu32_epi64(_mm512_extracti64x4_epi64(sample, 1)), 32), stream);
    const __m512i h0 = _mm512_loadu_si512(px.h.data() + p0), h1 = _mm512_loadu_si512(px.h.data() + p0 + 8);
    const __m512i k_lo = mix64_x8(_mm512_xor_si512(_mm512_permutex2var_epi64(h0, pick_lo, h1), key_lo));
    const __m512i k_hi = mix64_x8(_mm512_xor_si512(_mm512_permutex2var_epi64(h0, pick_hi, h1), key_hi));
    const __m512i dim1 = _mm512_set1_epi64(1);
    const __m512 u0 = uniform_x16(mix64_x8(k_lo), mix64_x8(k_hi));
    const __m512 u1 = uniform_x16(mix64_x8(_mm512_xor_si512(k_lo, dim1)), mix64_x8(_mm512_xor_si512(k_hi, dim1)));
    const __m512 r = _mm512_sqrt_ps(u0);
    const __m512 z = _mm512_sqrt_ps(_mm512_sub_ps(one, u0));
    __m512 c, s;
    sincos_2pi_x16(u1, c, s);
    const __m512 rc = _mm512_mul_ps(r, c), rs = _mm512_mul_ps(r, s);
    _mm512_store_ps(pk.org_x, lane_values(px, AoPixels::kOx, p0, pick));
    _mm512_store_ps(pk.org_y, lane_values(px, AoPixels::kOy, p0, pick));
    _mm512_store_ps(pk.org_z, lane_values(px, AoPixels::kOz, p0, pick));
    _mm512_store_ps(pk.dir_x, cosine_dir_x16(px, AoPixels::kTx, p0, pick, rc, rs, z));
    _mm512_store_ps(pk.dir_y, cosine_dir_x16(px, AoPixels::kTy, p0, pick, rc, rs, z));
    _mm512_store_ps(pk.dir_z, cosine_dir_x16(px, AoPixels::kTz, p0, pick, rc, rs, z));
    _mm512_store_ps(pk.tfar, _mm512_set1_ps(radius_m));  // tfar = r: never trace further
    if (batch.record) {  // collect_ao_rays: push() keeps the rays, traces nothing
      for (int l = 0; l < live; ++l)
        batch.push(glm::vec3(pk.org_x[l], pk.org_y[l], pk.org_z[l]), pk.dir_x[l], pk.dir_y[l], pk.dir_z[l], radius_m,
                   nullptr);
      continue;
    }
    for (int l = 0; l < 16; ++l) valid[l] = l < live ? -1 : 0;
    rtcOccluded16(valid, batch.scene, &batch.ctx, &pk);
    // Embree sets tfar = -inf on an occluded ray; anything else reached (as Batch::flush).
    const uint32_t live_mask = (1u << live) - 1u;
    const uint32_t reached = _mm512_cmp_ps_mask(_mm512_load_ps(pk.tfar), _mm512_setzero_ps(), _CMP_NLT_UQ) & live_mask;
    const int last = (s0 + live - 1) / rays;  // the packet's last pixel, relative to p0
    for (int g = 0; g <= last; ++g) {
      const uint32_t lanes = _mm512_cmpeq_epi32_mask(pick, _mm512_set1_epi32(g));
      uint16_t* count = px.count[size_t(p0 + g)];
      *count = uint16_t(*count + popcount16(reached & lanes));  // the target has no POPCNT either
    }
    batch.traced += uint64_t(live);
  }
}
#endif

// A pixel's AO set-up shared by both row kernels: the surface, its basis and validation
// (once per pixel: with a valid origin, a finite unit basis and 0 <= tfar = r, every direction
// is a finite unit-length combination of the basis, so every ray of the pixel is valid --
// ray_is_valid would pass each one). Returns false for background; sets valid.
bool ao_surface(const RtScene& rt, const GBuffer& g, int x, int y, float radius_m, Surface& s, bool& valid,
                uint64_t& unres, TriangleCache& cache) {
  if (!surface_at(rt, g, x, y, s, unres, cache)) return false;
  orthonormal_basis(s.n, s.t, s.b);
  valid = ray_is_valid(s.origin, s.n, 0.0f, radius_m) && std::isfinite(s.t.x + s.t.y + s.t.z) &&
          std::isfinite(s.b.x + s.b.y + s.b.z);
  return true;
}

#if DHR_TRACE_AVX512
// The AO rows with the AVX-512 ray generator: stage 1 gathers the row's tracing pixels
// (scalar: surface, basis, validation, hash), stage 2 (ao_rays_x16) makes and traces the rays.
void ao_rows_x16(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                 AoCounts& out, std::vector<std::vector<RTCRay>>* rows_out, int y0, int y1, TraceStats& st) {
  const int w = g.width();
  Batch<16> batch(rt.handle(), kMaskAll);
  TriangleCache cache;
  AoPixels px(w);
  uint64_t invalid = 0, unres = 0, cov = 0;
  for (int y = y0; y < y1; ++y) {
    if (rows_out) batch.record = &(*rows_out)[size_t(y)];
    px.n = 0;
    for (int x = 0; x < w; ++x) {
      Surface s;
      bool valid = false;
      if (!ao_surface(rt, g, x, y, radius_m, s, valid, unres, cache)) continue;
      ++cov;
      const size_t pixel = size_t(y) * size_t(w) + size_t(x);
      uint16_t* count = &out.unoccluded[pixel];
      if (!valid) {
        invalid += uint64_t(ao_rays);
        *count = uint16_t(ao_rays);
        continue;
      }
      *count = 0;
      const size_t i = size_t(px.n++);
      const float v[AoPixels::kComponents] = {s.origin.x, s.origin.y, s.origin.z, s.t.x, s.t.y, s.t.z,
                                              s.b.x,      s.b.y,      s.b.z,      s.n.x, s.n.y, s.n.z};
      for (int k = 0; k < AoPixels::kComponents; ++k) px.c[size_t(k)][i] = v[k];
      px.h[i] = PixelRng(settings.seed, uint32_t(pixel), settings.frame).h;
      px.count[i] = count;
    }
    ao_rays_x16(px, ao_rays, radius_m, batch);
  }
  if (rows_out)
    for (int y = y0; y < y1; ++y) batch.traced += (*rows_out)[size_t(y)].size();
  st.ao_rays = batch.traced;
  st.invalid_rays = invalid;
  st.unresolved_pixels = unres;
  st.covered_pixels = cov;
}
#endif

template <int W>
void ao_rows(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings, AoCounts& out,
             std::vector<std::vector<RTCRay>>* rows_out, int y0, int y1, TraceStats& st) {
  const int w = g.width();
  Batch<W> batch(rt.handle(), kMaskAll);
  TriangleCache cache;
  uint64_t invalid = 0, unres = 0, cov = 0;
  alignas(64) float u0[kChunk], u1[kChunk], dx[kChunk], dy[kChunk], dz[kChunk];
  for (int y = y0; y < y1; ++y) {
    if (rows_out) batch.record = &(*rows_out)[size_t(y)];
    for (int x = 0; x < w; ++x) {
      Surface s;
      bool valid = false;
      if (!ao_surface(rt, g, x, y, radius_m, s, valid, unres, cache)) continue;
      ++cov;
      const size_t pixel = size_t(y) * size_t(w) + size_t(x);
      uint16_t* count = &out.unoccluded[pixel];
      *count = 0;
      if (!valid) {
        invalid += uint64_t(ao_rays);
        *count = uint16_t(ao_rays);
        continue;
      }
      const PixelRng rng(settings.seed, uint32_t(pixel), settings.frame);
      const glm::vec3 t = s.t, b = s.b, n = s.n;
      for (int k0 = 0; k0 < ao_rays; k0 += kChunk) {
        const int m = std::min(kChunk, ao_rays - k0);
        uniforms_chunk(rng.h, uint32_t(k0), kStreamAo, u0, u1);
        cosine_dirs_chunk(t, b, n, u0, u1, dx, dy, dz);
        // tfar = r: "occluded if anything is hit within r", never trace further.
        batch.push_chunk(s.origin, dx, dy, dz, radius_m, m, count);
      }
    }
  }
  batch.flush();
  if (rows_out)
    for (int y = y0; y < y1; ++y) batch.traced += (*rows_out)[size_t(y)].size();
  st.ao_rays = batch.traced;
  st.invalid_rays = invalid;
  st.unresolved_pixels = unres;
  st.covered_pixels = cov;
}

AoCounts ao_impl(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                 TraceStats& stats, std::vector<std::vector<RTCRay>>* rows_out) {
  if (ao_rays < 1 || ao_rays > 65535) fail("trace_ao: ao_rays {} out of range 1..65535", ao_rays);
  if (!(radius_m > 0.0f) || !std::isfinite(radius_m)) fail("trace_ao: radius_m {} must be finite and > 0", radius_m);
  check_gbuffer(g);
  const auto t0 = std::chrono::steady_clock::now();
  rt.set_time(g.time_s);
  const int w = g.width(), h = g.height();
  const size_t npx = size_t(w) * size_t(h);
  AoCounts out;
  out.width = w;
  out.height = h;
  out.rays = ao_rays;
  // Background pixels read as unoccluded.
  out.unoccluded.assign(npx, uint16_t(ao_rays));
  const bool wide = wide_packets(rt);
#if DHR_TRACE_AVX512
  const bool x16 = wide && settings.wide_kernels && cpu_has_avx512dq();
#else
  const bool x16 = false;
#endif
  TraceStats st = trace_rows(rt, settings, w, h, [&](int y0, int y1, TraceStats& rs) {
#if DHR_TRACE_AVX512
    if (x16) return ao_rows_x16(rt, g, ao_rays, radius_m, settings, out, rows_out, y0, y1, rs);
#endif
    if (wide) ao_rows<16>(rt, g, ao_rays, radius_m, settings, out, rows_out, y0, y1, rs);
    else ao_rows<8>(rt, g, ao_rays, radius_m, settings, out, rows_out, y0, y1, rs);
  });
  st.ao_ms = ms_since(t0);
  stats.add(st);
  return out;
}

}  // namespace

bool wide_kernels_available(const RtScene& rt) {
#if DHR_TRACE_AVX512
  return wide_packets(rt) && cpu_has_avx512dq();
#else
  (void)rt;
  return false;
#endif
}

VisibilityCounts trace_visibility_counts(RtScene& rt, const GBuffer& g, const PassPlan& plan,
                                         const TraceSettings& settings, TraceStats& stats) {
  return visibility_impl(rt, g, plan, settings, stats, nullptr);
}

AoCounts trace_ao_counts(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                         TraceStats& stats) {
  return ao_impl(rt, g, ao_rays, radius_m, settings, stats, nullptr);
}

std::vector<RTCRay> collect_visibility_rays(RtScene& rt, const GBuffer& g, const PassPlan& plan,
                                            const TraceSettings& settings) {
  std::vector<std::vector<RTCRay>> rows(size_t(g.height()));
  TraceStats st;
  visibility_impl(rt, g, plan, settings, st, &rows);
  std::vector<RTCRay> out;
  out.reserve(st.shadow_rays);
  for (auto& r : rows) out.insert(out.end(), r.begin(), r.end());
  return out;
}

std::vector<RTCRay> collect_ao_rays(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m,
                                    const TraceSettings& settings) {
  std::vector<std::vector<RTCRay>> rows(size_t(g.height()));
  TraceStats st;
  ao_impl(rt, g, ao_rays, radius_m, settings, st, &rows);
  std::vector<RTCRay> out;
  out.reserve(st.ao_rays);
  for (auto& r : rows) out.insert(out.end(), r.begin(), r.end());
  return out;
}

PassBuffer pack_visibility(const VisibilityCounts& c, const PassPlan& plan) {
  PassBuffer pb;
  pb.desc = plan.visibility_desc(c.width, c.height);
  const std::string problem = pb.desc.validate();
  if (!problem.empty()) fail("pack_visibility: {}", problem);
  const size_t npx = size_t(c.width) * size_t(c.height);
  pb.bytes.assign(pb.desc.byte_size(), 0);
  if (pb.desc.kind == PassKind::Visibility) {
    const size_t bpp = size_t((c.lights + 7) / 8);
    for (int l = 0; l < c.lights; ++l) {
      const uint16_t* v = &c.visible[size_t(l) * npx];
      const uint8_t bit = uint8_t(1u << (l & 7));
      uint8_t* dst = pb.bytes.data() + size_t(l >> 3);
      for (size_t i = 0; i < npx; ++i)
        if (v[i] * 2 >= c.samples[size_t(l)]) dst[i * bpp] |= bit;  // samples are 1 here
    }
  } else {
    const int fs = pb.desc.full_scale;
    for (int l = 0; l < c.lights; ++l) {
      const uint16_t* v = &c.visible[size_t(l) * npx];
      uint8_t* dst = pb.bytes.data() + size_t(l) * npx;
      const uint32_t sl = uint32_t(c.samples[size_t(l)]);
      for (size_t i = 0; i < npx; ++i)
        dst[i] = sl == uint32_t(fs) ? uint8_t(v[i]) : uint8_t((uint32_t(v[i]) * uint32_t(fs) + sl / 2) / sl);
    }
  }
  return pb;
}

PassBuffer pack_ao(const AoCounts& c) {
  if (c.rays < 1 || c.rays > 255) fail("pack_ao: {} rays do not fit the 8-bit AO pass (1..255)", c.rays);
  PassBuffer pb;
  pb.desc.kind = PassKind::Ao;
  pb.desc.width = c.width;
  pb.desc.height = c.height;
  pb.desc.channels = 1;
  pb.desc.full_scale = c.rays;
  pb.bytes.resize(c.unoccluded.size());
  for (size_t i = 0; i < c.unoccluded.size(); ++i) pb.bytes[i] = uint8_t(c.unoccluded[i]);
  return pb;
}

PassBuffer trace_visibility(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                            TraceStats& stats) {
  return pack_visibility(trace_visibility_counts(rt, g, plan, settings, stats), plan);
}

PassBuffer trace_ao(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                    TraceStats& stats) {
  if (!plan.ao) fail("trace_ao: the plan has no AO pass ({})", plan.describe());
  return pack_ao(trace_ao_counts(rt, g, plan.ao_rays, plan.ao_radius_m, settings, stats));
}

TraceResult trace_passes(RtScene& rt, const GBuffer& g, const TraceSettings& settings) {
  TraceResult r;
  r.plan = plan_passes(rt.scene(), settings);
  r.stats.pixels = uint64_t(g.width()) * uint64_t(g.height());
  TraceStats vs, as;
  if (r.plan.visibility()) r.visibility = trace_visibility(rt, g, r.plan, settings, vs);
  if (r.plan.ao) r.ao = trace_ao(rt, g, r.plan, settings, as);
  // pixels/covered are per G-buffer, not per pass: take them once.
  r.stats.covered_pixels = std::max(vs.covered_pixels, as.covered_pixels);
  vs.pixels = as.pixels = vs.covered_pixels = as.covered_pixels = 0;
  if (r.plan.visibility() && r.plan.ao) as.unresolved_pixels = 0;  // same pixels counted twice
  r.stats.add(vs);
  r.stats.add(as);
  return r;
}

}  // namespace dhr
