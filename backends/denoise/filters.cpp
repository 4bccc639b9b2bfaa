// The SVGF-family filter's pipeline (filters.h): the guide (sanitised G-buffer planes), the
// temporal accumulation with reprojection, the variance estimate and the a-trous iterations'
// driver, plus the parameters the four denoisers share. The a-trous and spatial-moment kernels
// are in filters_kernels.cpp, the vector maths in filters_simd.h.
//
// Cost at 1280x720 (tests/backends/bench_denoise.cpp): around the a-trous taps, the passes are fused
// (FilterPipeline::run) and the guide is built 8 pixels at a time, 16 with AVX-512
// (guide_row16), the accumulation's rows 16 (AVX-512) or 8 (AVX2) at a time
// (filters_accumulate.cpp): temporal alone takes 12.1 CPU ms with AVX-512. The rest of a frame
// is memory-bound (the reprojection touches about 25 planes; on a cache-resident crop it is
// 5-7x faster per pixel). svgf_ao's light_history path (one 3x3 iteration where the history is
// long) takes a steady frame in about 40 CPU ms against about 140 for the full filter. What
// each step saved: `git show aec67ef:docs/performance.md`, "svgf_ao".
#include "backends/denoise/filters.h"
#include "backends/denoise/filters_simd.h"
#include "core/base/error.h"
#include "core/buffers/gbuffer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <bit>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif
#if DHR_DENOISE_AVX512
#include <immintrin.h>
#endif
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <utility>
#include <vector>

namespace dhr::denoise {
namespace {

// Row blocks come from tbb::simple_partitioner: it splits [0, height) by halving down to the
// grain, so the blocks depend on the height alone, never on the thread count or on timing.
// (Kernels that carry state across the rows of a block, like atrous_rows' accumulators, gave
// different roundings under the default auto_partitioner from one call to the next.)
template <class Body>
void parallel_rows(int height, Body&& body) {
  tbb::parallel_for(
      tbb::blocked_range<int>(0, height, 4),
      [&](const tbb::blocked_range<int>& r) {
        for (int y = r.begin(); y < r.end(); ++y) body(y);
      },
      tbb::simple_partitioner());
}

// ---------------------------------------------------------------- the guide (G-buffer planes)

// sqrt lane by lane (IEEE: correctly rounded, the bits of std::sqrt).
DHR_ALWAYS_INLINE VecF sqrt_lanes(VecF v) {
#if defined(__SSE__)
  __m128 lo, hi;
  std::memcpy(&lo, &v, 16);
  std::memcpy(&hi, reinterpret_cast<const char*>(&v) + 16, 16);
  lo = _mm_sqrt_ps(lo);
  hi = _mm_sqrt_ps(hi);
  std::memcpy(&v, &lo, 16);
  std::memcpy(reinterpret_cast<char*>(&v) + 16, &hi, 16);
  return v;
#else
  for (int l = 0; l < kLanes; ++l) v[l] = std::sqrt(v[l]);
  return v;
#endif
}

struct GuideRowArgs {
  const float* z;
  const glm::vec3* n;
  const uint32_t* id;
  Guide* out;
};

#if DHR_DENOISE_AVX512
// Pixels [0, w - w % 16) of a row of the guide, 16 at a time with AVX-512: guide_row's 8-lane
// operations lane for lane (the normals' x, y, z picked out of the 16 vec3 by permutes; sqrt
// and the division are IEEE, correctly rounded), so the same bits. Returns where it ended.
__attribute__((noinline)) DHR_DENOISE_TARGET_AVX512 int guide_row16(const GuideRowArgs& a, size_t row, int w) {
  Guide& o = *a.out;
  const __mmask16 all = 0xffff;
  // Component k of vec3 number l is float 3 l + k of the 48: lanes 0-10 (3 l + k < 32 for
  // k = 0; for k = 1, 2 lanes 0-9 / 0-10 likewise) from the first two loads, the rest from the third.
  auto idx = [](int k, bool second) {
    alignas(64) int32_t v[16];
    for (int l = 0; l < 16; ++l) {
      const int f = 3 * l + k;
      v[l] = second ? (f < 32 ? l : 16 + (f - 32)) : (f < 32 ? f : 0);
    }
    return _mm512_load_si512(v);
  };
  const __m512i i0a = idx(0, false), i0b = idx(0, true), i1a = idx(1, false), i1b = idx(1, true);
  const __m512i i2a = idx(2, false), i2b = idx(2, true);
  const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f);
  int x = 0;
  for (; x + 16 <= w; x += 16) {
    const size_t i = row + size_t(x);
    const float* n = reinterpret_cast<const float*>(a.n + i);
    const __m512 n0 = _mm512_loadu_ps(n), n1 = _mm512_loadu_ps(n + 16), n2 = _mm512_loadu_ps(n + 32);
    const __m512 nx = _mm512_permutex2var_ps(_mm512_permutex2var_ps(n0, i0a, n1), i0b, n2);
    const __m512 ny = _mm512_permutex2var_ps(_mm512_permutex2var_ps(n0, i1a, n1), i1b, n2);
    const __m512 nz = _mm512_permutex2var_ps(_mm512_permutex2var_ps(n0, i2a, n1), i2b, n2);
    const __m512 z = _mm512_loadu_ps(a.z + i);
    const __m512i id = _mm512_loadu_si512(a.id + i);
    const __m512 len2 =
        _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(nx, nx), _mm512_mul_ps(ny, ny)), _mm512_mul_ps(nz, nz));
    const __mmask16 ok = _mm512_test_epi32_mask(id, id) & _mm512_cmp_ps_mask(z, zero, _CMP_GT_OQ) &
                         _mm512_cmp_ps_mask(z, _mm512_set1_ps(1e30f), _CMP_LT_OQ) &
                         _mm512_cmp_ps_mask(len2, _mm512_set1_ps(0.25f), _CMP_GE_OQ) &
                         _mm512_cmp_ps_mask(len2, _mm512_set1_ps(4.0f), _CMP_LE_OQ);
    const __m512 inv_len = _mm512_maskz_div_ps(ok, one, _mm512_maskz_sqrt_ps(all, len2));
    _mm512_storeu_ps(o.depth.data() + i, _mm512_maskz_mov_ps(ok, z));
    _mm512_storeu_ps(o.nx.data() + i, _mm512_maskz_mul_ps(ok, nx, inv_len));
    _mm512_storeu_ps(o.ny.data() + i, _mm512_maskz_mul_ps(ok, ny, inv_len));
    _mm512_storeu_ps(o.nz.data() + i, _mm512_maskz_mul_ps(ok, nz, inv_len));
    _mm512_storeu_si512(o.id.data() + i, _mm512_maskz_mov_epi32(ok, id));
    _mm512_storeu_ps(o.valid_f.data() + i, _mm512_maskz_mov_ps(ok, one));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(o.valid.data() + i),
                     _mm512_maskz_cvtepi32_epi8(all, _mm512_maskz_mov_epi32(ok, _mm512_set1_epi32(1))));
  }
  return x;
}
#endif

