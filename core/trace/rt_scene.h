// The server's ray-tracing scene: an Embree 3 device and scene built from a dhr::Scene.
//
// Layout. Static objects are triangle geometries in world space. Each moving object keeps its
// mesh in object space in a child scene that is instanced into the top-level scene; set_time()
// updates the instance transforms and recommits only the (small) top level. When the scene has
// moving objects, the static geometries live in a child scene too (one identity instance), so
// that a recommit never rebuilds the static BVH.
//
// Robustness. Debian's Embree asserts (aborts) on rays with non-finite or huge values and may
// misbehave on such triangles, so the build skips -- and counts -- triangles with a non-finite
// vertex, a vertex coordinate with |c| >= 1e18 (kMaxCoordinate), a zero-area (degenerate)
// triangle or an index out of range. Embree primitive ids then differ from mesh triangle
// indices; hit_object()/hit_triangle() map them back.
//
// Emitter geometry (Material::emitter) carries geometry mask kMaskEmitter only, and shadow rays
// use mask kMaskShadow, so emitters never occlude shadow rays (the light's proxy surface would
// otherwise shadow its own light). Emitters still occlude AO rays and primary rays. The scene
// model cannot say which light an emitter belongs to, so an emitter casts no shadow on any
// light: documented simplification.
//
// Alpha cut-out (Material::alpha_cutout with a texture that has alpha and per-vertex uvs):
// intersection and occlusion filter functions reject hits where the texel's alpha is below the
// material's threshold, for every kind of ray.
#pragma once

#include "core/buffers/camera.h"
#include "core/buffers/gbuffer.h"
#include "core/scene/scene.h"

#include <glm/glm.hpp>
#include <tbb/task_arena.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

// Embree's handle types, declared as <embree3/rtcore.h> declares them, so that this header
// does not bring Embree to its readers: only the trace layer's sources include Embree
// (docs/architecture.md, "Layers").
typedef struct RTCDeviceTy* RTCDevice;
typedef struct RTCSceneTy* RTCScene;
typedef struct RTCGeometryTy* RTCGeometry;

