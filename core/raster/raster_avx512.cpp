// The rasterizer's AVX-512 kernels (core/raster/raster_detail.h), chosen at run time on a CPU with
// AVX-512F/DQ (Context::wide_kernels; core/raster/raster.cpp keeps the scalar code for other CPUs and
// under DHR_MAX_ISA):
// - cover_row_x8: cover()'s loop over a covered row span, 8 pixels at a time;
// - resolve_x8: resolve() of up to 8 neighbouring pixels of a tile row with the same nearest
//   triangle. The doubles of the barycentrics and the position are in one 512-bit register, the
//   floats in 256-bit ones.
// Every lane takes the scalar code's operations in its order and precision (no FMA:
// DHR_AVX512_TARGET), so the G-buffer has the same bits (tests/core/raster/test_raster_bits.cpp, also under
// DHR_MAX_ISA=avx2 for the scalar code). docs/performance.md has the measurements.
//
// Only the functions marked DHR_AVX512_TARGET are compiled for AVX-512 (core/base/avx512.h).
#include "core/raster/raster_detail.h"

#include <algorithm>
#include <cmath>

#if DHR_AVX512_KERNELS

namespace dhr::raster_detail {

namespace {

// (r.x * px + r.y * py) + r.z, as cover() and barycentrics() evaluate a plane
// (1/W and the barycentrics), for 8 pixels of a row.
DHR_AVX512_TARGET inline __m512d plane_x8(const glm::dvec3& r, __m512d px, double py) {
  return _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(_mm512_set1_pd(r.x), px), _mm512_set1_pd(r.y * py)),
                       _mm512_set1_pd(r.z));
}

// The centres x + 0.5 .. x + 7.5 of 8 pixels of a row (exact in double).
DHR_AVX512_TARGET inline __m512d pixel_centres_x8(int x) {
  return _mm512_add_pd(_mm512_set1_pd(double(x) + 0.5), _mm512_set_pd(7, 6, 5, 4, 3, 2, 1, 0));
}

// Where element j of 8 interleaved vec3 (24 floats) or vec2 (16) comes from: the x lanes are
// indices 0-7 of the first table, y 8-15, z 16-23 (the second operand).
struct Interleave8 {
  alignas(64) int32_t v3_lo[16];
  alignas(64) int32_t v3_hi[16];
  alignas(64) int32_t v2[16];
  constexpr Interleave8() : v3_lo{}, v3_hi{}, v2{} {
    for (int j = 0; j < 24; ++j) (j < 16 ? v3_lo[j] : v3_hi[j - 16]) = 8 * (j % 3) + j / 3;
    for (int j = 0; j < 16; ++j) v2[j] = 8 * (j % 2) + j / 2;
  }
};
constexpr Interleave8 kInterleave8{};

struct Vec3x8 {
  __m256 x, y, z;
};

// Lanes 0..n-1 of (x, y, z) to dst[0..n-1] as vec3.
DHR_AVX512_TARGET inline void store_vec3_x8(glm::vec3* dst, const Vec3x8& v, unsigned n) {
  const __m512 xy = _mm512_insertf32x8(_mm512_castps256_ps512(v.x), v.y, 1);
  const __m512 z = _mm512_insertf32x8(_mm512_castps256_ps512(v.z), v.z, 1);
  float* f = &dst->x;
  const unsigned count = 3 * n;
  _mm512_mask_storeu_ps(f, __mmask16(count >= 16 ? 0xffffu : (1u << count) - 1),
                        _mm512_permutex2var_ps(xy, _mm512_load_si512(kInterleave8.v3_lo), z));
  if (count > 16)
    _mm512_mask_storeu_ps(f + 16, __mmask16((1u << (count - 16)) - 1),
                          _mm512_permutex2var_ps(xy, _mm512_load_si512(kInterleave8.v3_hi), z));
}

