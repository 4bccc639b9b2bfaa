// Speed of the packet layer: CRC-32C (hardware and portable), packetize, and the assembler
// reassembling a 1 MB pass whose packets arrive in reverse order. Each case reports bytes/s and, as "of_memcpy", its rate
// as a fraction of memcpy over the same bytes measured in the same run (the ceiling: the
// packet layer copies every byte at least once on each side).
//   build-packet/tests/bench_packets --benchmark_min_time=0.2
#include "core/assembler.h"
#include "core/checksum.h"
#include "core/packet.h"
#include "core/rng.h"

#include <benchmark/benchmark.h>

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

}  // namespace
}  // namespace dhr

BENCHMARK_MAIN();
