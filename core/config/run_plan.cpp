#include "core/config/run_plan.h"

#include "core/base/error.h"
#include "core/net/network.h"
#include "core/net/packet.h"
#include "core/pass/passes.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace dhr {

std::optional<RateControlSettings> RunPlan::abr_settings(const SimConfig& c) {
  if (c.abr == "off") return std::nullopt;
  RateControlSettings rs;
  rs.start_kbps = c.stream_kbps;
  rs.min_kbps = c.abr_min_kbps;
  rs.max_kbps = c.abr_max_kbps > 0.0 ? c.abr_max_kbps : c.stream_kbps;
  rs.target_queue_ms = c.abr_target_queue_ms;
  rs.interval_ms = c.abr_interval_ms;
  return rs;
}

bool RunPlan::server_does(ServerStage stage) const {
  return std::find(server_stages.begin(), server_stages.end(), stage) != server_stages.end();
}

bool RunPlan::client_does(ClientStage stage) const {
  return std::find(client_stages.begin(), client_stages.end(), stage) != client_stages.end();
}

nlohmann::json effective_backend(const RunSetting& s, const nlohmann::json& value, const Registries& r) {
  const std::string name = value.at("name").get<std::string>();
  Params p;
  if (s.kind == "codec")
    r.codecs.create(name, value.at("params"), &p);
  else if (s.kind == "denoiser")
    r.denoisers.create(name, value.at("params"), &p);
  else
    r.predictors.create(name, value.at("params"), &p);
  return {{"name", name}, {"params", p.effective()}};
}

std::string warmup_problem(const SimConfig& c) {
  // A datagram's latency when sent at virtual time t.
  auto latency_at = [](const LinkConfig& l, double t_ms) {
    switch (l.latency_model) {
      case LinkConfig::Latency::Constant: return l.latency_ms;
      case LinkConfig::Latency::Normal: return std::max(l.latency_floor_ms, l.latency_ms + 3.0 * l.jitter_ms);
      case LinkConfig::Latency::Trace: try { return load_latency_trace(l.trace_file).at(t_ms + l.trace_offset_ms);
        } catch (const Error&) {
          return 0.0;  // plan_run reports the trace
        }
    }
    return 0.0;
  };
  const double server_ms = c.server_timing == SimConfig::ServerTiming::Fixed ? c.server_fixed_ms : 0.0;
  const double up_ms = latency_at(c.uplink, 0.0);
  const double down_ms = latency_at(c.downlink, up_ms + server_ms);
  const double first_ms = up_ms + server_ms + down_ms;
  const double interval_ms = 1000.0 / c.display_hz;
  const double warmup_ms = c.warmup_frames * interval_ms;
  if (c.score_startup || warmup_ms + 1e-9 >= first_ms) return {};
  const int need = int(std::ceil(first_ms / interval_ms - 1e-9));
  return fmt::format(
      "warmup_frames {} ({:.1f} ms) ends before the first server frame can arrive ({:.1f} ms: uplink {:.1f} + "
      "server {:.1f} + downlink {:.1f} ms), so the first scored frames would show no server data; "
      "use warmup_frames >= {} (or score_startup true to measure the startup)",
      c.warmup_frames, warmup_ms, first_ms, up_ms, server_ms, down_ms, need);
}

