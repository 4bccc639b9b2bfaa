// Shards: a deterministic split of an experiment's runs over N processes or machines
// (`dhrbench run EXPERIMENT --shard K/N`, `dhrbench merge`; README.md, "On a Slurm cluster").
//
// Runs that share traced buffers or ground truths (the same scene and the same settings of the
// trace cache key or of the ground-truth key, core/config/run_config.h: kInTraceKey, kInTruthKey) form
// one group, and a group is never split: a shard traces what it needs once. Groups are dealt to
// shards largest first (cost: pixels x frames of their runs), each to the shard with the least
// cost so far (the lower number on a tie). Within a shard, runs keep the experiment's order.
// The plan depends only on the experiment, so every shard computes the same plan.
#pragma once

#include "core/experiment/experiment.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace dhr {

struct ShardSpec {
  int index = 1;  // K, 1-based
  int count = 1;  // N
};

// Parses "K/N" (1 <= K <= N <= 10000). Throws dhr::Error naming the text and what is valid.
ShardSpec parse_shard(const std::string& text);

struct ShardPlan {
  int count = 1;
  // Per shard (0-based): indices into Experiment::runs, in the experiment's order.
  std::vector<std::vector<size_t>> runs;
  std::vector<double> cost;  // per shard: sum of width x height x (frames + warmup_frames)
  size_t groups = 0;         // groups of runs that share traces or ground truths
};

ShardPlan plan_shards(const Experiment& e, int count);

// A hex digest identifying the experiment as run: its JSON after --set overrides (canonical
// dump) and its run ids. Shards of one sweep carry the same one.
std::string experiment_hash(const Experiment& e);

// The shard manifest, DIR/shard.json, written by a sharded run at its start ("status":
// "running"), when it ends ("complete": every run recorded, some may have failed and carry an
// "error" in results.json) or when it stops on an error ("failed", with "error"). A shard killed
// from outside (a time limit, out of memory) stays "running": the merge reports it as such.
struct ShardManifest {
  std::string experiment_hash;
  std::string experiment_path;
  nlohmann::json git_commit;  // string or null (context.git_commit)
  int index = 1, count = 1;
  std::vector<std::string> run_ids;   // this shard's runs
  std::vector<std::string> all_runs;  // every run of the experiment, in its order
  std::string status = "running";     // running, complete, failed
  std::string error;                  // when failed
  nlohmann::json to_json() const;
};

constexpr const char* kShardManifestFile = "shard.json";

// Writes DIR/shard.json atomically (temporary file and rename).
void write_shard_manifest(const std::string& dir, const ShardManifest& m);
// Reads and checks DIR/shard.json; throws dhr::Error naming the file and the field.
ShardManifest read_shard_manifest(const std::string& dir);

}  // namespace dhr

namespace dhr {

// A sharded run in progress: keeps only shard K's runs (and the scenes they use) in `e`,
// removes results of an earlier attempt from `dir` and writes its manifest ("running").
// finish() records "complete", or "failed" with the error.
struct ShardRun {
  std::string dir;
  ShardManifest manifest;
  static ShardRun start(Experiment& e, const ShardSpec& spec, const std::string& dir, const nlohmann::json& git_commit);
  void finish(const std::string& error = {});
};

}  // namespace dhr
