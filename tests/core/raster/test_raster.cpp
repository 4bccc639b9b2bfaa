// The CPU rasterizer (core/raster/raster.h): coverage rules, clipping, robustness, consistency with
// the camera's primary rays, every G-buffer field, motion vectors and thread-count
// independence. Small images, so that the suite stays fast under AddressSanitizer.
#include "core/raster/raster.h"

#include "core/base/error.h"
#include "core/buffers/camera.h"
#include "core/buffers/gbuffer.h"
#include "core/scene/scene.h"
#include "core/scene/shapes.h"
#include "core/trace/rt_scene.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

namespace dhr {
namespace {

Camera make_camera(glm::vec3 pos, glm::vec3 target, int w = 64, int h = 48, float fov = 60.0f, float near_m = 0.05f,
                   float far_m = 100.0f) {
  return Camera::look_at(pos, target, {0, 1, 0}, fov, w, h, near_m, far_m);
}

Scene empty_scene() {
  Scene s;
  s.name = "test";
  s.materials.push_back(Material{"grey", glm::vec3(0.5f), -1, false, 0.5f, false});
  return s;
}

// A quad a-b-c-d (two triangles a,b,c and a,c,d) with per-vertex normal `n` and uvs
// (0,0), (1,0), (1,1), (0,1).
Object quad(uint32_t id, glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 d, uint32_t material = 0) {
  Object o;
  o.name = "quad" + std::to_string(id);
  o.id = id;
  o.material = material;
  o.mesh.positions = {a, b, c, d};
  const glm::vec3 n = glm::normalize(glm::cross(b - a, c - a));
  o.mesh.normals = {n, n, n, n};
  o.mesh.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  o.mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  return o;
}

// An axis-aligned quad facing +z at depth z (camera at the origin looking down -z).
Object facing_quad(uint32_t id, float x0, float y0, float x1, float y1, float z, uint32_t material = 0) {
  return quad(id, {x0, y0, z}, {x1, y0, z}, {x1, y1, z}, {x0, y1, z}, material);
}

Object with_shape(uint32_t id, Mesh mesh, glm::vec3 offset) {
  Object o;
  o.name = "shape" + std::to_string(id);
  o.id = id;
  for (auto& p : mesh.positions) p += offset;
  o.mesh = std::move(mesh);
  return o;
}

RasterFrame still(const Scene& scene, const Camera& cam, double t = 0.0) { return {&scene, cam, t, cam, t}; }

GBuffer render(const Scene& scene, const Camera& cam, RasterStats* stats = nullptr) {
  GBuffer g;
  const RasterStats s = rasterize(still(scene, cam), g);
  if (stats) *stats = s;
  return g;
}

template <class T>
bool bytes_equal(const Image<T>& a, const Image<T>& b) {
  return a.same_size(b) && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

bool identical(const GBuffer& a, const GBuffer& b) {
  return bytes_equal(a.depth, b.depth) && bytes_equal(a.position, b.position) && bytes_equal(a.normal, b.normal) &&
         bytes_equal(a.geo_normal, b.geo_normal) && bytes_equal(a.albedo, b.albedo) &&
         bytes_equal(a.object_id, b.object_id) && bytes_equal(a.prim_id, b.prim_id) && bytes_equal(a.bary, b.bary) &&
         bytes_equal(a.motion, b.motion);
}

bool finite(glm::vec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }
bool finite(glm::vec2 v) { return std::isfinite(v.x) && std::isfinite(v.y); }

// No NaN anywhere; covered pixels are finite everywhere, with unit normals.
void expect_well_formed(const GBuffer& g) {
  int bad = 0;
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) {
      const bool ok_common = finite(g.position(x, y)) && finite(g.normal(x, y)) && finite(g.geo_normal(x, y)) &&
                             finite(g.albedo(x, y)) && finite(g.bary(x, y)) && finite(g.motion(x, y));
      if (g.covered(x, y)) {
        const bool ok = ok_common && std::isfinite(g.depth(x, y)) &&
                        std::abs(glm::length(g.normal(x, y)) - 1.0f) < 1e-4f &&
                        std::abs(glm::length(g.geo_normal(x, y)) - 1.0f) < 1e-4f;
        bad += !ok;
      } else {
        bad += !(ok_common && g.depth(x, y) == kBackgroundDepth);
      }
    }
  EXPECT_EQ(bad, 0);
}

int covered_count(const GBuffer& g, uint32_t id = 0) {
  int n = 0;
  for (uint32_t v : g.object_id.pixels()) n += id == 0 ? v != kBackgroundId : v == id;
  return n;
}

TEST(Raster, FullScreenQuadCoversEveryPixelOnceWithExactDepth) {
  Scene s = empty_scene();
  s.objects.push_back(facing_quad(1, -10, -10, 10, 10, -2.0f));
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  RasterStats st;
  const GBuffer g = render(s, cam, &st);
  ASSERT_EQ(g.width(), 64);
  ASSERT_EQ(g.height(), 48);
  EXPECT_EQ(st.triangles_in, 2u);
  EXPECT_EQ(st.fragments, uint64_t(64 * 48));
  EXPECT_EQ(covered_count(g, 1), 64 * 48);
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      ASSERT_EQ(g.depth(x, y), 2.0f) << x << "," << y;
      ASSERT_EQ(g.position(x, y).z, -2.0f);
      ASSERT_LT(g.prim_id(x, y), 2u);
      ASSERT_EQ(g.normal(x, y), glm::vec3(0, 0, 1));
      ASSERT_EQ(g.geo_normal(x, y), glm::vec3(0, 0, 1));
      ASSERT_EQ(g.albedo(x, y), glm::vec3(0.5f));
      ASSERT_EQ(g.motion(x, y), glm::vec2(0.0f));
    }
  EXPECT_EQ(g.camera.width, 64);
  expect_well_formed(g);
}

// A square image whose diagonal and centre vertex fall exactly on pixel centres: the fill
// rule must give every pixel to exactly one triangle.
TEST(Raster, SharedEdgesThroughPixelCentresCoverEachPixelOnce) {
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1}, 48, 48, 90.0f);
  // At z = -1 the frustum is [-1, 1]^2 and pixel x spans X in [x/24 - 1, (x+1)/24 - 1].
  const float c = 24.5f / 24.0f - 1.0f;  // the centre of pixel (24, 23) in x... and y below
  const float cy = 1.0f - 24.5f / 24.0f;
  Scene s = empty_scene();
  Object fan;
  fan.id = 1;
  fan.mesh.positions = {{c, cy, -1}, {-1, 1, -1}, {0, 1, -1},   {1, 1, -1}, {1, 0, -1},
                        {1, -1, -1}, {0, -1, -1}, {-1, -1, -1}, {-1, 0, -1}};
  for (uint32_t i = 1; i <= 8; ++i) fan.mesh.triangles.push_back({0, i, i % 8 + 1});
  s.objects.push_back(fan);
  RasterStats st;
  const GBuffer g = render(s, cam, &st);
  EXPECT_EQ(st.fragments, uint64_t(48 * 48));
  EXPECT_EQ(covered_count(g, 1), 48 * 48);

  // The same square split along its diagonal, which runs through every pixel centre (x+.5, x+.5).
  Scene d = empty_scene();
  d.objects.push_back(facing_quad(1, -1, -1, 1, 1, -1));
  const GBuffer gd = render(d, cam, &st);
  EXPECT_EQ(st.fragments, uint64_t(48 * 48));
  EXPECT_EQ(covered_count(gd, 1), 48 * 48);
}

