// The registry: every expected backend is registered, names and parameters are validated,
// and every backend of every kind can be created with its defaults.
#include "core/backend.h"

#include <gtest/gtest.h>

#include <set>

namespace dhr {
namespace {

template <class I>
std::set<std::string> names(const Registry<I>& r) {
  std::set<std::string> s;
  for (const auto& e : r.entries()) s.insert(e.name);
  return s;
}

bool contains_all(const std::set<std::string>& have, std::initializer_list<const char*> want,
                  std::string& missing) {
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

TEST(Registry, UnknownParameterIsAnError) {
  EXPECT_THROW(registries().codecs.create("raw", {{"level", 3}}), Error);
}

TEST(Registry, DuplicateRegistrationIsAnError) {
  Registry<Codec> r("codec");
  r.add({"x", "d", {}, [](const Params&) -> std::unique_ptr<Codec> { return nullptr; }});
  EXPECT_THROW(r.add({"x", "d", {}, nullptr}), Error);
}

std::vector<ParamSpec> demo_specs() {
  return {ParamSpec::integer("level", 1, 1, 19, "compression level"),
          ParamSpec::real("radius_m", 1.0, 0.0, 100.0, "radius"),
          ParamSpec::boolean("checksum", true, "checksum on"),
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

TEST(Params, FloatForIntegerRejected) {
  EXPECT_THROW(Params("demo", demo_specs(), {{"level", 2.5}}), Error);
}

TEST(Params, NonObjectRejected) {
  EXPECT_THROW(Params("demo", demo_specs(), nlohmann::json::array({1, 2})), Error);
}

}  // namespace
}  // namespace dhr
