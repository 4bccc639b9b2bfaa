// Reading JSON from outside (core/base/json_io.h) and the readers built on it: the depth scan
// (brackets inside strings and escaped quotes do not count), parse errors that name their
// source, bounded excerpts in messages, --set values, experiment files and link configs.
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/experiment/experiment.h"
#include "core/net/network.h"
#include "tests/support.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <string>

namespace dhr {
namespace {

namespace fs = std::filesystem;

using test::error_of;

bool starts_with(const std::string& s, const std::string& prefix) { return s.rfind(prefix, 0) == 0; }

TEST(JsonDepth, CountsArraysAndObjectsOutsideStrings) {
  EXPECT_EQ(json_depth(""), 0);
  EXPECT_EQ(json_depth("1"), 0);
  EXPECT_EQ(json_depth("[]"), 1);
  EXPECT_EQ(json_depth("[[], [[]], {}]"), 3);
  EXPECT_EQ(json_depth(R"({"a": {"b": [1, {"c": []}]}})"), 5);
  // Brackets inside strings do not count, however many.
  EXPECT_EQ(json_depth(R"(["[[[[{{{{", "]]]]"])"), 1);
  EXPECT_EQ(json_depth(R"({"[[[": "{{{"})"), 1);
  // An escaped quote does not end the string; an escaped backslash before a quote does.
  EXPECT_EQ(json_depth(R"(["a\"[[[[", 1])"), 1);
  EXPECT_EQ(json_depth(R"(["a\\", [[1]]])"), 3);
  EXPECT_EQ(json_depth(R"(["\\\"[[", "\\\\"])"), 1);
  // Unbalanced text: closing brackets never make the depth negative; unclosed ones count.
  EXPECT_EQ(json_depth("]]]]["), 1);
  EXPECT_EQ(json_depth("[[[["), 4);
  // An unterminated string hides everything after it.
  EXPECT_EQ(json_depth(R"(["abc[[[[)"), 1);
  // Comments are skipped: brackets inside do not count, and a quote inside starts no string
  // (a quote in a comment once hid 100,000 levels of nesting from the scan: SIGSEGV).
  EXPECT_EQ(json_depth("// [[[[\n[1]"), 1);
  EXPECT_EQ(json_depth("/* [[[[ */ [1]"), 1);
  EXPECT_EQ(json_depth("// \"\n[[[1]]]"), 3);
  EXPECT_EQ(json_depth("// \"\r[[[1]]]"), 3);
  EXPECT_EQ(json_depth("/* \" */ [[[1]]]"), 3);
  EXPECT_EQ(json_depth("/*/ \" */ [[1]]"), 2);
  EXPECT_EQ(json_depth(R"(["//", [[1]], "/*"])"), 3);  // inside strings, no comment
  EXPECT_EQ(json_depth("[1] /* [[[[ never closed"), 1);
  EXPECT_EQ(json_depth("[1] // [[[["), 1);
}

TEST(JsonDepth, StopsCountingPastTheLimit) {
  const std::string deep(100000, '[');
  EXPECT_EQ(json_depth(deep, 64), 65);
  EXPECT_EQ(json_depth(deep, 3), 4);
  EXPECT_EQ(json_depth(std::string(64, '[') + std::string(64, ']')), 64);
}

TEST(ParseJson, RejectsDeepNestingNamingTheSourceAndTheLimit) {
  for (const std::string& text : {std::string(100000, '[') + std::string(100000, ']'), std::string(100000, '{'),
                                  std::string(65, '[') + std::string(65, ']')}) {
    const std::string e = error_of([&] { parse_json(text, "some/file.json"); });
    EXPECT_TRUE(starts_with(e, "some/file.json: JSON nested deeper than 64 levels")) << e.substr(0, 200);
  }
  EXPECT_NO_THROW(parse_json(std::string(64, '[') + std::string(64, ']'), "x"));
  // A smaller limit when asked.
  EXPECT_NE(error_of([] { parse_json("[[[1]]]", "x", false, 2); }).find("deeper than 2 levels"), std::string::npos);
}

TEST(ParseJson, ErrorsNameTheSource) {
  for (const char* text : {"1e400", "[-1e400]", R"({"a": 1e999})", "{", "", "nul", "[1,]", "\"\xff\""}) {
    const std::string e = error_of([&] { parse_json(text, "src.json"); });
    EXPECT_TRUE(starts_with(e, "src.json: not valid JSON: ")) << text << ": " << e;
    EXPECT_LT(e.size(), 400u) << e;
  }
  // nlohmann quotes the token it was reading: a long one is cut.
  const std::string e = error_of([] { parse_json("\"" + std::string(100000, 'x'), "src.json"); });
  EXPECT_LT(e.size(), 400u);
  // Comments only when allowed.
  EXPECT_FALSE(error_of([] { parse_json("// c\n{}", "x"); }).empty());
  EXPECT_TRUE(parse_json("// c\n{\"a\": /* [[[ */ 1}", "x", true).is_object());
}

TEST(ParseJson, ReadJsonFileNamesAMissingFile) {
  const std::string missing = (fs::temp_directory_path() / "dhr_no_such_file.json").string();
  EXPECT_EQ(error_of([&] { read_json_file(missing); }), missing + ": cannot open the file");
}

TEST(JsonExcerpt, IsBounded) {
  EXPECT_EQ(json_excerpt(nlohmann::json(1)), "1");
  EXPECT_EQ(json_excerpt(nlohmann::json("abc")), "\"abc\"");
  const std::string e = json_excerpt(nlohmann::json(std::string(100000, 'x')));
  EXPECT_EQ(e, "\"" + std::string(59, 'x') + "...");
  EXPECT_EQ(json_excerpt(nlohmann::json::array({1, 2, 3}), 3), "[1,...");
}

// --set values: JSON when they parse, a plain string otherwise, and never deeper than the limit.
TEST(ApplyOverride, BoundsTheDepthOfValues) {
  nlohmann::json j = nlohmann::json::object();
  apply_override(j, "run.frames=10");
  apply_override(j, "run.ao_codec.name=zstd");
  apply_override(j, "notes=[[not json");
  EXPECT_EQ(j["run"]["frames"], 10);
  EXPECT_EQ(j["run"]["ao_codec"]["name"], "zstd");
  EXPECT_EQ(j["notes"], "[[not json");
  for (const std::string& value :
       {std::string(100000, '[') + std::string(100000, ']'), std::string(100000, '['), std::string(65, '{')}) {
    const std::string e = error_of([&] { apply_override(j, "scenes=" + value); });
    EXPECT_TRUE(starts_with(e, "--set 'scenes': the value is nested deeper than 64 levels")) << e.substr(0, 200);
    EXPECT_LT(e.size(), 300u);
  }
  // A number out of range is not JSON: it stays text, and the reader of the key names it.
  apply_override(j, "run.frames=1e400");
  EXPECT_EQ(j["run"]["frames"], "1e400");
}

class ExperimentFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / fmt::format("dhr_json_io_{}", ::getpid());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name) << text;
    return (dir_ / name).string();
  }
  fs::path dir_;
};

TEST_F(ExperimentFiles, DeepNestingIsAClearError) {
  const int n = 100000;
  std::string deep_object;
  for (int k = 0; k < n; ++k) deep_object += "{\"a\":";
  deep_object += "1" + std::string(n, '}');
  for (const std::string& text :
       {std::string(n, '[') + std::string(n, ']'), std::string(n, '['), deep_object,
        R"({"version": 1, "scenes": ["room"], "run": )" + std::string(n, '[') + std::string(n, ']') + "}"}) {
    const std::string file = write("deep.json", text);
    const std::string e = error_of([&] { load_experiment(file); });
    EXPECT_TRUE(starts_with(e, file + ": JSON nested deeper than 64 levels")) << e.substr(0, 300);
  }
  // A quote in a comment does not hide the nesting after it.
  for (const std::string& comment : {std::string("// \"\n"), std::string("/* \" */ ")}) {
    const std::string file = write("comment.json", comment + std::string(n, '[') + std::string(n, ']'));
    const std::string e = error_of([&] { load_experiment(file); });
    EXPECT_TRUE(starts_with(e, file + ": JSON nested deeper than 64 levels")) << e.substr(0, 300);
  }
  // Through --set, on a valid file.
  const std::string ok = write("ok.json", R"({"version": 1, "scenes": ["room"]})");
  EXPECT_NO_THROW(load_experiment(ok));
  const std::string e =
      error_of([&] { load_experiment(ok, {"run.uplink=" + std::string(n, '[') + std::string(n, ']')}); });
  EXPECT_TRUE(starts_with(e, "--set 'run.uplink': the value is nested deeper than 64")) << e.substr(0, 300);
}

TEST_F(ExperimentFiles, HugeNumbersNameTheFile) {
  for (const char* text : {R"({"version": 1, "scenes": ["room"], "run": {"frames": 1e400}})", R"({"version": 1e400})",
                           R"(// a comment
                              {"version": 1, "scenes": ["room"], "run": {"uplink": {"latency_ms": -1e400}}})"}) {
    const std::string file = write("huge.json", text);
    const std::string e = error_of([&] { load_experiment(file); });
    EXPECT_TRUE(starts_with(e, file + ": not valid JSON: ")) << e;
    EXPECT_NE(e.find("1e400"), std::string::npos) << e;
  }
  // Through --set: a plain string, which the typed reader refuses by key.
  const std::string ok = write("ok.json", R"({"version": 1, "scenes": ["room"]})");
  const std::string e = error_of([&] { load_experiment(ok, {"run.frames=1e400"}); });
  EXPECT_NE(e.find("run.frames = \"1e400\": must be an integer"), std::string::npos) << e;
}

TEST_F(ExperimentFiles, MessagesPrintOnlyAnExcerptOfAValue) {
  const std::string big = "\"" + std::string(1 << 20, 'x') + "\"";
  const std::string file = write("long.json", R"({"version": )" + big + R"(, "scenes": [)" + big +
                                                  R"(], "run": {"frames": )" + big + R"(, "trace": {"soft_shadows": )" +
                                                  big + R"(}, "mode": )" + big + R"(, "uplink": {"latency": )" + big +
                                                  R"(, "loss_rate": )" + big + R"(}, "downlink": )" + big + R"(}})");
  const std::string e = error_of([&] { load_experiment(file); });
  EXPECT_NE(e.find("version \"xxx"), std::string::npos) << e.substr(0, 400);
  EXPECT_LT(e.size(), 2000u) << e.substr(0, 2000);
  const std::string e2 = error_of([&] { load_experiment(file, {"scenes=[\"room\"]", "version=1"}); });
  EXPECT_LT(e2.size(), 2000u) << e2.substr(0, 2000);
  for (const char* key :
       {"run.frames = \"xxx", "run.trace.soft_shadows = \"xxx", "run.mode = \"xxx", "run.uplink.latency = \"xxx",
        "run.uplink.loss_rate = \"xxx", "run.downlink: a link must be a JSON object, got \"xxx"})
    EXPECT_NE(e2.find(key), std::string::npos) << key << "\n" << e2;
}

TEST(LinkConfigJson, MessagesPrintOnlyAnExcerptOfAValue) {
  const nlohmann::json big = std::string(1 << 20, 'x');
  EXPECT_LT(error_of([&] { LinkConfig::from_json(big, "--uplink"); }).size(), 200u);
  const std::string e = error_of([&] {
    LinkConfig::from_json({{"latency", big}, {"loss", big}, {"latency_ms", big}}, "--uplink");
  });
  EXPECT_NE(e.find("--uplink.latency = \"xxx"), std::string::npos) << e;
  EXPECT_LT(e.size(), 600u) << e;
}

}  // namespace
}  // namespace dhr
