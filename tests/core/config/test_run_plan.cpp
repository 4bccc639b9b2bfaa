// A run planned once (core/config/run_plan.h): the passes each mode traces and sends, its stage
// lists, the effective backends, and every problem reported at once.
#include "backends/register_all.h"
#include "core/config/run_plan.h"
#include "core/scene/scene_load.h"
#include "tests/support.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace dhr {
namespace {

const Scene& room() {
  static const Scene s = load_scene(std::string(DHR_SOURCE_DIR) + "/scenes/room.json", SceneSearchPath::standard());
  return s;
}

std::vector<std::string> names(const std::vector<PlannedPass>& passes) {
  std::vector<std::string> out;
  for (const PlannedPass& p : passes) out.push_back(p.name);
  return out;
}

SimConfig small() {
  SimConfig c;
  c.width = 64;
  c.height = 36;
  return c;
}

TEST(RunPlan, HybridTracesAndSendsTheScenesPasses) {
  const RunPlan plan = plan_run(small(), room(), registries());
  EXPECT_FALSE(plan.remote());
  EXPECT_EQ(plan.scene, &room());
  EXPECT_EQ(names(plan.traced), (std::vector<std::string>{"visibility", "ao"}));
  EXPECT_EQ(names(plan.sent), names(plan.traced));
  EXPECT_EQ(plan.depth_bits, 0);
  EXPECT_EQ(plan.server_stages, (std::vector<ServerStage>{ServerStage::Rasterize, ServerStage::Trace,
                                                          ServerStage::Denoise, ServerStage::Encode}));
  EXPECT_EQ(plan.client_stages, (std::vector<ClientStage>{ClientStage::Rasterize, ClientStage::Decode,
                                                          ClientStage::Predict, ClientStage::Composite}));
  EXPECT_EQ(plan.passes.lights, int(room().lights.size()));
}

TEST(RunPlan, AoAtReducedResolutionAddsTheClientsUpsampling) {
  SimConfig c = small();
  c.trace.ao_scale = 2;
  const RunPlan plan = plan_run(c, room(), registries());
  EXPECT_TRUE(plan.client_does(ClientStage::Upsample));
  EXPECT_EQ(plan.sent.back().desc.width, 32);
}

TEST(RunPlan, RemoteIsTheHybridServerThenCompositeAndColour) {
  SimConfig c = small();
  c.mode = "remote";
  const RunPlan rotation = plan_run(c, room(), registries());
  EXPECT_TRUE(rotation.remote());
  EXPECT_EQ(names(rotation.traced), (std::vector<std::string>{"visibility", "ao"}));
  EXPECT_EQ(names(rotation.sent), (std::vector<std::string>{"colour"}));
  EXPECT_EQ(rotation.server_stages,
            (std::vector<ServerStage>{ServerStage::Rasterize, ServerStage::Trace, ServerStage::Denoise,
                                      ServerStage::Composite, ServerStage::Encode}));
  EXPECT_EQ(rotation.client_stages, (std::vector<ClientStage>{ClientStage::Decode, ClientStage::Predict}));

  // A colour predictor that reads depth: the server packs the depth pass beside the colour.
  c.pass("colour").predictor = {"depth_warp", {{"depth_bits", 12}}};
  const RunPlan depth = plan_run(c, room(), registries());
  EXPECT_EQ(names(depth.sent), (std::vector<std::string>{"colour", "depth"}));
  EXPECT_EQ(depth.depth_bits, 12);
  EXPECT_TRUE(depth.server_does(ServerStage::PackDepth));
  EXPECT_FALSE(rotation.server_does(ServerStage::PackDepth));
}

TEST(RunPlan, RecordsEveryBackendWithItsEffectiveParameters) {
  const RunPlan plan = plan_run(small(), room(), registries());
  for (const RunSetting& s : run_settings()) {
    if (s.type != SettingType::Backend) continue;
    ASSERT_TRUE(plan.backends.contains(s.key)) << s.key;
    EXPECT_EQ(plan.backends[s.key]["name"], s.get(plan.config)["name"]) << s.key;
  }
  // The defaults a backend fills in are there although the settings name none.
  SimConfig c = small();
  c.pass("ao").codec = {"h264"};
  const RunPlan h264 = plan_run(c, room(), registries());
  EXPECT_TRUE(h264.backends["passes.ao.codec"]["params"].contains("crf")) << h264.backends["passes.ao.codec"].dump();
}

TEST(RunPlan, ListsEveryProblemAtOnce) {
  SimConfig c = small();
  c.width = 0;
  c.pass("ao").codec = {"no-such-codec"};
  c.pass("visibility").codec = {"h264"};
  const std::string m = test::error_of([&] { plan_run(c, room(), registries()); });
  EXPECT_NE(m.find("width"), std::string::npos) << m;
  EXPECT_NE(m.find("passes.ao.codec"), std::string::npos) << m;
  EXPECT_NE(m.find("no-such-codec"), std::string::npos) << m;

  // Pose prediction is remote rendering's: a hybrid client's G-buffers would not match.
  SimConfig lead = small();
  lead.server_pose_prediction = "delay";
  const std::string hybrid = test::error_of([&] { plan_run(lead, room(), registries()); });
  EXPECT_NE(hybrid.find("server_pose_prediction 'delay'"), std::string::npos) << hybrid;
  lead.mode = "remote";
  EXPECT_NO_THROW(plan_run(lead, room(), registries()));
  lead.server_timing = SimConfig::ServerTiming::Measured;
  EXPECT_NE(test::error_of([&] { plan_run(lead, room(), registries()); }).find("needs server_timing fixed"),
            std::string::npos);

  // A lossy codec cannot carry the bitmask (checked once the passes are planned).
  SimConfig lossy = small();
  lossy.pass("visibility").codec = {"h264"};
  const std::string bitmask = test::error_of([&] { plan_run(lossy, room(), registries()); });
  EXPECT_NE(bitmask.find("passes.visibility.codec 'h264' cannot carry"), std::string::npos) << bitmask;
}

}  // namespace
}  // namespace dhr