// One row of the guide: pixels [0, w) of row `row` (offset of the row's first pixel).
// 8 pixels at a time with the same IEEE operations as the scalar tail: "finite and in range"
// is tested by the range comparisons alone (NaN fails them, inf is out of range).
DHR_DENOISE_TARGETS
void guide_row(const GuideRowArgs& a, size_t row, int w) {
  Guide& o = *a.out;
  int x = 0;
  for (; x + kLanes <= w; x += kLanes) {
    const size_t i = row + size_t(x);
    VecF z, nx, ny, nz;
    VecU id;
    std::memcpy(&z, a.z + i, sizeof z);
    std::memcpy(&id, a.id + i, sizeof id);
    for (int l = 0; l < kLanes; ++l) {
      nx[l] = a.n[i + size_t(l)].x;
      ny[l] = a.n[i + size_t(l)].y;
      nz[l] = a.n[i + size_t(l)].z;
    }
    const VecF len2 = nx * nx + ny * ny + nz * nz;
    const VecI ok = (id != VecU{}) & (z > VecF{}) & (z < splat(1e30f)) & (len2 >= splat(0.25f)) & (len2 <= splat(4.0f));
    const VecF inv_len = ok ? splat(1.0f) / sqrt_lanes(len2) : VecF{};
    const VecF zo = ok ? z : VecF{};
    const VecF nxo = ok ? nx * inv_len : VecF{}, nyo = ok ? ny * inv_len : VecF{}, nzo = ok ? nz * inv_len : VecF{};
    const VecU ido = ok ? id : VecU{};
    const VecF vf = ok ? splat(1.0f) : VecF{};
    std::memcpy(o.depth.data() + i, &zo, sizeof zo);
    std::memcpy(o.nx.data() + i, &nxo, sizeof nxo);
    std::memcpy(o.ny.data() + i, &nyo, sizeof nyo);
    std::memcpy(o.nz.data() + i, &nzo, sizeof nzo);
    std::memcpy(o.id.data() + i, &ido, sizeof ido);
    std::memcpy(o.valid_f.data() + i, &vf, sizeof vf);
    for (int l = 0; l < kLanes; ++l) o.valid[i + size_t(l)] = uint8_t(ok[l] & 1);
  }
  for (; x < w; ++x) {
    const size_t i = row + size_t(x);
    const float z = a.z[i];
    const glm::vec3 n = a.n[i];
    const float len2 = n.x * n.x + n.y * n.y + n.z * n.z;
    const bool ok = a.id[i] != kBackgroundId && z > 0.0f && z < 1e30f && len2 >= 0.25f && len2 <= 4.0f;
    const float inv_len = ok ? 1.0f / std::sqrt(len2) : 0.0f;
    o.valid[i] = ok ? 1 : 0;
    o.valid_f[i] = ok ? 1.0f : 0.0f;
    o.depth[i] = ok ? z : 0.0f;
    o.nx[i] = ok ? n.x * inv_len : 0.0f;
    o.ny[i] = ok ? n.y * inv_len : 0.0f;
    o.nz[i] = ok ? n.z * inv_len : 0.0f;
    o.id[i] = ok ? a.id[i] : kBackgroundId;
  }
}