RunPlan plan_run(const SimConfig& c, const Scene& scene, const Registries& r) {
  RunPlan run;
  run.config = c;
  run.scene = &scene;
  run.mode = c.mode == "remote" ? RunMode::Remote : RunMode::Hybrid;
  std::vector<std::string> problems;
  auto check = [&](bool ok, std::string what) {
    if (!ok) problems.push_back(std::move(what));
  };
  // Ranges and choices: the table of settings (core/config/run_config.cpp).
  for (std::string& p : setting_range_problems(c)) problems.push_back(std::move(p));
  check(c.max_payload_bytes + kPacketHeaderBytes + kIpUdpOverheadBytes <= size_t(c.downlink.mtu_bytes),
        fmt::format("max_payload_bytes {} + {} header + {} IP/UDP exceeds the downlink MTU {}", c.max_payload_bytes,
                    kPacketHeaderBytes, kIpUdpOverheadBytes, c.downlink.mtu_bytes));
  for (const LinkConfig* link : {&c.uplink, &c.downlink}) {
    try {
      if (link->latency_model == LinkConfig::Latency::Trace) load_latency_trace(link->trace_file);
      if (!link->capacity_trace_file.empty()) load_capacity_trace(link->capacity_trace_file);
    } catch (const Error& e) {
      problems.push_back(fmt::format("{}: {}", link == &c.uplink ? "uplink" : "downlink", e.what()));
    }
  }
  check(c.server_pose_prediction == "off" || c.mode == "remote",
        fmt::format("server_pose_prediction '{}': pose prediction is for remote rendering (mode remote); a hybrid "
                    "client predicts from its own G-buffers, which the server's would no longer match",
                    c.server_pose_prediction));
  check(c.server_pose_prediction != "delay" || c.server_timing == SimConfig::ServerTiming::Fixed,
        "server_pose_prediction 'delay' needs server_timing fixed (the delay counts server_fixed_ms); use 'lead' "
        "with server_pose_lead_ms");
  std::optional<PassPlan> plan;
  try {
    plan = plan_passes(scene, c.trace);
  } catch (const Error& e) {
    problems.push_back(e.what());
  }
  for (const RunSetting& s : run_settings()) {
    if (s.type != SettingType::Backend) continue;
    try {
      run.backends[s.key] = effective_backend(s, s.get(c), r);
    } catch (const Error& e) {
      problems.push_back(fmt::format("{}: {}", s.key, e.what()));
    }
  }
  if (problems.empty()) {
    run.passes = std::move(*plan);
    run.traced = traced_passes(run.passes, c.width, c.height);
    if (run.remote()) {
      // The colour predictor says whether it reprojects with depth the server sends beside it.
      const BackendChoice& p = c.pass(kColourPassName).predictor;
      run.depth_bits = r.predictors.create(p.name, p.params)->depth_bits();
    }
    run.sent = sent_passes(run.passes, run.remote(), run.depth_bits, c.width, c.height);
    run.server_stages = {ServerStage::Rasterize, ServerStage::Trace, ServerStage::Denoise};
    if (run.remote()) {
      run.server_stages.push_back(ServerStage::Composite);
      if (run.depth_bits > 0) run.server_stages.push_back(ServerStage::PackDepth);
      run.client_stages = {ClientStage::Decode, ClientStage::Predict};
    } else {
      const bool reduced = std::any_of(run.sent.begin(), run.sent.end(), [&](const PlannedPass& p) {
        return p.desc.width != c.width || p.desc.height != c.height;
      });
      run.client_stages = {ClientStage::Rasterize, ClientStage::Decode};
      if (reduced) run.client_stages.push_back(ClientStage::Upsample);
      run.client_stages.insert(run.client_stages.end(), {ClientStage::Predict, ClientStage::Composite});
    }
    run.server_stages.push_back(ServerStage::Encode);
    // A lossy codec must not be asked to carry a bitmask.
    std::string sent;
    bool budgeted = false;
    for (const PlannedPass& p : run.sent) {
      const BackendChoice codec = c.pass(p.name).codec;
      const std::unique_ptr<Codec> made = r.codecs.create(codec.name, codec.params);
      if (std::string why = made->refuses(p.desc); !why.empty())
        problems.push_back(fmt::format("passes.{}.codec '{}' cannot carry the {} pass: {}", p.name, codec.name,
                                       pass_kind_name(p.desc.kind), why));
      budgeted = budgeted || made->takes_target_kbps();
      sent += fmt::format("{}passes.{}.codec '{}'", sent.empty() ? "" : ", ", p.name, codec.name);
    }
    if (c.abr != "off" && c.stream_kbps <= 0.0)
      problems.push_back(
          fmt::format("abr '{}' moves the stream budget: set stream_kbps (its start) and give one "
                      "pass h264 with rate_control bitrate",
                      c.abr));
    if (const auto rs = RunPlan::abr_settings(c);
        rs && c.stream_kbps > 0.0 && !(rs->min_kbps <= rs->start_kbps && rs->start_kbps <= rs->max_kbps))
      problems.push_back(fmt::format("abr: stream_kbps {} (the start) is not within abr_min_kbps {} .. abr_max_kbps {}",
                                     rs->start_kbps, rs->min_kbps, rs->max_kbps));
    if (c.stream_kbps > 0.0 && !budgeted)
      problems.push_back(
          fmt::format("stream_kbps {}: no pass's codec takes a target bitrate ({}); give one pass "
                      "h264 with rate_control bitrate",
                      c.stream_kbps, sent));
  }
  if (!problems.empty()) {
    std::string msg = problems.front();
    for (size_t i = 1; i < problems.size(); ++i) msg += "\n" + problems[i];
    throw Error(msg);
  }
  return run;
}

}  // namespace dhr
