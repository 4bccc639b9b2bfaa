// temporal: temporal accumulation only -- svgf_ao's first stage (Schied et al. 2017, section
// 4.1) with no spatial filter. The pixel is reprojected through the G-buffer's motion vector,
// the 2x2 previous taps are blended bilinearly, each accepted only when depth (relative
// tolerance), normal (dot threshold) and object id agree; the output is the exponential moving
// average with weight max(alpha, 1/history), history capped at history_cap. A disoccluded
// pixel, the first frame and every frame after history_valid = false or reset() output the
// rescaled input (what `none` gives, within rounding). Filter in filters.h.
//
// Parameters: alpha 0.2, history_cap 32, depth_tolerance 0.1, normal_threshold 0.9.
// Example: {"name": "temporal", "params": {"alpha": 0.1, "history_cap": 64}}
#include "backends/denoise/filters.h"

namespace dhr {
namespace {

class TemporalDenoiser final : public Denoiser {
 public:
  explicit TemporalDenoiser(const denoise::FilterSettings& s) : pipeline_(s) {}
  void denoise(const DenoiseInput& in, ImageU8& out) override { pipeline_.run(in, out); }
  void reset() override { pipeline_.reset(); }

 private:
  denoise::FilterPipeline pipeline_;
};

}  // namespace

DenoiserEntry make_temporal_denoiser() {
  return {"temporal", "temporal accumulation only: reprojected exponential moving average, no spatial filter",
          denoise::temporal_param_specs(), [](const Params& p) {
            denoise::FilterSettings s;
            s.temporal = true;
            s.iterations = 0;
            s.feedback_filtered = false;
            denoise::read_temporal_params(p, s);
            return std::make_unique<TemporalDenoiser>(s);
          }};
}

}  // namespace dhr
