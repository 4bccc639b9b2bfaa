// dhrbench run / validate / report: the experiment runner (core/experiment/experiment.h describes the
// file). A run validates the whole sweep first and reports every problem at once; then it
// runs each configuration on each scene, records a failing configuration with its error and
// goes on, and writes results.json, frames.csv, images and the report.
#include "backends/register_all.h"
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/base/process.h"
#include "core/buffers/image_io.h"
#include "core/config/cache_keys.h"
#include "core/config/run_plan.h"
#include "core/experiment/experiment.h"
#include "core/experiment/shard.h"
#include "core/metrics/flip.h"
#include "core/metrics/metrics.h"
#include "core/pass/passes.h"
#include "core/pass/reference.h"
#include "core/results/results.h"
#include "core/results/results_check.h"
#include "core/scene/scene_load.h"
#include "core/sim/frame_loop.h"
#include "experiments/cli/commands.h"
#include "experiments/cli/context.h"

#include <fmt/format.h>
#include <tbb/global_control.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <thread>

namespace dhr::cli {

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct LoadedScenes {
  std::map<std::string, Scene> scenes;
  std::map<std::string, std::string> keys;  // content hash per scene
  std::vector<RunPlan> plans;               // per run of the experiment, in its order (plan_run)
};

// Loads every scene of the experiment and plans every run on it (the plans, one per run, are
// what the runs then take). Throws one dhr::Error listing every problem.
LoadedScenes validate_all(const Experiment& e, const std::vector<std::string>& scene_path) {
  LoadedScenes loaded;
  std::vector<std::string> problems;
  const SceneSearchPath search = SceneSearchPath::standard(scene_path);
  for (const auto& name : e.scenes) {
    if (loaded.scenes.count(name)) continue;
    try {
      Scene s = load_scene_or_model(name, search);
      loaded.keys[name] = fmt::format("{:016x}", scene_content_hash(s));
      loaded.scenes.emplace(name, std::move(s));
    } catch (const Error& err) {
      problems.push_back(fmt::format("scene '{}': {}", name, err.what()));
    }
  }
  for (const auto& run : e.runs) {
    auto it = loaded.scenes.find(run.scene);
    if (it == loaded.scenes.end()) continue;
    try {
      loaded.plans.push_back(plan_run(run.config, it->second, registries()));
      if (std::string why = warmup_problem(run.config); !why.empty()) throw Error(why);
    } catch (const Error& err) {
      std::string what = err.what();
      for (size_t pos = 0; (pos = what.find('\n', pos)) != std::string::npos; pos += 5) what.replace(pos, 1, "\n    ");
      problems.push_back(fmt::format("{} ({} on {}): {}", run.id, run.label, run.scene, what));
    }
  }
  if (!problems.empty()) {
    std::string msg = fmt::format("{}: {} problem(s); nothing was run:", e.path, problems.size());
    for (const auto& p : problems) msg += "\n  " + p;
    throw Error(msg);
  }
  if (loaded.plans.size() != e.runs.size()) fail("internal: {} plans for {} runs", loaded.plans.size(), e.runs.size());
  return loaded;
}

// Progress: a bar on a terminal, plain lines otherwise.
class Progress {
 public:
  explicit Progress(size_t runs) : runs_(runs), tty_(isatty(fileno(stderr))) {}
  // Run `run` (of those in flight) is at frame `frame` of `total`. Thread-safe.
  void update(size_t run, const std::string& label, int frame, int total) {
    std::lock_guard lock(mutex_);
    in_flight_[run] = double(frame) / std::max(total, 1);
    double done = double(finished_);
    for (const auto& [r, fraction] : in_flight_) done += fraction;
    done /= double(runs_);
    const double elapsed = std::chrono::duration<double>(Clock::now() - start_).count();
    const double eta = done > 0 ? elapsed / done - elapsed : 0;
    if (tty_) {
      const int width = 24, filled = int(done * width);
      std::fprintf(stderr, "\r[%s%s] config %zu/%zu frame %d/%d  ETA %s  %-40.40s",
                   std::string(size_t(filled), '#').c_str(), std::string(size_t(width - filled), '.').c_str(), run + 1,
                   runs_, frame, total, eta_text(eta).c_str(), label.c_str());
      std::fflush(stderr);
    } else if (frame == total || frame % std::max(1, total / 4) == 0) {
      std::fprintf(stderr, "progress: config %zu/%zu (%s) frame %d/%d, elapsed %.0f s, ETA %s\n", run + 1, runs_,
                   label.c_str(), frame, total, elapsed, eta_text(eta).c_str());
    }
  }
  void run_done(size_t run) {
    std::lock_guard lock(mutex_);
    in_flight_.erase(run);
    ++finished_;
  }
  void finish() {
    if (tty_) std::fprintf(stderr, "\n");
  }

