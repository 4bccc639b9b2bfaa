// The scene layer: the JSON format (strictness, error collection), procedural shapes,
// animation and camera-path interpolation, texture lookup, the built-in scenes, model import
// (good models load, every broken model in assimp's test set is rejected) and the real scenes.
#include "core/base/error.h"
#include "core/buffers/image_io.h"
#include "core/scene/mesh_import.h"
#include "core/scene/scene.h"
#include "core/scene/scene_load.h"
#include "core/scene/shapes.h"
#include "tests/support.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <glm/gtc/quaternion.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <numbers>
#include <string>

namespace dhr {
namespace {

namespace fs = std::filesystem;

const std::string kAssimpModels = "/usr/share/assimp/models";

// A scratch folder per test, removed afterwards.
class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = fs::temp_directory_path() /
            fmt::format("dhr_scene_{}_{}_{}", info->test_suite_name(), info->name(), ::getpid());
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  std::string write(const std::string& name, const std::string& text) const {
    const fs::path p = path_ / name;
    fs::create_directories(p.parent_path());
    std::ofstream(p) << text;
    return p.string();
  }
  std::string path() const { return path_.string(); }

 private:
  fs::path path_;
};

using test::error_of;

const char* kMinimalScene = R"({
  "version": 1,
  "geometry": [{"type": "box", "size_m": [1, 1, 1]}],
  "camera": {"path": {"keys": [{"t_s": 0, "position": [0, 0, 5], "target": [0, 0, 0]}]}}
})";

SceneSearchPath empty_search() { return SceneSearchPath{}; }

// --- shapes -------------------------------------------------------------------------------------

// Signed volume of a closed mesh (divergence theorem); positive when normals point outward.
double signed_volume(const Mesh& m) {
  double v = 0.0;
  for (const auto& t : m.triangles)
    v +=
        glm::dot(glm::dvec3(m.positions[t.x]), glm::cross(glm::dvec3(m.positions[t.y]), glm::dvec3(m.positions[t.z]))) /
        6.0;
  return v;
}

void expect_outward(const Mesh& m, glm::vec3 centre = glm::vec3(0.0f)) {
  ASSERT_EQ(m.normals.size(), m.positions.size());
  ASSERT_EQ(m.uvs.size(), m.positions.size());
  for (const auto& t : m.triangles) {
    const glm::vec3 g = glm::cross(m.positions[t.y] - m.positions[t.x], m.positions[t.z] - m.positions[t.x]);
    const glm::vec3 c = (m.positions[t.x] + m.positions[t.y] + m.positions[t.z]) / 3.0f;
    EXPECT_GT(glm::dot(g, c - centre), 0.0f);  // convex, centred: outward means away from the centre
    for (uint32_t i : {t.x, t.y, t.z}) {
      EXPECT_NEAR(glm::length(m.normals[i]), 1.0f, 1e-5f);
      EXPECT_GE(glm::dot(m.normals[i], glm::normalize(g)), 0.0f);
    }
  }
}

TEST(Shapes, BoxIsClosedWithOutwardNormalsAndTheRightVolume) {
  const Mesh m = make_box({2.0f, 3.0f, 4.0f});
  EXPECT_EQ(m.triangles.size(), 12u);
  EXPECT_NEAR(signed_volume(m), 24.0, 1e-4);
  expect_outward(m);
  for (const auto& p : m.positions) {
    EXPECT_FLOAT_EQ(std::abs(p.x), 1.0f);
    EXPECT_FLOAT_EQ(std::abs(p.y), 1.5f);
    EXPECT_FLOAT_EQ(std::abs(p.z), 2.0f);
  }
}

TEST(Shapes, SphereCylinderPlane) {
  const Mesh s = make_sphere(2.0f, 48, 24);
  expect_outward(s);
  const double sphere_v = 4.0 / 3.0 * std::numbers::pi * 8.0;
  EXPECT_NEAR(signed_volume(s), sphere_v, 0.02 * sphere_v);
  for (const auto& p : s.positions) EXPECT_NEAR(glm::length(p), 2.0f, 1e-5f);

  const Mesh c = make_cylinder(1.0f, 2.0f, 64, true);
  expect_outward(c);
  EXPECT_NEAR(signed_volume(c), std::numbers::pi * 2.0, 0.01 * std::numbers::pi * 2.0);
  EXPECT_EQ(make_cylinder(1.0f, 2.0f, 16, false).triangles.size(), 32u);

  const Mesh p = make_plane(4.0f, 2.0f);
  ASSERT_EQ(p.triangles.size(), 2u);
  for (const auto& t : p.triangles) {
    const glm::vec3 g = glm::cross(p.positions[t.y] - p.positions[t.x], p.positions[t.z] - p.positions[t.x]);
    EXPECT_GT(g.y, 0.0f);
  }
  for (const auto& n : p.normals) EXPECT_EQ(n, glm::vec3(0, 1, 0));

  EXPECT_THROW(make_box({1.0f, 0.0f, 1.0f}), Error);
  EXPECT_THROW(make_sphere(1.0f, 2, 8), Error);
  EXPECT_THROW(make_cylinder(NAN, 1.0f), Error);
}

