// The SVGF-family filter shared by the denoisers svgf_ao, atrous, single_iteration and
// temporal: G-buffer sanitising, temporal accumulation with reprojection, moment-based and
// spatial variance estimates, and the edge-aware a-trous wavelet pass. After Schied et al.
// 2017, "Spatiotemporal Variance-Guided Filtering" (SVGF), as modified for ambient occlusion in
// the DHR-S paper, section 3.3 (see svgf_ao.cpp for how that modification is read).
//
// This header declares what the four backends and tests/backends/test_denoisers.cpp use; the code is
// compiled once, in two layers:
//   filters.cpp          the guide (G-buffer planes), temporal accumulation, variance
//                        estimate, the a-trous iterations' driver (FilterPipeline) and the
//                        parameters;
//   filters_kernels.cpp  the hot kernels: a-trous rows and spatial moments, 8 lanes (AVX2 or
//                        baseline) and 16 lanes (AVX-512, chosen at run time);
//   filters_accumulate.cpp  the temporal accumulation's rows in 16 (AVX-512) or 8 (AVX2)
//                        lanes, chosen at run time;
//   filters_simd.h       the lane types and the bit-exact vector maths both files share.
// Everything works on float32 planes in [0, 1] (1 = unoccluded / fully visible), and every
// result is bit-identical for any thread count and vector width (filters_simd.h says how).
//
// Internal to backends/denoise/ (and its tests): not a public API.
#pragma once

#include "core/backend/backend.h"
#include "core/base/params.h"
#include "core/buffers/image.h"

#include <cstdint>
#include <vector>