 private:
  static std::string eta_text(double s) {
    return s < 90 ? fmt::format("{:.0f} s", s)
                  : fmt::format("{:.0f} min {:02.0f} s", std::floor(s / 60), std::fmod(s, 60));
  }
  size_t runs_;
  bool tty_;
  Clock::time_point start_ = Clock::now();
  std::mutex mutex_;
  std::map<size_t, double> in_flight_;  // run -> fraction done
  size_t finished_ = 0;
};

// The memory one run may add beside the others (bytes), an upper estimate: the client's
// G-buffers (history_frames of them, 76 bytes per pixel; runs on one scene often share them
// through the cache, so this overestimates) and its images, pipelines and denoisers (about
// 300 bytes per pixel).
double run_memory_estimate(const SimConfig& c) {
  const double pixels = double(c.width) * double(c.height);
  const int kept = std::min(c.history_frames, c.warmup_frames + c.frames);
  return pixels * (76.0 * kept + 300.0);
}

// This process's resident memory (bytes), from /proc/self/statm; 0 where it cannot be read.
double resident_bytes() {
  std::ifstream statm("/proc/self/statm");
  double size = 0, resident = 0;
  if (!(statm >> size >> resident)) return 0.0;
  return resident * double(sysconf(_SC_PAGESIZE));
}

double physical_memory_bytes() { return double(sysconf(_SC_PHYS_PAGES)) * double(sysconf(_SC_PAGESIZE)); }

ImageRGB8 downscale(const ImageRGB8& img, int max_width) {
  if (img.width() <= max_width) return img;
  const int f = (img.width() + max_width - 1) / max_width;
  ImageRGB8 out(img.width() / f, img.height() / f);
  for (int y = 0; y < out.height(); ++y)
    for (int x = 0; x < out.width(); ++x) {
      int r = 0, g = 0, b = 0;
      for (int dy = 0; dy < f; ++dy)
        for (int dx = 0; dx < f; ++dx) {
          const Rgb8 p = img(x * f + dx, y * f + dy);
          r += p.r;
          g += p.g;
          b += p.b;
        }
      const int n = f * f;
      out(x, y) = {uint8_t(r / n), uint8_t(g / n), uint8_t(b / n)};
    }
  return out;
}

}  // namespace

// Runs the report script (Debian's python3 with matplotlib) on a results folder (also used by
// 'dhrbench merge', experiments/cli/cmd_merge.cpp).
int write_report(const std::string& dir) {
  const std::string script = std::string(DHR_SOURCE_DIR) + "/experiments/report.py";
  const std::string python = fs::exists("/usr/bin/python3") ? "/usr/bin/python3" : "python3";
  // An argument vector, never a shell: the folder's name reaches the script as it is.
  const ProcessResult r = run_process({python, script, dir});
  if (r.ok()) return 0;
  if (!r.started) {
    std::fprintf(stderr, "dhrbench: cannot start %s to write the report (install python3: scripts/setup.sh)\n",
                 python.c_str());
    return 3;
  }
  // Exit 2: the script found the results damaged and has said what is wrong, naming the file.
  if (r.exit_code == 2) return 2;
  // Exit 3: no matplotlib (checked by the script once the results are found sound).
  if (r.exit_code == 3) {
    std::fprintf(stderr,
                 "dhrbench: the results in %s are complete; rebuild the report once matplotlib is installed with "
                 "'dhrbench report %s'\n",
                 dir.c_str(), dir.c_str());
    return 3;
  }
  std::fprintf(stderr, "dhrbench: the report script %s failed (%s %d) on %s\n", script.c_str(),
               r.signal ? "signal" : "exit", r.signal ? r.signal : r.exit_code, dir.c_str());
  return 3;
}

