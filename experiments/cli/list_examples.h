// The backend examples that `dhrbench list` prints, in the one syntax that experiment files,
// --config files and --set accept (core/config/run_config.cpp, the Backend settings):
//
//   "passes": {"ao": {"codec": {"name": "zstd", "params": {"level": 3}}}}   in an experiment's "run"
//   --set run.passes.ao.codec='{"name":"zstd","params":{"level":3}}'         on the command line
//
// Header-only so that tests/backends/test_registry.cpp can check that every example is accepted by the
// loader and creates its backend, without a library of its own.
#pragma once

#include "core/backend/backend.h"
#include "core/config/run_config.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace dhr::cli {

struct BackendExample {
  std::string kind;      // codec, denoiser, predictor
  std::string name;      // the backend
  std::string run_key;   // a key of an experiment's "run" that takes this kind: passes.ao.codec, ...
  nlohmann::json value;  // {"name": ..., "params": {...}}; "params" left out when there are none

  // `"passes": {"ao": {"codec": {"name": "zstd", "params": {"level": 3}}}}`, as written in an
  // experiment file (the dotted key nested).
  std::string file_text() const {
    // Appended piece by piece: GCC 12 warns, wrongly, about chains of + on temporaries.
    std::string text, close;
    size_t start = 0;
    for (size_t dot; (dot = run_key.find('.', start)) != std::string::npos; start = dot + 1) {
      text += '"';
      text.append(run_key, start, dot - start);
      text += "\": {";
      close += '}';
    }
    text += '"';
    text.append(run_key, start, std::string::npos);
    text += "\": ";
    text += value.dump();
    text += close;
    return text;
  }
  // `run.passes.ao.codec={"name":"zstd","params":{"level":3}}`, the argument of --set (without the
  // shell quotes around the value that `dhrbench list` prints).
  std::string set_assignment() const { return "run." + run_key + "=" + value.dump(); }
};

// The keys of an experiment's "run" that take a backend of each kind (the Backend settings of
// core/config/run_config.cpp).
inline std::vector<std::string> run_keys(const std::string& kind) {
  std::vector<std::string> keys;
  for (const RunSetting& s : run_settings())
    if (s.type == SettingType::Backend && s.kind == kind) keys.push_back(s.key);
  return keys;
}

// The key the examples use: the AO pass's (every built-in codec and denoiser can take it).
inline std::string example_run_key(const std::string& kind) { return "passes.ao." + kind; }

// One example per backend of `registry`: its first parameter at its default value (so that
// the example is valid whatever the ranges), under example_run_key(kind).
template <class Interface>
std::vector<BackendExample> backend_examples(const Registry<Interface>& registry) {
  const std::string kind = registry.kind();
  std::vector<BackendExample> examples;
  for (const auto& e : registry.entries()) {
    nlohmann::json value{{"name", e.name}};
    if (!e.params.empty()) value["params"] = {{e.params.front().name, e.params.front().default_value}};
    examples.push_back({kind, e.name, example_run_key(kind), std::move(value)});
  }
  return examples;
}

// Every example `dhrbench list` prints: codecs, denoisers, predictors.
inline std::vector<BackendExample> all_backend_examples(const Registries& r) {
  std::vector<BackendExample> all = backend_examples(r.codecs);
  for (auto& e : backend_examples(r.denoisers)) all.push_back(std::move(e));
  for (auto& e : backend_examples(r.predictors)) all.push_back(std::move(e));
  return all;
}

}  // namespace dhr::cli
