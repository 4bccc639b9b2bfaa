// The experiment runner end to end: a tiny experiment through the dhrbench command, then the
// results schema, the CSV and the report files; and its validation of bad experiments.
#include "core/experiment.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <sstream>

namespace dhr {
namespace {

namespace fs = std::filesystem;

int run(const std::string& args, std::string* output = nullptr) {
  const std::string log = (fs::temp_directory_path() / "dhr_runner_test.log").string();
  const int rc = std::system((std::string(DHR_CLI) + " " + args + " >" + log + " 2>&1").c_str());
  if (output) {
    std::ifstream in(log);
    std::stringstream s;
    s << in.rdbuf();
    *output = s.str();
  }
  return rc;
}

TEST(Runner, TinyExperimentEndToEnd) {
  const fs::path out = fs::temp_directory_path() / "dhr_runner_tiny";
  fs::remove_all(out);
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json";
  std::string log;
  ASSERT_EQ(run("run " + exp + " --out " + out.string(), &log), 0) << log;
  std::ifstream in(out / "results.json");
  const nlohmann::json r = nlohmann::json::parse(in);
  // Context block.
  const auto& ctx = r.at("context");
  EXPECT_EQ(ctx.at("schema_version"), 1);
  for (const char* key : {"git_commit", "git_dirty", "compiler", "build_type", "cpu_model", "hardware_threads", "kernel"})
    EXPECT_TRUE(ctx.contains(key)) << key;
  for (const char* lib : {"embree", "lz4", "zstd", "libavcodec", "x264", "opencv", "openimageio"})
    EXPECT_FALSE(ctx.at("libraries").at(lib).get<std::string>().empty()) << lib;
  EXPECT_EQ(r.at("experiment").at("name"), "tiny");
  // 2 configurations x 2 denoisers x 1 network = 4 runs.
  ASSERT_EQ(r.at("runs").size(), 4u);
  for (const auto& run : r.at("runs")) {
    ASSERT_FALSE(run.contains("error")) << run.dump();
    const auto& m = run.at("metrics");
    EXPECT_GT(m.at("ssim_local_mean").get<double>(), 0.0);
    EXPECT_LE(m.at("ssim_local_mean").get<double>(), 1.0);
    EXPECT_GT(m.at("bandwidth_mbps").get<double>(), 0.0);
    EXPECT_TRUE(m.at("stages_wall").contains("rasterize"));
    EXPECT_GE(m.at("stages_wall").at("rasterize").at("p95_ms").get<double>(),
              m.at("stages_wall").at("rasterize").at("median_ms").get<double>());
    // Effective parameters: defaults filled in.
    EXPECT_TRUE(run.at("backends").at("ao_codec").at("params").is_object());
    EXPECT_EQ(run.at("config").at("downlink").at("latency_ms"), 40.0);
  }
  EXPECT_EQ(r.at("runs")[2].at("backends").at("ao_codec").at("params").at("level"), 3);
  // frames.csv: a header and one row per displayed frame per run.
  std::ifstream csv(out / "frames.csv");
  std::string line;
  int rows = -1;
  while (std::getline(csv, line)) ++rows;
  EXPECT_EQ(rows, 4 * 6);
  for (const char* f : {"report.md", "plots/quality_vs_bandwidth.png", "plots/quality_vs_server_time.png",
                        "plots/ssim_per_frame.png", "grids/grid_room_0.png", "images/r000_shown.png",
                        "images/r000_truth.png", "images/r000_error.png"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  // The report can be rebuilt without running again.
  fs::remove(out / "report.md");
  ASSERT_EQ(run("report " + out.string(), &log), 0) << log;
  EXPECT_TRUE(fs::exists(out / "report.md"));
  fs::remove_all(out);
}

TEST(Runner, ValidateReportsEveryProblemAtOnceAndRunsNothing) {
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json";
  std::string log;
  const int rc = run("validate " + exp + " --set run.ao_codec.name=lz5 --set run.width=3 --set 'scenes=[\"room\",\"nosuchscene\"]'", &log);
  EXPECT_NE(rc, 0);
  EXPECT_NE(log.find("width = 3"), std::string::npos) << log;
  // Scene and backend problems are found in the second stage, once the file itself is valid.
  const int rc2 = run("validate " + exp + " --set run.visibility_codec.name=lz5 --set 'scenes=[\"room\",\"nosuchscene\"]'", &log);
  EXPECT_NE(rc2, 0);
  EXPECT_NE(log.find("unknown codec 'lz5'"), std::string::npos) << log;
  EXPECT_NE(log.find("nosuchscene"), std::string::npos) << log;
  EXPECT_NE(log.find("nothing was run"), std::string::npos) << log;
}

TEST(Experiment, SweepExpandsTheCartesianProduct) {
  const Experiment e = load_experiment(std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json",
                                       {R"(sweep={"ao_denoiser.name": ["none", "atrous"], "network": ["slow"], "trace.ao_rays": [1, 2, 4]})"});
  EXPECT_EQ(e.runs.size(), 2u * 2u * 1u * 3u);
  EXPECT_EQ(e.runs[0].config.downlink.latency_ms, 40.0);
  EXPECT_EQ(e.runs[0].config.ao_codec.name, "lz4");
}

TEST(Experiment, BadFilesAreErrors) {
  const fs::path dir = fs::temp_directory_path() / "dhr_bad_experiments";
  fs::create_directories(dir);
  auto write = [&](const char* name, const char* text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  EXPECT_THROW(load_experiment(write("noversion.json", R"({"scenes": ["room"]})")), Error);
  EXPECT_THROW(load_experiment(write("v2.json", R"({"version": 2, "scenes": ["room"]})")), Error);
  EXPECT_THROW(load_experiment(write("notjson.json", "{")), Error);
  EXPECT_THROW(load_experiment(write("noscenes.json", R"({"version": 1, "scenes": []})")), Error);
  EXPECT_THROW(load_experiment(write("badnet.json", R"({"version": 1, "scenes": ["room"], "sweep": {"network": ["x"]}})")), Error);
  EXPECT_THROW(load_experiment((dir / "missing.json").string()), Error);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace dhr
