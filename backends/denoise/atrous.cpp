// atrous: the edge-aware a-trous wavelet filter alone, without any temporal part (Dammertz et
// al. 2010, "Edge-Avoiding A-Trous Wavelet Transform for fast Global Illumination
// Filtering", as used in SVGF, Schied et al. 2017, section 4.3). Filter in filters.h.
//
// Every frame stands alone: the variance of the AO value is estimated spatially from the
// current frame (7x7 window weighted by depth and normal only, DHR-S section 3.3, boosted by 4
// as SVGF does for a pixel without history), then `iterations` passes of the 5x5 B3-spline
// (or 3x3) kernel at step 2^i with depth, normal and variance-driven AO edge-stopping weights
// (see svgf_ao.cpp for the formula). This is exactly what svgf_ao outputs on a frame without
// history. Invalid (background / NaN) pixels pass through unfiltered.
//
// Parameters: iterations 5 (1..10), kernel_radius 2 (1: 3x3, 2: 5x5), sigma_l 4, sigma_n 128,
// sigma_z 1, variance_radius 3.
// Example: {"name": "atrous", "params": {"iterations": 3}}
#include "backends/denoise/filters.h"

namespace dhr {
namespace {

class AtrousDenoiser final : public Denoiser {
 public:
  explicit AtrousDenoiser(const denoise::FilterSettings& s) : pipeline_(s) {}
  void denoise(const DenoiseInput& in, ImageU8& out) override { pipeline_.run(in, out); }
  void reset() override { pipeline_.reset(); }

 private:
  denoise::FilterPipeline pipeline_;
};

}  // namespace

DenoiserEntry make_atrous_denoiser() {
  return {"atrous", "edge-aware a-trous wavelet filter (depth/normal/variance guided), no temporal part",
          denoise::spatial_param_specs(5, 2), [](const Params& p) {
            denoise::FilterSettings s;
            s.temporal = false;
            denoise::read_spatial_params(p, s);
            return std::make_unique<AtrousDenoiser>(s);
          }};
}

}  // namespace dhr
