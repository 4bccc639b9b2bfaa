#include "core/run_config.h"

namespace dhr {

nlohmann::json SimConfig::to_json() const {
  auto backend = [](const BackendChoice& b) { return nlohmann::json{{"name", b.name}, {"params", b.params}}; };
  return {{"mode", mode},
          {"width", width},
          {"height", height},
          {"frames", frames},
          {"warmup_frames", warmup_frames},
          {"display_hz", display_hz},
          {"start_time_s", start_time_s},
          {"seed", seed},
          {"trace",
           {{"ao_rays", trace.ao_rays},
            {"ao_radius_m", trace.ao_radius_m},
            {"soft_shadows", trace.soft_shadows},
            {"samples_per_light", trace.samples_per_light},
            {"visibility_pass", trace.visibility_pass},
            {"ao_pass", trace.ao_pass}}},
          {"visibility_codec", backend(visibility_codec)},
          {"ao_codec", backend(ao_codec)},
          {"colour_codec", backend(colour_codec)},
          {"ao_denoiser", backend(ao_denoiser)},
          {"visibility_denoiser", backend(visibility_denoiser)},
          {"predictor", backend(predictor)},
          {"colour_predictor", backend(colour_predictor)},
          {"server_timing", server_timing == ServerTiming::Fixed ? "fixed" : "measured"},
          {"server_fixed_ms", server_fixed_ms},
          {"uplink", uplink.to_json()},
          {"downlink", downlink.to_json()},
          {"max_payload_bytes", max_payload_bytes},
          {"history_frames", history_frames},
          {"score_every", score_every},
          {"ground_truth_every", ground_truth_every},
          {"ground_truth_ao_rays", ground_truth_ao_rays},
          {"ground_truth_samples_per_light", ground_truth_samples_per_light},
          {"cache_dir", cache_dir}};
}

}  // namespace dhr