void build_guide(const GBuffer& g, Guide& out) {
  const int w = g.width(), h = g.height();
  if (!g.normal.same_size(w, h) || !g.object_id.same_size(w, h) || !g.motion.same_size(w, h))
    fail("denoiser: G-buffer planes differ in size (depth {}x{}, normal {}x{}, object_id {}x{}, motion {}x{})", w, h,
         g.normal.width(), g.normal.height(), g.object_id.width(), g.object_id.height(), g.motion.width(),
         g.motion.height());
  if (out.width != w || out.height != h) out.resize(w, h);
  const GuideRowArgs a{g.depth.data(), g.normal.data(), g.object_id.data(), &out};
#if DHR_DENOISE_AVX512
  if (cpu_has_avx512()) {
    parallel_rows(h, [&](int y) {
      const size_t row = size_t(y) * size_t(w);
      const int x = guide_row16(a, row, w);
      if (x < w) guide_row(a, row + size_t(x), w - x);
    });
    return;
  }
#endif
  parallel_rows(h, [&](int y) { guide_row(a, size_t(y) * size_t(w), w); });
}

// The per-pixel planes of the spatial filter that depend on the guide alone, for row y:
//  inv_phi_z = 1 / (sigma_z max(|grad z|, 1e-3 z)) (floored at 1e-30 before the inverse,
//    capped at 1e30 after), 0 at invalid pixels or with sigma_z = 0. |grad z| = |dz/dx| +
//    |dz/dy|, each the smaller one-sided difference to a valid neighbour (0 without one). SVGF
//    uses the screen-space derivative fwidth(z); taking the smaller side keeps a depth
//    discontinuity from inflating the tolerance of the pixels right at the edge (which would
//    let the filter bleed across it). Floor: 1e-3 of the depth (a fronto-parallel plane has no
//    gradient), and 1e-30 so that 1/phi stays finite and 0 * (1/phi) is never NaN.
//  inv_valid_k = 1 / (mass of the 3x3 Gaussian (1/4 1/2 1/4)^2 over the valid pixels), 0 at
//    invalid pixels (the variance prefilter of the a-trous passes). The masses are multiples
//    of 1/16 up to 1: exact in any order.
struct GuideSpatialArgs {
  const Guide* g;
  float sigma_z;
  float *inv_phi_z, *inv_valid_k;
};

template <class T>
DHR_ALWAYS_INLINE T min_lanes(T a, T b) {  // std::min(a, b) = b < a ? b : a, lane by lane
  return b < a ? b : a;
}

DHR_DENOISE_TARGETS
void guide_spatial_row(const GuideSpatialArgs& a, int y) {
  const Guide& g = *a.g;
  const int w = g.width, h = g.height;
  const size_t row = size_t(y) * size_t(w);
  const float* z = g.depth.data() + row;
  const float* vf = g.valid_f.data() + row;
  const float* zu = y > 0 ? z - w : nullptr;
  const float* vu = y > 0 ? vf - w : nullptr;
  const float* zd = y + 1 < h ? z + w : nullptr;
  const float* vd = y + 1 < h ? vf + w : nullptr;
  float* ipz = a.inv_phi_z + row;
  float* ivk = a.inv_valid_k + row;
  const float sz = a.sigma_z;
  auto scalar = [&](int x) {
    const float zc = z[x];
    auto side = [&](const float* zr, const float* vr, int xx) {
      if (!zr || xx < 0 || xx >= w) return INFINITY;
      return vr[xx] != 0.0f ? std::fabs(zr[xx] - zc) : INFINITY;
    };
    const float gx = std::min(side(z, vf, x - 1), side(z, vf, x + 1));
    const float gy = std::min(side(zu, vu, x), side(zd, vd, x));
    const float grad = (gx < INFINITY ? gx : 0.0f) + (gy < INFINITY ? gy : 0.0f);
    const float phi = std::max(sz * std::max(grad, 1e-3f * zc), 1e-30f);
    const bool ok = vf[x] != 0.0f;
    ipz[x] = (ok && sz > 0.0f) ? std::min(1.0f / phi, 1e30f) : 0.0f;
    float sk = 0.0f;
    for (int dy = -1; dy <= 1; ++dy) {
      const float* vr = dy < 0 ? vu : (dy > 0 ? vd : vf);
      if (!vr) continue;
      for (int dx = -1; dx <= 1; ++dx) {
        const int xx = x + dx;
        if (xx < 0 || xx >= w) continue;
        sk += (dx == 0 ? 0.5f : 0.25f) * (dy == 0 ? 0.5f : 0.25f) * vr[xx];
      }
    }
    ivk[x] = ok ? 1.0f / sk : 0.0f;  // sk >= 0.25 when the centre is valid
  };
  if (w < kLanes + 2) {
    for (int x = 0; x < w; ++x) scalar(x);
    return;
  }
  scalar(0);
  const VecF inf = splat(INFINITY), zero{};
  auto ld = [](const float* p) {
    VecF v;
    std::memcpy(&v, p, sizeof v);
    return v;
  };
  int x = 1;
  for (; x + kLanes <= w - 1; x += kLanes) {
    const VecF zc = ld(z + x), vc = ld(vf + x);
    const VecF vl = ld(vf + x - 1), vr = ld(vf + x + 1);
    const VecF sl = vl != zero ? abs_f(ld(z + x - 1) - zc) : inf;
    const VecF sr = vr != zero ? abs_f(ld(z + x + 1) - zc) : inf;
    VecF su = inf, sd = inf;
    VecF sk_u = zero, sk_d = zero;
    if (zu) {
      const VecF v = ld(vu + x);
      su = v != zero ? abs_f(ld(zu + x) - zc) : inf;
      sk_u = (0.25f * 0.25f) * ld(vu + x - 1) + (0.5f * 0.25f) * v + (0.25f * 0.25f) * ld(vu + x + 1);
    }
    if (zd) {
      const VecF v = ld(vd + x);
      sd = v != zero ? abs_f(ld(zd + x) - zc) : inf;
      sk_d = (0.25f * 0.25f) * ld(vd + x - 1) + (0.5f * 0.25f) * v + (0.25f * 0.25f) * ld(vd + x + 1);
    }
    const VecF gx = min_lanes(sl, sr), gy = min_lanes(su, sd);
    const VecF grad = (gx < inf ? gx : zero) + (gy < inf ? gy : zero);
    const VecF t = splat(1e-3f) * zc;
    const VecF m = grad < t ? t : grad;
    VecF phi = sz * m;
    phi = phi < splat(1e-30f) ? splat(1e-30f) : phi;
    const VecF inv = splat(1.0f) / phi;
    const VecI ok = vc != zero;
    const VecI use = sz > 0.0f ? ok : VecI{};
    const VecF ipz_v = use ? (splat(1e30f) < inv ? splat(1e30f) : inv) : zero;
    const VecF sk = sk_u + ((0.25f * 0.5f) * vl + (0.5f * 0.5f) * vc + (0.25f * 0.5f) * vr) + sk_d;
    const VecF ivk_v = ok ? splat(1.0f) / sk : zero;
    std::memcpy(ipz + x, &ipz_v, sizeof ipz_v);
    std::memcpy(ivk + x, &ivk_v, sizeof ivk_v);
  }
  for (; x < w; ++x) scalar(x);
}

