// dhrbench: the command-line entry point. Subcommands live in cmd_*.cpp.
#include "core/base/error.h"
#include "experiments/cli/commands.h"

extern "C" {
#include <libavutil/log.h>
}

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>
#include <vector>

namespace {

// libavcodec's own messages (a decoder's "non-existing PPS" after every loss, x265's notes) fill
// a long run's log; the codecs report their failures themselves (decode_errors, error messages).
// DHR_AV_LOG=error|warning|info|debug shows them again.
bool set_av_log_level() {
  const char* want = std::getenv("DHR_AV_LOG");
  int level = AV_LOG_FATAL;
  if (want && *want) {
    const std::pair<const char*, int> levels[] = {{"quiet", AV_LOG_QUIET}, {"fatal", AV_LOG_FATAL},
                                                  {"error", AV_LOG_ERROR}, {"warning", AV_LOG_WARNING},
                                                  {"info", AV_LOG_INFO},   {"debug", AV_LOG_DEBUG}};
    bool known = false;
    std::string valid;
    for (const auto& [name, value] : levels) {
      valid += (valid.empty() ? "" : ", ") + std::string(name);
      if (std::strcmp(want, name) == 0) {
        level = value;
        known = true;
      }
    }
    if (!known) {
      std::fprintf(stderr, "dhrbench: error: DHR_AV_LOG '%s' is not one of %s\n", want, valid.c_str());
      return false;
    }
  }
  av_log_set_level(level);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "dhrbench: a benchmark for distributed hybrid rendering (DHR).\n"
      "A server ray-traces shadow visibility and ambient occlusion, denoises, compresses and\n"
      "streams them; a thin client rasterizes the scene, predicts around late or lost data and\n"
      "composites. Every stage is a backend chosen by name ('dhrbench list' shows them).\n"
      "Environment: DHR_CACHE_DIR (the trace cache), DHR_SCENE_PATH (where scenes are found),\n"
      "DHR_AV_LOG=error|warning|info|debug (libavcodec's own messages; default: fatal only)."};
  if (!set_av_log_level()) return 2;
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Print help for every subcommand");

  std::vector<std::pair<CLI::App*, dhr::cli::Runner>> commands;
  auto add = [&](auto adder) {
    const size_t before = app.get_subcommands({}).size();
    dhr::cli::Runner run = adder(app);
    commands.emplace_back(app.get_subcommands({}).at(before), std::move(run));
  };
  add(dhr::cli::add_run_command);
  add(dhr::cli::add_validate_command);
  add(dhr::cli::add_report_command);
  add(dhr::cli::add_list_command);
  add(dhr::cli::add_settings_command);
  add(dhr::cli::add_metrics_command);
  add(dhr::cli::add_converge_command);
  add(dhr::cli::add_render_command);
  add(dhr::cli::add_compare_command);
  add(dhr::cli::add_serve_command);
  add(dhr::cli::add_client_command);
  add(dhr::cli::add_relay_command);
  add(dhr::cli::add_merge_command);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    for (auto& [sub, run] : commands)
      if (sub->parsed()) return run();
  } catch (const dhr::Error& e) {
    std::fprintf(stderr, "dhrbench: error: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "dhrbench: unexpected error: %s\n", e.what());
    return 1;
  }
  return 0;
}
