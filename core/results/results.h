// What a run produces, and every figure written from it, declared once (docs/architecture.md,
// "Results" and "Adding a metric").
//
// Three tables name every figure dhrbench writes:
//   image_metrics()  scored per displayed frame against each reference (the local reference,
//                    the ground truth): SSIM, PSNR, ... One entry gives the frames.csv columns
//                    (ssim_local, psnr_ground_truth_db), the per-run aggregates in results.json
//                    (ssim_local_mean, ...) and live.json's quality record.
//   run_metrics()    per run, from the RunResult: bandwidth, frame rates, counts.
//   pass_metrics()   per pass of a run, from its PassTraffic: bytes per frame, losses.
// The frames.csv writers of `dhrbench run` and of live mode, RunResult's results.json record,
// `dhrbench metrics` and experiments/report.py (through results.json's "declared" record) all
// read these tables; a new metric is one function and one line in core/results/results.cpp.
#pragma once

#include "core/buffers/image.h"
#include "core/metrics/flip.h"
#include "core/metrics/temporal.h"
#include "core/pass/passes.h"
#include "core/plan/trace_plan.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <limits>
#include <map>
#include <string>
#include <vector>

namespace dhr {

// The references a displayed frame is scored against.
enum class Against { Local, GroundTruth };
const char* against_name(Against a);  // "local", "ground_truth"

// The image a frame is scored against, with what the metrics compute from it alone where the
// caller computed that once for many frames (the runner keeps a reference's FLIP features for
// the runs of a sweep that score against it); nullptr: computed here. The same values either way.
struct ScoreReference {
  const ImageRGB8& image;
  const FlipFeatures* flip = nullptr;
};

// One image metric, scored per displayed frame.
struct ImageMetric {
  std::string name;  // ssim, psnr
  std::string unit;  // "" or a suffix of every column and key: "db"
  std::string doc;   // how it is computed, one line
  bool higher_is_better = true;
  double (*score)(const ScoreReference& reference, const ImageRGB8& shown) = nullptr;
  // The value as averaged over frames (PSNR: identical frames count as 100 dB); nullptr: as is.
  double (*for_mean)(double) = nullptr;
  // Instead of `score`, a metric of the change since the previous scored frame (the reference and
  // the shown frame at both), read from that frame step's temporal_scores (core/metrics/temporal.h,
  // computed once per step for every such metric): scored against the local reference only, NaN
  // (no value) on a run's first scored frame and against the ground truth.
  double (*score_step)(const TemporalScores& step) = nullptr;

  std::string column(Against a) const;                                   // ssim_local, psnr_ground_truth_db
  std::string aggregate(Against a, const std::string& statistic) const;  // ssim_local_mean, psnr_local_mean_db
};
const std::vector<ImageMetric>& image_metrics();

// One value per image_metrics() entry, in its order; the step metrics need the previous scored
// frame's reference and shown image (nullptr: NaN, no value).
std::vector<double> score_frame(const ImageRGB8& reference, const ImageRGB8& shown,
                                const ImageRGB8* reference_prev = nullptr, const ImageRGB8* shown_prev = nullptr);
std::vector<double> score_frame(const ScoreReference& reference, const ImageRGB8& shown,
                                const ImageRGB8* reference_prev = nullptr, const ImageRGB8* shown_prev = nullptr);

// One pass of one displayed frame.
struct PassFrameRecord {
  std::string pass;       // the pass's name (visibility, ao; remote: colour)
  int source_frame = -1;  // the client frame whose server buffer was displayed (-1: none)
  double age_ms = 0.0;    // its age at composite (virtual)
  uint64_t disoccluded = 0;
  // age_ms as the stages the displayed buffer went through (their sum; NaN: not known): the
  // camera's way up, its wait for the busy server, the server's time, the way down (queue,
  // transmission, propagation, and the wait for the packets FEC rebuilds from), and the wait
  // from its completion at the client to this display.
  double uplink_ms = std::numeric_limits<double>::quiet_NaN();
  double server_wait_ms = std::numeric_limits<double>::quiet_NaN();
  double server_ms = std::numeric_limits<double>::quiet_NaN();
  double downlink_ms = std::numeric_limits<double>::quiet_NaN();
  double display_wait_ms = std::numeric_limits<double>::quiet_NaN();
};

// Per displayed frame (virtual times in ms).
struct FrameRecord {
  int frame = 0;
  double t_ms = 0.0;
  bool scored = false, scored_ground_truth = false;
  // One value per image_metrics() entry when scored against that reference, else empty (NaN: the
  // metric has no value on this frame, e.g. a step metric on the first scored frame).
  std::vector<double> local, ground_truth;
  std::vector<PassFrameRecord> passes;  // in the order of the run's pass list
  double client_wall_ms = 0.0;          // rasterize + decode + predict + composite