// The 1D a-trous kernels: B3-spline (5x5) and (1/4, 1/2, 1/4) (3x3).
constexpr float kB3[5] = {1.0f / 16, 1.0f / 4, 3.0f / 8, 1.0f / 4, 1.0f / 16};
constexpr float kK3[3] = {0.25f, 0.5f, 0.25f};

}  // namespace

void Guide::resize(int w, int h) {
  width = w;
  height = h;
  const size_t n = size_t(w) * size_t(h);
  for (auto* v : {&depth, &nx, &ny, &nz, &valid_f}) fill_parallel(*v, n, 0.0f);
  fill_parallel(id, n, kBackgroundId);
  fill_parallel(valid, n, uint8_t(0));
}

// ---------------------------------------------------------------- parameters

std::vector<ParamSpec> temporal_param_specs() {
  return {
      ParamSpec::real("alpha", 0.2, 0.01, 1.0,
                      "weight of the new frame in the exponential moving average (value and moments)"),
      ParamSpec::integer("history_cap", 32, 1, 1024, "history length cap in frames (1/alpha reached earlier wins)"),
      ParamSpec::real("depth_tolerance", 0.1, 0.001, 1.0,
                      "reprojection: a previous tap is accepted when |z_prev - z| <= tolerance * z"),
      ParamSpec::real("normal_threshold", 0.9, -1.0, 1.0,
                      "reprojection: a previous tap is accepted when dot(n_prev, n) >= threshold"),
  };
}

std::vector<ParamSpec> spatial_param_specs(int default_iterations, int default_radius) {
  return {
      ParamSpec::integer("iterations", default_iterations, 1, 10, "a-trous iterations (step 2^i)"),
      ParamSpec::integer("kernel_radius", default_radius, 1, 2, "1: 3x3 kernel (1/4 1/2 1/4), 2: 5x5 B3-spline"),
      ParamSpec::real("sigma_l", 4.0, 0.0, 1000.0,
                      "AO edge-stopping: weight exp(-|l_p - l_q| / (sigma_l sqrt(var) + 1e-4)); 0 turns it off"),
      ParamSpec::integer("sigma_n", 128, 1, 1024,
                         "normal edge-stopping power: max(0, n_p . n_q)^sigma_n; a power of two (1, 2, 4, ..., 1024)"),
      ParamSpec::real("sigma_z", 1.0, 0.0, 1000.0,
                      "depth edge-stopping: exp(-|z_p - z_q| / (sigma_z |grad z| |offset|)); 0 turns it off"),
      ParamSpec::integer("variance_radius", 3, 1, 5,
                         "window radius of the spatial variance estimate (3: 7x7) used where history is short"),
      ParamSpec::boolean("fast_weights", true,
                         "a-trous weights by fused multiply-adds and a degree-3 exponential (true: 0.8x the CPU "
                         "on AVX-512) or by separate products and sums and a degree-4 exponential (false: the "
                         "weights of reports before this option); outputs within one 8-bit level of each other "
                         "(docs/performance.md, svgf_ao's fast weights)"),
  };
}

void read_temporal_params(const Params& p, FilterSettings& s) {
  s.alpha = float(p.get_float("alpha"));
  s.history_cap = p.get_int("history_cap");
  s.depth_tolerance = float(p.get_float("depth_tolerance"));
  s.normal_threshold = float(p.get_float("normal_threshold"));
}

void read_spatial_params(const Params& p, FilterSettings& s, bool with_iterations) {
  if (with_iterations) s.iterations = p.get_int("iterations");
  s.kernel_radius = p.get_int("kernel_radius");
  s.sigma_l = float(p.get_float("sigma_l"));
  s.sigma_n = p.get_int("sigma_n");
  if (!std::has_single_bit(unsigned(s.sigma_n)))
    fail(
        "denoiser parameter sigma_n = {} must be a power of two (1, 2, 4, ..., 1024): the normal weight is "
        "computed by repeated squaring",
        s.sigma_n);
  s.sigma_z = float(p.get_float("sigma_z"));
  s.variance_radius = p.get_int("variance_radius");
  s.fast_weights = p.get_bool("fast_weights");
}

