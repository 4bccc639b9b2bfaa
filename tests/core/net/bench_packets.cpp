// Speed of the packet layer: CRC-32C (hardware and portable), packetize, the assembler
// reassembling a 1 MB pass whose packets arrive in reverse order, and forward error correction
// (core/net/fec.h: 20 % parity on 1200-byte shards) against ISA-L's own calls on the same buffers
// with tables made once (the floor; "of_isal" = its time over ours). Each case reports bytes/s and, as "of_memcpy", its rate
// as a fraction of memcpy over the same bytes measured in the same run (the ceiling: the
// packet layer copies every byte at least once on each side). Last, the adaptive bitrate
// controller's work per frame beside a 1 KB CRC.
//   build-packet/tests/bench_packets --benchmark_min_time=0.2
#include "core/base/checksum.h"
#include "core/base/rng.h"
#include "core/net/assembler.h"
#include "core/net/fec.h"
#include "core/net/packet.h"
#include "core/net/rate_controller.h"

#include <benchmark/benchmark.h>
#include <isa-l/erasure_code.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <vector>

namespace dhr {
namespace {

constexpr size_t kPassBytes = size_t(1) << 20;

std::vector<uint8_t> pass_bytes() {
  std::vector<uint8_t> v(kPassBytes);
  for (size_t i = 0; i < v.size(); ++i) v[i] = uint8_t(rng_bits({1, uint32_t(i)}));
  return v;
}

// memcpy of kPassBytes, best of a few tries, in bytes per second.
double memcpy_bytes_per_second() {
  static const double rate = [] {
    std::vector<uint8_t> a = pass_bytes(), b(kPassBytes);
    double best = 1e30;
    for (int rep = 0; rep < 50; ++rep) {
      const auto t0 = std::chrono::steady_clock::now();
      std::memcpy(b.data(), a.data(), a.size());
      benchmark::DoNotOptimize(b.data());
      benchmark::ClobberMemory();
      best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    return double(kPassBytes) / best;
  }();
  return rate;
}

using Clock = std::chrono::steady_clock;

// Sets bytes/s and of_memcpy = (this case's wall-clock rate) / (memcpy's wall-clock rate).
void finish(benchmark::State& state, size_t bytes_per_iteration, Clock::time_point start) {
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  state.SetBytesProcessed(int64_t(state.iterations()) * int64_t(bytes_per_iteration));
  const double rate = double(state.iterations()) * double(bytes_per_iteration) / seconds;
  state.counters["of_memcpy"] = rate / memcpy_bytes_per_second();
}

void BM_Crc32c(benchmark::State& state) {
  const auto data = pass_bytes();
  memcpy_bytes_per_second();
  const auto start = Clock::now();
  for (auto _ : state) benchmark::DoNotOptimize(crc32c(data));
  finish(state, data.size(), start);
  state.SetLabel(crc32c_hardware() ? "sse4.2" : "portable");
}
BENCHMARK(BM_Crc32c);

void BM_Crc32cPortable(benchmark::State& state) {
  const auto data = pass_bytes();
  memcpy_bytes_per_second();
  const auto start = Clock::now();
  for (auto _ : state) benchmark::DoNotOptimize(crc32c_portable(data));
  finish(state, data.size(), start);
}
BENCHMARK(BM_Crc32cPortable);

PacketMeta meta(uint32_t frame) {
  PacketMeta m;
  m.desc = {PassKind::Colour, 1024, 342, 3, 255};
  m.frame_id = frame;
  m.first_sequence = frame * 1000;
  return m;
}

void BM_Packetize1MB(benchmark::State& state) {
  const auto data = pass_bytes();
  memcpy_bytes_per_second();
  const auto start = Clock::now();
  for (auto _ : state) benchmark::DoNotOptimize(packetize(meta(0), data));
  finish(state, data.size(), start);
}
BENCHMARK(BM_Packetize1MB);

void BM_Assemble1MB(benchmark::State& state) {
  const auto data = pass_bytes();
  memcpy_bytes_per_second();
  std::vector<std::vector<std::vector<uint8_t>>> frames;
  for (uint32_t f = 0; f < 8; ++f) {
    auto pk = packetize(meta(f), data);
    std::reverse(pk.begin(), pk.end());  // worst order for nothing: every packet out of place
    frames.push_back(std::move(pk));
  }
  Assembler a;
  uint32_t f = 0;
  const auto start = Clock::now();
  for (auto _ : state) {
    for (const auto& d : frames[f % 8]) a.push(d, f);
    benchmark::DoNotOptimize(a.poll(f));
    ++f;
    if (f % 8 == 0) a = Assembler();  // frame ids repeat every 8 iterations
  }
  finish(state, data.size(), start);
}
BENCHMARK(BM_Assemble1MB);

// ---- FEC: the 1 MB pass as 1200-byte shards, its blocks as core/net/fec.h lays them out.
struct FecCase {
  std::vector<uint8_t> data = pass_bytes();
  FecLayout layout;
  size_t shard = kDefaultMaxPayloadBytes;
  std::vector<std::vector<uint8_t>> parity;  // per block: per_block shards
  FecCase() {
    const int n = int(packet_count(data.size(), shard));
    fec_layout(n, fec_parity_count(n, 0.2, 1), layout);
    data.resize(size_t(n) * shard, 0);  // the last shard zero-padded
    parity.assign(size_t(layout.parity), std::vector<uint8_t>(shard));
  }
  std::vector<const uint8_t*> block_data(int b) const {
    std::vector<const uint8_t*> v;
    for (int i = b; i < layout.data; i += layout.blocks) v.push_back(data.data() + size_t(i) * shard);
    return v;
  }
  std::vector<uint8_t*> block_parity(int b) {
    std::vector<uint8_t*> v;
    for (int j = 0; j < layout.per_block; ++j) v.push_back(parity[size_t(b * layout.per_block + j)].data());
    return v;
  }
};

// The shards a decode case rebuilt (the last block's data shards 0..per_block-1) are the data.
void check_rebuilt(benchmark::State& state, const FecCase& c, const std::vector<std::vector<uint8_t>>& out) {
  const int last = c.layout.blocks - 1;
  for (int j = 0; j < c.layout.per_block; ++j)
    if (std::memcmp(out[size_t(j)].data(), c.data.data() + size_t(last + j * c.layout.blocks) * c.shard, c.shard) != 0)
      state.SkipWithError("a rebuilt shard differs from the data");
}

double g_isal_encode_s = 0, g_isal_decode_s = 0;  // seconds per pass of ISA-L's own calls

void BM_FecEncodeIsal(benchmark::State& state) {
  FecCase c;
  std::vector<std::vector<uint8_t>> tables;
  for (int b = 0; b < c.layout.blocks; ++b) {
    const int k = c.layout.block_data(b), m = c.layout.per_block;
    std::vector<uint8_t> a(size_t(k + m) * size_t(k));
    gf_gen_cauchy1_matrix(a.data(), k + m, k);
    tables.emplace_back(size_t(k) * size_t(m) * 32);
    ec_init_tables(k, m, a.data() + size_t(k) * size_t(k), tables.back().data());
  }
  const auto start = Clock::now();
  for (auto _ : state)
    for (int b = 0; b < c.layout.blocks; ++b) {
      auto d = c.block_data(b);
      auto p = c.block_parity(b);
      ec_encode_data(int(c.shard), int(d.size()), c.layout.per_block, tables[size_t(b)].data(),
                     const_cast<uint8_t**>(d.data()), p.data());
      benchmark::ClobberMemory();
    }
  g_isal_encode_s = std::chrono::duration<double>(Clock::now() - start).count() / double(state.iterations());
  finish(state, kPassBytes, start);
}
BENCHMARK(BM_FecEncodeIsal);

void BM_FecEncode(benchmark::State& state) {
  FecCase c;
  const auto start = Clock::now();
  for (auto _ : state)
    for (int b = 0; b < c.layout.blocks; ++b) {
      auto d = c.block_data(b);
      auto p = c.block_parity(b);
      rs_encode(int(d.size()), c.layout.per_block, c.shard, d.data(), p.data());
      benchmark::ClobberMemory();
    }
  const double s = std::chrono::duration<double>(Clock::now() - start).count() / double(state.iterations());
  finish(state, kPassBytes, start);
  if (g_isal_encode_s > 0) state.counters["of_isal"] = g_isal_encode_s / s;
}
BENCHMARK(BM_FecEncode);

// Rebuilding per_block lost data shards of every block (the most its parity repairs).
void BM_FecDecodeIsal(benchmark::State& state) {
  FecCase c;
  const int m = c.layout.per_block;
  std::vector<std::vector<uint8_t>> tables, out(size_t(m), std::vector<uint8_t>(c.shard));
  std::vector<std::vector<const uint8_t*>> present;
  for (int b = 0; b < c.layout.blocks; ++b) {
    auto d = c.block_data(b);
    auto p = c.block_parity(b);
    rs_encode(int(d.size()), m, c.shard, d.data(), p.data());
    const int k = int(d.size());
    std::vector<uint8_t> a(size_t(k + m) * size_t(k)), sub(size_t(k) * size_t(k)), inv(sub.size());
    gf_gen_cauchy1_matrix(a.data(), k + m, k);
    std::vector<const uint8_t*> shards;
    for (int r = 0; r < k; ++r) {  // data shards m..k-1, then the m parity shards
      const int row = r < k - m ? r + m : k + (r - (k - m));
      std::copy_n(a.data() + size_t(row) * size_t(k), k, sub.data() + size_t(r) * size_t(k));
      shards.push_back(row < k ? d[size_t(row)] : p[size_t(row - k)]);
    }
    gf_invert_matrix(sub.data(), inv.data(), k);
    tables.emplace_back(size_t(k) * size_t(m) * 32);
    ec_init_tables(k, m, inv.data(), tables.back().data());  // rows 0..m-1: the lost data shards
    present.push_back(std::move(shards));
  }
  std::vector<uint8_t*> o;
  for (auto& v : out) o.push_back(v.data());
  const auto start = Clock::now();
  for (auto _ : state)
    for (int b = 0; b < c.layout.blocks; ++b) {
      ec_encode_data(int(c.shard), int(present[size_t(b)].size()), m, tables[size_t(b)].data(),
                     const_cast<uint8_t**>(present[size_t(b)].data()), o.data());
      benchmark::ClobberMemory();
    }
  g_isal_decode_s = std::chrono::duration<double>(Clock::now() - start).count() / double(state.iterations());
  finish(state, kPassBytes, start);
  check_rebuilt(state, c, out);
}
BENCHMARK(BM_FecDecodeIsal);

void BM_FecDecode(benchmark::State& state) {
  FecCase c;
  const int m = c.layout.per_block;
  std::vector<std::vector<const uint8_t*>> present;
  std::vector<int> rows, missing;
  for (int b = 0; b < c.layout.blocks; ++b) {
    auto d = c.block_data(b);
    auto p = c.block_parity(b);
    rs_encode(int(d.size()), m, c.shard, d.data(), p.data());
    std::vector<const uint8_t*> shards;
    for (int r = m; r < int(d.size()); ++r) shards.push_back(d[size_t(r)]);
    for (int j = 0; j < m; ++j) shards.push_back(p[size_t(j)]);
    present.push_back(std::move(shards));
  }
  std::vector<std::vector<uint8_t>> out(size_t(m), std::vector<uint8_t>(c.shard));
  std::vector<uint8_t*> o;
  for (auto& v : out) o.push_back(v.data());
  for (int j = 0; j < m; ++j) missing.push_back(j);
  const auto start = Clock::now();
  for (auto _ : state)
    for (int b = 0; b < c.layout.blocks; ++b) {
      const int k = c.layout.block_data(b);
      rows.clear();
      for (int r = m; r < k; ++r) rows.push_back(r);
      for (int j = 0; j < m; ++j) rows.push_back(k + j);
      if (!rs_decode(k, m, c.shard, rows, present[size_t(b)].data(), missing, o.data()))
        state.SkipWithError("rs_decode");
      benchmark::ClobberMemory();
    }
  const double s = std::chrono::duration<double>(Clock::now() - start).count() / double(state.iterations());
  finish(state, kPassBytes, start);
  if (g_isal_decode_s > 0) state.counters["of_isal"] = g_isal_decode_s / s;
  check_rebuilt(state, c, out);
}
BENCHMARK(BM_FecDecode);

// The adaptive bitrate controller's work per server frame of a hybrid stream (two passes sent,
// two reported, one update), against the frame's CRC-32C of its smallest pass (1 KB): the
// controller must cost nothing beside the packet layer. "of_crc_1kb" = its time over the CRC's.
void BM_RateControllerPerFrame(benchmark::State& state) {
  const std::vector<uint8_t> kb(1024, 7);
  const auto crc_start = Clock::now();
  constexpr int kCrcs = 100000;
  uint32_t sink = 0;
  for (int i = 0; i < kCrcs; ++i) sink += crc32c(kb, uint32_t(i));
  benchmark::DoNotOptimize(sink);
  const double crc_s = std::chrono::duration<double>(Clock::now() - crc_start).count() / kCrcs;
  RateController c(RateControlSettings{});
  uint32_t f = 0;
  uint64_t received = 0;
  const auto start = Clock::now();
  for (auto _ : state) {
    const double t = f * 16.7;
    for (int pass = 0; pass < 2; ++pass) c.on_sent(f, pass, 6000, t);
    for (int pass = 0; pass < 2; ++pass) c.on_report({f, pass, false, t + 20.0 + (f % 7)});
    received += 10;
    c.on_counts(received, 0);
    benchmark::DoNotOptimize(c.update(t));
    ++f;
  }
  const double s = std::chrono::duration<double>(Clock::now() - start).count() / double(state.iterations());
  state.counters["of_crc_1kb"] = s / crc_s;
  state.counters["ns_per_frame"] = s * 1e9;
}
BENCHMARK(BM_RateControllerPerFrame);

}  // namespace
}  // namespace dhr

BENCHMARK_MAIN();