// --- animation and camera path -----------------------------------------------------------------

TEST(Animation, HitsKeysInterpolatesAndWraps) {
  Animation a;
  a.keys.push_back({0.0, {0, 0, 0}, glm::angleAxis(0.0f, glm::vec3(0, 1, 0)), {1, 1, 1}});
  a.keys.push_back({2.0, {4, 0, 0}, glm::angleAxis(glm::radians(90.0f), glm::vec3(0, 1, 0)), {3, 3, 3}});
  const glm::vec4 o(0, 0, 0, 1), x(1, 0, 0, 1);
  EXPECT_NEAR(glm::length(glm::vec3(a.at(0.0) * o) - glm::vec3(0, 0, 0)), 0.0f, 1e-5f);
  EXPECT_NEAR(glm::length(glm::vec3(a.at(2.0) * o) - glm::vec3(4, 0, 0)), 0.0f, 1e-5f);
  EXPECT_NEAR(glm::length(glm::vec3(a.at(1.0) * o) - glm::vec3(2, 0, 0)), 0.0f, 1e-5f);  // linear translation
  // slerp: half way is a 45 degree turn, scale 2.
  const glm::vec3 half = glm::vec3(a.at(1.0) * x) - glm::vec3(2, 0, 0);
  EXPECT_NEAR(glm::length(half), 2.0f, 1e-4f);
  EXPECT_NEAR(std::atan2(-half.z, half.x), glm::radians(45.0f), 1e-4f);
  // Clamped outside the keys when not looping; wrapped when looping.
  EXPECT_EQ(a.at(5.0), a.at(2.0));
  EXPECT_EQ(a.at(-1.0), a.at(0.0));
  a.loop = true;
  EXPECT_NEAR(glm::length(glm::vec3(a.at(3.0) * o) - glm::vec3(a.at(1.0) * o)), 0.0f, 1e-5f);
  EXPECT_NEAR(glm::length(glm::vec3(a.at(-0.5) * o) - glm::vec3(a.at(1.5) * o)), 0.0f, 1e-5f);
}

CameraPath test_path(bool loop) {
  CameraPath p;
  p.loop = loop;
  p.keys = {{0.0, {0, 1, 5}, {0, 1, 0}},
            {2.0, {5, 1, 0}, {0, 1, 0}},
            {5.0, {0, 2, -5}, {0, 0, 0}},
            {6.0, {-5, 1, 0}, {0, 1, 0}},
            {8.0, {0, 1, 5}, {0, 1, 0}}};
  return p;
}

TEST(CameraPath, HitsKeysIsContinuousAndClampsOrWraps) {
  const CameraPath p = test_path(false);
  EXPECT_DOUBLE_EQ(p.duration_s(), 8.0);
  for (const auto& k : p.keys) {
    const Camera c = p.at(k.time_s, 64, 36);
    EXPECT_NEAR(glm::length(c.position - k.position), 0.0f, 1e-4f) << k.time_s;
    EXPECT_NEAR(glm::dot(c.forward, glm::normalize(k.target - k.position)), 1.0f, 1e-5f) << k.time_s;
  }
  // Continuity: small time steps give small moves, also across keys.
  glm::vec3 prev = p.at(0.0, 64, 36).position;
  for (double t = 0.01; t <= 8.0; t += 0.01) {
    const glm::vec3 pos = p.at(t, 64, 36).position;
    EXPECT_LT(glm::length(pos - prev), 0.1f) << t;
    prev = pos;
  }
  // Not the straight line between keys: Catmull-Rom bends.
  const glm::vec3 mid = p.at(1.0, 64, 36).position;
  EXPECT_GT(glm::length(mid - glm::vec3(2.5f, 1.0f, 2.5f)), 0.05f);
  EXPECT_EQ(p.at(-3.0, 64, 36).position, p.at(0.0, 64, 36).position);
  EXPECT_EQ(p.at(20.0, 64, 36).position, p.at(8.0, 64, 36).position);
  const CameraPath l = test_path(true);
  EXPECT_NEAR(glm::length(l.at(9.0, 64, 36).position - l.at(1.0, 64, 36).position), 0.0f, 1e-4f);
  // The looped path (last key = first) is smooth across the seam.
  EXPECT_LT(glm::length(l.at(7.99, 64, 36).position - l.at(0.01, 64, 36).position), 0.1f);
  EXPECT_EQ(l.at(0.0, 640, 360).width, 640);
}

