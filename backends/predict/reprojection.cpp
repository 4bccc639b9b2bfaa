// reprojection: carries a lighting pass computed for an older client frame j to the frame k
// being displayed, through the client's own G-buffers of both frames (DHR-S paper, section
// 4.1, Fig. 5 against Fig. 6: each lighting pass is predicted for the current frame, so late
// buffers still land on the right surfaces). The validity tests (object id, depth, normal)
// are the reprojection tests of SVGF's temporal accumulation (Schied et al. 2017, section
// 4.1), which the paper's modified SVGF uses too (section 3.3).
//
// Method, per pixel of dst (frame k):
// - Background (object id kBackgroundId): fully lit (every light's bit, soft = full_scale,
//   AO = full_scale): nothing there is shaded, and it is not counted.
// - Covered: its world point P = dst.position is projected through src.camera (frame j's
//   camera) to the image point q and the view depth z. This is exact for static geometry under
//   any camera motion and any age j < k, the main case. For an object that moved between j
//   and k it is an approximation: q is where P's world position was seen in frame j, not
//   where the object's surface point was; the id/depth/normal tests then usually reject the
//   sample (another object or surface is there: a disocclusion, filled) or accept a nearby
//   part of the same object. Motion vectors are not used: dst.motion points to the frame
//   right before k, and the predictor is not told whether j = k - 1.
// - The 2x2 source taps around q (bilinear footprint, pixel centres at x + 0.5) are tested
//   against P: same object id; depth agreement, |d| <= depth_tolerance * z where d is P's
//   distance from the tap's surface plane (its world position and geometric normal; that is
//   the tap's depth extrapolated to q along its own surface, so a grazing surface does not
//   fail for a sub-pixel offset the way a plain |z_tap - z| test does; a tap without a usable
//   geometric normal falls back to |src.depth - z| <= depth_tolerance * z); normal
//   agreement, dot(n_src, n_dst) >= normal_threshold (shading normals). A tap with zero
//   bilinear weight or outside the image does not take part.
// - Visibility bitmasks take the valid tap of largest bilinear weight (the nearest valid one;
//   bits cannot be interpolated). SoftVisibility and Ao take the same tap (filter = nearest)
//   or the bilinear mean of the valid taps, renormalised and rounded (filter = bilinear).
// - No valid tap, q off-screen or behind the src camera, or a covered dst pixel with
//   non-finite data: a disocclusion (counted), filled by `fill`:
//     nearest_valid: the valid source pixel (same tests) nearest to q within a square window
//       of fill_radius_px; the local fallback when there is none;
//     local: the local fallback, fully lit (all bits set / soft = full_scale, AO = full_scale).
// Colour buffers are refused (the hybrid client never receives colour; the remote baseline
// uses rotation_warp). Sizes of received, src and dst must agree. Rows run in parallel with
// TBB; every pixel is computed on its own, so the result is bit-identical at any thread count.
// Where the CPU has AVX-512, 16 pixels at a time find their taps and write the passes
// (plan_x16, write_x16: the scalar code's operations in the same order, lane by lane; the taps'
// values loaded where they lie side by side, picked by permutes from 32 columns of the rows
// they lie on, or else gathered), and write the background lanes; the pixels they do not
// resolve take the scalar path. Same bytes (tests/backends/test_predictors.cpp:
// Reprojection.HardTapTestsKeepTheirBits, both paths; SameBytesOnTheVectorAndScalarPaths, each
// way of reading the taps); docs/performance.md has the measurements.
//
// Parameters: filter (nearest|bilinear, default bilinear), fill (nearest_valid|local, default
// nearest_valid), fill_radius_px (1..16, default 3), depth_tolerance (0.0001..1, default
// 0.02), normal_threshold (-1..1, default 0.9).
// Example: {"name": "reprojection", "params": {"filter": "nearest", "fill": "local"}}
#include "core/base/avx512.h"
#include "backends/predict/warp.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cstring>
#include <span>
#include <vector>

namespace dhr {
namespace {

constexpr const char* kName = "reprojection";

struct ReprojectionSettings {
  bool bilinear = true;
  bool fill_nearest_valid = true;
  int fill_radius_px = 3;
  float depth_tolerance = 0.02f;
  float normal_threshold = 0.9f;
};

void check_gbuffer(const char* which, const GBuffer& g) {
  const int w = g.width(), h = g.height();
  if (!g.position.same_size(w, h) || !g.normal.same_size(w, h) || !g.geo_normal.same_size(w, h) ||
      !g.object_id.same_size(w, h))
    fail(
        "predictor '{}': the {} G-buffer's planes differ in size (depth {}x{}, position {}x{}, normal {}x{}, "
        "geo_normal {}x{}, object_id {}x{})",
        kName, which, w, h, g.position.width(), g.position.height(), g.normal.width(), g.normal.height(),
        g.geo_normal.width(), g.geo_normal.height(), g.object_id.width(), g.object_id.height());
  predict::check_camera(kName, which, g.camera);
  if (g.camera.width != w || g.camera.height != h)
    fail("predictor '{}': the {} G-buffer is {}x{} but its camera is {}x{} (they must agree)", kName, which, w, h,
         g.camera.width, g.camera.height);
}

// The source side of one dst pixel for the passes that blend (8-bit, filter bilinear): the valid
// taps with their renormalised weights, in tap order.
struct Taps {
  uint32_t index[4] = {0, 0, 0, 0};
  float weight[4] = {0, 0, 0, 0};
  int count = 0;
};

// What the 16-lane kernel reads and how it tests (Reprojection::run's values).
struct PlanInputs {
  const uint32_t* sid;
  const glm::vec3 *snrm, *sgeo, *spos;
  const float* sdep;
  const uint32_t* did;
  const glm::vec3 *dpos, *dnrm;
  int w, h;
  predict::Projector proj;
  float thr2, tol, tol2;
  bool thr_nonneg, any_bilinear, any_nearest;
};

// The taps of 16 dst pixels that the kernel resolved, lane by lane: the source index of tap 0
// (tap k = j0 + (k & 1) + (k >> 1) w), bit k of `valid` when tap k has weight and passes the
// tests, the nearest passes' tap and the bilinear passes' renormalised weights (valid taps).
struct Plan16 {
  int32_t j0[16], valid[16], nearest[16];
  float weight[4][16];
  // Where the taps were read through a window (plan_x16): the index of its first pixel (row
  // y_lo, column xs) and each lane's tap 0 as a row (0 or 1) and column (0 .. 30) from there.
  bool window = false;
  size_t window_first = 0;
  int32_t window_row[16] = {}, window_col[16] = {};
  uint32_t background = 0;  // the lanes whose dst pixel is background
};

std::atomic<bool> g_scalar_only{false};

#if DHR_AVX512_KERNELS
// glm::dot's sum in its order, (x x' + y y') + z z', and the scalar code's comparisons (false
// on NaN, as there).
DHR_AVX512_TARGET inline __m512 dot16(__m512 ax, __m512 ay, __m512 az, __m512 bx, __m512 by, __m512 bz) {
  return _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(ax, bx), _mm512_mul_ps(ay, by)), _mm512_mul_ps(az, bz));
}
DHR_AVX512_TARGET inline __mmask16 ge16(__m512 a, float b) {
  return _mm512_cmp_ps_mask(a, _mm512_set1_ps(b), _CMP_GE_OQ);
}
DHR_AVX512_TARGET inline __mmask16 le16(__m512 a, float b) {
  return _mm512_cmp_ps_mask(a, _mm512_set1_ps(b), _CMP_LE_OQ);
}
DHR_AVX512_TARGET inline __mmask16 finite16(__m512 a) {
  return __mmask16(~_mm512_fpclass_ps_mask(a, 0x99));
}  // not NaN or +-inf
DHR_AVX512_TARGET inline __m512 gather16(__mmask16 m, __m512i index, const float* base) {
  return _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m, index, base, 4);
}

