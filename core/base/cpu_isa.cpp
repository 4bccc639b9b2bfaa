// The run-time ISA and its cap (core/base/cpu_isa.h).
#include "core/base/cpu_isa.h"

#include "core/base/error.h"

#include <algorithm>
#include <array>
#include <cstdlib>
#include <string>

namespace dhr {

namespace {
constexpr std::array<const char*, 5> kNames = {"sse2", "sse4.2", "avx", "avx2", "avx512"};
constexpr const char* kCapVariable = "DHR_MAX_ISA";

// The CPU's best, each ISA needing the ones before it (what Embree tests for, in short).
Isa cpu_isa() {
  if (!(__builtin_cpu_supports("sse4.2") && __builtin_cpu_supports("popcnt"))) return Isa::kSse2;
  if (!__builtin_cpu_supports("avx")) return Isa::kSse42;
  if (!(__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && __builtin_cpu_supports("bmi") &&
        __builtin_cpu_supports("bmi2")))
    return Isa::kAvx;
  if (!(__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512cd") && __builtin_cpu_supports("avx512dq") &&
        __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl")))
    return Isa::kAvx2;
  return Isa::kAvx512;
}

// The CPU's best capped by `cap`, a value of $DHR_MAX_ISA (empty: no cap).
Isa capped(const std::string& cap) {
  static const Isa cpu = cpu_isa();
  if (cap.empty()) return cpu;
  for (size_t i = 0; i < kNames.size(); ++i)
    if (cap == kNames[i]) return std::min(cpu, Isa(i));
  fail(
      "{} = \"{}\": not an instruction set dhrbench knows (valid: sse2, sse4.2, avx, avx2, avx512; unset "
      "for the best this CPU has)",
      kCapVariable, cap);
}

std::string cap_now() {
  const char* env = std::getenv(kCapVariable);
  return env ? env : "";
}

// $DHR_MAX_ISA as the process started: read before main (below), so that code which sets the
// variable later (a test's ScopedEnv, to cap Embree) cannot fix the kernels' cap by happening
// to make the first call.
const std::string& cap_at_start() {
  static const std::string cap = cap_now();
  return cap;
}
[[maybe_unused]] const std::string& g_cap_read_before_main = cap_at_start();
}  // namespace

const char* isa_name(Isa isa) { return kNames[size_t(isa)]; }

Isa usable_isa() { return capped(cap_now()); }

bool isa_capped() { return !cap_now().empty(); }

bool kernels_may_use(Isa isa) {
  static const Isa cap = capped(cap_at_start());
  return isa <= cap;
}

}  // namespace dhr