// ---------------------------------------------------------------- the pipeline

// One frame: guide -> temporal accumulation (or the rescaled input) -> variance -> a-trous
// iterations -> 8 bits. Passes are fused where that saves a trip through memory: the guide's
// second pass also makes the depth phi and the valid-mass planes of the spatial filter, the
// accumulation also rescales the input, writes the temporal variance (and the output of the
// temporal-only denoiser), the a-trous rows compute their own AO phi, and the last iteration
// writes the 8-bit output. The first iteration's output is written straight into the value
// history when it is fed back. None of this changes a bit of the result (the operations per
// pixel are those of the unfused passes, in the same order).
void FilterPipeline::run(const DenoiseInput& in, ImageU8& out) {
  const int w = in.noisy.width(), h = in.noisy.height();
  if (in.full_scale < 1)
    fail("denoiser: full_scale {} is invalid (must be >= 1: the value that means 1.0)", in.full_scale);
  if (in.gbuf.width() != w || in.gbuf.height() != h)
    fail("denoiser: noisy image is {}x{} but the G-buffer is {}x{} (they must match)", w, h, in.gbuf.width(),
         in.gbuf.height());
  if (out.width() != w || out.height() != h) out.resize(w, h);  // every pixel is written below
  if (w == 0 || h == 0) return;
  if (!in.history_valid || w != w_ || h != h_) history_ok_ = false;
  if (w != w_ || h != h_) allocate(w, h);
  const bool spatial = s_.iterations > 0;
  build_guide(in.gbuf, guide_[cur_]);
  if (spatial) {
    GuideSpatialArgs ga{&guide_[cur_], s_.sigma_z, inv_phi_z_.data(), inv_valid_k_.data()};
    parallel_rows(h, [&](int y) { guide_spatial_row(ga, y); });
  }
  if (s_.temporal)
    accumulate(in, spatial ? nullptr : out.data());
  else
    sanitize_input(in, spatial ? nullptr : out.data());
  if (spatial) {
    spatial_variance();
    atrous_iterations(out.data());
  }
  history_ok_ = s_.temporal;
  cur_ ^= 1;
}

void FilterPipeline::allocate(int w, int h) {
  w_ = w;
  h_ = h;
  const size_t n = size_t(w) * size_t(h);
  for (auto* v :
       {&input_, &value_, &var_, &inv_phi_z_, &inv_valid_k_, &work_v_[0], &work_v_[1], &work_var_[0], &work_var_[1],
        &hv_[0], &hv_[1], &hm1_[0], &hm1_[1], &hm2_[0], &hm2_[1], &hist_[0], &hist_[1], &hk_[0], &hk_[1]})
    fill_parallel(*v, n, 0.0f);
  fill_parallel(cls_, n, uint8_t(0));
  span_lo_.assign(size_t(h), 0);
  span_hi_.assign(size_t(h), -1);
  guide_[0].resize(w, h);
  guide_[1].resize(w, h);
  history_ok_ = false;
}

bool FilterPipeline::light() const { return s_.temporal && s_.light_history > 0 && s_.iterations > 0; }
bool FilterPipeline::feedback() const { return s_.temporal && s_.feedback_filtered && s_.iterations > 0; }

// Without temporal accumulation: input to [0, 1] (values above full_scale count as
// full_scale); every valid pixel takes the spatial variance path (no history), its
// "temporal" variance max(0, m1^2 - m1^2) being 0. out: the 8-bit output when nothing follows.
void FilterPipeline::sanitize_input(const DenoiseInput& in, uint8_t* out) {
  const int fs = in.full_scale;
  const float inv = 1.0f / float(fs);
  const int w = w_;
  const Guide& g = guide_[cur_];
  parallel_rows(h_, [&](int y) {
    const size_t row = size_t(y) * w;
    const uint8_t* src = in.noisy.data() + row;
    float* dst = input_.data() + row;
    int xa = w, xb = -1;
    for (int x = 0; x < w; ++x) {
      const int v = src[x] > fs ? fs : src[x];
      dst[x] = float(v) * inv;
      var_[row + x] = 0.0f;
      if (g.valid[row + x]) {
        xa = std::min(xa, x);
        xb = x;
      }
      if (out) out[row + x] = to_u8(dst[x]);
    }
    span_lo_[size_t(y)] = xa;
    span_hi_[size_t(y)] = xb;
  });
}

