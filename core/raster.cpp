// The client's tile-binned CPU rasterizer (see core/raster.h for the pipeline and every
// convention of the G-buffer it writes).
//
// Coverage and attributes are kept apart on purpose:
// - Coverage uses triangles snapped to 1/256 px and exact 64-bit integer edge functions with
//   the top-left rule (Pineda 1988; the D3D/OpenGL rasterization rules), so that triangles
//   sharing an edge neither leave gaps nor cover a pixel twice. Vertices that cross the near
//   plane, or that project beyond a +-2^21 px guard band (which keeps the integer edge
//   functions within 62 bits), are clipped in homogeneous space first (Sutherland-Hodgman).
// - Attributes use the 2D homogeneous barycentric planes of the original triangle (Olano &
//   Greer, "Triangle scan conversion using 2D homogeneous coordinates", 1997): with M the
//   3x3 matrix whose columns are the vertices' homogeneous pixel coordinates (X, Y, W),
//   u = M^-1 (px, py, 1) gives u_i / sum(u) = the perspective-correct barycentrics and
//   sum(u) = 1/W (W = linear view depth) as linear functions of the pixel position. They are
//   evaluated in double, so the position written lies on the pixel's primary ray to float
//   rounding, and clipped pieces need no barycentric bookkeeping.
#include "core/raster.h"

#include "core/avx512.h"
#include "core/error.h"
#include "core/workspace.h"

#include <glm/gtc/matrix_inverse.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <numeric>
#include <span>
#include <vector>