// A jittered grid of triangles across several tiles: no gaps, no pixel written twice.
TEST(Raster, JitteredMeshHasNoCracksNorOverlaps) {
  const int w = 150, h = 100;
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1}, w, h);
  const int nx = 23, ny = 17;
  Object grid;
  grid.id = 1;
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i) {
      float x = -6.0f + 12.0f * float(i) / nx, y = -4.0f + 8.0f * float(j) / ny;
      if (i > 0 && i < nx && j > 0 && j < ny) {  // deterministic jitter of interior vertices
        const uint32_t hsh = uint32_t(i * 7919 + j * 104729) * 2654435761u;
        x += (float(hsh & 1023) / 1023.0f - 0.5f) * 0.3f * 12.0f / nx;
        y += (float((hsh >> 10) & 1023) / 1023.0f - 0.5f) * 0.3f * 8.0f / ny;
      }
      // Slanted in depth so that 1/w varies across the mesh.
      grid.mesh.positions.push_back({x, y, -2.0f - 0.2f * x + 0.1f * y});
    }
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const uint32_t a = uint32_t(j * (nx + 1) + i), b = a + 1, c = a + uint32_t(nx + 1), d = c + 1;
      if ((i + j) % 2) {
        grid.mesh.triangles.push_back({a, b, d});
        grid.mesh.triangles.push_back({a, d, c});
      } else {  // also flip the winding of some: no culling, same coverage
        grid.mesh.triangles.push_back({a, c, b});
        grid.mesh.triangles.push_back({b, c, d});
      }
    }
  Scene s = empty_scene();
  s.objects.push_back(grid);
  RasterStats st;
  const GBuffer g = render(s, cam, &st);
  EXPECT_EQ(st.fragments, uint64_t(w * h));
  EXPECT_EQ(covered_count(g, 1), w * h);
  expect_well_formed(g);
}

