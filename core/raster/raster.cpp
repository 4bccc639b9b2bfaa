// The client's tile-binned CPU rasterizer (see core/raster/raster.h for the pipeline and every
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
#include "core/raster/raster.h"

#include "core/base/error.h"
#include "core/base/workspace.h"
#include "core/raster/raster_detail.h"

#include <glm/gtc/matrix_inverse.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <span>
#include <vector>

namespace dhr {

namespace raster_detail {

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

}  // namespace raster_detail

namespace {

using namespace raster_detail;

constexpr int kSubpixelBits = 8;
constexpr int64_t kSubpixel = int64_t(1) << kSubpixelBits;
constexpr int64_t kHalfSubpixel = kSubpixel / 2;
// Vertices are kept within +-kGuardBandPx after clipping: fixed-point coordinates stay below
// 2^29 in magnitude, differences below 2^30 and edge-function values below 2^62.
constexpr double kGuardBandPx = double(1 << 21);
constexpr float kMaxCoordinate = 1e18f;  // same limit as RtScene's build
constexpr size_t kTriangleJob = 8192;    // triangles per setup/binning job
constexpr size_t kVertexJob = 16384;     // vertices per transform job

bool finite3(const glm::vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

void check_camera(const Camera& c, const char* which) {
  if (!finite3(c.position) || !finite3(c.forward) || !finite3(c.up))
    fail("rasterize: {} has a non-finite position, forward or up vector", which);
  if (std::abs(glm::length(c.forward) - 1.0f) > 1e-3f || std::abs(glm::length(c.up) - 1.0f) > 1e-3f ||
      std::abs(glm::dot(c.forward, c.up)) > 1e-3f)
    fail("rasterize: {} needs unit, orthogonal forward and up vectors (use Camera::look_at)", which);
  if (!(c.vfov_deg > 0.0f && c.vfov_deg < 180.0f))
    fail("rasterize: {} vfov_deg {} is outside (0, 180)", which, c.vfov_deg);
  if (!(c.near_m > 0.0f && c.far_m > c.near_m && std::isfinite(c.far_m)))
    fail("rasterize: {} needs 0 < near_m < far_m (finite), got near_m {} far_m {}", which, c.near_m, c.far_m);
  if (c.width <= 0 || c.height <= 0) fail("rasterize: {} resolution {}x{} must be positive", which, c.width, c.height);
  check_image_size(c.width, c.height);
}

bool same_camera(const Camera& a, const Camera& b) {
  return a.position == b.position && a.forward == b.forward && a.up == b.up && a.vfov_deg == b.vfov_deg &&
         a.near_m == b.near_m && a.far_m == b.far_m && a.width == b.width && a.height == b.height;
}

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
      fail("rasterize: object '{}' has {} uvs for {} positions (need one per vertex or none)", o.name,
           o.mesh.uvs.size(), nv);
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
      n = clip_polygon(
          poly, n, tmp, [&](const Hom& v) { return v.w - near_w; }, true, near_w);
      n = clip_polygon(
          tmp, n, poly, [&](const Hom& v) { return v.x + g * v.w; }, false, 0.0);
      n = clip_polygon(
          poly, n, tmp, [&](const Hom& v) { return g * v.w - v.x; }, false, 0.0);
      n = clip_polygon(
          tmp, n, poly, [&](const Hom& v) { return v.y + g * v.w; }, false, 0.0);
      n = clip_polygon(
          poly, n, tmp, [&](const Hom& v) { return g * v.w - v.y; }, false, 0.0);
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

// Visibility pass of one coverage triangle within the tile [X0, X1] x [Y0, Y1].
void cover(const Context& ctx, const CoverTri& c, int X0, int Y0, int X1, int Y1, TileScratch& s, uint64_t& fragments) {
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

  glm::vec3 ng =
      st.geo_normal.x != 0.0f || st.geo_normal.y != 0.0f || st.geo_normal.z != 0.0f ? st.geo_normal : -cam.forward;
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
        return std::isfinite(v) ? std::clamp(v, -kMaxMotionPx, kMaxMotionPx)
                                : (v > 0.0f ? kMaxMotionPx : -kMaxMotionPx);
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
// frame; core/base/workspace.h).
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
  Context ctx{frame.scene,
              &cam,
              Projector(cam),
              Projector(frame.prev_camera),
              same_camera(cam, frame.prev_camera),
              float(cam.width) / float(frame.prev_camera.width),
              float(cam.height) / float(frame.prev_camera.height),
              1.0 / double(cam.near_m),
              1.0 / double(cam.far_m),
              cam.width,
              cam.height,
              (cam.width + kTile - 1) / kTile,
              (cam.height + kTile - 1) / kTile,
              {},
              nullptr};
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
