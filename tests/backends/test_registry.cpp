// The registry: every expected backend is registered, names and parameters are validated,
// every backend of every kind can be created with its defaults, and every example that
// `dhrbench list` prints is accepted by the experiment loader and by --set.
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/experiment/experiment.h"
#include "experiments/cli/list_examples.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <string>
#include <vector>

namespace dhr {
namespace {

template <class I>
std::set<std::string> names(const Registry<I>& r) {
  std::set<std::string> s;
  for (const auto& e : r.entries()) s.insert(e.name);
  return s;
}

bool contains_all(const std::set<std::string>& have, std::initializer_list<const char*> want, std::string& missing) {
  for (const char* w : want)
    if (!have.count(w)) missing += std::string(" ") + w;
  return missing.empty();
}

TEST(Registry, ExpectedBackendsAreRegistered) {
  std::string missing;
  EXPECT_TRUE(contains_all(names(registries().codecs), {"raw", "lz4", "zstd", "h264", "delta"}, missing))
      << "codecs missing:" << missing;
  EXPECT_TRUE(contains_all(names(registries().denoisers), {"none", "svgf_ao", "atrous", "single_iteration", "temporal"},
                           missing))
      << "denoisers missing:" << missing;
  EXPECT_TRUE(contains_all(names(registries().predictors), {"none", "reprojection", "rotation_warp"}, missing))
      << "predictors missing:" << missing;
}

TEST(Registry, EveryBackendHasDescriptionAndCreatesWithDefaults) {
  const Registries& r = registries();
  for (const auto& e : r.codecs.entries()) {
    EXPECT_FALSE(e.description.empty()) << e.name;
    EXPECT_NE(r.codecs.create(e.name, nlohmann::json::object()), nullptr) << e.name;
  }
  for (const auto& e : r.denoisers.entries()) {
    EXPECT_FALSE(e.description.empty()) << e.name;
    EXPECT_NE(r.denoisers.create(e.name, nlohmann::json::object()), nullptr) << e.name;
  }
  for (const auto& e : r.predictors.entries()) {
    EXPECT_FALSE(e.description.empty()) << e.name;
    EXPECT_NE(r.predictors.create(e.name, nlohmann::json::object()), nullptr) << e.name;
  }
}

TEST(Registry, UnknownNameListsValidChoices) {
  try {
    registries().codecs.create("lz5", nlohmann::json::object());
    FAIL() << "no error for an unknown codec";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("unknown codec 'lz5'"), std::string::npos) << m;
    EXPECT_NE(m.find("raw"), std::string::npos) << m;
  }
}

TEST(Registry, UnknownParameterIsAnError) { EXPECT_THROW(registries().codecs.create("raw", {{"level", 3}}), Error); }

TEST(Registry, DuplicateRegistrationIsAnError) {
  Registry<Codec> r("codec");
  r.add({"x", "d", {}, [](const Params&) -> std::unique_ptr<Codec> { return nullptr; }});
  EXPECT_THROW(r.add({"x", "d", {}, nullptr}), Error);
}

std::vector<ParamSpec> demo_specs() {
  return {ParamSpec::integer("level", 1, 1, 19, "compression level"),
          ParamSpec::real("radius_m", 1.0, 0.0, 100.0, "radius"), ParamSpec::boolean("checksum", true, "checksum on"),
          ParamSpec::choice("mode", "fast", {"fast", "hc"}, "mode")};
}

TEST(Params, DefaultsFilledIn) {
  Params p("demo", demo_specs(), nlohmann::json::object());
  EXPECT_EQ(p.get_int("level"), 1);
  EXPECT_DOUBLE_EQ(p.get_float("radius_m"), 1.0);
  EXPECT_TRUE(p.get_bool("checksum"));
  EXPECT_EQ(p.get_string("mode"), "fast");
  EXPECT_EQ(p.effective().size(), 4u);
}

TEST(Params, GivenValuesOverride) {
  Params p("demo", demo_specs(), {{"level", 19}, {"radius_m", 0.5}, {"mode", "hc"}, {"checksum", false}});
  EXPECT_EQ(p.get_int("level"), 19);
  EXPECT_DOUBLE_EQ(p.get_float("radius_m"), 0.5);
  EXPECT_EQ(p.get_string("mode"), "hc");
  EXPECT_FALSE(p.get_bool("checksum"));
}

TEST(Params, IntegerAcceptedForFloat) {
  Params p("demo", demo_specs(), {{"radius_m", 2}});
  EXPECT_DOUBLE_EQ(p.get_float("radius_m"), 2.0);
}

TEST(Params, EveryProblemReportedAtOnce) {
  try {
    Params p("codec 'zstd'", demo_specs(),
             {{"level", 25}, {"lvl", 3}, {"mode", "ultra"}, {"checksum", 1}, {"radius_m", "big"}});
    FAIL() << "no error";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("'level' = 25 is out of range (valid: integer 1..19)"), std::string::npos) << m;
    EXPECT_NE(m.find("unknown parameter 'lvl' (valid: level, radius_m, checksum, mode)"), std::string::npos) << m;
    EXPECT_NE(m.find("one of: fast hc"), std::string::npos) << m;
    EXPECT_NE(m.find("'checksum' = 1 must be true or false"), std::string::npos) << m;
    EXPECT_NE(m.find("'radius_m' = \"big\" must be a number"), std::string::npos) << m;
    EXPECT_NE(m.find("codec 'zstd'"), std::string::npos) << m;
  }
}

