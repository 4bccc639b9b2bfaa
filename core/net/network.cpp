#include "core/net/network.h"

#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/base/rng.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>

namespace dhr {

namespace {

const char* latency_name(LinkConfig::Latency l) {
  switch (l) {
    case LinkConfig::Latency::Constant: return "constant";
    case LinkConfig::Latency::Normal: return "normal";
    case LinkConfig::Latency::Trace: return "trace";
  }
  return "?";
}
const char* loss_name(LinkConfig::Loss l) {
  switch (l) {
    case LinkConfig::Loss::None: return "none";
    case LinkConfig::Loss::Independent: return "independent";
    case LinkConfig::Loss::GilbertElliott: return "gilbert_elliott";
  }
  return "?";
}

// Standard normal from two uniforms (Box-Muller); u1 is kept away from 0.
double normal01(double u1, double u2) {
  u1 = std::max(u1, 1e-300);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
}

}  // namespace

LinkConfig LinkConfig::from_json(const nlohmann::json& j, const std::string& where) {
  LinkConfig c;
  if (!j.is_object()) fail("{}: a link must be a JSON object, got {}", where, json_excerpt(j));
  std::vector<std::string> problems;
  auto number = [&](const char* key, double& out, double lo, double hi) {
    if (!j.contains(key)) return;
    const auto& v = j.at(key);
    if (!v.is_number() || !std::isfinite(v.get<double>()) || v.get<double>() < lo || v.get<double>() > hi) {
      problems.push_back(fmt::format("{}.{} = {}: must be a number in {}..{}", where, key, json_excerpt(v), lo, hi));
      return;
    }
    out = v.get<double>();
  };
  static const std::vector<std::string> keys = {
      "latency",           "latency_ms",  "jitter_ms",      "latency_floor_ms",    "trace_file",
      "trace_offset_ms",   "loss",        "loss_rate",      "ge_p_good_to_bad",    "ge_p_bad_to_good",
      "ge_loss_good",      "ge_loss_bad", "bandwidth_mbps", "capacity_trace_file", "capacity_trace_offset_ms",
      "queue_limit_bytes", "mtu_bytes",   "preserve_order"};
  for (const auto& [key, value] : j.items()) {
    if (std::find(keys.begin(), keys.end(), key) == keys.end()) {
      std::string valid;
      for (const auto& k : keys) valid += (valid.empty() ? "" : ", ") + k;
      problems.push_back(fmt::format("{}: unknown key '{}' (valid: {})", where, text_excerpt(key), valid));
    }
  }
  if (j.contains("latency")) {
    const auto& v = j.at("latency");
    const std::string s = v.is_string() ? v.get<std::string>() : "";
    if (s == "constant")
      c.latency_model = Latency::Constant;
    else if (s == "normal")
      c.latency_model = Latency::Normal;
    else if (s == "trace")
      c.latency_model = Latency::Trace;
    else
      problems.push_back(
          fmt::format("{}.latency = {}: must be one of constant, normal, trace", where, json_excerpt(v)));
  }
  if (j.contains("loss")) {
    const auto& v = j.at("loss");
    const std::string s = v.is_string() ? v.get<std::string>() : "";
    if (s == "none")
      c.loss_model = Loss::None;
    else if (s == "independent")
      c.loss_model = Loss::Independent;
    else if (s == "gilbert_elliott")
      c.loss_model = Loss::GilbertElliott;
    else
      problems.push_back(
          fmt::format("{}.loss = {}: must be one of none, independent, gilbert_elliott", where, json_excerpt(v)));
  }
  number("latency_ms", c.latency_ms, 0.0, 1e5);
  number("jitter_ms", c.jitter_ms, 0.0, 1e5);
  number("latency_floor_ms", c.latency_floor_ms, 0.0, 1e5);
  number("trace_offset_ms", c.trace_offset_ms, 0.0, 1e9);
  number("loss_rate", c.loss_rate, 0.0, 1.0);
  number("ge_p_good_to_bad", c.ge_p_good_to_bad, 0.0, 1.0);
  number("ge_p_bad_to_good", c.ge_p_bad_to_good, 0.0, 1.0);
  number("ge_loss_good", c.ge_loss_good, 0.0, 1.0);
  number("ge_loss_bad", c.ge_loss_bad, 0.0, 1.0);
  number("bandwidth_mbps", c.bandwidth_mbps, 0.0, 1e6);
  number("capacity_trace_offset_ms", c.capacity_trace_offset_ms, 0.0, 1e9);
  if (j.contains("capacity_trace_file")) {
    if (!j.at("capacity_trace_file").is_string())
      problems.push_back(fmt::format("{}.capacity_trace_file: must be a path string (\"\": none)", where));
    else
      c.capacity_trace_file = j.at("capacity_trace_file").get<std::string>();
  }
  double queue = double(c.queue_limit_bytes), mtu = c.mtu_bytes;
  number("queue_limit_bytes", queue, 0.0, 1e10);
  number("mtu_bytes", mtu, 68.0, 65535.0);
  c.queue_limit_bytes = uint64_t(queue);
  c.mtu_bytes = int(mtu);
  if (j.contains("trace_file")) {
    if (!j.at("trace_file").is_string())
      problems.push_back(fmt::format("{}.trace_file: must be a path string", where));
    else
      c.trace_file = j.at("trace_file").get<std::string>();
  }
  if (j.contains("preserve_order")) {
    if (!j.at("preserve_order").is_boolean())
      problems.push_back(fmt::format("{}.preserve_order: must be true or false", where));
    else
      c.preserve_order = j.at("preserve_order").get<bool>();
  }
  if (c.latency_model == Latency::Trace && c.trace_file.empty())
    problems.push_back(fmt::format("{}: latency 'trace' needs trace_file", where));
  if ((c.bandwidth_mbps > 0 || !c.capacity_trace_file.empty()) && c.queue_limit_bytes == 0)
    problems.push_back(
        fmt::format("{}: a bandwidth cap needs queue_limit_bytes > 0 (an unbounded queue hides congestion)", where));
  if (c.bandwidth_mbps > 0 && !c.capacity_trace_file.empty())
    problems.push_back(
        fmt::format("{}: bandwidth_mbps and capacity_trace_file both set; give one (the trace is the "
                    "capacity over time)",
                    where));
  if (!problems.empty()) {
    std::string msg = problems.front();
    for (size_t i = 1; i < problems.size(); ++i) msg += "\n" + problems[i];
    throw Error(msg);
  }
  return c;
}

nlohmann::json LinkConfig::to_json() const {
  return {{"latency", latency_name(latency_model)},
          {"latency_ms", latency_ms},
          {"jitter_ms", jitter_ms},
          {"latency_floor_ms", latency_floor_ms},
          {"trace_file", trace_file},
          {"trace_offset_ms", trace_offset_ms},
          {"loss", loss_name(loss_model)},
          {"loss_rate", loss_rate},
          {"ge_p_good_to_bad", ge_p_good_to_bad},
          {"ge_p_bad_to_good", ge_p_bad_to_good},
          {"ge_loss_good", ge_loss_good},
          {"ge_loss_bad", ge_loss_bad},
          {"bandwidth_mbps", bandwidth_mbps},
          {"queue_limit_bytes", queue_limit_bytes},
          {"mtu_bytes", mtu_bytes},
          {"preserve_order", preserve_order},
          {"capacity_trace_file", capacity_trace_file},
          {"capacity_trace_offset_ms", capacity_trace_offset_ms}};
}

double SampleTrace::at(double t_ms) const {
  if (samples.empty()) return 0.0;
  const double slot = std::floor(std::max(t_ms, 0.0) / interval_ms);
  const auto i = size_t(std::fmod(slot, double(samples.size())));
  return samples[i];
}

namespace {

// A trace file's samples: `what` names it in errors, values lo..hi.
SampleTrace parse_sample_trace(const std::string& path, const char* what, const char* unit, double lo, double hi) {
  std::ifstream in(path);
  if (!in) fail("{}: {} trace not found or unreadable", path, what);
  SampleTrace t;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    line.erase(0, line.find_first_not_of(" \t\r"));
    line.erase(line.find_last_not_of(" \t\r") + 1);
    if (line.empty()) continue;
    if (line.rfind("interval_ms:", 0) == 0) {
      std::istringstream s(line.substr(12));
      double v = 0;
      if (!(s >> v) || !(v > 0 && v < 1e6)) fail("{}:{}: interval_ms must be a positive number", path, number);
      t.interval_ms = v;
      continue;
    }
    std::istringstream s(line);
    double v = 0;
    std::string rest;
    if (!(s >> v) || (s >> rest) || !std::isfinite(v) || v < lo || v > hi)
      fail("{}:{}: '{}' is not a {} in {} (a number {}..{})", path, number, line, what, unit, lo, hi);
    t.samples.push_back(v);
    if (t.samples.size() > 10'000'000) fail("{}: more than 10 million samples", path);
  }
  if (t.samples.empty()) fail("{}: no {} samples", path, what);
  return t;
}

// parse_sample_trace once per (file, kind, size, modification time): an experiment validates
// and runs thousands of runs over the same trace files. Only traces that parsed are kept.
SampleTrace load_sample_trace(const std::string& path, const char* what, const char* unit, double lo, double hi) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const auto size = fs::file_size(path, ec);
  const auto time = ec ? fs::file_time_type{} : fs::last_write_time(path, ec);
  if (ec) return parse_sample_trace(path, what, unit, lo, hi);  // it names what is wrong with the file
  const std::string key = fmt::format("{}\n{}\n{}\n{}", what, path, size, time.time_since_epoch().count());
  static std::mutex mutex;
  static std::map<std::string, std::shared_ptr<const SampleTrace>> parsed;
  {
    std::lock_guard<std::mutex> lock(mutex);
    if (auto it = parsed.find(key); it != parsed.end()) return *it->second;
  }
  auto t = std::make_shared<const SampleTrace>(parse_sample_trace(path, what, unit, lo, hi));
  std::lock_guard<std::mutex> lock(mutex);
  parsed.emplace(key, t);
  return *t;
}

}  // namespace