DHR_AVX512_TARGET inline void store_vec2_x8(glm::vec2* dst, __m256 x, __m256 y, unsigned n) {
  const __m512 xy = _mm512_insertf32x8(_mm512_castps256_ps512(x), y, 1);
  _mm512_mask_storeu_ps(&dst->x, __mmask16((1u << (2 * n)) - 1),
                        _mm512_permutexvar_ps(_mm512_load_si512(kInterleave8.v2), xy));
}

// (b0 a0 + b1 a1) + b2 a2 of one coordinate, in double (the position) or float (the rest).
DHR_AVX512_TARGET inline __m512d blend3_pd(double a0, double a1, double a2, __m512d b0, __m512d b1, __m512d b2) {
  return _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(_mm512_set1_pd(a0), b0), _mm512_mul_pd(_mm512_set1_pd(a1), b1)),
                       _mm512_mul_pd(_mm512_set1_pd(a2), b2));
}
DHR_AVX512_TARGET inline __m256 blend3_ps(float a0, float a1, float a2, __m256 b0, __m256 b1, __m256 b2) {
  return _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(b0, _mm256_set1_ps(a0)), _mm256_mul_ps(b1, _mm256_set1_ps(a1))),
                       _mm256_mul_ps(b2, _mm256_set1_ps(a2)));
}

// glm::dot(a, v): (a.x v.x + a.y v.y) + a.z v.z.
DHR_AVX512_TARGET inline __m256 dot_x8(const Vec3x8& a, const Vec3x8& v) {
  return _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(a.x, v.x), _mm256_mul_ps(a.y, v.y)), _mm256_mul_ps(a.z, v.z));
}
DHR_AVX512_TARGET inline Vec3x8 broadcast_x8(const glm::vec3& v) {
  return {_mm256_set1_ps(v.x), _mm256_set1_ps(v.y), _mm256_set1_ps(v.z)};
}
DHR_AVX512_TARGET inline Vec3x8 sub_x8(const Vec3x8& a, const Vec3x8& b) {
  return {_mm256_sub_ps(a.x, b.x), _mm256_sub_ps(a.y, b.y), _mm256_sub_ps(a.z, b.z)};
}
// -v in the lanes of `flip` (all ones or zero), v elsewhere.
DHR_AVX512_TARGET inline Vec3x8 negate_where_x8(const Vec3x8& v, __m256 flip) {
  const __m256 sign = _mm256_and_ps(flip, _mm256_set1_ps(-0.0f));
  return {_mm256_xor_ps(v.x, sign), _mm256_xor_ps(v.y, sign), _mm256_xor_ps(v.z, sign)};
}
DHR_AVX512_TARGET inline Vec3x8 select_x8(const Vec3x8& a, const Vec3x8& b, __m256 take_b) {
  return {_mm256_blendv_ps(a.x, b.x, take_b), _mm256_blendv_ps(a.y, b.y, take_b), _mm256_blendv_ps(a.z, b.z, take_b)};
}
// The motion offset of resolve(): clamped to +-kMaxMotionPx, infinities to their sign, NaN to -.
DHR_AVX512_TARGET inline __m256 motion_offset_x8(__m256 v) {
  const __m256 hi = _mm256_set1_ps(kMaxMotionPx), lo = _mm256_set1_ps(-kMaxMotionPx);
  __m256 r = _mm256_blendv_ps(v, hi, _mm256_cmp_ps(v, hi, _CMP_GT_OQ));
  r = _mm256_blendv_ps(r, lo, _mm256_cmp_ps(v, lo, _CMP_LT_OQ));
  return _mm256_blendv_ps(r, lo, _mm256_cmp_ps(v, v, _CMP_UNORD_Q));
}

// The texture wrap of an index within [-size, 2 size).
DHR_AVX512_TARGET inline __m256i wrap_x8(__m256i i, __m256i size) {
  const __m256i below = _mm256_cmpgt_epi32(_mm256_setzero_si256(), i);
  const __m256i above = _mm256_cmpgt_epi32(i, _mm256_sub_epi32(size, _mm256_set1_epi32(1)));
  return _mm256_sub_epi32(_mm256_add_epi32(i, _mm256_and_si256(below, size)), _mm256_and_si256(above, size));
}

