// The adaptive bitrate controller of a stream: the server moves the stream's bit budget
// (stream_kbps: every pass whose codec takes a target bitrate shares it; in remote mode the
// colour stream) from what the client reports over the uplink: when each frame's last packet
// arrived (or that it was lost), and its running counts of datagrams received and lost (as an
// RTCP receiver report). The same controller serves hybrid (one budget over all passes) and
// remote colour.
//
// The rule, at most once per interval_ms of server time, from the reports that reached the
// server since the last update (after Google Congestion Control, draft-ietf-rmcat-gcc-02:
// its delay-based decrease to beta = 0.85 of the received rate, its loss-based rule, and its
// multiplicative increase of at most 8 % per second; and ALVR's adaptive bitrate, which bounds
// its rate by a latency target, max_network_latency_ms):
//   queue  = mean over the reported frames of (delivery delay - the smallest delivery delay seen
//            in the session): the delay the link's queue adds (the propagation and a frame's
//            serialization at full rate are in the smallest one; no clock sync is needed)
//   loss   = datagrams lost / (lost + received), from the growth of the client's counts
//   received = wire bits of the delivered frames / the time between the update before and this one
//   queue > target_queue_ms:    rate = beta * received          (the link is full: drain its queue)
//   else loss > 10 %:           rate = rate * (1 - loss / 2)
//   else loss < 2 %:            rate = rate * (1 + increase_per_s)^(elapsed s)
//   (2..10 % loss: the rate holds); then the rate is clamped to [min_kbps, max_kbps].
// Reports of frames the server never sent, sent twice, or with a delay that is not finite or
// beyond 1e9 ms either way (the client's clock may differ from the server's by a constant: the
// smallest delay takes it out), are dropped and counted, as every other untrusted datagram is; counts lower than
// the newest are an older message overtaken on the way and change nothing.
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <map>
#include <utility>

namespace dhr {

struct RateControlSettings {
  double start_kbps = 10000.0;
  double min_kbps = 300.0;
  double max_kbps = 10000.0;
  double target_queue_ms = 10.0;
  double interval_ms = 100.0;
  double increase_per_s = 0.08;  // GCC's multiplicative increase
  double beta = 0.85;            // GCC's delay-based decrease
};

// What the reports add to the client's camera message (live mode's wire format,
// core/live/live_protocol.h; the simulator counts the same on its uplink): the datagram counts
// and the report count, then each report (frame, slot, lost flag, reserved, arrival time).
constexpr size_t kReportsHeadBytes = 8 + 8 + 2, kFrameReportWireBytes = 16;

// One frame as the client reports it.
struct FrameReport {
  uint32_t frame = 0;
  int pass = 0;
  bool lost = false;
  double arrival_ms = 0.0;  // delivered: when its last packet arrived (the client's clock)
};

class RateController {
 public:
  explicit RateController(const RateControlSettings& s);
  // The server sent `wire_bytes` of pass `pass` of frame `frame` at sent_ms.
  void on_sent(uint32_t frame, int pass, uint64_t wire_bytes, double sent_ms);
  // A client report that reached the server.
  void on_report(const FrameReport& r);
  // The client's running counts of datagrams received and lost (by sequence gaps).
  void on_counts(uint64_t received, uint64_t lost);
  // Updates the rate if interval_ms has passed since the last update; returns the rate (kbit/s).
  double update(double now_ms);
  double rate_kbps() const { return rate_; }
  uint64_t reports_dropped() const { return dropped_; }
  uint64_t updates() const { return updates_; }

 private:
  struct Sent {
    uint64_t wire_bytes = 0;
    double sent_ms = 0.0;
  };
  RateControlSettings s_;
  double rate_;
  std::map<std::pair<uint32_t, int>, Sent> sent_;                  // sent, not yet reported
  double min_delay_ms_ = std::numeric_limits<double>::infinity();  // the smallest delivery delay seen
  double last_update_ms_ = -1.0;
  // Since the last update:
  double queue_sum_ms_ = 0.0;
  uint64_t delivered_ = 0, reported_ = 0, delivered_bits_ = 0;
  uint64_t received_ = 0, lost_ = 0;          // the counts at the last update
  uint64_t new_received_ = 0, new_lost_ = 0;  // the newest counts
  uint64_t dropped_ = 0, updates_ = 0;
};

}  // namespace dhr