namespace dhr {

namespace {

constexpr int kTile = kRasterTileSize;
constexpr int kSubpixelBits = 8;
constexpr int64_t kSubpixel = int64_t(1) << kSubpixelBits;
constexpr int64_t kHalfSubpixel = kSubpixel / 2;
// Vertices are kept within +-kGuardBandPx after clipping: fixed-point coordinates stay below
// 2^29 in magnitude, differences below 2^30 and edge-function values below 2^62.
constexpr double kGuardBandPx = double(1 << 21);
constexpr float kMaxCoordinate = 1e18f;  // same limit as RtScene's build
constexpr size_t kTriangleJob = 8192;    // triangles per setup/binning job
constexpr size_t kVertexJob = 16384;     // vertices per transform job
constexpr uint32_t kNoSetup = ~0u;
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

bool finite3(const glm::vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

void check_camera(const Camera& c, const char* which) {
  if (!finite3(c.position) || !finite3(c.forward) || !finite3(c.up))
    fail("rasterize: {} has a non-finite position, forward or up vector", which);
  if (std::abs(glm::length(c.forward) - 1.0f) > 1e-3f || std::abs(glm::length(c.up) - 1.0f) > 1e-3f ||
      std::abs(glm::dot(c.forward, c.up)) > 1e-3f)
    fail("rasterize: {} needs unit, orthogonal forward and up vectors (use Camera::look_at)", which);
  if (!(c.vfov_deg > 0.0f && c.vfov_deg < 180.0f)) fail("rasterize: {} vfov_deg {} is outside (0, 180)", which, c.vfov_deg);
  if (!(c.near_m > 0.0f && c.far_m > c.near_m && std::isfinite(c.far_m)))
    fail("rasterize: {} needs 0 < near_m < far_m (finite), got near_m {} far_m {}", which, c.near_m, c.far_m);
  if (c.width <= 0 || c.height <= 0) fail("rasterize: {} resolution {}x{} must be positive", which, c.width, c.height);
  check_image_size(c.width, c.height);
}

bool same_camera(const Camera& a, const Camera& b) {
  return a.position == b.position && a.forward == b.forward && a.up == b.up && a.vfov_deg == b.vfov_deg &&
         a.near_m == b.near_m && a.far_m == b.far_m && a.width == b.width && a.height == b.height;
}

// Per-object data prepared once per call.
struct ObjectPrep {
  const Object* object = nullptr;
  const Mesh* mesh = nullptr;
  const glm::vec3* world = nullptr;  // world-space positions (the mesh's, or `moved`)
  std::vector<glm::vec3> moved;      // moving objects: positions placed at time_s
  size_t view_offset = 0;            // first vertex in the camera-space array
  bool moving = false;
  glm::mat4 world_from_object{1.0f}; // moving objects: at time_s
  glm::mat3 normal_matrix{1.0f};     // moving objects: world-from-object for normals
  bool static_motion = true;         // the point does not move between the frames
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

// Output of one triangle job: its coverage triangles and, per tile, which of them touch it.
struct TriangleJobOut {
  std::vector<std::pair<uint32_t, uint32_t>> bins;  // (tile, index into tris), scratch
  std::vector<CoverTri> tris;
  std::vector<uint32_t> tile_begin;  // tiles + 1 offsets into tile_tris
  std::vector<uint32_t> tile_tris;
  uint64_t clipped = 0;
  uint64_t culled = 0;
};

struct Job {
  uint32_t object;
  size_t begin, end;
};

// Pixel range [x0, x1] x [y0, y1] whose centres lie in the bounding box of a coverage
// triangle, clipped to the image; false when empty.
bool pixel_bounds(const CoverTri& t, int width, int height, int& x0, int& y0, int& x1, int& y1) {
  const int64_t minx = std::min({t.x[0], t.x[1], t.x[2]}), maxx = std::max({t.x[0], t.x[1], t.x[2]});
  const int64_t miny = std::min({t.y[0], t.y[1], t.y[2]}), maxy = std::max({t.y[0], t.y[1], t.y[2]});
  // Centre of pixel x is x * 256 + 128: first x with centre >= min, last with centre <= max.
  auto ceil_div = [](int64_t a, int64_t b) { return a >= 0 ? (a + b - 1) / b : -((-a) / b); };
  auto floor_div = [](int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); };
  const int64_t px0 = std::max<int64_t>(ceil_div(minx - kHalfSubpixel, kSubpixel), 0);
  const int64_t px1 = std::min<int64_t>(floor_div(maxx - kHalfSubpixel, kSubpixel), width - 1);
  const int64_t py0 = std::max<int64_t>(ceil_div(miny - kHalfSubpixel, kSubpixel), 0);
  const int64_t py1 = std::min<int64_t>(floor_div(maxy - kHalfSubpixel, kSubpixel), height - 1);
  if (px0 > px1 || py0 > py1) return false;
  x0 = int(px0), x1 = int(px1), y0 = int(py0), y1 = int(py1);
  return true;
}

// Edge functions of a coverage triangle: E_k >= 0 inside, for edge k from vertex k+1 to k+2.
// Edges that are not top-left carry a bias of -1, so that a sample exactly on them is out.
struct Edges {
  int64_t dx[3], dy[3], bias[3];
  int64_t ax[3], ay[3];
  explicit Edges(const CoverTri& t) {
    for (int k = 0; k < 3; ++k) {
      const int a = (k + 1) % 3, b = (k + 2) % 3;
      ax[k] = t.x[a];
      ay[k] = t.y[a];
      dx[k] = int64_t(t.x[b]) - t.x[a];
      dy[k] = int64_t(t.y[b]) - t.y[a];
      // With y down and positive area, a top edge runs in +x, a left edge in -y.
      const bool top_left = dy[k] < 0 || (dy[k] == 0 && dx[k] > 0);
      bias[k] = top_left ? 0 : -1;
    }
  }
  // At the centre of pixel (px, py).
  int64_t at(int k, int64_t px, int64_t py) const {
    const int64_t sx = px * kSubpixel + kHalfSubpixel, sy = py * kSubpixel + kHalfSubpixel;
    return dx[k] * (sy - ay[k]) - dy[k] * (sx - ax[k]) + bias[k];
  }
};

// Does the coverage triangle possibly cover a pixel centre of the rectangle [x0,x1]x[y0,y1]?
// (Each edge function is linear: its maximum over the rectangle is at a corner.)
bool touches_rect(const Edges& e, int x0, int y0, int x1, int y1) {
  for (int k = 0; k < 3; ++k) {
    const int64_t px = e.dy[k] < 0 ? x1 : x0;  // E grows with -dy * x
    const int64_t py = e.dx[k] > 0 ? y1 : y0;  // and with dx * y
    if (e.at(k, px, py) < 0) return false;
  }
  return true;
}

// Sutherland-Hodgman clipping of a convex polygon against the plane dist(v) >= 0.
template <class Dist>
int clip_polygon(const Hom* in, int n, Hom* out, Dist dist, bool on_near, double near_w) {
  int m = 0;
  for (int i = 0; i < n; ++i) {
    const Hom& a = in[i];
    const Hom& b = in[(i + 1) % n];
    const double da = dist(a), db = dist(b);
    if (da >= 0.0) out[m++] = a;
    if ((da >= 0.0) != (db >= 0.0)) {
      const double t = da / (da - db);
      Hom c{a.x + t * (b.x - a.x), a.y + t * (b.y - a.y), a.w + t * (b.w - a.w)};
      if (on_near) c.w = near_w;  // exactly on the plane
      out[m++] = c;
    }
  }
  return m;
}

// The barycentric planes of a mesh triangle for one tile (built when it first covers a pixel).
struct Setup {
  glm::dvec3 r1, r2, rs;  // u1, u2 and sum(u) = 1/W as plane coefficients of (px, py, 1)
  double iw_lo, iw_hi;    // range of 1/W over the (visible part of the) triangle
  uint32_t object, prim;
  glm::uvec3 tri;         // the mesh triangle's vertex indices
  glm::vec3 v[3];         // its world-space vertices
  glm::vec3 geo_normal;   // unit (not yet flipped); zero when degenerate in float
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
  View3* view = nullptr;  // camera-space vertices of all objects
  bool wide_kernels = false;  // cover_row_x8 and resolve_x8 (AVX-512): 8 pixels of a row at a time
};

void prepare_objects(Context& ctx, const RasterFrame& frame, size_t& total_vertices) {
  const Scene& scene = *ctx.scene;
  ctx.objects.resize(scene.objects.size());
  total_vertices = 0;
  for (size_t i = 0; i < scene.objects.size(); ++i) {
    const Object& o = scene.objects[i];
    ObjectPrep& p = ctx.objects[i];
    p.object = &o;
    p.mesh = &o.mesh;
    const size_t nv = o.mesh.positions.size();
    if (!o.mesh.normals.empty() && o.mesh.normals.size() != nv)
      fail("rasterize: object '{}' has {} normals for {} positions (need one per vertex or none)", o.name,
           o.mesh.normals.size(), nv);
    if (!o.mesh.uvs.empty() && o.mesh.uvs.size() != nv)
      fail("rasterize: object '{}' has {} uvs for {} positions (need one per vertex or none)", o.name, o.mesh.uvs.size(), nv);
    if (o.material >= scene.materials.size())
      fail("rasterize: object '{}' has material index {} but the scene has {} materials", o.name, o.material,
           scene.materials.size());
    p.material = &scene.materials[o.material];
    if (p.material->texture >= 0) {
      if (size_t(p.material->texture) >= scene.textures.size())
        fail("rasterize: material '{}' has texture index {} but the scene has {} textures", p.material->name,
             p.material->texture, scene.textures.size());
      const Texture& t = scene.textures[size_t(p.material->texture)];
      if (t.width <= 0 || t.height <= 0 || t.texels.size() != size_t(t.width) * size_t(t.height))
        fail("rasterize: texture '{}' is empty or inconsistent ({}x{}, {} texels)", t.path, t.width, t.height,
             t.texels.size());
      if (!o.mesh.uvs.empty()) p.texture = &t;
    }
    p.cutout = p.texture && p.material->alpha_cutout && p.texture->has_alpha;
    p.moving = o.moving();
    if (p.moving) {
      const glm::mat4 now = o.world_from_object(frame.time_s);
      const glm::mat4 prev = o.world_from_object(frame.prev_time_s);
      p.world_from_object = now;
      p.normal_matrix = glm::inverseTranspose(glm::mat3(now));
      p.world_from_object_prev = prev;
      p.static_motion = now == prev;
      p.moved.resize(nv);
      p.world = p.moved.data();
    } else {
      p.world = o.mesh.positions.data();
    }
    p.view_offset = total_vertices;
    total_vertices += nv;
  }
}


// Phase 1: place moving objects at time_s and transform every vertex to camera space.
void transform_vertices(Context& ctx) {
  std::vector<Job> jobs;
  for (size_t i = 0; i < ctx.objects.size(); ++i) {
    const size_t nv = ctx.objects[i].mesh->positions.size();
    for (size_t b = 0; b < nv; b += kVertexJob) jobs.push_back({uint32_t(i), b, std::min(nv, b + kVertexJob)});
  }
  tbb::parallel_for(tbb::blocked_range<size_t>(0, jobs.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t j = r.begin(); j != r.end(); ++j) {
      const Job& job = jobs[j];
      ObjectPrep& p = ctx.objects[job.object];
      const glm::vec3* src = p.mesh->positions.data();
      View3* dst = ctx.view + p.view_offset;
      if (p.moving) {
        for (size_t v = job.begin; v < job.end; ++v)
          p.moved[v] = glm::vec3(p.world_from_object * glm::vec4(src[v], 1.0f));
      }
      for (size_t v = job.begin; v < job.end; ++v) dst[v] = ctx.proj.view(p.world[v]);
    }
  });
}

// Phase 2 for one job: reject, clip, snap and bin the triangles [job.begin, job.end) of one object.
void setup_triangles(const Context& ctx, const Job& job, TriangleJobOut& out) {
  const ObjectPrep& p = ctx.objects[job.object];
  const Mesh& mesh = *p.mesh;
  const size_t nv = mesh.positions.size();
  const View3* view = ctx.view + p.view_offset;
  const double near_w = ctx.camera->near_m, far_w = ctx.camera->far_m;
  const double width = ctx.width, height = ctx.height;
  const int tiles = ctx.tiles_x * ctx.tiles_y;
  auto& bins = out.bins;
  bins.clear();
  out.tris.clear();
  out.clipped = out.culled = 0;

  for (size_t i = job.begin; i < job.end; ++i) {
    const glm::uvec3 t = mesh.triangles[i];
    if (t.x >= nv || t.y >= nv || t.z >= nv) {
      ++out.culled;
      continue;
    }
    bool valid = true;
    for (int k = 0; k < 3; ++k) {
      const glm::vec3& w = p.world[t[k]];
      // !(|c| < max) also rejects NaN and infinities.
      if (!(std::abs(w.x) < kMaxCoordinate && std::abs(w.y) < kMaxCoordinate && std::abs(w.z) < kMaxCoordinate))
        valid = false;
    }
    if (!valid) {
      ++out.culled;
      continue;
    }
    Hom h[3] = {ctx.proj.hom(view[t.x]), ctx.proj.hom(view[t.y]), ctx.proj.hom(view[t.z])};
    // Trivial reject: all three vertices outside the same plane of the view volume.
    unsigned outside_all = ~0u;
    bool needs_clip = false;
    for (const Hom& v : h) {
      unsigned code = 0;
      if (v.w < near_w) code |= 1u;
      if (v.w > far_w) code |= 2u;
      if (v.x < 0.0) code |= 4u;
      if (v.x > width * v.w) code |= 8u;
      if (v.y < 0.0) code |= 16u;
      if (v.y > height * v.w) code |= 32u;
      outside_all &= code;
      if (v.w < near_w || std::abs(v.x) > kGuardBandPx * v.w || std::abs(v.y) > kGuardBandPx * v.w) needs_clip = true;
    }
    if (outside_all != 0) {
      ++out.culled;
      continue;
    }
    // det(M) = 0: zero area, or the triangle's plane contains the eye (seen edge-on).
    const glm::dvec3 a{h[0].x, h[0].y, h[0].w}, b{h[1].x, h[1].y, h[1].w}, c{h[2].x, h[2].y, h[2].w};
    const double det = glm::dot(a, glm::cross(b, c));
    if (!(det != 0.0) || !std::isfinite(det)) {
      ++out.culled;
      continue;
    }
    Hom poly[16];
    int n = 3;
    std::copy(h, h + 3, poly);
    if (needs_clip) {
      ++out.clipped;
      Hom tmp[16];
      const double g = kGuardBandPx;
      n = clip_polygon(poly, n, tmp, [&](const Hom& v) { return v.w - near_w; }, true, near_w);
      n = clip_polygon(tmp, n, poly, [&](const Hom& v) { return v.x + g * v.w; }, false, 0.0);
      n = clip_polygon(poly, n, tmp, [&](const Hom& v) { return g * v.w - v.x; }, false, 0.0);
      n = clip_polygon(tmp, n, poly, [&](const Hom& v) { return v.y + g * v.w; }, false, 0.0);
      n = clip_polygon(poly, n, tmp, [&](const Hom& v) { return g * v.w - v.y; }, false, 0.0);
      std::copy(tmp, tmp + n, poly);
    }
    int32_t fx[16], fy[16];
    for (int j = 0; j < n; ++j) {
      fx[j] = int32_t(std::llround(poly[j].x / poly[j].w * double(kSubpixel)));
      fy[j] = int32_t(std::llround(poly[j].y / poly[j].w * double(kSubpixel)));
    }
    bool emitted = false;
    for (int j = 1; j + 1 < n; ++j) {  // fan: (0, j, j + 1)
      CoverTri ct{{fx[0], fx[j], fx[j + 1]}, {fy[0], fy[j], fy[j + 1]}, job.object, uint32_t(i)};
      const int64_t area = (int64_t(ct.x[1]) - ct.x[0]) * (int64_t(ct.y[2]) - ct.y[0]) -
                           (int64_t(ct.x[2]) - ct.x[0]) * (int64_t(ct.y[1]) - ct.y[0]);
      if (area == 0) continue;
      if (area < 0) {  // no back-face culling: just orient every triangle the same way
        std::swap(ct.x[1], ct.x[2]);
        std::swap(ct.y[1], ct.y[2]);
      }
      int x0, y0, x1, y1;
      if (!pixel_bounds(ct, ctx.width, ctx.height, x0, y0, x1, y1)) continue;
      const uint32_t index = uint32_t(out.tris.size());
      const int tx0 = x0 / kTile, tx1 = x1 / kTile, ty0 = y0 / kTile, ty1 = y1 / kTile;
      if (tx0 == tx1 && ty0 == ty1) {
        bins.emplace_back(uint32_t(ty0 * ctx.tiles_x + tx0), index);
      } else {
        const Edges e(ct);
        bool any = false;
        for (int ty = ty0; ty <= ty1; ++ty)
          for (int tx = tx0; tx <= tx1; ++tx) {
            const int rx0 = std::max(x0, tx * kTile), rx1 = std::min(x1, tx * kTile + kTile - 1);
            const int ry0 = std::max(y0, ty * kTile), ry1 = std::min(y1, ty * kTile + kTile - 1);
            if (!touches_rect(e, rx0, ry0, rx1, ry1)) continue;
            bins.emplace_back(uint32_t(ty * ctx.tiles_x + tx), index);
            any = true;
          }
        if (!any) continue;
      }
      out.tris.push_back(ct);
      emitted = true;
    }
    if (!emitted) ++out.culled;
  }

  // Counting sort by tile; stable, so each tile lists its triangles in scene order.
  out.tile_begin.assign(size_t(tiles) + 1, 0);
  for (const auto& [tile, index] : bins) ++out.tile_begin[tile + 1];
  std::partial_sum(out.tile_begin.begin(), out.tile_begin.end(), out.tile_begin.begin());
  out.tile_tris.resize(bins.size());
  // tile_begin[t] serves as the cursor of tile t, then is shifted back.
  for (const auto& [tile, index] : bins) out.tile_tris[out.tile_begin[tile]++] = index;
  for (size_t t = out.tile_begin.size() - 1; t > 0; --t) out.tile_begin[t] = out.tile_begin[t - 1];
  out.tile_begin[0] = 0;
}

Setup make_setup(const Context& ctx, const CoverTri& c) {
  const ObjectPrep& p = ctx.objects[c.object];
  const glm::uvec3 t = p.mesh->triangles[c.prim];
  const View3* view = ctx.view + p.view_offset;
  const Hom h0 = ctx.proj.hom(view[t.x]), h1 = ctx.proj.hom(view[t.y]), h2 = ctx.proj.hom(view[t.z]);
  const glm::dvec3 a{h0.x, h0.y, h0.w}, b{h1.x, h1.y, h1.w}, d{h2.x, h2.y, h2.w};
  // Rows of M^-1 = adj(M) / det, M = [a b d] (columns).
  const glm::dvec3 c0 = glm::cross(b, d), c1 = glm::cross(d, a), c2 = glm::cross(a, b);
  const double inv_det = 1.0 / glm::dot(a, c0);
  Setup s;
  s.r1 = c1 * inv_det;
  s.r2 = c2 * inv_det;
  s.rs = (c0 + c1 + c2) * inv_det;
  const double w_min = std::min({a.z, b.z, d.z}), w_max = std::max({a.z, b.z, d.z});
  s.iw_lo = w_max > 0.0 ? 1.0 / w_max : 0.0;
  s.iw_hi = ctx.inv_near;
  if (w_min > double(ctx.camera->near_m)) s.iw_hi = 1.0 / w_min;
  s.object = c.object;
  s.prim = c.prim;
  s.tri = t;
  for (int k = 0; k < 3; ++k) s.v[k] = p.world[t[k]];
  const glm::vec3 n = glm::cross(s.v[1] - s.v[0], s.v[2] - s.v[0]);
  const float len = glm::length(n);
  s.geo_normal = len > 0.0f && std::isfinite(len) ? n / len : glm::vec3(0.0f);
  return s;
}

// The index in s.setups of coverage triangle c's setup, made when it first covers a pixel of the
// tile. Pieces of one clipped triangle follow each other: they share the setup.
uint32_t tile_setup(const Context& ctx, const CoverTri& c, TileScratch& s) {
  if (s.setups.empty() || s.setups.back().object != c.object || s.setups.back().prim != c.prim)
    s.setups.push_back(make_setup(ctx, c));
  return uint32_t(s.setups.size() - 1);
}

#if DHR_AVX512_KERNELS
// (r.x * px + r.y * py) + r.z, as cover() and barycentrics() evaluate a plane
// (1/W and the barycentrics), for 8 pixels of a row.
DHR_AVX512_TARGET inline __m512d plane_x8(const glm::dvec3& r, __m512d px, double py) {
  return _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(_mm512_set1_pd(r.x), px), _mm512_set1_pd(r.y * py)),
                       _mm512_set1_pd(r.z));
}

