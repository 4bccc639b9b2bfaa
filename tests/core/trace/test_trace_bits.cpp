// The visibility pass's output bits, pinned: on every built-in scene and every real scene
// (skipped when ../shared/scenes is missing), in each shadow mode (hard, one jittered ray per
// light, 4 rays per light), the FNV-1a hash of the counts, of the statistics and of the rays
// handed to Embree (collect_visibility_rays) must equal the recorded values (below: which code
// recorded them); where Embree runs other kernels than AVX-512, the values of that ISA's table.
// A change of the tracer's kernels that moves any ray or any count by one bit fails here; a
// deliberate change of the output must update every table and say so. Run with
// DHR_PRINT_TRACE_HASHES=1 to print the table's rows for the current code, once per ISA on a
// machine with AVX-512:
//   for isa in avx512 avx2 avx sse4.2; do DHR_MAX_ISA=$isa DHR_PRINT_TRACE_HASHES=1
//     build/tests/test_trace_bits --gtest_filter=TraceBits.VisibilityPassIsPinned; done
// (one command: the loop's body is one line).
#include "core/base/error.h"
#include "core/scene/scene_load.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"
#include "core/trace/trace_rays.h"

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
// dhr::embree_isa(), the CPU's best or DHR_MAX_ISA's cap (core/trace/rt_scene.h). ctest runs
// this binary once as it is and once per other table with the cap (tests/CMakeLists.txt), so a
// machine with AVX-512 checks every table. The tables of the ISAs before AVX-512 were recorded
// on AMD EPYCs: those kernels start from rcpps, whose bits the x86 vendors do not share, so an
// Intel CPU without AVX-512 may give other hashes (not checked: no such machine here).

// scene/mode -> hash, by the ISA Embree runs (dhr::embree_isa(); SSE2 and SSE4.2 agree). Every
// row of every table is the tracer's with ray origins from an error bound (core/trace/trace.h,
// origin_offset_m) and scenes with moving objects in Embree's two-level layout
// (RtSceneOptions::static_child), recorded with the loop in this file's header (every ISA by
// DHR_MAX_ISA on one AVX-512 machine) in commit 9db9702, whose message lists the counts that
// moved. On AMD EPYCs, DHR_MAX_ISA=avx2 on an AVX-512 machine gives the table of a machine
// without AVX-512 (compared on the tables of commit c05ad78). Debian's Embree does not read a
// ~/.embree3 file: DHR_MAX_ISA is what caps its kernels. The plain tables below AVX-512 are an
// AMD Zen 4's (family 25); the "@b1456c31" ones an AMD Zen 5's (family 26, the same loop), whose
// rcpps differs: every row below AVX-512 differs, the AVX-512 table is the same.
// The table's name: the ISA Embree runs (SSE2 reads SSE4.2's), and below AVX-512 "@" and the
// CPU's rcpps signature (core/trace/rt_scene.h, cpu_rcp_signature). A CPU whose signature has no table
// reads the plain ISA's, recorded on AMD Zen 4 (family 25).
std::string table_key() {
  const std::string isa = embree_isa() == "sse2" ? "sse4.2" : embree_isa();
  return isa == "avx512" ? isa : isa + "@" + cpu_rcp_signature();
}

