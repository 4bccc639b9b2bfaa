// The rasterizer's output bits, pinned: on every built-in scene and every real scene (skipped
// when ../shared/scenes is missing), at 321x181 (odd sizes: partial tiles and spans) and
// 1280x720, the FNV-1a hash of every G-buffer plane and of the statistics must equal the values
// recorded from the rasterizer (core/raster.cpp) of commit 9b6eb01, before the speed work of
// docs/performance.md ("Client stages (item 5)"), with one thread and with all of them. A
// change of core/raster.cpp that moves any pixel of any plane by one bit fails here; a
// deliberate change of the output must update the table and say so.
// Run with DHR_PRINT_RASTER_HASHES=1 to print the table's rows for the current code.
#include "core/error.h"
#include "core/raster.h"
#include "core/scene_load.h"

#include "tests/support.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <string>

namespace dhr {
namespace {

// scene/size -> hash, recorded with DHR_PRINT_RASTER_HASHES=1 from the rasterizer of 9b6eb01.
const std::map<std::string, uint64_t>& pinned() {
  static const std::map<std::string, uint64_t> m = {
      {"room/321x181", 0xf00ba59b5f26432full},
      {"room/1280x720", 0x224381224c7ad34cull},
      {"street/321x181", 0x9707acd044bb1f01ull},
      {"street/1280x720", 0xf05d5881aa6fa958ull},
      {"temple/321x181", 0xc9341bf2e939b4c8ull},
      {"temple/1280x720", 0xa63de3be043152cfull},
      {"classroom/321x181", 0xd41cab45a3205c06ull},
      {"classroom/1280x720", 0x96ddce0603154f70ull},
      {"dining-room/321x181", 0x746a7ea3ed3f8347ull},
      {"dining-room/1280x720", 0x84f887d59767953cull},
      {"living-room/321x181", 0x5bd037a48e0d4146ull},
      {"living-room/1280x720", 0x95a8c5f101368ed5ull},
      {"sponza-dabrovic/321x181", 0x0d844bf2574fceefull},
      {"sponza-dabrovic/1280x720", 0xfe6eda43ab93ddc4ull},
      {"staircase/321x181", 0x03c0f087738d30abull},
      {"staircase/1280x720", 0x72813cb272ea35c8ull},
  };
  return m;
}

uint64_t gbuffer_hash(const Scene& scene, int w, int h) {
  // Camera and object motion: the frame at 0.25 s, the previous one 1/30 s before.
  const double t = 0.25, prev = t - 1.0 / 30.0;
  const RasterFrame frame{&scene, scene.camera.at(t, w, h), t, scene.camera.at(prev, w, h), prev};
  GBuffer g;
  const RasterStats st = rasterize(frame, g);
  test::Fnv1a f;
  f.plane(g.depth);
  f.plane(g.position);
  f.plane(g.normal);
  f.plane(g.geo_normal);
  f.plane(g.albedo);
  f.plane(g.object_id);
  f.plane(g.prim_id);
  f.plane(g.bary);
  f.plane(g.motion);
  for (uint64_t v : {st.triangles_in, st.triangles_clipped, st.triangles_culled, st.fragments}) f.bytes(&v, sizeof v);
  return f.h;
}

TEST(RasterBits, GBufferIsPinned) {
  const bool print = std::getenv("DHR_PRINT_RASTER_HASHES") != nullptr;
  int checked = 0;
  test::for_each_scene([&](const std::string& name, const Scene& scene) {
    for (const auto& [w, h] : {std::pair{321, 181}, std::pair{1280, 720}}) {
      const std::string key = name + "/" + std::to_string(w) + "x" + std::to_string(h);
      const uint64_t all_threads = gbuffer_hash(scene, w, h);
      uint64_t one_thread = 0;
      {
        const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        one_thread = gbuffer_hash(scene, w, h);
      }
      EXPECT_EQ(one_thread, all_threads) << key << ": one thread and all threads differ";
      if (print) {
        std::printf("      {\"%s\", 0x%016llxull},\n", key.c_str(), static_cast<unsigned long long>(all_threads));
        continue;
      }
      const auto it = pinned().find(key);
      ASSERT_NE(it, pinned().end()) << key << " has no pinned hash";
      EXPECT_EQ(all_threads, it->second) << key << ": the G-buffer's bits changed";
      ++checked;
    }
  });
  if (!print) {
    EXPECT_GE(checked, 6);  // the built-in scenes, at least
  }
}

}  // namespace
}  // namespace dhr