namespace dhr {

// Triangles with any vertex coordinate at or beyond this magnitude are skipped; rays with an
// origin component at or beyond it are invalid (Embree 3.13 asserts at |origin| >= 1.844e18).
constexpr float kMaxCoordinate = 1e18f;

// Ray/geometry masks. A ray hits a geometry when (ray.mask & geometry.mask) != 0.
constexpr unsigned kMaskOccluder = 1u;  // ordinary geometry: everything may hit it
constexpr unsigned kMaskEmitter = 2u;   // emitter geometry: camera and AO rays only
constexpr unsigned kMaskShadow = kMaskOccluder;
constexpr unsigned kMaskAll = kMaskOccluder | kMaskEmitter;

// The BVH build quality of Embree's static and object-space trees (RTC_BUILD_QUALITY_*).
enum class RtBuildQuality { low, medium, high };

struct RtSceneOptions {
  int threads = 0;  // Embree's build threads and the TBB arena used for tracing; 0 = all cores
  // RTC_SCENE_FLAG_ROBUST: watertight traversal (no rays slipping through shared edges) at a
  // cost in speed. Default off: bench_trace measures the cost (see the report of this module)
  // and the ray origin offset (core/trace/trace.h) already removes self-intersection.
  bool robust = false;
  RtBuildQuality quality = RtBuildQuality::high;  // static and object-space BVHs (built once)
  // The layout of a scene with moving objects. By default every static geometry is attached to
  // the top level beside the moving objects' instances, and the top level is built at
  // RTC_BUILD_QUALITY_LOW: Embree then builds two levels, one BVH per geometry at `quality` and
  // one over the geometries and instances, and a set_time() rebuilds only the upper one.
  // static_child = true is the layout before that (for measurement: bench_trace's scene_layout
  // rows): all static geometry in one child scene built at `quality`, instanced once. The
  // two-level layout traced the built-in scenes with moving objects in 0.74-0.91x the time of
  // this one, and answers a few rays on shared edges differently (docs/performance.md,
  // "Embree's two-level layout").
  // A scene without moving objects has one level, built at `quality`, either way.
  bool static_child = false;
};

// The kernels Embree traverses with: "avx512", "avx2", "avx", "sse4.2" or "sse2", the best this
// CPU has, capped by $DHR_MAX_ISA when it is set (core/base/cpu_isa.h; passed as Embree's max_isa).
// Kernels of two ISAs can answer a ray that grazes an edge differently (their reciprocal and
// FMA roundings differ), so the ISA is part of a result's identity: the disk caches' keys and
// results.json's context record it, and the cap lets one machine reproduce another's bits (an
// AVX-512 machine with DHR_MAX_ISA=avx2 traces as an AVX2 one of the same CPU generation does:
// tests/core/trace/test_trace_bits.cpp checks every ISA's table on every machine). Throws dhr::Error naming
// the variable when it holds anything else.
std::string embree_isa();
// The version of the Embree library loaded, "3.13.5" (read once, from a device of its own).
const std::string& embree_version();
// 8 hex digits: a hash of the CPU's rcpps (SSE's approximate reciprocal) over every one of its
// table's mantissas. Embree's kernels before AVX-512 start their divisions from rcpps, whose
// bits differ between vendors and between one vendor's generations (AMD's Zen 4 and Zen 5 trace
// every scene of tests/core/trace/test_trace_bits.cpp differently with DHR_MAX_ISA=avx2); AVX-512's
// rcp14ps agrees on both.
const std::string& cpu_rcp_signature();
// "embree <embree_version()> <embree_isa()>", with " rcp:<cpu_rcp_signature()>" below
// AVX-512: what decides the answer of a ray besides the scene and the ray (the disk caches' keys
// read it; RtScene::tracer()).
std::string embree_tracer();

struct RtBuildStats {
  size_t triangles_total = 0;  // in the scene
  size_t triangles_built = 0;  // handed to Embree
  size_t skipped_nonfinite = 0;
  size_t skipped_huge = 0;        // a coordinate with |c| >= kMaxCoordinate
  size_t skipped_degenerate = 0;  // zero area
  size_t skipped_bad_index = 0;   // a vertex index out of range
  size_t skipped() const { return skipped_nonfinite + skipped_huge + skipped_degenerate + skipped_bad_index; }
};

// What a geometry (or, for alpha filters, its hit) refers to. Geometry user data.
struct RtGeometryInfo {
  uint32_t object_index = 0;               // into Scene::objects
  std::vector<uint32_t> prim_to_triangle;  // Embree primID -> mesh triangle index
  const Material* material = nullptr;
  const Texture* cutout_texture = nullptr;  // set when the alpha filter is installed
  const Mesh* mesh = nullptr;
};

// The ray validation done before every rtcIntersect/rtcOccluded call (Embree 3.13 in Debian
// asserts on anything else): finite origin and direction, every origin component below
// kMaxCoordinate in magnitude, a non-zero direction, 0 <= tnear <= tfar (tfar may be +inf).
inline bool ray_is_valid(const glm::vec3& origin, const glm::vec3& direction, float tnear, float tfar) {
  for (int i = 0; i < 3; ++i) {
    // !(|x| < max) also rejects NaN.
    if (!(std::abs(origin[i]) < kMaxCoordinate)) return false;
    if (!std::isfinite(direction[i])) return false;
  }
  if (direction.x == 0.0f && direction.y == 0.0f && direction.z == 0.0f) return false;
  return tnear >= 0.0f && tnear <= tfar;  // false for NaN
}

// Statistics of one primary_gbuffer() call.
struct PrimaryStats {
  uint64_t rays = 0;
  uint64_t invalid_rays = 0;
  uint64_t hits = 0;
};

class RtScene {
 public:
  // The scene is referenced, not copied: it must outlive the RtScene and stay unchanged.
  // Throws dhr::Error when the scene has a material or texture index out of range, an
  // inconsistent texture, an object id of 0, more than 64 lights, or when Embree fails (the
  // message carries Embree's). Note: Debian's Embree (TBB tasking) applies "threads=N"
  // through ONE process-wide tbb::global_control that the newest device replaces: it caps
  // every TBB loop of the process, not only Embree's. options.threads = 0 passes all cores
  // (no cap). Results never depend on it.
  explicit RtScene(const Scene& scene, const RtSceneOptions& options = {});
  ~RtScene();
  RtScene(const RtScene&) = delete;
  RtScene& operator=(const RtScene&) = delete;