// Temporal accumulation (SVGF section 4.1): reproject through the motion vector, bilinear
// over the 2x2 previous taps that pass the depth, normal and object-id tests, renormalised;
// EMA with weight max(alpha, 1/history) (a plain mean while the history is short). Also:
// the input rescaled to [0, 1] on the way in; with a spatial filter, the temporal variance
// (m2 - m1^2) k per pixel, the span of each row that needs the spatial estimate (history
// shorter than min_history) and the light_history class; without one, the 8-bit output.
void FilterPipeline::accumulate(const DenoiseInput& in, uint8_t* out) {
  const int w = w_, h = h_;
  const ImageVec2& motion = in.gbuf.motion;
  const int fs = in.full_scale;
  const float inv_fs = 1.0f / float(fs);
  const Guide& g = guide_[cur_];
  const Guide& gp = guide_[cur_ ^ 1];
  const float* pv = hv_[cur_ ^ 1].data();
  const float* pm1 = hm1_[cur_ ^ 1].data();
  const float* pm2 = hm2_[cur_ ^ 1].data();
  const float* ph = hist_[cur_ ^ 1].data();
  const float* pk = hk_[cur_ ^ 1].data();
  // With the first iteration fed back, the accumulated value goes to value_ and the first
  // a-trous iteration writes the history; otherwise straight into the history.
  float* nv = feedback() ? value_.data() : hv_[cur_].data();
  float* nm1 = hm1_[cur_].data();
  float* nm2 = hm2_[cur_].data();
  float* nh = hist_[cur_].data();
  float* nk = hk_[cur_].data();
  const bool have_history = history_ok_;
  const float cap = float(s_.history_cap);
  const bool spatial = s_.iterations > 0, lt = light();
  const float min_h = float(s_.min_history), light_h = float(s_.light_history);
  const float tol = s_.depth_tolerance, nthr = s_.normal_threshold, alpha = s_.alpha;
  const float wmax = float(w) + 1.0f, hmax = float(h) + 1.0f;
  // Plain pointers: the compiler cannot keep a vector's data pointer in a register across
  // the byte stores below (a uint8_t store may alias anything).
  const glm::vec2* const mo = motion.data();
  const uint8_t* const noisy = in.noisy.data();
  const uint8_t *const cvalid = g.valid.data(), *const pvalid = gp.valid.data();
  const uint32_t *const cid = g.id.data(), *const pid = gp.id.data();
  const float *const cz = g.depth.data(), *const pz = gp.depth.data();
  const float *const cnx = g.nx.data(), *const cny = g.ny.data(), *const cnz = g.nz.data();
  const float *const pnx = gp.nx.data(), *const pny = gp.ny.data(), *const pnz = gp.nz.data();
  float* const var = var_.data();
  uint8_t* const cls = cls_.data();
  int* const span_lo = span_lo_.data();
  int* const span_hi = span_hi_.data();
  const AccumulateArgs args{
      mo,  noisy,  cvalid, cid,  pid,   cz,  pz,    cnx,     cny,  cnz,  pnx,          pny,     pnz, pv,
      pm1, pm2,    ph,     pk,   nv,    nm1, nm2,   nh,      nk,   var,  cls,          out,     w,   h,
      fs,  inv_fs, tol,    nthr, alpha, cap, min_h, light_h, wmax, hmax, have_history, spatial, lt};
  parallel_rows(h, [=](int y) {
    // Locals, not the closure's members: those live in memory that the byte stores below
    // might alias, so the compiler would reload every pointer for every pixel.
    const glm::vec2* const mo_l = mo;
    const uint8_t *const cvalid_l = cvalid, *const pvalid_l = pvalid;
    const uint32_t *const cid_l = cid, *const pid_l = pid;
    const float *const cz_l = cz, *const pz_l = pz, *const cnx_l = cnx, *const cny_l = cny, *const cnz_l = cnz;
    const float *const pnx_l = pnx, *const pny_l = pny, *const pnz_l = pnz;
    const float *const pv_l = pv, *const pm1_l = pm1, *const pm2_l = pm2, *const ph_l = ph, *const pk_l = pk;
    float *const nv_l = nv, *const nm1_l = nm1, *const nm2_l = nm2, *const nh_l = nh, *const nk_l = nk;
    float* const var_l = var;
    uint8_t *const cls_l = cls, *const out_l = out;
    const int w_l = w, h_l = h, fs_l = fs;
    const float inv_fs_l = inv_fs, tol_l = tol, nthr_l = nthr, alpha_l = alpha, cap_l = cap, min_h_l = min_h,
                light_h_l = light_h, wmax_l = wmax, hmax_l = hmax;
    const bool hist_l = have_history, spatial_l = spatial, lt_l = lt;
    const size_t row = size_t(y) * w_l;
    const uint8_t* src = noisy + row;
    int xa = w_l, xb = -1;
    // The blend and the EMA of one pixel, from the (renormalised) sums of its accepted taps.
    auto finish = [&](int x, float len, float pval, float p1, float p2, float pkk) {
      const size_t i = row + x;
      const int iv = src[x] > fs_l ? fs_l : src[x];
      const float c = float(iv) * inv_fs_l;
      const bool valid = cvalid_l[i] != 0;
      float v, m1, m2, kk;
      if (len > 0.0f) {
        len = std::min(len + 1.0f, cap_l);
        const float a = std::max(alpha_l, 1.0f / len);
        v = pval + a * (c - pval);
        m1 = p1 + a * (c - p1);
        m2 = p2 + a * (c * c - p2);
        kk = (1.0f - a) * (1.0f - a) * pkk + a * a;
      } else {
        len = valid ? 1.0f : 0.0f;
        v = c;
        m1 = c;
        m2 = c * c;
        kk = 1.0f;
      }
      nv_l[i] = v;
      nm1_l[i] = m1;
      nm2_l[i] = m2;
      nk_l[i] = kk;
      nh_l[i] = len;
      if (spatial_l) {
        var_l[i] = valid ? std::max(0.0f, m2 - m1 * m1) * kk : 0.0f;
        if (valid && len < min_h_l) {
          xa = std::min(xa, x);
          xb = x;
        }
        if (lt_l) cls_l[i] = valid && len < light_h_l ? 1 : 0;
      } else {
        out_l[i] = to_u8(v);
      }
    };
    // Reprojection of one pixel: the sums of its accepted taps, renormalised.
    auto reproject = [&](int x, float& len, float& pval, float& p1, float& p2, float& pkk) {
      const size_t i = row + x;
      const glm::vec2 m = mo_l[i];
      // Previous pixel centre of this surface point, in pixel-index coordinates. The range
      // tests also reject NaN and inf.
      const float px = float(x) + m.x, py = float(y) + m.y;
      if (!(px > -2.0f && py > -2.0f && px < wmax_l && py < hmax_l)) return;
      // floor by truncation: px, py > -2 here (std::floor is a libm call without SSE4.1)
      const int x0 = int(px + 2.0f) - 2, y0 = int(py + 2.0f) - 2;
      const float fx = px - float(x0), fy = py - float(y0);
      const float bw[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
      const uint32_t idc = cid_l[i];
      const float zc = cz_l[i], ztol = tol_l * zc;
      const float ncx = cnx_l[i], ncy = cny_l[i], ncz = cnz_l[i];
      float sw = 0.0f;
      for (int k = 0; k < 4; ++k) {
        const int xx = x0 + (k & 1), yy = y0 + (k >> 1);
        if (xx < 0 || yy < 0 || xx >= w_l || yy >= h_l || bw[k] <= 0.0f) continue;
        const size_t j = size_t(yy) * w_l + xx;
        if (!pvalid_l[j] || pid_l[j] != idc || ph_l[j] <= 0.0f) continue;
        if (std::fabs(pz_l[j] - zc) > ztol) continue;
        const float d = pnx_l[j] * ncx + pny_l[j] * ncy + pnz_l[j] * ncz;
        if (d < nthr_l) continue;
        sw += bw[k];
        pval += bw[k] * pv_l[j];
        p1 += bw[k] * pm1_l[j];
        p2 += bw[k] * pm2_l[j];
        len += bw[k] * ph_l[j];
        pkk += bw[k] * pk_l[j];
      }
      if (sw >= 0.01f) {
        const float inv = 1.0f / sw;
        pval *= inv;
        p1 *= inv;
        p2 *= inv;
        len *= inv;
        pkk *= inv;
      } else {
        len = 0.0f;  // disoccluded: no usable history
      }
    };
    for (int x = accumulate_row_vector(args, y, xa, xb); x < w_l; ++x) {
      float len = 0.0f, pval = 0.0f, p1 = 0.0f, p2 = 0.0f, pkk = 0.0f;
      if (hist_l && cvalid_l[row + x]) reproject(x, len, pval, p1, p2, pkk);
      finish(x, len, pval, p1, p2, pkk);
    }
    span_lo[y] = xa;
    span_hi[y] = xb;
  });
}

// Per-pixel variance of the AO signal: from the temporal moments (written by accumulate)
// where the history has at least min_history frames, else spatially from the moments in a
// (2r+1)^2 window weighted by depth and normal only (DHR-S section 3.3: no luminance term),
// boosted by 4/h as SVGF does for young pixels. Without temporal accumulation (atrous) every
// pixel takes the spatial path with h = 1 and the moments of the current frame.
void FilterPipeline::spatial_variance() {
  const int w = w_, h = h_;
  const Guide& g = guide_[cur_];
  const float* hl = s_.temporal ? hist_[cur_].data() : nullptr;  // null: no history (h = 0)
  const float* kf = s_.temporal ? hk_[cur_].data() : nullptr;    // null: k = 1 (one frame)
  const float* m1 = s_.temporal ? hm1_[cur_].data() : input_.data();
  const float* m2 = s_.temporal ? hm2_[cur_].data() : nullptr;  // null: m2 = input^2
  const float min_h = float(s_.min_history);
  MomentArgs margs;
  margs.width = w;
  margs.height = h;
  margs.radius = s_.variance_radius;
  margs.normal_squarings = normal_squarings();
  margs.depth = g.depth.data();
  margs.nx = g.nx.data();
  margs.ny = g.ny.data();
  margs.nz = g.nz.data();
  margs.inv_phi_z = inv_phi_z_.data();
  margs.m1 = m1;
  margs.m2 = m2;
  tbb::parallel_for(
      tbb::blocked_range<int>(0, h, 4),
      [&](const tbb::blocked_range<int>& range) {
        std::vector<float> acc;
        for (int y = range.begin(); y < range.end(); ++y) {
          const int xa = span_lo_[size_t(y)], xb = span_hi_[size_t(y)];
          if (xb < xa) continue;
          const int n = xb - xa + 1;
          acc.assign(size_t(n) * 3, 0.0f);
          moment_span(margs, y, xa, xb, acc.data());
          const float* a0 = acc.data();
          const float* a1 = a0 + n;
          const float* a2 = a1 + n;
          const size_t row = size_t(y) * w;
          for (int x = xa; x <= xb; ++x) {
            const size_t i = row + x;
            const float hh0 = hl ? hl[i] : 0.0f;
            if (!g.valid[i] || hh0 >= min_h) continue;
            const float sw_ = a0[x - xa];
            if (!(sw_ > 0.0f)) continue;  // keeps the temporal estimate
            const float mean = a1[x - xa] / sw_;
            const float mean2 = a2[x - xa] / sw_;
            const float hh = std::max(hh0, 1.0f);
            var_[i] = std::max(0.0f, mean2 - mean * mean) * (4.0f / hh) * (kf ? kf[i] : 1.0f);
          }
        }
      },
      tbb::simple_partitioner());  // blocks independent of threads and timing (see parallel_rows)
}

// The a-trous iterations (SVGF section 4.3, Dammertz et al. 2010): iteration i has step 2^i.
// The values ping-pong between the work planes; the first iteration writes the value history
// when it is fed back (feedback "first_iteration"), the last one the 8-bit output.
//
// light_history (svgf_ao, DHR-S 3.3 last paragraph): pixels whose history is at least
// light_history frames long (cls_ 0, with the invalid ones) get the first iteration with the
// 3x3 kernel and keep its result; the others (cls_ 1) get every iteration with the configured
// kernel. The first iteration runs twice over the image, each run filtering only its own
// pixels (and skipping blocks without one); it writes its result into every plane a later
// iteration may write, so a later iteration need only write the pixels it filters.
void FilterPipeline::atrous_iterations(uint8_t* out) {
  const int n_it = s_.iterations;
  const bool lt = light();
  float* hv = hv_[cur_].data();
  float* w0 = work_v_[0].data();
  float* w1 = work_v_[1].data();
  float* wv0 = work_var_[0].data();
  float* wv1 = work_var_[1].data();
  const float* v_in = !s_.temporal ? input_.data() : (feedback() ? value_.data() : hv);
  float* v0 = feedback() ? hv : w0;  // the first iteration's output
  AtrousArgs a = atrous_args(1, s_.kernel_radius);
  a.v_in = v_in;
  a.var_in = var_.data();
  a.v_out = v0;
  a.var_out = wv0;
  if (lt && n_it > 1) {  // later iterations write only their own pixels
    a.v_out2 = v0 == hv ? w0 : w1;
    a.v_out3 = v0 == hv ? w1 : nullptr;
    a.var_out2 = wv1;
  }
  if (lt && s_.kernel_radius != 1) {
    AtrousArgs a3 = a;  // the long-history pixels: 3x3
    a3.radius = 1;
    a3.k1d = kK3 + 1;
    a3.cls = cls_.data();
    a3.active_cls = 0;
    atrous_pass(a3);
    a.cls = cls_.data();
    a.active_cls = 1;
  }
  a.u8_out = n_it == 1 ? out : nullptr;
  atrous_pass(a);
  const float* v = v0;
  const float* var = wv0;
  for (int it = 1; it < n_it; ++it) {
    AtrousArgs b = atrous_args(1 << it, s_.kernel_radius);
    float* v_out = v == w0 ? w1 : w0;
    float* var_out = var == wv0 ? wv1 : wv0;
    b.v_in = v;
    b.var_in = var;
    b.v_out = v_out;
    b.var_out = it + 1 == n_it ? nullptr : var_out;  // the last iteration's variance is not used
    if (lt) {
      b.cls = cls_.data();
      b.active_cls = 1;
    }
    b.u8_out = it + 1 == n_it ? out : nullptr;
    atrous_pass(b);
    v = v_out;
    var = var_out;
  }
}

// One edge-aware a-trous iteration: kernel h (B3-spline 5x5 or 3x3) at step `step`, weight
//   w = h * exp(-|z_p - z_q| / (sigma_z |grad z_p| step |offset|) - |l_p - l_q| / (sigma_l sqrt(g3x3(var_p)) + eps))
//         * max(0, n_p . n_q)^sigma_n,
// value = sum w l_q / sum w, variance = sum w^2 var_q / (sum w)^2. The variance is
// prefiltered with a 3x3 Gaussian over valid pixels (SVGF) inside the rows (AtrousArgs).
AtrousArgs FilterPipeline::atrous_args(int step, int radius) const {
  const Guide& g = guide_[cur_];
  AtrousArgs a;
  a.width = w_;
  a.height = h_;
  a.step = step;
  a.radius = radius;
  a.normal_squarings = normal_squarings();
  a.k1d = radius == 2 ? kB3 + 2 : kK3 + 1;
  a.depth = g.depth.data();
  a.nx = g.nx.data();
  a.ny = g.ny.data();
  a.nz = g.nz.data();
  a.valid = g.valid.data();
  a.inv_phi_z = inv_phi_z_.data();
  a.inv_valid_k = inv_valid_k_.data();
  a.sigma_l = s_.sigma_l;
  a.eps_l = kEpsL;
  a.fast_weights = s_.fast_weights;
  return a;
}

void FilterPipeline::atrous_pass(const AtrousArgs& a) const {
  const int w = w_;
  tbb::parallel_for(
      tbb::blocked_range<int>(0, h_, 4),
      [&](const tbb::blocked_range<int>& range) {
        // Scratch, fully written before it is read: no need to clear it.
        const auto acc = std::make_unique_for_overwrite<float[]>(size_t(w) * 4);
        atrous_rows(a, range.begin(), range.end(), acc.get());
      },
      tbb::simple_partitioner());  // blocks independent of threads and timing (see parallel_rows)
}

int FilterPipeline::normal_squarings() const { return std::countr_zero(unsigned(s_.sigma_n)); }

}  // namespace dhr::denoise
