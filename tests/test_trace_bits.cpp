// The visibility pass's output bits, pinned: on every built-in scene and every real scene
// (skipped when ../shared/scenes is missing), in each shadow mode (hard, one jittered ray per
// light, 4 rays per light), the FNV-1a hash of the counts, of the statistics and of the rays
// handed to Embree (collect_visibility_rays) must equal the values recorded from the tracer
// of commit d05e197 (before the speed work of docs/performance.md); where Embree runs other
// kernels than AVX-512, the values of that ISA's table (below). A change of the tracer's
// kernels that moves any ray or any count by one bit fails here; a deliberate change of the
// output must update every table and say so. Run with DHR_PRINT_TRACE_HASHES=1 to print the
// table's rows for the current code, once per ISA on a machine with AVX-512:
//   for isa in avx512 avx2 avx sse4.2; do DHR_MAX_ISA=$isa DHR_PRINT_TRACE_HASHES=1
//     build/tests/test_trace_bits --gtest_filter=TraceBits.VisibilityPassIsPinned; done
// (one command: the loop's body is one line).
#include "core/error.h"
#include "core/rt_scene.h"
#include "core/scene_load.h"
#include "core/trace.h"

#include "tests/support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <string>

namespace dhr {
namespace {

// The G-buffer these hashes start from is Embree's (primary rays), and Embree's kernels of
// different ISAs give hit points that differ in their last bits (their reciprocal
// approximations and FMAs differ), so the table depends on which kernels Embree runs:
// dhr::embree_isa(), the CPU's best or DHR_MAX_ISA's cap (core/rt_scene.h). ctest runs
// this binary once as it is and once per other table with the cap (tests/CMakeLists.txt), so a
// machine with AVX-512 checks every table. The tables of the ISAs before AVX-512 were recorded
// on AMD EPYCs: those kernels start from rcpps, whose bits the x86 vendors do not share, so an
// Intel CPU without AVX-512 may give other hashes (not checked: no such machine here).

// scene/mode -> hash, by the ISA Embree runs (dhr::embree_isa(); SSE2 and SSE4.2 agree):
// - avx512: recorded with DHR_PRINT_TRACE_HASHES=1 at commit d05e197 (AVX-512 machine);
// - avx2: recorded at commit c05ad78 on an AMD EPYC without AVX-512 (the tracer of that commit
//   gave the avx512 table on AVX-512 machines, its CI run included); the AVX-512 EPYC with
//   DHR_MAX_ISA=avx2 gives the same table;
// - avx and sse4.2 (and sse2): recorded with DHR_MAX_ISA=avx and =sse4.2 (and =sse2) on the
//   AVX-512 EPYC at commit 2746b24, which brought the cap. (An earlier comment here said that
//   Embree's SSE4.2 and AVX2 kernels agree, from a ~/.embree3 file; Debian's Embree does not read
//   that file, so both runs had used AVX2.)
// In every table the street rows were recorded again (the same loop, every ISA on the AVX-512
// EPYC) at commit bf65e45, which moved scenes with moving objects to Embree's two-level layout
// (RtSceneOptions::static_child): it answers a few of street's rays on shared edges
// differently. The other rows did not move.
const std::map<std::string, uint64_t>& pinned() {
  using Table = std::map<std::string, uint64_t>;
  static const std::map<std::string, Table> by_isa = {
    {"avx512", {
        {"room/hard", 0x47c22a5598623c55ull},
        {"room/soft1", 0xb7f90787bd269b47ull},
        {"room/soft4", 0x016ef43aebaf323aull},
        {"street/hard", 0x8a6b3dfe209cde2cull},
        {"street/soft1", 0x6d7b2be4e294d5a2ull},
        {"street/soft4", 0x53332d3f20f26656ull},
        {"temple/hard", 0x718defe329c23645ull},
        {"temple/soft1", 0x3f06f8b5097f1e61ull},
        {"temple/soft4", 0x71b0e834715f4253ull},
        {"classroom/hard", 0x1f14383a0424d32eull},
        {"classroom/soft1", 0xfb4922c2c5200c74ull},
        {"classroom/soft4", 0x486d5ff7cbac0d3cull},
        {"dining-room/hard", 0x27c89ad6614306e5ull},
        {"dining-room/soft1", 0x646495173ea605c5ull},
        {"dining-room/soft4", 0x1b4e1c68a9b1b0edull},
        {"sponza-dabrovic/hard", 0x25f504298b1846ecull},
        {"sponza-dabrovic/soft1", 0x40dee685a0aea845ull},
        {"sponza-dabrovic/soft4", 0x383b601ee2f6f938ull},
        {"staircase/hard", 0xf8b2b9fde8e8c8e3ull},
        {"staircase/soft1", 0xd29df6f678894b72ull},
        {"staircase/soft4", 0xa311989f05c90d74ull},
    }},
    {"avx2", {
        {"room/hard", 0xb0b76470ba50377dull},
        {"room/soft1", 0xc58dcc7c881ad7cbull},
        {"room/soft4", 0xdde546653c541aa7ull},
        {"street/hard", 0x9309315a2b4d6a5eull},
        {"street/soft1", 0x5c49586b1b9fb1eeull},
        {"street/soft4", 0x7a26d57f7fb9eb73ull},
        {"temple/hard", 0x938355dbb8aab068ull},
        {"temple/soft1", 0x636ec2ba11620ba0ull},
        {"temple/soft4", 0xbbdbb4696b3c108full},
        {"classroom/hard", 0xc04b9989dabaf3d0ull},
        {"classroom/soft1", 0x3c2627e050f796f2ull},
        {"classroom/soft4", 0xfed9579a8315e924ull},
        {"dining-room/hard", 0x15d7672a030a3ba4ull},
        {"dining-room/soft1", 0x02e0c6d5c83cc76cull},
        {"dining-room/soft4", 0xfec625d4fb73cf65ull},
        {"sponza-dabrovic/hard", 0x78fc1449c047b766ull},
        {"sponza-dabrovic/soft1", 0x2207e81910f291bfull},
        {"sponza-dabrovic/soft4", 0xc1ca47028de979d5ull},
        {"staircase/hard", 0xa6e446c0c2fc1f03ull},
        {"staircase/soft1", 0x00f30c34fbf870b9ull},
        {"staircase/soft4", 0x26abf432743e04b5ull},
    }},
    {"avx", {
        {"room/hard", 0x6446b24575d15986ull},
        {"room/soft1", 0x1f5e9c44ead5f16cull},
        {"room/soft4", 0xa624af3460efc7ecull},
        {"street/hard", 0xd5b4c35dabe6e419ull},
        {"street/soft1", 0x8c14fd3de2169a54ull},
        {"street/soft4", 0xb8b232ba0d763100ull},
        {"temple/hard", 0xf20af540717db0cdull},
        {"temple/soft1", 0x53720df8aef7529dull},
        {"temple/soft4", 0xf48d97b6c43b4c0full},
        {"classroom/hard", 0xc5f42136d2df0adaull},
        {"classroom/soft1", 0xd791ad9b43f65dfaull},
        {"classroom/soft4", 0xf014c7d9361007a4ull},
        {"dining-room/hard", 0xca556603a8e911d7ull},
        {"dining-room/soft1", 0x6f83e01da91f941bull},
        {"dining-room/soft4", 0xc1112c5db6dc7495ull},
        {"sponza-dabrovic/hard", 0x8c0680128b60140full},
        {"sponza-dabrovic/soft1", 0x014b10084e66c93cull},
        {"sponza-dabrovic/soft4", 0x97908e0bcdb45354ull},
        {"staircase/hard", 0x4f41f6ccd7e831a8ull},
        {"staircase/soft1", 0x2037ad2805b0dc3full},
        {"staircase/soft4", 0xc69a326a1236358eull},
    }},
    {"sse4.2", {
        {"room/hard", 0x6446b24575d15986ull},
        {"room/soft1", 0x1f5e9c44ead5f16cull},
        {"room/soft4", 0xa624af3460efc7ecull},
        {"street/hard", 0xec2e340fac880cf5ull},
        {"street/soft1", 0xdc9324d28e4cf55bull},
        {"street/soft4", 0x7d991243964c82aeull},
        {"temple/hard", 0xf20af540717db0cdull},
        {"temple/soft1", 0x53720df8aef7529dull},
        {"temple/soft4", 0xf48d97b6c43b4c0full},
        {"classroom/hard", 0xc5f42136d2df0adaull},
        {"classroom/soft1", 0xd791ad9b43f65dfaull},
        {"classroom/soft4", 0xf014c7d9361007a4ull},
        {"dining-room/hard", 0x4b569024b8fb26caull},
        {"dining-room/soft1", 0xe7babefa40f1eacaull},
        {"dining-room/soft4", 0xe707f154160001f5ull},
        {"sponza-dabrovic/hard", 0x8c0680128b60140full},
        {"sponza-dabrovic/soft1", 0x014b10084e66c93cull},
        {"sponza-dabrovic/soft4", 0x97908e0bcdb45354ull},
        {"staircase/hard", 0x4f41f6ccd7e831a8ull},
        {"staircase/soft1", 0x2037ad2805b0dc3full},
        {"staircase/soft4", 0xc69a326a1236358eull},
    }},
  };
  const std::string isa = embree_isa();
  return by_isa.at(isa == "sse2" ? "sse4.2" : isa);
}

uint64_t pass_hash(RtScene& rt, const GBuffer& g, const TraceSettings& s) {
  const PassPlan plan = plan_passes(rt.scene(), s);
  TraceStats st;
  const VisibilityCounts c = trace_visibility_counts(rt, g, plan, s, st);
  test::Fnv1a f;
  f.bytes(c.visible.data(), c.visible.size() * sizeof(uint16_t));
  for (uint64_t v : {st.covered_pixels, st.shadow_rays, st.invalid_rays, st.unresolved_pixels, st.shadow_skipped_facing,
                     st.shadow_skipped_range, st.shadow_inside_light})
    f.value(v);
  for (const RTCRay& r : collect_visibility_rays(rt, g, plan, s)) {
    for (float v : {r.org_x, r.org_y, r.org_z, r.tnear, r.dir_x, r.dir_y, r.dir_z, r.time, r.tfar}) f.value(v);
    f.value(r.mask);
  }
  return f.h;
}

TEST(TraceBits, VisibilityPassIsPinned) {
  const bool print = std::getenv("DHR_PRINT_TRACE_HASHES") != nullptr;
  int checked = 0;
  test::for_each_scene([&](const std::string& name, const Scene& scene) {
    if (scene.lights.empty()) return;
    RtScene rt(scene);
    // 321 x 181: odd sizes, so that rows end in partial vector blocks.
    const Camera cam = scene.camera.at(0.25, 321, 181);
    const GBuffer g = rt.primary_gbuffer(cam, 0.25);
    for (const std::string mode : {"hard", "soft1", "soft4"}) {
      TraceSettings s;
      s.seed = 7;
      s.frame = 3;
      s.soft_shadows = mode != "hard";
      s.samples_per_light = mode == "soft4" ? 4 : 1;
      const std::string key = name + "/" + mode;
      const uint64_t h = pass_hash(rt, g, s);
      TraceSettings base = s;
      base.wide_kernels = false;  // the baseline kernels: the same bits
      EXPECT_EQ(pass_hash(rt, g, base), h) << key << ": the vector and baseline kernels differ";
      if (print) {
        std::printf("      {\"%s\", 0x%016llxull},\n", key.c_str(), static_cast<unsigned long long>(h));
        continue;
      }
      const auto it = pinned().find(key);
      ASSERT_NE(it, pinned().end()) << key << " has no pinned hash";
      EXPECT_EQ(h, it->second) << key << ": the visibility pass's bits changed (Embree's " << embree_isa() << " kernels)";
      ++checked;
    }
  });
  if (!print) {
    EXPECT_GE(checked, 6);  // the built-in scenes with lights, at least
  }
}

// A packet's rays come from one row of the image: which rows a thread's block of work holds (TBB
// chooses the blocks as the threads run) must not change which rays share a packet, because
// Embree's traversal (without RTC_SCENE_FLAG_ROBUST) can decide a ray on an edge differently in
// another packet. Measured before the fix: street at 640x360 and t = 2 s, hard shadows, the
// baseline kernels gave one count more or less after other traces had run, and this test failed
// there (blocks of 1 row against blocks of 3 and of all rows). Both kernels, hard and soft (4
// rays per area light) shadows and AO.
TEST(TraceBits, CountsDoNotDependOnRowBlocks) {
  int compared = 0;
  test::for_each_scene([&](const std::string& name, const Scene& scene) {
    if (name != "street") return;
    RtScene rt(scene);
    const double t = 2.0;
    const Camera cam = scene.camera.at(t, 640, 360);
    const GBuffer g = rt.primary_gbuffer(cam, t);
    for (const std::string mode : {"hard", "soft4", "ao8"})
      for (bool wide : {true, false}) {
        std::vector<uint16_t> first;
        for (int rows : {1, 3, g.height()}) {
          TraceSettings s;
          s.seed = 7;
          s.frame = uint32_t(t * 60.0);
          s.soft_shadows = mode == "soft4";
          s.samples_per_light = mode == "soft4" ? 4 : 1;
          s.ao_rays = 8;
          s.wide_kernels = wide;
          s.rows_per_block = rows;
          const PassPlan plan = plan_passes(scene, s);
          TraceStats st;
          const std::vector<uint16_t> counts =
              mode == "ao8" ? trace_ao_counts(rt, g, 8, plan.ao_radius_m, s, st).unoccluded
                            : trace_visibility_counts(rt, g, plan, s, st).visible;
          if (first.empty()) {
            first = counts;
            continue;
          }
          size_t differ = 0;
          for (size_t i = 0; i < counts.size(); ++i) differ += counts[i] != first[i];
          EXPECT_EQ(differ, 0u) << name << " t = " << t << " " << mode << (wide ? " vector" : " baseline")
                                << " kernels: blocks of " << rows << " rows against 1";
          ++compared;
        }
      }
  });
  EXPECT_EQ(compared, 12);
}

// The AVX-512 kernels' fallbacks (zero G-buffer normals: orientation by the camera; unknown
// object and triangle ids: the G-buffer's position; NaN barycentrics) give the baseline
// kernels' bits too.
TEST(TraceBits, DamagedGBufferSameBitsOnBothKernels) {
  Scene scene = load_scene(builtin_scene_files().front(), SceneSearchPath::standard());
  ASSERT_FALSE(scene.lights.empty());
  RtScene rt(scene);
  const Camera cam = scene.camera.at(0.0, 97, 61);
  GBuffer g = rt.primary_gbuffer(cam, 0.0);
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) {
      if (g.object_id(x, y) == kBackgroundId) continue;
      switch ((x + 3 * y) % 7) {
        case 0: g.geo_normal(x, y) = glm::vec3(0.0f); break;
        case 1: g.object_id(x, y) = 0xfffffff0u; break;
        case 2: g.prim_id(x, y) = 0x7fffffffu; break;
        case 3: g.bary(x, y) = glm::vec2(std::nanf(""), 0.25f); break;
        default: break;
      }
    }
  for (const bool soft : {false, true}) {
    TraceSettings s;
    s.soft_shadows = soft;
    TraceSettings base = s;
    base.wide_kernels = false;
    EXPECT_EQ(pass_hash(rt, g, s), pass_hash(rt, g, base)) << (soft ? "soft" : "hard");
  }
}

}  // namespace
}  // namespace dhr