// The centres x + 0.5 .. x + 7.5 of 8 pixels of a row (exact in double).
DHR_AVX512_TARGET inline __m512d pixel_centres_x8(int x) {
  return _mm512_add_pd(_mm512_set1_pd(double(x) + 0.5), _mm512_set_pd(7, 6, 5, 4, 3, 2, 1, 0));
}

// cover()'s loop over the pixels xa..xb of row y, 8 at a time (AVX-512), for a triangle without
// alpha cut-out: the same edge tests on the same 64-bit values, the same 1/W in double and the
// same depth test, whose exact ties are settled lane by lane as cover() settles them. e_a holds
// the three edge functions at xa.
DHR_AVX512_TARGET void cover_row_x8(const Context& ctx, const CoverTri& c, int y, int xa, int xb, const int64_t* e_a,
                                    const int64_t* step_x, int X0, int Y0, TileScratch& s, uint32_t& sid,
                                    uint64_t& fragments) {
  const ObjectPrep& p = ctx.objects[c.object];
  const double py = y + 0.5;
  const __m512i iota = _mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0);
  __m512i e[3], step8[3];
  for (int k = 0; k < 3; ++k) {
    e[k] = _mm512_add_epi64(_mm512_set1_epi64(e_a[k]), _mm512_mullo_epi64(iota, _mm512_set1_epi64(step_x[k])));
    step8[k] = _mm512_set1_epi64(8 * step_x[k]);
  }
  for (int x = xa; x <= xb; x += 8) {
    const unsigned n = unsigned(std::min(8, xb - x + 1));
    __mmask8 m = _mm512_mask_cmpge_epi64_mask(__mmask8((1u << n) - 1),
                                              _mm512_or_si512(_mm512_or_si512(e[0], e[1]), e[2]), _mm512_setzero_si512());
    for (int k = 0; k < 3; ++k) e[k] = _mm512_add_epi64(e[k], step8[k]);
    if (!m) continue;
    fragments += uint64_t(__builtin_popcount(m));
    if (sid == kNoSetup) sid = tile_setup(ctx, c, s);
    const Setup& st = s.setups[sid];
    const __m512d px = pixel_centres_x8(x);
    __m512d iw = plane_x8(st.rs, px, py);
    iw = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(iw, _mm512_set1_pd(st.iw_lo), _CMP_GE_OQ), _mm512_set1_pd(st.iw_lo), iw);
    iw = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(iw, _mm512_set1_pd(st.iw_hi), _CMP_LE_OQ), _mm512_set1_pd(st.iw_hi), iw);
    m &= _mm512_cmp_pd_mask(iw, _mm512_set1_pd(ctx.inv_far), _CMP_NLT_UQ);  // not beyond the far plane
    const size_t k0 = size_t((y - Y0) * kTile + (x - X0));
    const __m512d cur = _mm512_maskz_loadu_pd(m, &s.inv_w[k0]);
    m &= _mm512_cmp_pd_mask(iw, cur, _CMP_NLT_UQ);
    if (!m) continue;
    __mmask8 win = m & ~_mm512_cmp_pd_mask(iw, cur, _CMP_EQ_OQ);
    if (__mmask8 tie = __mmask8(m & ~win)) {  // exact ties: the smaller (object id, prim id) wins
      for (unsigned i = 0; i < n; ++i)
        if (tie & (1u << i)) {
          const Setup& o = s.setups[s.setup[k0 + i]];
          const uint32_t id = p.object->id, other = ctx.objects[o.object].object->id;
          if (id < other || (id == other && st.prim < o.prim)) win = __mmask8(win | (1u << i));
        }
    }
    _mm512_mask_storeu_pd(&s.inv_w[k0], win, iw);
    _mm512_mask_storeu_epi32(&s.setup[k0], __mmask16(win), _mm512_set1_epi32(int(sid)));
  }
}
#endif

