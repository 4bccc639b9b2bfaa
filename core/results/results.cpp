#include "core/results/results.h"

#include "core/base/error.h"
#include "core/metrics/flip.h"
#include "core/metrics/metrics.h"
#include "core/metrics/temporal.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>

namespace dhr {

namespace {

nlohmann::json finite_or_null(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

double ssim_of(const ScoreReference& reference, const ImageRGB8& shown) {
  return ssim_u8(luma(reference.image), luma(shown), nullptr, SsimBorder::Valid);
}
double psnr_of(const ScoreReference& reference, const ImageRGB8& shown) { return psnr_db(reference.image, shown); }
double flip_of(const ScoreReference& reference, const ImageRGB8& shown) {
  if (reference.flip && reference.flip->ppd == kFlipDefaultPpd) return flip(*reference.flip, shown).mean;
  return flip(reference.image, shown, kFlipDefaultPpd).mean;
}
double temporal_error_of(const TemporalScores& s) { return s.temporal_error; }
double static_flicker_of(const TemporalScores& s) { return s.static_pixels > 0 ? s.static_flicker : std::nan(""); }

// Metric i of the frames scored against `against`, in frame order, for_mean applied.
std::vector<double> scores_of(const RunResult& r, size_t i, Against against) {
  const ImageMetric& m = image_metrics()[i];
  std::vector<double> v;
  for (const FrameRecord& f : r.frames) {
    const std::vector<double>& s = against == Against::Local ? f.local : f.ground_truth;
    if (s.size() > i && !std::isnan(s[i])) v.push_back(m.for_mean ? m.for_mean(s[i]) : s[i]);
  }
  return v;
}

double mean_of(const std::vector<double>& v) {
  double sum = 0;
  for (double x : v) sum += x;
  return sum / double(v.size());
}

// The values sorted from the worst to the best frame.
std::vector<double> worst_first(std::vector<double> v, bool higher_is_better) {
  if (higher_is_better)
    std::sort(v.begin(), v.end());
  else
    std::sort(v.begin(), v.end(), std::greater<>());
  return v;
}

double per_second(double count, double seconds) { return seconds > 0 ? count / seconds : 0.0; }
double seconds_of(const RunResult& r) { return r.duration_ms / 1000.0; }
uint64_t wire_bytes(const RunResult& r) {
  uint64_t wire = 0;
  for (const auto& t : r.traffic) wire += t.wire_bytes;
  return wire;
}
StageStats client_frames(const RunResult& r) {
  StageStats client;
  for (const auto& f : r.frames) client.samples_ms.push_back(f.client_wall_ms);
  return client;
}

// Stalls (RunMetric stalls, stall_ms_*, frames_frozen): a pass stalls when the server frame it
// shows stays the same for more than stall_after_frames display intervals, or it shows none. A
// stall's frames are the displayed frames that showed no new frame of that pass; frozen are those
// past the threshold. Episodes are runs of displayed frames in which some pass stalls.
struct Stalls {
  uint64_t episodes = 0, frozen = 0;
  double total_ms = 0.0, longest_ms = 0.0;
};
Stalls stalls_of(const RunResult& r) {
  Stalls out;
  const bool set = r.config.is_object();  // a RunResult made in a test may have no config
  const double hz = set ? r.config.value("display_hz", 60.0) : 60.0;
  const long after = set ? r.config.value("stall_after_frames", 3) : 3;
  const long n = long(r.frames.size());
  std::vector<bool> stalled(size_t(n), false), frozen(size_t(n), false);
  std::map<std::string, std::vector<int>> shown;  // per pass: its source frame per displayed frame
  for (long k = 0; k < n; ++k)
    for (const auto& p : r.frames[size_t(k)].passes) {
      auto& v = shown[p.pass];
      v.resize(size_t(n), -1);
      v[size_t(k)] = p.source_frame;
    }
  for (const auto& [pass, src] : shown) {
    long last = -1;                    // the displayed frame where this pass last showed a new server frame
    auto close_gap = [&](long next) {  // the frames after `last` up to `next`, exclusive
      if (last < 0 || next - last <= after) return;
      for (long j = last + 1; j < next; ++j) {
        stalled[size_t(j)] = true;
        if (j - last > after) frozen[size_t(j)] = true;
      }
    };
    for (long k = 0; k < n; ++k) {
      if (src[size_t(k)] < 0) {  // nothing to show yet, or the pass was reset
        stalled[size_t(k)] = frozen[size_t(k)] = true;
        continue;
      }
      if (k > 0 && src[size_t(k)] == src[size_t(k - 1)]) continue;
      close_gap(k);
      last = k;
    }
    close_gap(n);
  }
  for (long k = 0, run = 0; k <= n; ++k) {
    if (k < n && stalled[size_t(k)]) {
      ++run;
      continue;
    }
    if (run > 0) {
      ++out.episodes;
      const double ms = double(run) * 1000.0 / hz;
      out.total_ms += ms;
      out.longest_ms = std::max(out.longest_ms, ms);
    }
    run = 0;
  }
  out.frozen = uint64_t(std::count(frozen.begin(), frozen.end(), true));
  return out;
}

}  // namespace

const char* against_name(Against a) { return a == Against::Local ? "local" : "ground_truth"; }

std::string ImageMetric::column(Against a) const {
  return unit.empty() ? fmt::format("{}_{}", name, against_name(a))
                      : fmt::format("{}_{}_{}", name, against_name(a), unit);
}

std::string ImageMetric::aggregate(Against a, const std::string& statistic) const {
  return unit.empty() ? fmt::format("{}_{}_{}", name, against_name(a), statistic)
                      : fmt::format("{}_{}_{}_{}", name, against_name(a), statistic, unit);
}

// ---- the image metrics ----------------------------------------------------------------------

const std::vector<ImageMetric>& image_metrics() {
  static const std::vector<ImageMetric> metrics = {
      {"ssim", "",
       "SSIM (Wang et al. 2004; Gaussian 11x11, sigma 1.5, K1 0.01, K2 0.03, L 255) on BT.601 luma, mean over the "
       "valid interior as Wang's code and scikit-image (docs/metrics.md)",
       true, ssim_of, nullptr},
      {"psnr", "db",
       "PSNR over R, G and B, 10 log10(255^2 / MSE); identical frames are +inf, counted as 100 dB in means", true,
       psnr_of, psnr_for_mean},
      {"flip", "",
       "LDR-FLIP (Andersson et al. 2020) at 67 pixels per degree, mean of the error map, 0..1 (docs/metrics.md)", false,
       flip_of, nullptr},
      {"temporal_error", "levels",
       "mean |(shown_k - shown_j) - (ref_k - ref_j)| in luma levels, j the previous scored frame: error of the change "
       "between frames (docs/metrics.md, Temporal stability)",
       false, nullptr, nullptr, temporal_error_of},
      {"static_flicker", "levels",
       "mean |shown_k - shown_j| in luma levels over the pixels whose reference did not change, j the previous scored "
       "frame (docs/metrics.md); no value when no pixel is static",
       false, nullptr, nullptr, static_flicker_of},
  };
  return metrics;
}

std::vector<double> score_frame(const ImageRGB8& reference, const ImageRGB8& shown, const ImageRGB8* reference_prev,
                                const ImageRGB8* shown_prev) {
  return score_frame(ScoreReference{reference}, shown, reference_prev, shown_prev);
}

std::vector<double> score_frame(const ScoreReference& reference, const ImageRGB8& shown,
                                const ImageRGB8* reference_prev, const ImageRGB8* shown_prev) {
  const ImageRGB8& ref = reference.image;
  if (ref.width() != shown.width() || ref.height() != shown.height() || ref.empty())
    fail("score_frame: images of {}x{} and {}x{} (they must be the same size, not empty)", ref.width(), ref.height(),
         shown.width(), shown.height());
  std::vector<double> s;
  std::optional<TemporalScores> step;  // computed once for every metric of the step
  for (const ImageMetric& m : image_metrics()) {
    if (m.score) {
      s.push_back(m.score(reference, shown));
    } else if (reference_prev && shown_prev) {
      if (!step) step = temporal_scores(*reference_prev, ref, *shown_prev, shown);
      s.push_back(m.score_step(*step));
    } else {
      s.push_back(std::nan(""));
    }
  }
  return s;
}

double student_t95(int dof) {
  // Two-sided 95 % (the 0.975 quantile), dof 1..30; above 30 the normal value's neighbourhood.
  static const double t[] = {12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
                             2.201,  2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
                             2.080,  2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042};
  if (dof < 1) fail("student_t95: {} degrees of freedom (at least 1)", dof);
  if (dof <= 30) return t[dof - 1];
  if (dof <= 60) return 2.000;
  if (dof <= 120) return 1.980;
  return 1.960;
}

const std::vector<ImageStatistic>& image_statistics() {
  static const std::vector<ImageStatistic> stats = {
      {"mean", "mean over the scored frames", [](std::vector<double> v, bool) { return mean_of(v); }},
      {"ci95",
       "half-width of the 95 % confidence interval of the mean, Student's t over the scored frames taken as "
       "independent "
       "(consecutive frames are correlated, so the true interval is wider); 0 with one frame",
       [](std::vector<double> v, bool) {
         if (v.size() < 2) return 0.0;
         const double m = mean_of(v);
         double ss = 0;
         for (double x : v) ss += (x - m) * (x - m);
         const double sd = std::sqrt(ss / double(v.size() - 1));
         return student_t95(int(v.size()) - 1) * sd / std::sqrt(double(v.size()));
       }},
      {"worst_5pct",
       "the value 5 % of the scored frames are worse than or equal to (nearest rank, by the metric's direction)",
       [](std::vector<double> v, bool higher) {
         const std::vector<double> w = worst_first(std::move(v), higher);
         return w[size_t(std::max(1.0, std::ceil(0.05 * double(w.size())))) - 1];
       }},
      {"worst", "the worst scored frame",
       [](std::vector<double> v, bool higher) { return worst_first(std::move(v), higher)[0]; }},
  };
  return stats;
}

double FrameRecord::score(const std::string& metric, Against against) const {
  const std::vector<double>& s = against == Against::Local ? local : ground_truth;
  const auto& m = image_metrics();
  for (size_t i = 0; i < m.size(); ++i)
    if (m[i].name == metric) {
      if (i >= s.size()) fail("frame {} was not scored against the {} reference", frame, against_name(against));
      return s[i];
    }
  fail("no image metric named '{}' (core/results/results.cpp, image_metrics)", metric);
}

// ---- stage statistics -----------------------------------------------------------------------

double StageStats::median() const {
  if (samples_ms.empty()) return 0.0;
  std::vector<double> s = samples_ms;
  std::nth_element(s.begin(), s.begin() + std::ptrdiff_t(s.size() / 2), s.end());
  return s[s.size() / 2];
}

double StageStats::p95() const {
  if (samples_ms.empty()) return 0.0;
  std::vector<double> s = samples_ms;
  std::sort(s.begin(), s.end());
  return s[std::min(s.size() - 1, size_t(std::ceil(0.95 * double(s.size()))) - 1)];
}

double StageStats::total() const {
  double t = 0;
  for (double v : samples_ms) t += v;
  return t;
}

// ---- the per-pass and per-run metrics -------------------------------------------------------

const std::vector<PassMetric>& pass_metrics() {
  using T = const PassTraffic&;
  static const std::vector<PassMetric> metrics = {
      {"server_frames", "frames", "server frames that sent this pass",
       [](T t, double) -> nlohmann::json { return t.server_frames; }},
      {"bytes_per_frame", "bytes", "encoded bytes per server frame (codec output)",
       [](T t, double) -> nlohmann::json { return t.bytes_per_frame(); }},
      {"encoded_bytes", "bytes", "codec output, all server frames",
       [](T t, double) -> nlohmann::json { return t.encoded_bytes; }},
      {"wire_bytes", "bytes", "packets on the wire: payload, the dhrbench header and 28 bytes of IP/UDP each",
       [](T t, double) -> nlohmann::json { return t.wire_bytes; }},
      {"packets", "packets", "datagrams sent", [](T t, double) -> nlohmann::json { return t.packets; }},
      {"bandwidth_mbps", "Mb/s", "wire_bytes over the scored frames' virtual time",
       [](T t, double s) -> nlohmann::json { return per_second(double(t.wire_bytes) * 8 / 1e6, s); }},
      {"frames_completed", "frames", "frames assembled and handed to the decoder",
       [](T t, double) -> nlohmann::json { return t.frames_completed; }},
      {"delivered_fps", "frames/s", "frames_completed over the scored frames' virtual time",
       [](T t, double s) -> nlohmann::json { return per_second(double(t.frames_completed), s); }},
      {"frames_lost", "frames", "server frames with a datagram dropped on the link (and not rebuilt by FEC)",
       [](T t, double) -> nlohmann::json { return t.frames_lost; }},
      {"frames_recovered", "frames", "server frames with datagrams dropped on the link that FEC parity rebuilds",
       [](T t, double) -> nlohmann::json { return t.frames_recovered; }},
      {"frames_given_up_by_receiver", "frames", "partial frames the receiver's assembler gave up",
       [](T t, double) -> nlohmann::json { return t.frames_given_up; }},
      {"decode_errors", "frames", "frames the decoder refused",
       [](T t, double) -> nlohmann::json { return t.decode_errors; }},
      {"keyframe_requests", "requests", "keyframes the client asked for after a loss",
       [](T t, double) -> nlohmann::json { return t.keyframe_requests; }},
      {"frames_without_data", "frames", "displayed frames that showed this pass's local fallback",
       [](T t, double) -> nlohmann::json { return t.frames_without_data; }},
  };
  return metrics;
}

const std::vector<RunMetric>& run_metrics() {
  using R = const RunResult&;
  static const std::vector<RunMetric> metrics = {
      {"psnr_note", "", "how PSNR is averaged", false,
       [](R) -> nlohmann::json { return "PSNR of identical frames is counted as 100 dB in the means"; }},
      {"passes", "", "one record per pass sent (pass_metrics)", false,
       [](R r) -> nlohmann::json {
         nlohmann::json passes = nlohmann::json::array();
         for (const PassTraffic& t : r.traffic) {
           nlohmann::json p = {{"pass", t.pass}};
           for (const PassMetric& m : pass_metrics()) p[m.key] = m.value(t, seconds_of(r));
           passes.push_back(std::move(p));
         }
         return passes;
       }},
      {"frames_displayed", "frames", "displayed frames after the warm-up (the rows of frames.csv)", false,
       [](R r) -> nlohmann::json { return r.frames.size(); }},
      {"frames_scored", "frames", "displayed frames scored against the local reference", false,
       [](R r) -> nlohmann::json {
         return std::count_if(r.frames.begin(), r.frames.end(), [](const FrameRecord& f) { return f.scored; });
       }},
      {"frames_scored_ground_truth", "frames", "displayed frames scored against the ground truth", false,
       [](R r) -> nlohmann::json {
         return std::count_if(r.frames.begin(), r.frames.end(),
                              [](const FrameRecord& f) { return f.scored_ground_truth; });
       }},
      {"bandwidth_mbps", "Mb/s", "every pass's packets on the wire over the scored frames' virtual time", false,
       [](R r) -> nlohmann::json { return per_second(double(wire_bytes(r)) * 8 / 1e6, seconds_of(r)); }},
      {"server_fps_virtual", "frames/s", "server frames over the scored frames' virtual time (the server time model)",
       false, [](R r) -> nlohmann::json { return per_second(double(r.server_frames), seconds_of(r)); }},
      {"server_frames", "frames", "frames the server traced and sent", false,
       [](R r) -> nlohmann::json { return r.server_frames; }},
      {"cameras_dropped", "cameras", "cameras the busy server skipped for a newer one", false,
       [](R r) -> nlohmann::json { return r.cameras_dropped; }},
      {"cameras_lost", "cameras", "camera messages lost on the uplink", false,
       [](R r) -> nlohmann::json { return r.cameras_lost; }},
      {"abr_updates", "updates", "abr: the times the controller changed the stream budget", false,
       [](R r) -> nlohmann::json { return r.abr_updates; }},
      {"abr_reports_dropped", "reports",
       "abr: client frame reports dropped (of frames never sent or already reported, or with an impossible delay)",
       false, [](R r) -> nlohmann::json { return r.abr_reports_dropped; }},
      {"abr_kbps_lowest", "kbit/s",
       "abr: the lowest stream budget the controller set for a scored frame (null: abr off)", false,
       [](R r) -> nlohmann::json {
         return std::isnan(r.abr_kbps_lowest) ? nlohmann::json() : nlohmann::json(r.abr_kbps_lowest);
       }},
      {"frames_without_data", "frames", "displayed frames with at least one pass shown with its local fallback", false,
       [](R r) -> nlohmann::json { return r.frames_without_data; }},
      {"receiver_packets_lost", "packets", "found by the receiver from sequence-number gaps", false,
       [](R r) -> nlohmann::json { return r.receiver_packets_lost; }},
      {"stalls", "stalls",
       "episodes in which some pass showed no new server frame for more than stall_after_frames display intervals "
       "(a loss, a late frame, a capacity drop)",
       false, [](R r) -> nlohmann::json { return stalls_of(r).episodes; }},
      {"stall_ms_total", "ms",
       "the stalls' time on the display: the display intervals that showed no new frame of a "
       "stalled pass",
       false, [](R r) -> nlohmann::json { return stalls_of(r).total_ms; }},
      {"stall_ms_longest", "ms", "the longest stall (the recovery time after the worst loss burst)", false,
       [](R r) -> nlohmann::json { return stalls_of(r).longest_ms; }},
      {"frames_frozen", "frames", "displayed frames past a stall's threshold, or with a pass that has no data", false,
       [](R r) -> nlohmann::json { return stalls_of(r).frozen; }},
      {"client_frame_ms_median", "ms", "client stages per displayed frame, median (wall clock)", true,
       [](R r) -> nlohmann::json { return client_frames(r).median(); }},
      {"client_frame_ms_p95", "ms", "client stages per displayed frame, 95th percentile (wall clock)", true,
       [](R r) -> nlohmann::json { return client_frames(r).p95(); }},
      {"client_fps_wall", "frames/s", "1000 / client_frame_ms_median (wall clock)", true,
       [](R r) -> nlohmann::json {
         const double m = client_frames(r).median();
         return m > 0 ? 1000.0 / m : 0.0;
       }},
      {"server_frame_ms_median", "ms",
       "the server's stages per server frame (rasterize, trace, denoise, [composite,] encode, packetize), median "
       "(wall clock)",
       true, [](R r) -> nlohmann::json { return r.server_frames_wall.median(); }},
      {"server_fps_wall", "frames/s",
       "server frames per second this machine sustains: 1000 / the mean of the server's per-frame wall time (beside "
       "server_fps_virtual, which follows the server time model)",
       true,
       [](R r) -> nlohmann::json {
         const auto& v = r.server_frames_wall.samples_ms;
         return v.empty() || r.server_frames_wall.total() <= 0
                    ? 0.0
                    : 1000.0 * double(v.size()) / r.server_frames_wall.total();
       }},
      {"client_fps_wall_mean", "frames/s",
       "displayed frames per second this machine sustains: 1000 / the mean client frame (every client stage, decode "
       "included on the frames that decode)",
       true,
       [](R r) -> nlohmann::json {
         const StageStats c = client_frames(r);
         return c.total() > 0 ? 1000.0 * double(c.samples_ms.size()) / c.total() : 0.0;
       }},
      {"buffer_age_ms", "ms", "per pass: age of the displayed buffer at composite, median and p95 (virtual)", false,
       [](R r) -> nlohmann::json {
         std::map<std::string, StageStats> ages;  // per pass name
         for (const auto& f : r.frames)
           for (const auto& p : f.passes)
             if (p.source_frame >= 0) ages[p.pass].samples_ms.push_back(p.age_ms);
         nlohmann::json out = nlohmann::json::object();
         for (const auto& [pass, age] : ages) out[pass] = {{"median", age.median()}, {"p95", age.p95()}};
         return out;
       },
       true},
      {"latency_breakdown_ms", "ms",
       "per pass: the displayed buffer's age (motion to photon, virtual) as its stages, each the median over the "
       "displayed frames: uplink, server_wait (for the busy server), server, downlink (queue, transmission, "
       "propagation, FEC), display_wait (from completion at the client to the display)",
       false,
       [](R r) -> nlohmann::json {
         std::map<std::string, std::array<StageStats, 5>> parts;  // per pass name
         for (const auto& f : r.frames)
           for (const auto& p : f.passes) {
             if (p.source_frame < 0 || std::isnan(p.uplink_ms)) continue;
             auto& a = parts[p.pass];
             const double v[5] = {p.uplink_ms, p.server_wait_ms, p.server_ms, p.downlink_ms, p.display_wait_ms};
             for (size_t k = 0; k < 5; ++k) a[k].samples_ms.push_back(v[k]);
           }
         nlohmann::json out = nlohmann::json::object();
         for (const auto& [pass, a] : parts)
           out[pass] = {{"uplink", a[0].median()},
                        {"server_wait", a[1].median()},
                        {"server", a[2].median()},
                        {"downlink", a[3].median()},
                        {"display_wait", a[4].median()}};
         return out;
       },
       true},
      {"stages_wall", "ms", "per stage: median, p95 and count of its wall time", true,
       [](R r) -> nlohmann::json {
         nlohmann::json st = nlohmann::json::object();
         for (const auto& [name, s] : r.stages)
           st[name] = {{"median_ms", s.median()}, {"p95_ms", s.p95()}, {"count", s.samples_ms.size()}};
         return st;
       }},
      {"rays", "rays", "rays traced for the server frames: shadow, ao, invalid", false,
       [](R r) -> nlohmann::json {
         return {{"shadow", r.trace_stats.shadow_rays},
                 {"ao", r.trace_stats.ao_rays},
                 {"invalid", r.trace_stats.invalid_rays}};
       }},
      {"passes_planned", "", "the run's pass plan (core/pass/passes.h)", false,
       [](R r) -> nlohmann::json { return r.plan.describe(); }},
  };
  return metrics;
}

nlohmann::json RunResult::metrics() const {
  nlohmann::json m = nlohmann::json::object();
  const auto& images = image_metrics();
  for (size_t i = 0; i < images.size(); ++i)
    for (Against a : {Against::Local, Against::GroundTruth}) {
      const std::vector<double> v = scores_of(*this, i, a);
      for (const ImageStatistic& st : image_statistics())
        m[images[i].aggregate(a, st.name)] =
            v.empty() ? nlohmann::json(nullptr) : finite_or_null(st.of(v, images[i].higher_is_better));
    }
  for (const RunMetric& rm : run_metrics()) {
    nlohmann::json v = rm.value(*this);
    if (!rm.one_key_per_pass) {
      m[rm.key] = std::move(v);
      continue;
    }
    for (auto it = v.begin(); it != v.end(); ++it) m[fmt::format("{}_{}", rm.key, it.key())] = it.value();
  }
  return m;
}

nlohmann::json declared_json() {
  nlohmann::json images = nlohmann::json::array();
  for (const ImageMetric& m : image_metrics()) {
    nlohmann::json columns, aggregates = nlohmann::json::object();
    for (Against a : {Against::Local, Against::GroundTruth}) {
      columns[against_name(a)] = m.column(a);
      for (const ImageStatistic& st : image_statistics())
        aggregates[against_name(a)][st.name] = m.aggregate(a, st.name);
    }
    images.push_back({{"name", m.name},
                      {"unit", m.unit},
                      {"doc", m.doc},
                      {"higher_is_better", m.higher_is_better},
                      {"columns", columns},
                      {"aggregates", aggregates}});
  }
  nlohmann::json statistics = nlohmann::json::array();
  for (const ImageStatistic& st : image_statistics()) statistics.push_back({{"name", st.name}, {"doc", st.doc}});
  nlohmann::json runs = nlohmann::json::array(), passes = nlohmann::json::array();
  for (const RunMetric& m : run_metrics())
    runs.push_back({{"key", m.one_key_per_pass ? m.key + "_PASS" : m.key},
                    {"unit", m.unit},
                    {"doc", m.doc},
                    {"wall_clock", m.wall_clock}});
  for (const PassMetric& m : pass_metrics()) passes.push_back({{"key", m.key}, {"unit", m.unit}, {"doc", m.doc}});
  return {{"image_metrics", images},
          {"image_statistics", statistics},
          {"run_metrics", runs},
          {"pass_metrics", passes},
          {"frames_csv_wall_clock_columns", frames_csv_wall_clock_columns()}};
}

// ---- frames.csv -----------------------------------------------------------------------------

std::string csv_quote(const std::string& s) {
  std::string out = "\"";
  for (char ch : s) out += ch == '"' ? std::string("\"\"") : std::string(1, ch);
  return out + "\"";
}

std::string csv_number(double v) { return std::isfinite(v) ? fmt::format("{:.6g}", v) : (v > 0 ? "inf" : ""); }

const std::vector<std::string>& frames_csv_wall_clock_columns() {
  static const std::vector<std::string> columns = {"client_wall_ms"};
  return columns;
}

std::string frames_csv_header(const std::vector<std::string>& leading, const std::vector<std::string>& passes) {
  std::vector<std::string> cols = leading;
  cols.insert(cols.end(), {"frame", "t_ms", "scored"});
  for (const ImageMetric& m : image_metrics()) cols.push_back(m.column(Against::Local));
  cols.push_back("scored_ground_truth");
  for (const ImageMetric& m : image_metrics()) cols.push_back(m.column(Against::GroundTruth));
  for (const std::string& p : passes)
    for (const char* c : {"source_frame", "age_ms", "disoccluded", "uplink_ms", "server_wait_ms", "server_ms",
                          "downlink_ms", "display_wait_ms"})
      cols.push_back(fmt::format("{}_{}", p, c));
  cols.push_back("client_wall_ms");
  return fmt::format("{}\n", fmt::join(cols, ","));
}

std::string frames_csv_row(const std::vector<std::string>& leading, const FrameRecord& f,
                           const std::vector<std::string>& passes) {
  std::vector<std::string> cells = leading;
  cells.push_back(std::to_string(f.frame));
  cells.push_back(csv_number(f.t_ms));
  cells.push_back(f.scored ? "1" : "0");
  const size_t n = image_metrics().size();
  for (size_t i = 0; i < n; ++i) cells.push_back(i < f.local.size() ? csv_number(f.local[i]) : "");
  cells.push_back(f.scored_ground_truth ? "1" : "0");
  for (size_t i = 0; i < n; ++i) cells.push_back(i < f.ground_truth.size() ? csv_number(f.ground_truth[i]) : "");
  for (const std::string& name : passes) {
    const auto it =
        std::find_if(f.passes.begin(), f.passes.end(), [&](const PassFrameRecord& p) { return p.pass == name; });
    if (it == f.passes.end()) {
      cells.insert(cells.end(), 8, "");  // the run has no such pass
      continue;
    }
    cells.push_back(std::to_string(it->source_frame));
    cells.push_back(csv_number(it->age_ms));
    cells.push_back(std::to_string(it->disoccluded));
    for (double v : {it->uplink_ms, it->server_wait_ms, it->server_ms, it->downlink_ms, it->display_wait_ms})
      cells.push_back(std::isnan(v) ? "" : csv_number(v));
  }
  cells.push_back(csv_number(f.client_wall_ms));
  return fmt::format("{}\n", fmt::join(cells, ","));
}

}  // namespace dhr