  // Places moving objects at `time_s` and recommits (no-op when nothing moves or the time is
  // unchanged).
  void set_time(double time_s);
  double time() const { return time_s_; }

  RTCScene handle() const { return top_; }
  RTCDevice device() const { return device_; }
  // embree_tracer() of this scene's device (the ground truth's cache key reads it).
  const std::string& tracer() const { return tracer_; }
  const Scene& scene() const { return scene_; }
  const RtSceneOptions& options() const { return options_; }
  const RtBuildStats& build_stats() const { return build_stats_; }
  int threads() const { return threads_; }
  // The arena every parallel loop over this scene runs in (honours options.threads).
  tbb::task_arena& arena() const { return *arena_; }

  // Object index (into Scene::objects) for an Object::id; -1 when unknown.
  int object_index(uint32_t object_id) const;
  // World-space vertices of triangle `triangle` of object `object_index` at the current time.
  // False when the indices are out of range or the triangle was skipped at build.
  bool triangle_world(int object_index, uint32_t triangle, glm::vec3 v[3]) const;
  // Same, in double precision (vertices transformed in double for moving objects).
  bool triangle_world(int object_index, uint32_t triangle, glm::dvec3 v[3]) const;
  const glm::mat4& world_from_object(int object_index) const { return world_from_object_[size_t(object_index)]; }

  // Maps an Embree hit (geomID, instID[0], primID) to (object index, mesh triangle index).
  // False for an unknown geometry.
  bool resolve_hit(unsigned geom_id, unsigned inst_id, unsigned prim_id, int& object_index, uint32_t& triangle) const;

  // The G-buffer from Embree primary rays through pixel centres (core/buffers/gbuffer.h), for
  // cross-checking the rasterizer. Moves the scene to `time_s`. Rays span the camera's
  // near..far planes (view depth), like the rasterizer's clip volume. Motion is left zero.
  GBuffer primary_gbuffer(const Camera& camera, double time_s, PrimaryStats* stats = nullptr);

 private:
  void build();
  RTCGeometry make_triangle_geometry(uint32_t object_index);

  const Scene& scene_;
  RtSceneOptions options_;
  int threads_ = 1;
  std::unique_ptr<tbb::task_arena> arena_;
  RTCDevice device_ = nullptr;
  RTCScene top_ = nullptr;
  RTCScene static_child_ = nullptr;        // static geometry when the scene has moving objects
  std::vector<RTCScene> moving_children_;  // one per moving object
  std::vector<RTCGeometry> instances_;     // one per moving object (top-level geometries)
  std::vector<uint32_t> moving_objects_;   // object index per moving child
  // Lookup: top-level geomID -> info for static geometry in the top scene; child scenes keep
  // their own ids. Instance geomID -> moving slot.
  std::vector<std::unique_ptr<RtGeometryInfo>> infos_;
  std::vector<const RtGeometryInfo*> top_geom_info_;      // by top-level geomID (null: instance)
  std::vector<int> top_geom_moving_slot_;                 // by top-level geomID (-1: not a moving instance)
  std::vector<const RtGeometryInfo*> static_child_info_;  // by geomID in static_child_
  std::vector<const RtGeometryInfo*> moving_child_info_;  // by moving slot (geomID 0 in its child)
  unsigned static_instance_geom_ = ~0u;                   // RTC_INVALID_GEOMETRY_ID: no static instance
  std::vector<glm::mat4> world_from_object_;              // per object, at time_s_
  std::vector<std::vector<uint8_t>> skipped_;             // per object: triangle skipped at build
  std::vector<int> id_to_index_;                          // Object::id -> index (dense up to max id)
  RtBuildStats build_stats_;
  std::string last_error_;  // first error Embree reported (see embree_error)
  std::string tracer_;
  double time_s_ = 0.0;
  bool time_set_ = false;
};

}  // namespace dhr