namespace dhr::denoise {

// ---------------------------------------------------------------- settings and parameters

struct FilterSettings {
  bool temporal = true;           // accumulate over frames (svgf_ao, single_iteration, temporal)
  int iterations = 5;             // a-trous iterations; 0 = no spatial filter (temporal)
  int kernel_radius = 2;          // 2: 5x5 B3-spline kernel; 1: 3x3 (1/4, 1/2, 1/4)
  float alpha = 0.2f;             // EMA weight of the new frame (value and moments)
  int history_cap = 32;           // history length is capped here (frames)
  float depth_tolerance = 0.1f;   // reprojection: |z_prev - z| <= tol * z
  float normal_threshold = 0.9f;  // reprojection: dot(n_prev, n) >= threshold
  float sigma_l = 4.0f;           // AO edge-stopping: |l_p - l_q| / (sigma_l sqrt(var) + eps); 0 = off
  int sigma_n = 128;              // normal edge-stopping: max(0, n_p . n_q)^sigma_n, a power of two
  float sigma_z = 1.0f;           // depth edge-stopping: |z_p - z_q| / (sigma_z |grad z| |offset|); 0 = off
  int variance_radius = 3;        // spatial variance window (2r + 1)^2 where history is short
  int min_history = 4;            // below this many frames the variance is estimated spatially
  bool feedback_filtered = true;  // history keeps the first a-trous iteration's output (SVGF)
  // svgf_ao's lightweight path (DHR-S 3.3, last paragraph): pixels with at least this many
  // frames of history get one 3x3 a-trous iteration instead of `iterations`; 0 = off.
  int light_history = 0;
  // The a-trous weights with fused multiply-adds and a degree-3 exponential (filters_simd.h,
  // fast_weight); false: separate products and sums and exp_neg. The same filter, its weights
  // rounded differently; less CPU (docs/performance.md, "svgf_ao's fast weights").
  bool fast_weights = true;
};

// The parameters of the temporal part (alpha, history_cap, depth_tolerance, normal_threshold)
// and of the spatial part (iterations, kernel_radius, sigma_l, sigma_n, sigma_z,
// variance_radius), with the defaults and ranges every backend shares.
std::vector<ParamSpec> temporal_param_specs();
std::vector<ParamSpec> spatial_param_specs(int default_iterations, int default_radius);
void read_temporal_params(const Params& p, FilterSettings& s);
// with_iterations = false for single_iteration, which has no "iterations" key.
void read_spatial_params(const Params& p, FilterSettings& s, bool with_iterations = true);

// ---------------------------------------------------------------- the kernels (filters_kernels.cpp)

// ---- One a-trous iteration over whole rows.
struct AtrousArgs {
  int width = 0, height = 0, step = 1, radius = 2, normal_squarings = 7;
  const float* k1d = nullptr;  // k1d[-radius..radius]
  const float *depth = nullptr, *nx = nullptr, *ny = nullptr, *nz = nullptr;
  const uint8_t* valid = nullptr;
  const float* inv_phi_z = nullptr;
  // The AO phi per pixel: given as a plane (inv_phi_l), or, when that is null, computed row by
  // row from var_in (3x3 Gaussian over valid pixels, inv_phi_l_lanes) with inv_valid_k (0 at an
  // invalid pixel, which gets phi^-1 = 0) and sigma_l (sigma_l = 0: no AO term, phi^-1 = 0). The
  // a-trous taps read it at the centre pixel only, so each row needs its own row alone (no extra
  // pass over the image).
  const float* inv_phi_l = nullptr;
  const float* inv_valid_k = nullptr;
  float sigma_l = 0.0f, eps_l = 1e-4f;
  const float *v_in = nullptr, *var_in = nullptr;
  // var_out null: the variance is not wanted (the last iteration's); it is then neither written
  // nor, on the 16-lane kernel, summed.
  float *v_out = nullptr, *var_out = nullptr;
  // Optional, all may be null. cls: pixels whose cls equals active_cls are filtered; the others
  // are left as they are in v_out / var_out (svgf_ao's light_history path: a pixel's result
  // never depends on which other pixels are filtered, nor on the vector width). Rows and vector
  // blocks without an active pixel are skipped.
  const uint8_t* cls = nullptr;
  uint8_t active_cls = 1;
  float *v_out2 = nullptr, *v_out3 = nullptr, *var_out2 = nullptr;  // copies of v_out / var_out
  uint8_t* u8_out = nullptr;  // the result in 0..255 (to_u8) of every pixel (inactive: of v_out as it is)
  bool fast_weights = false;  // FilterSettings::fast_weights
};

// Rows [y0, y1) of one a-trous iteration; acc holds 4 * width floats of scratch (need not be
// initialised). With the fastest kernel the CPU has (16 lanes on AVX-512, unrolled 8 lanes on
// AVX2; same bits either way); fastest = false forces the portable 8-wide kernel (tests compare
// them).
void atrous_rows(const AtrousArgs& a, int y0, int y1, float* acc, bool fastest = true);

// ---- The spatial moments of one row span [xa, xb] in a (2r+1)^2 window, weighted by depth
// and normal only (DHR-S 3.3).
struct MomentArgs {
  int width = 0, height = 0, radius = 3, normal_squarings = 7;
  const float *depth = nullptr, *nx = nullptr, *ny = nullptr, *nz = nullptr, *inv_phi_z = nullptr;
  const float* m1 = nullptr;
  const float* m2 = nullptr;  // null: m2 = m1^2 (one frame)
};

// acc: 3 * (xb - xa + 1) floats, zeroed by the caller: sum w, sum w m1, sum w m2. With the
// widest vectors the CPU has (same bits either way).
void moment_span(const MomentArgs& a, int y, int xa, int xb, float* acc, bool use_avx512 = true);

// ---- The temporal accumulation's rows (filters_accumulate.cpp).
// What FilterPipeline::accumulate's rows read and write (its locals of the same names; the
// steps are its reproject and finish lambdas').
struct AccumulateArgs {
  const glm::vec2* mo;
  const uint8_t* noisy;
  const uint8_t* cvalid;
  const uint32_t *cid, *pid;
  const float *cz, *pz, *cnx, *cny, *cnz, *pnx, *pny, *pnz;
  const float *pv, *pm1, *pm2, *ph, *pk;
  float *nv, *nm1, *nm2, *nh, *nk, *var;
  uint8_t *cls, *out;
  int w, h, fs;
  float inv_fs, tol, nthr, alpha, cap, min_h, light_h, wmax, hmax;
  bool hist, spatial, lt;
};

// Pixels [0, n) of row y of the accumulation, n a multiple of the lanes, with the widest
// vectors this CPU has (16 lanes on AVX-512, 8 on AVX2; the same bits as the caller's scalar
// loop, which does [n, w)); widens [xa, xb] to the pixels that need the spatial variance.
// Returns n: 0 without either (and in sanitizer or non-GCC builds).
int accumulate_row_vector(const AccumulateArgs& a, int y, int& xa, int& xb);

// Whether atrous_rows and moment_span take their 16-lane AVX-512 kernels on this CPU (GCC
// builds without sanitizers on x86-64 only).
bool cpu_has_avx512();
// Whether the CPU has AVX2 (the same builds only): atrous_rows' unrolled 8-lane kernel and the
// temporal accumulation's 8-lane rows where AVX-512 is missing.
bool cpu_has_avx2();
// Tests only: on, both of the above answer false, so every kernel takes its portable path (the
// results must not change: tests compare the two).
void force_portable_kernels(bool on);

// A value in [0, 1] to 0..255, rounded to nearest; NaN gives 0. Inline: the kernels call it
// per pixel.
[[gnu::always_inline]] inline uint8_t to_u8(float v01) {
  float v = v01 * 255.0f + 0.5f;
  v = v >= 0.0f ? v : 0.0f;  // also maps NaN to 0
  v = v <= 255.0f ? v : 255.0f;
  return uint8_t(v);
}

// ---------------------------------------------------------------- the pipeline (filters.cpp)

// The G-buffer as float planes, sanitised: a pixel is valid when it shows an object (id not
// kBackgroundId), its depth is finite and in (0, 1e30) and its normal is finite and of
// length 0.5..2 (renormalised). Invalid pixels get depth 0, normal (0, 0, 0) and id
// kBackgroundId, so a weight computed from them is 0 and nothing NaN ever enters a filter.
struct Guide {
  int width = 0;
  int height = 0;
  PixelVector<float> depth, nx, ny, nz;
  PixelVector<float> valid_f;  // 1 at a valid pixel, else 0
  PixelVector<uint32_t> id;
  PixelVector<uint8_t> valid;