// Texture::sample_bilinear's linear RGB (core/scene/scene.cpp) at 8 points, with its operations in its
// order: 4 texels gathered per lane, their sRGB codes looked up in the same table. Returns false
// (nothing written) where the scalar lookup must run instead: a texture it would reject, one
// with too many texels for 32-bit indices, or a lane whose texel lies more than one texture
// size outside the texture (the scalar wrap's modulo; a coordinate wrapped into [0, 1] never
// does). Lanes n..7 give 0.
DHR_AVX512_TARGET bool texture_rgb_x8(const Texture& tex, __m256 u, __m256 v, unsigned n, Vec3x8& rgb) {
  const int w = tex.width, h = tex.height;
  if (w <= 0 || h <= 0 || tex.texels.size() != size_t(w) * size_t(h) || tex.texels.size() > size_t(1) << 30)
    return false;
  const __m256 inf = _mm256_set1_ps(INFINITY), sign = _mm256_set1_ps(-0.0f);
  const __m256i live = _mm256_cmpgt_epi32(_mm256_set1_epi32(int(n)), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
  const __m256 use = _mm256_and_ps(_mm256_castsi256_ps(live),
                                   _mm256_and_ps(_mm256_cmp_ps(_mm256_andnot_ps(sign, u), inf, _CMP_LT_OQ),
                                                 _mm256_cmp_ps(_mm256_andnot_ps(sign, v), inf, _CMP_LT_OQ)));
  const __m256 half = _mm256_set1_ps(0.5f);
  const __m256 x = _mm256_sub_ps(_mm256_mul_ps(_mm256_sub_ps(u, _mm256_floor_ps(u)), _mm256_set1_ps(float(w))), half);
  const __m256 y =
      _mm256_sub_ps(_mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(1.0f), _mm256_sub_ps(v, _mm256_floor_ps(v))),
                                  _mm256_set1_ps(float(h))),
                    half);
  const __m256 fx = _mm256_floor_ps(x), fy = _mm256_floor_ps(y);
  const __m256 wx = _mm256_sub_ps(x, fx), wy = _mm256_sub_ps(y, fy);
  // Integral floats in range convert exactly; unused lanes take texel (0, 0).
  const __m256i ix = _mm256_and_si256(_mm256_cvttps_epi32(fx), _mm256_castps_si256(use));
  const __m256i iy = _mm256_and_si256(_mm256_cvttps_epi32(fy), _mm256_castps_si256(use));
  const __m256i W = _mm256_set1_epi32(w), H = _mm256_set1_epi32(h), one = _mm256_set1_epi32(1);
  // ix and ix + 1 within [-w, 2w): ix >= -w and ix + 1 < 2w, likewise iy.
  const __m256i out_of_reach = _mm256_or_si256(
      _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(_mm256_setzero_si256(), W), ix),
                      _mm256_cmpgt_epi32(_mm256_add_epi32(ix, one), _mm256_sub_epi32(_mm256_add_epi32(W, W), one))),
      _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(_mm256_setzero_si256(), H), iy),
                      _mm256_cmpgt_epi32(_mm256_add_epi32(iy, one), _mm256_sub_epi32(_mm256_add_epi32(H, H), one))));
  if (!_mm256_testz_si256(out_of_reach, out_of_reach)) return false;
  const __m256i x0 = wrap_x8(ix, W), x1 = wrap_x8(_mm256_add_epi32(ix, one), W);
  const __m256i y0 = wrap_x8(iy, H), y1 = wrap_x8(_mm256_add_epi32(iy, one), H);
  const int* texels = reinterpret_cast<const int*>(tex.texels.data());
  const float* lut = srgb_table().data();
  const __m256i row0 = _mm256_mullo_epi32(y0, W), row1 = _mm256_mullo_epi32(y1, W);
  const __m256i t00 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row0, x0), 4);
  const __m256i t10 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row0, x1), 4);
  const __m256i t01 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row1, x0), 4);
  const __m256i t11 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row1, x1), 4);
  const __m256 one_f = _mm256_set1_ps(1.0f);
  const __m256 ax = _mm256_sub_ps(one_f, wx), ay = _mm256_sub_ps(one_f, wy);
  __m256 c[3];
  for (int k = 0; k < 3; ++k) {
    const __m256i byte = _mm256_set1_epi32(0xff);
    const __m256 c00 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t00, 8 * k), byte), 4);
    const __m256 c10 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t10, 8 * k), byte), 4);
    const __m256 c01 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t01, 8 * k), byte), 4);
    const __m256 c11 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t11, 8 * k), byte), 4);
    // glm::mix(a, b, t) = a (1 - t) + b t, along x in both rows, then along y.
    const __m256 r0 = _mm256_add_ps(_mm256_mul_ps(c00, ax), _mm256_mul_ps(c10, wx));
    const __m256 r1 = _mm256_add_ps(_mm256_mul_ps(c01, ax), _mm256_mul_ps(c11, wx));
    c[k] = _mm256_and_ps(_mm256_add_ps(_mm256_mul_ps(r0, ay), _mm256_mul_ps(r1, wy)), use);
  }
  rgb = {c[0], c[1], c[2]};
  return true;
}

