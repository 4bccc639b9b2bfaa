// One run, planned and validated once (plan_run): the passes the scene and the settings call
// for, what the server traces and what it sends, each setting's backend with its effective
// parameters, and the mode's stage lists. Everything that runs a frame (core/pipeline/pipeline.h,
// the simulator, live mode) takes a `const RunPlan&` and plans nothing itself; remote rendering
// is the hybrid server's stages followed by composite -> colour [+ depth], not a branch on the
// mode's name. Also here: the warm-up against the first frame's arrival (warmup_problem) and a
// backend setting's effective parameters (effective_backend).
#pragma once

#include "core/backend/backend.h"
#include "core/config/run_config.h"
#include "core/net/rate_controller.h"
#include "core/pass/passes.h"
#include "core/scene/scene.h"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

namespace dhr {

// What the server does to a frame, in order.
enum class ServerStage : uint8_t {
  Rasterize,  // its G-buffer of the frame
  Trace,      // the traced passes (through the caller's cache)
  Denoise,    // each traced pass's 8-bit planes through its denoiser
  Composite,  // the denoised passes composited into the colour pass (remote)
  PackDepth,  // the depth pass beside the colour, for a colour predictor that reads depth (remote)
  Encode,     // each sent pass through its codec, then into packets
};
// What the client does to show a frame, in order.
enum class ClientStage : uint8_t {
  Rasterize,  // its own G-buffer, kept for prediction (hybrid; the remote client scores with one)
  Decode,     // each completed frame of a sent pass
  Upsample,   // passes traced at reduced resolution, once per received frame
  Predict,    // each sent pass's newest buffer to the displayed frame (remote: the colour warped)
  Composite,  // the predicted passes into the image (hybrid)
};

enum class RunMode : uint8_t { Hybrid, Remote };

struct RunPlan {
  SimConfig config;  // the settings it was planned from
  const Scene* scene = nullptr;
  RunMode mode = RunMode::Hybrid;
  PassPlan passes;                  // what the scene and the trace settings call for (plan_passes)
  std::vector<PlannedPass> traced;  // what the server traces and denoises, in the order of pass_types()
  std::vector<PlannedPass> sent;    // what it streams: hybrid, the traced passes; remote, colour [+ depth]
  int depth_bits = 0;               // remote: the bits of the depth pass sent (0: none)
  std::vector<ServerStage> server_stages;
  std::vector<ClientStage> client_stages;
  // Per backend setting (run_settings() of type Backend, by key: "passes.ao.codec"): its
  // {"name", "params"} with the defaults the backend fills in, as results.json's "backends" and
  // live mode's offer record them.
  nlohmann::json backends = nlohmann::json::object();

  bool remote() const { return mode == RunMode::Remote; }
  bool server_does(ServerStage stage) const;
  bool client_does(ClientStage stage) const;
  // The backends of a planned pass (config.pass(name)).
  const PassChoice& choice(const PlannedPass& pass) const { return config.pass(pass.name); }
  // The adaptive bitrate controller's settings (abr_*, stream_kbps its start); none when abr is off.
  std::optional<RateControlSettings> abr() const { return abr_settings(config); }
  static std::optional<RateControlSettings> abr_settings(const SimConfig& config);
};

// Plans `config` on `scene` with the backends of `registries` (each created once, to check it):
// throws dhr::Error listing every problem (ranges, links, traces, backends, a codec that cannot
// carry its pass, a bit budget no codec takes). The plan keeps a pointer to `scene`.
RunPlan plan_run(const SimConfig& config, const Scene& scene, const Registries& registries);

// What experiments check besides (experiments/cli/cmd_run.cpp): empty, or why the warm-up ends
// before the first server frame can reach the client. Then the first scored frames would show
// no server data (a startup, not streaming) and a comparison at that latency would score it;
// score_startup true allows it. The bound: uplink + the server's fixed time + downlink latency
// of the first camera and its frame (a Normal link: its mean plus three standard deviations).
std::string warmup_problem(const SimConfig& config);

// A backend setting's value (`{"name", "params"}`, RunSetting::get of a SettingType::Backend
// setting) with its effective parameters: the defaults the backend fills in. Throws dhr::Error
// as the registry does.
nlohmann::json effective_backend(const RunSetting& setting, const nlohmann::json& value, const Registries& registries);

}  // namespace dhr
