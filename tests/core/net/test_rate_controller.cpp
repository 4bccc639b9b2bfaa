// The adaptive bitrate controller's rule (core/net/rate_controller.h), each branch on reports
// whose answer is known, and the reports it must drop.
#include "core/net/rate_controller.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <map>
#include <utility>

namespace dhr {
namespace {

RateControlSettings settings() {
  RateControlSettings s;
  s.start_kbps = 4000;
  s.min_kbps = 500;
  s.max_kbps = 8000;
  s.target_queue_ms = 10;
  s.interval_ms = 100;
  return s;
}

// The client's datagram counts (received, lost) per controller of the running test.
std::map<const RateController*, std::pair<uint64_t, uint64_t>> counts;

// Sends frame f (wire_bytes, at f * 16 ms) and reports it delivered after delay_ms, or lost;
// the client's datagram counts grow by 10 a frame (all 10 lost with a lost frame).
void frame(RateController& c, uint32_t f, uint64_t wire_bytes, double delay_ms, bool lost = false) {
  auto& [received, lost_datagrams] = counts[&c];
  const double sent = f * 16.0;
  c.on_sent(f, 0, wire_bytes, sent);
  c.on_report({f, 0, lost, sent + delay_ms});
  (lost ? lost_datagrams : received) += 10;
  c.on_counts(received, lost_datagrams);
}

TEST(RateController, RisesEightPercentPerSecondWhileTheQueueStaysEmpty) {
  counts.clear();
  RateController c(settings());
  EXPECT_EQ(c.update(0), 4000);
  for (uint32_t f = 0; f < 7; ++f) frame(c, f, 1000, 20.0);
  EXPECT_NEAR(c.update(112), 4000 * std::pow(1.08, 0.112), 1e-9);
  EXPECT_EQ(c.updates(), 1u);
  EXPECT_EQ(c.update(150), c.rate_kbps());  // within the interval: no change
  EXPECT_EQ(c.updates(), 1u);
  // Up to the bound, not past it.
  double t = 112;
  for (uint32_t f = 7; f < 20000; ++f) {
    frame(c, f, 1000, 20.0);
    t += 16;
    c.update(t);
  }
  EXPECT_EQ(c.rate_kbps(), 8000);
}

TEST(RateController, AQueueAboveTheTargetCutsToBetaOfTheReceivedRate) {
  counts.clear();
  RateController c(settings());
  c.update(0);
  frame(c, 0, 1000, 20.0);  // the smallest delay: the base
  // 24 ms more than the base on average: the link's queue holds 24 ms.
  for (uint32_t f = 1; f < 7; ++f) frame(c, f, 2000, 20.0 + 28.0);
  // Received: (1000 + 6 * 2000) bytes * 8 bits over 100 ms = 1040 kbit/s.
  EXPECT_NEAR(c.update(100), 0.85 * 1040.0, 1e-9);
}

// The loss rule reads the growth of the datagram counts, not the frames (one lost datagram
// loses a whole frame of many).
TEST(RateController, LossAboveTenPercentCutsByHalfTheLoss) {
  counts.clear();
  RateController c(settings());
  c.update(0);
  for (uint32_t f = 0; f < 10; ++f) frame(c, f, 1000, 20.0, f < 3);  // 30 % lost
  EXPECT_NEAR(c.update(100), 4000 * (1 - 0.15), 1e-9);
  // 5 % loss: holds.
  for (uint32_t f = 10; f < 30; ++f) frame(c, f, 1000, 20.0, f == 10);
  EXPECT_NEAR(c.update(200), 3400, 1e-9);
  // Never below the floor.
  for (int k = 0; k < 50; ++k) {
    for (uint32_t f = 0; f < 10; ++f) frame(c, 100 + k * 10 + f, 1000, 20.0, true);
    c.update(300 + k * 100.0);
  }
  EXPECT_EQ(c.rate_kbps(), 500);
}

TEST(RateController, DatagramLossNotFrameLossDrivesTheLossRule) {
  counts.clear();
  RateController c(settings());
  c.update(0);
  // Every third frame lost (33 % of frames), but 1 datagram of its 30: 1.1 % of the datagrams.
  uint64_t received = 0, lost = 0;
  for (uint32_t f = 0; f < 9; ++f) {
    c.on_sent(f, 0, 1000, f * 10.0);
    c.on_report({f, 0, f % 3 == 0, f * 10.0 + 20.0});
    received += f % 3 == 0 ? 29 : 30;
    lost += f % 3 == 0 ? 1 : 0;
    c.on_counts(received, lost);
  }
  c.on_counts(received - 5, lost);                               // an older message, overtaken: changes nothing
  EXPECT_NEAR(c.update(100), 4000 * std::pow(1.08, 0.1), 1e-9);  // under 2 %: up
  EXPECT_EQ(c.reports_dropped(), 0u);
}

TEST(RateController, ForgedRepeatedAndImpossibleReportsAreDroppedAndCounted) {
  counts.clear();
  RateController c(settings());
  c.update(0);
  c.on_report({99, 0, false, 50.0});  // never sent
  c.on_sent(1, 0, 1000, 16.0);
  c.on_report({1, 1, false, 30.0});  // another pass
  c.on_report({1, 0, false, 30.0});
  c.on_report({1, 0, false, 31.0});  // again
  c.on_sent(2, 0, 1000, 32.0);
  c.on_report({2, 0, false, -2e9});  // no real clock
  c.on_sent(3, 0, 1000, 48.0);
  c.on_report({3, 0, false, std::numeric_limits<double>::quiet_NaN()});
  EXPECT_EQ(c.reports_dropped(), 5u);
  EXPECT_NEAR(c.update(100), 4000 * std::pow(1.08, 0.1), 1e-9);  // one good report, no queue
}

// Live mode: the client's clock may run behind the server's, so every delay is negative; the
// smallest one still takes the offset out (a queue of 24 ms on average is over the target).
TEST(RateController, AClockOffsetDropsOutEvenWhenDelaysAreNegative) {
  counts.clear();
  RateController c(settings());
  c.update(0);
  constexpr double kOffset = -5000.0;
  c.on_sent(0, 0, 1000, 0.0);
  c.on_report({0, 0, false, kOffset + 20.0});
  for (uint32_t f = 1; f < 7; ++f) {
    c.on_sent(f, 0, 2000, f * 16.0);
    c.on_report({f, 0, false, f * 16.0 + kOffset + 48.0});
  }
  c.on_counts(70, 0);
  EXPECT_NEAR(c.update(100), 0.85 * 1040.0, 1e-9);
  EXPECT_EQ(c.reports_dropped(), 0u);
}

TEST(RateController, NoReportsNoChange) {
  counts.clear();
  RateController c(settings());
  c.update(0);
  c.on_sent(0, 0, 1000, 0.0);
  EXPECT_EQ(c.update(1000), 4000);
  EXPECT_EQ(c.updates(), 0u);
}

}  // namespace
}  // namespace dhr
