// The cache keys (core/config/cache_keys.h): a key changes exactly when what it names could
// change, so runs that would compute the same bits share a value and no others do.
#include "core/config/cache_keys.h"
#include "core/scene/scene_load.h"

#include <gtest/gtest.h>

#include <string>

namespace dhr {
namespace {

const Scene& room() {
  static const Scene s = load_scene(std::string(DHR_SOURCE_DIR) + "/scenes/room.json", SceneSearchPath::standard());
  return s;
}

CacheKeys keys(const SimConfig& c) { return CacheKeys::of(c, room(), "room"); }

TEST(CacheKeys, ATracedSettingChangesTracesReferencesAndDenoisersButNotTheTruth) {
  SimConfig a;
  SimConfig b = a;
  b.trace.ao_rays = a.trace.ao_rays + 4;
  EXPECT_NE(keys(a).pass_trace(3, "ao"), keys(b).pass_trace(3, "ao"));
  EXPECT_EQ(keys(a).pass_trace(3, "visibility"), keys(b).pass_trace(3, "visibility"));  // another pass's setting
  EXPECT_NE(keys(a).local_reference(3), keys(b).local_reference(3));
  EXPECT_NE(keys(a).denoise_chain("ao"), keys(b).denoise_chain("ao"));
  EXPECT_EQ(keys(a).truth(3), keys(b).truth(3));  // the truth is the scene's, not the run's AO
  EXPECT_NE(keys(a).pass_trace(3, "ao"), keys(a).pass_trace(4, "ao"));
  EXPECT_NE(keys(a).truth(3), keys(a).truth(4));
}

TEST(CacheKeys, CodecsNetworksAndModeShareEverything) {
  SimConfig a;
  SimConfig b = a;
  b.pass("ao").codec = {"zstd"};
  b.downlink.latency_ms = 50;
  b.mode = "remote";
  b.stream_kbps = 3000;
  b.abr = "latency";
  for (int f : {0, 7}) {
    EXPECT_EQ(keys(a).pass_trace(f, "ao"), keys(b).pass_trace(f, "ao"));
    EXPECT_EQ(keys(a).local_reference(f), keys(b).local_reference(f));
    EXPECT_EQ(keys(a).truth(f), keys(b).truth(f));
  }
  EXPECT_EQ(keys(a).denoise_chain("ao"), keys(b).denoise_chain("ao"));
}

TEST(CacheKeys, ADenoiserChangesTheLocalReferenceAndItsChainOnly) {
  SimConfig a;
  SimConfig b = a;
  b.pass("ao").denoiser = {"atrous"};
  EXPECT_EQ(keys(a).pass_trace(2, "ao"), keys(b).pass_trace(2, "ao"));
  EXPECT_NE(keys(a).local_reference(2), keys(b).local_reference(2));
  EXPECT_NE(keys(a).denoise_chain("ao"), keys(b).denoise_chain("ao"));
  EXPECT_EQ(keys(a).denoise_chain("visibility"), keys(b).denoise_chain("visibility"));
  EXPECT_EQ(keys(a).truth(2), keys(b).truth(2));
}

TEST(CacheKeys, TheScenesOwnValuesKeyAsTheSceneDefault) {
  SimConfig left;  // trace.ao_rays 0: the scene's
  left.trace.ao_rays = 0;
  SimConfig named = left;
  named.trace.ao_rays = plan_passes(room(),
                                    [] {
                                      TraceSettings t;
                                      t.ao_pass = true;
                                      t.ao_rays = 0;
                                      return t;
                                    }())
                            .ao_rays;
  ASSERT_GT(named.trace.ao_rays, 0);
  EXPECT_EQ(keys(left).pass_trace(1, "ao"), keys(named).pass_trace(1, "ao"));
  EXPECT_EQ(keys(left).local_reference(1), keys(named).local_reference(1));
}

TEST(CacheKeys, FlipReferencesFollowTheScoringSchedule) {
  SimConfig c;
  c.warmup_frames = 2;
  c.frames = 10;
  c.score_every = 3;         // displayed frames 0, 3, 6, 9
  c.ground_truth_every = 6;  // of those, 0 and 6
  const CacheKeys k = keys(c);
  const std::vector<std::string> want = {k.local_reference(2), k.truth(2), k.local_reference(5),
                                         k.local_reference(8), k.truth(8), k.local_reference(11)};
  EXPECT_EQ(k.flip_references(), want);
}

}  // namespace
}  // namespace dhr
