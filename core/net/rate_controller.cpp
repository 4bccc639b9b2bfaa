#include "core/net/rate_controller.h"

#include <algorithm>
#include <cmath>

namespace dhr {

namespace {
// Sent frames whose reports never came (the uplink lost them) are forgotten past this many.
constexpr size_t kMaxUnreported = 4096;
// A report whose arrival is this far from the frame's sending is not from a real clock.
constexpr double kMaxDelayMs = 1e9;
}  // namespace

RateController::RateController(const RateControlSettings& s)
    : s_(s), rate_(std::clamp(s.start_kbps, s.min_kbps, s.max_kbps)) {}

void RateController::on_sent(uint32_t frame, int pass, uint64_t wire_bytes, double sent_ms) {
  sent_[{frame, pass}] = {wire_bytes, sent_ms};
  while (sent_.size() > kMaxUnreported) sent_.erase(sent_.begin());
}

void RateController::on_report(const FrameReport& r) {
  auto it = sent_.find({r.frame, r.pass});
  if (it == sent_.end()) {  // never sent, already reported, or forgotten
    ++dropped_;
    return;
  }
  const Sent sent = it->second;
  sent_.erase(it);
  ++reported_;
  if (r.lost) return;  // (the loss rule reads the datagram counts)
  // (Live mode: the client's clock and the server's differ by a constant, which the smallest
  // delay takes out; a delay may then be negative, but not beyond any real clock's range.)
  const double delay = r.arrival_ms - sent.sent_ms;
  if (!std::isfinite(delay) || std::fabs(delay) > kMaxDelayMs) {
    ++dropped_;
    return;
  }
  min_delay_ms_ = std::min(min_delay_ms_, delay);
  queue_sum_ms_ += delay - min_delay_ms_;
  ++delivered_;
  delivered_bits_ += sent.wire_bytes * 8;
}

void RateController::on_counts(uint64_t received, uint64_t lost) {
  // The counts only grow: lower ones come from an older message overtaken on the way.
  new_received_ = std::max(new_received_, received);
  new_lost_ = std::max(new_lost_, lost);
}

double RateController::update(double now_ms) {
  if (last_update_ms_ < 0.0) last_update_ms_ = now_ms;
  const double elapsed_ms = now_ms - last_update_ms_;
  if (elapsed_ms < s_.interval_ms || reported_ == 0) return rate_;
  const uint64_t got = new_received_ - received_, missed = new_lost_ - lost_;
  const double loss = got + missed > 0 ? double(missed) / double(got + missed) : 0.0;
  const double queue_ms = delivered_ > 0 ? queue_sum_ms_ / double(delivered_) : 0.0;
  const double received_kbps = double(delivered_bits_) / elapsed_ms;  // bits per ms = kbit/s
  if (delivered_ > 0 && queue_ms > s_.target_queue_ms)
    rate_ = s_.beta * received_kbps;
  else if (loss > 0.10)
    rate_ *= 1.0 - loss / 2.0;
  else if (loss < 0.02)
    rate_ *= std::pow(1.0 + s_.increase_per_s, elapsed_ms / 1000.0);
  rate_ = std::clamp(rate_, s_.min_kbps, s_.max_kbps);
  last_update_ms_ = now_ms;
  queue_sum_ms_ = 0.0;
  delivered_ = reported_ = delivered_bits_ = 0;
  received_ = new_received_;
  lost_ = new_lost_;
  ++updates_;
  return rate_;
}

}  // namespace dhr