TEST(Raster, DepthTestIsOrderIndependentAndBreaksTiesBySmallerId) {
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  std::vector<Object> objs = {facing_quad(5, -3, -3, 3, 3, -2.0f), facing_quad(3, -3, -3, 3, 3, -2.0f),
                              facing_quad(7, -0.5f, -0.5f, 0.5f, 0.5f, -1.0f),
                              quad(9, {-3, -0.2f, -3}, {3, -0.2f, -1.5f}, {3, 0.2f, -1.5f}, {-3, 0.2f, -3})};
  std::vector<int> order = {0, 1, 2, 3};
  GBuffer first;
  bool have_first = false;
  do {
    Scene s = empty_scene();
    for (int i : order) s.objects.push_back(objs[size_t(i)]);
    const GBuffer g = render(s, cam);
    if (!have_first) {
      first = g;
      have_first = true;
      // The coplanar, identical quads tie exactly: id 3 beats id 5 everywhere.
      EXPECT_EQ(covered_count(g, 5), 0);
      EXPECT_GT(covered_count(g, 3), 0);
      EXPECT_EQ(g.object_id(32, 24), 7u);  // the nearest quad, in the centre
      EXPECT_EQ(g.depth(32, 24), 1.0f);
      EXPECT_EQ(g.object_id(2, 2), 3u);
      EXPECT_EQ(g.depth(2, 2), 2.0f);
      EXPECT_GT(covered_count(g, 9), 0);  // the slanted quad pierces the far pair
    } else {
      EXPECT_TRUE(identical(first, g));
    }
  } while (std::next_permutation(order.begin(), order.end()));
}

// Ray/triangle test in double for a reference coverage.
bool ray_hits(const Ray& r, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c, double& t, double& margin) {
  const glm::dvec3 o(r.origin), d(r.direction);
  const glm::dvec3 e1 = b - a, e2 = c - a, p = glm::cross(d, e2);
  const double det = glm::dot(e1, p);
  if (std::abs(det) < 1e-300) return false;
  const glm::dvec3 s = o - a;
  const double u = glm::dot(s, p) / det;
  const glm::dvec3 q = glm::cross(s, e1);
  const double v = glm::dot(d, q) / det;
  t = glm::dot(e2, q) / det;
  margin = std::min({u, v, 1.0 - u - v});
  return t > 0.0;
}

TEST(Raster, NearPlaneClippingGivesCorrectCoverageWithoutNaN) {
  // A floor triangle that reaches from far ahead to behind the camera.
  const glm::vec3 A{-50, -1, 20}, B{50, -1, 20}, C{0, -1, -80};
  const Camera cam = make_camera({0, 0, 0}, {0, -0.4f, -1});
  Scene s = empty_scene();
  Object tri;
  tri.id = 1;
  tri.mesh.positions = {A, B, C};
  tri.mesh.triangles = {{0, 1, 2}};
  s.objects.push_back(tri);
  RasterStats st;
  const GBuffer g = render(s, cam, &st);
  EXPECT_EQ(st.triangles_clipped, 1u);
  expect_well_formed(g);
  int mismatches = 0, hits = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const Ray r = cam.primary_ray(x + 0.5f, y + 0.5f);
      double t = 0, margin = 0;
      const bool hit = ray_hits(r, A, B, C, t, margin);
      if (hit && std::abs(margin) < 1e-3) continue;  // on an edge: either answer is fine
      const bool expect = hit && margin > 0.0 && cam.view_depth(r.origin + float(t) * r.direction) <= cam.far_m;
      hits += expect;
      mismatches += expect != g.covered(x, y);
      if (g.covered(x, y)) {
        EXPECT_NEAR(g.depth(x, y), cam.view_depth(r.origin + float(t) * r.direction), 1e-4 * t);
        EXPECT_NEAR(g.position(x, y).y, -1.0f, 1e-4f);
      }
    }
  EXPECT_GT(hits, 500);
  EXPECT_EQ(mismatches, 0);

  // Entirely behind the camera: nothing.
  Scene b = empty_scene();
  Object behind = tri;
  behind.mesh.positions = {{-1, -1, 1}, {1, -1, 1}, {0, 1, 0.01f}};
  b.objects.push_back(behind);
  const GBuffer gb = render(b, cam, &st);
  EXPECT_EQ(covered_count(gb), 0);
  EXPECT_EQ(st.triangles_culled, 1u);

  // A camera whose near plane cuts through a wall it stands in front of: the visible part is
  // the wall beyond the near plane, bary still refers to the original triangle.
  const Camera grazing = make_camera({0, 0, 0}, {1, 0, -0.05f});
  Scene w = empty_scene();
  w.objects.push_back(quad(1, {-5, -3, -0.5f}, {30, -3, -0.5f}, {30, 3, -0.5f}, {-5, 3, -0.5f}));
  const GBuffer gw = render(w, grazing, &st);
  expect_well_formed(gw);
  EXPECT_GT(covered_count(gw), 0);
  EXPECT_GT(st.triangles_clipped, 0u);
  for (int y = 0; y < gw.height(); ++y)
    for (int x = 0; x < gw.width(); ++x) {
      if (!gw.covered(x, y)) continue;
      EXPECT_GE(gw.depth(x, y), grazing.near_m * 0.999f);
      const glm::vec3 v[4] = {{-5, -3, -0.5f}, {30, -3, -0.5f}, {30, 3, -0.5f}, {-5, 3, -0.5f}};
      const glm::uvec3 t = gw.prim_id(x, y) == 0 ? glm::uvec3(0, 1, 2) : glm::uvec3(0, 2, 3);
      const glm::vec2 b = gw.bary(x, y);
      const glm::vec3 p = (1 - b.x - b.y) * v[t.x] + b.x * v[t.y] + b.y * v[t.z];
      EXPECT_LT(glm::length(p - gw.position(x, y)), 1e-4f * glm::length(gw.position(x, y)) + 1e-6f);
    }
}

