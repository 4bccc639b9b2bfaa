// What a trace is asked for and what it counted: the settings of the server's ray-traced passes,
// the plan derived from them and the scene (plan_passes), the statistics of a trace and the
// ground truth's ray counts. Plain data and the planning (core/plan/trace_plan.cpp); the kernels
// that use them are in core/trace/trace.h, and nothing here sees the ray tracer.
#pragma once

#include "core/buffers/pass_buffer.h"
#include "core/scene/scene.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dhr {

struct TraceSettings {
  uint64_t seed = 1;
  uint32_t frame = 0;
  int ao_rays = 0;           // 1..255 rays per pixel; 0 = the scene's ao.rays
  float ao_radius_m = 0.0f;  // > 0; 0 = the scene's ao.radius_m
  bool soft_shadows = true;  // false: one ray to each light's centre (hard) even for area lights
  // Rays per area light per pixel (soft shadows only). 1: one jittered ray, one bit per light
  // (Visibility pass, the paper's bitmask). 2..1024: the visible fraction per light in 8 bits
  // (SoftVisibility pass, full_scale = S, or 255 when S > 255).
  int samples_per_light = 1;
  // How the visibility pass is sent with one ray per light: false, a bitmask (the paper's, one bit
  // per light); true, 8 bits per light (the SoftVisibility pass, full_scale 1), which a denoiser
  // can smooth into a soft fraction and a lossy video codec can code. With S > 1 rays per light
  // the pass is a fraction either way.
  bool visibility_fraction = false;
  int threads = 0;  // 0 = the RtScene's arena; else a dedicated arena of this size
  // Tests: split the image into blocks of exactly this many rows (TBB's simple_partitioner)
  // instead of TBB's own blocks, whose bounds depend on the threads' timing. The counts must not
  // depend on it (tests/core/trace/test_trace_bits.cpp: TraceBits.CountsDoNotDependOnRowBlocks).
  int rows_per_block = 0;
  // The vector kernels where the CPU has them: with AVX-512, the AO pass's ray generator and the
  // visibility pass's stages; with AVX2 only, the AO pass's ray generator and the visibility
  // pass's surfaces, packets and cone loops. They give the same rays and results bit for bit; false forces the baseline kernels (tests compare the
  // two: tests/core/trace/test_trace.cpp, tests/core/trace/test_trace_bits.cpp).
  bool wide_kernels = true;
  // A run may switch a pass off (the paper's Table 2 adds the passes one at a time); it can
  // never switch on a pass the scene does not call for.
  bool visibility_pass = true;
  bool ao_pass = true;
  // The AO pass at 1/ao_scale of the width and height (1..kMaxPassScale): traced on the
  // G-buffer's sampled pixels and upsampled by the client (core/buffers/upsample.h).
  int ao_scale = 1;
  // Where a pixel takes S > 1 samples (AO rays, rays per area light): the samples on a lattice
  // with the pixel's own random shift (lattice_uniform below) instead of independent uniforms.
  // Set by the ground truth's converged estimates only (ReferenceRays::lattice); every kernel
  // gives the same bits, as with independent uniforms.
  bool lattice = false;
};

enum class ShadowMode : uint8_t {
  None,          // no visibility pass
  Hard,          // one ray to each light's centre: bitmask
  SoftBit,       // one ray per light, jittered within the light's cone: bitmask
  SoftFraction,  // S rays per light: 8-bit fraction per light
};
const char* shadow_mode_name(ShadowMode mode);

struct PassPlan {
  ShadowMode shadow = ShadowMode::None;
  int lights = 0;
  int samples_per_light = 0;        // S for SoftFraction, 1 for Hard / SoftBit, 0 for None
  std::vector<uint8_t> light_soft;  // per light: 1 = cone sampling, 0 = one ray to the centre
  bool ao = false;
  int ao_rays = 0;
  float ao_radius_m = 0.0f;
  int ao_scale = 1;                  // the AO pass is traced at 1/ao_scale of the image's width and height
  std::vector<std::string> reasons;  // why each pass runs or not (one line each)

  bool visibility() const { return shadow != ShadowMode::None; }
  PassKind visibility_kind() const {
    return shadow == ShadowMode::SoftFraction ? PassKind::SoftVisibility : PassKind::Visibility;
  }
  int visibility_full_scale() const;  // SoftFraction: min(S, 255); else 1
  PassDesc visibility_desc(int width, int height) const;
  PassDesc ao_desc(int width, int height) const;  // at 1/ao_scale of width x height
  std::string describe() const;                   // the reasons, joined
};

// Throws dhr::Error for out-of-range settings (naming the key and the valid range) and for
// scenes with more than 64 lights.
PassPlan plan_passes(const Scene& scene, const TraceSettings& settings);

struct TraceStats {
  uint64_t pixels = 0;                 // in the G-buffer
  uint64_t covered_pixels = 0;         // not background
  uint64_t shadow_rays = 0;            // traced (handed to Embree)
  uint64_t ao_rays = 0;                // traced
  uint64_t invalid_rays = 0;           // failed validation: counted, never traced
  uint64_t unresolved_pixels = 0;      // object/prim id not in the scene: G-buffer position used
  uint64_t shadow_skipped_facing = 0;  // (pixel, light) pairs: surface faces away, no ray
  uint64_t shadow_skipped_range = 0;   // (pixel, light) pairs beyond range_m, no ray
  uint64_t shadow_inside_light = 0;    // (pixel, light) pairs inside the light's sphere, no ray
  void add(const TraceStats& o);
};

// The ground truth's ray counts (part of ReferenceSettings, core/pass/reference.h). A pass whose
// converged estimate needs a count of its own adds it here.
struct ReferenceRays {
  int ao_rays = 512;            // 1..65535 AO rays per pixel (radius: the scene's ao block)
  int samples_per_light = 256;  // 1..65535 rays per area light per pixel (point lights: 1)
  // true: a shifted lattice of samples per pixel and light (TraceSettings::lattice), unbiased
  // and converging faster than independent uniforms (false) per ray (docs/architecture.md,
  // "The references").
  bool lattice = true;
};
// ReferenceRays::lattice by name, as the run setting ground_truth_sampling and the commands'
// --sampling options spell it: "lattice" or "random".
inline const char* sampling_name(bool lattice) { return lattice ? "lattice" : "random"; }
inline bool is_lattice(const std::string& name) { return name == sampling_name(true); }
// Both names, the valid values of the setting and of the options.
inline std::vector<std::string> sampling_names() { return {sampling_name(false), sampling_name(true)}; }

}  // namespace dhr
