#include "core/experiment/shard.h"

#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/config/run_config.h"

#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <map>
#include <numeric>
#include <random>

namespace dhr {

namespace {

uint64_t fnv1a64(std::string_view s, uint64_t h = 0xcbf29ce484222325ull) {
  for (unsigned char ch : s) h = (h ^ ch) * 0x100000001b3ull;
  return h;
}

// Union-find over run indices.
size_t root(std::vector<size_t>& parent, size_t i) {
  while (parent[i] != i) i = parent[i] = parent[parent[i]];
  return i;
}

}  // namespace

ShardSpec parse_shard(const std::string& text) {
  const size_t slash = text.find('/');
  auto number = [](std::string_view s, int& out) {
    const auto r = std::from_chars(s.data(), s.data() + s.size(), out);
    return !s.empty() && r.ec == std::errc() && r.ptr == s.data() + s.size();
  };
  ShardSpec s;
  if (slash == std::string::npos || !number(std::string_view(text).substr(0, slash), s.index) ||
      !number(std::string_view(text).substr(slash + 1), s.count) || s.count < 1 || s.count > 10000 || s.index < 1 ||
      s.index > s.count)
    fail("--shard '{}': expected K/N with 1 <= K <= N <= 10000 (shard K of N), e.g. --shard 2/4", text_excerpt(text));
  return s;
}

ShardPlan plan_shards(const Experiment& e, int count) {
  if (count < 1) fail("shards: {} is not a shard count (1 or more)", count);
  const size_t n = e.runs.size();
  std::vector<size_t> parent(n);
  std::iota(parent.begin(), parent.end(), size_t(0));
  // Runs with the same scene and trace key settings share traced buffers; with the same scene
  // and ground-truth key settings they share ground truths. Join both.
  for (SettingFlag flag : {kInTraceKey, kInTruthKey}) {
    std::map<std::string, size_t> first;
    for (size_t i = 0; i < n; ++i) {
      const std::string key = e.runs[i].scene + '\n' + settings_key(e.runs[i].config, flag);
      auto [it, added] = first.emplace(key, i);
      if (!added) parent[root(parent, i)] = root(parent, it->second);
    }
  }
  // Groups in the order of their first run, with their cost.
  std::map<size_t, size_t> group_of_root;
  std::vector<std::vector<size_t>> groups;
  std::vector<double> group_cost;
  for (size_t i = 0; i < n; ++i) {
    const size_t r = root(parent, i);
    auto [it, added] = group_of_root.emplace(r, groups.size());
    if (added) {
      groups.emplace_back();
      group_cost.push_back(0.0);
    }
    groups[it->second].push_back(i);
    const SimConfig& c = e.runs[i].config;
    group_cost[it->second] += double(c.width) * double(c.height) * double(c.frames + c.warmup_frames);
  }
  std::vector<size_t> order(groups.size());
  std::iota(order.begin(), order.end(), size_t(0));
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return group_cost[a] > group_cost[b]; });

  ShardPlan plan;
  plan.count = count;
  plan.groups = groups.size();
  plan.runs.resize(size_t(count));
  plan.cost.assign(size_t(count), 0.0);
  for (size_t g : order) {
    const size_t shard = size_t(std::min_element(plan.cost.begin(), plan.cost.end()) - plan.cost.begin());
    plan.cost[shard] += group_cost[g];
    plan.runs[shard].insert(plan.runs[shard].end(), groups[g].begin(), groups[g].end());
  }
  for (auto& r : plan.runs) std::sort(r.begin(), r.end());
  return plan;
}

std::string experiment_hash(const Experiment& e) {
  uint64_t h = fnv1a64(e.source.dump());
  for (const auto& r : e.runs) h = fnv1a64(r.id + '\n' + r.scene + '\n' + r.label + '\n', h);
  return fmt::format("{:016x}", h);
}

nlohmann::json ShardManifest::to_json() const {
  nlohmann::json j = {{"experiment_hash", experiment_hash},
                      {"experiment_path", experiment_path},
                      {"git_commit", git_commit},
                      {"shard", index},
                      {"shards", count},
                      {"runs", run_ids},
                      {"experiment_runs", all_runs},
                      {"status", status}};
  if (!error.empty()) j["error"] = error;
  return j;
}