TEST(Raster, DegenerateAndNonFiniteTrianglesAreSkipped) {
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  Scene clean = empty_scene();
  clean.objects.push_back(facing_quad(1, -1, -1, 1, 1, -3.0f));
  const GBuffer expected = render(clean, cam);

  Scene s = clean;
  Object junk;
  junk.id = 2;
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  junk.mesh.positions = {
      {-1, -1, -2},     {1, 1, -2},       {0, 0, -2},     // collinear: zero area
      {0.5f, 0.5f, -2}, {0.5f, 0.5f, -2},                 // repeated vertex
      {nan, 0, -2},     {inf, 1, -2},     {0, -inf, -2},  // non-finite
      {2e18f, 0, -2},   {0, 1e19f, -2},                   // huge
      {-1, 0, -2},      {1, 0, -2},       {0, 0, -2}};    // a line through the eye's plane... collinear
  junk.mesh.triangles = {{0, 1, 2}, {3, 4, 0}, {3, 3, 3}, {5, 0, 1},    {6, 0, 1},
                         {7, 1, 0}, {8, 0, 1}, {9, 1, 0}, {10, 11, 12}, {0, 1, 99}};  // last: index out of range
  s.objects.push_back(junk);
  RasterStats st;
  const GBuffer g = render(s, cam, &st);
  EXPECT_EQ(st.triangles_in, 12u);
  EXPECT_EQ(st.triangles_culled, 10u);
  EXPECT_TRUE(identical(expected, g));
  expect_well_formed(g);

  // A triangle seen exactly edge-on (its plane contains the eye).
  Scene e = clean;
  e.objects.push_back(quad(3, {-1, 0, -1}, {1, 0, -1}, {1, 0, -5}, {-1, 0, -5}));
  const GBuffer ge = render(e, cam, &st);
  expect_well_formed(ge);
}

// Scenes for the consistency checks: shapes at several depths seen obliquely.
Scene shapes_scene() {
  Scene s = empty_scene();
  s.objects.push_back(with_shape(1, make_sphere(0.8f, 24, 12), {0.5f, 0.3f, -1.0f}));
  s.objects.push_back(with_shape(2, make_box({1.0f, 0.6f, 1.4f}), {-1.0f, 0.0f, 0.5f}));
  s.objects.push_back(with_shape(3, make_plane(12.0f, 12.0f), {0.0f, -0.8f, 0.0f}));
  s.objects.push_back(with_shape(4, make_cylinder(0.3f, 1.5f, 20, true), {1.5f, 0.0f, 1.0f}));
  Object far_quad = quad(5, {-40, -10, -60}, {40, -10, -60}, {40, 30, -60}, {-40, 30, -60});
  s.objects.push_back(far_quad);
  return s;
}

// shapes_scene() and a sphere (id 6) that moves, turns and grows over [0, 1] s.
Scene shapes_scene_with_mover() {
  Scene s = shapes_scene();
  Object mover = with_shape(6, make_sphere(0.4f, 16, 8), {0, 0, 0});
  Animation anim;
  anim.keys = {TransformKey{0.0, {-1, 1, 0}, glm::quat(1, 0, 0, 0), glm::vec3(1)},
               TransformKey{1.0, {1, 1, 0}, glm::angleAxis(1.0f, glm::vec3(0, 1, 0)), glm::vec3(1.5f)}};
  mover.animation = anim;
  s.objects.push_back(mover);
  return s;
}

TEST(Raster, PositionsLieOnPrimaryRaysAndDepthIsViewDepth) {
  const Scene s = shapes_scene();
  for (const Camera& cam :
       {make_camera({3, 2, 5}, {0, 0, 0}), make_camera({-2.5f, 0.4f, 3}, {0.3f, 0.1f, -1}, 61, 47, 75.0f),
        make_camera({0.2f, 5, 0.1f}, {0, 0, 0}, 64, 48, 30.0f)}) {
    RasterStats st;
    const GBuffer g = render(s, cam, &st);
    expect_well_formed(g);
    EXPECT_GT(covered_count(g), cam.width * cam.height / 2);
    double worst = 0.0;
    for (int y = 0; y < g.height(); ++y)
      for (int x = 0; x < g.width(); ++x) {
        if (!g.covered(x, y)) continue;
        const Ray r = cam.primary_ray(x + 0.5f, y + 0.5f);
        const glm::dvec3 v = glm::dvec3(g.position(x, y)) - glm::dvec3(r.origin);
        const double t = glm::dot(v, glm::dvec3(r.direction));
        worst = std::max(worst, glm::length(v - t * glm::dvec3(r.direction)) / t);
        ASSERT_EQ(g.depth(x, y), cam.view_depth(g.position(x, y)));
        const glm::vec3 to_cam = cam.position - g.position(x, y);
        ASSERT_GE(glm::dot(g.normal(x, y), to_cam), 0.0f);
        ASSERT_GE(glm::dot(g.geo_normal(x, y), to_cam), 0.0f);
      }
    EXPECT_LT(worst, 1e-4);
  }
}

