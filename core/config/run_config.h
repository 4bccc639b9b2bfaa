// The settings of one run (one simulation, or one live session): what the experiment files'
// "run" object holds. Every setting is declared once, in run_settings() (core/config/run_config.cpp):
// its key, type, range or choices, default (SimConfig's), doc and flags; the JSON reader and
// writer, plan_run's ranges, the trace and ground-truth cache keys, live mode's
// offer and `dhrbench settings` are all driven by that table.
#pragma once

#include "core/net/network.h"
#include "core/pass/passes.h"
#include "core/plan/trace_plan.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace dhr {

// The default backends of every pass (pass_types()'s defaults; colour: h264, predictor none).
std::map<std::string, PassChoice, std::less<>> default_pass_choices();

struct SimConfig {
  std::string mode = "hybrid";  // hybrid | remote
  int width = 320;
  int height = 180;
  int frames = 60;        // displayed and scored frames
  int warmup_frames = 0;  // run before them, not scored, not counted
  double display_hz = 60.0;
  double start_time_s = 0.0;  // scene time of the first (warm-up) frame
  // The camera's path runs this many times faster than the scene's clock (moving objects keep
  // the scene's): a second, faster head motion over the same scene.
  double camera_speed = 1.0;
  double camera_time_s(double scene_time_s) const {
    return start_time_s + (scene_time_s - start_time_s) * camera_speed;
  }
  uint64_t seed = 1;

  TraceSettings trace;  // seed and frame are set per frame from `seed` and the frame index
  // trace.ao_scale > 1: how the client (and the server's composite in remote mode, and the local
  // reference) upsamples the AO pass: joint_bilateral | bilinear | nearest (core/buffers/upsample.h).
  std::string ao_upsample = "joint_bilateral";
  // Per pass, by name (every entry of pass_types(), then colour): its codec, denoiser (8-bit
  // planes; bitmasks are never denoised) and predictor, the settings
  // passes.<name>.{codec,denoiser,predictor}. Remote mode uses colour's codec and predictor and
  // the traced passes' denoisers; colour itself is never denoised.
  std::map<std::string, PassChoice, std::less<>> passes = default_pass_choices();

  enum class ServerTiming { Fixed, Measured };
  ServerTiming server_timing = ServerTiming::Fixed;
  double server_fixed_ms = 10.0;  // Fixed: the server's compute time per frame (virtual)
  // Remote: server-side pose prediction. The server renders for the newest camera it received
  // extrapolated ahead (extrapolate_pose, core/buffers/camera.h), and the client warps from that
  // camera. "off": the camera as received; "delay": ahead by the expected camera-to-display
  // delay; "lead": by server_pose_lead_ms.
  std::string server_pose_prediction = "off";
  double server_pose_lead_ms = 0.0;

  LinkConfig uplink, downlink;
  size_t max_payload_bytes = 1200;
  // A bit budget for the whole stream on the wire (kbit/s; 0: none): the passes whose codec takes
  // a target bitrate (Codec::takes_target_kbps: h264 in bitrate mode) share, frame by frame, what
  // the other passes used over the last second (core/pipeline/pipeline.h, ServerPipeline).
  double stream_kbps = 0.0;
  // Adaptive bitrate (core/net/rate_controller.h): "off", or "latency": the server moves the
  // stream budget, starting at stream_kbps, within [abr_min_kbps, abr_max_kbps (0: stream_kbps)]
  // from the client's reports of each frame's delivery and loss.
  std::string abr = "off";
  double abr_min_kbps = 300.0;
  double abr_max_kbps = 0.0;
  double abr_target_queue_ms = 10.0;
  double abr_interval_ms = 100.0;
  int history_frames = 64;  // client G-buffers kept for prediction
  // A pass is stalled while its newest data stays the same for more than this many display
  // intervals (the stall metrics of core/results/results.h).
  int stall_after_frames = 3;
  int score_every = 1;         // quality against the local reference on every n-th frame
  int ground_truth_every = 0;  // against the ground truth on every n-th frame (0: never)
  // Experiments refuse a warm-up shorter than the first server frame's way to the client
  // (warmup_problem, core/sim/frame_loop.h) unless this says the startup is what is measured.
  bool score_startup = false;
  int ground_truth_ao_rays = 256;
  int ground_truth_samples_per_light = 64;
  std::string ground_truth_sampling = sampling_name(ReferenceRays{}.lattice);  // or the other (core/trace/trace.h)
  bool keep_images = false;      // keep one frame's images (RunResult::images) for image grids
  std::string cache_dir;         // ground truths on disk; empty: default_cache_dir() (core/pass/reference.h)
  std::string dump_streams_dir;  // non-empty: the server writes each video pass's stream there
                                 // (<pass>.<Codec::stream_format()>; dhrbench run --dump-streams)

