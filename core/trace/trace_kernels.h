// Internal to the tracer (core/trace/trace.cpp, core/trace/trace_rows.cpp, core/trace/trace_avx512.cpp): what the
// entry points and the row kernels share. Not part of the public API (core/trace/trace.h).
//
// - Surface, TriangleCache, surface_at: a surface point rebuilt from the G-buffer
//   (core/trace/trace.h: "Surface points").
// - LightInfo: a light's constants for the visibility pass.
// - Batch<W>: Embree SoA packets of occlusion rays and the counters they increment.
// - The row kernels: each traces the rows [y0, y1) of a pass into its counts (or, with
//   rows_out, records the rays of each row instead of tracing them).
#pragma once

#include "core/base/avx512.h"
#include "core/trace/trace.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

// The vector kernels (core/trace/trace_avx512.cpp for AVX-512F/DQ, core/trace/trace_avx2.cpp for AVX2) are
// compiled by target attributes and chosen at run time; everything else keeps the baseline ISA.
#if defined(__x86_64__) && defined(__GNUC__)
#define DHR_TRACE_X86_KERNELS 1
#else
#define DHR_TRACE_X86_KERNELS 0
#endif

namespace dhr::trace_detail {

// A surface point rebuilt from the G-buffer (core/trace/trace.h: "Surface points").
struct Surface {
  glm::vec3 p{0.0f};           // on the triangle
  glm::vec3 n{0.0f};           // unit geometric normal, oriented like the G-buffer's (camera side)
  glm::vec3 origin{0.0f};      // p offset along n (offset_ray_origin in core/trace/trace.h; see surface_at)
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
  double offset_m = 0.0;  // origin_offset_m (core/trace/trace.h): how far along n ray origins start
};

// origin_offset_m (core/trace/trace.h) of triangle `prim` of object oi, with world vertices v and unit
// normal n. Embree intersects a static object's triangles in world space with the very float
// positions; a moving object's in object space (its float mesh positions), through an instance
// whose transform stretches object-space distances by at most its 3x3 part's Frobenius norm.
inline double triangle_offset_m(const RtScene& rt, int oi, uint32_t prim, const glm::dvec3 v[3], const glm::dvec3& n) {
  const Object& o = rt.scene().objects[size_t(oi)];
  if (!o.moving()) return origin_offset_m(v, n, 0.0, embree_plane_error(v));
  const glm::uvec3 tri = o.mesh.triangles[prim];
  glm::dvec3 w[3];
  for (int k = 0; k < 3; ++k) w[k] = glm::dvec3(o.mesh.positions[tri[k]]);
  const glm::dmat4 m(rt.world_from_object(oi));
  double frob = 0.0;
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) frob += m[c][r] * m[c][r];
  frob = std::sqrt(frob);
  PlaneError e = embree_plane_error(w);
  e.fixed_m *= frob;
  return origin_offset_m(v, n, frob * moving_offset_m(v, glm::dvec3(m[3])), e);
}

// Rebuilds the cache for the triangle (id, prim).
inline void update_triangle(const RtScene& rt, TriangleCache& cache, uint32_t id, uint32_t prim) {
  cache.id = id;
  cache.prim = prim;
  const int oi = rt.object_index(id);
  cache.resolved = oi >= 0 && rt.triangle_world(oi, prim, cache.v);
  if (cache.resolved) {
    const glm::dvec3* v = cache.v;
    glm::dvec3 n = glm::cross(v[1] - v[0], v[2] - v[0]);
    const double len = glm::length(n);
    n /= len;  // non-degenerate: degenerate triangles were skipped at build
    cache.n = n;
    cache.offset_m = triangle_offset_m(rt, oi, prim, v, n);
  }
}

