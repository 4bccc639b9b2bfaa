// Embree 3 scene construction, per-time instance updates and primary-ray G-buffers.
// See core/trace/rt_scene.h for the layout and the robustness rules.
#include "core/trace/rt_scene.h"

#include "core/base/cpu_isa.h"
#include "core/base/error.h"

#include <embree3/rtcore.h>

#include <fmt/format.h>
#include <immintrin.h>
#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>

namespace dhr {

namespace {

RTCBuildQuality embree_quality(RtBuildQuality q) {
  switch (q) {
    case RtBuildQuality::low: return RTC_BUILD_QUALITY_LOW;
    case RtBuildQuality::medium: return RTC_BUILD_QUALITY_MEDIUM;
    case RtBuildQuality::high: return RTC_BUILD_QUALITY_HIGH;
  }
  return RTC_BUILD_QUALITY_HIGH;
}

void embree_error(void* user, RTCError code, const char* message) {
  // Embree reports errors through this callback; keep the first one so the next check can
  // throw it with context (throwing through Embree's C frames is not allowed).
  auto* last = static_cast<std::string*>(user);
  if (last->empty()) last->assign(fmt::format("Embree error {}: {}", int(code), message ? message : ""));
}

bool finite_and_small(const glm::vec3& v, bool& huge) {
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(v[i])) return false;
    if (std::abs(v[i]) >= kMaxCoordinate) huge = true;
  }
  return true;
}

// The alpha cut-out filter (intersection and occlusion): a hit on a texel whose alpha is below
// the material's threshold is no hit. Embree calls it with N rays at once (streams, packets).
void alpha_cutout_filter(const RTCFilterFunctionNArguments* args) {
  const auto* info = static_cast<const RtGeometryInfo*>(args->geometryUserPtr);
  const Mesh& mesh = *info->mesh;
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] == 0) continue;
    const unsigned prim = RTCHitN_primID(args->hit, args->N, i);
    if (prim >= info->prim_to_triangle.size()) continue;
    const glm::uvec3 tri = mesh.triangles[info->prim_to_triangle[prim]];
    const float u = RTCHitN_u(args->hit, args->N, i);
    const float v = RTCHitN_v(args->hit, args->N, i);
    const glm::vec2 uv = (1.0f - u - v) * mesh.uvs[tri.x] + u * mesh.uvs[tri.y] + v * mesh.uvs[tri.z];
    if (info->cutout_texture->sample_bilinear(uv).w < info->material->alpha_threshold) args->valid[i] = 0;
  }
}

std::string tracer_name(const std::string& isa) {
  if (isa == "avx512") return fmt::format("embree {} {}", embree_version(), isa);
  return fmt::format("embree {} {} rcp:{}", embree_version(), isa, cpu_rcp_signature());
}

}  // namespace

const std::string& embree_version() {
  static const std::string version = [] {
    RTCDevice device = rtcNewDevice("verbose=0");
    if (!device) fail("rt_scene: rtcNewDevice(\"verbose=0\") failed (error {})", int(rtcGetDeviceError(nullptr)));
    const ssize_t v = rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_VERSION);
    rtcReleaseDevice(device);
    return fmt::format("{}.{}.{}", v / 10000, (v / 100) % 100, v % 100);
  }();
  return version;
}

const std::string& cpu_rcp_signature() {
  static const std::string signature = [] {
    // rcpps reads the top 12 bits of the mantissa (and the exponent, which only scales the
    // result): 1 + i/4096 for every i covers its table, the half steps its interpolation.
    uint32_t h = 2166136261u;  // FNV-1a
    for (int i = 0; i < 8192; ++i) {
      const float x = 1.0f + float(i) / 8192.0f;
      const float r = _mm_cvtss_f32(_mm_rcp_ss(_mm_set_ss(x)));
      uint32_t bits = 0;
      std::memcpy(&bits, &r, sizeof bits);
      for (int b = 0; b < 4; ++b) h = (h ^ ((bits >> (8 * b)) & 0xffu)) * 16777619u;
    }
    return fmt::format("{:08x}", h);
  }();
  return signature;
}

