// The row kernels of the visibility pass (paper section 3.1) and the baseline AO pass (section
// 3.2, Eq. 1-3): each turns rows of the G-buffer into rays in Embree packets (Batch,
// core/trace/trace_kernels.h) and counts the unoccluded ones. core/trace/trace.cpp runs them over blocks of
// rows; core/trace/trace_avx512.cpp and core/trace/trace_avx2.cpp hold the vector kernels.
//
// Speed (bench_trace compares every pass with a bare Embree loop over the same rays):
// - rays go straight into SoA packets (Batch) traced with rtcOccluded16 where Embree has native
//   16-wide kernels (AVX-512), else rtcOccluded8; Embree marks an occluded ray by setting tfar
//   to -inf. Neighbouring pixels reuse the last triangle's rebuild (TriangleCache).
// - random numbers: 8 keys at a time (uniforms_chunk / uniforms_pixels, an AVX-512 clone with
//   64-bit vector multiplies where the CPU has it; integer arithmetic only, same bits).
// - directions: SSE2 kernels (sincos_2pi_x4, cone_x4, ...) doing the scalar code's IEEE
//   operations in the same order, 4 lanes at a time, so results are bit-identical to it.
// - where the CPU has AVX-512 (and TraceSettings::wide_kernels): the AO pass's ray generator
//   and the visibility pass's stages (surfaces; light classification and the hard or single
//   jittered ray; packets where every light takes one ray per pixel; the cone loops of S > 1),
//   in core/trace/trace_avx512.cpp; where it has AVX2 only: the AO pass's ray
//   generator, the surfaces, the packets and the cone loops of S > 1 (core/trace/trace_avx2.cpp; the
//   light classification stays here). This file keeps the baseline kernels and the per-pixel
//   work the vector kernels hand back (unresolved ids, normals oriented by the camera).
// - the visibility pass works a row at a time in stages (surfaces; each light over the row,
//   compacted to the pairs that trace; rays in pixel order) so the square-root and division
//   chains of neighbouring pixels overlap instead of running one after the other.
// The rays, their order and every result are the same as the straightforward per-ray code's.
#include "core/trace/trace_directions.h"
#include "core/trace/trace_kernels.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>

