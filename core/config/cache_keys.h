// The cache keys of a run (TraceCache, core/sim/frame_loop.h): what each value a run computes
// depends on, as a string, so that runs of a sweep that would compute the same bits share one.
// Built once per run from its plan (CacheKeys::of) and read by the simulator's stages; nothing
// else names a cached value.
//
// Every key starts with the scene and takes the run's settings as keyed_config sees them (a
// setting left to the scene, such as trace.ao_rays 0, as the scene's value), and of those only
// the ones flagged in core/config/run_config.cpp as changing the traced buffers (kInTraceKey) or
// the ground truth (kInTruthKey).
#pragma once

#include "core/config/run_config.h"
#include "core/config/run_plan.h"
#include "core/scene/scene.h"

#include <string>
#include <string_view>
#include <vector>

namespace dhr {

// Bump when tracing, rasterizing or the cache file format changes: disk entries written by an
// older version are then never read (the key is stored in the file and compared).
// 2: ray offsets scaled by the hit triangle's own error. 3: scenes with moving objects
// in Embree's two-level layout (RtSceneOptions::static_child).
constexpr int kTraceCacheVersion = 3;

// The run's settings as its cache keys see them: what the run leaves to the scene
// (trace.ao_rays and trace.ao_radius_m 0: the scene's ao block) set to the scene's values, as
// plan_passes resolves them. A run that names the scene's own values (paper's "F3 AO radius 2 m"
// on temple, whose ao.radius_m is 2) then shares the traces, denoised passes and references of
// one that leaves them to the scene: the same plan, so the same bits.
SimConfig keyed_config(const SimConfig& config, const Scene& scene);

// Which displayed frames (0 = the first after warm-up) a run scores against the local
// reference, and which of those also against the ground truth.
bool scores_frame(const SimConfig& c, int frame);
bool scores_ground_truth(const SimConfig& c, int frame);

struct CacheKeys {
  std::string scene_key;  // the scene as the runner names it
  SimConfig keyed;        // keyed_config of the run's settings

  static CacheKeys of(const RunPlan& plan, std::string scene_key);
  static CacheKeys of(const SimConfig& config, const Scene& scene, std::string scene_key);

  // One traced pass of client frame `frame`: the settings of every pass and its own
  // (pass_settings_key), so runs that differ in another pass's settings share it.
  std::string pass_trace(int frame, std::string_view pass) const;
  // The local reference of client frame `frame`: the traced passes of frames 0..frame, the
  // denoisers and, for a pass traced at reduced resolution, the upsampling filter
  // (core/pipeline/pipeline.h, LocalReference): all it depends on.
  std::string local_reference(int frame) const;
  // What a traced pass's denoised buffers depend on besides the frames fed (DenoiseSharing): the
  // pass's trace key without the frame, and its denoiser.
  std::string denoise_chain(std::string_view pass) const;
  // The ground truth of client frame `frame`.
  std::string truth(int frame) const;
  // One key per FLIP score the run will compute, in order: the local reference of every scored
  // frame and the ground truth of every frame scored against it (TraceCache::expect_flip_reads).
  std::vector<std::string> flip_references() const;
};

}  // namespace dhr