std::string embree_tracer() { return tracer_name(embree_isa()); }

std::string embree_isa() { return isa_name(usable_isa()); }

RtScene::RtScene(const Scene& scene, const RtSceneOptions& options) : scene_(scene), options_(options) {
  if (options.threads < 0) fail("rt_scene: threads {} must be >= 0 (0 = all cores)", options.threads);
  if (scene.lights.size() > 64)
    fail("rt_scene: scene '{}' has {} lights; at most 64 are supported", scene.name, scene.lights.size());
  threads_ = options.threads > 0 ? options.threads : std::max(1, tbb::info::default_concurrency());
  arena_ = std::make_unique<tbb::task_arena>(threads_);
  build();
}

RtScene::~RtScene() {
  if (top_) rtcReleaseScene(top_);
  if (static_child_) rtcReleaseScene(static_child_);
  for (RTCScene s : moving_children_) rtcReleaseScene(s);
  if (device_) rtcReleaseDevice(device_);
}

RTCGeometry RtScene::make_triangle_geometry(uint32_t object_index) {
  const Object& obj = scene_.objects[object_index];
  const Mesh& mesh = obj.mesh;
  auto& skipped = skipped_[object_index];
  skipped.assign(mesh.triangles.size(), 0);
  auto info = std::make_unique<RtGeometryInfo>();
  info->object_index = object_index;
  info->mesh = &mesh;
  info->material = &scene_.materials[obj.material];

  // Vertex validity once per vertex, then triangle validity.
  const size_t nv = mesh.positions.size();
  std::vector<uint8_t> vertex_state(nv, 0);  // 0 ok, 1 non-finite, 2 huge
  for (size_t i = 0; i < nv; ++i) {
    bool huge = false;
    if (!finite_and_small(mesh.positions[i], huge))
      vertex_state[i] = 1;
    else if (huge)
      vertex_state[i] = 2;
  }
  build_stats_.triangles_total += mesh.triangles.size();
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const glm::uvec3 tri = mesh.triangles[t];
    if (tri.x >= nv || tri.y >= nv || tri.z >= nv) {
      ++build_stats_.skipped_bad_index;
      skipped[t] = 1;
      continue;
    }
    const int state = std::max({vertex_state[tri.x], vertex_state[tri.y], vertex_state[tri.z]});
    if (state == 1) {
      ++build_stats_.skipped_nonfinite;
      skipped[t] = 1;
      continue;
    }
    if (state == 2) {
      ++build_stats_.skipped_huge;
      skipped[t] = 1;
      continue;
    }
    const glm::dvec3 a(mesh.positions[tri.x]), b(mesh.positions[tri.y]), c(mesh.positions[tri.z]);
    const glm::dvec3 cr = glm::cross(b - a, c - a);
    if (!(glm::dot(cr, cr) > 0.0)) {
      ++build_stats_.skipped_degenerate;
      skipped[t] = 1;
      continue;
    }
    info->prim_to_triangle.push_back(uint32_t(t));
  }
  if (info->prim_to_triangle.empty()) {
    infos_.push_back(std::move(info));
    return nullptr;
  }
  build_stats_.triangles_built += info->prim_to_triangle.size();

  RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vb = static_cast<float*>(
      rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), nv));
  auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                            3 * sizeof(unsigned), info->prim_to_triangle.size()));
  if (!vb || !ib) fail("rt_scene: Embree could not allocate buffers for object '{}': {}", obj.name, last_error_);
  for (size_t i = 0; i < nv; ++i) {
    // Vertices used only by skipped triangles are zeroed so no non-finite value reaches Embree.
    const glm::vec3 p = vertex_state[i] == 0 ? mesh.positions[i] : glm::vec3(0.0f);
    vb[3 * i + 0] = p.x;
    vb[3 * i + 1] = p.y;
    vb[3 * i + 2] = p.z;
  }
  for (size_t k = 0; k < info->prim_to_triangle.size(); ++k) {
    const glm::uvec3 tri = mesh.triangles[info->prim_to_triangle[k]];
    ib[3 * k + 0] = tri.x;
    ib[3 * k + 1] = tri.y;
    ib[3 * k + 2] = tri.z;
  }
  const Material& mat = *info->material;
  rtcSetGeometryMask(g, mat.emitter ? kMaskEmitter : kMaskAll);
  rtcSetGeometryBuildQuality(g, embree_quality(options_.quality));
  if (mat.alpha_cutout && mat.texture >= 0 && size_t(mat.texture) < scene_.textures.size() &&
      scene_.textures[size_t(mat.texture)].has_alpha && mesh.uvs.size() == nv) {
    info->cutout_texture = &scene_.textures[size_t(mat.texture)];
    rtcSetGeometryIntersectFilterFunction(g, alpha_cutout_filter);
    rtcSetGeometryOccludedFilterFunction(g, alpha_cutout_filter);
  }
  rtcSetGeometryUserData(g, info.get());
  rtcCommitGeometry(g);
  infos_.push_back(std::move(info));
  return g;
}