// Visibility pass of one coverage triangle within the tile [X0, X1] x [Y0, Y1].
void cover(const Context& ctx, const CoverTri& c, int X0, int Y0, int X1, int Y1, TileScratch& s,
           uint64_t& fragments) {
  int x0, y0, x1, y1;
  if (!pixel_bounds(c, ctx.width, ctx.height, x0, y0, x1, y1)) return;
  x0 = std::max(x0, X0), y0 = std::max(y0, Y0), x1 = std::min(x1, X1), y1 = std::min(y1, Y1);
  if (x0 > x1 || y0 > y1) return;
  const Edges e(c);
  int64_t row[3], step_x[3], step_y[3];
  for (int k = 0; k < 3; ++k) {
    row[k] = e.at(k, x0, y0);
    step_x[k] = -e.dy[k] * kSubpixel;
    step_y[k] = e.dx[k] * kSubpixel;
  }
  const ObjectPrep& p = ctx.objects[c.object];
  uint32_t sid = kNoSetup;
  // Rows wider than this find their covered span [xa, xb] from the edge functions (exact
  // integer division) instead of testing every pixel of the bounding box.
  constexpr int kSpanMinWidth = 8;
  const bool spans = x1 - x0 >= kSpanMinWidth;
  for (int y = y0; y <= y1; ++y) {
    int xa = x0, xb = x1;
    if (spans) {
      // E_k(x) = row[k] + (x - x0) step_x[k] >= 0 for all k: one bound per edge.
      int64_t lo = 0, hi = x1 - x0;
      for (int k = 0; k < 3 && lo <= hi; ++k) {
        const int64_t e = row[k], st = step_x[k];
        if (st > 0) {
          if (e < 0) lo = std::max(lo, (-e + st - 1) / st);
        } else if (st < 0) {
          hi = e < 0 ? -1 : std::min(hi, e / -st);
        } else if (e < 0) {
          hi = -1;
        }
      }
      if (lo > hi) {
        for (int k = 0; k < 3; ++k) row[k] += step_y[k];
        continue;
      }
      xa = x0 + int(lo), xb = x0 + int(hi);
    }
    int64_t e0 = row[0] + int64_t(xa - x0) * step_x[0], e1 = row[1] + int64_t(xa - x0) * step_x[1],
            e2 = row[2] + int64_t(xa - x0) * step_x[2];
#if DHR_AVX512_KERNELS
    if (ctx.wide_kernels && !p.cutout) {
      const int64_t e_a[3] = {e0, e1, e2};
      cover_row_x8(ctx, c, y, xa, xb, e_a, step_x, X0, Y0, s, sid, fragments);
      for (int k = 0; k < 3; ++k) row[k] += step_y[k];
      continue;
    }
#endif
    for (int x = xa; x <= xb; ++x, e0 += step_x[0], e1 += step_x[1], e2 += step_x[2]) {
      if ((e0 | e1 | e2) < 0) continue;
      ++fragments;
      if (sid == kNoSetup) sid = tile_setup(ctx, c, s);
      const Setup& st = s.setups[sid];
      const double px = x + 0.5, py = y + 0.5;
      // 1/W, kept within the triangle's own range: outside the exact triangle (snapping) the
      // plane extrapolates, wildly so for a triangle seen nearly edge-on.
      double iw = st.rs.x * px + st.rs.y * py + st.rs.z;
      if (!(iw >= st.iw_lo)) iw = st.iw_lo;
      if (!(iw <= st.iw_hi)) iw = st.iw_hi;
      if (iw < ctx.inv_far) continue;  // beyond the far plane
      const int k = (y - Y0) * kTile + (x - X0);
      const double cur = s.inv_w[size_t(k)];
      if (iw < cur) continue;
      if (iw == cur) {  // exact tie: the smaller (object id, prim id) wins, whatever the order
        const Setup& o = s.setups[s.setup[size_t(k)]];
        const uint32_t id = p.object->id, other = ctx.objects[o.object].object->id;
        if (!(id < other || (id == other && st.prim < o.prim))) continue;
      }
      if (p.cutout) {
        const glm::dvec3 b = barycentrics(st, px, py);
        const glm::uvec3 t = p.mesh->triangles[c.prim];
        const auto& uv = p.mesh->uvs;
        const glm::vec2 u = float(b.x) * uv[t.x] + float(b.y) * uv[t.y] + float(b.z) * uv[t.z];
        if (p.texture->sample_bilinear(u).w < p.material->alpha_threshold) continue;
      }
      s.inv_w[size_t(k)] = iw;
      s.setup[size_t(k)] = sid;
    }
    for (int k = 0; k < 3; ++k) row[k] += step_y[k];
  }
}

