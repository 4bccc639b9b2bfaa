// Sharded sweeps (core/experiment/shard.h, experiments/cli/cmd_merge.cpp) and the disk caches several
// processes share (core/sim/frame_loop.h, TraceCache): the plan, a sharded run merged against an
// unsharded one in every non-timing figure, the merge's refusals, a failed shard rerun alone,
// and two processes writing and reading one cache entry at once.
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/experiment/experiment.h"
#include "core/experiment/shard.h"
#include "core/results/results.h"
#include "core/sim/frame_loop.h"
#include "core/trace/rt_scene.h"
#include "tests/support.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

namespace dhr {
namespace {

namespace fs = std::filesystem;

const std::string kExperiment = std::string(DHR_SOURCE_DIR) + "/tests/data/shard_experiment.json";

// Runs the dhrbench command with DHR_CACHE_DIR=cache (when given) and the `env` assignments
// ("NAME=value "); returns its exit code.
int cli(const std::string& args, std::string* output = nullptr, const fs::path& cache = {},
        const std::string& env_more = "") {
  static int n = 0;
  const std::string log =
      (fs::temp_directory_path() / fmt::format("dhr_shard_test.{}.{}.log", ::getpid(), n++)).string();
  const std::string env = (cache.empty() ? "" : "DHR_CACHE_DIR='" + cache.string() + "' ") + env_more;
  const int rc = std::system((env + DHR_CLI + " " + args + " >" + log + " 2>&1").c_str());
  std::ifstream in(log);
  std::stringstream s;
  s << in.rdbuf();
  if (output) *output = s.str();
  fs::remove(log);
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : 128 + WTERMSIG(rc);
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// The figures measured on the wall clock (they vary from run to run): the run metrics that
// core/results/results.cpp declares wall-clock, and each run's and shard's wall_s; everything else must
// be equal.
bool is_timing_key(const std::string& k) {
  if (k == "wall_s") return true;
  for (const RunMetric& m : run_metrics())
    if (m.wall_clock && m.key == k) return true;
  return false;
}

nlohmann::json without_timing(const nlohmann::json& j) {
  if (j.is_object()) {
    nlohmann::json out = nlohmann::json::object();
    for (const auto& [k, v] : j.items())
      if (!is_timing_key(k)) out[k] = without_timing(v);
    return out;
  }
  if (j.is_array()) {
    nlohmann::json out = nlohmann::json::array();
    for (const auto& v : j) out.push_back(without_timing(v));
    return out;
  }
  return j;
}

// frames.csv without its client_wall_ms column (the last; frames_csv_wall_clock_columns()).
std::string frames_without_timing(const fs::path& p) {
  std::istringstream in(read_text(p));
  std::string line, out;
  std::getline(in, line);
  EXPECT_EQ(line.substr(line.rfind(',') + 1), "client_wall_ms") << "frames.csv's columns changed: update this test";
  out += line.substr(0, line.rfind(',')) + '\n';
  while (std::getline(in, line)) out += line.substr(0, line.rfind(',')) + '\n';
  return out;
}

// Every non-timing value of two results folders: the run records (order included) and
// frames.csv, and the guard's own comparison (scripts/check_figures.py --compare).
void expect_same_figures(const fs::path& merged, const fs::path& whole) {
  const nlohmann::json a = nlohmann::json::parse(read_text(merged / "results.json"));
  const nlohmann::json b = nlohmann::json::parse(read_text(whole / "results.json"));
  ASSERT_EQ(a.at("runs").size(), b.at("runs").size());
  for (size_t i = 0; i < a.at("runs").size(); ++i)
    EXPECT_EQ(without_timing(a.at("runs")[i]), without_timing(b.at("runs")[i])) << "run " << i;
  EXPECT_EQ(a.at("experiment"), b.at("experiment"));
  EXPECT_EQ(a.at("context").at("command"), b.at("context").at("command"));
  EXPECT_EQ(frames_without_timing(merged / "frames.csv"), frames_without_timing(whole / "frames.csv"));
  std::set<std::string> images_a, images_b;
  for (const auto& f : fs::directory_iterator(merged / "images")) images_a.insert(f.path().filename().string());
  for (const auto& f : fs::directory_iterator(whole / "images")) images_b.insert(f.path().filename().string());
  EXPECT_EQ(images_a, images_b);
  for (const auto& name : images_b)
    EXPECT_EQ(read_text(merged / "images" / name), read_text(whole / "images" / name)) << name;
  const std::string cmd = "/usr/bin/python3 " + std::string(DHR_SOURCE_DIR) + "/scripts/check_figures.py --compare '" +
                          merged.string() + "' '" + whole.string() + "' >/dev/null";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
}

TEST(Shard, ParseRefusesWhatIsNotKOfN) {
  EXPECT_EQ(parse_shard("2/4").index, 2);
  EXPECT_EQ(parse_shard("2/4").count, 4);
  for (const char* bad : {"0/4", "5/4", "4", "/4", "1/", "a/b", "1/0", "-1/2", "1/2/3", "1 /2", "1/10001"}) {
    const std::string e = test::error_of([&] { parse_shard(bad); });
    EXPECT_NE(e.find(std::string("--shard '") + bad + "'"), std::string::npos) << bad << ": " << e;
    EXPECT_NE(e.find("1 <= K <= N"), std::string::npos) << e;
  }
}

TEST(Shard, PlanKeepsRunsSharingTracesTogetherAndCoversEveryRunOnce) {
  // 3 seeds x 2 denoisers: a seed's runs share traced buffers and ground truths.
  const Experiment e = load_experiment(kExperiment);
  ASSERT_EQ(e.runs.size(), 6u);
  for (int n = 1; n <= 5; ++n) {
    SCOPED_TRACE(n);
    const ShardPlan plan = plan_shards(e, n);
    EXPECT_EQ(plan.groups, 3u);
    ASSERT_EQ(plan.runs.size(), size_t(n));
    std::multiset<size_t> all;
    std::map<uint64_t, int> shard_of_seed;
    for (int k = 0; k < n; ++k) {
      EXPECT_TRUE(std::is_sorted(plan.runs[size_t(k)].begin(), plan.runs[size_t(k)].end()));
      for (size_t i : plan.runs[size_t(k)]) {
        all.insert(i);
        auto [it, added] = shard_of_seed.emplace(e.runs[i].config.seed, k);
        EXPECT_EQ(it->second, k) << "seed " << e.runs[i].config.seed << " split over two shards";
      }
    }
    EXPECT_EQ(all, (std::multiset<size_t>{0, 1, 2, 3, 4, 5}));
    // Deterministic; shards beyond the groups are empty.
    EXPECT_EQ(plan_shards(e, n).runs, plan.runs);
    size_t empty = 0;
    for (const auto& r : plan.runs) empty += r.empty();
    EXPECT_EQ(empty, size_t(std::max(0, n - 3)));
  }
  // Another sweep is another experiment.
  EXPECT_NE(experiment_hash(e), experiment_hash(load_experiment(kExperiment, {"run.frames=5"})));
  EXPECT_EQ(experiment_hash(e), experiment_hash(load_experiment(kExperiment)));
}

TEST(Shard, MergedShardsEqualTheUnshardedRunInEveryNonTimingFigure) {
  const fs::path base = fs::temp_directory_path() / fmt::format("dhr_shard_merge.{}", ::getpid());
  fs::remove_all(base);
  std::string log;
  // Each with a cold cache of its own: the unsharded run, and the shards sharing one folder.
  ASSERT_EQ(cli("run " + kExperiment + " --out " + (base / "whole").string(), &log, base / "cache_whole"), 0) << log;
  for (int k : {3, 1, 2})
    ASSERT_EQ(cli(fmt::format("run {} --shard {}/3 --out {}", kExperiment, k, (base / fmt::format("s{}", k)).string()),
                  &log, base / "cache_shared"),
              0)
        << log;
  // No report in a shard's folder; one manifest each, complete.
  EXPECT_FALSE(fs::exists(base / "s1" / "report.md"));
  for (int k = 1; k <= 3; ++k) {
    const ShardManifest m = read_shard_manifest((base / fmt::format("s{}", k)).string());
    EXPECT_EQ(m.status, "complete");
    EXPECT_EQ(m.index, k);
    EXPECT_EQ(m.count, 3);
    EXPECT_EQ(m.run_ids.size(), 2u);
  }
  // Any order of folders.
  ASSERT_EQ(cli("merge " + (base / "merged").string() + " " + (base / "s2").string() + " " + (base / "s3").string() +
                    " " + (base / "s1").string(),
                &log),
            0)
      << log;
  expect_same_figures(base / "merged", base / "whole");
  EXPECT_TRUE(fs::exists(base / "merged" / "report.md"));

  // Refusals: nothing is written, every problem named.
  const std::string s1 = (base / "s1").string(), s2 = (base / "s2").string(), s3 = (base / "s3").string();
  EXPECT_EQ(cli("merge " + (base / "m2").string() + " " + s1 + " " + s3, &log), 1);
  EXPECT_NE(log.find("shard 2/3 is missing"), std::string::npos) << log;
  EXPECT_EQ(cli("merge " + (base / "m2").string() + " " + s1 + " " + s2 + " " + s3 + " " + s1, &log), 1);
  EXPECT_NE(log.find("shard 1/3 given twice"), std::string::npos) << log;
  EXPECT_FALSE(fs::exists(base / "m2"));
  ASSERT_EQ(cli(fmt::format("run {} --set run.frames=5 --shard 2/3 --out {}", kExperiment, (base / "other").string()),
                &log, base / "cache_shared"),
            0)
      << log;
  EXPECT_EQ(cli("merge " + (base / "m2").string() + " " + s1 + " " + (base / "other").string() + " " + s3, &log), 1);
  EXPECT_NE(log.find((base / "other").string() + ": another experiment"), std::string::npos) << log;
  // A shard traced with other Embree kernels (a node of another CPU kind): its figures could
  // differ on rays that graze an edge.
  const std::string isa = embree_isa(), other = isa == "sse2" ? "sse4.2" : "sse2";
  ASSERT_EQ(cli(fmt::format("run {} --shard 2/3 --out {}", kExperiment, (base / "other_isa").string()), &log,
                base / "cache_other_isa", "DHR_MAX_ISA=" + other + " "),
            0)
      << log;
  const int merged =
      cli("merge " + (base / "m2").string() + " " + s1 + " " + (base / "other_isa").string() + " " + s3, &log);
  const std::string got = read_json_file((base / "other_isa" / "results.json").string()).at("context").at("embree_isa");
  if (got != isa) {  // else this CPU has no other ISA
    EXPECT_EQ(merged, 1);
    EXPECT_NE(log.find("traced with Embree's \"" + got + "\" kernels"), std::string::npos) << log;
    EXPECT_NE(log.find("DHR_MAX_ISA"), std::string::npos) << log;
  }
  EXPECT_EQ(cli("merge " + (base / "m2").string() + " " + s1 + " " + (base / "whole").string(), &log), 1);
  EXPECT_NE(log.find((base / "whole").string() + ": no shard.json here"), std::string::npos) << log;
  EXPECT_FALSE(fs::exists(base / "m2"));
  // Plan: validate prints each shard's runs.
  ASSERT_EQ(cli("validate " + kExperiment + " --shards 2", &log), 0) << log;
  EXPECT_NE(log.find("shard 1/2: 4 run(s)"), std::string::npos) << log;
  EXPECT_NE(log.find("shard 2/2: 2 run(s)"), std::string::npos) << log;
  fs::remove_all(base);
}

// A shard that stops on an error records it; the merge names the shard, the error and its
// runs; rerunning only that shard, then merging, gives the whole result.
TEST(Shard, AFailedShardIsReportedAndRerunAlone) {
  const fs::path base = fs::temp_directory_path() / fmt::format("dhr_shard_fail.{}", ::getpid());
  fs::remove_all(base);
  fs::create_directories(base);
  // Seed 1's runs read a latency trace beside the experiment; seed 2's do not.
  std::ofstream(base / "e.json") << R"({"version": 2, "name": "shard_fail", "scenes": ["room"],
    "run": {"width": 48, "height": 32, "frames": 6, "warmup_frames": 3, "trace": {"ao_rays": 2},
            "ground_truth_every": 3, "ground_truth_ao_rays": 16, "ground_truth_samples_per_light": 4, "server_fixed_ms": 5},
    "configurations": [
      {"name": "measured latency", "set": {"seed": 1, "downlink.latency": "trace", "downlink.trace_file": "latency.txt"}},
      {"name": "fixed latency", "set": {"seed": 2, "downlink.latency_ms": 40}}],
    "sweep": {"passes.ao.denoiser.name": ["none", "atrous"]}})";
  const std::string exp = (base / "e.json").string();
  const fs::path trace = fs::path(DHR_SOURCE_DIR) / "experiments/traces/5g_paper_shape.txt";
  fs::copy_file(trace, base / "latency.txt");
  std::string log;
  ASSERT_EQ(cli("run " + exp + " --out " + (base / "whole").string(), &log, base / "cache"), 0) << log;
  ASSERT_EQ(cli("validate " + exp + " --shards 2", &log), 0) << log;
  ASSERT_NE(log.find("shard 1/2: 2 run(s)"), std::string::npos) << log;
  ASSERT_NE(log.find("r000  room                   measured latency"), std::string::npos) << log;

