// The list of every backend: one line each. To add a backend, write one .cpp in
// backends/<kind>/ defining `dhr::CodecEntry make_<name>_codec()` (or DenoiserEntry /
// PredictorEntry), then add its line here. See docs/adding-a-backend.md.
#include "backends/register_all.h"

// Declares the entry function and adds what it returns to the registry (one line each).
#define DHR_CODEC(fn)              \
  do {                             \
    extern ::dhr::CodecEntry fn(); \
    r.codecs.add(fn());            \
  } while (0)
#define DHR_DENOISER(fn)              \
  do {                                \
    extern ::dhr::DenoiserEntry fn(); \
    r.denoisers.add(fn());            \
  } while (0)
#define DHR_PREDICTOR(fn)              \
  do {                                 \
    extern ::dhr::PredictorEntry fn(); \
    r.predictors.add(fn());            \
  } while (0)

namespace dhr {

void register_all_backends(Registries& r) {
  // Codecs (backends/codec/)
  DHR_CODEC(make_raw_codec);
  DHR_CODEC(make_lz4_codec);
  DHR_CODEC(make_zstd_codec);
  DHR_CODEC(make_h264_codec);
  DHR_CODEC(make_hevc_codec);
  DHR_CODEC(make_av1_codec);
  DHR_CODEC(make_delta_codec);
  DHR_CODEC(make_delta_video_codec);

  // Denoisers (backends/denoise/)
  DHR_DENOISER(make_none_denoiser);
  DHR_DENOISER(make_svgf_ao_denoiser);
  DHR_DENOISER(make_atrous_denoiser);
  DHR_DENOISER(make_single_iteration_denoiser);
  DHR_DENOISER(make_temporal_denoiser);

  // Predictors (backends/predict/)
  DHR_PREDICTOR(make_none_predictor);
  DHR_PREDICTOR(make_reprojection_predictor);
  DHR_PREDICTOR(make_rotation_warp_predictor);
  DHR_PREDICTOR(make_depth_warp_predictor);
}

const Registries& registries() {
  static const Registries all = [] {
    Registries r;
    register_all_backends(r);
    return r;
  }();
  return all;
}

}  // namespace dhr