// Resolve pass: every G-buffer field of pixel (x, y), whose nearest fragment is `st`.
void resolve(const Context& ctx, const Setup& st, int x, int y, GBuffer& out) {
  const ObjectPrep& p = ctx.objects[st.object];
  const Mesh& mesh = *p.mesh;
  const glm::uvec3 t = st.tri;
  const double px = x + 0.5, py = y + 0.5;
  const glm::dvec3 b = barycentrics(st, px, py);
  const glm::vec3 pos(glm::dvec3(st.v[0]) * b.x + glm::dvec3(st.v[1]) * b.y + glm::dvec3(st.v[2]) * b.z);
  const Camera& cam = *ctx.camera;
  const glm::vec3 to_cam = cam.position - pos;

  glm::vec3 ng = st.geo_normal.x != 0.0f || st.geo_normal.y != 0.0f || st.geo_normal.z != 0.0f ? st.geo_normal
                                                                                                : -cam.forward;
  if (glm::dot(ng, to_cam) < 0.0f) ng = -ng;
  glm::vec3 ns = ng;
  const glm::vec3 bf(b);
  if (!mesh.normals.empty()) {
    glm::vec3 n = bf.x * mesh.normals[t.x] + bf.y * mesh.normals[t.y] + bf.z * mesh.normals[t.z];
    if (p.moving) n = p.normal_matrix * n;
    const float len = glm::length(n);
    if (len > 1e-12f && std::isfinite(len)) {
      ns = n / len;
      if (glm::dot(ns, to_cam) < 0.0f) ns = -ns;
    }
  }
  glm::vec3 albedo = p.material->albedo;
  if (p.texture) {
    const glm::vec2 uv = bf.x * mesh.uvs[t.x] + bf.y * mesh.uvs[t.y] + bf.z * mesh.uvs[t.z];
    albedo *= glm::vec3(p.texture->sample_bilinear(uv));
  }

  glm::vec2 motion{0.0f};
  if (!(p.static_motion && ctx.same_cameras)) {
    glm::vec3 prev = pos;
    if (!p.static_motion) {  // the same surface point, placed at prev_time_s (object space is exact)
      const auto& o = mesh.positions;
      const glm::vec3 obj(glm::dvec3(o[t.x]) * b.x + glm::dvec3(o[t.y]) * b.y + glm::dvec3(o[t.z]) * b.z);
      prev = glm::vec3(p.world_from_object_prev * glm::vec4(obj, 1.0f));
    }
    const glm::vec3 q = ctx.prev_proj.project(prev);
    if (q.z > 0.0f) {
      auto offset = [](float v) {
        return std::isfinite(v) ? std::clamp(v, -kMaxMotionPx, kMaxMotionPx) : (v > 0.0f ? kMaxMotionPx : -kMaxMotionPx);
      };
      motion = {offset(q.x * ctx.motion_scale_x - float(px)), offset(q.y * ctx.motion_scale_y - float(py))};
    } else {
      motion = glm::vec2(-kMaxMotionPx);  // behind the previous camera: was not visible
    }
  }

  out.depth(x, y) = cam.view_depth(pos);
  out.position(x, y) = pos;
  out.normal(x, y) = ns;
  out.geo_normal(x, y) = ng;
  out.albedo(x, y) = albedo;
  out.object_id(x, y) = p.object->id;
  out.prim_id(x, y) = st.prim;
  out.bary(x, y) = {float(b.y), float(b.z)};
  out.motion(x, y) = motion;
}

#if DHR_AVX512_KERNELS
// Eight pixels of a row at a time (resolve_x8): the doubles of the barycentrics and the position
// in one 512-bit register, the floats in 256-bit ones. Every lane takes resolve()'s operations
// in its order and precision (no FMA: DHR_AVX512_TARGET), so the G-buffer has the same bits
// (tests/test_raster_bits.cpp, also under DHR_MAX_ISA=avx2 for the scalar resolve).

// Where element j of 8 interleaved vec3 (24 floats) or vec2 (16) comes from: the x lanes are
// indices 0-7 of the first table, y 8-15, z 16-23 (the second operand).
struct Interleave8 {
  alignas(64) int32_t v3_lo[16];
  alignas(64) int32_t v3_hi[16];
  alignas(64) int32_t v2[16];
  constexpr Interleave8() : v3_lo{}, v3_hi{}, v2{} {
    for (int j = 0; j < 24; ++j) (j < 16 ? v3_lo[j] : v3_hi[j - 16]) = 8 * (j % 3) + j / 3;
    for (int j = 0; j < 16; ++j) v2[j] = 8 * (j % 2) + j / 2;
  }
};
constexpr Interleave8 kInterleave8{};

struct Vec3x8 {
  __m256 x, y, z;
};

// Lanes 0..n-1 of (x, y, z) to dst[0..n-1] as vec3.
DHR_AVX512_TARGET inline void store_vec3_x8(glm::vec3* dst, const Vec3x8& v, unsigned n) {
  const __m512 xy = _mm512_insertf32x8(_mm512_castps256_ps512(v.x), v.y, 1);
  const __m512 z = _mm512_insertf32x8(_mm512_castps256_ps512(v.z), v.z, 1);
  float* f = &dst->x;
  const unsigned count = 3 * n;
  _mm512_mask_storeu_ps(f, __mmask16(count >= 16 ? 0xffffu : (1u << count) - 1),
                        _mm512_permutex2var_ps(xy, _mm512_load_si512(kInterleave8.v3_lo), z));
  if (count > 16)
    _mm512_mask_storeu_ps(f + 16, __mmask16((1u << (count - 16)) - 1),
                          _mm512_permutex2var_ps(xy, _mm512_load_si512(kInterleave8.v3_hi), z));
}

DHR_AVX512_TARGET inline void store_vec2_x8(glm::vec2* dst, __m256 x, __m256 y, unsigned n) {
  const __m512 xy = _mm512_insertf32x8(_mm512_castps256_ps512(x), y, 1);
  _mm512_mask_storeu_ps(&dst->x, __mmask16((1u << (2 * n)) - 1),
                        _mm512_permutexvar_ps(_mm512_load_si512(kInterleave8.v2), xy));
}

// (b0 a0 + b1 a1) + b2 a2 of one coordinate, in double (the position) or float (the rest).
DHR_AVX512_TARGET inline __m512d blend3_pd(double a0, double a1, double a2, __m512d b0, __m512d b1, __m512d b2) {
  return _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(_mm512_set1_pd(a0), b0), _mm512_mul_pd(_mm512_set1_pd(a1), b1)),
                       _mm512_mul_pd(_mm512_set1_pd(a2), b2));
}
DHR_AVX512_TARGET inline __m256 blend3_ps(float a0, float a1, float a2, __m256 b0, __m256 b1, __m256 b2) {
  return _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(b0, _mm256_set1_ps(a0)), _mm256_mul_ps(b1, _mm256_set1_ps(a1))),
                       _mm256_mul_ps(b2, _mm256_set1_ps(a2)));
}

// glm::dot(a, v): (a.x v.x + a.y v.y) + a.z v.z.
DHR_AVX512_TARGET inline __m256 dot_x8(const Vec3x8& a, const Vec3x8& v) {
  return _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(a.x, v.x), _mm256_mul_ps(a.y, v.y)), _mm256_mul_ps(a.z, v.z));
}
DHR_AVX512_TARGET inline Vec3x8 broadcast_x8(const glm::vec3& v) {
  return {_mm256_set1_ps(v.x), _mm256_set1_ps(v.y), _mm256_set1_ps(v.z)};
}
DHR_AVX512_TARGET inline Vec3x8 sub_x8(const Vec3x8& a, const Vec3x8& b) {
  return {_mm256_sub_ps(a.x, b.x), _mm256_sub_ps(a.y, b.y), _mm256_sub_ps(a.z, b.z)};
}
// -v in the lanes of `flip` (all ones or zero), v elsewhere.
DHR_AVX512_TARGET inline Vec3x8 negate_where_x8(const Vec3x8& v, __m256 flip) {
  const __m256 sign = _mm256_and_ps(flip, _mm256_set1_ps(-0.0f));
  return {_mm256_xor_ps(v.x, sign), _mm256_xor_ps(v.y, sign), _mm256_xor_ps(v.z, sign)};
}
DHR_AVX512_TARGET inline Vec3x8 select_x8(const Vec3x8& a, const Vec3x8& b, __m256 take_b) {
  return {_mm256_blendv_ps(a.x, b.x, take_b), _mm256_blendv_ps(a.y, b.y, take_b), _mm256_blendv_ps(a.z, b.z, take_b)};
}
// The motion offset of resolve(): clamped to +-kMaxMotionPx, infinities to their sign, NaN to -.
DHR_AVX512_TARGET inline __m256 motion_offset_x8(__m256 v) {
  const __m256 hi = _mm256_set1_ps(kMaxMotionPx), lo = _mm256_set1_ps(-kMaxMotionPx);
  __m256 r = _mm256_blendv_ps(v, hi, _mm256_cmp_ps(v, hi, _CMP_GT_OQ));
  r = _mm256_blendv_ps(r, lo, _mm256_cmp_ps(v, lo, _CMP_LT_OQ));
  return _mm256_blendv_ps(r, lo, _mm256_cmp_ps(v, v, _CMP_UNORD_Q));
}

