// Deterministic random numbers: a counter-based hash of (seed, pixel, frame, sample, stream,
// dimension). No state is shared between threads, so a result never depends on the thread
// count or on scheduling. The mixer is the SplitMix64 finalizer (Steele et al. 2014), applied
// once per key word so that neighbouring keys give uncorrelated outputs.
#pragma once

#include <cstdint>

namespace dhr {

// Streams keep independent uses of randomness apart (AO rays, light l's shadow rays, ...).
enum RngStream : uint32_t {
  kStreamAo = 1,
  kStreamNetwork = 2,
  kStreamLightBase = 1024,  // light l uses kStreamLightBase + l
};

constexpr uint64_t mix64(uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

struct RngKey {
  uint64_t seed = 0;
  uint32_t pixel = 0;
  uint32_t frame = 0;
  uint32_t sample = 0;
  uint32_t stream = 0;
};

constexpr uint64_t rng_bits(const RngKey& k, uint32_t dimension = 0) {
  uint64_t h = mix64(k.seed);
  h = mix64(h ^ ((uint64_t(k.pixel) << 32) | k.frame));
  h = mix64(h ^ ((uint64_t(k.sample) << 32) | k.stream));
  return mix64(h ^ dimension);
}

// Uniform in [0, 1), 24 bits of resolution (exactly representable as float).
constexpr float rng_uniform(const RngKey& k, uint32_t dimension = 0) {
  return float(rng_bits(k, dimension) >> 40) * (1.0f / 16777216.0f);
}

// Uniform in [0, 1), 53 bits of resolution.
constexpr double rng_uniform_double(const RngKey& k, uint32_t dimension = 0) {
  return double(rng_bits(k, dimension) >> 11) * (1.0 / 9007199254740992.0);
}

}  // namespace dhr