// Tap k's offset from tap 0 (the pixel right, below, below right): Plan16's layout.
inline int tap_offset(int k, int w) { return (k & 1) + (k >> 1) * w; }

// Whether tap 0 of lane l is lane 0's plus l for all 16 lanes (the taps lie side by side, as
// under smooth motion: a tap's 16 source values are then consecutive). lane0: lane 0's index.
DHR_AVX512_TARGET inline bool side_by_side16(__m512i j0, int32_t& lane0) {
  lane0 = _mm_cvtsi128_si32(_mm512_castsi512_si128(j0));
  const __m512i lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  return _mm512_cmpeq_epi32_mask(j0, _mm512_add_epi32(_mm512_set1_epi32(lane0), lane)) == 0xFFFF;
}

// x, y and z of 16 consecutive vec3 (core/base/avx512.h's load_xyz16).
DHR_AVX512_TARGET inline Xyz16 load_xyz16(const glm::vec3* v) {
  static_assert(sizeof(glm::vec3) == 3 * sizeof(float));
  return dhr::load_xyz16(&v->x);
}
// The same for lanes at any indices j (gathered; lanes outside m read nothing and hold 0).
DHR_AVX512_TARGET inline Xyz16 gather_xyz16(__mmask16 m, __m512i j, const glm::vec3* v) {
  const __m512i j3 = _mm512_mullo_epi32(j, _mm512_set1_epi32(3));
  const float* f = &v->x;
  return {gather16(m, j3, f), gather16(m, _mm512_add_epi32(j3, _mm512_set1_epi32(1)), f),
          gather16(m, _mm512_add_epi32(j3, _mm512_set1_epi32(2)), f)};
}

// The dst side of 16 lanes that a tap is tested against: object id, point, shading normal
// with its squared length, and the point's view depth in the src camera.
struct DstLanes {
  __m512i id;
  __m512 px, py, pz, nx, ny, nz, ln, z;
};

// One tap's source values in 16 lanes: object id, shading normal, geometric normal, position
// and depth.
struct TapValues16 {
  __m512i id;
  Xyz16 n, g, p;
  __m512 depth;
};

// valid_tap's tests of one tap in 16 lanes, in its order (so the same answers): lanes outside t
// (not in play, or the tap without weight) fail, whatever their values.
DHR_AVX512_TARGET inline __mmask16 tap_tests16(const TapValues16& s, __mmask16 t, const DstLanes& d,
                                               const PlanInputs& a) {
  t &= _mm512_cmpeq_epi32_mask(s.id, d.id);
  const __m512 ls = dot16(s.n.x, s.n.y, s.n.z, s.n.x, s.n.y, s.n.z);
  t &= ge16(ls, 0.25f) & le16(ls, 4.0f);
  const __m512 dn = dot16(s.n.x, s.n.y, s.n.z, d.nx, d.ny, d.nz);
  const __m512 bound = _mm512_mul_ps(_mm512_mul_ps(_mm512_set1_ps(a.thr2), ls), d.ln);
  const __m512 d2 = _mm512_mul_ps(dn, dn);
  const __mmask16 d_nonneg = ge16(dn, 0.0f);
  t &= a.thr_nonneg ? __mmask16(d_nonneg & _mm512_cmp_ps_mask(d2, bound, _CMP_GE_OQ))
                    : __mmask16(d_nonneg | _mm512_cmp_ps_mask(d2, bound, _CMP_LE_OQ));
  const __m512 lg = dot16(s.g.x, s.g.y, s.g.z, s.g.x, s.g.y, s.g.z);
  const __mmask16 has_plane = ge16(lg, 0.25f) & le16(lg, 4.0f);
  const __m512 ex = _mm512_sub_ps(d.px, s.p.x), ey = _mm512_sub_ps(d.py, s.p.y), ez = _mm512_sub_ps(d.pz, s.p.z);
  const __m512 e = dot16(ex, ey, ez, s.g.x, s.g.y, s.g.z);
  const __mmask16 plane =
      _mm512_cmp_ps_mask(_mm512_mul_ps(e, e),
                         _mm512_mul_ps(_mm512_mul_ps(_mm512_mul_ps(_mm512_set1_ps(a.tol2), d.z), d.z), lg), _CMP_LE_OQ);
  const __m512 adz = _mm512_abs_ps(_mm512_sub_ps(s.depth, d.z));
  const __mmask16 depth = _mm512_cmp_ps_mask(adz, _mm512_mul_ps(_mm512_set1_ps(a.tol), d.z), _CMP_LE_OQ);
  return t & ((has_plane & plane) | (~has_plane & depth));
}

// The values of 16 consecutive source pixels from index j.
DHR_AVX512_TARGET inline TapValues16 load_taps16(const PlanInputs& a, size_t j) {
  return {_mm512_loadu_si512(a.sid + j), load_xyz16(a.snrm + j), load_xyz16(a.sgeo + j), load_xyz16(a.spos + j),
          _mm512_loadu_ps(a.sdep + j)};
}

// The values of the source pixels at indices j, for the lanes in m (the others hold 0).
DHR_AVX512_TARGET inline TapValues16 gather_taps16(const PlanInputs& a, __mmask16 m, __m512i j) {
  return {_mm512_mask_i32gather_epi32(_mm512_setzero_si512(), m, j, a.sid, 4), gather_xyz16(m, j, a.snrm),
          gather_xyz16(m, j, a.sgeo), gather_xyz16(m, j, a.spos), gather16(m, j, a.sdep)};
}