namespace {

// Reads DIR/results.json the way every JSON is read (depth-bounded, errors naming the file) and
// checks it and DIR/frames.csv against each other (core/results/results_check.h); report.py checks every
// field it reads besides. A published report may hold frames.csv.gz instead (report.py reads it).
void check_results_folder(const std::string& dir) {
  const fs::path path = fs::path(dir) / "results.json";
  if (!fs::exists(path)) fail("{}: no results.json here (was it written by 'dhrbench run'?)", dir);
  const nlohmann::json r = read_json_file(path.string());
  check_results_json(r, path.string());
  const fs::path frames = fs::path(dir) / "frames.csv";
  if (fs::exists(frames)) {
    check_frames_csv(read_text_file(frames.string()), r, frames.string());
  } else if (!fs::exists(fs::path(dir) / "frames.csv.gz")) {
    fail("{}: missing: the report needs the frames of every run (results.json names {} run(s))", frames.string(),
         r.at("runs").size());
  }
}

}  // namespace

Runner add_run_command(CLI::App& app) {
  struct Options {
    std::string experiment, out;
    std::vector<std::string> sets, scene_path;
    int threads = 0, jobs = 1;
    double memory_limit_gb = 0.0;
    bool no_report = false, no_disk_cache = false;
    std::string shard;
    std::optional<ShardRun> shard_run;
    std::string dump_streams;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "run",
      "Run an experiment: every configuration of its sweep on every scene. Validates the whole sweep first\n"
      "(every problem at once), then writes DIR/results.json (context + one record per run), DIR/frames.csv\n"
      "(one row per displayed frame), DIR/images/ and DIR/report.md with plots. A configuration that fails\n"
      "is recorded with its error and the sweep goes on. Examples:\n"
      "  dhrbench run experiments/quick.json\n"
      "  dhrbench run experiments/paper.json --out out/paper --set run.frames=30 --threads 2\n"
      "  dhrbench run experiments/hybrid_vs_remote_720p.json --jobs 2");
  cmd->add_option("experiment", o->experiment, "Experiment file (JSON, version 1 or 2)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--out", o->out, "Output folder (default: out/<experiment name>)");
  cmd->add_option("--set", o->sets,
                  "Override a key of the experiment: key=value, dotted from the top (repeatable), "
                  "e.g. --set run.frames=10 --set 'scenes=[\"room\"]'");
  cmd->add_option("--scene-path", o->scene_path, "Folder to look for scene assets in (repeatable)");
  cmd->add_option("--threads", o->threads, "Threads (0 = all cores)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--jobs", o->jobs,
                  "Runs side by side (default 1), sharing the caches; each stage still uses every thread. The\n"
                  "results are the same bytes and figures at any number of jobs (wall times aside); records keep\n"
                  "the order of the runs. A run starts beside others only while the process stays within\n"
                  "--memory-limit")
      ->check(CLI::Range(1, 64));
  cmd->add_option("--memory-limit", o->memory_limit_gb,
                  "GB the process may hold before --jobs stops starting runs side by side (default: 75 % of "
                  "physical memory). A run estimates what it adds: its client's G-buffers and about 300 bytes per "
                  "pixel")
      ->check(CLI::PositiveNumber);
  cmd->add_flag("--no-disk-cache", o->no_disk_cache,
                "Keep traced buffers in memory only (default: also in $DHR_CACHE_DIR or cache/ under trace/, so that "
                "later runs never trace the same frame twice)");
  cmd->add_flag("--no-report", o->no_report, "Write results only (build the report later with 'dhrbench report DIR')");
  cmd->add_option("--dump-streams", o->dump_streams,
                  "Write each video pass's stream as DIR/<run id>/<pass>.h264|.hevc|.ivf (ffmpeg reads them)");
  cmd->add_option("--shard", o->shard,
                  "Run only shard K of N (K/N, e.g. 2/4) and write DIR/shard.json; no report. Runs sharing traces or\n"
                  "ground truths stay in one shard ('dhrbench validate EXPERIMENT --shards N' prints the plan);\n"
                  "'dhrbench merge OUT DIR...' joins the shards' folders into one result");
  auto run = [o]() -> int {
    std::unique_ptr<tbb::global_control> limit;
    if (o->threads > 0)
      limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, size_t(o->threads));
    const auto wall_start = Clock::now();
    Experiment e = load_experiment(o->experiment, o->sets);
    const std::string dir = o->out.empty() ? "out/" + e.name : o->out;
    make_output_dir((fs::path(dir) / "images").string(),
                    o->out.empty() ? "the output folder out/<experiment name>" : "--out");
    if (!o->shard.empty())
      o->shard_run = ShardRun::start(e, parse_shard(o->shard), dir, run_context(DHR_BUILD_TYPE).at("git_commit"));
    LoadedScenes loaded = validate_all(e, o->scene_path);
    fmt::print(stderr, "{}: {} runs ({} scenes); writing {}\n", e.name, e.runs.size(), loaded.scenes.size(), dir);

    nlohmann::json results;
    results["context"] = run_context(DHR_BUILD_TYPE);
    results["context"]["threads"] = o->threads;
    results["context"]["jobs"] = o->jobs;
    results["context"]["command"] = "dhrbench run " + o->experiment;
    for (const auto& s : o->sets)
      results["context"]["command"] = results["context"]["command"].get<std::string>() + " --set " + s;
    results["experiment"] = e.source;
    results["experiment_path"] = e.path;
    results["declared"] = declared_json();
    results["runs"] = nlohmann::json::array();
    const std::vector<std::string> pass_names = all_pass_names();
    std::ofstream csv(fs::path(dir) / "frames.csv");
    csv << frames_csv_header({"run", "scene", "label"}, pass_names);

    TraceCache cache;
    if (!o->no_disk_cache) cache.set_disk_dir((fs::path(default_cache_dir()) / "trace").string());
    // Every FLIP score the sweep will compute, so that the cache keeps a reference's features
    // only while a later score needs them (a reference one run scores is never kept).
    for (size_t i = 0; i < e.runs.size(); ++i)
      for (const std::string& key : CacheKeys::of(loaded.plans[i], loaded.keys.at(e.runs[i].scene)).flip_references())
        cache.expect_flip_reads(key, 1);
    Progress progress(e.runs.size());
    // One run: its record and its rows of frames.csv. A run that fails is recorded with its error.
    struct RunOutput {
      nlohmann::json record;
      std::string csv;
      bool failed = false;
    };
    auto run_one = [&](size_t i) {
      RunOutput out;
      nlohmann::json& record = out.record;
      std::ostringstream csv_rows;
      const RunSpec& spec = e.runs[i];
      record = {{"id", spec.id}, {"scene", spec.scene}, {"label", spec.label}, {"settings", spec.settings}};
      if (!spec.configuration.empty()) record["configuration"] = spec.configuration;
      if (!spec.family.empty()) record["family"] = spec.family;
      const auto run_start = Clock::now();
      try {
        RunPlan& plan = loaded.plans[i];  // planned by validate_all; these two settings plan nothing
        SimConfig& config = plan.config;
        config.keep_images = true;
        if (!o->dump_streams.empty()) config.dump_streams_dir = (fs::path(o->dump_streams) / spec.id).string();
        RunResult r = run_simulation(plan, loaded.keys.at(spec.scene), cache, registries(),
                                     [&](int f, int total) { progress.update(i, spec.label, f, total); });
        record["config"] = r.config;
        // Effective backend parameters (defaults filled in), one entry per backend setting of
        // core/config/run_config.cpp, under its key ("passes.ao.codec").
        record["backends"] = plan.backends;
        record["metrics"] = r.metrics();
        record["server_time_model"] =
            config.server_timing == SimConfig::ServerTiming::Fixed
                ? fmt::format("fixed {} ms per server frame (virtual)", config.server_fixed_ms)
                : std::string("measured wall time of the server's stages");
        for (const auto& f : r.frames)
          csv_rows << frames_csv_row({spec.id, csv_quote(spec.scene), csv_quote(spec.label)}, f, pass_names);
        // Images of the last scored frame (downscaled): what was shown, the local reference,
        // the ground truth when scored, and the error against the best reference available.
        if (!r.images.empty()) {
          const fs::path img_dir = fs::path(dir) / "images";
          const ImageRGB8& shown = r.images.back();
          const ImageRGB8& local = r.local_images.back();
          write_png((img_dir / (spec.id + "_shown.png")).string(), downscale(shown, 480));
          write_png((img_dir / (spec.id + "_local.png")).string(), downscale(local, 480));
          const ImageRGB8* truth = r.ground_truth_images.empty() ? nullptr : &r.ground_truth_images.back();
          if (truth) write_png((img_dir / (spec.id + "_truth.png")).string(), downscale(*truth, 480));
          const ImageRGB8& against = truth ? *truth : local;
          // The error as grey levels: |luma difference| 0..32 -> 0..255 (saturating); the report
          // colours every map with one fixed colour scale and its colour bar.
          const ImageF err = abs_luma_difference(against, shown);
          ImageRGB8 grey(err.width(), err.height());
          for (size_t p = 0; p < err.size(); ++p) {
            const uint8_t g = uint8_t(std::lround(std::min(err[p], 32.0f) * 255.0f / 32.0f));
            grey[p] = {g, g, g};
          }
          write_png((img_dir / (spec.id + "_error.png")).string(), downscale(grey, 480));
          // FLIP's error map against the same reference, on FLIP's colour map.
          write_png((img_dir / (spec.id + "_flip.png")).string(),
                    downscale(flip_colour_map(flip(against, shown).map), 480));
          record["images"] = {{"frame", r.kept_frame},
                              {"error_against", &against == &local ? "local reference" : "ground truth"},
                              {"error_scale", "|luma difference| 0..32 levels"}};
        }
      } catch (const std::exception& err) {
        record["error"] = err.what();
        out.failed = true;
        fmt::print(stderr, "\n{} ({} on {}) failed: {}\n", spec.id, spec.label, spec.scene, err.what());
      }
      record["wall_s"] = std::chrono::duration<double>(Clock::now() - run_start).count();
      out.csv = csv_rows.str();
      progress.run_done(i);
      return out;
    };
    // Records and rows go out in the order of the runs, whichever finishes first; results.json
    // is written after each, so that nothing is lost if a later run crashes the process.
    std::vector<std::optional<RunOutput>> outputs(e.runs.size());
    size_t written = 0;
    int failed = 0;
    auto write_ready = [&] {
      for (; written < outputs.size() && outputs[written]; ++written) {
        RunOutput& r = *outputs[written];
        failed += r.failed ? 1 : 0;
        csv << r.csv;
        csv.flush();
        results["runs"].push_back(std::move(r.record));
        std::ofstream(fs::path(dir) / "results.json") << results.dump(1) << '\n';
        outputs[written].reset();
      }
    };
    // --jobs: independent runs side by side, sharing the cache. A run starts beside others only
    // while this process's resident memory plus its estimate (run_memory_estimate) stays within
    // the limit; else it waits for one to finish.
    const double limit_bytes = o->memory_limit_gb > 0 ? o->memory_limit_gb * 1e9 : 0.75 * physical_memory_bytes();
    std::mutex mutex;
    std::condition_variable finished;
    size_t next = 0, running = 0;
    bool told_wait = false;
    std::exception_ptr error;
    auto worker = [&] {
      std::unique_lock lock(mutex);
      while (next < e.runs.size() && !error) {
        const double need = run_memory_estimate(e.runs[next].config);
        if (running > 0 && resident_bytes() + need > limit_bytes) {
          if (!told_wait)
            fmt::print(stderr,
                       "\n--jobs {}: {} waits: resident {:.1f} GB + {:.1f} GB for the run would pass "
                       "--memory-limit {:.1f} GB\n",
                       o->jobs, e.runs[next].id, resident_bytes() / 1e9, need / 1e9, limit_bytes / 1e9);
          told_wait = true;
          finished.wait(lock);
          continue;
        }
        const size_t i = next++;
        ++running;
        lock.unlock();
        std::optional<RunOutput> out;
        try {
          out = run_one(i);
        } catch (...) {
          lock.lock();
          if (!error) error = std::current_exception();
          --running;
          finished.notify_all();
          return;
        }
        lock.lock();
        --running;
        outputs[i] = std::move(out);
        try {
          write_ready();
        } catch (...) {
          if (!error) error = std::current_exception();
        }
        finished.notify_all();
      }
    };
    const int jobs = std::max(1, std::min(o->jobs, int(e.runs.size())));
    if (jobs == 1) {
      worker();
    } else {
      std::vector<std::thread> threads;
      for (int j = 0; j < jobs; ++j) threads.emplace_back(worker);
      for (std::thread& t : threads) t.join();
    }
    if (error) std::rethrow_exception(error);
    progress.finish();
    csv.close();
    results["wall_s"] = std::chrono::duration<double>(Clock::now() - wall_start).count();
    std::ofstream(fs::path(dir) / "results.json") << results.dump(1) << '\n';
    fmt::print(stderr, "{} runs done ({} failed) in {:.1f} s: {}/results.json\n", e.runs.size(), failed,
               results["wall_s"].get<double>(), dir);
    int rc = 0;
    if (o->shard_run) {
      o->shard_run->finish();
      return failed ? 4 : 0;
    }
    if (!o->no_report) {
      rc = write_report(dir);
      if (rc == 0) fmt::print(stderr, "report: {}/report.md\n", dir);
    }
    return failed ? 4 : rc;
  };
  return [o, run] {
    try {
      return run();
    } catch (const std::exception& err) {
      if (o->shard_run) o->shard_run->finish(err.what());  // the merge reports it with the shard's runs
      throw;
    }
  };
}