TEST(Texture, BilinearWrapsFlipsVAndLinearises) {
  Texture t;
  t.width = 2;
  t.height = 2;
  // Row 0 (top): red, green; row 1 (bottom): blue, white with alpha 0.
  t.texels = {{255, 0, 0, 255}, {0, 255, 0, 255}, {0, 0, 255, 255}, {255, 255, 255, 0}};
  // uv (0.25, 0.25) is the centre of the bottom-left texel: blue.
  EXPECT_NEAR(glm::length(t.sample_bilinear({0.25f, 0.25f}) - glm::vec4(0, 0, 1, 1)), 0.0f, 1e-5f);
  EXPECT_NEAR(glm::length(t.sample_bilinear({0.25f, 0.75f}) - glm::vec4(1, 0, 0, 1)), 0.0f, 1e-5f);
  EXPECT_NEAR(t.sample_bilinear({0.75f, 0.25f}).w, 0.0f, 1e-6f);
  // Wrapping: uv + 1 is the same; u = 0 is half-way between the left and the wrapped right texel.
  EXPECT_NEAR(glm::length(t.sample_bilinear({1.25f, -0.75f}) - t.sample_bilinear({0.25f, 0.25f})), 0.0f, 1e-5f);
  const glm::vec4 edge = t.sample_bilinear({0.0f, 0.75f});
  EXPECT_NEAR(edge.x, 0.5f, 1e-5f);
  EXPECT_NEAR(edge.y, 0.5f, 1e-5f);
  // sRGB 128 -> linear 0.2158.
  Texture g;
  g.width = g.height = 1;
  g.texels = {{128, 128, 128, 128}};
  const glm::vec4 v = g.sample_bilinear({0.3f, 0.6f});
  EXPECT_NEAR(v.x, 0.2158f, 1e-3f);
  EXPECT_NEAR(v.w, 128.0f / 255.0f, 1e-6f);
}

// --- the JSON format ----------------------------------------------------------------------------

TEST(SceneFormat, MinimalSceneLoads) {
  TempDir dir;
  const Scene s = load_scene(dir.write("min.json", kMinimalScene), empty_search());
  ASSERT_EQ(s.objects.size(), 1u);
  EXPECT_EQ(s.objects[0].id, 1u);
  EXPECT_EQ(s.triangle_count(), 12u);
  EXPECT_FALSE(s.ao.has_value());
  EXPECT_EQ(s.name, "min");
}

TEST(SceneFormat, UnknownKeysAreRejectedAtAnyDepthWithTheirPath) {
  TempDir dir;
  const std::string file = dir.write("bad.json", R"({
    "version": 1, "colour_grading": 1,
    "materials": {"red": {"albedo": [1, 0, 0], "shininess": 3}},
    "geometry": [{"type": "box", "size_m": [1, 1, 1], "material": "red",
                  "transform": {"translate": [0, 0, 0], "skew": 1}},
                 {"type": "sphere", "radius_m": 1, "size_m": [1, 1, 1]}],
    "lights": [{"type": "sphere", "position": [0, 2, 0], "radius_m": 0.1, "direction": [0, 1, 0]}],
    "camera": {"path": {"keys": [{"t_s": 0, "position": [0, 0, 5], "target": [0, 0, 0], "roll": 3}]}}
  })");
  const std::string e = error_of([&] { load_scene(file, empty_search()); });
  EXPECT_NE(e.find(file + ": colour_grading: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find(file + ": materials.red.shininess: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find(file + ": geometry[0].transform.skew: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find(file + ": geometry[1].size_m: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find(file + ": lights[0].direction: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find(file + ": camera.path.keys[0].roll: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find("6 problems"), std::string::npos) << e;
}

TEST(SceneFormat, VersionIsRequiredAndChecked) {
  TempDir dir;
  std::string text = kMinimalScene;
  const std::string no_version = dir.write("nov.json", std::string("{") + text.substr(text.find("\"geometry\"")));
  EXPECT_NE(error_of([&] { load_scene(no_version, empty_search()); }).find("version: is required"), std::string::npos);
  std::string v2 = text;
  v2.replace(v2.find("\"version\": 1"), 12, "\"version\": 2");
  const std::string e = error_of([&] { load_scene(dir.write("v2.json", v2), empty_search()); });
  EXPECT_NE(e.find("version: 2 is not a supported version"), std::string::npos) << e;
  EXPECT_NE(error_of([&] {
              load_scene(dir.write("syntax.json", "{\"version\": 1,"), empty_search());
            }).find("not valid JSON"),
            std::string::npos);
}

// Hostile JSON: 100,000 levels of nesting (printing such a value in an error message can
// overflow the stack) and a number out of range (1e400, which the JSON library reports in an
// exception that names no file) must each give one dhr::Error naming the file, not a crash.
TEST(SceneFormat, HostileJsonIsAClearErrorNamingTheFile) {
  TempDir dir;
  const int n = 100000;
  const std::string deep_cases[] = {
      std::string(n, '[') + std::string(n, ']'),                                            // the whole file
      "{\"version\": 1, \"geometry\": " + std::string(n, '[') + std::string(n, ']') + "}",  // inside a key
      std::string(n, '['),                                                                  // never closed
  };
  int i = 0;
  for (const auto& text : deep_cases) {
    const std::string file = dir.write(fmt::format("deep{}.json", i++), text);
    const std::string e = error_of([&] { load_scene(file, empty_search()); });
    EXPECT_EQ(e.rfind(file + ": JSON nested deeper than 64 levels", 0), 0u) << e.substr(0, 300);
  }
  std::string deep_object;
  for (int k = 0; k < n; ++k) deep_object += "{\"a\":";
  deep_object += "1" + std::string(n, '}');
  const std::string file = dir.write("deep_object.json", deep_object);
  EXPECT_NE(error_of([&] { load_scene(file, empty_search()); }).find(file + ": JSON nested deeper than 64"),
            std::string::npos);

  // A number too large for a double, where a number belongs and in the version.
  std::string huge = kMinimalScene;
  huge.replace(huge.find("[1, 1, 1]"), 9, "[1e400, 1, 1]");
  for (const std::string& text : {huge, std::string(R"({"version": 1e400})"), std::string("-1e400")}) {
    const std::string f = dir.write("huge.json", text);
    const std::string e = error_of([&] { load_scene(f, empty_search()); });
    EXPECT_EQ(e.rfind(f + ": not valid JSON: ", 0), 0u) << e;
    EXPECT_NE(e.find("1e400"), std::string::npos) << e;
  }
  // Just under the limit is still parsed (and then refused by the format, not the parser).
  const std::string at_limit = dir.write("limit.json", std::string(64, '[') + std::string(64, ']'));
  const std::string e = error_of([&] { load_scene(at_limit, empty_search()); });
  EXPECT_EQ(e.find("nested deeper"), std::string::npos) << e;
  EXPECT_NE(e.find("must be an object"), std::string::npos) << e;
}

TEST(SceneFormat, ErrorMessagesPrintOnlyAnExcerptOfAValue) {
  TempDir dir;
  std::string text = kMinimalScene;
  const std::string long_value = "\"" + std::string(1 << 20, 'x') + "\"";
  text.replace(text.find("[1, 1, 1]"), 9, long_value);
  const std::string file = dir.write("long.json", text);
  const std::string e = error_of([&] { load_scene(file, empty_search()); });
  EXPECT_NE(e.find(file + ": geometry[0].size_m: must be an array of 3 numbers, got \"xxx"), std::string::npos)
      << e.substr(0, 300);
  EXPECT_LT(e.size(), 400u);
  // A long key and a long string where a name belongs.
  const std::string name(1 << 20, 'k');
  const std::string file2 =
      dir.write("long_key.json", R"({"version": 1, ")" + name + R"(": 1, "geometry": [{"type": ")" + name +
                                     R"("}], "camera": {"path": {"keys": []}}})");
  const std::string e2 = error_of([&] { load_scene(file2, empty_search()); });
  EXPECT_NE(e2.find(file2 + ": kkkk"), std::string::npos) << e2.substr(0, 300);
  EXPECT_NE(e2.find(file2 + ": geometry[0].type: 'kkkk"), std::string::npos) << e2.substr(0, 300);
  EXPECT_LT(e2.size(), 3000u) << e2.substr(0, 3000);
}