TEST(Raster, BarycentricsReconstructPosition) {
  const Scene s = shapes_scene();
  const Camera cam = make_camera({3, 2, 5}, {0, 0, 0});
  const GBuffer g = render(s, cam);
  int checked = 0;
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) {
      if (!g.covered(x, y)) continue;
      const Object* o = nullptr;
      for (const auto& obj : s.objects)
        if (obj.id == g.object_id(x, y)) o = &obj;
      ASSERT_NE(o, nullptr);
      ASSERT_LT(g.prim_id(x, y), o->mesh.triangles.size());
      const glm::uvec3 t = o->mesh.triangles[g.prim_id(x, y)];
      const glm::vec2 b = g.bary(x, y);
      ASSERT_GE(b.x, 0.0f);
      ASSERT_GE(b.y, 0.0f);
      ASSERT_LE(b.x + b.y, 1.0f + 1e-6f);
      const glm::vec3 p =
          (1 - b.x - b.y) * o->mesh.positions[t.x] + b.x * o->mesh.positions[t.y] + b.y * o->mesh.positions[t.z];
      ASSERT_LT(glm::length(p - g.position(x, y)), 1e-5f * (1.0f + glm::length(g.position(x, y))));
      // The geometric normal is the triangle's, up to the flip.
      const glm::vec3 ng = glm::normalize(
          glm::cross(o->mesh.positions[t.y] - o->mesh.positions[t.x], o->mesh.positions[t.z] - o->mesh.positions[t.x]));
      ASSERT_GT(std::abs(glm::dot(ng, g.geo_normal(x, y))), 0.9999f);
      ++checked;
    }
  EXPECT_GT(checked, 1000);
}

// The server recomputes the G-buffer with Embree primary rays (RtScene::primary_gbuffer):
// away from silhouettes and shared edges both must agree.
TEST(Raster, AgreesWithEmbreePrimaryRays) {
  const Scene s = shapes_scene_with_mover();
  const Camera cam = make_camera({3, 2, 5}, {0, 0, 0});
  GBuffer g;
  rasterize({&s, cam, 0.4, cam, 0.4}, g);
  RtScene rt(s, RtSceneOptions{1});
  const GBuffer r = rt.primary_gbuffer(cam, 0.4);
  int same_coverage = 0, same_prim = 0, compared = 0;
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) {
      same_coverage += g.covered(x, y) == r.covered(x, y);
      if (!g.covered(x, y) || g.object_id(x, y) != r.object_id(x, y) || g.prim_id(x, y) != r.prim_id(x, y)) continue;
      ++same_prim;
      ++compared;
      const float scale = 1.0f + glm::length(r.position(x, y));
      ASSERT_LT(glm::length(g.position(x, y) - r.position(x, y)), 1e-4f * scale) << x << "," << y;
      ASSERT_NEAR(g.depth(x, y), r.depth(x, y), 1e-4f * scale);
      ASSERT_GT(glm::dot(g.geo_normal(x, y), r.geo_normal(x, y)), 0.9999f);
      ASSERT_GT(glm::dot(g.normal(x, y), r.normal(x, y)), 0.999f);
      ASSERT_LT(glm::length(g.bary(x, y) - r.bary(x, y)), 1e-3f);
      ASSERT_LT(glm::length(g.albedo(x, y) - r.albedo(x, y)), 1e-4f);
    }
  const int n = g.width() * g.height();
  EXPECT_GT(covered_count(g, 6), 20);
  EXPECT_GE(same_coverage, n * 99 / 100);
  EXPECT_GE(same_prim, covered_count(g) * 95 / 100);
  EXPECT_GT(compared, n / 2);
}

