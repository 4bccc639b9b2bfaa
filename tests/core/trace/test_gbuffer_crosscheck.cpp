// The client's rasterized G-buffer (core/raster/raster.h) and the server's Embree primary-ray
// G-buffer (RtScene::primary_gbuffer) must agree: the server traces from the G-buffer it
// recomputes, the client composites on its own (docs/architecture.md, "The frame loop"). For each built-in scene
// at 160x90 and three times along its camera path: depth within 1e-3 relative, the same
// object id and geometric and shading normals with dot > 0.99 on at least 99.5% of the
// pixels; every disagreeing pixel lies on an edge: one of its 8 neighbours (in either
// G-buffer) has another object id or is background, or shows a depth discontinuity (> 1%
// relative), or lies on another triangle whose normal differs (a crease). Pixels where two
// objects' surfaces coincide (same depth to 1e-5 and normal: z-fighting in the scene itself)
// count as agreeing -- either answer is right -- and are reported; at most 2% are tolerated.
#include "core/raster/raster.h"
#include "core/scene/scene_load.h"
#include "core/trace/rt_scene.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>
#include <utility>

namespace dhr {
namespace {

constexpr int kW = 160, kH = 90;

// Why two pixels disagree (kAgree when they do not).
enum Mismatch { kAgree, kCoverage, kObject, kDepth, kGeoNormal, kShadingNormal, kCoincident, kMismatchKinds };
const char* const kMismatchNames[] = {"agree",          "coverage",           "object id", "depth", "geometric normal",
                                      "shading normal", "coincident surfaces"};

Mismatch compare_pixel(const GBuffer& a, const GBuffer& b, int x, int y) {
  const bool ca = a.covered(x, y), cb = b.covered(x, y);
  if (!ca || !cb) return ca == cb ? kAgree : kCoverage;
  const float da = a.depth(x, y), db = b.depth(x, y);
  if (a.object_id(x, y) != b.object_id(x, y)) {
    // Two objects' coincident surfaces (z-fighting in the scene itself): the rasterizer breaks
    // the tie by the smaller (object id, prim id), Embree by traversal order. Both are right.
    const bool tie =
        std::abs(da - db) <= 1e-5f * std::max(da, db) && glm::dot(a.geo_normal(x, y), b.geo_normal(x, y)) > 0.99f;
    return tie ? kCoincident : kObject;
  }
  if (!(std::abs(da - db) <= 1e-3f * std::max(da, db))) return kDepth;
  if (!(glm::dot(a.geo_normal(x, y), b.geo_normal(x, y)) > 0.99f)) return kGeoNormal;
  return glm::dot(a.normal(x, y), b.normal(x, y)) > 0.99f ? kAgree : kShadingNormal;
}

bool on_edge(const GBuffer& g, int x, int y) {
  const bool c = g.covered(x, y);
  for (int dy = -1; dy <= 1; ++dy)
    for (int dx = -1; dx <= 1; ++dx) {
      const int nx = x + dx, ny = y + dy;
      if ((dx == 0 && dy == 0) || nx < 0 || ny < 0 || nx >= g.width() || ny >= g.height()) continue;
      if (g.covered(nx, ny) != c) return true;
      if (!c) continue;
      if (g.object_id(nx, ny) != g.object_id(x, y)) return true;
      const float d = g.depth(x, y), dn = g.depth(nx, ny);
      if (std::abs(d - dn) > 0.01f * std::max(d, dn)) return true;
      if (g.prim_id(nx, ny) != g.prim_id(x, y) && glm::dot(g.geo_normal(nx, ny), g.geo_normal(x, y)) < 0.99f)
        return true;
    }
  return false;
}

TEST(GBufferCrosscheck, RasterMatchesEmbreeOnBuiltinScenes) {
  const auto files = builtin_scene_files();
  ASSERT_FALSE(files.empty()) << "no built-in scenes under scenes/";
  for (const std::string& file : files) {
    const Scene scene = load_scene(file, SceneSearchPath::standard());
    RtScene rt(scene);
    const double duration = scene.camera.duration_s();
    const double t0 = scene.camera.keys.front().time_s;
    for (double t : {t0, t0 + 0.5 * duration, t0 + duration}) {
      const Camera cam = scene.camera.at(t, kW, kH);
      RasterFrame frame;
      frame.scene = &scene;
      frame.camera = cam;
      frame.time_s = t;
      frame.prev_camera = cam;
      frame.prev_time_s = t;
      GBuffer raster;
      rasterize(frame, raster);
      const GBuffer traced = rt.primary_gbuffer(cam, t);
      size_t agree = 0, covered = 0, off_edge = 0;
      size_t kinds[kMismatchKinds] = {};
      std::set<std::pair<uint32_t, uint32_t>> ties;
      std::string tie_names;
      for (int y = 0; y < kH; ++y)
        for (int x = 0; x < kW; ++x) {
          covered += raster.covered(x, y);
          const Mismatch m = compare_pixel(raster, traced, x, y);
          ++kinds[m];
          if (m == kCoincident && !ties.count({raster.object_id(x, y), traced.object_id(x, y)})) {
            ties.insert({raster.object_id(x, y), traced.object_id(x, y)});
            tie_names += fmt::format(" {}/{}", scene.objects[size_t(rt.object_index(raster.object_id(x, y)))].name,
                                     scene.objects[size_t(rt.object_index(traced.object_id(x, y)))].name);
          }
          if (m == kAgree || m == kCoincident) {
            ++agree;
            continue;
          }
          if (!on_edge(raster, x, y) && !on_edge(traced, x, y)) {
            ++off_edge;
            ADD_FAILURE() << file << " t=" << t << " pixel " << x << "," << y << ": raster id "
                          << raster.object_id(x, y) << " depth " << raster.depth(x, y) << " vs embree id "
                          << traced.object_id(x, y) << " depth " << traced.depth(x, y);
          }
        }
      const double fraction = double(agree) / double(kW * kH);
      std::string breakdown;
      for (int k = 1; k < kMismatchKinds; ++k) breakdown += fmt::format(" {}: {}", kMismatchNames[k], kinds[k]);
      EXPECT_GE(fraction, 0.995) << file << " at t=" << t << "; disagreements by kind:" << breakdown;
      EXPECT_GT(covered, size_t(kW * kH / 4)) << file << " at t=" << t << ": the view is mostly empty";
      EXPECT_EQ(off_edge, 0u) << file << " at t=" << t;
      // Coincident surfaces are a property of the scene (reported, tolerated up to 2%).
      EXPECT_LE(kinds[kCoincident], size_t(kW * kH / 50)) << file << " at t=" << t;
      if (kinds[kCoincident] > 0)
        std::printf("%s t=%g: %zu pixels on coincident surfaces (raster/embree):%s\n", file.c_str(), t,
                    kinds[kCoincident], tie_names.c_str());
      RecordProperty(std::filesystem::path(file).stem().string() + "_t" + std::to_string(int(t * 1000)),
                     std::to_string(fraction));
    }
  }
}

}  // namespace
}  // namespace dhr
