// The rasterizer's output bits, pinned: on every built-in scene and every real scene (skipped
// when ../shared/scenes is missing), at 321x181 (odd sizes: partial tiles and spans) and
// 1280x720, the FNV-1a hash of every G-buffer plane and of the statistics must equal the values
// recorded from the rasterizer (core/raster/raster.cpp) of commit 9b6eb01, the code without the vector
// kernels (core/raster/raster_avx512.cpp), with one thread and with all of them. A
// change of core/raster/raster*.cpp that moves any pixel of any plane by one bit fails here; a
// deliberate change of the output must update the table and say so.
// Run with DHR_PRINT_RASTER_HASHES=1 to print the table's rows for the current code.
#include "core/base/error.h"
#include "core/raster/raster.h"
#include "core/scene/scene_load.h"

#include "tests/support.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <string>
#include <tuple>
#include <vector>
#include <limits>
#include <array>

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
      // living-room's leaf.png has alpha: its colour is read as stored, not premultiplied (recorded at 9cdc6ef).
      {"living-room/321x181", 0xbe5ef65f9f8eb2c9ull},
      {"living-room/1280x720", 0xcca0aa9cec6ba5a4ull},
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

// Attributes no real scene has, pinned the same way: uvs that are NaN, infinite, huge, negative
// or far outside [0, 1] on a texture of odd size; shading normals that are zero, NaN, infinite,
// tiny or so large their length overflows; a sliver seen edge-on (barycentrics clamped); and a
// previous camera turned away, so that some surface points lie behind it, on its plane or at
// huge offsets (motion clamped). Recorded with DHR_PRINT_RASTER_HASHES=1 under DHR_MAX_ISA=avx2,
// the scalar resolve of core/raster/raster.cpp; the AVX-512 one (core/raster/raster_avx512.cpp) must give the
// same bits (this test runs under both: tests/CMakeLists.txt).
Scene damaged_scene() {
  Scene s;
  s.name = "damaged";
  Texture tex;
  tex.path = "damaged-texture";
  tex.width = 5;
  tex.height = 3;
  uint32_t state = 12345u;
  for (int i = 0; i < tex.width * tex.height; ++i) {
    state = state * 1664525u + 1013904223u;
    tex.texels.push_back(glm::u8vec4(uint8_t(state >> 24), uint8_t(state >> 16), uint8_t(state >> 8), 255));
  }
  s.textures.push_back(tex);
  s.materials.push_back(Material{"textured", glm::vec3(0.9f, 0.6f, 0.3f), 0, false, 0.5f, false});
  s.materials.push_back(Material{"plain", glm::vec3(0.5f), -1, false, 0.5f, false});
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  const std::vector<std::array<glm::vec2, 4>> uvs = {
      {{{0.0f, 0.0f}, {1.0f, 0.0f}, {1.0f, 1.0f}, {0.0f, 1.0f}}},
      {{{nan, 0.2f}, {0.3f, inf}, {-inf, 0.5f}, {0.7f, 0.1f}}},
      {{{1e30f, -1e30f}, {3.7f, -2.2f}, {-1e-30f, 1e7f}, {-5.5f, 12.25f}}},
      {{{-0.5f, -0.5f}, {1.5f, -0.5f}, {1.5f, 1.5f}, {-0.5f, 1.5f}}},
  };
  const std::vector<std::array<glm::vec3, 4>> normals = {
      {{{0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0, 0, 1}}},
      {{{0, 0, 0}, {0, 0, 0}, {0, 0, 1}, {0, 0, -1}}},
      {{{nan, 0, 1}, {0, inf, 0}, {1e-20f, 0, 0}, {0, 0, -1e-25f}}},
      {{{1e30f, 1e30f, 0}, {0, 3e38f, 3e38f}, {-1, 0.5f, 0.2f}, {0, -1, 0}}},
  };
  uint32_t id = 1;
  for (size_t i = 0; i < uvs.size(); ++i)
    for (size_t j = 0; j < normals.size(); ++j) {
      Object o;
      o.name = "quad" + std::to_string(id);
      o.id = id++;
      o.material = (i + j) % 3 == 2 ? 1u : 0u;
      const float x0 = -2.0f + float(i), y0 = -2.0f + float(j), z = -3.0f - 0.1f * float(i * 4 + j);
      o.mesh.positions = {{x0, y0, z}, {x0 + 0.9f, y0, z - 0.2f}, {x0 + 0.9f, y0 + 0.9f, z}, {x0, y0 + 0.9f, z + 0.3f}};
      o.mesh.normals.assign(normals[j].begin(), normals[j].end());
      o.mesh.uvs.assign(uvs[i].begin(), uvs[i].end());
      o.mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
      s.objects.push_back(std::move(o));
    }
  // A wall seen almost edge-on (its pixels' barycentrics clamped where the snapped triangle
  // covers a centre the exact one misses), and a floor reaching behind the camera.
  Object wall;
  wall.name = "wall";
  wall.id = id++;
  wall.mesh.positions = {{0.25f, -1.0f, -1.0f}, {0.1f, -1.0f, -40.0f}, {0.1f, 1.0f, -40.0f}, {0.25f, 1.0f, -1.0f}};
  wall.mesh.uvs = {{0.0f, 0.0f}, {40.0f, 0.0f}, {40.0f, 1.0f}, {0.0f, 1.0f}};
  wall.mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  s.objects.push_back(std::move(wall));
  Object floor;
  floor.name = "floor";
  floor.id = id++;
  floor.material = 1;
  floor.mesh.positions = {
      {-50.0f, -2.5f, 10.0f}, {50.0f, -2.5f, 10.0f}, {50.0f, -2.5f, -50.0f}, {-50.0f, -2.5f, -50.0f}};
  floor.mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  s.objects.push_back(std::move(floor));
  return s;
}