void RtScene::build() {
  last_error_.clear();
  const std::string isa = embree_isa();
  std::string config = fmt::format("threads={}", threads_);
  if (isa_capped()) config += fmt::format(",max_isa={}", isa);
  device_ = rtcNewDevice(config.c_str());
  if (!device_) fail("rt_scene: rtcNewDevice(\"{}\") failed (error {})", config, int(rtcGetDeviceError(nullptr)));
  rtcSetDeviceErrorFunction(device_, embree_error, &last_error_);
  tracer_ = tracer_name(isa);

  for (size_t i = 0; i < scene_.objects.size(); ++i) {
    const Object& o = scene_.objects[i];
    if (o.material >= scene_.materials.size())
      fail("rt_scene: object '{}' has material {} but the scene has {} materials", o.name, o.material,
           scene_.materials.size());
    if (o.id == kBackgroundId) fail("rt_scene: object '{}' has id 0 (reserved for the background)", o.name);
    if (o.id >= id_to_index_.size()) id_to_index_.resize(size_t(o.id) + 1, -1);
    id_to_index_[o.id] = int(i);
  }
  // Textures are sampled inside Embree's filter callbacks, where nothing may throw: check
  // them here.
  for (const Material& m : scene_.materials) {
    if (m.texture < 0) continue;
    if (size_t(m.texture) >= scene_.textures.size())
      fail("rt_scene: material '{}' has texture {} but the scene has {} textures", m.name, m.texture,
           scene_.textures.size());
    const Texture& t = scene_.textures[size_t(m.texture)];
    if (t.width <= 0 || t.height <= 0 || t.texels.size() != size_t(t.width) * size_t(t.height))
      fail("rt_scene: texture '{}' is empty or inconsistent ({}x{}, {} texels)", t.path, t.width, t.height,
           t.texels.size());
  }
  skipped_.resize(scene_.objects.size());
  world_from_object_.assign(scene_.objects.size(), glm::mat4(1.0f));

  const RTCSceneFlags flags = options_.robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE;
  top_ = rtcNewScene(device_);
  rtcSetSceneFlags(top_, flags);
  const bool has_moving = scene_.has_moving_objects();
  // With moving objects the top level is rebuilt on every set_time(): built at LOW quality,
  // Embree keeps a BVH per static geometry and rebuilds only the level above them and the
  // instances (RtSceneOptions::static_child: the older layout, one child scene for all static
  // geometry, built once and instanced).
  rtcSetSceneBuildQuality(top_, has_moving ? RTC_BUILD_QUALITY_LOW : embree_quality(options_.quality));
  const bool static_child = has_moving && options_.static_child;
  RTCScene static_target = top_;
  if (static_child) {
    static_child_ = rtcNewScene(device_);
    rtcSetSceneFlags(static_child_, flags);
    rtcSetSceneBuildQuality(static_child_, embree_quality(options_.quality));
    static_target = static_child_;
  }

  auto set_at = [](auto& vec, unsigned id, auto value, auto fill) {
    if (vec.size() <= id) vec.resize(size_t(id) + 1, fill);
    vec[id] = value;
  };
  size_t static_geometries = 0;
  for (uint32_t i = 0; i < scene_.objects.size(); ++i) {
    if (scene_.objects[i].moving()) continue;
    RTCGeometry g = make_triangle_geometry(i);
    if (!g) continue;
    const unsigned id = rtcAttachGeometry(static_target, g);
    rtcReleaseGeometry(g);
    ++static_geometries;
    if (static_child)
      set_at(static_child_info_, id, infos_.back().get(), (const RtGeometryInfo*)nullptr);
    else
      set_at(top_geom_info_, id, infos_.back().get(), (const RtGeometryInfo*)nullptr);
  }
  if (static_child && static_geometries > 0) {
    arena_->execute([&] { rtcCommitScene(static_child_); });
    RTCGeometry inst = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(inst, static_child_);
    rtcSetGeometryTimeStepCount(inst, 1);
    const glm::mat4 identity(1.0f);
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT4X4_COLUMN_MAJOR, &identity[0][0]);
    rtcCommitGeometry(inst);
    static_instance_geom_ = rtcAttachGeometry(top_, inst);
    rtcReleaseGeometry(inst);
  }
  for (uint32_t i = 0; i < scene_.objects.size(); ++i) {
    if (!scene_.objects[i].moving()) continue;
    RTCGeometry g = make_triangle_geometry(i);
    if (!g) continue;
    RTCScene child = rtcNewScene(device_);
    rtcSetSceneFlags(child, flags);
    rtcSetSceneBuildQuality(child, embree_quality(options_.quality));
    rtcAttachGeometryByID(child, g, 0);
    rtcReleaseGeometry(g);
    arena_->execute([&] { rtcCommitScene(child); });
    const int slot = int(moving_children_.size());
    moving_children_.push_back(child);
    moving_objects_.push_back(i);
    moving_child_info_.push_back(infos_.back().get());
    RTCGeometry inst = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(inst, child);
    rtcSetGeometryTimeStepCount(inst, 1);
    const unsigned id = rtcAttachGeometry(top_, inst);
    rtcReleaseGeometry(inst);
    instances_.push_back(inst);  // owned by top_; the handle stays valid while top_ lives
    set_at(top_geom_moving_slot_, id, slot, -1);
  }
  if (!last_error_.empty()) fail("rt_scene: building scene '{}' failed: {}", scene_.name, last_error_);
  set_time(0.0);
}