const std::map<std::string, uint64_t>& pinned() {
  using Table = std::map<std::string, uint64_t>;
  // clang-format off
  static const std::map<std::string, Table> by_isa = {
    {"avx512", {
        {"room/hard", 0x9a889fefc41c71edull},
        {"room/soft1", 0x66bca036b0dcc83bull},
        {"room/soft4", 0x54d70e1f7f05006aull},
        {"street/hard", 0xa35fbbbc2c58da61ull},
        {"street/soft1", 0x9109aede4b50c2f4ull},
        {"street/soft4", 0xf0b3177f09e6b416ull},
        {"temple/hard", 0xd85dd201eda79d8bull},
        {"temple/soft1", 0x455c1b4f3683f013ull},
        {"temple/soft4", 0x637618f5587ea8f0ull},
        {"classroom/hard", 0xa1c1419a2fafa9d3ull},
        {"classroom/soft1", 0xb5f5a789ec8754abull},
        {"classroom/soft4", 0x3973d2ffd9358057ull},
        {"dining-room/hard", 0xaac75c43e562518aull},
        {"dining-room/soft1", 0xb9560233374fd29aull},
        {"dining-room/soft4", 0xa184e74f7e243e14ull},
        {"sponza-dabrovic/hard", 0xce31411a06b6e69bull},
        {"sponza-dabrovic/soft1", 0x0c0e0a4c25d8f7abull},
        {"sponza-dabrovic/soft4", 0x9a1bfeb9880fcccaull},
        {"staircase/hard", 0xaefc0a44a1d622b4ull},
        {"staircase/soft1", 0xaa648bbd43897ce4ull},
        {"staircase/soft4", 0x87afde0a1c84f112ull},
    }},
    {"avx2", {
        {"room/hard", 0xefc81d0bc326cde5ull},
        {"room/soft1", 0x34203acea0ac609eull},
        {"room/soft4", 0x06ad2efe5ca3f768ull},
        {"street/hard", 0x989be843b3248af7ull},
        {"street/soft1", 0x011a34157d2e4d1dull},
        {"street/soft4", 0x07134fccfd6a87f2ull},
        {"temple/hard", 0x6d6441a69a682f3aull},
        {"temple/soft1", 0x1b5e24f24e3e940eull},
        {"temple/soft4", 0x23e92f667892e5fcull},
        {"classroom/hard", 0x84731f03b347ce38ull},
        {"classroom/soft1", 0xf888b723773a49cbull},
        {"classroom/soft4", 0xe0911c842ae59b87ull},
        {"dining-room/hard", 0xf5c91981ec267bc0ull},
        {"dining-room/soft1", 0xa9b4240c3a821a49ull},
        {"dining-room/soft4", 0x433fcb9ac1e541c0ull},
        {"sponza-dabrovic/hard", 0xed120db7c1782e16ull},
        {"sponza-dabrovic/soft1", 0x7085d03548e1de7full},
        {"sponza-dabrovic/soft4", 0xff722f2891a9b315ull},
        {"staircase/hard", 0xcc5076e56778b903ull},
        {"staircase/soft1", 0x2681e4a35071bfd4ull},
        {"staircase/soft4", 0x752bbda6f5f739e3ull},
    }},
    {"avx", {
        {"room/hard", 0xdf70a9961eb319b2ull},
        {"room/soft1", 0x06b3ca29b471d984ull},
        {"room/soft4", 0x949577a3032efc6full},
        {"street/hard", 0x32d74047590ddc60ull},
        {"street/soft1", 0xb9cb8336accb7a2cull},
        {"street/soft4", 0x4f1dd4b5cc6dbd3cull},
        {"temple/hard", 0x866ea6a0b902f813ull},
        {"temple/soft1", 0x8c4370b86dfd10e7ull},
        {"temple/soft4", 0x06d58c6b42c9dce4ull},
        {"classroom/hard", 0x29a44b6e45176c1dull},
        {"classroom/soft1", 0xcf85aeb9adf35246ull},
        {"classroom/soft4", 0x4ac67145350b1e9aull},
        {"dining-room/hard", 0xc724f45c65dcca94ull},
        {"dining-room/soft1", 0x4592ed7e395df97full},
        {"dining-room/soft4", 0x1a3769905acf5460ull},
        {"sponza-dabrovic/hard", 0xa71c8f54fb03ccddull},
        {"sponza-dabrovic/soft1", 0xde4468e09e1cf0d7ull},
        {"sponza-dabrovic/soft4", 0xc92ff06aea832896ull},
        {"staircase/hard", 0xe2507debe5b1050dull},
        {"staircase/soft1", 0x68e9cbac611471d8ull},
        {"staircase/soft4", 0x601acd1fe68fe4d0ull},
    }},
    {"sse4.2", {
        {"room/hard", 0xdf70a9961eb319b2ull},
        {"room/soft1", 0x06b3ca29b471d984ull},
        {"room/soft4", 0x949577a3032efc6full},
        {"street/hard", 0x492ead2cc7f65e47ull},
        {"street/soft1", 0xa8d47fc10a29e88eull},
        {"street/soft4", 0x0cebd82742f53ac7ull},
        {"temple/hard", 0x866ea6a0b902f813ull},
        {"temple/soft1", 0x8c4370b86dfd10e7ull},
        {"temple/soft4", 0x06d58c6b42c9dce4ull},
        {"classroom/hard", 0x29a44b6e45176c1dull},
        {"classroom/soft1", 0xcf85aeb9adf35246ull},
        {"classroom/soft4", 0x4ac67145350b1e9aull},
        {"dining-room/hard", 0x907b45bf83d65d3cull},
        {"dining-room/soft1", 0x2aa2ac0c2b2b89f7ull},
        {"dining-room/soft4", 0x4407fb76c6281178ull},
        {"sponza-dabrovic/hard", 0xa71c8f54fb03ccddull},
        {"sponza-dabrovic/soft1", 0xde4468e09e1cf0d7ull},
        {"sponza-dabrovic/soft4", 0xc92ff06aea832896ull},
        {"staircase/hard", 0xe2507debe5b1050dull},
        {"staircase/soft1", 0x68e9cbac611471d8ull},
        {"staircase/soft4", 0x601acd1fe68fe4d0ull},
    }},
    {"avx2@b1456c31", {
      {"room/hard", 0x7fce1f2dbd6cd39cull},
      {"room/soft1", 0x57f82535bcf144b2ull},
      {"room/soft4", 0x0e476640f58dfb53ull},
      {"street/hard", 0xa4f1eabff8cfdbf8ull},
      {"street/soft1", 0x34a5479e46380f4bull},
      {"street/soft4", 0x1a1d80b35b18b8deull},
      {"temple/hard", 0x7c34b5061beec8e6ull},
      {"temple/soft1", 0x29331be6c481ef5eull},
      {"temple/soft4", 0x979ce6ab3181f435ull},
      {"classroom/hard", 0x5b8aa29915240062ull},
      {"classroom/soft1", 0xdce196f8403d4445ull},
      {"classroom/soft4", 0x49803e388572b367ull},
      {"dining-room/hard", 0x74a1e6f913229df9ull},
      {"dining-room/soft1", 0x5460fceaf16f281aull},
      {"dining-room/soft4", 0x327471e97c03111cull},
      {"sponza-dabrovic/hard", 0x64c9976fb0f0d6a1ull},
      {"sponza-dabrovic/soft1", 0x9b0a681ab6b353d2ull},
      {"sponza-dabrovic/soft4", 0x525d3fae17a4c5d0ull},
      {"staircase/hard", 0x5900397a6b8bbf6aull},
      {"staircase/soft1", 0x8756df83e6c023d9ull},
      {"staircase/soft4", 0x268cf36ad6b4cf0cull},
    }},
    {"avx@b1456c31", {
      {"room/hard", 0xa4b60a9a388694caull},
      {"room/soft1", 0x111afe9e1582ce56ull},
      {"room/soft4", 0x6148f71919f88184ull},
      {"street/hard", 0x37ec8ade03a1630bull},
      {"street/soft1", 0xfc35a904271ae227ull},
      {"street/soft4", 0x81b7c4fed470d2daull},
      {"temple/hard", 0xfa5ff3b032ce419eull},
      {"temple/soft1", 0x14ceb13919837cfaull},
      {"temple/soft4", 0x12514027f47fbe66ull},
      {"classroom/hard", 0x4331f56f15bfcc55ull},
      {"classroom/soft1", 0x25b5c8786e70240aull},
      {"classroom/soft4", 0x3ccd63b6c14251f2ull},
      {"dining-room/hard", 0xb37eeb81efa36ba3ull},
      {"dining-room/soft1", 0xb7b9830b91a77e67ull},
      {"dining-room/soft4", 0x56204324ee0b64ecull},
      {"sponza-dabrovic/hard", 0x8b2554d21fc3b147ull},
      {"sponza-dabrovic/soft1", 0xb0b8cc30bfd4557full},
      {"sponza-dabrovic/soft4", 0x4b2cc95cd201a1f1ull},
      {"staircase/hard", 0x47708b38f26d2528ull},
      {"staircase/soft1", 0xebb51b8fa80cef7eull},
      {"staircase/soft4", 0xc7012b162c73f66full},
    }},
    {"sse4.2@b1456c31", {
      {"room/hard", 0xa4b60a9a388694caull},
      {"room/soft1", 0x111afe9e1582ce56ull},
      {"room/soft4", 0x6148f71919f88184ull},
      {"street/hard", 0xa8888c3ed12586ffull},
      {"street/soft1", 0x0df448d2860b6627ull},
      {"street/soft4", 0xd79ab7602cff2f7dull},
      {"temple/hard", 0xfa5ff3b032ce419eull},
      {"temple/soft1", 0x14ceb13919837cfaull},
      {"temple/soft4", 0x12514027f47fbe66ull},
      {"classroom/hard", 0x4331f56f15bfcc55ull},
      {"classroom/soft1", 0x25b5c8786e70240aull},
      {"classroom/soft4", 0x3ccd63b6c14251f2ull},
      {"dining-room/hard", 0xa63bc3a8d3140226ull},
      {"dining-room/soft1", 0x76cb10f5ca9f5082ull},
      {"dining-room/soft4", 0x2db75f68c076581cull},
      {"sponza-dabrovic/hard", 0x8b2554d21fc3b147ull},
      {"sponza-dabrovic/soft1", 0xb0b8cc30bfd4557full},
      {"sponza-dabrovic/soft4", 0x4b2cc95cd201a1f1ull},
      {"staircase/hard", 0x47708b38f26d2528ull},
      {"staircase/soft1", 0xebb51b8fa80cef7eull},
      {"staircase/soft4", 0xc7012b162c73f66full},
    }},
  };
  // clang-format on
  const std::string key = table_key();
  const auto it = by_isa.find(key);
  return it != by_isa.end() ? it->second : by_isa.at(key.substr(0, key.find('@')));
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
  if (print) std::printf("    {\"%s\", {\n", table_key().c_str());
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
      EXPECT_EQ(h, it->second) << key << ": the visibility pass's bits changed (Embree's " << embree_isa()
                               << " kernels)";
      ++checked;
    }
  });
  if (print) std::printf("    }},\n");
  if (!print) {
    EXPECT_GE(checked, 6);  // the built-in scenes with lights, at least
  }
}

// A packet's rays come from one row of the image: which rows a thread's block of work holds (TBB
// chooses the blocks as the threads run) must not change which rays share a packet, because
// Embree's traversal (without RTC_SCENE_FLAG_ROBUST) can decide a ray on an edge differently in
// another packet. Packets that follow the blocks instead make street at 640x360 and t = 2 s,
// hard shadows, give one count more or less with the baseline kernels after other traces have
// run, and this test fails on them (blocks of 1 row against blocks of 3 and of all rows).
// Both kernels, hard and soft (4 rays per area light) shadows and AO.
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
          const std::vector<uint16_t> counts = mode == "ao8"
                                                   ? trace_ao_counts(rt, g, 8, plan.ao_radius_m, s, st).unoccluded
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
