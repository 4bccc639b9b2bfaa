// Experiment files: a versioned JSON description of a sweep, expanded into runs.
//
// {
//   "version": 2,
//   "name": "quick",           a plain name (kPlainNameRule below; default: the file's stem)
//   "description": "what this experiment shows",
//   "scenes": ["room", "scenes/real/living-room.json"],
//   "run": { the settings of core/config/run_config.h (`dhrbench settings` lists them): width, height,
//            frames, display_hz, seed, trace {...},
//            passes {"visibility": {"codec", "denoiser", "predictor"}, "ao": {...},
//                    "colour": {"codec", "predictor"}}   each {"name", "params"},
//            uplink {...}, downlink {...}, ... }      the base of every run
//   "networks": { "5g": {"uplink": {...}, "downlink": {...}}, ... }   named networks
//   "sweep": { "dotted.key": [values...], ... }      Cartesian product over the keys, or
//   "configurations": [ {"name": "...", "family": "...", "set": {"dotted.key": value, ...}}, ... ]
//   "curves": {"vary": ["dotted.key", ...], "anchor": "family" | ["family", ...],
//              "replicates": ["seed", ...]}   swept keys whose values are independent draws
//                                                                  rate-quality curves (optional)
//   "answer": {"question": "...", "cost": "bandwidth" | "server_time", "group": "key", "along": "key",
//              "terms": [{"name": "...", "with": "configuration", "without": "configuration"}, ...]}
//                                  what report.md opens with (optional; experiments/report.py);
//                                  "group": "configuration" compares the configurations
// }
// Rate-quality curves (docs/architecture.md, "Rate-quality curves"): the runs of one family on
// one scene under the same values of every swept key not in "vary" form one curve; the report
// draws the curves and the BD-rate of every family against the anchor family (each of them, for
// a list).
// A dotted key addresses a field of "run" (e.g. "passes.ao.denoiser.name", "trace.ao_rays",
// "downlink.latency_ms"); the key "network" picks a named network.
// Version 1 (every committed experiment) writes the per-pass backends as top-level keys:
// visibility_codec, ao_codec, colour_codec, visibility_denoiser, ao_denoiser, predictor (both
// the visibility and the AO pass's) and colour_predictor, also in dotted keys ("ao_denoiser.name");
// `dhrbench validate` prints how to write them in version 2, where they are errors. Runs = scenes x
// configurations (or the sweep's product; both may be given: each configuration is swept).
// Every problem in the file (unknown keys, bad values, unknown backends or parameters,
// missing scenes) is reported at once, before anything runs.
#pragma once

#include "core/config/run_config.h"
#include "core/scene/scene.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace dhr {

// The newest version; every version from 1 is read.
constexpr int kExperimentVersion = 2;

// The most runs one experiment may expand to (scenes x configurations x sweep values).
constexpr size_t kMaxRuns = 10000;

// A plain name (an experiment's "name", which names its output folder out/<name>): 1 to 64 of
// the characters below, starting with a letter, a digit or '_'.
constexpr const char* kPlainNameRule =
    "1 to 64 letters, digits, '_', '-', '.' or '+', starting with a letter, a digit or '_'";
bool is_plain_name(const std::string& name);

struct RunSpec {
  std::string id;             // r000, r001, ...
  std::string scene;          // as written in the experiment
  std::string label;          // the configuration's name, or "key=value, ..." of the sweep
  std::string configuration;  // the configuration's name ("" without configurations)
  std::string family;         // its "family" (default: its name): one rate-quality curve's runs
  nlohmann::json settings;    // the dotted keys set for this run
  SimConfig config;
};

struct Experiment {
  std::string path;
  std::string name;
  std::string description;
  nlohmann::json source;  // the file's JSON after --set overrides
  std::vector<std::string> scenes;
  std::vector<RunSpec> runs;
  // Version 1 files: how each version-1 key used is written in version 2 (not problems).
  std::vector<std::string> hints;
};

// sim_config_from_json (a "run" object -> SimConfig) is declared in core/config/run_config.h.

// Sets `value` at a dotted path inside `target` (creating objects on the way).
void set_dotted(nlohmann::json& target, const std::string& dotted, const nlohmann::json& value);

// Parses "key=value" (value as JSON, or a plain string when it is not valid JSON) and applies
// it to the experiment's JSON (a dotted path from the top: "run.frames=10", "scenes=[\"room\"]"),
// or with `under` to that top-level object (live mode: under "run", "frames=10"); errors name the
// assignment as the user typed it.
void apply_override(nlohmann::json& experiment, const std::string& assignment, const std::string& under = "");

// Loads, applies overrides and expands. Throws dhr::Error listing every problem of the file
// (scenes and backends are checked by validate_experiment).
Experiment load_experiment(const std::string& path, const std::vector<std::string>& overrides = {});

}  // namespace dhr