void RtScene::set_time(double time_s) {
  if (time_set_ && time_s == time_s_) return;
  if (!std::isfinite(time_s)) fail("rt_scene: time {} is not finite", time_s);
  const bool first = !time_set_;
  time_s_ = time_s;
  time_set_ = true;
  if (moving_objects_.empty() && !first) return;  // nothing moves: the committed scene stands
  for (size_t slot = 0; slot < moving_objects_.size(); ++slot) {
    const uint32_t oi = moving_objects_[slot];
    const glm::mat4 m = scene_.objects[oi].world_from_object(time_s);
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r)
        if (!std::isfinite(m[c][r]))
          fail("rt_scene: object '{}' has a non-finite transform at time {} s", scene_.objects[oi].name, time_s);
    world_from_object_[oi] = m;
    rtcSetGeometryTransform(instances_[slot], 0, RTC_FORMAT_FLOAT4X4_COLUMN_MAJOR, &m[0][0]);
    rtcCommitGeometry(instances_[slot]);
  }
  arena_->execute([&] { rtcCommitScene(top_); });
  if (!last_error_.empty())
    fail("rt_scene: committing scene '{}' at time {} s failed: {}", scene_.name, time_s, last_error_);
}

int RtScene::object_index(uint32_t object_id) const {
  return object_id < id_to_index_.size() ? id_to_index_[object_id] : -1;
}