Runner add_validate_command(CLI::App& app) {
  struct Options {
    std::string experiment;
    std::vector<std::string> sets, scene_path;
    int shards = 0;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand("validate",
                                 "Check an experiment without running it: the file, every backend name and parameter, "
                                 "every scene and path. Prints every problem at once.");
  cmd->add_option("experiment", o->experiment, "Experiment file (JSON, version 1 or 2)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--set", o->sets, "Override a key (as for run)");
  cmd->add_option("--scene-path", o->scene_path, "Folder to look for scene assets in (repeatable)");
  cmd->add_option("--shards", o->shards, "Also print the plan of 'run --shard K/N' for N shards: each shard's runs")
      ->check(CLI::Range(1, 10000));
  return [o] {
    const Experiment e = load_experiment(o->experiment, o->sets);
    validate_all(e, o->scene_path);
    if (o->shards > 0) print_shard_plan(e, o->shards);
    int frames = 0;
    for (const auto& r : e.runs) frames += r.config.frames + r.config.warmup_frames;
    fmt::print("{}: valid: {} runs over {} scene(s), {} frames in all\n", o->experiment, e.runs.size(), e.scenes.size(),
               frames);
    if (!e.hints.empty()) {
      fmt::print(
          "hint: this is a version-1 file; version 2 writes the per-pass backends under \"passes\" "
          "(`dhrbench settings` lists every key):\n");
      for (const auto& h : e.hints) fmt::print("  {}\n", h);
    }
    for (const auto& r : e.runs) fmt::print("  {}  {:<22} {}\n", r.id, r.scene, r.label);
    return 0;
  };
}

Runner add_report_command(CLI::App& app) {
  auto dir = std::make_shared<std::string>();
  auto* cmd = app.add_subcommand(
      "report",
      "Rebuild DIR/report.md and its plots from DIR/results.json and DIR/frames.csv, "
      "without running anything again. A damaged results.json (not JSON, nested deeper than\n"
      "64 levels, a field of the wrong type) is reported naming the file and the field, with exit code 2.");
  cmd->add_option("dir", *dir, "A folder written by 'dhrbench run'")->required()->check(CLI::ExistingDirectory);
  return [dir] {
    try {
      check_results_folder(*dir);
    } catch (const Error& e) {
      // Exit 2 for damaged results, as report.py does for what it finds.
      std::fprintf(stderr, "dhrbench: error: %s\n", e.what());
      return 2;
    }
    const int rc = write_report(*dir);
    if (rc == 0) fmt::print("report: {}/report.md\n", *dir);
    return rc;
  };
}

}  // namespace dhr::cli
