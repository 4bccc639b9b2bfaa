// Each subcommand of `dhrbench` lives in its own cmd_<name>.cpp and adds itself to the
// command line in main.cpp through one add_<name>_command line.
#pragma once

#include <CLI/CLI.hpp>

#include <functional>

namespace dhr {
struct Experiment;
}

namespace dhr::cli {

// A subcommand registers its options on `app` and returns the function that runs it
// (returning the process exit code).
using Runner = std::function<int()>;

Runner add_list_command(CLI::App& app);
Runner add_render_command(CLI::App& app);
Runner add_compare_command(CLI::App& app);
Runner add_run_command(CLI::App& app);
Runner add_validate_command(CLI::App& app);
Runner add_report_command(CLI::App& app);
Runner add_settings_command(CLI::App& app);
Runner add_metrics_command(CLI::App& app);
Runner add_converge_command(CLI::App& app);
Runner add_serve_command(CLI::App& app);   // cmd_live.cpp
Runner add_client_command(CLI::App& app);  // cmd_live.cpp
Runner add_relay_command(CLI::App& app);   // cmd_live.cpp
Runner add_merge_command(CLI::App& app);

// Builds DIR/report.md with experiments/report.py (cmd_run.cpp); returns the exit code for the
// command: 0, 2 (damaged results, the script said what) or 3 (no report).
int write_report(const std::string& dir);
// Prints the shard plan of `e` for `count` shards (cmd_merge.cpp).
void print_shard_plan(const Experiment& e, int count);

}  // namespace dhr::cli