  // The trace is gone while shard 1 runs (a filesystem not mounted on its machine).
  fs::rename(base / "latency.txt", base / "latency.away");
  EXPECT_EQ(cli(fmt::format("run {} --shard 1/2 --out {}", exp, (base / "s1").string()), &log, base / "cache"), 1);
  ASSERT_EQ(cli(fmt::format("run {} --shard 2/2 --out {}", exp, (base / "s2").string()), &log, base / "cache"), 0)
      << log;
  const ShardManifest failed = read_shard_manifest((base / "s1").string());
  EXPECT_EQ(failed.status, "failed");
  EXPECT_NE(failed.error.find("latency.txt: latency trace not found or unreadable"), std::string::npos) << failed.error;
  const std::string merge =
      "merge " + (base / "merged").string() + " " + (base / "s1").string() + " " + (base / "s2").string();
  EXPECT_EQ(cli(merge, &log), 1);
  EXPECT_NE(log.find("shard 1/2 (" + (base / "s1").string() + ") failed: "), std::string::npos) << log;
  EXPECT_NE(log.find("latency.txt: latency trace not found or unreadable"), std::string::npos) << log;
  EXPECT_NE(log.find("its runs: r000, r001"), std::string::npos) << log;
  EXPECT_NE(log.find("rerun it: dhrbench run " + exp + " --shard 1/2 --out " + (base / "s1").string()),
            std::string::npos)
      << log;
  EXPECT_FALSE(fs::exists(base / "merged"));