void write_shard_manifest(const std::string& dir, const ShardManifest& m) {
  namespace fs = std::filesystem;
  const fs::path path = fs::path(dir) / kShardManifestFile;
  const fs::path tmp =
      fs::path(dir) / fmt::format(".{}.tmp{}.{:08x}", kShardManifestFile, ::getpid(), std::random_device{}());
  {
    std::ofstream f(tmp);
    f << m.to_json().dump(1) << '\n';
    f.close();
    if (!f) fail("{}: cannot write the shard manifest", tmp.string());
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) fail("cannot move {} to {}: {}", tmp.string(), path.string(), ec.message());
}

ShardManifest read_shard_manifest(const std::string& dir) {
  namespace fs = std::filesystem;
  const std::string path = (fs::path(dir) / kShardManifestFile).string();
  if (!fs::exists(path))
    fail("{}: no {} here (a folder written by 'dhrbench run --shard K/N' has one from its start)", dir,
         kShardManifestFile);
  const nlohmann::json j = read_json_file(path);
  if (!j.is_object()) fail("{}: must be a JSON object, got {}", path, json_excerpt(j));
  auto field = [&](const char* key) -> const nlohmann::json& {
    if (!j.contains(key)) fail("{}: \"{}\" is missing", path, key);
    return j.at(key);
  };
  auto string = [&](const char* key) {
    const auto& v = field(key);
    if (!v.is_string()) fail("{}: \"{}\" must be a string, got {}", path, key, json_excerpt(v));
    return v.get<std::string>();
  };
  auto integer = [&](const char* key) {
    const auto& v = field(key);
    if (!v.is_number_integer() || v.get<int64_t>() < 1 || v.get<int64_t>() > 10000)
      fail("{}: \"{}\" must be an integer 1..10000, got {}", path, key, json_excerpt(v));
    return v.get<int>();
  };
  auto strings = [&](const char* key) {
    const auto& v = field(key);
    if (!v.is_array()) fail("{}: \"{}\" must be a list of run ids, got {}", path, key, json_excerpt(v));
    std::vector<std::string> out;
    for (const auto& x : v) {
      if (!x.is_string()) fail("{}: \"{}\" holds {}, not a run id", path, key, json_excerpt(x));
      out.push_back(x.get<std::string>());
    }
    return out;
  };
  ShardManifest m;
  m.experiment_hash = string("experiment_hash");
  m.experiment_path = string("experiment_path");
  m.git_commit = field("git_commit");
  if (!m.git_commit.is_string() && !m.git_commit.is_null())
    fail("{}: \"git_commit\" must be a string or null, got {}", path, json_excerpt(m.git_commit));
  m.index = integer("shard");
  m.count = integer("shards");
  if (m.index > m.count) fail("{}: shard {} of {}: the shard number exceeds the count", path, m.index, m.count);
  m.run_ids = strings("runs");
  m.all_runs = strings("experiment_runs");
  m.status = string("status");
  if (m.status != "running" && m.status != "complete" && m.status != "failed")
    fail("{}: \"status\" = {}: must be running, complete or failed", path, json_excerpt(field("status")));
  if (j.contains("error")) m.error = string("error");
  return m;
}

}  // namespace dhr

namespace dhr {

ShardRun ShardRun::start(Experiment& e, const ShardSpec& spec, const std::string& dir,
                         const nlohmann::json& git_commit) {
  namespace fs = std::filesystem;
  const ShardPlan plan = plan_shards(e, spec.count);
  ShardRun s;
  s.dir = dir;
  ShardManifest& m = s.manifest;
  m.experiment_hash = experiment_hash(e);
  m.experiment_path = e.path;
  m.git_commit = git_commit;
  m.index = spec.index;
  m.count = spec.count;
  for (const auto& r : e.runs) m.all_runs.push_back(r.id);
  std::vector<RunSpec> mine;
  for (size_t i : plan.runs[size_t(spec.index - 1)]) {
    m.run_ids.push_back(e.runs[i].id);
    mine.push_back(e.runs[i]);
  }
  e.runs = std::move(mine);
  std::vector<std::string> scenes;
  for (const auto& scene : e.scenes)
    if (std::any_of(e.runs.begin(), e.runs.end(), [&](const RunSpec& r) { return r.scene == scene; }))
      scenes.push_back(scene);
  e.scenes = std::move(scenes);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) fail("{}: cannot create the shard's folder: {}", dir, ec.message());
  for (const char* stale : {"results.json", "frames.csv", "report.md"}) fs::remove(fs::path(dir) / stale, ec);
  write_shard_manifest(dir, m);
  return s;
}

void ShardRun::finish(const std::string& error) {
  manifest.status = error.empty() ? "complete" : "failed";
  manifest.error = error;
  write_shard_manifest(dir, manifest);
}

}  // namespace dhr
