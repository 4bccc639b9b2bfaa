// The simulated link: each effect alone against its closed form, determinism, and the shipped
// 5G-shaped trace's statistics.
#include "core/base/error.h"
#include "core/net/network.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

namespace dhr {
namespace {

TEST(Link, ConstantLatencyNoLoss) {
  LinkConfig c;
  c.latency_ms = 25;
  Link link(c, 1, 0);
  for (int i = 0; i < 10; ++i) {
    Delivery d = link.send(1228, i * 1.0);
    ASSERT_TRUE(d.delivered);
    EXPECT_DOUBLE_EQ(d.arrival_ms, i * 1.0 + 25);
  }
  EXPECT_EQ(link.stats().bytes_delivered, 12280u);
}

TEST(Link, IndependentLossRateWithinBinomialError) {
  for (double p : {0.01, 0.05}) {
    LinkConfig c;
    c.loss_model = LinkConfig::Loss::Independent;
    c.loss_rate = p;
    Link link(c, 7, 0);
    const int n = 100000;
    for (int i = 0; i < n; ++i) link.send(100, i * 0.01);
    const double rate = double(link.stats().dropped_loss) / n;
    EXPECT_NEAR(rate, p, 5 * std::sqrt(p * (1 - p) / n)) << p;
  }
}

TEST(Link, GilbertElliottIsBurstyWithStationaryRate) {
  LinkConfig c;
  c.loss_model = LinkConfig::Loss::GilbertElliott;
  c.ge_p_good_to_bad = 0.01;
  c.ge_p_bad_to_good = 0.25;
  c.ge_loss_good = 0.0;
  c.ge_loss_bad = 1.0;
  Link link(c, 3, 0);
  const int n = 200000;
  int runs = 0, lost = 0;
  bool prev_lost = false;
  for (int i = 0; i < n; ++i) {
    const bool l = !link.send(100, i * 0.01).delivered;
    lost += l;
    if (l && !prev_lost) ++runs;
    prev_lost = l;
  }
  const double stationary_bad = 0.01 / (0.01 + 0.25);  // = 0.0385
  EXPECT_NEAR(double(lost) / n, stationary_bad, 0.005);
  EXPECT_NEAR(double(lost) / runs, 1 / 0.25, 0.3);  // mean burst length 1/p_bad_to_good
}

TEST(Link, BandwidthCapSerializesAndTailDrops) {
  LinkConfig c;
  c.bandwidth_mbps = 8;  // 1000 bytes per ms
  c.queue_limit_bytes = 5000;
  Link link(c, 1, 0);
  // Ten 1000-byte datagrams at t = 0: the first five fit the queue, each takes 1 ms.
  int delivered = 0;
  for (int i = 0; i < 10; ++i) {
    Delivery d = link.send(1000, 0.0);
    if (d.delivered) {
      ++delivered;
      EXPECT_NEAR(d.arrival_ms, (i + 1) * 1.0, 1e-9);
    } else {
      EXPECT_EQ(d.reason, DropReason::QueueFull);
    }
  }
  EXPECT_EQ(delivered, 5);
  // Once drained, the link accepts again.
  EXPECT_TRUE(link.send(1000, 10.0).delivered);
}

// A capacity trace: 8 Mb/s (1000 bytes per ms) for 10 ms, then 0.8 Mb/s (100 bytes per ms).
// A datagram goes at the capacity in force when its transmission starts; the queue counts the
// bytes not yet sent whole and drops what would pass queue_limit_bytes.
TEST(Link, CapacityTraceChangesTheRateAndTheQueueDrops) {
  const auto dir = std::filesystem::temp_directory_path() / "dhr_test_capacity";
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "step.txt") << "interval_ms: 10\n8\n0.8\n0.8\n0.8\n";
  LinkConfig c;
  c.capacity_trace_file = (dir / "step.txt").string();
  c.queue_limit_bytes = 3000;
  Link link(c, 1, 0);
  // Before the step: 1 ms per 1000-byte datagram.
  EXPECT_NEAR(link.send(1000, 0.0).arrival_ms, 1.0, 1e-9);
  EXPECT_NEAR(link.send(1000, 5.0).arrival_ms, 6.0, 1e-9);
  // After it: 10 ms per datagram, and they queue.
  EXPECT_NEAR(link.send(1000, 12.0).arrival_ms, 22.0, 1e-9);
  EXPECT_NEAR(link.send(1000, 12.0).arrival_ms, 32.0, 1e-9);
  EXPECT_NEAR(link.send(1000, 12.0).arrival_ms, 42.0, 1e-9);
  // Three datagrams (3000 bytes) wait: a fourth would pass the queue's limit.
  const Delivery d = link.send(1000, 12.0);
  EXPECT_FALSE(d.delivered);
  EXPECT_EQ(d.reason, DropReason::QueueFull);
  // Once the first has gone, one fits again, behind the others: its transmission starts at 42 ms,
  // where the trace (40 ms long) has begun again at 8 Mb/s.
  EXPECT_NEAR(link.send(1000, 22.5).arrival_ms, 43.0, 1e-9);
  EXPECT_EQ(link.stats().dropped_queue, 1u);
  // The trace repeats: at 40 ms (slot 0 again) the capacity is back at 8 Mb/s.
  Link fresh(c, 1, 0);
  EXPECT_NEAR(fresh.send(1000, 40.0).arrival_ms, 41.0, 1e-9);
  // Both a fixed cap and a trace, or a trace without a queue limit: refused, naming the keys.
  EXPECT_THROW(LinkConfig::from_json(
                   {{"bandwidth_mbps", 10}, {"capacity_trace_file", "x.txt"}, {"queue_limit_bytes", 1000}}, "downlink"),
               Error);
  try {
    LinkConfig::from_json({{"capacity_trace_file", "x.txt"}}, "downlink");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("queue_limit_bytes > 0"), std::string::npos) << e.what();
  }
  // Samples are Mb/s in 0.01..1e6: a zero capacity is refused, naming the line.
  std::ofstream(dir / "zero.txt") << "5\n0\n";
  try {
    load_capacity_trace((dir / "zero.txt").string());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("zero.txt:2: '0' is not a capacity in Mb/s"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

TEST(Link, OverMtuRefused) {
  LinkConfig c;
  c.mtu_bytes = 1500;
  Link link(c, 1, 0);
  EXPECT_EQ(link.send(1501, 0).reason, DropReason::OverMtu);
  EXPECT_TRUE(link.send(1500, 0).delivered);
}

TEST(Link, NormalJitterFlooredAndOrdered) {
  LinkConfig c;
  c.latency_model = LinkConfig::Latency::Normal;
  c.latency_ms = 20;
  c.jitter_ms = 10;
  c.latency_floor_ms = 5;
  const int n = 20000;
  // Without order preservation: the floored normal. E[max(5, N(20, 10))] = 20.29 ms (closed
  // form: 20 + 10 (phi(1.5) - 1.5 (1 - Phi(1.5)))), sd a little below 10.
  c.preserve_order = false;
  Link free_link(c, 11, 0);
  double sum = 0, sum2 = 0;
  int reordered = 0;
  double last = 0;
  for (int i = 0; i < n; ++i) {
    Delivery d = free_link.send(100, i * 1.0);
    ASSERT_TRUE(d.delivered);
    const double lat = d.arrival_ms - i;
    EXPECT_GE(lat, 5.0 - 1e-9);
    reordered += d.arrival_ms < last;
    last = std::max(last, d.arrival_ms);
    sum += lat;
    sum2 += lat * lat;
  }
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 20.29, 0.3);
  EXPECT_GT(sd, 8.5);
  EXPECT_LT(sd, 10.0);
  EXPECT_GT(reordered, 0);
  // With order preservation: never reordered, and the mean latency can only grow.
  c.preserve_order = true;
  Link ordered(c, 11, 0);
  last = 0;
  double sum_ordered = 0;
  for (int i = 0; i < n; ++i) {
    Delivery d = ordered.send(100, i * 1.0);
    EXPECT_GE(d.arrival_ms, last);
    last = d.arrival_ms;
    sum_ordered += d.arrival_ms - i;
  }
  EXPECT_GT(sum_ordered / n, mean);
}

TEST(Link, DeterministicPerSeedAndStream) {
  LinkConfig c;
  c.latency_model = LinkConfig::Latency::Normal;
  c.latency_ms = 20;
  c.jitter_ms = 5;
  c.loss_model = LinkConfig::Loss::Independent;
  c.loss_rate = 0.1;
  auto run = [&](uint64_t seed, uint32_t stream) {
    Link l(c, seed, stream);
    std::vector<double> out;
    for (int i = 0; i < 500; ++i) {
      Delivery d = l.send(100, i * 0.5);
      out.push_back(d.delivered ? d.arrival_ms : -1);
    }
    return out;
  };
  EXPECT_EQ(run(5, 0), run(5, 0));
  EXPECT_NE(run(5, 0), run(6, 0));
  EXPECT_NE(run(5, 0), run(5, 1));
}

TEST(Link, SendTimesMustNotDecrease) {
  Link link(LinkConfig{}, 1, 0);
  link.send(10, 5.0);
  EXPECT_THROW(link.send(10, 4.0), Error);
}

TEST(LinkConfig, JsonRoundTripAndErrors) {
  nlohmann::json j = {{"latency", "normal"},         {"latency_ms", 50},  {"jitter_ms", 5},
                      {"loss", "independent"},       {"loss_rate", 0.01}, {"bandwidth_mbps", 100},
                      {"queue_limit_bytes", 1000000}};
  LinkConfig c = LinkConfig::from_json(j, "networks[0].downlink");
  EXPECT_EQ(LinkConfig::from_json(c.to_json(), "x").to_json(), c.to_json());
  try {
    LinkConfig::from_json({{"latency", "gamma"}, {"loss_rate", 2}, {"latncy_ms", 3}, {"bandwidth_mbps", 10}}, "net");
    FAIL() << "no error";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("net.latency = \"gamma\": must be one of constant, normal, trace"), std::string::npos) << m;
    EXPECT_NE(m.find("net.loss_rate = 2: must be a number in 0..1"), std::string::npos) << m;
    EXPECT_NE(m.find("unknown key 'latncy_ms'"), std::string::npos) << m;
    EXPECT_NE(m.find("queue_limit_bytes"), std::string::npos) << m;
  }
}

TEST(LatencyTrace, FileFormatAndErrors) {
  const auto dir = std::filesystem::temp_directory_path() / "dhr_test_trace";
  std::filesystem::create_directories(dir);
  {
    std::ofstream f(dir / "t.txt");
    f << "# comment\ninterval_ms: 5\n10\n20 # inline\n30\n";
  }
  SampleTrace t = load_latency_trace((dir / "t.txt").string());
  EXPECT_EQ(t.samples.size(), 3u);
  EXPECT_DOUBLE_EQ(t.at(0), 10);
  EXPECT_DOUBLE_EQ(t.at(7), 20);
  EXPECT_DOUBLE_EQ(t.at(15), 10);  // wraps
  {
    std::ofstream f(dir / "bad.txt");
    f << "10\nabc\n";
  }
  try {
    load_latency_trace((dir / "bad.txt").string());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.txt:2"), std::string::npos) << e.what();
  }
  EXPECT_THROW(load_latency_trace((dir / "missing.txt").string()), Error);
  std::filesystem::remove_all(dir);
}

// The shipped capacity traces (scripts/make_capacity_traces.py) hold what their headers say.
TEST(CapacityTrace, ShippedTracesHaveTheirStatedShape) {
  const std::string dir = std::string(DHR_SOURCE_DIR) + "/experiments/traces/";
  const SampleTrace step = load_capacity_trace(dir + "capacity_step.txt");
  EXPECT_DOUBLE_EQ(step.at(500), 10.0);
  EXPECT_DOUBLE_EQ(step.at(1500), 2.0);
  EXPECT_DOUBLE_EQ(step.at(2500), 10.0);
  const SampleTrace ramp = load_capacity_trace(dir + "capacity_ramp.txt");
  EXPECT_DOUBLE_EQ(*std::min_element(ramp.samples.begin(), ramp.samples.end()), 1.0);
  EXPECT_DOUBLE_EQ(ramp.at(0), 10.0);
  const SampleTrace mobile = load_capacity_trace(dir + "capacity_mobile.txt");
  ASSERT_EQ(mobile.samples.size(), 600u);
  const auto& x = mobile.samples;
  double mean = 0;
  for (double v : x) mean += v / double(x.size());
  double c0 = 0, c1 = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    c0 += (x[i] - mean) * (x[i] - mean);
    if (i > 0) c1 += (x[i] - mean) * (x[i - 1] - mean);
  }
  EXPECT_NEAR(mean, 8.0, 1.5);
  EXPECT_GT(c1 / c0, 0.8);  // the AR(1)'s 0.9, seen through the exponential and the clamp
  EXPECT_NEAR(std::sqrt(c0 / double(x.size())) / mean, 0.6, 0.2);
}

TEST(LatencyTrace, Shipped5gTraceHasThePapersMeanAndP99) {
  SampleTrace t = load_latency_trace(std::string(DHR_SOURCE_DIR) + "/experiments/traces/5g_paper_shape.txt");
  std::vector<double> v = t.samples;
  double mean = 0;
  for (double x : v) mean += x;
  mean /= double(v.size());
  std::sort(v.begin(), v.end());
  EXPECT_NEAR(mean, 12.0, 0.1);
  EXPECT_NEAR(v[size_t(0.99 * double(v.size() - 1))], 48.3, 0.1);
}

}  // namespace
}  // namespace dhr
