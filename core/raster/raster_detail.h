// Internal to the rasterizer (core/raster/raster.cpp and core/raster/raster_avx512.cpp): the types its scalar
// pipeline and its AVX-512 cover and resolve kernels share. Not part of the public API
// (core/raster/raster.h, which describes the pipeline and the G-buffer's conventions).
#pragma once

#include "core/base/avx512.h"
#include "core/raster/raster.h"

#include <glm/glm.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

namespace dhr::raster_detail {

constexpr int kTile = kRasterTileSize;
constexpr uint32_t kNoSetup = ~0u;  // TileScratch::setup of a pixel no fragment covers yet
constexpr float kMaxMotionPx = 1e6f;

struct View3 {
  float x, y, z;  // camera space: along right, up, forward (z = linear view depth)
};

struct Hom {
  double x, y, w;  // homogeneous pixel coordinates: pixel = (x / w, y / w), w = view depth
};

// The camera's basis, computed once with the same float arithmetic as Camera::project.
struct Projector {
  glm::vec3 position, forward, right, up;
  float tan_half, aspect;
  int width, height;
  // Homogeneous pixel mapping: X = sx * right + hw * z, Y = hh * z - sy * up, W = z.
  double sx, sy, hw, hh;

  explicit Projector(const Camera& c)
      : position(c.position),
        forward(c.forward),
        right(c.right()),
        up(c.up),
        tan_half(std::tan(glm::radians(c.vfov_deg) * 0.5f)),
        aspect(c.aspect()),
        width(c.width),
        height(c.height) {
    hw = 0.5 * double(c.width);
    hh = 0.5 * double(c.height);
    sx = hw / (double(tan_half) * double(aspect));
    sy = hh / double(tan_half);
  }
  View3 view(const glm::vec3& p) const {
    const glm::vec3 d = p - position;
    return {glm::dot(d, right), glm::dot(d, up), glm::dot(d, forward)};
  }
  Hom hom(const View3& v) const {
    return {sx * double(v.x) + hw * double(v.z), hh * double(v.z) - sy * double(v.y), double(v.z)};
  }
  // Identical to Camera::project (without recomputing the basis per call).
  glm::vec3 project(const glm::vec3& world) const {
    const glm::vec3 d = world - position;
    const float z = glm::dot(d, forward);
    const float px = glm::dot(d, right) / (z * tan_half * aspect);
    const float py = glm::dot(d, up) / (z * tan_half);
    return {(px + 1.0f) * 0.5f * float(width), (1.0f - py) * 0.5f * float(height), z};
  }
};

// Per-object data prepared once per call.
struct ObjectPrep {
  const Object* object = nullptr;
  const Mesh* mesh = nullptr;
  const glm::vec3* world = nullptr;  // world-space positions (the mesh's, or `moved`)
  std::vector<glm::vec3> moved;      // moving objects: positions placed at time_s
  size_t view_offset = 0;            // first vertex in the camera-space array
  bool moving = false;
  glm::mat4 world_from_object{1.0f};       // moving objects: at time_s
  glm::mat3 normal_matrix{1.0f};           // moving objects: world-from-object for normals
  bool static_motion = true;               // the point does not move between the frames
  glm::mat4 world_from_object_prev{1.0f};  // moving objects: at prev_time_s
  const Material* material = nullptr;
  const Texture* texture = nullptr;  // albedo texture when the mesh has uvs, else null
  bool cutout = false;
};

// One coverage triangle: a whole mesh triangle or a piece of a clipped one. Fixed-point pixel
// coordinates (1/256 px), ordered so that the doubled signed area is positive.
struct CoverTri {
  int32_t x[3], y[3];
  uint32_t object;  // index into Scene::objects
  uint32_t prim;    // mesh triangle index
};

// The barycentric planes of a mesh triangle for one tile (built when it first covers a pixel).
struct Setup {
  glm::dvec3 r1, r2, rs;  // u1, u2 and sum(u) = 1/W as plane coefficients of (px, py, 1)
  double iw_lo, iw_hi;    // range of 1/W over the (visible part of the) triangle
  uint32_t object, prim;
  glm::uvec3 tri;        // the mesh triangle's vertex indices
  glm::vec3 v[3];        // its world-space vertices
  glm::vec3 geo_normal;  // unit (not yet flipped); zero when degenerate in float
};

// Perspective-correct barycentrics at pixel point (px, py), clamped into the triangle (a
// centre covered by the snapped triangle may lie a fraction of 1/256 px outside the exact one).
inline glm::dvec3 barycentrics(const Setup& s, double px, double py) {
  const double inv_us = 1.0 / (s.rs.x * px + s.rs.y * py + s.rs.z);
  const double b1 = (s.r1.x * px + s.r1.y * py + s.r1.z) * inv_us;
  const double b2 = (s.r2.x * px + s.r2.y * py + s.r2.z) * inv_us;
  glm::dvec3 b{1.0 - b1 - b2, b1, b2};
  if (!(b.x >= 0.0 && b.y >= 0.0 && b.z >= 0.0)) {  // also catches NaN
    for (int i = 0; i < 3; ++i) b[i] = b[i] > 0.0 ? b[i] : 0.0;
    const double sum = b.x + b.y + b.z;
    b = sum > 0.0 && std::isfinite(sum) ? b / sum : glm::dvec3(1.0 / 3.0);
  }
  return b;
}

struct TileScratch {
  std::array<double, kTile * kTile> inv_w;  // 1/W of the nearest fragment, 0 = none
  std::array<uint32_t, kTile * kTile> setup;
  std::vector<Setup> setups;
};

struct Context {
  const Scene* scene;
  const Camera* camera;
  Projector proj;
  Projector prev_proj;
  bool same_cameras;
  float motion_scale_x, motion_scale_y;
  double inv_near, inv_far;
  int width, height, tiles_x, tiles_y;
  std::vector<ObjectPrep> objects;
  View3* view = nullptr;      // camera-space vertices of all objects
  bool wide_kernels = false;  // cover_row_x8 and resolve_x8 (AVX-512): 8 pixels of a row at a time
};

// The barycentric planes of coverage triangle c's mesh triangle (core/raster/raster.cpp).
Setup make_setup(const Context& ctx, const CoverTri& c);

// The index in s.setups of coverage triangle c's setup, made when it first covers a pixel of the
// tile. Pieces of one clipped triangle follow each other: they share the setup.
inline uint32_t tile_setup(const Context& ctx, const CoverTri& c, TileScratch& s) {
  if (s.setups.empty() || s.setups.back().object != c.object || s.setups.back().prim != c.prim)
    s.setups.push_back(make_setup(ctx, c));
  return uint32_t(s.setups.size() - 1);
}

#if DHR_AVX512_KERNELS
// core/raster/raster_avx512.cpp: cover()'s row loop and resolve() 8 pixels at a time, chosen at run time
// (Context::wide_kernels), with the same bits as the scalar code.
DHR_AVX512_TARGET void cover_row_x8(const Context& ctx, const CoverTri& c, int y, int xa, int xb, const int64_t* e_a,
                                    const int64_t* step_x, int X0, int Y0, TileScratch& s, uint32_t& sid,
                                    uint64_t& fragments);
DHR_AVX512_TARGET void resolve_x8(const Context& ctx, const Setup& st, int x, int y, unsigned n, GBuffer& out);
#endif

}  // namespace dhr::raster_detail