TEST(Params, FloatForIntegerRejected) { EXPECT_THROW(Params("demo", demo_specs(), {{"level", 2.5}}), Error); }

TEST(Params, NonObjectRejected) { EXPECT_THROW(Params("demo", demo_specs(), nlohmann::json::array({1, 2})), Error); }

// ---------------------------------------------------------------- dhrbench list's examples

std::string joined(const std::vector<std::string>& problems) {
  std::string s;
  for (const auto& p : problems) s += "\n  " + p;
  return s;
}

// The SimConfig field a run key sets.
BackendChoice choice_at(const SimConfig& c, const std::string& key) {
  const RunSetting* s = find_run_setting(key);
  if (!s || s->type != SettingType::Backend) {
    ADD_FAILURE() << "no backend setting for run key '" << key << "'";
    return {};
  }
  const nlohmann::json v = s->get(c);
  return {v.at("name").get<std::string>(), v.at("params")};
}

void expect_created(const cli::BackendExample& ex, const nlohmann::json& params) {
  const Registries& r = registries();
  if (ex.kind == "codec")
    EXPECT_NE(r.codecs.create(ex.name, params), nullptr);
  else if (ex.kind == "denoiser")
    EXPECT_NE(r.denoisers.create(ex.name, params), nullptr);
  else if (ex.kind == "predictor")
    EXPECT_NE(r.predictors.create(ex.name, params), nullptr);
  else
    ADD_FAILURE() << "unknown kind " << ex.kind;
}

TEST(ListExamples, OneExamplePerRegisteredBackend) {
  const Registries& r = registries();
  const auto examples = cli::all_backend_examples(r);
  EXPECT_EQ(examples.size(), r.codecs.entries().size() + r.denoisers.entries().size() + r.predictors.entries().size());
  for (const auto& ex : examples) {
    EXPECT_EQ(ex.value.at("name"), ex.name);
    EXPECT_EQ(ex.value.size(), ex.value.contains("params") ? 2u : 1u) << ex.file_text();
  }
}

// Each example as an experiment file writes it, at every run key of its kind, and as --set
// writes it: the loader reports no problem, the run holds the backend and its parameters, and
// the registry creates the backend from them.
TEST(ListExamples, EveryExampleIsAcceptedByTheLoaderAndBySet) {
  for (const cli::BackendExample& ex : cli::all_backend_examples(registries())) {
    SCOPED_TRACE(ex.file_text());
    const nlohmann::json params = ex.value.value("params", nlohmann::json::object());
    std::vector<std::string> keys = cli::run_keys(ex.kind);
    ASSERT_NE(std::find(keys.begin(), keys.end(), ex.run_key), keys.end()) << ex.run_key;
    for (const std::string& key : keys) {
      std::vector<std::string> problems;
      // The example's text as an experiment file holds it (appended: GCC 12 warns, wrongly,
      // about "{" + a temporary string).
      std::string text = "{";
      text += cli::BackendExample{ex.kind, ex.name, key, ex.value}.file_text();
      text += "}";
      const nlohmann::json run = nlohmann::json::parse(text);
      const SimConfig c = sim_config_from_json(run, "run", problems);
      EXPECT_TRUE(problems.empty()) << key << ":" << joined(problems);
      EXPECT_EQ(choice_at(c, key).name, ex.name) << key;
      EXPECT_EQ(choice_at(c, key).params, params) << key;
    }
    nlohmann::json experiment{{"run", nlohmann::json::object()}};
    apply_override(experiment, ex.set_assignment());
    std::vector<std::string> problems;
    const SimConfig c = sim_config_from_json(experiment.at("run"), "run", problems);
    EXPECT_TRUE(problems.empty()) << "--set " << ex.set_assignment() << ":" << joined(problems);
    EXPECT_EQ(choice_at(c, ex.run_key).name, ex.name);
    EXPECT_EQ(choice_at(c, ex.run_key).params, params);
    expect_created(ex, choice_at(c, ex.run_key).params);
  }
}

// A flat codec entry ({"ao_codec": {"codec": "zstd", "level": 3}}) is not an experiment's
// syntax: the loader names both unknown keys.
TEST(ListExamples, TheOldFlatSyntaxIsRejected) {
  std::vector<std::string> problems;
  sim_config_from_json({{"ao_codec", {{"codec", "zstd"}, {"level", 3}}}}, "run", problems);
  const std::string all = joined(problems);
  EXPECT_NE(all.find("run.ao_codec.codec: unknown key"), std::string::npos) << all;
  EXPECT_NE(all.find("run.ao_codec.level: unknown key"), std::string::npos) << all;
}

}  // namespace
}  // namespace dhr