// The texture wrap of an index within [-size, 2 size).
DHR_AVX512_TARGET inline __m256i wrap_x8(__m256i i, __m256i size) {
  const __m256i below = _mm256_cmpgt_epi32(_mm256_setzero_si256(), i);
  const __m256i above = _mm256_cmpgt_epi32(i, _mm256_sub_epi32(size, _mm256_set1_epi32(1)));
  return _mm256_sub_epi32(_mm256_add_epi32(i, _mm256_and_si256(below, size)), _mm256_and_si256(above, size));
}

// Texture::sample_bilinear's linear RGB (core/scene.cpp) at 8 points, with its operations in its
// order: 4 texels gathered per lane, their sRGB codes looked up in the same table. Returns false
// (nothing written) where the scalar lookup must run instead: a texture it would reject, one
// with too many texels for 32-bit indices, or a lane whose texel lies more than one texture
// size outside the texture (the scalar wrap's modulo; a coordinate wrapped into [0, 1] never
// does). Lanes n..7 give 0.
DHR_AVX512_TARGET bool texture_rgb_x8(const Texture& tex, __m256 u, __m256 v, unsigned n, Vec3x8& rgb) {
  const int w = tex.width, h = tex.height;
  if (w <= 0 || h <= 0 || tex.texels.size() != size_t(w) * size_t(h) || tex.texels.size() > size_t(1) << 30)
    return false;
  const __m256 inf = _mm256_set1_ps(INFINITY), sign = _mm256_set1_ps(-0.0f);
  const __m256i live = _mm256_cmpgt_epi32(_mm256_set1_epi32(int(n)), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
  const __m256 use = _mm256_and_ps(
      _mm256_castsi256_ps(live), _mm256_and_ps(_mm256_cmp_ps(_mm256_andnot_ps(sign, u), inf, _CMP_LT_OQ),
                                               _mm256_cmp_ps(_mm256_andnot_ps(sign, v), inf, _CMP_LT_OQ)));
  const __m256 half = _mm256_set1_ps(0.5f);
  const __m256 x = _mm256_sub_ps(_mm256_mul_ps(_mm256_sub_ps(u, _mm256_floor_ps(u)), _mm256_set1_ps(float(w))), half);
  const __m256 y = _mm256_sub_ps(
      _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(1.0f), _mm256_sub_ps(v, _mm256_floor_ps(v))), _mm256_set1_ps(float(h))),
      half);
  const __m256 fx = _mm256_floor_ps(x), fy = _mm256_floor_ps(y);
  const __m256 wx = _mm256_sub_ps(x, fx), wy = _mm256_sub_ps(y, fy);
  // Integral floats in range convert exactly; unused lanes take texel (0, 0).
  const __m256i ix = _mm256_and_si256(_mm256_cvttps_epi32(fx), _mm256_castps_si256(use));
  const __m256i iy = _mm256_and_si256(_mm256_cvttps_epi32(fy), _mm256_castps_si256(use));
  const __m256i W = _mm256_set1_epi32(w), H = _mm256_set1_epi32(h), one = _mm256_set1_epi32(1);
  // ix and ix + 1 within [-w, 2w): ix >= -w and ix + 1 < 2w, likewise iy.
  const __m256i out_of_reach = _mm256_or_si256(
      _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(_mm256_setzero_si256(), W), ix),
                      _mm256_cmpgt_epi32(_mm256_add_epi32(ix, one), _mm256_sub_epi32(_mm256_add_epi32(W, W), one))),
      _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(_mm256_setzero_si256(), H), iy),
                      _mm256_cmpgt_epi32(_mm256_add_epi32(iy, one), _mm256_sub_epi32(_mm256_add_epi32(H, H), one))));
  if (!_mm256_testz_si256(out_of_reach, out_of_reach)) return false;
  const __m256i x0 = wrap_x8(ix, W), x1 = wrap_x8(_mm256_add_epi32(ix, one), W);
  const __m256i y0 = wrap_x8(iy, H), y1 = wrap_x8(_mm256_add_epi32(iy, one), H);
  const int* texels = reinterpret_cast<const int*>(tex.texels.data());
  const float* lut = srgb_table().data();
  const __m256i row0 = _mm256_mullo_epi32(y0, W), row1 = _mm256_mullo_epi32(y1, W);
  const __m256i t00 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row0, x0), 4);
  const __m256i t10 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row0, x1), 4);
  const __m256i t01 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row1, x0), 4);
  const __m256i t11 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row1, x1), 4);
  const __m256 one_f = _mm256_set1_ps(1.0f);
  const __m256 ax = _mm256_sub_ps(one_f, wx), ay = _mm256_sub_ps(one_f, wy);
  __m256 c[3];
  for (int k = 0; k < 3; ++k) {
    const __m256i byte = _mm256_set1_epi32(0xff);
    const __m256 c00 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t00, 8 * k), byte), 4);
    const __m256 c10 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t10, 8 * k), byte), 4);
    const __m256 c01 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t01, 8 * k), byte), 4);
    const __m256 c11 = _mm256_i32gather_ps(lut, _mm256_and_si256(_mm256_srli_epi32(t11, 8 * k), byte), 4);
    // glm::mix(a, b, t) = a (1 - t) + b t, along x in both rows, then along y.
    const __m256 r0 = _mm256_add_ps(_mm256_mul_ps(c00, ax), _mm256_mul_ps(c10, wx));
    const __m256 r1 = _mm256_add_ps(_mm256_mul_ps(c01, ax), _mm256_mul_ps(c11, wx));
    c[k] = _mm256_and_ps(_mm256_add_ps(_mm256_mul_ps(r0, ay), _mm256_mul_ps(r1, wy)), use);
  }
  rgb = {c[0], c[1], c[2]};
  return true;
}

// m * v of a glm::mat3 (m[0][r] v.x + m[1][r] v.y) + m[2][r] v.z, as glm evaluates it.
DHR_AVX512_TARGET inline Vec3x8 mat3_x8(const glm::mat3& m, const Vec3x8& v) {
  __m256 r[3];
  for (int k = 0; k < 3; ++k)
    r[k] = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(m[0][k]), v.x), _mm256_mul_ps(_mm256_set1_ps(m[1][k]), v.y)),
                         _mm256_mul_ps(_mm256_set1_ps(m[2][k]), v.z));
  return {r[0], r[1], r[2]};
}

// The xyz of m * vec4(v, 1) of a glm::mat4: (m[0][r] v.x + m[1][r] v.y) + (m[2][r] v.z + m[3][r] 1),
// as glm evaluates it.
DHR_AVX512_TARGET inline Vec3x8 point_x8(const glm::mat4& m, const Vec3x8& v) {
  __m256 r[3];
  for (int k = 0; k < 3; ++k)
    r[k] = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(m[0][k]), v.x), _mm256_mul_ps(_mm256_set1_ps(m[1][k]), v.y)),
        _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(m[2][k]), v.z), _mm256_mul_ps(_mm256_set1_ps(m[3][k]), _mm256_set1_ps(1.0f))));
  return {r[0], r[1], r[2]};
}

