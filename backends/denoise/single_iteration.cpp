// single_iteration: the lightweight AO denoiser the DHR-S paper proposes at the end of
// section 3.3 ("just one iteration of filter and also using a smaller kernel size", for when
// most pixels have a long temporal history). Read as: svgf_ao's temporal accumulation and
// variance estimate unchanged (reprojection, moments, spatial variance where the history is
// short), followed by ONE edge-aware a-trous iteration with the 3x3 kernel (1/4, 1/2, 1/4),
// step 1; that iteration's output is fed back into the history, as in SVGF. Pixels with a
// short history therefore get only a 3x3 spatial filter: the paper's trade of quality at
// disocclusions for time. Filter in filters.h; formula in svgf_ao.cpp.
//
// Parameters: alpha 0.2, history_cap 32, depth_tolerance 0.1, normal_threshold 0.9,
// kernel_radius 1 (2 gives a 5x5 kernel), sigma_l 4, sigma_n 128, sigma_z 1, variance_radius 3.
// Example: {"name": "single_iteration", "params": {"alpha": 0.1}}
#include "backends/denoise/filters.h"

namespace dhr {
namespace {

class SingleIterationDenoiser final : public Denoiser {
 public:
  explicit SingleIterationDenoiser(const denoise::FilterSettings& s) : pipeline_(s) {}
  void denoise(const DenoiseInput& in, ImageU8& out) override { pipeline_.run(in, out); }
  void reset() override { pipeline_.reset(); }

 private:
  denoise::FilterPipeline pipeline_;
};

}  // namespace

DenoiserEntry make_single_iteration_denoiser() {
  std::vector<ParamSpec> specs = denoise::temporal_param_specs();
  for (auto& s : denoise::spatial_param_specs(1, 1))
    if (s.name != "iterations") specs.push_back(std::move(s));
  return {"single_iteration",
          "lightweight AO denoiser (DHR-S 3.3): temporal accumulation + one 3x3 edge-aware a-trous pass",
          std::move(specs), [](const Params& p) {
            denoise::FilterSettings s;
            s.temporal = true;
            denoise::read_temporal_params(p, s);
            denoise::read_spatial_params(p, s, /*with_iterations=*/false);
            s.iterations = 1;
            return std::make_unique<SingleIterationDenoiser>(s);
          }};
}

}  // namespace dhr
