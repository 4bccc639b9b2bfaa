// dhrbench merge OUT SHARD_DIR...: joins the folders of a sharded sweep (`dhrbench run
// EXPERIMENT --shard K/N`, core/experiment/shard.h) into one results folder, as an unsharded run writes it.
// Works on the files: each shard's shard.json, results.json, frames.csv and images/. Checks
// first, and reports every problem at once before writing anything: the shards belong to the
// same experiment (hash of its JSON after --set overrides and its runs) and commit, every shard
// of 1..N is there once, each finished ("complete"), and together they hold every run once.
// A failed or unfinished shard is reported with its error and the runs it held.
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/experiment/experiment.h"
#include "core/experiment/shard.h"
#include "core/results/results_check.h"
#include "experiments/cli/commands.h"

#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

namespace dhr::cli {

namespace {

namespace fs = std::filesystem;

std::string join(const std::vector<std::string>& v, size_t max_items = 40) {
  std::string s;
  for (size_t i = 0; i < v.size() && i < max_items; ++i) s += (i ? ", " : "") + v[i];
  if (v.size() > max_items) s += fmt::format(" and {} more", v.size() - max_items);
  return s.empty() ? "none" : s;
}

struct Shard {
  std::string dir;
  ShardManifest manifest;
  nlohmann::json results;
  std::map<std::string, std::vector<std::string>> frames;  // run id -> CSV records
  std::string frames_header;
};

}  // namespace

void print_shard_plan(const Experiment& e, int count) {
  const ShardPlan plan = plan_shards(e, count);
  double total = 0;
  for (double c : plan.cost) total += c;
  fmt::print("shard plan for {} shard(s): {} group(s) of runs sharing traces or ground truths{}\n", count, plan.groups,
             plan.groups < size_t(count) ? fmt::format(" (shards {}..{} get no run)", plan.groups + 1, count) : "");
  for (int k = 0; k < count; ++k) {
    fmt::print("  shard {}/{}: {} run(s), {:.0f}% of the pixel-frames\n", k + 1, count, plan.runs[size_t(k)].size(),
               total > 0 ? 100.0 * plan.cost[size_t(k)] / total : 0.0);
    for (size_t i : plan.runs[size_t(k)])
      fmt::print("    {}  {:<22} {}\n", e.runs[i].id, e.runs[i].scene, e.runs[i].label);
  }
}

Runner add_merge_command(CLI::App& app) {
  struct Options {
    std::string out;
    std::vector<std::string> shards;
    bool no_report = false;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "merge",
      "Join the folders of a sharded run ('dhrbench run EXPERIMENT --shard K/N --out DIR_K') into OUT: one\n"
      "results.json, frames.csv, images/ and report.md, as 'dhrbench run' writes for the whole sweep. Checks that\n"
      "the shards belong to the same experiment and commit, that none is missing, repeated or unfinished, and\n"
      "reports every problem at once (a failed shard with its error and its runs: rerun that shard, then merge\n"
      "again). Exit 1 when nothing was merged; 4 when merged but some run recorded an error (as 'run'). Example:\n"
      "  dhrbench merge out/paper out/paper.shard1 out/paper.shard2");
  cmd->add_option("out", o->out, "Output folder")->required();
  cmd->add_option("shards", o->shards, "The shards' folders (any order)")->required()->check(CLI::ExistingDirectory);
  cmd->add_flag("--no-report", o->no_report, "Write results only (build the report later with 'dhrbench report OUT')");
  return [o] {
    std::vector<std::string> problems;
    std::vector<Shard> shards;
    // OUT must not be, or lie inside, a shard's folder: writing it would overwrite that shard.
    auto resolved = [](const std::string& dir) {  // absolute, links resolved, no trailing '/'
      std::error_code ec;
      fs::path p = fs::weakly_canonical(fs::absolute(dir), ec);
      if (ec) p = fs::absolute(dir).lexically_normal();
      return p.has_filename() ? p : p.parent_path();
    };
    const fs::path out_abs = resolved(o->out);
    for (const auto& dir : o->shards) {
      const fs::path shard_abs = resolved(dir);
      const auto [end, at] = std::mismatch(shard_abs.begin(), shard_abs.end(), out_abs.begin(), out_abs.end());
      if (end == shard_abs.end())
        problems.push_back(fmt::format("OUT {} {} the shard folder {}: merge into a new folder outside every shard",
                                       o->out, at == out_abs.end() ? "is" : "lies inside", dir));
    }
    if (fs::exists(o->out) && !fs::is_directory(o->out))
      problems.push_back(fmt::format("OUT {} is a file, not a folder", o->out));
    for (const auto& dir : o->shards) {
      try {
        shards.push_back({dir, read_shard_manifest(dir), {}, {}, {}});
      } catch (const Error& err) {
        problems.push_back(err.what());
      }
    }
    // Same experiment, commit and count; each shard once.
    std::map<int, std::string> seen;
    const Shard* first = shards.empty() ? nullptr : &shards.front();
    for (const Shard& s : shards) {
      const ShardManifest& m = s.manifest;
      if (m.experiment_hash != first->manifest.experiment_hash || m.all_runs != first->manifest.all_runs)
        problems.push_back(fmt::format("{}: another experiment (hash {}, {}) than {} (hash {}, {})", s.dir,
                                       m.experiment_hash, m.experiment_path, first->dir,
                                       first->manifest.experiment_hash, first->manifest.experiment_path));
      else if (m.git_commit != first->manifest.git_commit)
        problems.push_back(
            fmt::format("{}: run at commit {}, {} at commit {}: shards of one result come from one commit", s.dir,
                        m.git_commit.dump(), first->dir, first->manifest.git_commit.dump()));
      else if (m.count != first->manifest.count)
        problems.push_back(fmt::format("{}: shard {}/{}, but {} is one of {} shards", s.dir, m.index, m.count,
                                       first->dir, first->manifest.count));
      else if (auto [it, added] = seen.emplace(m.index, s.dir); !added)
        problems.push_back(fmt::format("shard {}/{} given twice: {} and {}", m.index, m.count, it->second, s.dir));
    }
    if (first && problems.empty())
      for (int k = 1; k <= first->manifest.count; ++k)
        if (!seen.count(k))
          problems.push_back(
              fmt::format("shard {}/{} is missing (none of the folders given holds it)", k, first->manifest.count));
    // Each shard finished, and its files agree with its manifest.
    for (Shard& s : shards) {
      const ShardManifest& m = s.manifest;
      const std::string runs = join(m.run_ids);
      if (m.status == "failed") {
        problems.push_back(fmt::format(
            "shard {}/{} ({}) failed: {}\n    its runs: {}\n    rerun it: dhrbench run {} --shard {}/{} --out {}",
            m.index, m.count, s.dir, m.error, runs, m.experiment_path, m.index, m.count, s.dir));
        continue;
      }
      if (m.status == "running") {
        problems.push_back(
            fmt::format("shard {}/{} ({}) did not finish (status \"running\": still running, or stopped "
                        "from outside, e.g. a time limit; see its log)\n    its runs: {}\n    rerun it: "
                        "dhrbench run {} --shard {}/{} --out {}",
                        m.index, m.count, s.dir, runs, m.experiment_path, m.index, m.count, s.dir));
        continue;
      }
      try {
        const fs::path results_path = fs::path(s.dir) / "results.json";
        if (!fs::exists(results_path)) fail("{}: missing, though shard.json says complete", results_path.string());
        s.results = read_json_file(results_path.string());
        check_results_json(s.results, results_path.string());
        std::vector<std::string> ids;
        for (const auto& r : s.results.at("runs")) ids.push_back(r.at("id").get<std::string>());
        if (ids != m.run_ids)
          fail("{}: holds runs {}, its shard.json {}", results_path.string(), join(ids), join(m.run_ids));
        const nlohmann::json commit = s.results.at("context").value("git_commit", nlohmann::json());
        if (commit != m.git_commit)
          fail("{}: written at commit {}, but its shard.json says {}: the folder mixes two runs", results_path.string(),
               commit.dump(), m.git_commit.dump());
        if (first->results.is_object() && &s != first && s.results.at("experiment") != first->results.at("experiment"))
          fail("{}: its experiment differs from {}'s", results_path.string(), first->dir);
        // Embree's kernels of two ISAs can answer a ray on an edge differently: one result, one ISA.
        if (first->results.is_object() && &s != first) {
          const nlohmann::json none;
          const nlohmann::json isa = s.results.at("context").value("embree_isa", none);
          const nlohmann::json first_isa = first->results.at("context").value("embree_isa", none);
          if (isa != first_isa)
            fail(
                "{}: traced with Embree's {} kernels, {} with its {}: the figures of one result come from one "
                "ISA (run every shard with the same DHR_MAX_ISA, e.g. avx2, the best all nodes have)",
                results_path.string(), isa.dump(), first->dir, first_isa.dump());
        }
        const fs::path frames_path = fs::path(s.dir) / "frames.csv";
        if (!fs::exists(frames_path)) fail("{}: missing, though shard.json says complete", frames_path.string());
        FramesCsv frames = check_frames_csv(read_text_file(frames_path.string()), s.results, frames_path.string());
        s.frames_header = std::move(frames.header);
        s.frames = std::move(frames.rows);
        if (s.frames_header != first->frames_header && !first->frames_header.empty())
          fail("{}: its header differs from {}'s", frames_path.string(), first->dir);
      } catch (const Error& err) {
        problems.push_back(err.what());
      }
    }
    // Together: every run of the experiment once.
    if (problems.empty() && first) {
      std::map<std::string, std::string> holder;
      for (const Shard& s : shards)
        for (const auto& id : s.manifest.run_ids)
          if (auto [it, added] = holder.emplace(id, s.dir); !added)
            problems.push_back(fmt::format("run {} is in two shards: {} and {}", id, it->second, s.dir));
      std::vector<std::string> missing;
      for (const auto& id : first->manifest.all_runs)
        if (!holder.count(id)) missing.push_back(id);
      if (!missing.empty()) problems.push_back(fmt::format("runs in no shard: {}", join(missing)));
      const std::set<std::string> all(first->manifest.all_runs.begin(), first->manifest.all_runs.end());
      std::vector<std::string> extra;
      for (const auto& [id, dir] : holder)
        if (!all.count(id)) extra.push_back(id + " (" + dir + ")");
      if (!extra.empty()) problems.push_back(fmt::format("runs that are not the experiment's: {}", join(extra)));
    }
    if (shards.empty() && problems.empty()) problems.push_back("no shard folders given");
    if (!problems.empty()) {
      std::string msg = fmt::format("merge into {}: {} problem(s); nothing was written:", o->out, problems.size());
      for (const auto& p : problems) msg += "\n  " + p;
      throw Error(msg);
    }

    // The runs in the experiment's order.
    std::map<std::string, const Shard*> holder;
    std::map<std::string, const nlohmann::json*> record;
    for (const Shard& s : shards)
      for (const auto& r : s.results.at("runs")) {
        holder[r.at("id").get<std::string>()] = &s;
        record[r.at("id").get<std::string>()] = &r;
      }
    std::vector<const Shard*> by_index(shards.size());
    for (const Shard& s : shards) by_index[size_t(s.manifest.index - 1)] = &s;
    nlohmann::json merged = by_index.front()->results;
    merged["runs"] = nlohmann::json::array();
    merged["shards"] = nlohmann::json::array();
    double wall = 0;
    int failed = 0;
    for (const Shard* s : by_index) {
      const double w = s->results.value("wall_s", 0.0);
      wall += w;
      merged["shards"].push_back({{"shard", s->manifest.index},
                                  {"folder", s->dir},
                                  {"runs", s->manifest.run_ids},
                                  {"wall_s", w},
                                  {"context", s->results.at("context")}});
    }
    merged["wall_s"] = wall;  // the sum over the shards (each shard's own is under "shards")
    make_output_dir((fs::path(o->out) / "images").string(), "OUT");
    std::ofstream csv(fs::path(o->out) / "frames.csv", std::ios::binary);
    csv << by_index.front()->frames_header;
    for (const auto& id : first->manifest.all_runs) {
      const nlohmann::json& r = *record.at(id);
      if (r.contains("error")) ++failed;
      merged["runs"].push_back(r);
      const Shard& s = *holder.at(id);
      if (auto it = s.frames.find(id); it != s.frames.end())
        for (const auto& line : it->second) csv << line;
    }
    csv.close();
    if (!csv) fail("{}: cannot write", (fs::path(o->out) / "frames.csv").string());
    // Images: each shard's images/ holds its runs' files (named by run id).
    for (const Shard* s : by_index) {
      const fs::path images = fs::path(s->dir) / "images";
      if (!fs::is_directory(images)) continue;
      for (const auto& f : fs::directory_iterator(images))
        if (f.is_regular_file())
          fs::copy_file(f.path(), fs::path(o->out) / "images" / f.path().filename(),
                        fs::copy_options::overwrite_existing);
    }
    std::ofstream(fs::path(o->out) / "results.json") << merged.dump(1) << '\n';
    fmt::print(stderr, "merged {} shard(s), {} runs ({} failed): {}/results.json\n", shards.size(),
               merged["runs"].size(), failed, o->out);
    int rc = 0;
    if (!o->no_report) {
      rc = write_report(o->out);
      if (rc == 0) fmt::print(stderr, "report: {}/report.md\n", o->out);
    }
    return failed ? 4 : rc;
  };
}

}  // namespace dhr::cli