TEST(SceneFormat, AllValueErrorsAreReportedTogether) {
  TempDir dir;
  const std::string file = dir.write("room.json", R"({
    "version": 1,
    "geometry": [{"type": "box", "size_m": [1, -1, 1]}, {"type": "torus"}, {"type": "box", "size_m": [1, 1, 1], "material": "nope"}],
    "lights": [{"type": "sphere", "position": [0, 2, 0]}, {"type": "sphere", "position": [0, 2, 0]},
               {"type": "sphere", "position": [0, 2, 0], "radius_m": -1}],
    "ao": {"radius_m": 1, "rays": 300},
    "camera": {"vfov_deg": 200, "path": {"keys": [{"t_s": 1, "position": [0, 0, 5], "target": [0, 0, 0]},
                                                 {"t_s": 0, "position": [0, 0, 4], "target": [0, 0, 0]}]}}
  })");
  const std::string e = error_of([&] { load_scene(file, empty_search()); });
  for (const char* expected : {": geometry[0].size_m[1]: must be >= ", ": geometry[1].type: 'torus' is not one of",
                               ": geometry[2].material: unknown material 'nope'", ": lights[2].radius_m: must be >= 0",
                               ": ao.rays: must be in [1, 255]", ": camera.vfov_deg: must be <= 179",
                               ": camera.path.keys[1].t_s: must be greater than"}) {
    EXPECT_NE(e.find(file + expected), std::string::npos) << expected << "\n" << e;
  }
  EXPECT_NE(e.find("7 problems"), std::string::npos) << e;
}