// 32 consecutive source pixels (from index j): each value as two registers of 16.
struct Window32 {
  TapValues16 lo, hi;
};
DHR_AVX512_TARGET inline Window32 load_window32(const PlanInputs& a, size_t j) {
  return {load_taps16(a, j), load_taps16(a, j + 16)};
}

// Lane l takes the window's pixel idx[l] (0 .. 31).
DHR_AVX512_TARGET inline __m512 pick16(__m512 lo, __m512 hi, __m512i idx) {
  return _mm512_permutex2var_ps(lo, idx, hi);
}
DHR_AVX512_TARGET inline Xyz16 pick_xyz16(const Xyz16& lo, const Xyz16& hi, __m512i idx) {
  return {pick16(lo.x, hi.x, idx), pick16(lo.y, hi.y, idx), pick16(lo.z, hi.z, idx)};
}
DHR_AVX512_TARGET inline TapValues16 pick_taps16(const Window32& w, __m512i idx) {
  return {_mm512_permutex2var_epi32(w.lo.id, idx, w.hi.id), pick_xyz16(w.lo.n, w.hi.n, idx),
          pick_xyz16(w.lo.g, w.hi.g, idx), pick_xyz16(w.lo.p, w.hi.p, idx), pick16(w.lo.depth, w.hi.depth, idx)};
}

// v takes b's values in the lanes of m.
DHR_AVX512_TARGET inline void blend_xyz16(Xyz16& v, __mmask16 m, const Xyz16& b) {
  v = {_mm512_mask_mov_ps(v.x, m, b.x), _mm512_mask_mov_ps(v.y, m, b.y), _mm512_mask_mov_ps(v.z, m, b.z)};
}
DHR_AVX512_TARGET inline void blend_taps16(TapValues16& v, __mmask16 m, const TapValues16& b) {
  v.id = _mm512_mask_mov_epi32(v.id, m, b.id);
  blend_xyz16(v.n, m, b.n);
  blend_xyz16(v.g, m, b.g);
  blend_xyz16(v.p, m, b.p);
  v.depth = _mm512_mask_mov_ps(v.depth, m, b.depth);
}