// m * v of a glm::mat3 (m[0][r] v.x + m[1][r] v.y) + m[2][r] v.z, as glm evaluates it.
DHR_AVX512_TARGET inline Vec3x8 mat3_x8(const glm::mat3& m, const Vec3x8& v) {
  __m256 r[3];
  for (int k = 0; k < 3; ++k)
    r[k] = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(m[0][k]), v.x), _mm256_mul_ps(_mm256_set1_ps(m[1][k]), v.y)),
        _mm256_mul_ps(_mm256_set1_ps(m[2][k]), v.z));
  return {r[0], r[1], r[2]};
}

// The xyz of m * vec4(v, 1) of a glm::mat4: (m[0][r] v.x + m[1][r] v.y) + (m[2][r] v.z + m[3][r] 1),
// as glm evaluates it.
DHR_AVX512_TARGET inline Vec3x8 point_x8(const glm::mat4& m, const Vec3x8& v) {
  __m256 r[3];
  for (int k = 0; k < 3; ++k)
    r[k] = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(m[0][k]), v.x), _mm256_mul_ps(_mm256_set1_ps(m[1][k]), v.y)),
        _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(m[2][k]), v.z),
                      _mm256_mul_ps(_mm256_set1_ps(m[3][k]), _mm256_set1_ps(1.0f))));
  return {r[0], r[1], r[2]};
}

}  // namespace