  void resize(int w, int h);
};

// One frame: guide -> temporal accumulation (or the rescaled input) -> variance -> a-trous
// iterations -> 8 bits (the steps are described at their definitions in filters.cpp).
class FilterPipeline {
 public:
  static constexpr float kEpsL = 1e-4f;  // added to sigma_l sqrt(var) (AO units, 1 = 1.0)

  explicit FilterPipeline(const FilterSettings& s) : s_(s) {}

  void reset() { history_ok_ = false; }
  void run(const DenoiseInput& in, ImageU8& out);
  const FilterSettings& settings() const { return s_; }

 private:
  void allocate(int w, int h);
  bool light() const;
  bool feedback() const;
  void sanitize_input(const DenoiseInput& in, uint8_t* out);
  void accumulate(const DenoiseInput& in, uint8_t* out);
  void spatial_variance();
  void atrous_iterations(uint8_t* out);
  AtrousArgs atrous_args(int step, int radius) const;
  void atrous_pass(const AtrousArgs& a) const;
  int normal_squarings() const;

  FilterSettings s_;
  int w_ = -1, h_ = -1;
  int cur_ = 0;              // index of this frame's history/guide planes; cur_ ^ 1 = previous
  bool history_ok_ = false;  // the previous planes hold a usable frame
  Guide guide_[2];
  // input_: the rescaled input (spatial-only denoiser); value_: the accumulated value when the
  // first a-trous iteration is fed back into hv_.
  PixelVector<float> input_, value_, var_, inv_phi_z_, inv_valid_k_;
  PixelVector<float> work_v_[2], work_var_[2];
  // History: value, moments, length, and the variance factor k of the accumulated value (the
  // variance of the EMA of independent samples is k times that of one sample).
  PixelVector<float> hv_[2], hm1_[2], hm2_[2], hist_[2], hk_[2];
  PixelVector<uint8_t> cls_;            // light_history: 1 = filtered by every iteration
  std::vector<int> span_lo_, span_hi_;  // per row: the pixels that need the spatial variance
};

}  // namespace dhr::denoise
