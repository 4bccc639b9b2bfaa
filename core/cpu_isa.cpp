// The run-time ISA and its cap (core/cpu_isa.h).
#include "core/cpu_isa.h"

#include "core/error.h"

#include <algorithm>
#include <array>
#include <cstdlib>
#include <string>

namespace dhr {

namespace {
constexpr std::array<const char*, 5> kNames = {"sse2", "sse4.2", "avx", "avx2", "avx512"};

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
}  // namespace

const char* isa_name(Isa isa) { return kNames[size_t(isa)]; }

Isa usable_isa() {
  static const Isa cpu = cpu_isa();
  const char* env = std::getenv("DHR_MAX_ISA");
  if (!env || !*env) return cpu;
  const std::string want = env;
  for (size_t i = 0; i < kNames.size(); ++i)
    if (want == kNames[i]) return std::min(cpu, Isa(i));
  fail("DHR_MAX_ISA = \"{}\": not an instruction set dhrbench knows (valid: sse2, sse4.2, avx, avx2, avx512; unset "
       "for the best this CPU has)",
       want);
}

bool kernels_may_use(Isa isa) {
  static const Isa cap = usable_isa();
  return isa <= cap;
}

}  // namespace dhr