// Reprojection::run's per-pixel work for dst pixels x .. x + 15 of row y, up to the taps: the
// same operations in the same order, lane by lane (so the same taps, tests and weights). A lane
// is resolved (bit set in the result) where the pixel is covered, its point and normal usable,
// it projects inside the src image with all four taps inside too, and it has what the passes
// take: a valid tap for the bilinear ones, a valid nearest (largest-weight) tap for the nearest
// ones. Every other lane (background, off-screen, image border, disocclusion, a nearest tap
// that fails) is left to the scalar code.
DHR_AVX512_TARGET uint32_t plan_x16(const PlanInputs& a, int y, int x, Plan16& out) {
  const size_t i0 = size_t(y) * size_t(a.w) + size_t(x);
  const __m512i one = _mm512_set1_epi32(1), two = _mm512_set1_epi32(2);
  const __m512i id = _mm512_loadu_si512(a.did + i0);
  __mmask16 m = _mm512_cmpneq_epi32_mask(id, _mm512_set1_epi32(int(kBackgroundId)));
  out.background = uint16_t(~m);
  out.window = false;
  const Xyz16 dp = load_xyz16(a.dpos + i0), dn = load_xyz16(a.dnrm + i0);
  const __m512 px = dp.x, py = dp.y, pz = dp.z, nx = dn.x, ny = dn.y, nz = dn.z;
  const __m512 ln = dot16(nx, ny, nz, nx, ny, nz);
  m &= finite16(px) & finite16(py) & finite16(pz) & ge16(ln, 0.25f) & le16(ln, 4.0f);
  if (!m) return 0;

  // predict::Projector::project
  const predict::Projector& c = a.proj;
  const __m512 dx = _mm512_sub_ps(px, _mm512_set1_ps(c.position.x)),
               dy = _mm512_sub_ps(py, _mm512_set1_ps(c.position.y)),
               dz = _mm512_sub_ps(pz, _mm512_set1_ps(c.position.z));
  const __m512 z =
      dot16(dx, dy, dz, _mm512_set1_ps(c.forward.x), _mm512_set1_ps(c.forward.y), _mm512_set1_ps(c.forward.z));
  const __m512 inv_z = _mm512_div_ps(_mm512_set1_ps(1.0f), z);
  const __m512 dr = dot16(dx, dy, dz, _mm512_set1_ps(c.right.x), _mm512_set1_ps(c.right.y), _mm512_set1_ps(c.right.z));
  const __m512 du = dot16(dx, dy, dz, _mm512_set1_ps(c.up.x), _mm512_set1_ps(c.up.y), _mm512_set1_ps(c.up.z));
  const __m512 qx = _mm512_add_ps(_mm512_set1_ps(c.cx), _mm512_mul_ps(_mm512_mul_ps(dr, _mm512_set1_ps(c.fx)), inv_z));
  const __m512 qy = _mm512_sub_ps(_mm512_set1_ps(c.cy), _mm512_mul_ps(_mm512_mul_ps(du, _mm512_set1_ps(c.fy)), inv_z));
  m &= _mm512_cmp_ps_mask(z, _mm512_setzero_ps(), _CMP_GT_OQ) & finite16(z) & finite16(qx) & finite16(qy);
  m &= ge16(qx, 0.0f) & _mm512_cmp_ps_mask(qx, _mm512_set1_ps(float(a.w)), _CMP_LT_OQ) & ge16(qy, 0.0f) &
       _mm512_cmp_ps_mask(qy, _mm512_set1_ps(float(a.h)), _CMP_LT_OQ);
  const __m512 u = _mm512_sub_ps(qx, _mm512_set1_ps(0.5f)), v = _mm512_sub_ps(qy, _mm512_set1_ps(0.5f));
  const __m512 x0f = _mm512_roundscale_ps(u, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
  const __m512 y0f = _mm512_roundscale_ps(v, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
  const __m512 ax = _mm512_sub_ps(u, x0f), ay = _mm512_sub_ps(v, y0f);
  const __m512i x0 = _mm512_cvttps_epi32(x0f), y0 = _mm512_cvttps_epi32(y0f);
  m &= _mm512_cmpge_epi32_mask(x0, _mm512_setzero_si512()) & _mm512_cmpge_epi32_mask(y0, _mm512_setzero_si512()) &
       _mm512_cmplt_epi32_mask(_mm512_add_epi32(x0, one), _mm512_set1_epi32(a.w)) &
       _mm512_cmplt_epi32_mask(_mm512_add_epi32(y0, one), _mm512_set1_epi32(a.h));
  if (!m) return 0;
  const __m512 one_f = _mm512_set1_ps(1.0f);
  const __m512 bx = _mm512_sub_ps(one_f, ax), by = _mm512_sub_ps(one_f, ay);
  const __m512 bw[4] = {_mm512_mul_ps(bx, by), _mm512_mul_ps(ax, by), _mm512_mul_ps(bx, ay), _mm512_mul_ps(ax, ay)};
  const __m512i j0 = _mm512_add_epi32(_mm512_mullo_epi32(y0, _mm512_set1_epi32(a.w)), x0);

  // valid_tap for each tap k, in 16 lanes, on its source values read by one of three routes:
  // - loads: every lane is in play and the taps lie side by side (tap 0 of lane l at j0 of
  //   lane 0 plus l, as under smooth motion): each tap's values are 16 consecutive pixels;
  // - a window: the lanes' taps lie in 32 columns of one or two row pairs (the source image is
  //   scaled or turned a little against dst): each row's 32 values are loaded once and each
  //   lane's picked from them by a permute;
  // - gathers: anything else.
  const DstLanes dst{id, px, py, pz, nx, ny, nz, ln, z};
  __mmask16 weighted[4];  // the lanes in play where tap k has weight
  for (int k = 0; k < 4; ++k) weighted[k] = m & _mm512_cmp_ps_mask(bw[k], _mm512_setzero_ps(), _CMP_GT_OQ);
  int32_t lane0 = 0;
  __mmask16 ok[4];
  if (m == 0xFFFF && side_by_side16(j0, lane0)) {
    for (int k = 0; k < 4; ++k)
      ok[k] = tap_tests16(load_taps16(a, size_t(lane0) + size_t(tap_offset(k, a.w))), weighted[k], dst, a);
  } else {
    const int x_lo = _mm512_mask_reduce_min_epi32(m, x0), x_hi = _mm512_mask_reduce_max_epi32(m, x0);
    const int y_lo = _mm512_mask_reduce_min_epi32(m, y0), y_hi = _mm512_mask_reduce_max_epi32(m, y0);
    if (a.w >= 32 && x_hi + 1 - x_lo < 32 && y_hi - y_lo <= 1) {
      // Columns xs .. xs + 31 hold every lane's taps (x0 and x0 + 1 < w). Lanes whose tap 0
      // lies a row lower (`lower`) take their taps from the next row's window.
      const int xs = std::min(x_lo, a.w - 32);
      const __m512i idx = _mm512_sub_epi32(x0, _mm512_set1_epi32(xs));
      const __m512i idx1 = _mm512_add_epi32(idx, one);
      const __mmask16 lower = m & _mm512_cmpneq_epi32_mask(y0, _mm512_set1_epi32(y_lo));
      out.window = true;
      out.window_first = size_t(y_lo) * size_t(a.w) + size_t(xs);
      _mm512_storeu_si512(out.window_row, _mm512_maskz_mov_epi32(lower, one));
      _mm512_storeu_si512(out.window_col, idx);
      // Taps 0 and 1 (pair 0) lie on row y_lo, 2 and 3 on the next (the lower lanes': a row
      // further down); each row's window is loaded once.
      Window32 top = load_window32(a, size_t(y_lo) * size_t(a.w) + size_t(xs));
      for (int pair = 0; pair < 2; ++pair) {
        TapValues16 left = pick_taps16(top, idx), right = pick_taps16(top, idx1);
        if (lower || pair == 0) {
          const Window32 next = load_window32(a, size_t(y_lo + pair + 1) * size_t(a.w) + size_t(xs));
          if (lower) {
            blend_taps16(left, lower, pick_taps16(next, idx));
            blend_taps16(right, lower, pick_taps16(next, idx1));
          }
          top = next;
        }
        ok[2 * pair] = tap_tests16(left, weighted[2 * pair], dst, a);
        ok[2 * pair + 1] = tap_tests16(right, weighted[2 * pair + 1], dst, a);
      }
    } else {
      for (int k = 0; k < 4; ++k) {
        const __m512i jk = _mm512_add_epi32(j0, _mm512_set1_epi32(tap_offset(k, a.w)));
        ok[k] = tap_tests16(gather_taps16(a, weighted[k], jk), weighted[k], dst, a);
      }
    }
  }

  const __mmask16 any = ok[0] | ok[1] | ok[2] | ok[3];
  const __m512i kn =
      _mm512_or_epi32(_mm512_maskz_mov_epi32(_mm512_cmp_ps_mask(ax, _mm512_set1_ps(0.5f), _CMP_GT_OQ), one),
                      _mm512_maskz_mov_epi32(_mm512_cmp_ps_mask(ay, _mm512_set1_ps(0.5f), _CMP_GT_OQ), two));
  __mmask16 near_ok = 0;
  for (int k = 0; k < 4; ++k) near_ok |= ok[k] & _mm512_cmpeq_epi32_mask(kn, _mm512_set1_epi32(k));
  const __mmask16 resolved = m & (a.any_bilinear ? any : m) & (a.any_nearest ? near_ok : m);
  if (!resolved) return 0;

  __m512i valid = _mm512_setzero_si512();
  for (int k = 0; k < 4; ++k) valid = _mm512_mask_or_epi32(valid, ok[k], valid, _mm512_set1_epi32(1 << k));
  _mm512_storeu_si512(out.j0, j0);
  _mm512_storeu_si512(out.valid, valid);
  _mm512_storeu_si512(out.nearest, kn);
  // The scalar code's sum of the valid taps' weights, in tap order from 0, then each divided
  // (only the bilinear passes read them).
  if (a.any_bilinear) {
    __m512 sum = _mm512_setzero_ps();
    for (int k = 0; k < 4; ++k) sum = _mm512_mask_add_ps(sum, ok[k], sum, bw[k]);
    for (int k = 0; k < 4; ++k) _mm512_storeu_ps(out.weight[k], _mm512_maskz_div_ps(ok[k] & resolved, bw[k], sum));
  }
  return resolved;
}
#endif

// One pass of those predicted together: where it reads and writes, and how.
struct PassIo {
  const uint8_t* in = nullptr;
  size_t in_bytes = 0;
  uint8_t* out = nullptr;
  bool bitmask = false;
  bool nearest = false;  // takes the valid tap of largest weight (bitmasks always; 8-bit with filter nearest)
  int bpp = 1;           // bitmask: bytes per pixel
  uint8_t lit[8] = {};   // bitmask: every light's bit
  predict::Layout8 lay;  // 8-bit
  uint8_t full = 255;    // 8-bit: full_scale
};

#if DHR_AVX512_KERNELS
// Tap k's source index, j0 + (k & 1) + (k >> 1) w, in 16 lanes.
DHR_AVX512_TARGET inline __m512i tap_index16(__m512i j0, __m512i k, int w) {
  return _mm512_add_epi32(_mm512_add_epi32(j0, _mm512_and_si512(k, _mm512_set1_epi32(1))),
                          _mm512_mullo_epi32(_mm512_srli_epi32(k, 1), _mm512_set1_epi32(w)));
}

// The 32 bytes from p, widened to two registers of 16 lanes.
DHR_AVX512_TARGET inline void load_bytes32(const uint8_t* p, __m512i& lo, __m512i& hi) {
  lo = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
  hi = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 16)));
}