SampleTrace load_latency_trace(const std::string& path) { return load_sample_trace(path, "latency", "ms", 0.0, 1e5); }

SampleTrace load_capacity_trace(const std::string& path) {
  return load_sample_trace(path, "capacity", "Mb/s", 0.01, 1e6);
}

const char* drop_reason_name(DropReason r) {
  switch (r) {
    case DropReason::None: return "none";
    case DropReason::Loss: return "loss";
    case DropReason::QueueFull: return "queue_full";
    case DropReason::OverMtu: return "over_mtu";
  }
  return "?";
}

Link::Link(const LinkConfig& config, uint64_t seed, uint32_t stream_id)
    : config_(config), seed_(seed), stream_(stream_id) {
  if (config_.latency_model == LinkConfig::Latency::Trace) trace_ = load_latency_trace(config_.trace_file);
  if (!config_.capacity_trace_file.empty()) capacity_ = load_capacity_trace(config_.capacity_trace_file);
}

Delivery Link::send(uint64_t wire_bytes, double now_ms) {
  if (now_ms < last_send_ms_) fail("network link: send times must not decrease ({} after {})", now_ms, last_send_ms_);
  last_send_ms_ = now_ms;
  const RngKey key{seed_, uint32_t(index_), uint32_t(index_ >> 32), 0, kStreamNetwork + (stream_ << 8)};
  ++index_;
  ++stats_.datagrams_sent;
  stats_.bytes_sent += wire_bytes;
  Delivery d;
  if (wire_bytes > uint64_t(config_.mtu_bytes)) {
    ++stats_.dropped_mtu;
    d.reason = DropReason::OverMtu;
    return d;
  }
  // 1. Loss.
  bool lost = false;
  switch (config_.loss_model) {
    case LinkConfig::Loss::None: break;
    case LinkConfig::Loss::Independent: lost = rng_uniform_double(key, 0) < config_.loss_rate; break;
    case LinkConfig::Loss::GilbertElliott: {
      const double u = rng_uniform_double(key, 1);
      ge_bad_ = ge_bad_ ? !(u < config_.ge_p_bad_to_good) : (u < config_.ge_p_good_to_bad);
      lost = rng_uniform_double(key, 0) < (ge_bad_ ? config_.ge_loss_bad : config_.ge_loss_good);
      break;
    }
  }
  if (lost) {
    ++stats_.dropped_loss;
    d.reason = DropReason::Loss;
    return d;
  }
  // 2. Bandwidth cap with a bounded FIFO queue.
  double depart = now_ms;
  if (!capacity_.samples.empty()) {
    // A capacity that changes: the queue counts the bytes of the datagrams not yet sent whole,
    // and a datagram goes at the capacity in force when its transmission starts.
    while (!queued_.empty() && queued_.front().first <= now_ms) {
      queued_bytes_ -= queued_.front().second;
      queued_.pop_front();
    }
    if (queued_bytes_ + wire_bytes > config_.queue_limit_bytes) {
      ++stats_.dropped_queue;
      d.reason = DropReason::QueueFull;
      return d;
    }
    const double start = std::max(now_ms, link_free_ms_);
    const double bytes_per_ms = capacity_.at(start + config_.capacity_trace_offset_ms) * 1e6 / 8.0 / 1000.0;
    depart = start + double(wire_bytes) / bytes_per_ms;
    link_free_ms_ = depart;
    queued_.emplace_back(depart, wire_bytes);
    queued_bytes_ += wire_bytes;
    stats_.max_queue_delay_ms = std::max(stats_.max_queue_delay_ms, depart - now_ms);
  } else if (config_.bandwidth_mbps > 0) {
    const double bytes_per_ms = config_.bandwidth_mbps * 1e6 / 8.0 / 1000.0;
    const double backlog_ms = std::max(0.0, link_free_ms_ - now_ms);
    if (backlog_ms * bytes_per_ms + double(wire_bytes) > double(config_.queue_limit_bytes)) {
      ++stats_.dropped_queue;
      d.reason = DropReason::QueueFull;
      return d;
    }
    depart = std::max(now_ms, link_free_ms_) + double(wire_bytes) / bytes_per_ms;
    link_free_ms_ = depart;
    stats_.max_queue_delay_ms = std::max(stats_.max_queue_delay_ms, depart - now_ms);
  }
  // 3. Latency.
  double latency = 0.0;
  switch (config_.latency_model) {
    case LinkConfig::Latency::Constant: latency = config_.latency_ms; break;
    case LinkConfig::Latency::Normal:
      latency = std::max(
          config_.latency_floor_ms,
          config_.latency_ms + config_.jitter_ms * normal01(rng_uniform_double(key, 2), rng_uniform_double(key, 3)));
      break;
    case LinkConfig::Latency::Trace: latency = trace_.at(depart + config_.trace_offset_ms); break;
  }
  d.arrival_ms = depart + latency;
  // 4. Order.
  if (config_.preserve_order) d.arrival_ms = std::max(d.arrival_ms, last_arrival_ms_);
  last_arrival_ms_ = std::max(last_arrival_ms_, d.arrival_ms);
  d.delivered = true;
  ++stats_.datagrams_delivered;
  stats_.bytes_delivered += wire_bytes;
  return d;
}

}  // namespace dhr