// RtSceneOptions::static_child (the layout before the two-level one, kept for measurement):
// static geometry in one instanced child scene beside a moving object's instance. Its hits must
// name the same objects and triangles as the default two-level layout's; Embree's traversal may
// decide a ray on a shared edge differently, so all but a few pixels must agree, and both
// objects must be seen.
TEST(Raster, BothLayoutsSeeTheSameSurfaces) {
  const Scene s = shapes_scene_with_mover();
  const Camera cam = make_camera({3, 2, 5}, {0, 0, 0});
  RtSceneOptions child;
  child.threads = 1;
  child.static_child = true;
  RtScene rt_default(s, RtSceneOptions{1}), rt_child(s, child);
  for (double t : {0.0, 0.4, 1.0}) {
    const GBuffer a = rt_child.primary_gbuffer(cam, t), b = rt_default.primary_gbuffer(cam, t);
    int same = 0, mover_px = 0, static_px = 0;
    for (int y = 0; y < a.height(); ++y)
      for (int x = 0; x < a.width(); ++x) {
        same += a.object_id(x, y) == b.object_id(x, y) && a.prim_id(x, y) == b.prim_id(x, y);
        mover_px += b.object_id(x, y) == 6;
        static_px += b.covered(x, y) && b.object_id(x, y) != 6;
      }
    const int n = a.width() * a.height();
    EXPECT_GE(same, n - n / 1000) << "t = " << t;
    EXPECT_GT(mover_px, 10) << "t = " << t;
    EXPECT_GT(static_px, n / 10) << "t = " << t;
  }
}

TEST(Raster, CameraTranslationGivesAnalyticMotion) {
  Scene s = empty_scene();
  const float d = 4.0f;
  s.objects.push_back(facing_quad(1, -20, -20, 20, 20, -d));
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  Camera prev = make_camera({0.1f, -0.05f, 0}, {0.1f, -0.05f, -1});  // was right of and below here
  GBuffer g;
  rasterize({&s, cam, 1.0, prev, 0.9}, g);
  // A point at depth d seen from a camera shifted by (dx, dy) moves by -dx * f / d pixels.
  const double tan_half = std::tan(glm::radians(30.0));
  const double fx = 0.5 * 64 / (tan_half * 64.0 / 48.0), fy = 0.5 * 48 / tan_half;
  const glm::vec2 expected(float(-0.1 * fx / d), float(-0.05 * fy / d));  // screen y points down
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      ASSERT_NEAR(g.motion(x, y).x, expected.x, 2e-3f);
      ASSERT_NEAR(g.motion(x, y).y, expected.y, 2e-3f);
      ASSERT_EQ(g.motion(x, y), g.motion(x, y));
    }
  EXPECT_NE(expected.x, 0.0f);

  // A rotation: motion == prev_camera.project(position) - pixel centre.
  const Camera turned = make_camera({0, 0, 0}, {0.1f, 0.05f, -1});
  rasterize({&s, cam, 1.0, turned, 0.9}, g);
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const glm::vec3 q = turned.project(g.position(x, y));
      ASSERT_NEAR(g.motion(x, y).x, q.x - (x + 0.5f), 1e-3f);
      ASSERT_NEAR(g.motion(x, y).y, q.y - (y + 0.5f), 1e-3f);
    }

  // A point behind the previous camera was not visible: motion far off-screen.
  const Camera backwards = make_camera({0, 0, -5}, {0, 0, -6});
  Scene near_quad = empty_scene();
  near_quad.objects.push_back(facing_quad(1, -20, -20, 20, 20, -2));
  rasterize({&near_quad, cam, 1.0, backwards, 0.9}, g);
  EXPECT_EQ(g.motion(10, 10), glm::vec2(-1e6f));
}

TEST(Raster, MovingObjectHasMotionAndStaticGeometryNone) {
  Scene s = empty_scene();
  s.objects.push_back(facing_quad(1, -20, -20, 20, 20, -6.0f));
  Object mover = facing_quad(2, -0.5f, -0.5f, 0.5f, 0.5f, 0.0f);  // object space
  Animation anim;
  anim.keys = {TransformKey{0.0, {-1, 0, -3}, glm::quat(1, 0, 0, 0), glm::vec3(1)},
               TransformKey{1.0, {1, 0, -3}, glm::quat(1, 0, 0, 0), glm::vec3(1)}};
  mover.animation = anim;
  s.objects.push_back(mover);
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  GBuffer g;
  rasterize({&s, cam, 0.75, cam, 0.5}, g);  // x = 0.5 now, 0 before: moved +0.5 m at depth 3
  const double f = 0.5 * 64 / (std::tan(glm::radians(30.0)) * 64.0 / 48.0);
  int moving_pixels = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      if (g.object_id(x, y) == 2) {
        ++moving_pixels;
        ASSERT_NEAR(g.motion(x, y).x, -0.5 * f / 3.0, 2e-3);
        ASSERT_NEAR(g.motion(x, y).y, 0.0f, 2e-3f);
        ASSERT_NEAR(g.position(x, y).z, -3.0f, 1e-5f);
        ASSERT_GT(g.position(x, y).x, -0.01f);  // placed at time_s: x in [0, 1]
        ASSERT_EQ(g.depth(x, y), cam.view_depth(g.position(x, y)));
      } else {
        ASSERT_EQ(g.motion(x, y), glm::vec2(0.0f));
      }
    }
  EXPECT_GT(moving_pixels, 100);

  // Same time for both frames: no motion at all.
  rasterize({&s, cam, 0.75, cam, 0.75}, g);
  for (const glm::vec2& m : g.motion.pixels()) ASSERT_EQ(m, glm::vec2(0.0f));
}