// False for background pixels. Unresolvable ids fall back to the G-buffer's position and
// geometric normal (counted); a non-finite result then fails ray validation downstream.
inline bool surface_at(const RtScene& rt, const GBuffer& g, int x, int y, Surface& s, uint64_t& unresolved,
                       TriangleCache& cache) {
  const uint32_t id = g.object_id(x, y);
  if (id == kBackgroundId) return false;
  const uint32_t prim = g.prim_id(x, y);
  if (id != cache.id || prim != cache.prim) update_triangle(rt, cache, id, prim);
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
    s.origin = offset_ray_origin(p, n, cache.offset_m);
  } else {
    ++unresolved;
    s.p = g.position(x, y);
    const float len = glm::length(gn);
    s.n = gn / len;  // NaN for a zero normal: the rays then fail validation (counted)
    const glm::dvec3 p(s.p), n(s.n);
    s.origin = offset_ray_origin(p, n, point_offset_m(p, n));
  }
  return true;
}

// A pixel's AO set-up shared by the row kernels: the surface, its basis and validation
// (once per pixel: with a valid origin, a finite unit basis and 0 <= tfar = r, every direction
// is a finite unit-length combination of the basis, so every ray of the pixel is valid --
// ray_is_valid would pass each one). Returns false for background; sets valid.
inline bool ao_surface(const RtScene& rt, const GBuffer& g, int x, int y, float radius_m, Surface& s, bool& valid,
                       uint64_t& unres, TriangleCache& cache) {
  if (!surface_at(rt, g, x, y, s, unres, cache)) return false;
  orthonormal_basis(s.n, s.t, s.b);
  valid = ray_is_valid(s.origin, s.n, 0.0f, radius_m) && std::isfinite(s.t.x + s.t.y + s.t.z) &&
          std::isfinite(s.b.x + s.b.y + s.b.z);
  return true;
}

