// The scene model: plain data that the loader (core/scene/scene_load.h) fills from a scene file or
// a model file, and that the rasterizer, the tracer and the composite read.
//
// Static objects are stored in world space (their transform applied at load). A moving object
// keeps its mesh in object space and is placed at time t by Object::world_from_object(t).
#pragma once

#include "core/buffers/camera.h"

#include <glm/glm.hpp>
#include <glm/gtc/quaternion.hpp>

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace dhr {

struct Texture {
  std::string path;
  int width = 0;
  int height = 0;
  bool has_alpha = false;
  std::vector<glm::u8vec4> texels;  // sRGB-encoded RGB, linear alpha; row 0 = top of the image
  // Bilinear lookup with wrapping; uv (0,0) is the bottom-left (OBJ/glTF convention after
  // the loader's flip). Returns linear RGB and alpha.
  glm::vec4 sample_bilinear(glm::vec2 uv) const;
};

// The linear value of each 8-bit sRGB code, as sample_bilinear decodes texels (the rasterizer's
// 8-lane lookup reads it too: core/raster/raster_avx512.cpp).
const std::array<float, 256>& srgb_table();

struct Material {
  std::string name;
  glm::vec3 albedo{0.8f};     // linear; multiplies the texture
  int texture = -1;           // index into Scene::textures, or -1
  bool alpha_cutout = false;  // texels with alpha < alpha_threshold are holes
  float alpha_threshold = 0.5f;
  bool emitter = false;  // light-emitting surface (rendered, casts no shadow on its light)
};

struct Mesh {
  std::vector<glm::vec3> positions;
  std::vector<glm::vec3> normals;  // per vertex, unit (same count as positions) or empty
  std::vector<glm::vec2> uvs;      // per vertex or empty
  std::vector<glm::uvec3> triangles;
};

struct TransformKey {
  double time_s = 0.0;
  glm::vec3 translation{0.0f};
  glm::quat rotation{1.0f, 0.0f, 0.0f, 0.0f};
  glm::vec3 scale{1.0f};
};

struct Animation {
  std::vector<TransformKey> keys;  // sorted by time, at least one
  bool loop = false;
  glm::mat4 at(double time_s) const;  // linear translation/scale, slerp rotation
};

struct Object {
  std::string name;
  uint32_t id = 0;        // >= 1 (kBackgroundId = 0)
  uint32_t material = 0;  // index into Scene::materials
  Mesh mesh;              // world space for static objects, object space for moving ones
  std::optional<Animation> animation;
  bool moving() const { return animation.has_value(); }
  glm::mat4 world_from_object(double time_s) const { return animation ? animation->at(time_s) : glm::mat4(1.0f); }
};

enum class LightType { Sphere, Distant };

struct Light {
  std::string name;
  LightType type = LightType::Sphere;
  glm::vec3 position{0.0f};               // Sphere: centre
  glm::vec3 direction{0.0f, 1.0f, 0.0f};  // Distant: unit vector from the scene towards the light
  glm::vec3 colour{1.0f};                 // linear
  float intensity = 1.0f;                 // Sphere: radiant intensity scale (falls off as 1/d^2); Distant: irradiance
  float radius_m = 0.0f;                  // Sphere: 0 = point light (hard shadows)
  float angular_radius_deg = 0.0f;        // Distant: 0 = hard shadows
  float range_m = 0.0f;                   // Sphere: 0 = unbounded; beyond it the light adds nothing
  // Hard shadows only (one deterministic ray to the centre).
  bool is_point() const { return type == LightType::Sphere ? radius_m <= 0.0f : angular_radius_deg <= 0.0f; }
};

struct AoSettings {
  float radius_m = 1.0f;
  int rays = 8;  // 1..255 (stored as an 8-bit count)
};

struct CameraKey {
  double time_s = 0.0;
  glm::vec3 position{0.0f};
  glm::vec3 target{0.0f, 0.0f, -1.0f};
};

struct CameraPath {
  std::vector<CameraKey> keys;  // sorted by time, at least one
  bool loop = false;
  float vfov_deg = 60.0f;
  float near_m = 0.05f;
  float far_m = 1000.0f;
  glm::vec3 up{0.0f, 1.0f, 0.0f};
  double duration_s() const { return keys.empty() ? 0.0 : keys.back().time_s - keys.front().time_s; }
  // Centripetal Catmull-Rom through the keys (smooth); clamps (or wraps when loop) outside.
  Camera at(double time_s, int width, int height) const;
};

struct Scene {
  std::string name;
  std::string source_path;  // the file it was loaded from
  std::vector<Object> objects;
  std::vector<Material> materials;
  std::vector<Texture> textures;
  std::vector<Light> lights;
  glm::vec3 ambient{0.0f};       // linear ambient radiance (colour x intensity), scaled by AO
  std::optional<AoSettings> ao;  // absent: the scene has no AO pass
  glm::vec3 background{0.0f};    // linear colour where nothing is hit
  CameraPath camera;

  size_t triangle_count() const {
    size_t n = 0;
    for (const auto& o : objects) n += o.mesh.triangles.size();
    return n;
  }
  bool has_moving_objects() const {
    for (const auto& o : objects)
      if (o.moving()) return true;
    return false;
  }
};

}  // namespace dhr