TEST(Raster, AlphaCutoutMakesHolesAndTextureScalesAlbedo) {
  Scene s = empty_scene();
  Texture tex;
  tex.path = "test-alpha";
  tex.width = 8;
  tex.height = 1;
  tex.has_alpha = true;
  for (int i = 0; i < 8; ++i) tex.texels.push_back(glm::u8vec4(255, 255, 255, i < 4 ? 255 : 0));
  s.textures.push_back(tex);
  s.materials.push_back(Material{"cutout", glm::vec3(0.25f, 0.5f, 1.0f), 0, true, 0.5f, false});
  s.objects.push_back(facing_quad(1, -1, -1, 1, 1, -2.0f, 1));  // u = (x + 1) / 2
  s.objects.push_back(facing_quad(2, -20, -20, 20, 20, -4.0f));
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  const GBuffer g = render(s, cam);
  int opaque = 0, holes = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const Ray r = cam.primary_ray(x + 0.5f, y + 0.5f);
      const glm::vec3 p = r.direction * (2.0f / -r.direction.z);  // on the cut-out quad's plane
      if (std::abs(p.y) > 0.95f) continue;
      const float u = (p.x + 1.0f) * 0.5f;
      if (u > 0.08f && u < 0.42f) {
        ++opaque;
        ASSERT_EQ(g.object_id(x, y), 1u);
        ASSERT_NEAR(g.albedo(x, y).x, 0.25f, 1e-5f);
        ASSERT_NEAR(g.albedo(x, y).z, 1.0f, 1e-5f);
      } else if (u > 0.58f && u < 0.92f) {
        ++holes;
        ASSERT_EQ(g.object_id(x, y), 2u);
        ASSERT_EQ(g.depth(x, y), 4.0f);
      }
    }
  EXPECT_GT(opaque, 50);
  EXPECT_GT(holes, 50);

  // The same material without cut-out is solid: the quad hides the background behind it.
  const int background_with_holes = covered_count(g, 2);
  s.materials[1].alpha_cutout = false;
  const GBuffer solid = render(s, cam);
  EXPECT_LE(covered_count(solid, 2), background_with_holes - holes);
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const Ray r = cam.primary_ray(x + 0.5f, y + 0.5f);
      const glm::vec3 p = r.direction * (2.0f / -r.direction.z);
      if (std::abs(p.x) < 0.95f && std::abs(p.y) < 0.95f) {
        ASSERT_EQ(solid.object_id(x, y), 1u);
      }
    }
}

TEST(Raster, OutputIsIdenticalForAnyThreadCount) {
  Scene s = shapes_scene();
  // Plus many small overlapping triangles across tile borders (ties included).
  Object soup;
  soup.id = 9;
  for (int i = 0; i < 3000; ++i) {
    const uint32_t hsh = uint32_t(i) * 2654435761u;
    const glm::vec3 c{float(hsh % 1000) / 250.0f - 2.0f, float((hsh >> 10) % 1000) / 500.0f - 1.0f,
                      float((hsh >> 20) % 1000) / 500.0f - 1.0f};
    const uint32_t base = uint32_t(soup.mesh.positions.size());
    soup.mesh.positions.push_back(c);
    soup.mesh.positions.push_back(c + glm::vec3(0.15f, 0.02f, 0.05f));
    soup.mesh.positions.push_back(c + glm::vec3(0.03f, 0.12f, -0.04f));
    soup.mesh.triangles.push_back({base, base + 1, base + 2});
  }
  s.objects.push_back(soup);
  const Camera cam = make_camera({3, 1.5f, 4}, {0, 0, 0}, 200, 130);
  const Camera prev = make_camera({3.1f, 1.5f, 4}, {0, 0.1f, 0}, 200, 130);
  GBuffer one, two, three;
  RasterStats s1, s2;
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    s1 = rasterize({&s, cam, 0.0, prev, 0.0}, one);
  }
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
    s2 = rasterize({&s, cam, 0.0, prev, 0.0}, two);
  }
  rasterize({&s, cam, 0.0, prev, 0.0}, three);
  EXPECT_TRUE(identical(one, two));
  EXPECT_TRUE(identical(one, three));
  EXPECT_EQ(s1.fragments, s2.fragments);
  EXPECT_EQ(s1.triangles_culled, s2.triangles_culled);
  EXPECT_GT(covered_count(one, 9), 100);

  // Rendering into a buffer that already holds another frame gives the same result.
  GBuffer reused = one;
  Scene other = empty_scene();
  other.objects.push_back(facing_quad(1, -1, -1, 1, 1, -2));
  rasterize(still(other, cam), reused);
  rasterize({&s, cam, 0.0, prev, 0.0}, reused);
  EXPECT_TRUE(identical(one, reused));
}