namespace dhr::trace_detail {

namespace {

// u0[j], u1[j] = PixelRng::uniform2(first + j, stream) for j < kChunk (core/base/rng.h dimensions 0
// and 1), bit-identical to it. Integer hashing and exact conversions only (no float arithmetic
// that a wider ISA could contract or reorder), so the AVX-512 clone -- 64-bit vector multiplies,
// 8 keys at once -- gives the same bits as the baseline one.
__attribute__((target_clones("default", "arch=x86-64-v4"))) void uniforms_chunk(uint64_t h, uint32_t first,
                                                                                uint32_t stream, float* u0, float* u1) {
  for (int j = 0; j < kChunk; ++j) {
    const uint64_t k = mix64(h ^ ((uint64_t(first + uint32_t(j)) << 32) | stream));
    u0[j] = float(mix64(k ^ 0u) >> 40) * (1.0f / 16777216.0f);
    u1[j] = float(mix64(k ^ 1u) >> 40) * (1.0f / 16777216.0f);
  }
}

// uniforms_chunk's values on the lattice of TraceSettings::lattice (core/trace/trace.h): samples
// first .. first + kChunk - 1 of the pixel whose shift is (s0, s1). Integers and an exact
// conversion only, as there.
void lattice_chunk(uint32_t s0, uint32_t s1, uint32_t first, float* u0, float* u1) {
  for (int j = 0; j < kChunk; ++j) {
    u0[j] = lattice_uniform(first + uint32_t(j), kLatticeA0, s0);
    u1[j] = lattice_uniform(first + uint32_t(j), kLatticeA1, s1);
  }
}

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

// Stage 2 for a sphere light over a row: classification in double precision (as the scalar
// rules in core/trace/trace.h), then the hard ray, the single jittered ray (S = 1) or the cone
// (S > 1). Branch-free: every pixel computes everything, the code picks.
// x16: the AVX-512 kernel (sphere_light_row_x16) does the classification and the hard rays.
void sphere_light_row(VisibilityRow& r, const LightInfo& li, size_t base, bool one_sample, bool x16) {
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
#if DHR_TRACE_X86_KERNELS
  if (x16) {
    m = sphere_light_row_x16(r, li, base, one_sample);
    if (!li.soft || one_sample) return;
  }
#else
  (void)x16;
#endif
  for (int x = 0; x < w && !x16; ++x) {
    const double tx = cx - double(r.px[size_t(x)]), ty = cy - double(r.py[size_t(x)]),
                 tz = cz - double(r.pz[size_t(x)]);
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
    const double tx = cx - double(r.px[size_t(x)]), ty = cy - double(r.py[size_t(x)]),
                 tz = cz - double(r.pz[size_t(x)]);
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

}  // namespace

uint64_t new_pass_id() {
  static std::atomic<uint64_t> last{0};
  return ++last;
}

template <int W>
void visibility_rows(RtScene& rt, const GBuffer& g, const TraceSettings& settings, const std::vector<LightInfo>& lights,
                     uint64_t pass, VisibilityCounts& out, std::vector<std::vector<RTCRay>>* rows_out, int y0, int y1,
                     TraceStats& st) {
  const int w = g.width();
  const size_t npx = size_t(w) * size_t(g.height());
  const int nl = int(lights.size());
  Batch<W> batch(rt.handle(), kMaskShadow);
  Batch<W> pair_batch(rt.handle(), kMaskShadow);  // a soft light's S > 1 rays of one pixel
  TriangleCache cache;
  // One set of row arrays per thread, kept from call to call (a block of rows is often only a
  // few rows: allocating them per block cost several percent of a pass). Every value a row
  // reads is written for that row first; the padding stays zero.
  thread_local std::unique_ptr<VisibilityRow> row_arrays;
  if (!row_arrays || row_arrays->w != w || row_arrays->lights != nl)
    row_arrays = std::make_unique<VisibilityRow>(w, nl);
  VisibilityRow& r = *row_arrays;
#if DHR_TRACE_X86_KERNELS
  // AVX-512: every stage, and the cone loops of soft lights with S > 1 (soft_pair_rays_x16)
  // where Embree has 16-wide packets. With 8-wide ones (Embree's AVX2 kernels: a CPU without
  // AVX-512, or DHR_MAX_ISA=avx2 on one with it) the AVX2 kernels below, so that the cap
  // runs exactly an AVX2 machine's path (tests/CMakeLists.txt checks it on every machine).
  const bool x16 = W == 16 && settings.wide_kernels && cpu_has_avx512dq();
  // AVX2 without AVX-512: the surfaces (surfaces_x8), the cone loops of soft lights with S > 1
  // (soft_pair_rays_x8) and the packets where every light takes one ray per pixel
  // (trace_pairs_x8).
  const bool x8 = W == 8 && settings.wide_kernels && !x16 && cpu_has_avx2();
#else
  const bool x16 = false, x8 = false;
#endif
  const bool vector_surfaces = x16 || x8;
  bool any_soft = false;   // hard lights need no random numbers
  bool all_single = true;  // every light one ray per pixel (hard, or soft with S = 1)
  for (const LightInfo& li : lights) {
    any_soft = any_soft || li.soft;
    all_single = all_single && li.samples == 1;
  }
  uint64_t invalid = 0, unres = 0, facing = 0, range = 0, inside = 0, cov = 0;
  // Kept by the thread like the row arrays, and its triangles from block to block of the same
  // pass (a block is a few rows: rebuilding the triangles for each cost temple's pass several
  // percent). A new pass empties every slot, so nothing of another scene, time or G-buffer is
  // reused: no pixel has the background id.
  thread_local std::vector<TriangleCache> seen;
  thread_local uint64_t seen_pass = 0;
  if (vector_surfaces && (seen_pass != pass || seen.size() != size_t(1) << kSeenBits)) {
    seen.resize(size_t(1) << kSeenBits);
    for (TriangleCache& slot : seen) slot.id = kBackgroundId;
    seen_pass = pass;
  }
  alignas(64) float u0[kChunk], u1[kChunk], dx[kChunk], dy[kChunk], dz[kChunk], tfar[kChunk];
  alignas(64) bool ok[kChunk];
  constexpr float kInf = std::numeric_limits<float>::infinity();
  for (int y = y0; y < y1; ++y) {
    // A packet holds one row's rays: the rows of a block (TBB's choice, as the threads run) must
    // not decide which rays share a packet (Embree can answer a ray on an edge differently in
    // another packet; TraceBits.CountsDoNotDependOnRowBlocks).
    batch.flush();
    if (rows_out) batch.record = pair_batch.record = &(*rows_out)[size_t(y)];
    // Stage 1: surfaces.
    bool any = false;
#if DHR_TRACE_X86_KERNELS
    if (vector_surfaces) {
      // Triangles and G-buffer values by pixel here, the points and origins in surfaces_x16 (or
      // surfaces_x8); what it cannot do (unresolved ids, triangles whose own error needs the
      // per-pixel test, normals oriented by the camera) surface_at does, with the same cache.
      const auto set = [&](size_t i, const Surface& s) {
        r.covered[i] = 1;
        r.px[i] = s.p.x, r.py[i] = s.p.y, r.pz[i] = s.p.z;
        r.nx[i] = s.n.x, r.ny[i] = s.n.y, r.nz[i] = s.n.z;
        r.ox[i] = s.origin.x, r.oy[i] = s.origin.y, r.oz[i] = s.origin.z;
        r.origin_ok[i] = origin_valid(s.origin) ? 1 : 0;
      };
      {
        // Plain restrict pointers (this block only, every access through them): through the
        // vectors' members the compiler reloads every data pointer after each byte store.
        const uint32_t* __restrict ids = &g.object_id(0, y);
        const uint32_t* __restrict prims = &g.prim_id(0, y);
        const glm::vec2* __restrict bary = &g.bary(0, y);
        const glm::vec3* __restrict gnorm = &g.geo_normal(0, y);
        uint8_t* __restrict kind = r.kind.data();
        uint8_t* __restrict covered = r.covered.data();
        uint8_t* __restrict origin_ok = r.origin_ok.data();
        int* __restrict tri_of = r.tri_of.data();
        float* __restrict b1 = r.b1.data();
        float* __restrict b2 = r.b2.data();
        float* __restrict gx = r.gx.data();
        float* __restrict gy = r.gy.data();
        float* __restrict gz = r.gz.data();
        float* const __restrict planes[9] = {r.px.data(), r.py.data(), r.pz.data(), r.nx.data(), r.ny.data(),
                                             r.nz.data(), r.ox.data(), r.oy.data(), r.oz.data()};
        const auto set_here = [&](size_t i, const Surface& sf) {
          covered[i] = 1;
          const float v[9] = {sf.p.x, sf.p.y, sf.p.z, sf.n.x, sf.n.y, sf.n.z, sf.origin.x, sf.origin.y, sf.origin.z};
          for (int k = 0; k < 9; ++k) planes[k][i] = v[k];
          origin_ok[i] = origin_valid(sf.origin) ? 1 : 0;
        };
        RowTriangles tri{&rt, seen.data(), &r};
#if DHR_TRACE_X86_KERNELS
        const SurfaceInputs io{ids, prims, bary, gnorm, kind, covered, origin_ok, tri_of, b1, b2, gx, gy, gz, planes};
        int scalar_until = 0;  // the block surface_inputs_x16 left last, done here pixel by pixel
#endif
        for (int x = 0; x < w; ++x) {
#if DHR_TRACE_X86_KERNELS
          // 16 pixels at a time while their triangles are resolved.
          if (x16 && x >= scalar_until) {
            const uint64_t before = cov;
            x = surface_inputs_x16(io, x, w, tri, cov);
            any = any || cov != before;
            scalar_until = x + 16;
            if (x >= w) break;
          }
#endif
          const size_t i = size_t(x);
          const uint32_t id = ids[i];
          if (id == kBackgroundId) {  // as surface_at's Surface{}: zeros, a valid origin
            kind[i] = 0;
            covered[i] = 0;
            for (float* plane : planes) plane[i] = 0.0f;
            origin_ok[i] = 1;
            continue;
          }
          ++cov;
          any = true;
          const uint32_t prim = prims[i];
          // Rebuilt triangles are kept by (id, prim) (direct-mapped): the next rows mostly see
          // the same ones. A rebuild gives the same values, so this changes no bit.
          if (!tri.tc || id != tri.tc->id || prim != tri.tc->prim) select_triangle(tri, id, prim);
          if (!tri.tc->resolved) {
            Surface s;
            TriangleCache c = *tri.tc;
            surface_at(rt, g, x, y, s, unres, c);  // c holds the triangle: no rebuild
            set_here(i, s);
            kind[i] = 2;
            continue;
          }
          if (tri.cur < 0) add_row_triangle(tri);
          kind[i] = 1;
          tri_of[i] = tri.cur;
          b1[i] = bary[i].x, b2[i] = bary[i].y;
          gx[i] = gnorm[i].x, gy[i] = gnorm[i].y, gz[i] = gnorm[i].z;
        }
      }
      if (x16)
        surfaces_x16(r, settings, size_t(y) * size_t(w), any_soft);
      else
        surfaces_x8(r, settings, size_t(y) * size_t(w), any_soft);
      for (int x = 0; x < w; ++x) {
        if (r.kind[size_t(x)] != 3) continue;
        Surface s;
        surface_at(rt, g, x, y, s, unres, cache);  // rebuilds the pixel's triangle
        set(size_t(x), s);
      }
    }
#endif
    for (int x = 0; x < w && !vector_surfaces; ++x) {
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
      if (li.soft && one_sample)
        uniforms_pixels(r.h.data(), w, 0, kStreamLightBase + uint32_t(l), r.u0.data(), r.u1.data());
      if (li.sphere) sphere_light_row(r, li, size_t(l) * size_t(w), one_sample, x16);
#if DHR_TRACE_X86_KERNELS
      else if (x16 && one_sample)
        distant_light_row_x16(r, li, size_t(l) * size_t(w));
#endif
      else
        distant_light_row(r, li, size_t(l) * size_t(w), one_sample);
    }
    // Stage 3: answers and rays in pixel order (pixel, light, sample).
#if DHR_TRACE_X86_KERNELS
    if (all_single && (W == 16 ? x16 : x8)) {
      // The pairs that trace, listed; trace_pairs_x16 or trace_pairs_x8 makes the packets.
      int n = 0;
      if constexpr (W == 16) {
        if (nl <= kListPairsMaxLights) {
          PairTally tally;
          n = list_pairs_x16(r, nl, &out.visible[size_t(y) * size_t(w)], npx, tally);
          range += tally.range, inside += tally.inside, facing += tally.facing, invalid += tally.invalid;
          trace_pairs_x16(r, n, batch);
          continue;
        }
      }
      for (int x = 0; x < w; ++x) {
        if (!r.covered[size_t(x)]) continue;
        const size_t pixel = size_t(y) * size_t(w) + size_t(x);
        for (int l = 0; l < nl; ++l) {
          const size_t i = size_t(l) * size_t(w) + size_t(x);
          uint16_t* count = &out.visible[size_t(l) * npx + pixel];
          switch (r.code[i]) {
            case kPairRange: ++range; continue;
            case kPairInside: *count = 1, ++inside; continue;
            case kPairFacing: ++facing; continue;
            default: break;
          }
          if (r.ok[i]) {
            list_pair(r, n++, size_t(x), i, count);
          } else {
            ++invalid;
            ++*count;
          }
        }
      }
      if constexpr (W == 16)
        trace_pairs_x16(r, n, batch);
      else
        trace_pairs_x8(r, n, batch);
      continue;
    }
#endif
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
        uint32_t shift0 = 0, shift1 = 0;
        if (settings.lattice) lattice_shift(r.h[size_t(x)], stream, shift0, shift1);
#if DHR_TRACE_X86_KERNELS
        if (W == 16 ? x16 : x8) {
          SoftPair pair{origin,  origin_ok, r.h[size_t(x)],           stream, li.samples, tb, bb, w_dir,
                        omc_max, li.sphere, glm::vec3(ocx, ocy, ocz), r2,     count};
          pair.lattice = settings.lattice;
          pair.shift0 = shift0, pair.shift1 = shift1;
          if constexpr (W == 16)
            soft_pair_rays_x16(pair, batch, invalid);
          else
            soft_pair_rays_x8(pair, batch, invalid);
          continue;
        }
#endif
        for (int k0 = 0; k0 < li.samples; k0 += kChunk) {
          const int n = std::min(kChunk, li.samples - k0);
          if (settings.lattice)
            lattice_chunk(shift0, shift1, uint32_t(k0), u0, u1);
          else
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
              pair_batch.push(origin, dx[j], dy[j], dz[j], tfar[j], count);
            } else {
              ++invalid;
              ++*count;
            }
            // Packets of the pair's samples W at a time, as soft_pair_rays_x16 and _x8 trace
            // them: the same rays share a packet in every kernel.
            if ((k0 + j + 1) % W == 0) pair_batch.flush();
          }
        }
        pair_batch.flush();
      }
    }
  }
  batch.flush();
  if (rows_out)
    for (int y = y0; y < y1; ++y) batch.traced += (*rows_out)[size_t(y)].size();
  st.shadow_rays = batch.traced + pair_batch.traced;
  st.invalid_rays = invalid;
  st.unresolved_pixels = unres;
  st.shadow_skipped_facing = facing;
  st.shadow_skipped_range = range;
  st.shadow_inside_light = inside;
  st.covered_pixels = cov;
}