bool RtScene::triangle_world(int oi, uint32_t triangle, glm::dvec3 v[3]) const {
  if (oi < 0 || size_t(oi) >= scene_.objects.size()) return false;
  const Object& o = scene_.objects[size_t(oi)];
  if (triangle >= o.mesh.triangles.size() || skipped_[size_t(oi)][triangle]) return false;
  const glm::uvec3 tri = o.mesh.triangles[triangle];
  if (!o.moving()) {
    v[0] = glm::dvec3(o.mesh.positions[tri.x]);
    v[1] = glm::dvec3(o.mesh.positions[tri.y]);
    v[2] = glm::dvec3(o.mesh.positions[tri.z]);
    return true;
  }
  const glm::dmat4 m(world_from_object_[size_t(oi)]);
  for (int k = 0; k < 3; ++k) v[k] = glm::dvec3(m * glm::dvec4(glm::dvec3(o.mesh.positions[tri[k]]), 1.0));
  return true;
}

bool RtScene::triangle_world(int oi, uint32_t triangle, glm::vec3 v[3]) const {
  glm::dvec3 d[3];
  if (!triangle_world(oi, triangle, d)) return false;
  for (int k = 0; k < 3; ++k) v[k] = glm::vec3(d[k]);
  return true;
}

bool RtScene::resolve_hit(unsigned geom_id, unsigned inst_id, unsigned prim_id, int& oi, uint32_t& triangle) const {
  const RtGeometryInfo* info = nullptr;
  if (inst_id == RTC_INVALID_GEOMETRY_ID) {
    if (geom_id < top_geom_info_.size()) info = top_geom_info_[geom_id];
  } else if (inst_id == static_instance_geom_) {
    if (geom_id < static_child_info_.size()) info = static_child_info_[geom_id];
  } else if (inst_id < top_geom_moving_slot_.size() && top_geom_moving_slot_[inst_id] >= 0) {
    info = moving_child_info_[size_t(top_geom_moving_slot_[inst_id])];
  }
  if (!info || prim_id >= info->prim_to_triangle.size()) return false;
  oi = int(info->object_index);
  triangle = info->prim_to_triangle[prim_id];
  return true;
}