  nlohmann::json to_json() const;
  // The backends of the pass `name` (dhr::Error for a name that is not a pass).
  const PassChoice& pass(std::string_view name) const;
  PassChoice& pass(std::string_view name);
  // `trace` with this run's seed and client frame `frame`: what the server traces for that
  // frame (the simulator, live mode and the local references all use it).
  TraceSettings trace_for_frame(uint32_t frame) const {
    TraceSettings t = trace;
    t.seed = seed;
    t.frame = frame;
    return t;
  }
};

// ---- the table of settings -------------------------------------------------------------------

enum class SettingType {
  Integer,  // a JSON integer in lo..hi
  Number,   // a finite JSON number in lo..hi
  Boolean,
  Choice,  // one of `choices`
  String,
  Backend,  // {"name", "params"}: a backend of the registry `kind` ("codec", "denoiser", "predictor")
  Link,     // a LinkConfig object (core/net/network.h checks its fields)
};
const char* setting_type_name(SettingType type);

// Flags of a setting.
enum SettingFlag : unsigned {
  kInLiveOffer = 1u << 0,  // client and server of a live session must agree on it (session_offer)
  kInTraceKey = 1u << 1,   // changes the traced buffers: part of the trace cache key
  kInTruthKey = 1u << 2,   // changes the ground truth: part of its cache key. The truth is the
                           // scene's: the run's AO settings are not in it. The seed is, though
                           // the truth does not depend on it either (its disk key has its own,
                           // core/pass/reference.h), so that a seed sweep's runs can go to separate
                           // shards (core/experiment/shard.h). FrameLoop.GroundTruthDoesNotDependOn...
                           // checks both.
};

struct RunSetting {
  std::string key;  // dotted, inside "run": "width", "trace.ao_rays", "passes.ao.codec"
  SettingType type;
  double lo = 0, hi = 0;             // Integer and Number
  std::vector<std::string> choices;  // Choice
  std::string kind;                  // Backend: the registry's kind
  std::string doc;                   // one line
  unsigned flags = 0;
  // kInTraceKey: the one traced pass whose buffers it changes ("ao"); empty: every pass. The
  // runner caches each pass under the settings of its own (pass_trace_key).
  std::string traced_pass;
  std::string live_ignored;  // non-empty: live mode ignores it, and why
  // The version-1 key this setting was read from (empty: the same key). `predictor` set both
  // passes.visibility.predictor and passes.ao.predictor.
  std::string v1_key;
  std::function<nlohmann::json(const SimConfig&)> get;
  std::function<void(SimConfig&, const nlohmann::json&)> set;  // a value that check_value accepted

  bool has(SettingFlag f) const { return (flags & f) != 0; }
  nlohmann::json default_value() const { return get(SimConfig{}); }
  // "an integer in 8..7680", "one of hybrid, remote", "a backend {name, params} (codec)".
  std::string range_text() const;
  // Why `value`, found at `at` ("run.width"), is not valid for this setting, as messages that
  // name `at` (several lines for a Backend), or nothing. A Backend's shape is checked here, its
  // name and parameters by plan_run (with the registries).
  std::optional<std::string> check_value(const nlohmann::json& value, const std::string& at) const;
};

// Every setting, in the order `dhrbench settings` lists them.
const std::vector<RunSetting>& run_settings();
// The setting with `key`, or nullptr.
const RunSetting* find_run_setting(const std::string& key);

// Version-1 keys (the top-level keys of "run" that version 2 writes under "passes") -> the
// keys that replace them ("predictor" -> passes.visibility.predictor and passes.ao.predictor).
const std::vector<std::pair<std::string, std::vector<std::string>>>& v1_run_keys();
// A dotted key of "run" written with a version-1 key ("ao_denoiser.name"), in version 2's
// words ("passes.ao.denoiser.name", or two keys joined by " and "); empty for any other key.
std::string v2_spelling(const std::string& dotted);

// Reads a SimConfig from a JSON object shaped like SimConfig::to_json (all keys optional;
// unknown keys are errors). Problems are appended to `problems`, each prefixed by `where`.
// `version` is the experiment file's: 1 also accepts the version-1 keys (v1_run_keys), which
// version 2 refuses naming the new key. Live mode's --config reads as version 1.
SimConfig sim_config_from_json(const nlohmann::json& j, const std::string& where, std::vector<std::string>& problems,
                               int version = 1);

// The range and choice problems of `config` (run_settings' check_value on every setting),
// each as "key = value: must be ...".
std::vector<std::string> setting_range_problems(const SimConfig& config);

// The settings with `flag`, as "key=value|key=value|..." (the cache keys use it).
std::string settings_key(const SimConfig& config, SettingFlag flag);
// The kInTraceKey settings that change the traced pass `pass` ("visibility", "ao"): those of
// every pass and its own, in the same form.
std::string pass_settings_key(const SimConfig& config, std::string_view pass);

}  // namespace dhr