TEST(RasterBits, DamagedAttributesArePinned) {
  const Scene scene = damaged_scene();
  const std::map<std::string, uint64_t> pins = {
      {"damaged/64x48", 0x895c924e6b911364ull},
      {"damaged/321x181", 0x022009f438beb248ull},
      {"damaged/67x45", 0x17a676f2960ed374ull},
  };
  const bool print = std::getenv("DHR_PRINT_RASTER_HASHES") != nullptr;
  for (const auto& [w, h, prev_fov] :
       {std::tuple{64, 48, 50.0f}, std::tuple{321, 181, 50.0f}, std::tuple{67, 45, 0.001f}}) {
    const Camera cam = Camera::look_at({0.3f, 0.2f, 1.0f}, {0.0f, -0.2f, -3.0f}, {0, 1, 0}, 70.0f, w, h, 0.05f, 100.0f);
    // The previous camera stands among the quads, turned to the side; with a very narrow field
    // of view almost every offset is clamped.
    const Camera prev =
        Camera::look_at({-0.5f, -0.5f, -3.2f}, {3.0f, -0.4f, -2.0f}, {0, 1, 0}, prev_fov, w, h, 0.05f, 100.0f);
    GBuffer g;
    const RasterStats st = rasterize({&scene, cam, 0.0, prev, -1.0 / 30.0}, g);
    test::Fnv1a f;
    g.for_each_plane([&](const auto& plane) { f.plane(plane); });
    for (uint64_t v : {st.triangles_in, st.triangles_clipped, st.triangles_culled, st.fragments}) f.bytes(&v, sizeof v);
    const std::string key = "damaged/" + std::to_string(w) + "x" + std::to_string(h);
    if (print) {
      std::printf("      {\"%s\", 0x%016llxull},\n", key.c_str(), static_cast<unsigned long long>(f.h));
      continue;
    }
    EXPECT_EQ(f.h, pins.at(key)) << key << ": the G-buffer's bits changed";
  }
}

}  // namespace
}  // namespace dhr
