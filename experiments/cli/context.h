// The context block of results.json (machine, build, code version, library versions).
#pragma once

#include <nlohmann/json.hpp>

#include <string>

namespace dhr::cli {

constexpr int kResultsSchemaVersion = 1;

nlohmann::json run_context(const std::string& build_type);

}  // namespace dhr::cli
