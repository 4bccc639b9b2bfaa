// The checks of one run's settings against its scene and the registries, made before anything
// runs: every problem at once (validate_sim_config), the warm-up against the first frame's
// arrival (warmup_problem), and what the backends chosen add to the plan (remote_depth_bits).
#pragma once

#include "core/backend/backend.h"
#include "core/config/run_config.h"
#include "core/scene/scene.h"

#include <nlohmann/json.hpp>

#include <string>

namespace dhr {

// The checks run_simulation does first: throws dhr::Error listing every problem.
void validate_sim_config(const SimConfig& config, const Scene& scene, const Registries& registries);

// What experiments check besides (experiments/cli/cmd_run.cpp): empty, or why the warm-up ends
// before the first server frame can reach the client. Then the first scored frames would show
// no server data (a startup, not streaming) and a comparison at that latency would score it;
// score_startup true allows it. The bound: uplink + the server's fixed time + downlink latency
// of the first camera and its frame (a Normal link: its mean plus three standard deviations).
std::string warmup_problem(const SimConfig& config);

// The bits of the depth pass the server of this run sends with its colour (0: none): remote mode
// with a colour predictor that reads depth (Predictor::depth_bits).
int remote_depth_bits(const SimConfig& config, const Registries& registries);

// A backend setting's value (`{"name", "params"}`, RunSetting::get of a SettingType::Backend
// setting) with its effective parameters: the defaults the backend fills in, as results.json's
// "backends" and live mode's offer record them. Throws dhr::Error as the registry does.
nlohmann::json effective_backend(const RunSetting& setting, const nlohmann::json& value, const Registries& registries);

}  // namespace dhr