// cover()'s loop over the pixels xa..xb of row y, 8 at a time (AVX-512), for a triangle without
// alpha cut-out: the same edge tests on the same 64-bit values, the same 1/W in double and the
// same depth test, whose exact ties are settled lane by lane as cover() settles them. e_a holds
// the three edge functions at xa.
DHR_AVX512_TARGET void cover_row_x8(const Context& ctx, const CoverTri& c, int y, int xa, int xb, const int64_t* e_a,
                                    const int64_t* step_x, int X0, int Y0, TileScratch& s, uint32_t& sid,
                                    uint64_t& fragments) {
  const ObjectPrep& p = ctx.objects[c.object];
  const double py = y + 0.5;
  const __m512i iota = _mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0);
  __m512i e[3], step8[3];
  for (int k = 0; k < 3; ++k) {
    e[k] = _mm512_add_epi64(_mm512_set1_epi64(e_a[k]), _mm512_mullo_epi64(iota, _mm512_set1_epi64(step_x[k])));
    step8[k] = _mm512_set1_epi64(8 * step_x[k]);
  }
  for (int x = xa; x <= xb; x += 8) {
    const unsigned n = unsigned(std::min(8, xb - x + 1));
    __mmask8 m = _mm512_mask_cmpge_epi64_mask(
        __mmask8((1u << n) - 1), _mm512_or_si512(_mm512_or_si512(e[0], e[1]), e[2]), _mm512_setzero_si512());
    for (int k = 0; k < 3; ++k) e[k] = _mm512_add_epi64(e[k], step8[k]);
    if (!m) continue;
    fragments += uint64_t(__builtin_popcount(m));
    if (sid == kNoSetup) sid = tile_setup(ctx, c, s);
    const Setup& st = s.setups[sid];
    const __m512d px = pixel_centres_x8(x);
    __m512d iw = plane_x8(st.rs, px, py);
    iw = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(iw, _mm512_set1_pd(st.iw_lo), _CMP_GE_OQ), _mm512_set1_pd(st.iw_lo),
                              iw);
    iw = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(iw, _mm512_set1_pd(st.iw_hi), _CMP_LE_OQ), _mm512_set1_pd(st.iw_hi),
                              iw);
    m &= _mm512_cmp_pd_mask(iw, _mm512_set1_pd(ctx.inv_far), _CMP_NLT_UQ);  // not beyond the far plane
    const size_t k0 = size_t((y - Y0) * kTile + (x - X0));
    const __m512d cur = _mm512_maskz_loadu_pd(m, &s.inv_w[k0]);
    m &= _mm512_cmp_pd_mask(iw, cur, _CMP_NLT_UQ);
    if (!m) continue;
    __mmask8 win = m & ~_mm512_cmp_pd_mask(iw, cur, _CMP_EQ_OQ);
    if (__mmask8 tie = __mmask8(m & ~win)) {  // exact ties: the smaller (object id, prim id) wins
      for (unsigned i = 0; i < n; ++i)
        if (tie & (1u << i)) {
          const Setup& o = s.setups[s.setup[k0 + i]];
          const uint32_t id = p.object->id, other = ctx.objects[o.object].object->id;
          if (id < other || (id == other && st.prim < o.prim)) win = __mmask8(win | (1u << i));
        }
    }
    _mm512_mask_storeu_pd(&s.inv_w[k0], win, iw);
    _mm512_mask_storeu_epi32(&s.setup[k0], __mmask16(win), _mm512_set1_epi32(int(sid)));
  }
}

