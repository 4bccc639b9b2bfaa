// dhrbench metrics: every figure dhrbench writes (core/results/results.cpp's tables): the image metrics
// scored per displayed frame, the per-run and per-pass metrics of results.json, with units and
// meaning; the same record results.json carries as "declared".
#include "core/results/results.h"
#include "experiments/cli/commands.h"

#include <fmt/format.h>

#include <memory>

namespace dhr::cli {

Runner add_metrics_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("metrics",
                                 "List every figure a run writes: image metrics per displayed frame (frames.csv "
                                 "columns, results.json means), run and pass metrics, units and meaning");
  auto json = std::make_shared<bool>(false);
  cmd->add_flag("--json", *json, "Print the declarations as JSON (what results.json holds as \"declared\")");
  return [json] {
    if (*json) {
      fmt::print("{}\n", declared_json().dump(2));
      return 0;
    }
    fmt::print(
        "Image metrics, scored per displayed frame against the local reference and the ground truth\n"
        "(frames.csv columns; results.json keys per run):\n");
    for (const ImageMetric& m : image_metrics()) {
      fmt::print("  {:<10} {}\n", m.name + (m.unit.empty() ? "" : " (" + m.unit + ")"), m.doc);
      fmt::print("             columns {}, {}; per run", m.column(Against::Local), m.column(Against::GroundTruth));
      for (const ImageStatistic& s : image_statistics())
        fmt::print(" {}, {}", m.aggregate(Against::Local, s.name), m.aggregate(Against::GroundTruth, s.name));
      fmt::print("; {} is better\n", m.higher_is_better ? "higher" : "lower");
    }
    fmt::print("\nStatistics over a run's scored frames:\n");
    for (const ImageStatistic& s : image_statistics()) fmt::print("  {:<10} {}\n", s.name, s.doc);
    fmt::print(
        "\nRun metrics (results.json runs[].metrics; [wall] = measured on the wall clock, varies run to run):\n");
    for (const RunMetric& m : run_metrics())
      fmt::print("  {:<26} {:<9} {}{}\n", m.one_key_per_pass ? m.key + "_PASS" : m.key, m.unit, m.doc,
                 m.wall_clock ? " [wall]" : "");
    fmt::print("\nPass metrics (results.json runs[].metrics.passes[], one record per pass sent):\n");
    for (const PassMetric& m : pass_metrics()) fmt::print("  {:<28} {:<9} {}\n", m.key, m.unit, m.doc);
    return 0;
  };
}

}  // namespace dhr::cli