TEST(SceneFormat, TransformsRepeatsAnimationAndIds) {
  TempDir dir;
  const std::string file = dir.write("t.json", R"({
    "version": 1, "notes": "a test",
    "materials": {"m": {"albedo": [0.5, 0.5, 0.5]}},
    "geometry": [
      {"type": "box", "size_m": [2, 2, 2], "material": "m",
       "transform": {"translate": [10, 0, 0], "rotate_deg": [0, 90, 0], "scale": 0.5},
       "repeat": {"count": 3, "offset": [0, 0, 5]}},
      {"type": "sphere", "radius_m": 1, "segments": 8, "rings": 4,
       "animation": {"loop": true, "keys": [{"t_s": 0, "translate": [0, 0, 0]}, {"t_s": 2, "translate": [4, 0, 0]}]}}],
    "lights": [{"type": "distant", "direction": [0, 2, 0], "angular_radius_deg": 0.27}],
    "ambient": {"colour": [1, 0.5, 0.5], "intensity": 0.2},
    "ao": {"radius_m": 0.5, "rays": 4},
    "camera": {"path": {"keys": [{"t_s": 0, "position": [0, 0, 5], "target": [0, 0, 0]},
                                 {"t_s": 10, "position": [5, 0, 5], "target": [0, 0, 0]}]}}
  })");
  const Scene s = load_scene(file, empty_search());
  ASSERT_EQ(s.objects.size(), 4u);
  for (size_t i = 0; i < s.objects.size(); ++i) EXPECT_EQ(s.objects[i].id, i + 1);
  // Static: baked in world space, unit box scaled 0.5 around (10, 0, 5 * copy).
  for (int c = 0; c < 3; ++c) {
    glm::vec3 lo(1e9f), hi(-1e9f);
    for (const auto& p : s.objects[size_t(c)].mesh.positions) {
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
    EXPECT_NEAR(glm::length(lo - glm::vec3(9.5f, -0.5f, 5.0f * c - 0.5f)), 0.0f, 1e-4f);
    EXPECT_NEAR(glm::length(hi - glm::vec3(10.5f, 0.5f, 5.0f * c + 0.5f)), 0.0f, 1e-4f);
    EXPECT_FALSE(s.objects[size_t(c)].moving());
    EXPECT_NEAR(signed_volume(s.objects[size_t(c)].mesh), 1.0, 1e-4);  // still outward after the transform
  }
  EXPECT_EQ(s.materials[s.objects[0].material].name, "m");
  const Object& ball = s.objects[3];
  ASSERT_TRUE(ball.moving());
  EXPECT_TRUE(s.has_moving_objects());
  EXPECT_NEAR(glm::length(ball.mesh.positions[0]), 1.0f, 1e-5f);  // object space
  EXPECT_NEAR(ball.world_from_object(1.0)[3].x, 2.0f, 1e-5f);
  EXPECT_NEAR(ball.world_from_object(3.0)[3].x, 2.0f, 1e-5f);  // looped
  ASSERT_EQ(s.lights.size(), 1u);
  EXPECT_EQ(s.lights[0].direction, glm::vec3(0, 1, 0));
  EXPECT_NEAR(s.ambient.y, 0.1f, 1e-6f);
  ASSERT_TRUE(s.ao.has_value());
  EXPECT_EQ(s.ao->rays, 4);
  EXPECT_DOUBLE_EQ(s.camera.duration_s(), 10.0);
}

TEST(SceneFormat, MissingAssetListsEveryPlaceLooked) {
  TempDir dir;
  SceneSearchPath search;
  search.dirs = {dir.path() + "/first", dir.path() + "/second"};
  const std::string file = dir.write("scene/m.json", R"({"version": 1,
    "geometry": [{"type": "mesh", "file": "models/chair.obj"}],
    "camera": {"path": {"keys": [{"t_s": 0, "position": [0, 0, 5], "target": [0, 0, 0]}]}}})");
  const std::string e = error_of([&] { load_scene(file, search); });
  EXPECT_NE(e.find("geometry[0].file: 'models/chair.obj' not found"), std::string::npos) << e;
  EXPECT_NE(e.find(dir.path() + "/scene/models/chair.obj"), std::string::npos) << e;
  EXPECT_NE(e.find(dir.path() + "/first/models/chair.obj"), std::string::npos) << e;
  EXPECT_NE(e.find(dir.path() + "/second/models/chair.obj"), std::string::npos) << e;
  // Found on the search path once it is there.
  dir.write("second/models/chair.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  const Scene s = load_scene(file, search);
  EXPECT_EQ(s.triangle_count(), 1u);
  EXPECT_EQ(s.objects[0].mesh.normals.size(), 3u);
}

TEST(SceneFormat, StandardSearchPathOrder) {
  const SceneSearchPath s = SceneSearchPath::standard({"/cli/dir"});
  ASSERT_GE(s.dirs.size(), 2u);
  EXPECT_EQ(s.dirs.front(), "/cli/dir");
  EXPECT_EQ(s.dirs.back(), std::string(DHR_SOURCE_DIR) + "/../shared/scenes");
}

// --- built-in scenes ----------------------------------------------------------------------------

TEST(BuiltinScenes, AllLoadWithLightsAoAndAPath) {
  const auto files = builtin_scene_files();
  ASSERT_GE(files.size(), 3u);
  bool any_moving = false;
  for (const auto& f : files) {
    SCOPED_TRACE(f);
    const Scene s = load_scene(f, empty_search());
    EXPECT_GT(s.triangle_count(), 1000u);
    EXPECT_LT(s.triangle_count(), 100000u);
    EXPECT_FALSE(s.lights.empty());
    EXPECT_TRUE(s.ao.has_value());
    EXPECT_GE(s.camera.duration_s(), 10.0);
    // The camera moves and turns.
    const Camera a = s.camera.at(0.0, 64, 36), b = s.camera.at(s.camera.duration_s() * 0.5, 64, 36);
    EXPECT_GT(glm::length(a.position - b.position), 0.5f);
    EXPECT_LT(glm::dot(a.forward, b.forward), 0.99f);
    any_moving = any_moving || s.has_moving_objects();
    for (const auto& o : s.objects) ASSERT_LT(o.material, s.materials.size());
  }
  EXPECT_TRUE(any_moving);
  const Scene street = load_scene_or_model("street", empty_search());
  EXPECT_GE(street.lights.size(), 6u);
}

