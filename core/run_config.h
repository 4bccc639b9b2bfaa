// The settings of one run (one simulation, or one live session): what the experiment files'
// "run" object holds (core/experiment.h reads it; docs/architecture.md lists the keys).
#pragma once

#include "core/network.h"
#include "core/passes.h"
#include "core/trace.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>

namespace dhr {

struct BackendChoice {
  std::string name;
  nlohmann::json params = nlohmann::json::object();
};

// The backends of one pass: how it is coded, denoised (on the server) and predicted (on the
// client).
struct PassChoice {
  BackendChoice codec, denoiser, predictor;
};

struct SimConfig {
  std::string mode = "hybrid";  // hybrid | remote
  int width = 320;
  int height = 180;
  int frames = 60;           // displayed and scored frames
  int warmup_frames = 0;     // run before them, not scored, not counted
  double display_hz = 60.0;
  double start_time_s = 0.0;  // scene time of the first (warm-up) frame
  uint64_t seed = 1;

  TraceSettings trace;  // seed and frame are set per frame from `seed` and the frame index
  // Per pass: codec, denoiser (AO and soft visibility; bitmasks are never denoised) and
  // predictor. Remote mode uses `colour` (codec and predictor) and the AO denoiser.
  BackendChoice visibility_codec{"lz4"}, ao_codec{"lz4"}, colour_codec{"h264"};
  BackendChoice ao_denoiser{"none"}, visibility_denoiser{"none"};
  BackendChoice predictor{"reprojection"}, colour_predictor{"none"};

  enum class ServerTiming { Fixed, Measured };
  ServerTiming server_timing = ServerTiming::Fixed;
  double server_fixed_ms = 10.0;  // Fixed: the server's compute time per frame (virtual)

  LinkConfig uplink, downlink;
  size_t max_payload_bytes = 1200;
  int history_frames = 64;     // client G-buffers kept for prediction
  int score_every = 1;         // quality against the local reference on every n-th frame
  int ground_truth_every = 0;  // against the ground truth on every n-th frame (0: never)
  int ground_truth_ao_rays = 256;
  int ground_truth_samples_per_light = 64;
  bool keep_images = false;    // keep one frame's images (RunResult::images) for image grids
  std::string cache_dir;       // ground truths on disk; empty: default_cache_dir() (core/reference.h)

  nlohmann::json to_json() const;
  // The backends of the pass with `meaning` (colour: the remote baseline's codec and predictor;
  // it is never denoised itself, its inputs are).
  PassChoice choice(PassMeaning meaning) const {
    switch (meaning) {
      case PassMeaning::Visibility: return {visibility_codec, visibility_denoiser, predictor};
      case PassMeaning::Ao: return {ao_codec, ao_denoiser, predictor};
      case PassMeaning::Colour: break;
    }
    return {colour_codec, {"none"}, colour_predictor};
  }
  // `trace` with this run's seed and client frame `frame`: what the server traces for that
  // frame (the simulator, live mode and the local references all use it).
  TraceSettings trace_for_frame(uint32_t frame) const {
    TraceSettings t = trace;
    t.seed = seed;
    t.frame = frame;
    return t;
  }
};

}  // namespace dhr