// The bytes of a window (plan_x16's) for the lanes of m: lane l's at row row[l] (0 .. 2) and
// column col[l] (0 .. 31) from index `first` of the plane `in` (rows w bytes apart); 0 in the
// other lanes. Only the rows some lane of m takes are read.
DHR_AVX512_TARGET inline __m512i window_bytes16(const uint8_t* in, size_t first, int w, __m512i row, __m512i col,
                                                __mmask16 m) {
  __m512i v = _mm512_setzero_si512();
  for (int r = 0; r < 3; ++r) {
    const __mmask16 mr = m & _mm512_cmpeq_epi32_mask(row, _mm512_set1_epi32(r));
    if (!mr) continue;
    __m512i lo, hi;
    load_bytes32(in + first + size_t(r) * size_t(w), lo, hi);
    v = _mm512_mask_mov_epi32(v, mr, _mm512_permutex2var_epi32(lo, col, hi));
  }
  return v;
}

// Lit values (every light's bit, or full_scale) in the lanes of m of dst pixels i0 .. i0 + 15,
// as write_lit, for a pass of one byte per pixel and plane (not a bitmask of more than 8
// lights: the caller leaves those passes' background to write_lit).
DHR_AVX512_TARGET inline void write_lit_x16(const PassIo& p, uint32_t m, size_t i0) {
  if (p.bitmask) {
    _mm512_mask_cvtepi32_storeu_epi8(p.out + i0, __mmask16(m), _mm512_set1_epi32(p.lit[0]));
  } else {
    for (int c = 0; c < p.lay.planes; ++c)
      _mm512_mask_cvtepi32_storeu_epi8(p.out + i0 + size_t(c) * p.lay.plane_stride, __mmask16(m),
                                       _mm512_set1_epi32(p.full));
  }
}

// Pass p's values of the resolved lanes of a plan (dst pixels i0 .. i0 + 15), as the scalar
// write_pass makes them: the nearest tap's byte, or the valid taps' weighted sum in tap order,
// from 0, rounded by round_u8 (one valid tap has weight 1 exactly: its byte). Bitmasks of more
// than one byte per pixel, and blocks whose 4-byte gathers could reach past the buffer's end,
// are left to the caller (false).
DHR_AVX512_TARGET bool write_x16(const PassIo& p, uint32_t resolved, const Plan16& plan, size_t i0, int w) {
  if (p.bitmask && p.bpp != 1) return false;
  const __m512i j0 = _mm512_loadu_si512(plan.j0);
  const __m512i byte = _mm512_set1_epi32(0xFF);
  const int planes = p.bitmask ? 1 : p.lay.planes;
  const size_t stride = p.bitmask ? 0 : p.lay.plane_stride;
  // The largest index read: tap 3 of any lane, in the last plane; a gather reads 4 bytes there.
  const size_t last =
      size_t(_mm512_mask_reduce_max_epi32(__mmask16(resolved), j0)) + 1 + size_t(w) + size_t(planes - 1) * stride;
  if (last + 4 > p.in_bytes) return false;
  const __mmask16 m = __mmask16(resolved);
  const __m512i valid = _mm512_loadu_si512(plan.valid);
  // Where the taps lie side by side (tap 0 of lane l at lane 0's plus l, as under smooth
  // motion), a tap's 16 bytes are consecutive: one load instead of a gather. The lanes a
  // gather would leave at 0 (not resolved, or the tap not valid) are not used either way.
  int32_t lane0 = 0;
  const bool side_by_side =
      side_by_side16(j0, lane0) && size_t(lane0) + 16 + size_t(tap_offset(3, w)) + size_t(planes - 1) * stride <=
                                       p.in_bytes;  // tap 3's last byte, last plane
  const __m512i nearest = _mm512_loadu_si512(plan.nearest);
  const __m512i row = _mm512_loadu_si512(plan.window_row), col = _mm512_loadu_si512(plan.window_col);
  const __m512i one = _mm512_set1_epi32(1);
  const int first_nearest = plan.nearest[std::countr_zero(resolved) & 15];  // the first resolved lane's (resolved != 0)
  const bool one_nearest =
      side_by_side && p.nearest && _mm512_mask_cmpneq_epi32_mask(m, nearest, _mm512_set1_epi32(first_nearest)) == 0;
  // A bilinear pass's taps: lanes and weights (the same for every plane).
  __mmask16 mk[4] = {};
  __m512 wk[4] = {};
  if (!p.nearest) {
    for (int k = 0; k < 4; ++k) {
      mk[k] = m & _mm512_test_epi32_mask(valid, _mm512_set1_epi32(1 << k));
      wk[k] = _mm512_loadu_ps(plan.weight[k]);
    }
  }
  const __mmask16 lower = _mm512_test_epi32_mask(row, row);  // window: lanes whose tap 0 is a row lower
  const __m512i col1 = _mm512_add_epi32(col, one);
  for (int c = 0; c < planes; ++c) {
    const uint8_t* in = p.in + size_t(c) * stride;
    uint8_t* out = p.out + i0 + size_t(c) * stride;
    __m512i result;
    if (one_nearest) {  // every resolved lane takes the same tap: 16 consecutive bytes
      const size_t jk = size_t(lane0) + size_t(tap_offset(first_nearest, w));
      result = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(in + jk)));
    } else if (p.nearest && plan.window) {
      result = window_bytes16(in, plan.window_first, w, _mm512_add_epi32(row, _mm512_srli_epi32(nearest, 1)),
                              _mm512_add_epi32(col, _mm512_and_si512(nearest, one)), m);
    } else if (p.nearest) {
      const __m512i jn = tap_index16(j0, nearest, w);
      result = _mm512_and_si512(_mm512_mask_i32gather_epi32(_mm512_setzero_si512(), m, jn, in, 1), byte);
    } else {
      // Tap k's bytes: loaded (side by side), picked from the window's rows (each row's 32
      // bytes read once: rows 0 and 1, and 2 where some lane's tap 0 is a row lower), or gathered.
      __m512i b[4];
      if (side_by_side) {
        for (int k = 0; k < 4; ++k)
          b[k] = _mm512_cvtepu8_epi32(
              _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + size_t(lane0) + size_t(tap_offset(k, w)))));
      } else if (plan.window) {
        __m512i lo[3], hi[3];
        for (int r = 0; r < (lower ? 3 : 2); ++r)
          load_bytes32(in + plan.window_first + size_t(r) * size_t(w), lo[r], hi[r]);
        for (int k = 0; k < 4; ++k) {
          const int r = k >> 1;
          const __m512i ck = (k & 1) ? col1 : col;
          b[k] = _mm512_permutex2var_epi32(lo[r], ck, hi[r]);
          if (lower) b[k] = _mm512_mask_mov_epi32(b[k], lower, _mm512_permutex2var_epi32(lo[r + 1], ck, hi[r + 1]));
        }
      } else {
        for (int k = 0; k < 4; ++k)
          b[k] = _mm512_and_si512(_mm512_mask_i32gather_epi32(_mm512_setzero_si512(), mk[k],
                                                              tap_index16(j0, _mm512_set1_epi32(k), w), in, 1),
                                  byte);
      }
      __m512 v = _mm512_setzero_ps();
      for (int k = 0; k < 4; ++k) v = _mm512_mask_add_ps(v, mk[k], v, _mm512_mul_ps(wk[k], _mm512_cvtepi32_ps(b[k])));
      // round_u8: r = v + 0.5, 0 below 0 and for NaN, 255 from 255 on, then truncated.
      __m512 r = _mm512_add_ps(v, _mm512_set1_ps(0.5f));
      r = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(r, _mm512_set1_ps(255.0f), _CMP_LT_OQ), _mm512_set1_ps(255.0f), r);
      r = _mm512_maskz_mov_ps(_mm512_cmp_ps_mask(r, _mm512_setzero_ps(), _CMP_GE_OQ), r);
      result = _mm512_cvttps_epi32(r);
    }
    _mm512_mask_cvtepi32_storeu_epi8(out, m, result);
  }
  return true;
}
#endif