// resolve() of pixels x .. x + n - 1 (n in 1..8) of row y, all of whose nearest fragment is
// `st`.
DHR_AVX512_TARGET void resolve_x8(const Context& ctx, const Setup& st, int x, int y, unsigned n, GBuffer& out) {
  const ObjectPrep& p = ctx.objects[st.object];
  const Mesh& mesh = *p.mesh;
  const glm::uvec3 t = st.tri;
  const Camera& cam = *ctx.camera;
  const __mmask8 live = __mmask8((1u << n) - 1);
  const __m512d px = pixel_centres_x8(x);
  const double py = y + 0.5;

  // barycentrics(), with its clamp taken lane by lane where a lane needs it (rare).
  const __m512d inv_us = _mm512_div_pd(_mm512_set1_pd(1.0), plane_x8(st.rs, px, py));
  __m512d b1 = _mm512_mul_pd(plane_x8(st.r1, px, py), inv_us);
  __m512d b2 = _mm512_mul_pd(plane_x8(st.r2, px, py), inv_us);
  __m512d b0 = _mm512_sub_pd(_mm512_sub_pd(_mm512_set1_pd(1.0), b1), b2);
  const __m512d zero = _mm512_setzero_pd();
  const __mmask8 inside = _mm512_cmp_pd_mask(b0, zero, _CMP_GE_OQ) & _mm512_cmp_pd_mask(b1, zero, _CMP_GE_OQ) &
                          _mm512_cmp_pd_mask(b2, zero, _CMP_GE_OQ);
  if (__mmask8 clamp = __mmask8(live & ~inside)) {
    alignas(64) double a0[8], a1[8], a2[8];
    _mm512_store_pd(a0, b0);
    _mm512_store_pd(a1, b1);
    _mm512_store_pd(a2, b2);
    for (unsigned i = 0; i < n; ++i)
      if (clamp & (1u << i)) {
        const glm::dvec3 b = barycentrics(st, double(x + int(i)) + 0.5, py);
        a0[i] = b.x, a1[i] = b.y, a2[i] = b.z;
      }
    b0 = _mm512_load_pd(a0), b1 = _mm512_load_pd(a1), b2 = _mm512_load_pd(a2);
  }

  const Vec3x8 pos{_mm512_cvtpd_ps(blend3_pd(st.v[0].x, st.v[1].x, st.v[2].x, b0, b1, b2)),
                   _mm512_cvtpd_ps(blend3_pd(st.v[0].y, st.v[1].y, st.v[2].y, b0, b1, b2)),
                   _mm512_cvtpd_ps(blend3_pd(st.v[0].z, st.v[1].z, st.v[2].z, b0, b1, b2))};
  const Vec3x8 to_cam = sub_x8(broadcast_x8(cam.position), pos);

  const glm::vec3 ng0 = st.geo_normal.x != 0.0f || st.geo_normal.y != 0.0f || st.geo_normal.z != 0.0f ? st.geo_normal
                                                                                                       : -cam.forward;
  const Vec3x8 ng0x8 = broadcast_x8(ng0);
  const __m256 zero_ps = _mm256_setzero_ps();
  const Vec3x8 ng = negate_where_x8(ng0x8, _mm256_cmp_ps(dot_x8(ng0x8, to_cam), zero_ps, _CMP_LT_OQ));
  Vec3x8 ns = ng;
  const __m256 bf0 = _mm512_cvtpd_ps(b0), bf1 = _mm512_cvtpd_ps(b1), bf2 = _mm512_cvtpd_ps(b2);
  if (!mesh.normals.empty()) {
    const glm::vec3 &n0 = mesh.normals[t.x], &n1 = mesh.normals[t.y], &n2 = mesh.normals[t.z];
    Vec3x8 nv{blend3_ps(n0.x, n1.x, n2.x, bf0, bf1, bf2), blend3_ps(n0.y, n1.y, n2.y, bf0, bf1, bf2),
              blend3_ps(n0.z, n1.z, n2.z, bf0, bf1, bf2)};
    if (p.moving) nv = mat3_x8(p.normal_matrix, nv);
    const __m256 len = _mm256_sqrt_ps(dot_x8(nv, nv));
    const __m256 ok = _mm256_and_ps(_mm256_cmp_ps(len, _mm256_set1_ps(1e-12f), _CMP_GT_OQ),
                                    _mm256_cmp_ps(len, _mm256_set1_ps(INFINITY), _CMP_LT_OQ));
    const Vec3x8 unit{_mm256_div_ps(nv.x, len), _mm256_div_ps(nv.y, len), _mm256_div_ps(nv.z, len)};
    const Vec3x8 facing = negate_where_x8(unit, _mm256_cmp_ps(dot_x8(unit, to_cam), zero_ps, _CMP_LT_OQ));
    ns = select_x8(ns, facing, ok);
  }

  Vec3x8 albedo = broadcast_x8(p.material->albedo);
  if (p.texture) {
    const glm::vec2 &u0 = mesh.uvs[t.x], &u1 = mesh.uvs[t.y], &u2 = mesh.uvs[t.z];
    const __m256 uu = blend3_ps(u0.x, u1.x, u2.x, bf0, bf1, bf2), vv = blend3_ps(u0.y, u1.y, u2.y, bf0, bf1, bf2);
    Vec3x8 rgb;
    if (texture_rgb_x8(*p.texture, uu, vv, n, rgb)) {
      albedo = {_mm256_mul_ps(albedo.x, rgb.x), _mm256_mul_ps(albedo.y, rgb.y), _mm256_mul_ps(albedo.z, rgb.z)};
    } else {
      alignas(32) float u[8], v[8], ax[8], ay[8], az[8];
      _mm256_store_ps(u, uu);
      _mm256_store_ps(v, vv);
      const glm::vec3 base = p.material->albedo;
      for (unsigned i = 0; i < 8; ++i) {
        const glm::vec4 tex = i < n ? p.texture->sample_bilinear({u[i], v[i]}) : glm::vec4(0.0f);
        ax[i] = base.x * tex.x, ay[i] = base.y * tex.y, az[i] = base.z * tex.z;
      }
      albedo = {_mm256_load_ps(ax), _mm256_load_ps(ay), _mm256_load_ps(az)};
    }
  }

  __m256 mx = zero_ps, my = zero_ps;
  if (!(p.static_motion && ctx.same_cameras)) {
    Vec3x8 prev = pos;
    if (!p.static_motion) {  // the same surface point, placed at prev_time_s
      const auto& o = mesh.positions;
      const glm::vec3 &o0 = o[t.x], &o1 = o[t.y], &o2 = o[t.z];
      const Vec3x8 obj{_mm512_cvtpd_ps(blend3_pd(o0.x, o1.x, o2.x, b0, b1, b2)),
                       _mm512_cvtpd_ps(blend3_pd(o0.y, o1.y, o2.y, b0, b1, b2)),
                       _mm512_cvtpd_ps(blend3_pd(o0.z, o1.z, o2.z, b0, b1, b2))};
      prev = point_x8(p.world_from_object_prev, obj);
    }
    const Projector& pp = ctx.prev_proj;
    const Vec3x8 d = sub_x8(prev, broadcast_x8(pp.position));
    const __m256 z = dot_x8(d, broadcast_x8(pp.forward));
    const __m256 tan_half = _mm256_set1_ps(pp.tan_half);
    const __m256 qx = _mm256_div_ps(dot_x8(d, broadcast_x8(pp.right)),
                                    _mm256_mul_ps(_mm256_mul_ps(z, tan_half), _mm256_set1_ps(pp.aspect)));
    const __m256 qy = _mm256_div_ps(dot_x8(d, broadcast_x8(pp.up)), _mm256_mul_ps(z, tan_half));
    const __m256 half = _mm256_set1_ps(0.5f), one = _mm256_set1_ps(1.0f);
    const __m256 sx = _mm256_mul_ps(_mm256_mul_ps(_mm256_add_ps(qx, one), half), _mm256_set1_ps(float(pp.width)));
    const __m256 sy = _mm256_mul_ps(_mm256_mul_ps(_mm256_sub_ps(one, qy), half), _mm256_set1_ps(float(pp.height)));
    const __m256 in_front = _mm256_cmp_ps(z, zero_ps, _CMP_GT_OQ);
    const __m256 behind = _mm256_set1_ps(-kMaxMotionPx);
    mx = _mm256_blendv_ps(
        behind, motion_offset_x8(_mm256_sub_ps(_mm256_mul_ps(sx, _mm256_set1_ps(ctx.motion_scale_x)), _mm512_cvtpd_ps(px))),
        in_front);
    my = _mm256_blendv_ps(
        behind, motion_offset_x8(_mm256_sub_ps(_mm256_mul_ps(sy, _mm256_set1_ps(ctx.motion_scale_y)), _mm256_set1_ps(float(py)))),
        in_front);
  }

  const __mmask16 lanes = __mmask16(live);
  _mm512_mask_storeu_ps(&out.depth(x, y), lanes,
                        _mm512_castps256_ps512(dot_x8(sub_x8(pos, broadcast_x8(cam.position)), broadcast_x8(cam.forward))));
  store_vec3_x8(&out.position(x, y), pos, n);
  store_vec3_x8(&out.normal(x, y), ns, n);
  store_vec3_x8(&out.geo_normal(x, y), ng, n);
  store_vec3_x8(&out.albedo(x, y), albedo, n);
  _mm512_mask_storeu_epi32(&out.object_id(x, y), lanes, _mm512_set1_epi32(int(p.object->id)));
  _mm512_mask_storeu_epi32(&out.prim_id(x, y), lanes, _mm512_set1_epi32(int(st.prim)));
  store_vec2_x8(&out.bary(x, y), bf1, bf2, n);
  store_vec2_x8(&out.motion(x, y), mx, my, n);
}
#endif