// resolve() of pixels x .. x + n - 1 (n in 1..8) of row y, all of whose nearest fragment is
// `st`.
DHR_AVX512_TARGET void resolve_x8(const Context& ctx, const Setup& st, int x, int y, unsigned n, GBuffer& out) {
  const ObjectPrep& p = ctx.objects[st.object];
  const Mesh& mesh = *p.mesh;
  const glm::uvec3 t = st.tri;
  const Camera& cam = *ctx.camera;
  const __mmask8 live = __mmask8((1u << n) - 1);
  const __m512d px = pixel_centres_x8(x);
  const double py = y + 0.5;

  // barycentrics(), with its clamp taken lane by lane where a lane needs it (rare).
  const __m512d inv_us = _mm512_div_pd(_mm512_set1_pd(1.0), plane_x8(st.rs, px, py));
  __m512d b1 = _mm512_mul_pd(plane_x8(st.r1, px, py), inv_us);
  __m512d b2 = _mm512_mul_pd(plane_x8(st.r2, px, py), inv_us);
  __m512d b0 = _mm512_sub_pd(_mm512_sub_pd(_mm512_set1_pd(1.0), b1), b2);
  const __m512d zero = _mm512_setzero_pd();
  const __mmask8 inside = _mm512_cmp_pd_mask(b0, zero, _CMP_GE_OQ) & _mm512_cmp_pd_mask(b1, zero, _CMP_GE_OQ) &
                          _mm512_cmp_pd_mask(b2, zero, _CMP_GE_OQ);
  if (__mmask8 clamp = __mmask8(live & ~inside)) {
    alignas(64) double a0[8], a1[8], a2[8];
    _mm512_store_pd(a0, b0);
    _mm512_store_pd(a1, b1);
    _mm512_store_pd(a2, b2);
    for (unsigned i = 0; i < n; ++i)
      if (clamp & (1u << i)) {
        const glm::dvec3 b = barycentrics(st, double(x + int(i)) + 0.5, py);
        a0[i] = b.x, a1[i] = b.y, a2[i] = b.z;
      }
    b0 = _mm512_load_pd(a0), b1 = _mm512_load_pd(a1), b2 = _mm512_load_pd(a2);
  }

  const Vec3x8 pos{_mm512_cvtpd_ps(blend3_pd(st.v[0].x, st.v[1].x, st.v[2].x, b0, b1, b2)),
                   _mm512_cvtpd_ps(blend3_pd(st.v[0].y, st.v[1].y, st.v[2].y, b0, b1, b2)),
                   _mm512_cvtpd_ps(blend3_pd(st.v[0].z, st.v[1].z, st.v[2].z, b0, b1, b2))};
  const Vec3x8 to_cam = sub_x8(broadcast_x8(cam.position), pos);

  const glm::vec3 ng0 =
      st.geo_normal.x != 0.0f || st.geo_normal.y != 0.0f || st.geo_normal.z != 0.0f ? st.geo_normal : -cam.forward;
  const Vec3x8 ng0x8 = broadcast_x8(ng0);
  const __m256 zero_ps = _mm256_setzero_ps();
  const Vec3x8 ng = negate_where_x8(ng0x8, _mm256_cmp_ps(dot_x8(ng0x8, to_cam), zero_ps, _CMP_LT_OQ));
  Vec3x8 ns = ng;
  const __m256 bf0 = _mm512_cvtpd_ps(b0), bf1 = _mm512_cvtpd_ps(b1), bf2 = _mm512_cvtpd_ps(b2);
  if (!mesh.normals.empty()) {
    const glm::vec3 &n0 = mesh.normals[t.x], &n1 = mesh.normals[t.y], &n2 = mesh.normals[t.z];
    Vec3x8 nv{blend3_ps(n0.x, n1.x, n2.x, bf0, bf1, bf2), blend3_ps(n0.y, n1.y, n2.y, bf0, bf1, bf2),
              blend3_ps(n0.z, n1.z, n2.z, bf0, bf1, bf2)};
    if (p.moving) nv = mat3_x8(p.normal_matrix, nv);
    const __m256 len = _mm256_sqrt_ps(dot_x8(nv, nv));
    const __m256 ok = _mm256_and_ps(_mm256_cmp_ps(len, _mm256_set1_ps(1e-12f), _CMP_GT_OQ),
                                    _mm256_cmp_ps(len, _mm256_set1_ps(INFINITY), _CMP_LT_OQ));
    const Vec3x8 unit{_mm256_div_ps(nv.x, len), _mm256_div_ps(nv.y, len), _mm256_div_ps(nv.z, len)};
    const Vec3x8 facing = negate_where_x8(unit, _mm256_cmp_ps(dot_x8(unit, to_cam), zero_ps, _CMP_LT_OQ));
    ns = select_x8(ns, facing, ok);
  }

  Vec3x8 albedo = broadcast_x8(p.material->albedo);
  if (p.texture) {
    const glm::vec2 &u0 = mesh.uvs[t.x], &u1 = mesh.uvs[t.y], &u2 = mesh.uvs[t.z];
    const __m256 uu = blend3_ps(u0.x, u1.x, u2.x, bf0, bf1, bf2), vv = blend3_ps(u0.y, u1.y, u2.y, bf0, bf1, bf2);
    Vec3x8 rgb;
    if (texture_rgb_x8(*p.texture, uu, vv, n, rgb)) {
      albedo = {_mm256_mul_ps(albedo.x, rgb.x), _mm256_mul_ps(albedo.y, rgb.y), _mm256_mul_ps(albedo.z, rgb.z)};
    } else {
      alignas(32) float u[8], v[8], ax[8], ay[8], az[8];
      _mm256_store_ps(u, uu);
      _mm256_store_ps(v, vv);
      const glm::vec3 base = p.material->albedo;
      for (unsigned i = 0; i < 8; ++i) {
        const glm::vec4 tex = i < n ? p.texture->sample_bilinear({u[i], v[i]}) : glm::vec4(0.0f);
        ax[i] = base.x * tex.x, ay[i] = base.y * tex.y, az[i] = base.z * tex.z;
      }
      albedo = {_mm256_load_ps(ax), _mm256_load_ps(ay), _mm256_load_ps(az)};
    }
  }

  __m256 mx = zero_ps, my = zero_ps;
  if (!(p.static_motion && ctx.same_cameras)) {
    Vec3x8 prev = pos;
    if (!p.static_motion) {  // the same surface point, placed at prev_time_s
      const auto& o = mesh.positions;
      const glm::vec3 &o0 = o[t.x], &o1 = o[t.y], &o2 = o[t.z];
      const Vec3x8 obj{_mm512_cvtpd_ps(blend3_pd(o0.x, o1.x, o2.x, b0, b1, b2)),
                       _mm512_cvtpd_ps(blend3_pd(o0.y, o1.y, o2.y, b0, b1, b2)),
                       _mm512_cvtpd_ps(blend3_pd(o0.z, o1.z, o2.z, b0, b1, b2))};
      prev = point_x8(p.world_from_object_prev, obj);
    }
    const Projector& pp = ctx.prev_proj;
    const Vec3x8 d = sub_x8(prev, broadcast_x8(pp.position));
    const __m256 z = dot_x8(d, broadcast_x8(pp.forward));
    const __m256 tan_half = _mm256_set1_ps(pp.tan_half);
    const __m256 qx = _mm256_div_ps(dot_x8(d, broadcast_x8(pp.right)),
                                    _mm256_mul_ps(_mm256_mul_ps(z, tan_half), _mm256_set1_ps(pp.aspect)));
    const __m256 qy = _mm256_div_ps(dot_x8(d, broadcast_x8(pp.up)), _mm256_mul_ps(z, tan_half));
    const __m256 half = _mm256_set1_ps(0.5f), one = _mm256_set1_ps(1.0f);
    const __m256 sx = _mm256_mul_ps(_mm256_mul_ps(_mm256_add_ps(qx, one), half), _mm256_set1_ps(float(pp.width)));
    const __m256 sy = _mm256_mul_ps(_mm256_mul_ps(_mm256_sub_ps(one, qy), half), _mm256_set1_ps(float(pp.height)));
    const __m256 in_front = _mm256_cmp_ps(z, zero_ps, _CMP_GT_OQ);
    const __m256 behind = _mm256_set1_ps(-kMaxMotionPx);
    mx = _mm256_blendv_ps(
        behind,
        motion_offset_x8(_mm256_sub_ps(_mm256_mul_ps(sx, _mm256_set1_ps(ctx.motion_scale_x)), _mm512_cvtpd_ps(px))),
        in_front);
    my = _mm256_blendv_ps(behind,
                          motion_offset_x8(_mm256_sub_ps(_mm256_mul_ps(sy, _mm256_set1_ps(ctx.motion_scale_y)),
                                                         _mm256_set1_ps(float(py)))),
                          in_front);
  }

  const __mmask16 lanes = __mmask16(live);
  _mm512_mask_storeu_ps(
      &out.depth(x, y), lanes,
      _mm512_castps256_ps512(dot_x8(sub_x8(pos, broadcast_x8(cam.position)), broadcast_x8(cam.forward))));
  store_vec3_x8(&out.position(x, y), pos, n);
  store_vec3_x8(&out.normal(x, y), ns, n);
  store_vec3_x8(&out.geo_normal(x, y), ng, n);
  store_vec3_x8(&out.albedo(x, y), albedo, n);
  _mm512_mask_storeu_epi32(&out.object_id(x, y), lanes, _mm512_set1_epi32(int(p.object->id)));
  _mm512_mask_storeu_epi32(&out.prim_id(x, y), lanes, _mm512_set1_epi32(int(st.prim)));
  store_vec2_x8(&out.bary(x, y), bf1, bf2, n);
  store_vec2_x8(&out.motion(x, y), mx, my, n);
}

}  // namespace dhr::raster_detail

#endif  // DHR_AVX512_KERNELS
