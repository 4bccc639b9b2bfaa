// The experiment runner end to end: a tiny experiment through the dhrbench command, then the
// results schema, the CSV and the report files; and its validation of bad experiments.
#include "core/base/error.h"
#include "core/experiment/experiment.h"
#include "core/sim/frame_loop.h"
#include "tests/support.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <sstream>

namespace dhr {
namespace {

namespace fs = std::filesystem;

int run(const std::string& args, std::string* output = nullptr) {
  // One log per process: two test runs at once (two checkouts) must not read each other's output.
  const std::string log =
      (fs::temp_directory_path() / ("dhr_runner_test." + std::to_string(getpid()) + ".log")).string();
  const int rc = std::system((std::string(DHR_CLI) + " " + args + " >" + log + " 2>&1").c_str());
  if (output) {
    std::ifstream in(log);
    std::stringstream s;
    s << in.rdbuf();
    *output = s.str();
  }
  return rc;
}

// Every committed experiment file still validates (settings renamed or tightened since it was
// written would break `regenerate_reports.sh` an hour into a grid). Those that name a scene
// beyond the built-in ones (the shared real scenes) are checked where ../shared/scenes is present.
TEST(Runner, EveryCommittedExperimentValidates) {
  const bool shared = fs::exists(DHR_SHARED_SCENES_DEFAULT);
  int validated = 0, files = 0;
  for (const auto& entry : fs::directory_iterator(fs::path(DHR_SOURCE_DIR) / "experiments")) {
    if (entry.path().extension() != ".json") continue;
    ++files;
    std::ifstream in(entry.path());
    const nlohmann::json e = nlohmann::json::parse(in, nullptr, false);
    ASSERT_FALSE(e.is_discarded()) << entry.path() << " is not JSON";
    // A built-in scene: scenes/NAME.json in the repository, named by NAME or that path.
    auto built_in = [](const nlohmann::json& scene) {
      if (!scene.is_string()) return false;
      const std::string name = scene.get<std::string>();
      const fs::path file = fs::path(DHR_SOURCE_DIR) / (name.ends_with(".json") ? name : "scenes/" + name + ".json");
      return fs::exists(file) && file.parent_path().filename() == "scenes";
    };
    const nlohmann::json scenes = e.value("scenes", nlohmann::json::array());
    if (!shared && !std::all_of(scenes.begin(), scenes.end(), built_in)) continue;
    // From the repository root, as regenerate_reports.sh runs them (scene paths are relative to it).
    const std::string log =
        (fs::temp_directory_path() / ("dhr_validate." + std::to_string(getpid()) + ".log")).string();
    const int rc = std::system(
        fmt::format("cd '{}' && '{}' validate '{}' >'{}' 2>&1", DHR_SOURCE_DIR, DHR_CLI, entry.path().string(), log)
            .c_str());
    std::ifstream log_in(log);
    const std::string output((std::istreambuf_iterator<char>(log_in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(rc, 0) << entry.path() << ":\n" << output;
    ++validated;
  }
  EXPECT_GE(files, 10);
  EXPECT_EQ(validated, shared ? files : validated);
  EXPECT_GE(validated, 1);
}

// A bad DHR_AV_LOG is an error naming the value and the valid ones, before anything runs.
TEST(Runner, ABadAvLogLevelIsRefused) {
  const std::string log = (fs::temp_directory_path() / ("dhr_avlog." + std::to_string(getpid()) + ".log")).string();
  const int rc = std::system(fmt::format("DHR_AV_LOG=loud '{}' list >'{}' 2>&1", DHR_CLI, log).c_str());
  std::ifstream in(log);
  const std::string output((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(rc, 0);
  EXPECT_NE(output.find("DHR_AV_LOG 'loud' is not one of quiet, fatal, error, warning, info, debug"), std::string::npos)
      << output;
  EXPECT_EQ(std::system(fmt::format("DHR_AV_LOG=warning '{}' list >'{}' 2>&1", DHR_CLI, log).c_str()), 0);
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
  for (const char* key :
       {"git_commit", "git_dirty", "compiler", "build_type", "cpu_model", "embree_isa", "hardware_threads", "kernel"})
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
    EXPECT_TRUE(run.at("backends").at("passes.ao.codec").at("params").is_object());
    EXPECT_EQ(run.at("config").at("downlink").at("latency_ms"), 40.0);
  }
  EXPECT_EQ(r.at("runs")[2].at("backends").at("passes.ao.codec").at("params").at("level"), 3);
  // Results declared once (core/results/results.h): every declared figure is in every run's record and
  // every declared column in frames.csv; `dhrbench metrics --json` prints the same declaration.
  const nlohmann::json& declared = r.at("declared");
  std::string printed;
  ASSERT_EQ(run("metrics --json", &printed), 0) << printed;
  EXPECT_EQ(nlohmann::json::parse(printed), declared);
  ASSERT_FALSE(declared.at("image_metrics").empty());
  for (const auto& run : r.at("runs")) {
    const auto& m = run.at("metrics");
    for (const auto& im : declared.at("image_metrics"))
      for (const char* ref : {"local", "ground_truth"})
        EXPECT_TRUE(m.contains(im.at("aggregates").at(ref).at("mean").get<std::string>())) << im.dump();
    for (const auto& rm : declared.at("run_metrics")) {
      const std::string key = rm.at("key");
      if (key.ends_with("_PASS"))
        EXPECT_TRUE(m.contains(key.substr(0, key.size() - 5) + "_ao")) << key;
      else
        EXPECT_TRUE(m.contains(key)) << key;
    }
    for (const auto& p : m.at("passes"))
      for (const auto& pm : declared.at("pass_metrics")) EXPECT_TRUE(p.contains(pm.at("key").get<std::string>())) << pm;
  }
  // frames.csv: a header with every declared column and one row per displayed frame per run.
  std::ifstream csv(out / "frames.csv");
  std::string line;
  ASSERT_TRUE(std::getline(csv, line));
  const std::string header = "," + line + ",";
  for (const auto& im : declared.at("image_metrics"))
    for (const char* ref : {"local", "ground_truth"})
      EXPECT_NE(header.find("," + im.at("columns").at(ref).get<std::string>() + ","), std::string::npos) << header;
  for (const char* col : {",visibility_source_frame,", ",ao_age_ms,", ",colour_disoccluded,", ",client_wall_ms,"})
    EXPECT_NE(header.find(col), std::string::npos) << col << " in " << header;
  int rows = 0;
  while (std::getline(csv, line)) ++rows;
  EXPECT_EQ(rows, 4 * 6);
  for (const char* f :
       {"report.md", "plots/quality_vs_bandwidth.png", "plots/quality_vs_server_time.png", "plots/ssim_per_frame.png",
        "grids/grid_room_0.png", "images/r000_shown.png", "images/r000_truth.png", "images/r000_error.png"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  // The report can be rebuilt without running again.
  fs::remove(out / "report.md");
  ASSERT_EQ(run("report " + out.string(), &log), 0) << log;
  EXPECT_TRUE(fs::exists(out / "report.md"));
  fs::remove_all(out);
}

// Runs side by side (--jobs) share the caches (traces, temporal denoisers' outputs, local
// references, ground truths) and must give what one job gives: every non-timing figure and
// frames.csv row the same (scripts/check_figures.py --compare), the records in the runs' order.
TEST(Runner, JobsGiveTheResultsOfOneJob) {
  const fs::path base = fs::temp_directory_path() / ("dhr_runner_jobs." + std::to_string(getpid()));
  fs::remove_all(base);
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/jobs_experiment.json";
  std::string log;
  for (const char* jobs : {"1", "3"}) {
    const fs::path out = base / jobs;
    ASSERT_EQ(run("run " + exp + " --no-report --no-disk-cache --jobs " + jobs + " --out " + out.string(), &log), 0)
        << log;
    std::ifstream in(out / "results.json");
    const nlohmann::json r = nlohmann::json::parse(in);
    ASSERT_EQ(r.at("runs").size(), 12u);
    for (size_t i = 0; i < r.at("runs").size(); ++i) {
      EXPECT_EQ(r.at("runs")[i].at("id"), fmt::format("r{:03d}", i));
      EXPECT_FALSE(r.at("runs")[i].contains("error")) << r.at("runs")[i].dump();
    }
    EXPECT_EQ(r.at("context").at("jobs"), std::stoi(jobs));
  }
  const std::string compare = "/usr/bin/python3 " + std::string(DHR_SOURCE_DIR) +
                              "/scripts/check_figures.py --compare " + (base / "3").string() + " " +
                              (base / "1").string();
  EXPECT_EQ(std::system(compare.c_str()), 0) << compare;
  // Out of range: a clear error, nothing run.
  ASSERT_NE(run("run " + exp + " --jobs 0 --out " + (base / "0").string(), &log), 0);
  EXPECT_NE(log.find("--jobs"), std::string::npos) << log;
  fs::remove_all(base);
}

// Rate-quality curves (experiments/rate_quality.py): families of configurations become curves per
// scene and latency, drawn with a BD-rate table against the anchor family.
TEST(Runner, RateQualityCurvesAndBdRate) {
  const fs::path out = fs::temp_directory_path() / "dhr_runner_curves";
  fs::remove_all(out);
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_curves.json";
  std::string log;
  ASSERT_EQ(run("run " + exp + " --out " + out.string(), &log), 0) << log;
  std::ifstream in(out / "results.json");
  const nlohmann::json r = nlohmann::json::parse(in);
  ASSERT_EQ(r.at("runs").size(), 10u);
  EXPECT_EQ(r.at("runs")[0].at("family"), "remote h264");
  EXPECT_EQ(r.at("runs")[0].at("configuration"), "remote crf 20");
  std::ifstream rep(out / "report.md");
  std::stringstream text;
  text << rep.rdbuf();
  EXPECT_NE(text.str().find("BD-rate against **remote h264** on SSIM"), std::string::npos) << text.str();
  EXPECT_NE(text.str().find("| room | downlink.latency_ms=60 |"), std::string::npos) << text.str();
  EXPECT_TRUE(fs::exists(out / "plots" / "rate_quality_ssim.png"));
  // A list of anchors: one table against each, the second one too.
  nlohmann::json two = r;
  two["experiment"]["curves"]["anchor"] = {"remote h264", "hybrid zstd"};
  std::ofstream(out / "results.json") << two.dump();
  ASSERT_EQ(run("report " + out.string(), &log), 0) << log;
  std::stringstream text2;
  text2 << std::ifstream(out / "report.md").rdbuf();
  EXPECT_NE(text2.str().find("BD-rate against **remote h264** on SSIM"), std::string::npos) << text2.str();
  EXPECT_NE(text2.str().find("BD-rate against **hybrid zstd** on SSIM"), std::string::npos) << text2.str();
  fs::remove_all(out);

  // A "vary" key that nothing sets, and an anchor that is no family: both named at once.
  const fs::path bad = fs::temp_directory_path() / "dhr_runner_bad_curves.json";
  nlohmann::json e = nlohmann::json::parse(std::ifstream(exp));
  e["curves"] = {{"vary", {"passes.ao.codec", "trace.ao_rays"}}, {"anchor", "remote x265"}};
  std::ofstream(bad) << e.dump();
  EXPECT_NE(run("validate " + bad.string(), &log), 0);
  EXPECT_NE(log.find("curves.vary: \"trace.ao_rays\" is not a key of \"sweep\" or of a configuration's \"set\""),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("curves.anchor: 'remote x265' is not a family"), std::string::npos) << log;
  // In a list: the one that is no family is named; a list of numbers is refused.
  e["curves"] = {{"vary", {"passes.ao.codec"}}, {"anchor", {"remote h264", "hybrid x266"}}};
  std::ofstream(bad) << e.dump();
  EXPECT_NE(run("validate " + bad.string(), &log), 0);
  EXPECT_NE(log.find("curves.anchor: 'hybrid x266' is not a family"), std::string::npos) << log;
  EXPECT_EQ(log.find("'remote h264' is not a family"), std::string::npos) << log;
  e["curves"] = {{"vary", {"passes.ao.codec"}}, {"anchor", {1, 2}}};
  std::ofstream(bad) << e.dump();
  EXPECT_NE(run("validate " + bad.string(), &log), 0);
  EXPECT_NE(log.find("must be a family's name or a non-empty list of them"), std::string::npos) << log;
  // The report's answer: a cost it does not know, a group without "along", a key nothing sets.
  e["curves"] = {{"vary", {"mode", "passes.colour.codec", "passes.ao.codec", "passes.ao.denoiser"}}};
  e["answer"] = {{"cost", "joules"}, {"group", "trace.ao_rays"}};
  std::ofstream(bad) << e.dump();
  EXPECT_NE(run("validate " + bad.string(), &log), 0);
  EXPECT_NE(log.find("answer.cost = \"joules\": must be one of"), std::string::npos) << log;
  EXPECT_NE(log.find("answer.group: 'trace.ao_rays' is not a key"), std::string::npos) << log;
  EXPECT_NE(log.find("\"group\" needs \"along\""), std::string::npos) << log;
  e["answer"] = {{"question", "which AO codec?"}, {"cost", "server_time"}};
  std::ofstream(bad) << e.dump();
  EXPECT_EQ(run("validate " + bad.string(), &log), 0) << log;
  // A warm-up that ends before the first server frame can arrive would score a startup: refused
  // with the bound and the frames it needs, unless score_startup says the startup is measured.
  e["run"]["uplink"] = {{"latency_ms", 50}};
  e["run"]["downlink"] = {{"latency_ms", 50}};
  e["run"]["server_fixed_ms"] = 16;
  e["run"]["warmup_frames"] = 6;
  e["run"]["display_hz"] = 60;
  std::ofstream(bad) << e.dump();
  EXPECT_NE(run("validate " + bad.string(), &log), 0);
  // (the sweep's downlink.latency_ms = 60 runs; the others arrive in time)
  EXPECT_NE(
      log.find("warmup_frames 6 (100.0 ms) ends before the first server frame can arrive (126.0 ms: uplink 50.0 + "
               "server 16.0 + downlink 60.0 ms)"),
      std::string::npos)
      << log;
  EXPECT_NE(log.find("use warmup_frames >= 8"), std::string::npos) << log;
  e["run"]["warmup_frames"] = 8;
  std::ofstream(bad) << e.dump();
  EXPECT_EQ(run("validate " + bad.string(), &log), 0) << log;
  e["run"]["warmup_frames"] = 6;
  e["run"]["score_startup"] = true;
  std::ofstream(bad) << e.dump();
  EXPECT_EQ(run("validate " + bad.string(), &log), 0) << log;
  fs::remove(bad);
}

// --dump-streams: every video pass of every run as a file that the ffmpeg command-line tool
// decodes without an error into whole pictures of the pass's size (that its pictures are ours
// bit for bit is VideoCodecs.DumpedStreamsDecodeWithFfmpegToOurPictures in tests/backends/test_codecs.cpp).
TEST(Runner, DumpStreamsWritesFilesThatFfmpegDecodes) {
  if (std::system("command -v ffmpeg >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "the ffmpeg command-line tool is not installed (scripts/setup.sh installs it)";
  const fs::path out = fs::temp_directory_path() / "dhr_runner_dump";
  const fs::path streams = out / "streams";
  fs::remove_all(out);
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json";
  const std::string configurations =
      R"('configurations=[{"name": "h264", "set": {"ao_codec.name": "h264"}}, )"
      R"({"name": "hevc", "set": {"ao_codec.name": "hevc"}}, {"name": "av1", "set": {"ao_codec.name": "av1"}}, )"
      R"({"name": "remote av1", "set": {"mode": "remote", "colour_codec.name": "av1"}}]')";
  std::string log;
  ASSERT_EQ(run("run " + exp + " --out " + out.string() + " --no-report --dump-streams " + streams.string() +
                    " --set " + configurations + R"( --set 'sweep={"network": ["slow"]}')",
                &log),
            0)
      << log;
  const std::map<std::string, std::pair<std::string, int>> expected{
      {"r000", {"ao.h264", 1}}, {"r001", {"ao.hevc", 1}}, {"r002", {"ao.ivf", 1}}, {"r003", {"colour.ivf", 3}}};
  for (const auto& [id, file_and_channels] : expected) {
    const auto& [name, channels] = file_and_channels;
    const fs::path file = streams / id / name;
    ASSERT_TRUE(fs::exists(file)) << file;
    EXPECT_EQ(std::distance(fs::directory_iterator(streams / id), fs::directory_iterator{}), 1)
        << id << ": only the video pass is dumped (visibility goes through lz4)";
    const fs::path raw = out / (id + ".raw");
    const std::string cmd = "ffmpeg -nostdin -v error -y -i " + file.string() + " -fps_mode passthrough -f rawvideo " +
                            "-pix_fmt " + (channels == 1 ? "gray " : "rgb24 ") + raw.string() + " >" +
                            (out / (id + ".log")).string() + " 2>&1";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    EXPECT_EQ(fs::file_size(out / (id + ".log")), 0u) << id << ": ffmpeg reported errors";
    const uintmax_t picture = uintmax_t(48) * 32 * uintmax_t(channels);
    EXPECT_GE(fs::file_size(raw), 6 * picture) << id;
    EXPECT_EQ(fs::file_size(raw) % picture, 0u) << id;
  }
  fs::remove_all(out);
}

TEST(Runner, ValidateReportsEveryProblemAtOnceAndRunsNothing) {
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json";
  std::string log;
  const int rc = run(
      "validate " + exp + " --set run.ao_codec.name=lz5 --set run.width=3 --set 'scenes=[\"room\",\"nosuchscene\"]'",
      &log);
  EXPECT_NE(rc, 0);
  EXPECT_NE(log.find("width = 3"), std::string::npos) << log;
  // Scene and backend problems are found in the second stage, once the file itself is valid.
  const int rc2 =
      run("validate " + exp + " --set run.visibility_codec.name=lz5 --set 'scenes=[\"room\",\"nosuchscene\"]'", &log);
  EXPECT_NE(rc2, 0);
  EXPECT_NE(log.find("unknown codec 'lz5'"), std::string::npos) << log;
  EXPECT_NE(log.find("nosuchscene"), std::string::npos) << log;
  EXPECT_NE(log.find("nothing was run"), std::string::npos) << log;
}

TEST(Experiment, SweepExpandsTheCartesianProduct) {
  const Experiment e = load_experiment(
      std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json",
      {R"(sweep={"ao_denoiser.name": ["none", "atrous"], "network": ["slow"], "trace.ao_rays": [1, 2, 4]})"});
  EXPECT_EQ(e.runs.size(), 2u * 2u * 1u * 3u);
  EXPECT_EQ(e.runs[0].config.downlink.latency_ms, 40.0);
  EXPECT_EQ(e.runs[0].config.pass("ao").codec.name, "lz4");
}

TEST(Experiment, BadFilesAreErrors) {
  const fs::path dir = fs::temp_directory_path() / "dhr_bad_experiments";
  fs::create_directories(dir);
  auto write = [&](const char* name, const char* text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  EXPECT_THROW(load_experiment(write("noversion.json", R"({"scenes": ["room"]})")), Error);
  EXPECT_THROW(load_experiment(write("v3.json", R"({"version": 3, "scenes": ["room"]})")), Error);
  EXPECT_THROW(load_experiment(write("notjson.json", "{")), Error);
  EXPECT_THROW(load_experiment(write("noscenes.json", R"({"version": 1, "scenes": []})")), Error);
  EXPECT_THROW(
      load_experiment(write("badnet.json", R"({"version": 1, "scenes": ["room"], "sweep": {"network": ["x"]}})")),
      Error);
  EXPECT_THROW(load_experiment((dir / "missing.json").string()), Error);
  // A key only some configurations set, outside curves.vary, would split their curves from the
  // others' (the remote families' server_pose_prediction): refused, naming it; in "vary", valid.
  const char* split = R"({"version": 2, "name": "split", "scenes": ["room"],
    "configurations": [
      {"name": "h 1", "family": "hybrid", "set": {"passes.ao.codec": {"name": "h264", "params": {"crf": 20}}}},
      {"name": "r 1", "family": "remote", "set": {"mode": "remote", "server_pose_prediction": "delay"}}],
    "curves": {"vary": ["passes.ao.codec", "mode"VARY]}})";
  std::string text = split;
  text.replace(text.find("VARY"), 4, "");
  const std::string m = test::error_of([&] { load_experiment(write("split.json", text.c_str())); });
  EXPECT_NE(m.find("'server_pose_prediction' is set by 1 of the 2 configurations"), std::string::npos) << m;
  text = split;
  text.replace(text.find("VARY"), 4, ", \"server_pose_prediction\"");
  EXPECT_NO_THROW(load_experiment(write("joined.json", text.c_str())));
  fs::remove_all(dir);
}

// 100,000 levels of nesting in an experiment (or a --set value) must not crash dhrbench: through
// the command it is one message naming the file and the limit, exit 1.
TEST(Runner, DeepNestingInAnExperimentOrASetValueIsAClearError) {
  const fs::path dir = fs::temp_directory_path() / "dhr_runner_deep";
  fs::create_directories(dir);
  const int n = 100000;
  std::ofstream(dir / "deep.json") << std::string(n, '[') << std::string(n, ']');
  std::ofstream(dir / "huge.json") << R"({"version": 1, "scenes": ["room"], "run": {"frames": 1e400}})";
  std::string log;
  for (const char* cmd : {"validate", "run"}) {
    const int rc = run(std::string(cmd) + " " + (dir / "deep.json").string(), &log);
    ASSERT_TRUE(WIFEXITED(rc)) << "killed by a signal: " << rc;
    EXPECT_EQ(WEXITSTATUS(rc), 1);
    EXPECT_NE(log.find((dir / "deep.json").string() + ": JSON nested deeper than 64 levels"), std::string::npos) << log;
    EXPECT_LT(log.size(), 400u) << log;
    const int rc2 = run(std::string(cmd) + " " + (dir / "huge.json").string(), &log);
    EXPECT_EQ(WEXITSTATUS(rc2), 1);
    EXPECT_NE(log.find((dir / "huge.json").string() + ": not valid JSON"), std::string::npos) << log;
  }
  // A --set value (kept under the kernel's limit on one argument).
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json";
  const int rc =
      run("validate " + exp + " --set 'run.uplink=" + std::string(50000, '[') + std::string(50000, ']') + "'", &log);
  ASSERT_TRUE(WIFEXITED(rc)) << "killed by a signal: " << rc;
  EXPECT_EQ(WEXITSTATUS(rc), 1);
  EXPECT_NE(log.find("--set 'run.uplink': the value is nested deeper than 64 levels"), std::string::npos) << log;
  fs::remove_all(dir);
}

// An experiment's name never reaches a shell ("name": "x'$(touch PWNED)'" must run nothing when
// the report is written) and never writes outside out/ ("../../escaped"): names are plain names
// or refused; folders with any character reach the report script as one argument.
TEST(Runner, NamesAndFoldersNeverReachAShell) {
  const fs::path base = fs::temp_directory_path() / ("dhr_runner_names." + std::to_string(getpid()));
  fs::remove_all(base);
  fs::create_directories(base);
  std::string log;
  auto cli = [&](const std::vector<std::string>& args) { return test::run_program(DHR_CLI, args, log); };
  nlohmann::json e = nlohmann::json::parse(
      std::ifstream(std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json"), nullptr, true, true);
  e["configurations"] = nlohmann::json::array({e["configurations"][0]});
  for (const std::string& name : std::vector<std::string>{"x'$(touch PWNED)'", "../../escaped", "a b", "`touch PWNED`",
                                                          "x\ny", ".hidden", std::string(65, 'a')}) {
    SCOPED_TRACE(name);
    e["name"] = name;
    const fs::path file = base / "named.json";
    std::ofstream(file) << e.dump();
    for (const char* cmd : {"validate", "run"}) {
      EXPECT_EQ(cli({cmd, file.string()}), 1) << log;
      EXPECT_NE(log.find("is not a plain name: 1 to 64 letters, digits"), std::string::npos) << log;
    }
  }
  // A file stem that is no plain name, without "name": the same rule, saying where the name came from.
  e.erase("name");
  std::ofstream(base / "it's.json") << e.dump();
  EXPECT_EQ(cli({"validate", (base / "it's.json").string()}), 1) << log;
  EXPECT_NE(log.find("the file's stem (no \"name\" given) 'it's' is not a plain name"), std::string::npos) << log;
  // Output folders with quotes, $(...), backticks, spaces and a newline: run and report work.
  e["name"] = "odd_folders";
  std::ofstream(base / "odd.json") << e.dump();
  const fs::path out = base / "it's $(touch PWNED) `touch PWNED` \n\"x\"";
  ASSERT_EQ(cli({"run", (base / "odd.json").string(), "--out", out.string()}), 0) << log;
  EXPECT_TRUE(fs::exists(out / "results.json"));
  if (std::system("/usr/bin/python3 -c 'import matplotlib' >/dev/null 2>&1") == 0) {
    EXPECT_TRUE(fs::exists(out / "report.md")) << log;
    fs::remove(out / "report.md");
    EXPECT_EQ(cli({"report", out.string()}), 0) << log;
    EXPECT_TRUE(fs::exists(out / "report.md")) << log;
  }
  EXPECT_FALSE(fs::exists("PWNED"));
  EXPECT_FALSE(fs::exists(base / "PWNED"));
  // --out naming a file: one clear message, not a filesystem exception.
  std::ofstream(base / "afile.txt") << "x";
  EXPECT_EQ(cli({"run", (base / "odd.json").string(), "--out", (base / "afile.txt").string()}), 1) << log;
  EXPECT_NE(log.find("afile.txt is a file, not a folder"), std::string::npos) << log;
  EXPECT_EQ(log.find("filesystem error"), std::string::npos) << log;
  // Live mode's --set names what was typed, not a "run." prefix the user never wrote.
  EXPECT_EQ(cli({"serve", "--scene", "room", "--set", "nonsense"}), 1) << log;
  EXPECT_NE(log.find("--set 'nonsense': expected key=value, e.g. frames=10"), std::string::npos) << log;
  EXPECT_EQ(log.find("run.nonsense"), std::string::npos) << log;
  fs::remove_all(base);
}

// A sweep too large to expand (8 keys x 256 values wraps the run count to 0 in size_t) and two
// configurations of one name are refused before anything is expanded.
TEST(Experiment, HugeSweepsAndRepeatedNamesAreRefusedBeforeExpanding) {
  const std::string exp = std::string(DHR_SOURCE_DIR) + "/tests/data/tiny_experiment.json";
  nlohmann::json sweep = nlohmann::json::object();
  for (int k = 0; k < 8; ++k) {
    nlohmann::json values = nlohmann::json::array();
    for (int v = 0; v < 256; ++v) values.push_back(v);
    sweep[fmt::format("trace.ao_rays{}", k)] = values;
  }
  const std::string e1 = test::error_of([&] { load_experiment(exp, {"sweep=" + sweep.dump()}); });
  EXPECT_NE(e1.find("more than 10000 runs (1 scene(s) x 2 configuration(s) x trace.ao_rays0 (256 values)"),
            std::string::npos)
      << e1;
  // Just past the limit (5001 seeds x 2 configurations).
  nlohmann::json seeds = nlohmann::json::array();
  for (int i = 0; i < 5001; ++i) seeds.push_back(i);
  const std::string over = nlohmann::json{{"seed", seeds}}.dump();
  EXPECT_NE(test::error_of([&] { load_experiment(exp, {"sweep=" + over}); }).find("more than 10000 runs"),
            std::string::npos);
  const std::string e2 = test::error_of([&] {
    load_experiment(
        exp, {R"(configurations=[{"name": "a", "set": {}}, {"name": "b", "set": {}}, {"name": "a", "set": {}}])"});
  });
  EXPECT_NE(e2.find("configurations[2]: the name 'a' is given twice"), std::string::npos) << e2;
}

// 'dhrbench report' on a damaged results.json (or frames.csv): one message naming the file and
// what is wrong, exit 2, no Python traceback, no report written.
TEST(Runner, ReportOnDamagedResultsIsAClearError) {
  if (std::system("/usr/bin/python3 -c 'import matplotlib' >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "python3-matplotlib is not installed (scripts/setup.sh installs it)";
  std::ifstream in(std::string(DHR_SOURCE_DIR) + "/reports/quick/results.json");
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  const nlohmann::json good = nlohmann::json::parse(text);
  ASSERT_FALSE(good.at("runs").empty());
  auto with = [&](const std::function<void(nlohmann::json&)>& f) {
    nlohmann::json r = good;
    f(r);
    return r.dump(1);
  };
  struct Case {
    const char* name;
    std::string results;
    std::string frames_csv;  // empty: none
    const char* expected;    // in the message
  };
  const std::vector<Case> cases = {
      {"truncated", text.substr(0, text.size() / 2), "", "results.json: not valid JSON"},
      {"empty", "", "", "results.json: not valid JSON"},
      {"not_json", "this is not JSON", "", "results.json: not valid JSON"},
      {"deep", std::string(100000, '[') + std::string(100000, ']'), "",
       "results.json: JSON nested deeper than 64 levels"},
      {"huge_number", "{\"x\": 1e400, " + text.substr(text.find('{') + 1), "", "results.json: not valid JSON"},
      {"top_array", "[1, 2]", "", "results.json: must be a JSON object"},
      {"no_runs", with([](auto& r) { r.erase("runs"); }), "", "results.json: \"runs\" must be a list"},
      {"runs_object", with([](auto& r) {
         r["runs"] = {{"a", 1}};
       }),
       "", "results.json: \"runs\" must be a list"},
      {"run_not_object", with([](auto& r) { r["runs"][0] = 42; }), "", "results.json: runs[0] must be a JSON object"},
      {"context_string", with([](auto& r) { r["context"] = "x"; }), "",
       "results.json: \"context\" must be a JSON object"},
      {"metrics_wrong_type", with([](auto& r) { r["runs"][0]["metrics"]["bandwidth_mbps"] = "fast"; }), "",
       "results.json: runs[0].metrics.bandwidth_mbps: must be a finite number, got \"fast\""},
      {"metrics_missing_key", with([](auto& r) { r["runs"][0]["metrics"].erase("passes"); }), "",
       "results.json: runs[0].metrics.passes is missing"},
      {"id_path", with([](auto& r) { r["runs"][0]["id"] = "../../x"; }), "",
       "results.json: runs[0].id \"../../x\" cannot name a run"},
      {"frames_csv", with([](auto& r) {
         r["runs"] = nlohmann::json::array({r["runs"][0]});
         r["runs"][0]["metrics"]["frames_displayed"] = 1;
       }),
       "run,scene,label,frame,ssim_local\nr000,room,x,abc,0.5\n", "frames.csv: line 2: frame must be"},
  };
  const fs::path base = fs::temp_directory_path() / "dhr_runner_damaged";
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path dir = base / c.name;
    fs::remove_all(dir);
    fs::create_directories(dir);
    std::ofstream(dir / "results.json") << c.results;
    // The report's frames, so that each case fails on its own damage only.
    if (!c.frames_csv.empty())
      std::ofstream(dir / "frames.csv") << c.frames_csv;
    else
      fs::copy_file(fs::path(DHR_SOURCE_DIR) / "reports/quick/frames.csv", dir / "frames.csv");
    std::string log;
    const int rc = run("report " + dir.string(), &log);
    ASSERT_TRUE(WIFEXITED(rc)) << "killed by a signal: " << rc;
    EXPECT_EQ(WEXITSTATUS(rc), 2) << log;
    EXPECT_NE(log.find((dir / "").string()), std::string::npos) << log;
    EXPECT_NE(log.find(c.expected), std::string::npos) << log;
    EXPECT_EQ(log.find("Traceback"), std::string::npos) << log;
    EXPECT_LT(log.size(), 600u) << log;
    EXPECT_FALSE(fs::exists(dir / "report.md"));
  }
  fs::remove_all(base);
}

}  // namespace
}  // namespace dhr