class Reprojection final : public Predictor {
 public:
  explicit Reprojection(const ReprojectionSettings& s) : s_(s) {}

  PredictStats predict(const PredictInput& in, PassBuffer& out) override {
    const PassBuffer* received[1] = {&in.received};
    PassBuffer* outs[1] = {&out};
    return predict_passes(in.src, in.dst, received, outs)[0];
  }

  // The taps, their tests and the fill depend on the G-buffers only: found once per pixel for
  // every pass, each pass then reads them its own way.
  bool predicts_passes_together() const override { return true; }

  std::vector<PredictStats> predict_passes(const GBuffer& src, const GBuffer& dst,
                                           std::span<const PassBuffer* const> received,
                                           std::span<PassBuffer* const> out) override {
    check_gbuffer("src", src);
    check_gbuffer("dst", dst);
    const int w = dst.width(), h = dst.height();
    std::vector<PassBuffer> temps(received.size());
    std::vector<PassBuffer*> results;
    std::vector<PassIo> io;
    for (size_t k = 0; k < received.size(); ++k) {
      const PassBuffer& rb = *received[k];
      predict::check_buffer(kName, rb);
      if (rb.desc.layout() == PassLayout::Rgb8)
        fail(
            "predictor '{}' refuses a colour buffer: it reprojects the hybrid client's lighting passes "
            "(visibility, soft_visibility, ao) through G-buffers; the remote-rendering baseline's colour "
            "frame is warped by 'rotation_warp'",
            kName);
      if (rb.desc.width != src.width() || rb.desc.height != src.height() || src.width() != w || src.height() != h)
        fail(
            "predictor '{}': sizes differ: received buffer {}x{}, src G-buffer {}x{}, dst G-buffer {}x{} (all "
            "three must agree)",
            kName, rb.desc.width, rb.desc.height, src.width(), src.height(), w, h);
      PassBuffer& result = predict::output_buffer(rb, *out[k], temps[k], w, h);
      results.push_back(&result);
      PassIo p;
      p.in = rb.bytes.data();
      p.in_bytes = rb.bytes.size();
      p.out = result.bytes.data();
      p.bitmask = rb.desc.layout() == PassLayout::Bitmask;
      p.nearest = p.bitmask || !s_.bilinear;
      if (p.bitmask) {
        p.bpp = (rb.desc.channels + 7) / 8;
        const uint64_t lit_bits = predict::fully_lit_bits(rb.desc.channels);
        for (int b = 0; b < 8; ++b) p.lit[b] = uint8_t(lit_bits >> (8 * b));
      } else {
        p.lay = predict::layout8(rb.desc);
        p.full = uint8_t(rb.desc.full_scale);
      }
      io.push_back(p);
    }

    std::vector<uint32_t> covered(size_t(h), 0), disoccluded(size_t(h), 0);
    run(src, dst, io, covered, disoccluded);

    PredictStats stats;
    for (int y = 0; y < h; ++y) {
      stats.pixels += covered[size_t(y)];
      stats.disoccluded += disoccluded[size_t(y)];
    }
    for (size_t k = 0; k < received.size(); ++k)
      if (results[k] == &temps[k]) *out[k] = std::move(temps[k]);
    return std::vector<PredictStats>(received.size(), stats);
  }