// --- model import -------------------------------------------------------------------------------

TEST(ModelImport, GoodModelsLoad) {
  if (!fs::exists(kAssimpModels)) GTEST_SKIP() << kAssimpModels << " missing (apt-get install assimp-testmodels)";
  const ImportedModel gltf = import_model(kAssimpModels + "/glTF2/BoxTextured-glTF/BoxTextured.gltf");
  EXPECT_EQ(gltf.triangle_count(), 12u);
  ASSERT_EQ(gltf.textures.size(), 1u);
  EXPECT_GT(gltf.textures[0].width, 0);
  ASSERT_EQ(gltf.materials.size(), 1u);
  EXPECT_EQ(gltf.materials[0].texture, 0);
  const ImportedModel glb = import_model(kAssimpModels + "/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb");
  ASSERT_EQ(glb.textures.size(), 1u);  // embedded
  EXPECT_EQ(glb.textures[0].width, gltf.textures[0].width);
  const ImportedModel obj = import_model(kAssimpModels + "/OBJ/box.obj");
  EXPECT_EQ(obj.triangle_count(), 12u);
  for (const auto& o : obj.objects)
    for (const auto& n : o.mesh.normals) EXPECT_NEAR(glm::length(n), 1.0f, 1e-4f);
  // A model loaded directly is framed by a default camera, light and AO.
  const Scene s = load_model_as_scene(kAssimpModels + "/glTF2/BoxTextured-glTF/BoxTextured.gltf", empty_search());
  EXPECT_EQ(s.lights.size(), 1u);
  EXPECT_TRUE(s.ao.has_value());
  EXPECT_GE(s.camera.duration_s(), 10.0);
  EXPECT_EQ(s.objects[0].id, 1u);
}

TEST(ModelImport, BadNormalsAreRegeneratedGeometryKept) {
  if (!fs::exists(kAssimpModels)) GTEST_SKIP() << kAssimpModels << " missing";
  // Decision: bad normals are recomputed (that never changes geometry); the model is accepted.
  const ImportedModel m = import_model(kAssimpModels + "/glTF2/BoxBadNormals-glTF-Binary/BoxBadNormals.glb");
  EXPECT_EQ(m.triangle_count(), 12u);
  for (const auto& o : m.objects)
    for (const auto& n : o.mesh.normals) EXPECT_NEAR(glm::length(n), 1.0f, 1e-4f);
}

TEST(ModelImport, EveryBrokenModelIsRejectedNamingTheFile) {
  if (!fs::exists(kAssimpModels)) GTEST_SKIP() << kAssimpModels << " missing";
  std::vector<std::string> broken = {
      "glTF2/BoxWithInfinites-glTF-Binary/BoxWithInfinites.glb",
      "glTF2/IndexOutOfRange/IndexOutOfRange.gltf",
      "glTF2/IndexOutOfRange/AllIndicesOutOfRange.gltf",
      "glTF2/MissingBin/BoxTextured.gltf",
      "glTF2/RecursiveNodes/RecursiveNodes.gltf",
      "glTF2/SchemaFailures/sceneWrongType.gltf",
      "glTF2/TestNoRootNode/NoScene.gltf",
      "glTF2/TestNoRootNode/SceneWithoutNodes.gltf",
      "glTF2/IncorrectVertexArrays/Cube.gltf",
      "invalid/OutOfMemory.off",
      "invalid/malformed.obj",
      "invalid/emptyIrrMesh.xml",
  };
  for (const auto& e : fs::directory_iterator(kAssimpModels + "/invalid"))
    if (e.path().filename().string().rfind("empty.", 0) == 0)
      broken.push_back("invalid/" + e.path().filename().string());
  for (const auto& rel : broken) {
    const std::string path = kAssimpModels + "/" + rel;
    if (!fs::exists(path)) {
      ADD_FAILURE() << path << " is missing from the test models";
      continue;
    }
    const std::string e = error_of([&] { import_model(path); });
    EXPECT_EQ(e.rfind(path + ":", 0), 0u) << rel << ": " << (e.empty() ? "accepted" : e);  // "FILE: " or "FILE:LINE: "
  }
}

TEST(ModelImport, ValidateMeshRejectsAndRepairsTheRightThings) {
  Mesh m = make_box({1, 1, 1});
  m.normals[3] = glm::vec3(0.0f);
  m.normals[4] = glm::vec3(NAN);
  m.normals[5] *= 3.0f;
  const Mesh before = m;
  EXPECT_EQ(validate_mesh(m, "box"), 3u);
  EXPECT_EQ(m.positions, before.positions);
  EXPECT_EQ(m.triangles, before.triangles);
  for (const auto& n : m.normals) EXPECT_NEAR(glm::length(n), 1.0f, 1e-5f);
  Mesh bad_index = make_box({1, 1, 1});
  bad_index.triangles[2].y = 24;
  EXPECT_NE(error_of([&] { validate_mesh(bad_index, "f.obj: mesh 0"); }).find("f.obj: mesh 0: triangle 2 has index"),
            std::string::npos);
  Mesh huge = make_box({1, 1, 1});
  huge.positions[1].x = 1e19f;
  EXPECT_THROW(validate_mesh(huge, "h"), Error);
  Mesh empty = make_box({1, 1, 1});
  empty.triangles.clear();
  EXPECT_THROW(validate_mesh(empty, "e"), Error);
}

