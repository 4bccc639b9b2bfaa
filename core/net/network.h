// A simulated network link on the virtual clock (milliseconds): one direction of the DHR
// connection. This kernel has no netem, so delay, jitter, loss and rate limits are simulated
// here, seeded and deterministic: the fate of the i-th datagram depends only on the seed, the
// link's stream id, i and the sizes and send times of the datagrams before it.
//
// Order of effects for a datagram sent at time t with s bytes on the wire:
//   1. loss (independent Bernoulli, or Gilbert-Elliott two-state bursts), decided per datagram;
//   2. the bandwidth cap: a FIFO queue drained at bandwidth_mbps; a datagram that would push
//      the queue beyond queue_limit_bytes is dropped (tail drop); else it leaves the queue at
//      t_depart = max(t, link free) + s * 8 / bandwidth;
//   3. propagation latency: constant, normal (mean latency_ms, sd jitter_ms, floored at
//      latency_floor_ms), or replayed from a trace (the latency in force at t_depart);
//   4. if preserve_order, a datagram never arrives before the one sent before it.
// A datagram larger than mtu_bytes is refused (the packetizer keeps them smaller).
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <deque>
#include <string>
#include <vector>

namespace dhr {

struct LinkConfig {
  enum class Latency { Constant, Normal, Trace };
  enum class Loss { None, Independent, GilbertElliott };

  Latency latency_model = Latency::Constant;
  double latency_ms = 0.0;        // Constant: the latency; Normal: the mean
  double jitter_ms = 0.0;         // Normal: standard deviation
  double latency_floor_ms = 0.0;  // Normal: no sample below this
  std::string trace_file;         // Trace: see load_latency_trace
  double trace_offset_ms = 0.0;   // Trace: where in the trace virtual time 0 falls

  Loss loss_model = Loss::None;
  double loss_rate = 0.0;         // Independent: probability a datagram is lost
  double ge_p_good_to_bad = 0.0;  // Gilbert-Elliott: per-datagram transition probabilities
  double ge_p_bad_to_good = 1.0;
  double ge_loss_good = 0.0;  // loss probability in each state
  double ge_loss_bad = 1.0;

  double bandwidth_mbps = 0.0;  // 0 = unlimited
  // A capacity that changes: a trace of Mb/s samples (the latency trace's format, values
  // 0.01..1e6; repeats), in place of bandwidth_mbps. A datagram is sent at the capacity in force
  // when its transmission starts; the FIFO holds at most queue_limit_bytes.
  std::string capacity_trace_file;
  double capacity_trace_offset_ms = 0.0;  // where in the trace virtual time 0 falls
  uint64_t queue_limit_bytes = 0;         // with a bandwidth cap: 0 = unbounded is refused; see validate
  int mtu_bytes = 1500;
  bool preserve_order = true;

  // Reads a JSON object; every unknown key, wrong type and out-of-range value is reported at
  // once (dhr::Error naming `where` and the key). Missing keys keep the defaults above.
  static LinkConfig from_json(const nlohmann::json& j, const std::string& where);
  nlohmann::json to_json() const;  // every field, defaults filled in
};

// A trace of samples over time: a text file; '#' starts a comment; an optional line
// "interval_ms: X" (default 10) gives the time between samples; every other line holds one
// sample. The trace repeats. Throws dhr::Error naming the file and line on bad content. Each
// file is parsed once per process (validation and every run's links read the same files), and
// again when its size or modification time changes.
struct SampleTrace {
  double interval_ms = 10.0;
  std::vector<double> samples;
  double at(double t_ms) const;  // the sample in force at time t (wrapping)
};
// A latency trace (LinkConfig::trace_file): samples in ms, 0..100000.
SampleTrace load_latency_trace(const std::string& path);
// A capacity trace (LinkConfig::capacity_trace_file): samples in Mb/s, 0.01..1e6.
SampleTrace load_capacity_trace(const std::string& path);

enum class DropReason : uint8_t { None = 0, Loss, QueueFull, OverMtu };
const char* drop_reason_name(DropReason r);

struct Delivery {
  bool delivered = false;
  DropReason reason = DropReason::None;
  double arrival_ms = 0.0;
};

struct LinkStats {
  uint64_t datagrams_sent = 0, datagrams_delivered = 0;
  uint64_t bytes_sent = 0, bytes_delivered = 0;  // on the wire (headers included)
  uint64_t dropped_loss = 0, dropped_queue = 0, dropped_mtu = 0;
  double max_queue_delay_ms = 0.0;
};

class Link {
 public:
  Link(const LinkConfig& config, uint64_t seed, uint32_t stream_id);
  // Send `wire_bytes` (payload + all headers) at time now_ms (non-decreasing across calls).
  Delivery send(uint64_t wire_bytes, double now_ms);
  const LinkStats& stats() const { return stats_; }
  const LinkConfig& config() const { return config_; }

 private:
  LinkConfig config_;
  SampleTrace trace_;
  SampleTrace capacity_;  // capacity_trace_file's samples (Mb/s); empty: bandwidth_mbps
  // With a capacity trace: the datagrams queued or in transmission (departure ms, bytes).
  std::deque<std::pair<double, uint64_t>> queued_;
  uint64_t queued_bytes_ = 0;
  uint64_t seed_;
  uint32_t stream_;
  uint64_t index_ = 0;         // datagrams sent so far
  bool ge_bad_ = false;        // Gilbert-Elliott state
  double link_free_ms_ = 0.0;  // when the queue has drained
  double last_arrival_ms_ = 0.0;
  double last_send_ms_ = 0.0;
  LinkStats stats_;
};

}  // namespace dhr