 private:
  void run(const GBuffer& src, const GBuffer& dst, const std::vector<PassIo>& io, std::vector<uint32_t>& covered,
           std::vector<uint32_t>& disoccluded) const {
    const int w = dst.width(), h = dst.height();
    const predict::Projector proj(src.camera);
    const ReprojectionSettings s = s_;

    const uint32_t* sid = src.object_id.data();
    const glm::vec3* spos = src.position.data();
    const glm::vec3* snrm = src.normal.data();
    const glm::vec3* sgeo = src.geo_normal.data();
    const float* sdep = src.depth.data();

    // The tests of one source tap j against the dst surface point (P, normal nd with squared
    // length ln, view depth z in src, object id). Squared forms of
    //   dot(ns, nd) / (|ns| |nd|) >= normal_threshold   and   |dot(P - Ps, g)| / |g| <= tol z
    // (no square roots in the inner loop); written so that any NaN fails them.
    const float thr = s.normal_threshold, thr2_ = thr * thr, tol = s.depth_tolerance, tol2 = tol * tol;
    const bool thr_nonneg = thr >= 0.0f;
    auto valid_tap = [=](size_t j, const glm::vec3& p, const glm::vec3& nd, float ln, float z, uint32_t id) {
      if (sid[j] != id) return false;
      const glm::vec3 ns = snrm[j];
      const float ls = glm::dot(ns, ns);
      if (!(ls >= 0.25f && ls <= 4.0f)) return false;
      const float d = glm::dot(ns, nd), bound = thr2_ * ls * ln;
      if (!(thr_nonneg ? (d >= 0.0f && d * d >= bound) : (d >= 0.0f || d * d <= bound))) return false;
      const glm::vec3 g = sgeo[j];
      const float lg = glm::dot(g, g);
      if (lg >= 0.25f && lg <= 4.0f) {
        const float e = glm::dot(p - spos[j], g);
        return e * e <= tol2 * z * z * lg;
      }
      return std::fabs(sdep[j] - z) <= tol * z;
    };

    // Whether any pass takes the nearest tap, any the bilinear mean (then all four taps are tested).
    bool any_nearest = false, any_bilinear = false;
    for (const PassIo& p : io) (p.nearest ? any_nearest : any_bilinear) = true;

    auto write_lit = [&](size_t i) {
      for (const PassIo& p : io) {
        if (p.bitmask) {
          if (p.bpp == 1)  // up to 8 lights: one byte, no call
            p.out[i] = p.lit[0];
          else
            std::memcpy(p.out + i * size_t(p.bpp), p.lit, size_t(p.bpp));
        } else {
          for (int c = 0; c < p.lay.planes; ++c) p.out[i + size_t(c) * p.lay.plane_stride] = p.full;
        }
      }
    };
    auto write_tap = [](const PassIo& p, size_t i, size_t j) {
      if (p.bitmask) {
        if (p.bpp == 1)
          p.out[i] = p.in[j];
        else
          std::memcpy(p.out + i * size_t(p.bpp), p.in + j * size_t(p.bpp), size_t(p.bpp));
      } else {
        for (int c = 0; c < p.lay.planes; ++c)
          p.out[i + size_t(c) * p.lay.plane_stride] = p.in[j + size_t(c) * p.lay.plane_stride];
      }
    };

    // The passes' values of covered dst pixel i from its valid taps t (bilinear passes) and
    // source pixel `nearest` (nearest passes).
    auto write_pass = [&](const PassIo& pass, size_t i, const Taps& t, int64_t nearest) {
      if (pass.nearest) {
        write_tap(pass, i, size_t(nearest));
      } else if (t.count == 1) {
        write_tap(pass, i, t.index[0]);
      } else {
        for (int c = 0; c < pass.lay.planes; ++c) {
          const uint8_t* plane = pass.in + size_t(c) * pass.lay.plane_stride;
          float v = 0.0f;
          for (int k = 0; k < t.count; ++k) v += t.weight[k] * float(plane[t.index[k]]);
          pass.out[i + size_t(c) * pass.lay.plane_stride] = predict::round_u8(v);
        }
      }
    };

    const float fw = float(w), fh = float(h);
    const int radius = s.fill_radius_px;
    auto pixel = [&](int y, int x, uint32_t& row_covered, uint32_t& row_disoccluded) {
      const size_t i = size_t(y) * size_t(w) + size_t(x);
      const uint32_t id = dst.object_id[i];
      if (id == kBackgroundId) {
        write_lit(i);
        return;
      }
      ++row_covered;
      const glm::vec3 p = dst.position[i];
      const glm::vec3 nd = dst.normal[i];
      const float ln = glm::dot(nd, nd);
      Taps t;                // the bilinear passes' taps
      int64_t nearest = -1;  // the nearest passes' tap
      float qx = 0.0f, qy = 0.0f, z = 0.0f;
      bool projected = false;
      if (predict::finite3(p) && ln >= 0.25f && ln <= 4.0f) {
        const glm::vec3 q = proj.project(p);
        qx = q.x;
        qy = q.y;
        z = q.z;
        // Inside the image rectangle and in front of the camera (NaN fails every test).
        projected = z > 0.0f && std::isfinite(z) && std::isfinite(qx) && std::isfinite(qy);
        if (projected && qx >= 0.0f && qx < fw && qy >= 0.0f && qy < fh) {
          const float u = qx - 0.5f, v = qy - 0.5f;
          const float x0f = std::floor(u), y0f = std::floor(v);
          const float ax = u - x0f, ay = v - y0f;
          const int x0 = int(x0f), y0 = int(y0f);
          const float bw[4] = {(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay};
          // Tap k's index when it lies in the image, has weight and passes the tests; else -1.
          auto tap = [&](int k) -> int64_t {
            const int tx = x0 + (k & 1), ty = y0 + (k >> 1);
            if (!(bw[k] > 0.0f) || tx < 0 || ty < 0 || tx >= w || ty >= h) return -1;
            const size_t j = size_t(ty) * size_t(w) + size_t(tx);
            return valid_tap(j, p, nd, ln, z, id) ? int64_t(j) : -1;
          };
          // The nearest: the valid tap of largest weight, ties in tap order. The nearest tap
          // (largest weight) is tried first: it passes almost always, and the common path
          // then has no data-dependent branch. `valid(k)`: tap k's index or -1.
          const int kn = int(ax > 0.5f) | (int(ay > 0.5f) << 1);
          auto nearest_of = [&](auto&& valid) {
            int64_t j = valid(kn);
            if (j < 0) {
              int order[4] = {0, 1, 2, 3};  // stable insertion sort by decreasing weight
              for (int a = 1; a < 4; ++a) {
                const int k = order[a];
                int b = a;
                for (; b > 0 && bw[order[b - 1]] < bw[k]; --b) order[b] = order[b - 1];
                order[b] = k;
              }
              for (int r = 0; r < 4 && j < 0; ++r)
                if (order[r] != kn) j = valid(order[r]);
            }
            return j;
          };
          if (!any_bilinear) {
            nearest = nearest_of(tap);
          } else {
            int64_t taps[4];
            float sum = 0.0f;
            for (int k = 0; k < 4; ++k) {
              taps[k] = tap(k);
              if (taps[k] >= 0) sum += bw[k];
            }
            // Each weight divided as it is stored: dividing the stored weights afterwards
            // compiled to one vector load of the four scalar stores just made, a
            // store-forwarding stall that was a tenth of the pass (perf, bench_predict).
            for (int k = 0; k < 4; ++k) {
              if (taps[k] < 0) continue;
              t.index[t.count] = uint32_t(taps[k]);
              t.weight[t.count] = bw[k] / sum;
              ++t.count;
            }
            if (any_nearest) nearest = nearest_of([&](int k) { return taps[k]; });
          }
        }
      }
      if (any_bilinear ? t.count == 0 : nearest < 0) {  // no valid tap (the same for every pass)
        ++row_disoccluded;
        bool filled = false;
        if (s.fill_nearest_valid && projected && qx > -float(radius + 1) && qx < fw + float(radius + 1) &&
            qy > -float(radius + 1) && qy < fh + float(radius + 1)) {
          // Nearest valid source pixel in the window, by distance from q to its centre;
          // ties keep the first in scan order.
          const int cx = int(std::floor(qx)), cy = int(std::floor(qy));
          float best_d2 = INFINITY;
          size_t best = 0;
          for (int ty = std::max(0, cy - radius); ty <= std::min(h - 1, cy + radius); ++ty)
            for (int tx = std::max(0, cx - radius); tx <= std::min(w - 1, cx + radius); ++tx) {
              const float dx = float(tx) + 0.5f - qx, dy = float(ty) + 0.5f - qy;
              const float d2 = dx * dx + dy * dy;
              if (d2 >= best_d2) continue;
              const size_t j = size_t(ty) * size_t(w) + size_t(tx);
              if (!valid_tap(j, p, nd, ln, z, id)) continue;
              best_d2 = d2;
              best = j;
            }
          if (best_d2 < INFINITY) {
            for (const PassIo& io_pass : io) write_tap(io_pass, i, best);
            filled = true;
          }
        }
        if (!filled) write_lit(i);
        return;
      }
      for (const PassIo& pass : io) write_pass(pass, i, t, nearest);
    };

#if DHR_AVX512_KERNELS
    // Where the CPU has AVX-512, 16 pixels at a time find their taps (plan_x16), and the pixels
    // it does not resolve take the scalar path above: the same taps, weights and bytes.
    const bool x16 = cpu_has_avx512dq() && !g_scalar_only.load(std::memory_order_relaxed);
    const PlanInputs plan_in{
        sid, snrm, sgeo,  spos, sdep, dst.object_id.data(), dst.position.data(), dst.normal.data(), w,
        h,   proj, thr2_, tol,  tol2, thr_nonneg,           any_bilinear,        any_nearest};
    // Whether write_lit_x16 can write the background lanes of every pass (no bitmask of more
    // than a byte per pixel); else they are left to write_lit.
    const bool lit_x16 = std::none_of(io.begin(), io.end(), [](const PassIo& p) { return p.bitmask && p.bpp != 1; });
#endif
    predict::parallel_rows(h, [&](int y) {
      uint32_t row_covered = 0, row_disoccluded = 0;
      int x = 0;
#if DHR_AVX512_KERNELS
      if (x16) {
        Plan16 plan;
        std::vector<const PassIo*> rest;  // the passes write_x16 leaves to the lane-by-lane writes
        for (; x + 16 <= w; x += 16) {
          const uint32_t resolved = plan_x16(plan_in, y, x, plan);
          const size_t i0 = size_t(y) * size_t(w) + size_t(x);
          row_covered += uint32_t(std::popcount(resolved));
          rest.clear();
          for (const PassIo& pass : io)
            if (resolved && !write_x16(pass, resolved, plan, i0, w)) rest.push_back(&pass);
          for (int l = 0; l < 16 && !rest.empty(); ++l) {  // their resolved lanes one at a time
            if (!((resolved >> l) & 1u)) continue;
            const size_t j0 = size_t(plan.j0[l]);
            auto tap_index = [&](int k) { return j0 + size_t(k & 1) + size_t(k >> 1) * size_t(w); };
            Taps t;
            for (int k = 0; k < 4; ++k) {
              if (!((plan.valid[l] >> k) & 1)) continue;
              t.index[t.count] = uint32_t(tap_index(k));
              t.weight[t.count] = plan.weight[k][l];
              ++t.count;
            }
            for (const PassIo* pass : rest) write_pass(*pass, i0 + size_t(l), t, int64_t(tap_index(plan.nearest[l])));
          }
          uint32_t done = resolved;  // and the background lanes, where every pass writes them here
          if (plan.background && lit_x16) {
            for (const PassIo& pass : io) write_lit_x16(pass, plan.background, i0);
            done |= plan.background;
          }
          for (int l = 0; l < 16; ++l)
            if (!((done >> l) & 1u)) pixel(y, x + l, row_covered, row_disoccluded);
        }
      }
#endif
      for (; x < w; ++x) pixel(y, x, row_covered, row_disoccluded);
      covered[size_t(y)] = row_covered;
      disoccluded[size_t(y)] = row_disoccluded;
    });
  }

  ReprojectionSettings s_;
};

}  // namespace