// The baseline AO kernel's stage 2 (ao_rows_compacted<W> with this as rays_fn): each compacted
// pixel's rays in chunks (uniforms_chunk, cosine_dirs_chunk) pushed into the Batch's packets.
template <int W>
void ao_rays_baseline(const AoPixels& px, int rays, float radius_m, Batch<W>& batch) {
  alignas(64) float u0[kChunk], u1[kChunk], dx[kChunk], dy[kChunk], dz[kChunk];
  for (int i = 0; i < px.n; ++i) {
    const auto at = [&](int k) { return px.c[size_t(k)][size_t(i)]; };
    const glm::vec3 origin(at(AoPixels::kOx), at(AoPixels::kOy), at(AoPixels::kOz));
    const glm::vec3 t(at(AoPixels::kTx), at(AoPixels::kTy), at(AoPixels::kTz));
    const glm::vec3 b(at(AoPixels::kBx), at(AoPixels::kBy), at(AoPixels::kBz));
    const glm::vec3 n(at(AoPixels::kNx), at(AoPixels::kNy), at(AoPixels::kNz));
    for (int k0 = 0; k0 < rays; k0 += kChunk) {
      const int m = std::min(kChunk, rays - k0);
      if (px.lattice)
        lattice_chunk(px.shift0[size_t(i)], px.shift1[size_t(i)], uint32_t(k0), u0, u1);
      else
        uniforms_chunk(px.h[size_t(i)], uint32_t(k0), kStreamAo, u0, u1);
      cosine_dirs_chunk(t, b, n, u0, u1, dx, dy, dz);
      // tfar = r: "occluded if anything is hit within r", never trace further.
      batch.push_chunk(origin, dx, dy, dz, radius_m, m, px.count[size_t(i)]);
    }
  }
}

