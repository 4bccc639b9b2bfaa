// The DHR frame loop on a virtual clock (docs/architecture.md, "The frame loop"): a client that rasterizes every
// frame, a server that traces, denoises, encodes and packetizes the passes for the newest
// camera it has, and a simulated network between them (core/net/network.h). Every displayed frame
// is composited and scored against the local reference and, every n-th frame, the ground truth.
//
// Virtual time (ms) drives the display rate, the network and the server schedule; wall time
// measures what each stage costs on this machine. They are kept apart: a FrameRecord's *_ms
// fields named "age" or "t" are virtual, StageTimes are wall time.
//
// Client frame k, at t_k = (warmup + k) * 1000 / display_hz:
//   gbuf_k = rasterize(scene, camera(t_k))
//   uplink  <- CameraMessage{k} (one datagram; carries a keyframe request after a loss)
//   server catches up to t_k (below); datagrams that arrived by t_k go to the assembler
//   each completed pass frame is decoded in order (stateful codecs: a lost frame resets the
//   decoder, which then waits for the keyframe it asked for)
//   for each pass: predictor(newest decoded buffer of frame j, gbuf_j, gbuf_k); none yet or
//   gbuf_j no longer in the history: the local fallback (fully lit, AO 1), counted
//   image_k = composite(gbuf_k, passes) -> scored
// Server: when free, takes the newest camera that has arrived (older ones are dropped), and
// spends its compute time (fixed, or the measured wall time of its stages) on it; its packets
// leave when it finishes. Traced buffers depend only on (scene, frame j, trace settings), so
// they are cached across runs (TraceCache): sweeps over codecs, denoisers, predictors and
// networks trace each frame once.
//
// Remote baseline (mode "remote"): the server also composites and streams only the colour
// frame; the client shows the newest one it has, warped by its colour predictor (none or
// rotation_warp). It has no scene, so nothing else is possible.
#pragma once

#include "core/backend/backend.h"
#include "core/buffers/gbuffer.h"
#include "core/config/cache_keys.h"
#include "core/config/run_config.h"
#include "core/config/run_plan.h"
#include "core/metrics/flip.h"
#include "core/net/network.h"
#include "core/pipeline/pipeline.h"
#include "core/results/results.h"
#include "core/scene/scene.h"
#include "core/trace/trace.h"

#include <nlohmann/json.hpp>

#include <functional>
#include <map>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <vector>

namespace dhr {

class RtScene;

// Traced buffers and ground truths shared across runs of one process. Thread-safe.
class TraceCache {
 public:
  using Entry = TracedPasses;
  explicit TraceCache(size_t max_bytes = size_t(4) << 30) : max_bytes_(max_bytes) {}
  // Also keep traced buffers on disk in `dir` (created when needed), so that later processes
  // never trace the same frame twice. Files are checked (magic, key, sizes, CRC-32C) when read;
  // a bad or foreign file is ignored and traced again. Several processes (on several machines,
  // over a shared filesystem) may share the folder: each file is written under a temporary name
  // and renamed, so a reader never sees part of one. Empty: memory only. The disk keys add the
  // tracer (embree_tracer(), core/trace/rt_scene.h: Embree's version and ISA, read here): machines of
  // two CPU kinds sharing the folder keep an entry each.
  void set_disk_dir(std::string dir);
  const std::string& disk_dir() const { return disk_dir_; }
  std::shared_ptr<const Entry> find(const std::string& key);
  void insert(const std::string& key, std::shared_ptr<const Entry> entry);
  std::shared_ptr<const ImageRGB8> find_image(const std::string& key);
  void insert_image(const std::string& key, std::shared_ptr<const ImageRGB8> image);
  // FLIP's half of the work on a reference image (flip_features), under the image's key: the
  // runs that score against the same local reference or ground truth compute it once.
  // Each find_flip counts as one read of its key. Once reads are announced (expect_flip_reads, by
  // the runner, from CacheKeys::flip_references of the runs to come), a key is kept only while announced
  // reads of it remain: insert_flip keeps nothing else (a key never announced included), and the
  // last read drops it. A cache with no announcement keeps every key, under the byte bound. The
  // features are the same either way (a dropped key is computed again if read after all):
  // memory, not results.
  std::shared_ptr<const FlipFeatures> find_flip(const std::string& key);
  void insert_flip(const std::string& key, std::shared_ptr<const FlipFeatures> features);
  void expect_flip_reads(const std::string& key, int reads);
  // Announced reads not yet made, and reads of keys never announced while some were.
  size_t flip_reads_pending() const;
  uint64_t flip_reads_unannounced() const;
  size_t flips_held() const;
  // A temporal denoiser's output for one pass and frame, under the key of the sequence that fed
  // it (DenoiseStage::share): the runs whose servers or local references feed the same frames
  // denoise them once.
  std::shared_ptr<const DenoisedPass> find_denoised(const std::string& key);
  void insert_denoised(const std::string& key, std::shared_ptr<const DenoisedPass> pass);
  size_t bytes() const { return bytes_; }