GBuffer RtScene::primary_gbuffer(const Camera& camera, double time_s, PrimaryStats* stats) {
  set_time(time_s);
  GBuffer g;
  g.camera = camera;
  g.time_s = time_s;
  g.resize(camera.width, camera.height);
  const int w = camera.width, h = camera.height;
  std::atomic<uint64_t> rays{0}, invalid{0}, hits{0};
  const glm::vec3 right = camera.right();
  const float tan_half = std::tan(glm::radians(camera.vfov_deg) * 0.5f);
  arena_->execute([&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
      std::vector<RTCRayHit> rh(static_cast<size_t>(w));
      uint64_t n_rays = 0, n_invalid = 0, n_hits = 0;
      for (int y = rows.begin(); y < rows.end(); ++y) {
        // Rays through pixel centres (Camera::primary_ray, expanded to share the basis). Only
        // valid rays enter the stream: rh[0, n).
        unsigned n = 0;
        for (int x = 0; x < w; ++x) {
          const float sx = (2.0f * (float(x) + 0.5f) / float(w) - 1.0f) * tan_half * camera.aspect();
          const float sy = (1.0f - 2.0f * (float(y) + 0.5f) / float(h)) * tan_half;
          const glm::vec3 dir = glm::normalize(camera.forward + sx * right + sy * camera.up);
          const float cos_fwd = glm::dot(dir, camera.forward);
          const float tnear = camera.near_m / cos_fwd, tfar = camera.far_m / cos_fwd;
          if (!ray_is_valid(camera.position, dir, tnear, tfar)) {
            ++n_invalid;
            continue;
          }
          ++n_rays;
          RTCRayHit& r = rh[n++];
          r.ray.org_x = camera.position.x;
          r.ray.org_y = camera.position.y;
          r.ray.org_z = camera.position.z;
          r.ray.dir_x = dir.x;
          r.ray.dir_y = dir.y;
          r.ray.dir_z = dir.z;
          r.ray.tnear = tnear;
          r.ray.tfar = tfar;
          r.ray.time = 0.0f;
          r.ray.mask = kMaskAll;
          r.ray.id = unsigned(x);
          r.ray.flags = 0;
          r.hit.geomID = RTC_INVALID_GEOMETRY_ID;
          r.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        }
        RTCIntersectContext ctx;
        rtcInitIntersectContext(&ctx);
        ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
        if (n > 0) rtcIntersect1M(top_, &ctx, rh.data(), n, sizeof(RTCRayHit));
        for (unsigned k = 0; k < n; ++k) {
          const RTCRayHit& r = rh[k];
          const int x = int(r.ray.id);
          if (r.hit.geomID == RTC_INVALID_GEOMETRY_ID) continue;
          int oi = -1;
          uint32_t tri = 0;
          if (!resolve_hit(r.hit.geomID, r.hit.instID[0], r.hit.primID, oi, tri)) continue;
          glm::dvec3 v[3];
          if (!triangle_world(oi, tri, v)) continue;
          ++n_hits;
          const Object& o = scene_.objects[size_t(oi)];
          const double u = r.hit.u, vv = r.hit.v;
          const glm::dvec3 p = (1.0 - u - vv) * v[0] + u * v[1] + vv * v[2];
          glm::dvec3 ng = glm::cross(v[1] - v[0], v[2] - v[0]);
          ng /= glm::length(ng);
          if (glm::dot(ng, glm::dvec3(camera.position) - p) < 0.0) ng = -ng;  // face the camera
          const glm::vec3 ngf(ng);
          glm::vec3 ns = ngf;
          const glm::uvec3 t = o.mesh.triangles[tri];
          if (o.mesh.normals.size() == o.mesh.positions.size()) {
            glm::vec3 n = (1.0f - float(u) - float(vv)) * o.mesh.normals[t.x] + float(u) * o.mesh.normals[t.y] +
                          float(vv) * o.mesh.normals[t.z];
            if (o.moving()) n = glm::transpose(glm::inverse(glm::mat3(world_from_object_[size_t(oi)]))) * n;
            const float len = glm::length(n);
            if (len > 0.0f && std::isfinite(len)) {
              n /= len;
              // Flipped to face the camera on its own (the rasterizer's convention).
              ns = glm::dot(n, glm::vec3(glm::dvec3(camera.position) - p)) < 0.0f ? -n : n;
            }
          }
          const Material& mat = scene_.materials[o.material];
          glm::vec3 albedo = mat.albedo;
          if (mat.texture >= 0 && size_t(mat.texture) < scene_.textures.size() &&
              o.mesh.uvs.size() == o.mesh.positions.size()) {
            const glm::vec2 uv = (1.0f - float(u) - float(vv)) * o.mesh.uvs[t.x] + float(u) * o.mesh.uvs[t.y] +
                                 float(vv) * o.mesh.uvs[t.z];
            albedo *= glm::vec3(scene_.textures[size_t(mat.texture)].sample_bilinear(uv));
          }
          const glm::vec3 pf(p);
          g.depth(x, y) = camera.view_depth(pf);
          g.position(x, y) = pf;
          g.geo_normal(x, y) = ngf;
          g.normal(x, y) = ns;
          g.albedo(x, y) = albedo;
          g.object_id(x, y) = o.id;
          g.prim_id(x, y) = tri;
          g.bary(x, y) = glm::vec2(float(u), float(vv));
        }
      }
      rays += n_rays;
      invalid += n_invalid;
      hits += n_hits;
    });
  });
  if (stats) {
    stats->rays = rays;
    stats->invalid_rays = invalid;
    stats->hits = hits;
  }
  return g;
}

}  // namespace dhr
