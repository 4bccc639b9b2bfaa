// Experiment files: a versioned JSON description of a sweep, expanded into runs.
//
// {
//   "version": 1,
//   "name": "quick",
//   "description": "what this experiment shows",
//   "scenes": ["room", "scenes/real/living-room.json"],
//   "run": { SimConfig fields (see SimConfig::to_json): width, height, frames, warmup_frames,
//            display_hz, seed, trace {...}, visibility_codec {"name", "params"}, ...,
//            uplink {...}, downlink {...} }           the base of every run
//   "networks": { "5g": {"uplink": {...}, "downlink": {...}}, ... }   named networks
//   "sweep": { "dotted.key": [values...], ... }      Cartesian product over the keys, or
//   "configurations": [ {"name": "...", "set": {"dotted.key": value, ...}}, ... ]
// }
// A dotted key addresses a field of "run" (e.g. "ao_denoiser.name", "trace.ao_rays",
// "downlink.latency_ms"); the key "network" picks a named network. Runs = scenes x
// configurations (or the sweep's product; both may be given: each configuration is swept).
// Every problem in the file (unknown keys, bad values, unknown backends or parameters,
// missing scenes) is reported at once, before anything runs.
#pragma once

#include "core/frame_loop.h"
#include "core/scene.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace dhr {

constexpr int kExperimentVersion = 1;

struct RunSpec {
  std::string id;          // r000, r001, ...
  std::string scene;       // as written in the experiment
  std::string label;       // the configuration's name, or "key=value, ..." of the sweep
  nlohmann::json settings; // the dotted keys set for this run
  SimConfig config;
};

struct Experiment {
  std::string path;
  std::string name;
  std::string description;
  nlohmann::json source;    // the file's JSON after --set overrides
  std::vector<std::string> scenes;
  std::vector<RunSpec> runs;
};

// Reads a SimConfig from a JSON object shaped like SimConfig::to_json (all keys optional;
// unknown keys are errors). Problems are appended to `problems`, each prefixed by `where`.
SimConfig sim_config_from_json(const nlohmann::json& j, const std::string& where, std::vector<std::string>& problems);

// Sets `value` at a dotted path inside `target` (creating objects on the way).
void set_dotted(nlohmann::json& target, const std::string& dotted, const nlohmann::json& value);

// Parses "key=value" (value as JSON, or a plain string when it is not valid JSON) and applies
// it to the experiment's JSON (a dotted path from the top: "run.frames=10", "scenes=[\"room\"]").
void apply_override(nlohmann::json& experiment, const std::string& assignment);

// Loads, applies overrides and expands. Throws dhr::Error listing every problem of the file
// (scenes and backends are checked by validate_experiment).
Experiment load_experiment(const std::string& path, const std::vector<std::string>& overrides = {});

}  // namespace dhr