  // One computation per key among runs side by side (`dhrbench run --jobs`): a Claim on a key
  // waits while another thread holds one on it, then holds it until destroyed. A run takes one
  // around computing what it missed and looks again once it holds it: what the other run
  // inserted meanwhile is found, not computed twice. Claims nest only from a denoised pass's
  // to a trace's (a trace and a ground truth claim nothing while held), so they cannot deadlock.
  class Claim {
   public:
    Claim(TraceCache& cache, std::string key);
    ~Claim();
    Claim(const Claim&) = delete;
    Claim& operator=(const Claim&) = delete;

   private:
    TraceCache& cache_;
    std::string key_;
  };
  // `find()`, or on a miss `make()` (which inserts what it makes) under a Claim on `key`, after
  // looking once more: what a run beside this one made meanwhile is taken, not made again.
  template <class Find, class Make>
  auto find_or_make(const std::string& key, Find find, Make make) {
    if (auto hit = find()) return hit;
    const Claim claim(*this, key);
    if (auto hit = find()) return hit;
    return make();
  }

  // The client's G-buffers of one scene and camera path, for the runs after the one that
  // rasterized them (docs/performance.md, "Computed once per sweep"): the runs of a sweep
  // display the same frames.
  // Kept apart from the byte bound above (one run's client already holds as many: its
  // `history_frames`, 8 in remote mode): the first `capacity` frames offered for one scene and
  // size are kept -- a run visits its frames in order, so the first ones, not the most recent,
  // are what the next run finds -- and a frame of another scene or size starts over. Exact: the
  // rasterizer is deterministic, and a frame is found only for the same scene (key and object)
  // and RasterFrame (same_raster_frame). A cache built with max_bytes 0 keeps none.
  Rastered find_raster(const std::string& scene_key, const RasterFrame& frame);
  void keep_raster(const std::string& scene_key, const RasterFrame& frame, const Rastered& rastered, size_t capacity);
  uint64_t raster_hits() const;

 private:
  void evict_locked();
  std::shared_ptr<const Entry> read_disk(const std::string& key) const;
  void write_disk(const std::string& key, const Entry& entry) const;
  std::string disk_dir_;
  std::string disk_tag_;  // "|" + embree_tracer(), appended to every disk key
  mutable std::mutex mutex_;
  std::condition_variable claim_released_;
  std::set<std::string> claimed_;  // keys under a Claim
  size_t max_bytes_;
  size_t bytes_ = 0;
  uint64_t tick_ = 0;
  std::map<std::string, std::pair<uint64_t, std::shared_ptr<const Entry>>> entries_;
  std::map<std::string, std::pair<uint64_t, std::shared_ptr<const ImageRGB8>>> images_;
  std::map<std::string, std::pair<uint64_t, std::shared_ptr<const FlipFeatures>>> flips_;
  std::map<std::string, int> flip_reads_;  // announced reads left, by key
  bool flip_reads_announced_ = false;
  uint64_t flip_reads_unannounced_ = 0;
  std::map<std::string, std::pair<uint64_t, std::shared_ptr<const DenoisedPass>>> denoised_;
  struct KeptRaster {
    RasterFrame frame;
    Rastered rastered;
  };
  std::string raster_scene_;  // the scene key of every kept G-buffer
  std::vector<KeptRaster> rasters_;
  uint64_t raster_hits_ = 0;
};

// Progress callback: (frame index among warm-up + scored, total).
using ProgressFn = std::function<void(int, int)>;

// Runs the planned run (plan_run: validated, core/config/run_plan.h). `scene_key` identifies the
// scene's content for the cache (e.g. a hash of its file).
RunResult run_simulation(const RunPlan& plan, const std::string& scene_key, TraceCache& cache,
                         const Registries& registries, const ProgressFn& progress = {});
// Plans the run (plan_run throws dhr::Error listing every problem), then runs it.
RunResult run_simulation(const SimConfig& config, const Scene& scene, const std::string& scene_key, TraceCache& cache,
                         const Registries& registries, const ProgressFn& progress = {});

}  // namespace dhr
