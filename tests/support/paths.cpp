#include "tests/support.h"

#include "core/base/error.h"
#include "core/scene/scene_load.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>

namespace dhr::test {

std::string source_dir() { return DHR_SOURCE_DIR; }

std::string shared_scenes_dir() {
  if (const char* p = std::getenv("DHR_SCENE_PATH"); p && *p) {
    std::string s = p;
    return s.substr(0, s.find(':'));
  }
  return DHR_SHARED_SCENES_DEFAULT;
}

void for_each_scene(const std::function<void(const std::string& name, const Scene& scene)>& fn) {
  std::vector<std::string> files = builtin_scene_files();
  for (const auto& f : real_scene_files()) files.push_back(f);
  for (const auto& file : files) {
    const std::string name = std::filesystem::path(file).stem().string();
    Scene scene;
    try {
      scene = load_scene(file, SceneSearchPath::standard());
    } catch (const Error& e) {
      std::printf("skipped %s: %s\n", name.c_str(), e.what());
      continue;
    }
    fn(name, scene);
  }
}

}  // namespace dhr::test

namespace dhr::test {

Object make_object(uint32_t id, Mesh mesh, glm::vec3 offset, uint32_t material) {
  for (auto& p : mesh.positions) p += offset;
  Object o;
  o.name = "object" + std::to_string(id);
  o.id = id;
  o.material = material;
  o.mesh = std::move(mesh);
  return o;
}

Light sphere_light(glm::vec3 p, float radius_m, float intensity) {
  Light l;
  l.type = LightType::Sphere;
  l.position = p;
  l.radius_m = radius_m;
  l.intensity = intensity;
  return l;
}

Light distant_light(glm::vec3 dir, float angular_radius_deg) {
  Light l;
  l.type = LightType::Distant;
  l.direction = glm::normalize(dir);
  l.angular_radius_deg = angular_radius_deg;
  return l;
}

}  // namespace dhr::test
