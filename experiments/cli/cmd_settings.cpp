// dhrbench settings: every run setting (core/config/run_config.cpp's table) with its type, range or
// choices, default, doc and flags: what an experiment's "run" object, --set and live mode's
// --config accept.
#include "core/config/run_config.h"
#include "experiments/cli/commands.h"

#include <fmt/format.h>

#include <memory>

namespace dhr::cli {

Runner add_settings_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("settings",
                                 "List every run setting (the keys of an experiment's \"run\" object, of --set "
                                 "and of live mode's --config) with its type, range, default and meaning");
  auto json = std::make_shared<bool>(false);
  cmd->add_flag("--json", *json, "Print the table as JSON (one object per setting)");
  return [json] {
    if (*json) {
      nlohmann::json out = nlohmann::json::array();
      for (const RunSetting& s : run_settings()) {
        nlohmann::json row{{"key", s.key},
                           {"type", setting_type_name(s.type)},
                           {"valid", s.range_text()},
                           {"default", s.default_value()},
                           {"doc", s.doc},
                           {"live_offer", s.has(kInLiveOffer)},
                           {"trace_key", s.has(kInTraceKey)},
                           {"truth_key", s.has(kInTruthKey)}};
        if (!s.traced_pass.empty()) row["traced_pass"] = s.traced_pass;
        if (!s.v1_key.empty()) row["version_1_key"] = s.v1_key;
        if (!s.live_ignored.empty()) row["live_ignores"] = s.live_ignored;
        out.push_back(row);
      }
      fmt::print("{}\n", out.dump(2));
      return 0;
    }
    fmt::print(
        "Run settings ({}): keys of an experiment's \"run\" (dotted in sweeps and --set run.KEY=VALUE).\n"
        "Flags: offer = client and server of a live session must agree; traced = changes the traced buffers\n"
        "(of every pass, or of the one named: the cache keeps each pass under its own settings);\n"
        "truth = changes the ground truth. Backends: `dhrbench list` shows their names and parameters.\n\n",
        run_settings().size());
    for (const RunSetting& s : run_settings()) {
      std::string flags;
      if (s.has(kInLiveOffer)) flags += " offer";
      if (s.has(kInTraceKey)) flags += s.traced_pass.empty() ? " traced" : " traced (" + s.traced_pass + " pass)";
      if (s.has(kInTruthKey)) flags += " truth";
      fmt::print("  {:<32} {:<8} default {}\n", s.key, setting_type_name(s.type), s.default_value().dump());
      fmt::print("      {}; {}\n", s.range_text(), s.doc);
      if (!flags.empty()) fmt::print("      flags:{}\n", flags);
      if (!s.v1_key.empty()) fmt::print("      version-1 key: {}\n", s.v1_key);
      if (!s.live_ignored.empty()) fmt::print("      live mode ignores it: {}\n", s.live_ignored);
    }
    return 0;
  };
}

}  // namespace dhr::cli