  // Back again: rerun shard 1 alone, merge.
  fs::rename(base / "latency.away", base / "latency.txt");
  ASSERT_EQ(cli(fmt::format("run {} --shard 1/2 --out {}", exp, (base / "s1").string()), &log, base / "cache"), 0)
      << log;
  ASSERT_EQ(cli(merge + " --no-report", &log), 0) << log;
  expect_same_figures(base / "merged", base / "whole");

  // A shard stopped from outside (a time limit) stays "running": reported as unfinished.
  ShardManifest stopped = read_shard_manifest((base / "s2").string());
  stopped.status = "running";
  write_shard_manifest((base / "s2").string(), stopped);
  EXPECT_EQ(cli(merge, &log), 1);
  EXPECT_NE(log.find("shard 2/2 (" + (base / "s2").string() + ") did not finish"), std::string::npos) << log;
  EXPECT_NE(log.find("its runs: r002, r003"), std::string::npos) << log;
  // A damaged manifest is named with what is wrong (untrusted input, as every file read).
  for (const auto& [text, expected] : std::vector<std::pair<std::string, std::string>>{
           {"{", "shard.json: not valid JSON"},
           {R"({"experiment_hash": 1})", "\"experiment_hash\" must be a string"},
           {std::string(1000, '[') + std::string(1000, ']'), "shard.json: JSON nested deeper than 64 levels"}}) {
    std::ofstream(base / "s2" / "shard.json") << text;
    EXPECT_EQ(cli(merge, &log), 1) << text;
    EXPECT_NE(log.find((base / "s2" / "shard.json").string()), std::string::npos) << log;
    EXPECT_NE(log.find(expected), std::string::npos) << log;
  }
  fs::remove_all(base);
}

// 'merge sh2 sh1 sh2' (OUT one of the shards) and a frames.csv with rows removed or cut mid-row
// are refused before anything is written, so no shard is damaged; folder names reach the report
// script as they are (no shell).
TEST(Shard, MergeRefusesOutInsideAShardAndDamagedShardsBeforeWriting) {
  const fs::path base = fs::temp_directory_path() / fmt::format("dhr_shard_refuse.{}", ::getpid());
  fs::remove_all(base);
  fs::create_directories(base);
  // Folder names a shell would take apart: quotes, $(...), backticks, spaces, a newline.
  const fs::path s1 = base / "s1 it's $(touch PWNED)", s2 = base / "s2 `touch PWNED`\nx";
  std::string log;
  auto run = [&](const std::vector<std::string>& args) { return test::run_program(DHR_CLI, args, log); };
  ASSERT_EQ(run({"run", kExperiment, "--shard", "1/2", "--out", s1.string()}), 0) << log;
  ASSERT_EQ(run({"run", kExperiment, "--shard", "2/2", "--out", s2.string()}), 0) << log;
  const std::string s2_results = read_text(s2 / "results.json"), s2_frames = read_text(s2 / "frames.csv");
  // OUT is a shard, or lies inside one: refused, the shard untouched.
  for (const fs::path& out : {s2, s2 / "merged", base / "s2 `touch PWNED`\nx/"}) {
    EXPECT_EQ(run({"merge", out.string(), s1.string(), s2.string()}), 1) << out;
    EXPECT_NE(log.find("the shard folder"), std::string::npos) << log;
    EXPECT_NE(log.find("nothing was written"), std::string::npos) << log;
    EXPECT_EQ(read_text(s2 / "results.json"), s2_results);
    EXPECT_EQ(read_text(s2 / "frames.csv"), s2_frames);
    EXPECT_FALSE(fs::exists(s2 / "merged"));
  }
  // A good merge into an odd name writes the report there.
  const fs::path merged = base / "merged 'q' $(touch PWNED)";
  ASSERT_EQ(run({"merge", merged.string(), s1.string(), s2.string()}), 0) << log;
  EXPECT_TRUE(fs::exists(merged / "report.md") || log.find("matplotlib") != std::string::npos) << log;
  // Damaged shards: each refused naming the file and what is wrong, nothing written.
  const std::string frames = read_text(s1 / "frames.csv");
  std::vector<std::string> lines;
  for (size_t at = 0; at < frames.size();) {
    const size_t nl = frames.find('\n', at);
    lines.push_back(frames.substr(at, nl + 1 - at));
    at = nl + 1;
  }
  ASSERT_GT(lines.size(), 8u);
  auto join = [](const std::vector<std::string>& v, size_t from, size_t to) {
    std::string out;
    for (size_t i = from; i < to; ++i) out += v[i];
    return out;
  };
  const nlohmann::json results = nlohmann::json::parse(read_text(s1 / "results.json"));
  nlohmann::json other_commit = results;
  other_commit["context"]["git_commit"] = "0123456789abcdef0123456789abcdef01234567";
  nlohmann::json no_metrics = results;
  no_metrics["runs"][0].erase("metrics");
  std::string short_row = lines[3];
  short_row = short_row.substr(0, short_row.rfind(',')) + "\n";
  struct Case {
    const char* name;
    std::string frames, results, expected;
    bool report_refuses = true;  // 'dhrbench report' knows no shard.json: it cannot see another commit
  };
  const std::vector<Case> cases = {
      {"seven_rows_removed", join(lines, 0, lines.size() - 7), "", "row(s), but results.json says it displayed"},
      {"cut_mid_row", frames.substr(0, frames.size() - 5), "", "the file ends inside this record (cut short"},
      {"row_short_of_fields", join(lines, 0, 3) + short_row + join(lines, 4, lines.size()), "", "line 4: "},
      {"row_of_unknown_run", frames + "r999" + lines[1].substr(lines[1].find(',')), "", "a row of run 'r999'"},
      {"other_commit", frames, other_commit.dump(1), "but its shard.json says", false},
      {"run_without_metrics", frames, no_metrics.dump(1), "has neither \"metrics\" nor \"error\""},
      {"no_frames_csv", "", "", "frames.csv: missing"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path d = base / c.name;
    fs::copy(s1, d, fs::copy_options::recursive);
    if (c.frames.empty())
      fs::remove(d / "frames.csv");
    else
      std::ofstream(d / "frames.csv", std::ios::binary) << c.frames;
    if (!c.results.empty()) std::ofstream(d / "results.json") << c.results;
    const fs::path out = base / ("out_" + std::string(c.name));
    EXPECT_EQ(run({"merge", out.string(), d.string(), s2.string()}), 1) << log;
    EXPECT_NE(log.find(c.expected), std::string::npos) << log;
    EXPECT_NE(log.find(d.string()), std::string::npos) << log;
    EXPECT_FALSE(fs::exists(out));
    // 'dhrbench report' refuses the same folder (exit 2), naming the file.
    if (!c.report_refuses) continue;
    EXPECT_EQ(run({"report", d.string()}), 2) << log;
    EXPECT_NE(log.find(c.expected), std::string::npos) << log;
    EXPECT_FALSE(fs::exists(d / "report.md"));
  }
  EXPECT_FALSE(fs::exists("PWNED"));
  EXPECT_FALSE(fs::exists(base / "PWNED"));
  fs::remove_all(base);
}

// A cache entry of one AO pass, w x 4 pixels, every byte `value`.
std::shared_ptr<TraceCache::Entry> ao_entry(int w, uint8_t value) {
  auto entry = std::make_shared<TraceCache::Entry>();
  PassBuffer ao;
  ao.desc = {PassKind::Ao, w, 4, 1, 8};
  ao.bytes.assign(ao.desc.byte_size(), value);
  entry->passes.push_back({"ao", PassMeaning::Ao, ao, 0.0});
  return entry;
}

TEST(TraceCache, AFlippedByteInACacheFileIsFoundByItsChecksum) {
  const fs::path dir = fs::temp_directory_path() / fmt::format("dhr_trace_cache_crc.{}", ::getpid());
  fs::remove_all(dir);
  const auto entry = ao_entry(64, 7);
  {
    TraceCache writer;
    writer.set_disk_dir(dir.string());
    writer.insert("key", entry);
  }
  std::vector<fs::path> files;
  for (const auto& f : fs::directory_iterator(dir)) files.push_back(f.path());
  ASSERT_EQ(files.size(), 1u) << "a temporary file was left behind";
  std::string bytes = read_text(files[0]);
  TraceCache reader;
  reader.set_disk_dir(dir.string());
  ASSERT_NE(reader.find("key"), nullptr);
  // One bit of a pixel: every size still agrees, only the checksum tells.
  bytes[bytes.size() - 100] ^= 0x10;
  std::ofstream(files[0], std::ios::binary) << bytes;
  TraceCache again;
  again.set_disk_dir(dir.string());
  EXPECT_EQ(again.find("key"), nullptr);
  fs::remove_all(dir);
}

// The disk keys carry Embree's ISA: a folder shared by machines of two CPU kinds never hands one
// the other's traces (their kernels can answer a ray on an edge differently).
TEST(TraceCache, DiskEntriesAreKeptPerEmbreeIsa) {
  const fs::path dir = fs::temp_directory_path() / fmt::format("dhr_trace_cache_isa.{}", ::getpid());
  fs::remove_all(dir);
  const auto entry = ao_entry(16, 3);
  const std::string isa = embree_isa();
  {
    TraceCache writer;
    writer.set_disk_dir(dir.string());
    writer.insert("key", entry);
  }
  TraceCache same;
  same.set_disk_dir(dir.string());
  ASSERT_NE(same.find("key"), nullptr);
  test::ScopedEnv cap("DHR_MAX_ISA", isa == "sse2" ? "sse4.2" : "sse2");
  if (embree_isa() != isa) {  // else this CPU has no other ISA
    TraceCache other;
    other.set_disk_dir(dir.string());
    EXPECT_EQ(other.find("key"), nullptr);
  }
  fs::remove_all(dir);
}

// Two processes write one entry over and over (each its own version, of the same size), and
// read it back between writes: every read is one whole version, never a mixture or a part.
TEST(TraceCache, TwoProcessesRacingOnOneEntryNeverCorruptOrHalfReadIt) {
  const fs::path dir = fs::temp_directory_path() / fmt::format("dhr_trace_cache_race.{}", ::getpid());
  fs::remove_all(dir);
  auto version = [](uint8_t fill) {
    auto e = std::make_shared<TraceCache::Entry>();
    PassBuffer ao;
    ao.desc = {PassKind::Ao, 512, 256, 1, 8};  // 128 KiB: many writes per file
    ao.bytes.assign(ao.desc.byte_size(), fill);
    e->passes.push_back({"ao", PassMeaning::Ao, ao, 0.0});
    e->stats.ao_rays = fill;
    return e;
  };
  // Returns the number of bad reads.
  auto hammer = [&](uint8_t fill, int rounds) {
    int bad = 0;
    for (int i = 0; i < rounds; ++i) {
      TraceCache c;  // a fresh one: every find reads the disk
      c.set_disk_dir(dir.string());
      c.insert("one-key", version(fill));
      TraceCache r;
      r.set_disk_dir(dir.string());
      auto got = r.find("one-key");
      if (!got || !got->find("ao")) {
        ++bad;  // a file is there from the first write on: a miss is a half-read file refused
        continue;
      }
      const uint8_t first = got->find("ao")->bytes[0];
      if ((first != 0xAA && first != 0x55) || got->stats.ao_rays != first) ++bad;
      for (uint8_t b : got->find("ao")->bytes) bad += b != first;
    }
    return bad;
  };
  const int rounds = 150;
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) _exit(std::min(hammer(0x55, rounds), 100));
  const int bad_here = hammer(0xAA, rounds);
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "bad reads in the child";
  EXPECT_EQ(bad_here, 0);
  std::vector<std::string> left;
  for (const auto& f : fs::directory_iterator(dir)) left.push_back(f.path().filename().string());
  EXPECT_EQ(left.size(), 1u) << "temporary files left: " << left.size();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace dhr