void predict::force_scalar_reprojection(bool on) { g_scalar_only.store(on, std::memory_order_relaxed); }

PredictorEntry make_reprojection_predictor() {
  return {kName,
          "reproject the received lighting pass through the client's G-buffers (world position to the "
          "old camera; id/depth/normal tests; disocclusions filled)",
          {ParamSpec::choice("filter", "bilinear", {"nearest", "bilinear"},
                             "8-bit passes (soft_visibility, ao): nearest valid tap, or bilinear mean of the valid "
                             "taps (visibility bitmasks are always nearest: bits cannot be interpolated)"),
           ParamSpec::choice("fill", "nearest_valid", {"nearest_valid", "local"},
                             "disocclusions: nearest valid source pixel within fill_radius_px (else local), or "
                             "local: fully lit / AO = full_scale"),
           ParamSpec::integer("fill_radius_px", 3, 1, 16,
                              "fill = nearest_valid: half-size of the square search window around the projected "
                              "point, in pixels"),
           ParamSpec::real("depth_tolerance", 0.02, 0.0001, 1.0,
                           "a tap is valid when the dst surface point lies within tolerance x view depth of the "
                           "tap's surface plane"),
           ParamSpec::real("normal_threshold", 0.9, -1.0, 1.0, "a tap is valid when dot(n_src, n_dst) >= threshold")},
          [](const Params& p) {
            ReprojectionSettings s;
            s.bilinear = p.get_string("filter") == "bilinear";
            s.fill_nearest_valid = p.get_string("fill") == "nearest_valid";
            s.fill_radius_px = p.get_int("fill_radius_px");
            s.depth_tolerance = float(p.get_float("depth_tolerance"));
            s.normal_threshold = float(p.get_float("normal_threshold"));
            return std::make_unique<Reprojection>(s);
          }};
}

}  // namespace dhr