TEST(Raster, EmptySceneIsAllBackground) {
  const Scene s = empty_scene();
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  RasterStats st;
  const GBuffer g = render(s, cam, &st);
  EXPECT_EQ(st.fragments, 0u);
  EXPECT_EQ(covered_count(g), 0);
  for (float d : g.depth.pixels()) ASSERT_EQ(d, kBackgroundDepth);
  for (const auto& p : g.position.pixels()) ASSERT_EQ(p, glm::vec3(0.0f));
  for (const auto& m : g.motion.pixels()) ASSERT_EQ(m, glm::vec2(0.0f));
}

TEST(Raster, FarPlaneDiscardsBeyondFar) {
  Scene s = empty_scene();
  s.objects.push_back(facing_quad(1, -100, -100, 100, 100, -150.0f));  // beyond far = 100
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  EXPECT_EQ(covered_count(render(s, cam)), 0);
  // A floor running past the far plane is cut there.
  Scene f = empty_scene();
  f.objects.push_back(quad(1, {-500, -1, 10}, {500, -1, 10}, {500, -1, -500}, {-500, -1, -500}));
  const GBuffer g = render(f, make_camera({0, 0, 0}, {0, -0.01f, -1}, 64, 48, 60.0f, 0.05f, 100.0f));
  EXPECT_GT(covered_count(g), 0);
  for (float d : g.depth.pixels())
    if (d != kBackgroundDepth) {
      ASSERT_LE(d, 100.0f * 1.0001f);
    }
}

TEST(Raster, CameraInsideClosedBoxSeesInsideFaces) {
  Scene s = empty_scene();
  s.objects.push_back(with_shape(1, make_box({4, 3, 5}), {0, 0, 0}));
  for (const Camera& cam : {make_camera({0.3f, 0.2f, -0.4f}, {1, 0.5f, -2}), make_camera({0, 0, 0}, {0, 1, 0}),
                            make_camera({1.9f, -1.4f, 2.4f}, {-1, 1, -1}, 64, 48, 120.0f)}) {
    const GBuffer g = render(s, cam);
    expect_well_formed(g);
    EXPECT_EQ(covered_count(g, 1), 64 * 48);
    for (int y = 0; y < 48; ++y)
      for (int x = 0; x < 64; ++x) {
        const glm::vec3 p = g.position(x, y);
        // On the box's surface, normals point inwards (towards the camera inside).
        const float on_face =
            std::min({std::abs(std::abs(p.x) - 2.0f), std::abs(std::abs(p.y) - 1.5f), std::abs(std::abs(p.z) - 2.5f)});
        ASSERT_LT(on_face, 1e-4f);
        ASSERT_GT(glm::dot(g.geo_normal(x, y), -p), 0.0f);
        ASSERT_GT(glm::dot(g.normal(x, y), cam.position - p), 0.0f);
        ASSERT_GE(g.depth(x, y), cam.near_m);
      }
  }
}

TEST(Raster, RejectsBadInput) {
  const Camera cam = make_camera({0, 0, 0}, {0, 0, -1});
  GBuffer g;
  EXPECT_THROW(rasterize({nullptr, cam, 0.0, cam, 0.0}, g), Error);
  Scene s = empty_scene();
  s.objects.push_back(facing_quad(1, -1, -1, 1, 1, -2, 7));  // material 7 does not exist
  EXPECT_THROW(rasterize(still(s, cam), g), Error);
  s.objects[0].material = 0;
  s.objects[0].mesh.normals.pop_back();
  EXPECT_THROW(rasterize(still(s, cam), g), Error);
  s.objects[0].mesh.normals.clear();
  EXPECT_NO_THROW(rasterize(still(s, cam), g));
  Camera bad = cam;
  bad.near_m = 0.0f;
  EXPECT_THROW(rasterize(still(s, bad), g), Error);
  bad = cam;
  bad.width = 0;
  EXPECT_THROW(rasterize(still(s, bad), g), Error);
  s.materials[0].texture = 3;
  EXPECT_THROW(rasterize(still(s, cam), g), Error);
}

TEST(Raster, MeshWithoutNormalsUsesGeometricNormal) {
  Scene s = empty_scene();
  Object o = quad(1, {-1, -1, -2}, {1, -1, -3}, {1, 1, -3}, {-1, 1, -2});
  o.mesh.normals.clear();
  o.mesh.uvs.clear();
  s.objects.push_back(o);
  const GBuffer g = render(s, make_camera({0, 0, 0}, {0, 0, -1}));
  ASSERT_TRUE(g.covered(32, 24));
  EXPECT_EQ(g.normal(32, 24), g.geo_normal(32, 24));
  EXPECT_NEAR(glm::dot(g.normal(32, 24), glm::normalize(glm::vec3(1, 0, 2))), 1.0f, 1e-5f);
}

}  // namespace
}  // namespace dhr