// A light's constants for the visibility pass (filled by light_infos in core/trace/trace.cpp).
struct LightInfo {
  bool sphere = true;
  bool soft = false;
  int samples = 1;
  glm::vec3 centre{0.0f};  // sphere
  glm::dvec3 centre_d{0.0};
  float radius = 0.0f;
  float range = 0.0f;
  glm::vec3 dir{0.0f, 1.0f, 0.0f};  // distant: unit, towards the light
  float one_minus_cos = 0.0f;       // distant: 1 - cos(angular radius)
  float sin_alpha = 0.0f;           // distant: sin(angular radius)
  glm::vec3 t{0.0f}, b{0.0f};       // distant: orthonormal basis around dir (cone sampling)
};

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
// most scenes, rtcOccluded1M streams (see bench_trace). A ray's answer can depend on its packet:
// Embree's traversal (without RTC_SCENE_FLAG_ROBUST) may decide a ray on an edge differently
// beside other rays (measured: one count in street's hard shadows at 640x360; docs/performance.md,
// "Which rays share a packet"). So a packet never holds more than one row's rays: the kernels
// flush at every row, and the rows a thread's block of work holds (TBB's choice as the threads
// run) cannot change a count.
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
    // Occlusion queries write only tfar: the other fields are set once. Lanes past n keep
    // whatever ray they last held, and Embree's SSE kernels (DHR_MAX_ISA=sse4.2, or a CPU
    // without AVX) check every lane's values, active or not, and abort on garbage: each lane
    // starts with a harmless ray.
    for (int k = 0; k < W; ++k) {
      packet.org_x[k] = packet.org_y[k] = packet.org_z[k] = 0.0f;
      packet.dir_x[k] = 1.0f;
      packet.dir_y[k] = packet.dir_z[k] = 0.0f;
      packet.tfar[k] = 0.0f;
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

// The AO pixels of one row that trace rays, compacted (stage 1 of ao_rows_x16): origin, basis
// (t, b, n), per-pixel hash and counter. Arrays padded by 16 so that any 16-pixel window loads.
struct AoPixels {
  enum { kOx, kOy, kOz, kTx, kTy, kTz, kBx, kBy, kBz, kNx, kNy, kNz, kComponents };
  std::array<std::vector<float>, kComponents> c;
  std::vector<uint64_t> h;
  // TraceSettings::lattice: each pixel's lattice shift (lattice_shift, stream kStreamAo).
  bool lattice = false;
  std::vector<uint32_t> shift0, shift1;
  std::vector<uint16_t*> count;
  int n = 0;
  explicit AoPixels(int width)
      : h(size_t(width) + 16, 0),
        shift0(size_t(width) + 16, 0),
        shift1(size_t(width) + 16, 0),
        count(size_t(width) + 16, nullptr) {
    for (auto& v : c) v.assign(size_t(width) + 16, 0.0f);
  }
};

// What a (pixel, light) pair does (core/trace/trace.h): trace ray(s), or a known answer.
enum PairCode : uint8_t { kPairRays = 0, kPairRange = 1, kPairInside = 2, kPairFacing = 3 };

// Per-row working arrays of the visibility pass, by pixel (x) and by light and pixel
// (l * w + x). The pass works a row at a time in stages -- surfaces, then one light at a time
// over the whole row, then the rays in pixel order -- so that the long chains of square roots
// and divisions of neighbouring pixels overlap (and vectorize) instead of running one after
// the other. Values of uncovered pixels are computed on zeros and never used.
struct VisibilityRow {
  static constexpr size_t kRowPad = 16;
  int w = 0;
  int lights = 0;
  std::vector<uint8_t> covered, origin_ok;
  std::vector<float> px, py, pz, nx, ny, nz, ox, oy, oz;
  std::vector<uint64_t> h;  // PixelRng hash per pixel
  std::vector<int> idx;     // compacted pixel indices (sphere_light_row)
  // Temporaries of the light stages, by compacted index (sphere) or pixel (distant); kRowPad
  // lanes of padding so that 4-, 8- and 16-lane loads and stores past the end stay inside.
  std::vector<float> t0, t1, t2, t3, t4, t5, t6, t7, t8, t9, t10, t11, t12;
  std::vector<float> u0, u1;  // one sample's uniforms per pixel
  // Per light and pixel (code and ok with kRowPad bytes of padding: list_pairs_x16 reads 16 at
  // a time).
  std::vector<uint8_t> code, ok;
  std::vector<float> dx, dy, dz, tfar;                // the ray (hard, or soft with one sample)
  std::vector<float> wx, wy, wz, ocx, ocy, ocz, omc;  // sphere cone (soft with S > 1)
  // The row's pairs that trace one ray each (every light with one sample), in pixel then
  // light order: their counters and their rays, copied in that order (list_pair, or
  // list_pairs_x16 16 pixels at a time): origin x, y, z, direction x, y, z and tfar, with
  // kRowPad entries of padding each.
  std::vector<uint16_t*> pair_count;
  std::vector<float> pair_ray[7];
  // Stage 1 on the x16 path (surfaces_x16): per pixel, kind (0 background, 1 on a row
  // triangle, rebuilt by the kernel; 2 done by surface_at; 3 left by the kernel to
  // surface_at), the row triangle and the G-buffer's barycentrics and geometric normal; per
  // row triangle, v0, v1, v2, n and offset_m (13 of 14 doubles, tris; grown as needed).
  std::vector<uint8_t> kind;
  std::vector<int> tri_of;
  std::vector<float> b1, b2, gx, gy, gz;
  std::vector<double> tris;

  VisibilityRow(int width, int light_count) : w(width), lights(light_count) {
    const size_t n = size_t(width), nl = n * size_t(light_count);
    // Per-pixel arrays padded too: the 16-lane kernels (core/trace/trace_avx512.cpp) load whole
    // blocks; the padding stays zero (an uncovered pixel) and nothing is stored there.
    for (auto* v : {&covered, &origin_ok}) v->assign(n + kRowPad, 0);
    for (auto* v : {&px, &py, &pz, &nx, &ny, &nz, &ox, &oy, &oz}) v->assign(n + kRowPad, 0.0f);
    for (auto* v : {&u0, &u1, &t0, &t1, &t2, &t3, &t4, &t5, &t6, &t7, &t8, &t9, &t10, &t11, &t12})
      v->assign(n + kRowPad, 0.0f);
    h.assign(n + kRowPad, 0);
    idx.assign(n + kRowPad, 0);
    kind.assign(n + kRowPad, 0);
    tri_of.assign(n + kRowPad, 0);
    for (auto* v : {&b1, &b2, &gx, &gy, &gz}) v->assign(n + kRowPad, 0.0f);

    for (auto* v : {&code, &ok}) v->assign(nl + kRowPad, 0);
    for (auto* v : {&dx, &dy, &dz, &tfar, &wx, &wy, &wz, &ocx, &ocy, &ocz, &omc}) v->assign(nl, 0.0f);
    pair_count.assign(nl + kRowPad, nullptr);
    for (auto& v : pair_ray) v.assign(nl + kRowPad, 0.0f);
  }
};

// ---- The row kernels ----

// Lists pair n: pixel x's ray for the light whose arrays start at l * w (i = l * w + x), and its
// counter.
inline void list_pair(VisibilityRow& r, int n, size_t x, size_t i, uint16_t* count) {
  const size_t j = size_t(n);
  r.pair_ray[0][j] = r.ox[x], r.pair_ray[1][j] = r.oy[x], r.pair_ray[2][j] = r.oz[x];
  r.pair_ray[3][j] = r.dx[i], r.pair_ray[4][j] = r.dy[i], r.pair_ray[5][j] = r.dz[i];
  r.pair_ray[6][j] = r.tfar[i];
  r.pair_count[j] = count;
}

// core/trace/trace_rows.cpp, instantiated for W = 8 and 16 (Embree's packet width). `pass` names the
// pass (new_pass_id(), one per call of the visibility pass): the blocks of rows one thread runs
// for the same pass share the triangles it rebuilt (same scene, time and G-buffer).
template <int W>
void visibility_rows(RtScene& rt, const GBuffer& g, const TraceSettings& settings, const std::vector<LightInfo>& lights,
                     uint64_t pass, VisibilityCounts& out, std::vector<std::vector<RTCRay>>* rows_out, int y0, int y1,
                     TraceStats& st);
extern template void visibility_rows<8>(RtScene&, const GBuffer&, const TraceSettings&, const std::vector<LightInfo>&,
                                        uint64_t, VisibilityCounts&, std::vector<std::vector<RTCRay>>*, int, int,
                                        TraceStats&);
extern template void visibility_rows<16>(RtScene&, const GBuffer&, const TraceSettings&, const std::vector<LightInfo>&,
                                         uint64_t, VisibilityCounts&, std::vector<std::vector<RTCRay>>*, int, int,
                                         TraceStats&);
// A number no earlier call returned in this process (never 0).
uint64_t new_pass_id();

// The AO rows (core/trace/trace_rows.cpp): the row's tracing pixels gathered into AoPixels by scalar
// code, then rays_fn makes, traces and counts their rays: ao_rays_baseline (the baseline
// kernel, in chunks through the Batch), ao_rays_x16 or ao_rays_x8 (below).
template <int W>
using AoRaysFn = void (*)(const AoPixels& px, int rays, float radius_m, Batch<W>& batch);
template <int W>
void ao_rows_compacted(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                       AoCounts& out, std::vector<std::vector<RTCRay>>* rows_out, int y0, int y1, TraceStats& st,
                       AoRaysFn<W> rays_fn);
extern template void ao_rows_compacted<8>(RtScene&, const GBuffer&, int, float, const TraceSettings&, AoCounts&,
                                          std::vector<std::vector<RTCRay>>*, int, int, TraceStats&, AoRaysFn<8>);
extern template void ao_rows_compacted<16>(RtScene&, const GBuffer&, int, float, const TraceSettings&, AoCounts&,
                                           std::vector<std::vector<RTCRay>>*, int, int, TraceStats&, AoRaysFn<16>);
template <int W>
void ao_rays_baseline(const AoPixels& px, int rays, float radius_m, Batch<W>& batch);
extern template void ao_rays_baseline<8>(const AoPixels&, int, float, Batch<8>&);
extern template void ao_rays_baseline<16>(const AoPixels&, int, float, Batch<16>&);

#if DHR_TRACE_X86_KERNELS
// core/trace/trace_avx2.cpp: whether the CPU has AVX2 (checked once), and the AO rays of a row's
// compacted pixels 8 at a time into Embree's 8-wide packets (the AO pass's generator where the
// CPU has AVX2 but not AVX-512): the baseline kernel's rays and counts, bit for bit.
bool cpu_has_avx2();
void ao_rays_x8(const AoPixels& px, int rays, float radius_m, Batch<8>& batch);
// One (pixel, light) pair of a soft light with S > 1 samples: what the cone loop of
// visibility_rows reads (the pixel's origin and hash, the light's stream, the cone's basis
// and opening, the sphere's centre from the origin and radius squared) and the pair's counter.
struct SoftPair {
  glm::vec3 origin{0.0f};
  bool origin_ok = false;
  uint64_t h = 0;
  uint32_t stream = 0;
  int samples = 0;
  glm::vec3 t{0.0f}, b{0.0f}, w{0.0f};
  float omc_max = 0.0f;
  bool sphere = false;
  glm::vec3 oc{0.0f};
  float r2 = 0.0f;
  uint16_t* count = nullptr;
  bool lattice = false;  // TraceSettings::lattice, with the pair's shift (lattice_shift)
  uint32_t shift0 = 0, shift1 = 0;
};
// The pair's S rays 8 at a time on AVX2 (core/trace/trace_avx2.cpp): traced and counted (invalid
// rays counted as unoccluded and added to invalid), or with batch.record kept; the cone
// loop's rays and counts bit for bit.
void soft_pair_rays_x8(const SoftPair& p, Batch<8>& batch, uint64_t& invalid);
// Stage 3 where every light takes one ray per pixel, 8 pairs per packet (trace_pairs_x16's
// work on AVX2, below): the n rays listed in r.pair_ray.
void trace_pairs_x8(const VisibilityRow& r, int n, Batch<8>& batch);
// Stage 1 for the pixels of kind 1, 8 at a time (surfaces_x16's work on AVX2, below).
void surfaces_x8(VisibilityRow& r, const TraceSettings& settings, size_t row_start, bool hashes);
// core/trace/trace_avx512.cpp: the AO rays 16 at a time (only where the CPU has AVX-512F and DQ,
// cpu_has_avx512dq in core/base/avx512.h, and Embree has 16-wide packets).
void ao_rays_x16(const AoPixels& px, int rays, float radius_m, Batch<16>& batch);
// Stage 2 of the visibility pass for a sphere light (sphere_light_row in core/trace/trace_rows.cpp),
// 16 pixels at a time: every pixel's code, the compacted indices (r.idx) of the covered pairs
// that trace, whose count it returns, and, for a hard light or a soft one with one sample,
// those pairs' rays and validity. The same operations in the same order as the scalar and
// SSE2 code: the same bits.
int sphere_light_row_x16(VisibilityRow& r, const LightInfo& li, size_t base, bool one_sample);
// Stage 1 of the visibility pass for the pixels of kind 1 (see VisibilityRow), 16 at a time:
// the point on the row triangle from the barycentrics (double), the normal oriented like the
// G-buffer's, the origin float(p + n offset_m) and its validity, as surface_at does (same
// bits). Pixels whose orientation needs the
// camera (a zero G-buffer normal) become kind 3. With
// hashes, every pixel's PixelRng hash (pixel = row_start + x).
void surfaces_x16(VisibilityRow& r, const TraceSettings& settings, size_t row_start, bool hashes);
// Stage 1's per-pixel inputs of one row on the vector path (visibility_rows' loop in
// core/trace/trace_rows.cpp): the G-buffer row it reads and the VisibilityRow arrays it writes.
struct SurfaceInputs {
  const uint32_t* ids;
  const uint32_t* prims;
  const glm::vec2* bary;
  const glm::vec3* gnorm;
  uint8_t* kind;
  uint8_t* covered;
  uint8_t* origin_ok;
  int* tri_of;
  float *b1, *b2, *gx, *gy, *gz;
  float* const __restrict* planes;  // px, py, pz, nx, ny, nz, ox, oy, oz
};
// The loop's triangle state (visibility_rows): the triangle of the last covered pixel (tc, a slot
// of the thread's table `seen`, 1 << kSeenBits slots) and its row triangle (cur, -1 while none),
// ntri row triangles so far (VisibilityRow::tris).
constexpr int kSeenBits = 10;
struct RowTriangles {
  const RtScene* rt = nullptr;
  TriangleCache* seen = nullptr;
  VisibilityRow* r = nullptr;
  const TriangleCache* tc = nullptr;
  int cur = -1;
  int ntri = 0;
};
// tc becomes triangle (id, prim), rebuilt unless its slot holds it; cur = -1.
inline void select_triangle(RowTriangles& t, uint32_t id, uint32_t prim) {
  TriangleCache& slot = t.seen[size_t(((id * 0x9E3779B1u) ^ (prim * 0x85EBCA77u)) >> (32 - kSeenBits))];
  if (slot.id != id || slot.prim != prim) update_triangle(*t.rt, slot, id, prim);
  t.tc = &slot;
  t.cur = -1;
}
// cur becomes a new row triangle holding tc (resolved): v0, v1, v2, n and offset_m.
inline void add_row_triangle(RowTriangles& t) {
  VisibilityRow& r = *t.r;
  const TriangleCache& c = *t.tc;
  t.cur = t.ntri++;
  if (r.tris.size() < 14 * size_t(t.ntri)) r.tris.resize(14 * size_t(t.ntri) * 2);
  double* v = &r.tris[14 * size_t(t.cur)];
  for (int k = 0; k < 3; ++k) v[k] = c.v[0][k], v[3 + k] = c.v[1][k], v[6 + k] = c.v[2][k], v[9 + k] = c.n[k];
  v[12] = c.offset_m;
  v[13] = 0.0;
}
// That loop over pixels x, x + 1, ... of a row of width w, 16 at a time, for as long as every
// covered pixel of a block lies on a resolved triangle: a background pixel gets kind 0, not
// covered, a zero surface and a valid origin; a covered one kind 1, its row triangle (t.cur
// where it lies on t.tc, else one selected and added as the loop does), its barycentrics and
// geometric normal: the same values the loop writes. Returns the first pixel of the block it
// left to the loop (one with a triangle that is not resolved; w when none) and adds the covered
// pixels of the blocks it did to cov.
int surface_inputs_x16(const SurfaceInputs& io, int x, int w, RowTriangles& t, uint64_t& cov);
// What stage 3 counts of the pairs that do not trace (TraceStats' fields of the same names).
struct PairTally {
  uint64_t range = 0, inside = 0, facing = 0, invalid = 0;
};
// Lights up to which list_pairs_x16 lists a row's pairs (it keeps a mask per light and block).
constexpr int kListPairsMaxLights = 32;
// A block of 16 pixels whose traced pairs lie on up to this many lights has them put in list
// order by permutes and compresses in registers; one with more, pair by pair.
constexpr int kListPairsVectorLights = 4;
// Stage 3's listing where every light takes one ray per pixel (visibility_rows' loop): for the
// covered pixels of a row, 16 at a time, each light's pair is counted by its code (out of
// range, inside the light: its count set to 1, facing away), counted as invalid (its count
// incremented) or listed, its ray in r.pair_ray and its counter in r.pair_count, in pixel then
// light order, as that loop does (per block of 16 pixels, in registers where its traced pairs
// lie on up to kListPairsVectorLights lights). counts: &VisibilityCounts::visible of light 0 at
// the row's first pixel; light l's are npx further on. nl <= kListPairsMaxLights. Returns the
// number of pairs listed.
int list_pairs_x16(VisibilityRow& r, int nl, uint16_t* counts, size_t npx, PairTally& tally);
// Stage 2 for a distant light (distant_light_row in core/trace/trace_rows.cpp) with one sample per
// pixel, 16 pixels at a time: codes, rays (the jittered cone for a soft light, the light's
// direction for a hard one) and validity. Same bits.
void distant_light_row_x16(VisibilityRow& r, const LightInfo& li, size_t base);
// The S rays of a soft pair 16 at a time on AVX-512 (soft_pair_rays_x8's work, below): the
// cone loop's rays and counts bit for bit.
void soft_pair_rays_x16(const SoftPair& p, Batch<16>& batch, uint64_t& invalid);
// Stage 3 of the visibility pass where every light takes one ray per pixel: the n rays listed
// in r.pair_ray (pixel then light order; by list_pairs_x16, or by list_pair past
// kListPairsMaxLights lights) 16 at a time into the packet (a row's last packet may be
// partial), traced, each unoccluded ray adding one to its counter; with batch.record, the rays
// are kept instead (Batch::push).
void trace_pairs_x16(const VisibilityRow& r, int n, Batch<16>& batch);
#endif

}  // namespace dhr::trace_detail
