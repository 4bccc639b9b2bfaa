// svgf_ao: the DHR-S paper's modified SVGF for ambient occlusion (section 3.3), after Schied
// et al. 2017, "Spatiotemporal Variance-Guided Filtering: Real-Time Reconstruction for
// Path-Traced Global Illumination" (HPG 2017). Filter in filters.h.
//
// Per frame: (1) temporal accumulation -- the pixel is reprojected through the G-buffer's
// motion vector, the 2x2 previous taps are blended bilinearly, each accepted only when its
// depth (relative tolerance), normal (dot threshold) and object id agree; an exponential
// moving average with weight max(alpha, 1/history) over the AO value and its first and second
// moments, history length capped at history_cap; (2) variance = (m2 - m1^2) k (clamped >= 0),
// or, where the history is shorter than 4 frames, estimated spatially in a 7x7 window
// weighted by depth and normal, boosted by 4/history (as SVGF does), times k. k is the
// variance of the accumulated value relative to one frame's (k' = (1 - a)^2 k + a^2 per EMA
// step, reprojected with the history; 1/h while the EMA is a plain mean, alpha/(2 - alpha) =
// 0.11 at steady state). SVGF uses the per-frame variance as is; scaling it by k is this
// implementation's choice: the a-trous range term then relaxes as the history converges, so
// with a static camera the error keeps falling instead of levelling off at the blur of a
// filter tuned for one frame's noise (tests/backends/test_denoisers.cpp, StaticCamera...); (3) `iterations`
// edge-aware a-trous passes (5x5 B3-spline kernel, step 2^i) whose weights are
//   exp(-|z_p - z_q| / (sigma_z |grad z| |offset|) - |l_p - l_q| / (sigma_l sqrt(g3x3(var)) + 1e-4))
//   * max(0, n_p . n_q)^sigma_n,
// with the variance filtered along (sum w^2 var / (sum w)^2); (4) the output of the FIRST
// a-trous iteration is fed back into the value history (as SVGF does); the moments history
// stays unfiltered. Output rounded to 0..255 (255 = 1.0).
//
// How section 3.3's modification is read: SVGF's signal is colour and its variance is that of
// luminance; the paper says "the variance computation were changed to no longer consider
// luminance ... Instead, it uses differences in depth and surface normals to calculate the
// variance at each pixel". Here: (a) the signal whose moments and variance are computed is the
// AO value itself (one channel: there is no luminance to take); (b) the spatial variance
// estimate (short history) is weighted by depth and normal differences only -- no
// luminance/colour/AO-value weight, unlike SVGF's which also weights by luminance; (c) the
// a-trous edge-stopping keeps the variance-driven range term, applied to the AO value (the
// paper keeps "the variance calculated ... drive the weights in the kernel"); sigma_l = 0
// removes it and leaves a purely depth/normal-guided filter.
//
// light_history = L (0 = off, the default): the lightweight path the paper proposes at the end
// of section 3.3 ("switch to a more lightweight denoiser for ambient occlusion due to many of
// the pixels having a high number of temporal samples ... just one iteration of filter and
// also using a smaller kernel size"), per pixel: a pixel whose history is at least L frames
// long gets ONE a-trous iteration with the 3x3 kernel (what single_iteration does) and keeps
// its result; the others get all `iterations` with the configured kernel. Iterations 2.. run
// only over the 8/16-pixel blocks of a row that hold a short-history pixel. Each pixel feeds
// its own first-iteration output back into the history. A pixel's result depends neither on
// its neighbours' path nor on the thread count or vector width. The first frame after a reset
// (history 1) is the full filter for any L >= 2; L = 1 makes every frame single_iteration's;
// L above history_cap never applies. The price (tests/backends/test_denoisers.cpp, LightHistory...):
// with a still camera the error settles at single_iteration's level (at 4 rays about 1.8x
// that of the full filter) instead of falling further.
//
// Invalid pixels (background, or a NaN/Inf/zero depth or normal) pass through unfiltered and
// never enter a neighbour's filter or the history. Values above full_scale count as
// full_scale. history_valid = false, reset() and a change of image size drop the history;
// the first frame after that equals the `atrous` denoiser with the same parameters.
//
// Parameters: alpha 0.2, history_cap 32, depth_tolerance 0.1, normal_threshold 0.9,
// iterations 5 (1..10), kernel_radius 2 (1: 3x3), sigma_l 4 (0 = no AO range term),
// sigma_n 128 (a power of two), sigma_z 1 (0 = no depth term), variance_radius 3 (7x7),
// feedback "first_iteration" | "accumulated", light_history 0 (0..1024 frames; 0 = off).
// Example: {"name": "svgf_ao", "params": {"iterations": 4, "alpha": 0.1}}
//          {"name": "svgf_ao", "params": {"light_history": 8}}
#include "backends/denoise/filters.h"

namespace dhr {
namespace {

class SvgfAoDenoiser final : public Denoiser {
 public:
  explicit SvgfAoDenoiser(const denoise::FilterSettings& s) : pipeline_(s) {}
  void denoise(const DenoiseInput& in, ImageU8& out) override { pipeline_.run(in, out); }
  void reset() override { pipeline_.reset(); }

 private:
  denoise::FilterPipeline pipeline_;
};

}  // namespace

DenoiserEntry make_svgf_ao_denoiser() {
  std::vector<ParamSpec> specs = denoise::temporal_param_specs();
  for (auto& s : denoise::spatial_param_specs(5, 2)) specs.push_back(std::move(s));
  specs.push_back(ParamSpec::integer(
      "light_history", 0, 0, 1024,
      "DHR-S 3.3's lightweight path: pixels with at least this many frames of history get one 3x3 a-trous "
      "iteration (the others the full `iterations`); 0 = off. Above history_cap it never applies"));
  specs.push_back(ParamSpec::choice("feedback", "first_iteration", {"first_iteration", "accumulated"},
                                    "what the value history keeps: the first a-trous iteration's output "
                                    "(SVGF) or the unfiltered temporal average"));
  return {"svgf_ao",
          "modified SVGF for AO (DHR-S 3.3): reprojected temporal accumulation, AO variance, "
          "depth/normal-guided a-trous",
          std::move(specs), [](const Params& p) {
            denoise::FilterSettings s;
            s.temporal = true;
            denoise::read_temporal_params(p, s);
            denoise::read_spatial_params(p, s);
            s.feedback_filtered = p.get_string("feedback") == "first_iteration";
            s.light_history = p.get_int("light_history");
            return std::make_unique<SvgfAoDenoiser>(s);
          }};
}

}  // namespace dhr