  // The score of the image metric named `metric` (dhr::Error if there is no such metric or the
  // frame was not scored against `against`).
  double score(const std::string& metric, Against against = Against::Local) const;
  // The record of the pass named `name`; an absent pass reads as nothing received.
  PassFrameRecord pass(const std::string& name) const {
    for (const auto& p : passes)
      if (p.pass == name) return p;
    return {name};
  }
};

struct StageStats {
  std::vector<double> samples_ms;
  double median() const;
  double p95() const;
  double total() const;
};

struct PassTraffic {
  std::string pass;  // visibility | ao | colour
  uint64_t server_frames = 0;
  uint64_t encoded_bytes = 0;  // codec output
  uint64_t wire_bytes = 0;     // packets incl. dhrbench header + 28 IP/UDP
  uint64_t packets = 0;
  uint64_t frames_completed = 0;  // assembled and handed to the decoder
  uint64_t frames_lost = 0;       // server frames with a datagram dropped on the link, not rebuilt
  uint64_t frames_recovered = 0;  // server frames with datagrams dropped that FEC rebuilds
  uint64_t frames_given_up = 0;   // partial frames the receiver's assembler gave up
  uint64_t decode_errors = 0, keyframe_requests = 0;
  uint64_t frames_without_data = 0;  // displayed frames that showed this pass's local fallback
  double bytes_per_frame() const { return server_frames ? double(encoded_bytes) / double(server_frames) : 0.0; }
};

// One pass of one server frame as sent (the packet layer's accounting).
struct ServerPassRecord {
  int frame = 0;     // the client frame whose camera it was traced for
  std::string pass;  // visibility | ao | colour
  uint64_t encoded_bytes = 0;
  uint64_t packets = 0;
  uint64_t wire_bytes = 0;  // packets incl. dhrbench header + 28 IP/UDP
};

struct RunResult {
  nlohmann::json config;  // SimConfig::to_json with backends' effective parameters
  PassPlan plan;
  std::vector<FrameRecord> frames;
  std::vector<PassTraffic> traffic;
  std::vector<ServerPassRecord> server_log;  // every pass sent for a scored frame, in order
  std::map<std::string, StageStats> stages;  // wall time per stage
  StageStats server_frames_wall;             // per server frame: the wall time of all its stages
  uint64_t server_frames = 0, cameras_dropped = 0, cameras_lost = 0;
  uint64_t frames_without_data = 0;    // displayed frames with at least one pass shown with its local fallback
  uint64_t receiver_packets_lost = 0;  // found by the receiver from sequence-number gaps
  TraceStats trace_stats;              // rays of the server frames
  // abr: the budget updates, the client reports dropped (forged, repeated or of unknown
  // frames) and the lowest budget the controller set for a scored frame (NaN: abr off).
  uint64_t abr_updates = 0, abr_reports_dropped = 0;
  double abr_kbps_lowest = std::numeric_limits<double>::quiet_NaN();
  double duration_ms = 0.0;  // virtual time of the scored frames
  // keep_images: the displayed image, local reference and ground truth of one frame (the last
  // scored against the ground truth, or the last scored when there is no ground truth).
  std::vector<ImageRGB8> images, local_images, ground_truth_images;
  int kept_frame = -1;

  nlohmann::json metrics() const;  // the per-run record written to results.json: every declared metric
};

// A per-run figure: its key in results.json's "metrics", unit, meaning, and whether it is
// measured on the wall clock (it then varies run to run; the refactoring guard skips it).
struct RunMetric {
  std::string key, unit, doc;
  bool wall_clock = false;
  nlohmann::json (*value)(const RunResult&) = nullptr;
  // The value is an object per pass name, written as one key per pass: KEY_PASS.
  bool one_key_per_pass = false;
};
const std::vector<RunMetric>& run_metrics();

// A per-pass figure, in results.json's "metrics.passes[]" records.
struct PassMetric {
  std::string key, unit, doc;
  nlohmann::json (*value)(const PassTraffic&, double seconds) = nullptr;
};
const std::vector<PassMetric>& pass_metrics();

// A statistic of an image metric over a run's scored frames (of the for_mean values), written
// as METRIC_REFERENCE_NAME[_UNIT] (ssim_local_mean, psnr_ground_truth_worst_db); null when no
// frame was scored against that reference.
struct ImageStatistic {
  std::string name, doc;
  double (*of)(std::vector<double> values, bool higher_is_better) = nullptr;  // values not empty
};
const std::vector<ImageStatistic>& image_statistics();
// Student's t quantile for a two-sided 95 % interval with `dof` degrees of freedom (>= 1).
double student_t95(int dof);

// Every declaration as JSON (written into results.json as "declared", printed by
// `dhrbench metrics --json`; experiments/report.py and scripts/check_figures.py read it).
nlohmann::json declared_json();

// frames.csv, one writer for `dhrbench run` and live mode. Columns: `leading` (the caller's,
// e.g. run,scene,label), frame, t_ms, scored, the image metrics against the local reference,
// scored_ground_truth, the image metrics against the ground truth, then per pass in `passes`
// PASS_source_frame, PASS_age_ms, PASS_disoccluded (empty where a run has no such pass), and
// client_wall_ms (wall clock).
std::string frames_csv_header(const std::vector<std::string>& leading, const std::vector<std::string>& passes);
std::string frames_csv_row(const std::vector<std::string>& leading, const FrameRecord& f,
                           const std::vector<std::string>& passes);
// Columns measured on the wall clock (the refactoring guard skips them).
const std::vector<std::string>& frames_csv_wall_clock_columns();
// RFC 4180 quoting, and numbers as every CSV writes them (6 significant digits, "inf", "" for NaN).
std::string csv_quote(const std::string& s);
std::string csv_number(double v);

}  // namespace dhr
