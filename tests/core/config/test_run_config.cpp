// The table of run settings (core/config/run_config.h): every test here loops over run_settings(), so
// that a new setting is covered without editing it.
#include "backends/register_all.h"
#include "core/config/run_config.h"
#include "core/experiment/experiment.h"
#include "core/live/live.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

namespace dhr {
namespace {

namespace fs = std::filesystem;

std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += "\n  " + x;
  return s;
}

// A valid value of `s` other than its default.
nlohmann::json other_value(const RunSetting& s) {
  const nlohmann::json d = s.default_value();
  switch (s.type) {
    case SettingType::Integer: return d.get<double>() == s.hi ? int64_t(s.lo) : int64_t(s.hi);
    case SettingType::Number: return d.get<double>() == s.hi ? s.lo : s.hi;
    case SettingType::Boolean: return !d.get<bool>();
    case SettingType::Choice:
      for (const auto& c : s.choices)
        if (c != d) return c;
      break;
    case SettingType::String: return d.get<std::string>() + "-other";
    case SettingType::Backend: return {{"name", "some-" + s.kind}, {"params", {{"p", 1}}}};
    case SettingType::Link: {
      nlohmann::json l = d;
      l["latency_ms"] = 33.0;
      l["mtu_bytes"] = 9000;
      return l;
    }
  }
  ADD_FAILURE() << s.key << ": no other value";
  return d;
}

SimConfig read(const nlohmann::json& j, int version, std::vector<std::string>& problems) {
  return sim_config_from_json(j, "run", problems, version);
}

TEST(RunSettings, KeysAreUniqueAndDefaultsAreValid) {
  std::set<std::string> keys;
  for (const RunSetting& s : run_settings()) {
    EXPECT_TRUE(keys.insert(s.key).second) << s.key;
    EXPECT_FALSE(s.doc.empty()) << s.key;
    EXPECT_FALSE(s.check_value(s.default_value(), s.key)) << s.key << ": the default is out of its own range";
  }
  EXPECT_TRUE(setting_range_problems(SimConfig{}).empty()) << joined(setting_range_problems(SimConfig{}));
}

TEST(RunSettings, EverySettingRoundTripsThroughToJsonAndTheReader) {
  SimConfig all;
  for (const RunSetting& s : run_settings()) {
    SimConfig c;
    s.set(c, other_value(s));
    s.set(all, other_value(s));
    ASSERT_NE(s.get(c), s.default_value()) << s.key;
    for (int version : {1, 2}) {
      std::vector<std::string> problems;
      const SimConfig back = read(c.to_json(), version, problems);
      EXPECT_TRUE(problems.empty()) << s.key << joined(problems);
      EXPECT_EQ(s.get(back), s.get(c)) << s.key;
      EXPECT_EQ(back.to_json(), c.to_json()) << s.key;
    }
  }
  std::vector<std::string> problems;
  EXPECT_EQ(read(all.to_json(), 2, problems).to_json(), all.to_json());
  EXPECT_TRUE(problems.empty()) << joined(problems);
}

TEST(RunSettings, AnOutOfRangeValueIsRejectedNamingTheKey) {
  for (const RunSetting& s : run_settings()) {
    std::vector<nlohmann::json> bad;
    if (s.type == SettingType::Integer || s.type == SettingType::Number) {
      const double above = s.hi + std::max(1.0, s.hi * 1e-3);
      bad = {s.type == SettingType::Integer ? nlohmann::json(int64_t(above)) : nlohmann::json(above), s.lo - 1, "7"};
      if (s.type == SettingType::Integer) bad.push_back(s.lo + 0.5);
    } else if (s.type == SettingType::Choice) {
      bad = {"no-such-choice", 1};
    } else if (s.type == SettingType::Boolean) {
      bad = {"yes", 1};
    } else if (s.type == SettingType::String) {
      bad = {1};
    } else if (s.type == SettingType::Backend) {
      bad = {"lz4", nlohmann::json{{"name", 1}}, nlohmann::json{{"name", "lz4"}, {"level", 3}}};
    } else {
      bad = {nlohmann::json{{"latency_ms", -1}}, nlohmann::json{{"no_such_key", 1}}};
    }
    for (const auto& v : bad) {
      nlohmann::json j = nlohmann::json::object();
      set_dotted(j, s.key, v);
      std::vector<std::string> problems;
      const SimConfig c = read(j, 2, problems);
      ASSERT_FALSE(problems.empty()) << s.key << " = " << v.dump() << " accepted";
      EXPECT_NE(problems.front().find("run." + s.key), std::string::npos) << s.key << joined(problems);
      EXPECT_EQ(s.get(c), s.default_value()) << s.key << ": a rejected value must not be set";
    }
    // plan_run's ranges (for a value set from C++) come from the same table.
    if (s.type == SettingType::Integer || s.type == SettingType::Number) {
      SimConfig c;
      s.set(c, nlohmann::json(int64_t(s.hi) + 1));
      const auto problems = setting_range_problems(c);
      ASSERT_EQ(problems.size(), 1u) << s.key << joined(problems);
      EXPECT_EQ(problems[0].rfind(s.key + " = ", 0), 0u) << problems[0];
      EXPECT_NE(problems[0].find(s.range_text()), std::string::npos) << problems[0];
    }
  }
}

TEST(RunSettings, UnknownKeysAreNamedWithTheValidOnes) {
  std::vector<std::string> problems;
  read({{"widht", 3}, {"trace", {{"ao_ray", 1}}}, {"passes", {{"ao", {{"codek", {}}}}, {"normal", {}}}}}, 2, problems);
  const std::string all = joined(problems);
  EXPECT_NE(all.find("run.widht: unknown key (valid: mode, width"), std::string::npos) << all;
  EXPECT_NE(all.find("run.trace.ao_ray: unknown key (valid: ao_rays"), std::string::npos) << all;
  EXPECT_NE(
      all.find("run.passes.ao.codek: unknown key (valid: codec, denoiser, predictor, fec_parity, fec_min_parity)"),
      std::string::npos)
      << all;
  EXPECT_NE(all.find("run.passes.normal: unknown key (valid: visibility, ao, colour, depth)"), std::string::npos)
      << all;
}

// The version-1 keys and the per-pass keys that replace them.
const nlohmann::json kOld = {{"visibility_codec", {{"name", "zstd"}, {"params", {{"level", 9}}}}},
                             {"ao_codec", {{"name", "h264"}}},
                             {"colour_codec", {{"name", "raw"}}},
                             {"visibility_denoiser", {{"name", "atrous"}}},
                             {"ao_denoiser", {{"name", "svgf_ao"}, {"params", {{"iterations", 2}}}}},
                             {"predictor", {{"name", "none"}}},
                             {"colour_predictor", {{"name", "rotation_warp"}}}};
const nlohmann::json kNew = {
    {"passes",
     {{"visibility",
       {{"codec", {{"name", "zstd"}, {"params", {{"level", 9}}}}},
        {"denoiser", {{"name", "atrous"}}},
        {"predictor", {{"name", "none"}}}}},
      {"ao",
       {{"codec", {{"name", "h264"}}},
        {"denoiser", {{"name", "svgf_ao"}, {"params", {{"iterations", 2}}}}},
        {"predictor", {{"name", "none"}}}}},
      {"colour", {{"codec", {{"name", "raw"}}}, {"predictor", {{"name", "rotation_warp"}}}}}}}};

TEST(RunSettings, OldKeysInVersion1GiveTheSameConfigAsTheNewKeys) {
  std::vector<std::string> p1, p2;
  const SimConfig a = read(kOld, 1, p1), b = read(kNew, 2, p2);
  EXPECT_TRUE(p1.empty()) << joined(p1);
  EXPECT_TRUE(p2.empty()) << joined(p2);
  EXPECT_EQ(a.to_json(), b.to_json());
  EXPECT_EQ(a.pass("ao").predictor.name, "none") << "\"predictor\" sets both passes";
  // Every version-1 key is covered above.
  for (const auto& [old, replacements] : v1_run_keys()) EXPECT_TRUE(kOld.contains(old)) << old;
  // Both spellings of one setting at once: an error.
  nlohmann::json both = kOld;
  both["passes"] = {{"ao", {{"codec", {{"name", "lz4"}}}}}};
  std::vector<std::string> p3;
  read(both, 1, p3);
  EXPECT_NE(joined(p3).find("run.ao_codec and run.passes.ao.codec: both given"), std::string::npos) << joined(p3);
}

TEST(RunSettings, OldKeysInVersion2AreErrorsNamingTheNewKey) {
  std::vector<std::string> problems;
  read(kOld, 2, problems);
  const std::string all = joined(problems);
  EXPECT_EQ(problems.size(), v1_run_keys().size()) << all;
  EXPECT_NE(all.find("run.ao_codec: a version-1 key; version 2 writes it passes.ao.codec"), std::string::npos) << all;
  EXPECT_NE(
      all.find(
          "run.predictor: a version-1 key; version 2 writes it passes.visibility.predictor and passes.ao.predictor"),
      std::string::npos)
      << all;
}

TEST(RunSettings, PerPassPredictorsMayDiffer) {
  std::vector<std::string> problems;
  nlohmann::json j = kNew;
  j["passes"]["ao"]["predictor"] = {{"name", "reprojection"}};
  const SimConfig c = read(j, 2, problems);
  EXPECT_TRUE(problems.empty()) << joined(problems);
  EXPECT_EQ(c.pass("visibility").predictor.name, "none");
  EXPECT_EQ(c.pass("ao").predictor.name, "reprojection");
  EXPECT_EQ(c.pass("colour").predictor.name, "rotation_warp");
}

TEST(RunSettings, CacheKeysChangeWithExactlyTheFlaggedSettings) {
  const SimConfig d;
  for (const RunSetting& s : run_settings()) {
    SimConfig c;
    s.set(c, other_value(s));
    EXPECT_EQ(settings_key(c, kInTraceKey) != settings_key(d, kInTraceKey), s.has(kInTraceKey)) << s.key;
    EXPECT_EQ(settings_key(c, kInTruthKey) != settings_key(d, kInTruthKey), s.has(kInTruthKey)) << s.key;
  }
}

void flatten(const nlohmann::json& j, const std::string& prefix, std::set<std::string>& out) {
  for (const auto& [k, v] : j.items()) {
    const std::string key = prefix.empty() ? k : prefix + "." + k;
    if ((k == "trace" || k == "passes") && prefix.empty())
      flatten(v, key, out);
    else if (prefix == "passes")
      flatten(v, key, out);
    else
      out.insert(key);
  }
}

TEST(RunSettings, TheLiveOfferHoldsExactlyTheOfferFlaggedSettings) {
  const nlohmann::json offer = session_offer(SimConfig{}, registries(), "room", "abc");
  std::set<std::string> keys, expected{"protocol", "scene", "scene_hash"};
  flatten(offer, "", keys);
  for (const RunSetting& s : run_settings())
    if (s.has(kInLiveOffer)) expected.insert(s.v1_key.empty() ? s.key : s.v1_key);
  EXPECT_EQ(keys, expected);
  // Each changes the offer.
  for (const RunSetting& s : run_settings()) {
    if (s.type == SettingType::Backend || s.type == SettingType::Link) continue;  // names must be registered
    SimConfig c;
    s.set(c, other_value(s));
    EXPECT_EQ(session_offer(c, registries(), "room", "abc") != offer, s.has(kInLiveOffer)) << s.key;
  }
}

TEST(RunSettings, LiveModeNamesTheSettingsItIgnores) {
  EXPECT_TRUE(live_ignored_fields(SimConfig{}).empty());
  for (const RunSetting& s : run_settings()) {
    if (s.live_ignored.empty()) continue;
    SimConfig c;
    s.set(c, other_value(s));
    const auto fields = live_ignored_fields(c);
    ASSERT_EQ(fields.size(), 1u) << s.key;
    EXPECT_EQ(fields[0].rfind(s.key + " (", 0), 0u) << fields[0];
  }
  // The live client runs ClientPipeline, which predicts each pass with its own predictor.
  SimConfig c;
  c.pass("ao").predictor = {"none"};
  EXPECT_TRUE(live_ignored_fields(c).empty());
}

// In experiment files: version 1 keeps its keys (also dotted, in sweeps) and labels, and gets
// hints; version 2 refuses them.
TEST(RunSettings, ExperimentVersions) {
  const fs::path dir = fs::temp_directory_path() / "dhr_run_config_test";
  fs::create_directories(dir);
  auto write = [&](const char* name, const nlohmann::json& j) {
    std::ofstream(dir / name) << j.dump();
    return (dir / name).string();
  };
  const nlohmann::json v1 = {{"version", 1},
                             {"scenes", {"room"}},
                             {"run", {{"ao_codec", {{"name", "zstd"}}}}},
                             {"sweep", {{"ao_denoiser.name", {"none", "atrous"}}, {"predictor.name", {"none"}}}}};
  const nlohmann::json v2 = {{"version", 2},
                             {"scenes", {"room"}},
                             {"run", {{"passes", {{"ao", {{"codec", {{"name", "zstd"}}}}}}}}},
                             {"sweep",
                              {{"passes.ao.denoiser.name", {"none", "atrous"}},
                               {"passes.visibility.predictor.name", {"none"}},
                               {"passes.ao.predictor.name", {"none"}}}}};
  const Experiment a = load_experiment(write("v1.json", v1)), b = load_experiment(write("v2.json", v2));
  ASSERT_EQ(a.runs.size(), 2u);
  ASSERT_EQ(b.runs.size(), 2u);
  for (size_t i = 0; i < 2; ++i) EXPECT_EQ(a.runs[i].config.to_json(), b.runs[i].config.to_json()) << i;
  EXPECT_EQ(a.runs[1].label, "ao_denoiser.name=atrous, predictor.name=none");
  EXPECT_EQ(a.hints.size(), 3u) << joined(a.hints);
  EXPECT_NE(joined(a.hints).find("sweep: \"predictor.name\" is written \"passes.visibility.predictor.name and "
                                 "passes.ao.predictor.name\" in version 2"),
            std::string::npos)
      << joined(a.hints);
  EXPECT_TRUE(b.hints.empty());
  nlohmann::json v2_old = v1;
  v2_old["version"] = 2;
  try {
    load_experiment(write("v2_old.json", v2_old));
    ADD_FAILURE() << "version 2 accepted version-1 keys";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("run.ao_codec: a version-1 key; version 2 writes it passes.ao.codec"), std::string::npos) << m;
    EXPECT_NE(m.find("run.ao_denoiser: a version-1 key; version 2 writes it passes.ao.denoiser"), std::string::npos)
        << m;
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace dhr

// camera_speed runs the camera's path faster than the scene clock from the run's start (a second,
// faster head motion over the same scene); 1 is the path as authored.
TEST(RunSettings, CameraSpeedScalesTheCameraClockFromTheStart) {
  dhr::SimConfig c;
  c.start_time_s = 1.0;
  EXPECT_DOUBLE_EQ(c.camera_time_s(1.5), 1.5);
  c.camera_speed = 2.0;
  EXPECT_DOUBLE_EQ(c.camera_time_s(1.0), 1.0);
  EXPECT_DOUBLE_EQ(c.camera_time_s(1.5), 2.0);
  EXPECT_DOUBLE_EQ(c.camera_time_s(3.0), 5.0);
}
