// References for quality measurements (docs/architecture.md, "The references"):
// - the ground truth: the composite (core/pass/composite.h) with converged estimates -- many AO
//   rays, many soft-shadow samples per area light, no denoiser -- at the client's G-buffer;
//   cached on disk, so sweeps never pay for the same reference twice;
// - the local reference: the same composite with the run's own trace settings at the client's
//   exact camera, with no network in between (what a PC with ray-tracing hardware shows).
//
// Cache: <cache_dir>/reference/<key>.png plus <key>.json describing the inputs. The key hashes
// the scene's content (every mesh, material, texture, light, animation, the ambient and AO
// settings, plus the bytes of the scene file when it can be read), the camera, the time, the
// resolution, the G-buffer's contents (so a different rasterizer gives a different key), the
// reference settings, the tracer (Embree's version and ISA: a cache folder shared by machines of
// two CPU kinds keeps one entry per kind) and kReferenceVersion (bumped whenever the estimator
// changes). The cache
// folder defaults to $DHR_CACHE_DIR, else <repo>/cache/.
#pragma once

#include "core/buffers/gbuffer.h"
#include "core/buffers/image.h"
#include "core/pass/composite.h"
#include "core/scene/scene.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"

#include <cstdint>
#include <string>

namespace dhr {

// 2: ray origins on triangles large against the hit point move off the plane by the triangle's
// own error (core/trace/trace.h), so converged estimates changed on such triangles. 3: scenes with
// moving objects are traced in Embree's two-level layout (RtSceneOptions::static_child), which
// answers a few rays on shared edges differently.
constexpr int kReferenceVersion = 3;

// The ray counts (ReferenceRays, core/trace/trace.h: what each pass's converged estimate reads) and
// the rest of the ground truth's settings.
struct ReferenceSettings : ReferenceRays {
  uint64_t seed = 0x6a09e667f3bcc908ull;
  CompositeSettings composite;
  std::string cache_dir;  // empty: default_cache_dir()
  bool use_cache = true;  // false: always compute, never read or write the cache
};

// $DHR_CACHE_DIR when set and not empty, else DHR_SOURCE_DIR "/cache".
std::string default_cache_dir();

// 64-bit content hash of a scene (see the header comment).
uint64_t scene_content_hash(const Scene& scene);
// The cache key (16 hex digits) of a ground truth traced by `tracer` (RtScene::tracer(): Embree's
// version and ISA, which can decide a ray on an edge).
std::string reference_key(const Scene& scene, const GBuffer& gbuf, const ReferenceSettings& settings,
                          const std::string& tracer);

struct ReferenceResult {
  ImageRGB8 image;
  bool from_cache = false;
  std::string key;
  std::string path;  // the cache file ("" when the cache is off)
  TraceStats stats;  // rays traced (zero when read from the cache)
};

// The ground truth for `gbuf` (rt moves to gbuf.time_s). Throws dhr::Error for bad settings
// or when the cache folder cannot be written.
ReferenceResult ground_truth(RtScene& rt, const GBuffer& gbuf, const ReferenceSettings& settings);

// The local reference: trace_passes with `settings` and the composite, no network.
ImageRGB8 local_reference(RtScene& rt, const GBuffer& gbuf, const TraceSettings& settings,
                          const CompositeSettings& composite_settings = {}, TraceStats* stats = nullptr);

}  // namespace dhr