void raster_tile(const Context& ctx, std::span<const TriangleJobOut> jobs, int tile, TileScratch& s, GBuffer& out,
                 uint64_t& fragments) {
  const int X0 = (tile % ctx.tiles_x) * kTile, Y0 = (tile / ctx.tiles_x) * kTile;
  const int X1 = std::min(X0 + kTile, ctx.width) - 1, Y1 = std::min(Y0 + kTile, ctx.height) - 1;
  s.inv_w.fill(0.0);
  s.setup.fill(kNoSetup);
  s.setups.clear();
  for (const TriangleJobOut& job : jobs)
    for (uint32_t i = job.tile_begin[size_t(tile)]; i < job.tile_begin[size_t(tile) + 1]; ++i)
      cover(ctx, job.tris[job.tile_tris[i]], X0, Y0, X1, Y1, s, fragments);

  for (int y = Y0; y <= Y1; ++y) {
    const uint32_t* row = s.setup.data() + size_t(y - Y0) * kTile;
    for (int x = X0; x <= X1; ++x) {
      const uint32_t sid = row[x - X0];
      if (sid != kNoSetup) {
#if DHR_AVX512_KERNELS
        // Up to 8 pixels of the row with the same nearest fragment at once.
        if (ctx.wide_kernels) {
          int end = x + 1;
          while (end <= X1 && end - x < 8 && row[end - X0] == sid) ++end;
          resolve_x8(ctx, s.setups[sid], x, y, unsigned(end - x), out);
          x = end - 1;
          continue;
        }
#endif
        resolve(ctx, s.setups[sid], x, y, out);
        continue;
      }
      out.depth(x, y) = kBackgroundDepth;
      out.position(x, y) = glm::vec3(0.0f);
      out.normal(x, y) = glm::vec3(0.0f);
      out.geo_normal(x, y) = glm::vec3(0.0f);
      out.albedo(x, y) = glm::vec3(0.0f);
      out.object_id(x, y) = kBackgroundId;
      out.prim_id(x, y) = 0;
      out.bary(x, y) = glm::vec2(0.0f);
      out.motion(x, y) = glm::vec2(0.0f);
    }
  }
}

// Per-call buffers, kept by the calling thread between calls (capacity reused frame after
// frame; core/workspace.h).
struct Workspace {
  std::vector<View3> view;
  std::vector<TriangleJobOut> binned;
};

bool has_size(const GBuffer& g, int w, int h) {
  bool all = true;
  g.for_each_plane([&](const auto& plane) { all = all && plane.same_size(w, h); });
  return all;
}

}  // namespace

bool same_raster_frame(const RasterFrame& a, const RasterFrame& b) {
  return a.scene == b.scene && a.time_s == b.time_s && a.prev_time_s == b.prev_time_s &&
         same_camera(a.camera, b.camera) && same_camera(a.prev_camera, b.prev_camera);
}

RasterStats rasterize(const RasterFrame& frame, GBuffer& out) {
  const auto start = std::chrono::steady_clock::now();
  if (!frame.scene) fail("rasterize: frame.scene is null");
  check_camera(frame.camera, "camera");
  check_camera(frame.prev_camera, "prev_camera");
  if (!std::isfinite(frame.time_s) || !std::isfinite(frame.prev_time_s))
    fail("rasterize: time_s {} and prev_time_s {} must be finite", frame.time_s, frame.prev_time_s);

  const Camera& cam = frame.camera;
  Context ctx{frame.scene, &cam, Projector(cam), Projector(frame.prev_camera), same_camera(cam, frame.prev_camera),
              float(cam.width) / float(frame.prev_camera.width), float(cam.height) / float(frame.prev_camera.height),
              1.0 / double(cam.near_m), 1.0 / double(cam.far_m), cam.width, cam.height,
              (cam.width + kTile - 1) / kTile, (cam.height + kTile - 1) / kTile, {}, nullptr};
#if DHR_AVX512_KERNELS
  ctx.wide_kernels = cpu_has_avx512dq();
#endif
  size_t total_vertices = 0;
  prepare_objects(ctx, frame, total_vertices);
  WorkspaceLease<Workspace> lease;
  Workspace& ws = *lease;
  ws.view.resize(total_vertices);
  ctx.view = ws.view.data();
  transform_vertices(ctx);

  RasterStats stats;
  std::vector<Job> jobs;
  for (size_t i = 0; i < ctx.objects.size(); ++i) {
    const size_t nt = ctx.objects[i].mesh->triangles.size();
    stats.triangles_in += nt;
    for (size_t b = 0; b < nt; b += kTriangleJob) jobs.push_back({uint32_t(i), b, std::min(nt, b + kTriangleJob)});
  }
  if (ws.binned.size() < jobs.size()) ws.binned.resize(jobs.size());
  std::vector<TriangleJobOut>& binned = ws.binned;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, jobs.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t j = r.begin(); j != r.end(); ++j) setup_triangles(ctx, jobs[j], binned[j]);
  });
  for (size_t j = 0; j < jobs.size(); ++j) {
    stats.triangles_clipped += binned[j].clipped;
    stats.triangles_culled += binned[j].culled;
  }

  // Sized without a fill: raster_tile writes every pixel of its tile, so the planes' fresh pages
  // are first touched by the tiles, on every core.
  if (!has_size(out, cam.width, cam.height)) out.resize_for_overwrite(cam.width, cam.height);
  out.camera = cam;
  out.time_s = frame.time_s;
  const int tiles = ctx.tiles_x * ctx.tiles_y;
  const std::span<const TriangleJobOut> jobs_out(binned.data(), jobs.size());
  std::vector<uint64_t> fragments(size_t(tiles), 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles, 1), [&](const tbb::blocked_range<int>& r) {
    // Per worker thread, reused across calls (no nested parallelism inside a tile, so a
    // thread never interleaves two tiles).
    static thread_local TileScratch s;
    for (int t = r.begin(); t != r.end(); ++t) raster_tile(ctx, jobs_out, t, s, out, fragments[size_t(t)]);
  });
  for (uint64_t f : fragments) stats.fragments += f;
  stats.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

}  // namespace dhr