// The AO rows: stage 1 gathers the row's tracing pixels (scalar: surface, basis, validation,
// hash), stage 2 (rays_fn: ao_rays_baseline, ao_rays_x16 on AVX-512, ao_rays_x8 on AVX2) makes
// and traces their rays.
template <int W>
void ao_rows_compacted(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                       AoCounts& out, std::vector<std::vector<RTCRay>>* rows_out, int y0, int y1, TraceStats& st,
                       AoRaysFn<W> rays_fn) {
  const int w = g.width();
  Batch<W> batch(rt.handle(), kMaskAll);
  TriangleCache cache;
  AoPixels px(w);
  px.lattice = settings.lattice;
  uint64_t invalid = 0, unres = 0, cov = 0;
  for (int y = y0; y < y1; ++y) {
    batch.flush();  // one row's rays per packet, as visibility_rows
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
      if (px.lattice) lattice_shift(px.h[i], kStreamAo, px.shift0[i], px.shift1[i]);
      px.count[i] = count;
    }
    rays_fn(px, ao_rays, radius_m, batch);
  }
  batch.flush();  // the baseline kernel's last packet
  if (rows_out)
    for (int y = y0; y < y1; ++y) batch.traced += (*rows_out)[size_t(y)].size();
  st.ao_rays = batch.traced;
  st.invalid_rays = invalid;
  st.unresolved_pixels = unres;
  st.covered_pixels = cov;
}

template void visibility_rows<8>(RtScene&, const GBuffer&, const TraceSettings&, const std::vector<LightInfo>&,
                                 uint64_t, VisibilityCounts&, std::vector<std::vector<RTCRay>>*, int, int, TraceStats&);
template void visibility_rows<16>(RtScene&, const GBuffer&, const TraceSettings&, const std::vector<LightInfo>&,
                                  uint64_t, VisibilityCounts&, std::vector<std::vector<RTCRay>>*, int, int,
                                  TraceStats&);
template void ao_rays_baseline<8>(const AoPixels&, int, float, Batch<8>&);
template void ao_rays_baseline<16>(const AoPixels&, int, float, Batch<16>&);
template void ao_rows_compacted<8>(RtScene&, const GBuffer&, int, float, const TraceSettings&, AoCounts&,
                                   std::vector<std::vector<RTCRay>>*, int, int, TraceStats&, AoRaysFn<8>);
template void ao_rows_compacted<16>(RtScene&, const GBuffer&, int, float, const TraceSettings&, AoCounts&,
                                    std::vector<std::vector<RTCRay>>*, int, int, TraceStats&, AoRaysFn<16>);

}  // namespace dhr::trace_detail
