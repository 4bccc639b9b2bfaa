// dhrbench: the command-line entry point. Subcommands live in cmd_*.cpp.
#include "core/base/error.h"
#include "experiments/cli/commands.h"

#include <cstdio>
#include <exception>
#include <vector>

int main(int argc, char** argv) {
  CLI::App app{
      "dhrbench: a benchmark for distributed hybrid rendering (DHR).\n"
      "A server ray-traces shadow visibility and ambient occlusion, denoises, compresses and\n"
      "streams them; a thin client rasterizes the scene, predicts around late or lost data and\n"
      "composites. Every stage is a backend chosen by name ('dhrbench list' shows them)."};
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