TEST(ModelImport, LyingOffHeaderIsRefusedBeforeAllocating) {
  TempDir dir;
  const std::string f = dir.write("lie.off", "OFF\n3 900000000000 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  EXPECT_NE(error_of([&] { import_model(f); }).find(f + ": OFF header declares"), std::string::npos);
  const std::string good = dir.write("tri.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  EXPECT_EQ(import_model(good).triangle_count(), 1u);
}

// A uv (or normal) index out of range and a missing MTL file are errors naming the file and
// line: not a mesh whose uvs or normals are dropped in silence, nor one rendered without
// materials.
TEST(ModelImport, ObjIndicesOutOfRangeAndMissingMtlAreErrorsNamingTheLine) {
  TempDir dir;
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n";
  EXPECT_EQ(import_model(dir.write("good.obj", tri + "f 1/1/1 2/2/1 3/3/1\n")).triangle_count(), 1u);
  EXPECT_EQ(import_model(dir.write("relative.obj", tri + "f -3/-3/-1 -2/-2/-1 -1/-1/-1\n")).triangle_count(), 1u);
  const std::string uv = dir.write("uv.obj", tri + "f 1/1/1 2/5/1 3/3/1\n");
  EXPECT_NE(error_of([&] { import_model(uv); }).find(uv + ":8: texture coordinate (vt) index 5 is out of range"),
            std::string::npos)
      << error_of([&] { import_model(uv); });
  const std::string vn = dir.write("vn.obj", tri + "f 1/1/1 2/2/9 3/3/1\n");
  EXPECT_NE(error_of([&] { import_model(vn); }).find(vn + ":8: normal (vn) index 9"), std::string::npos);
  const std::string v0 = dir.write("v0.obj", tri + "f 0 2 3\n");
  EXPECT_NE(error_of([&] { import_model(v0); }).find(v0 + ":8: vertex (v) index 0"), std::string::npos);
  const std::string back = dir.write("back.obj", tri + "f -4 2 3\n");
  EXPECT_NE(error_of([&] { import_model(back); }).find("index -4 is out of range"), std::string::npos);
  const std::string mtl = dir.write("mtl.obj", "mtllib missing.mtl\n" + tri + "f 1 2 3\n");
  EXPECT_NE(error_of([&] { import_model(mtl); }).find(mtl + ":1: mtllib 'missing.mtl': no such material file"),
            std::string::npos)
      << error_of([&] { import_model(mtl); });
  dir.write("has.mtl", "newmtl m\nKd 1 0 0\n");
  EXPECT_EQ(import_model(dir.write("has.obj", "mtllib has.mtl\nusemtl m\n" + tri + "f 1 2 3\n")).triangle_count(), 1u);
}

// A 200-byte GLB whose JSON claims a 4 GB buffer, or whose chunk claims 4 GB, is refused before
// the importer allocates it.
TEST(ModelImport, GlbThatClaimsMoreThanItHoldsIsRefusedBeforeAllocating) {
  TempDir dir;
  auto glb = [&](const std::string& name, const std::string& json, uint32_t claimed_chunk) {
    std::string j = json;
    while (j.size() % 4) j += ' ';
    std::string bytes = "glTF";
    auto u32 = [&](uint32_t v) {
      for (int k = 0; k < 4; ++k) bytes += char((v >> (8 * k)) & 255);
    };
    u32(2);
    u32(uint32_t(12 + 8 + j.size()));
    u32(claimed_chunk ? claimed_chunk : uint32_t(j.size()));
    u32(0x4E4F534Au);
    bytes += j;
    const std::string path = dir.path() + "/" + name;
    std::ofstream(path, std::ios::binary) << bytes;
    return path;
  };
  const std::string buffer =
      glb("buffer.glb", R"({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4294967295}]})", 0);
  EXPECT_NE(error_of([&] {
              import_model(buffer);
            }).find(buffer + ": glTF buffers[0] claims 4294967295 bytes, more than the GLB's BIN chunk"),
            std::string::npos)
      << error_of([&] { import_model(buffer); });
  const std::string chunk = glb("chunk.glb", R"({"asset": {"version": "2.0"}})", 0xFFFFFFF0u);
  EXPECT_NE(error_of([&] { import_model(chunk); }).find(chunk + ": the GLB chunk at byte 12 claims 4294967280 bytes"),
            std::string::npos)
      << error_of([&] { import_model(chunk); });
  const std::string gltf = dir.write(
      "big.gltf", R"({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4000000000, "uri": "none.bin"}]})");
  EXPECT_NE(error_of([&] { import_model(gltf); }).find("claims 4000000000 bytes, more than its file"),
            std::string::npos);
}

// Colour is read as stored, not premultiplied by alpha (OpenImageIO's default would read RGB 200
// with alpha 128 as 100); an EXR's floats are linear, not sRGB-encoded; NaN/inf are refused, not
// made 0/255 in silence.
TEST(ImageRead, AlphaIsUnassociatedFloatsAreLinearNonFiniteIsRefused) {
  TempDir dir;
  const std::string rgba = dir.path() + "/rgba.png";
  {
    auto out = OIIO::ImageOutput::create(rgba);
    ASSERT_TRUE(out);
    OIIO::ImageSpec spec(2, 1, 4, OIIO::TypeDesc::UINT8);
    spec.attribute("oiio:UnassociatedAlpha", 1);
    const uint8_t px[8] = {200, 100, 50, 128, 10, 20, 30, 0};
    ASSERT_TRUE(out->open(rgba, spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px));
    out->close();
  }
  const Rgba8Image a = read_rgba8(rgba);
  ASSERT_TRUE(a.has_alpha);
  EXPECT_EQ(std::vector<uint8_t>(a.rgba.begin(), a.rgba.end()),
            (std::vector<uint8_t>{200, 100, 50, 128, 10, 20, 30, 0}));
  const ImageRGB8 rgb = read_rgb8(rgba);
  EXPECT_EQ(rgb(0, 0).r, 200);
  EXPECT_EQ(rgb(1, 0).b, 30);
  // EXR: linear 0.5 is sRGB code 188; 0.2 / alpha 0.5 (OpenEXR premultiplies) is linear 0.4 -> 170.
  auto write_exr4 = [&](const std::string& name, std::vector<float> px) {
    const std::string path = dir.path() + "/" + name;
    auto out = OIIO::ImageOutput::create(path);
    OIIO::ImageSpec spec(int(px.size() / 4), 1, 4, OIIO::TypeDesc::FLOAT);
    EXPECT_TRUE(out->open(path, spec));
    EXPECT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
    return path;
  };
  const Rgba8Image e = read_rgba8(write_exr4("lin.exr", {0.5f, 0.5f, 0.5f, 1.0f, 0.2f, 0.0f, 2.0f, 0.5f}));
  EXPECT_EQ(e.rgba[0], 188);
  EXPECT_EQ(e.rgba[3], 255);
  EXPECT_EQ(e.rgba[4], 170);
  EXPECT_EQ(e.rgba[6], 255);  // 4.0 linear clamps to white
  EXPECT_EQ(e.rgba[7], 128);
  const std::string nan = write_exr4("nan.exr", {0.5f, 0.5f, 0.5f, 1.0f, 0.1f, std::nanf(""), 0.1f, 1.0f});
  EXPECT_NE(error_of([&] { read_rgba8(nan); }).find(nan + ": pixel (1, 0) channel 1 is nan"), std::string::npos)
      << error_of([&] { read_rgba8(nan); });
  const std::string inf = write_exr4("inf.exr", {INFINITY, 0.5f, 0.5f, 1.0f});
  EXPECT_NE(error_of([&] { read_rgba8(inf); }).find(inf + ": pixel (0, 0) channel 0 is inf"), std::string::npos);
}

// --- real scenes --------------------------------------------------------------------------------

TEST(RealScenes, SmallestLoadsWithTexturesLightsAndCamera) {
  const std::string shared = test::shared_scenes_dir();
  if (!fs::exists(shared + "/sponza-dabrovic/sponza-dabrovic.obj")) GTEST_SKIP() << "no real scenes under " << shared;
  // Only the smallest real scene (8 MB OBJ) is loaded here to keep this test fast (the five
  // together take several seconds in Release and far more under the sanitizers).
  SceneSearchPath search;
  search.dirs = {shared};
  const Scene s = load_scene(test::source_dir() + "/scenes/real/sponza-dabrovic.json", search);
  EXPECT_GT(s.triangle_count(), 50000u);
  EXPECT_FALSE(s.textures.empty());
  ASSERT_EQ(s.lights.size(), 1u);
  EXPECT_NEAR(s.lights[0].position.y, 17.0f, 1e-4f);  // from source-scene.xml
  EXPECT_GE(s.camera.duration_s(), 10.0);
  EXPECT_TRUE(s.ao.has_value());
  for (const auto& o : s.objects) ASSERT_LT(o.material, s.materials.size());
  bool emitter = false;
  for (const auto& m : s.materials) emitter = emitter || m.emitter;
  EXPECT_TRUE(emitter);
}

TEST(RealScenes, EverySceneFileParses) {
  // Every real scene file is valid apart from its mesh (checked with an empty search path,
  // so the only problem reported is the missing mesh file: the format itself is fine).
  const auto files = real_scene_files();
  EXPECT_EQ(files.size(), 5u);
  for (const auto& f : files) {
    const std::string e = error_of([&] { load_scene(f, empty_search()); });
    const bool only_missing_mesh =
        e.find("geometry[0].file: '") != std::string::npos && e.find("problems") == std::string::npos;
    EXPECT_TRUE(only_missing_mesh || e.empty()) << f << ": " << e;
  }
}

}  // namespace
}  // namespace dhr
