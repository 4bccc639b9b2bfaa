// The JSON scene format (docs/scene-format.md): a strict reader that collects every problem
// with its JSON path, then builds the Scene (static objects baked into world space, moving
// objects kept in object space with their animation).
#include "core/scene/scene_load.h"

#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/scene/mesh_import.h"
#include "core/scene/shapes.h"

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <sstream>

namespace dhr {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

constexpr size_t kMaxSceneTriangles = 50'000'000;
constexpr int kMaxRepeat = 10000;
constexpr int kMaxShapeSegments = 1024;
constexpr uint64_t kMaxSceneFileBytes = 64u << 20;

std::string join(const std::vector<std::string>& v, const char* sep) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? sep : "") + v[i];
  return s;
}

// --- a strict JSON reader that collects errors -------------------------------------------------

class Reader {
 public:
  explicit Reader(std::string file) : file_(std::move(file)) {}

  const std::string& file() const { return file_; }
  const std::vector<std::string>& errors() const { return errors_; }
  // Values and keys in `message` and `path` come from the file: each line is kept to a readable
  // length, however long a key or string in the file is.
  void error(const std::string& path, const std::string& message) {
    errors_.push_back(fmt::format("{}: {}: {}", file_, path.empty() ? "(top level)" : text_excerpt(path, 300),
                                  text_excerpt(message, 600)));
  }

  static std::string key_path(const std::string& path, const std::string& key) {
    return path.empty() ? key : path + "." + key;
  }
  static std::string index_path(const std::string& path, size_t i) { return fmt::format("{}[{}]", path, i); }

  // True when j is an object; reports every key not in `allowed`.
  bool object(const json& j, const std::string& path, const std::vector<std::string>& allowed) {
    if (!j.is_object()) {
      error(path, fmt::format("must be an object, got {}", describe(j)));
      return false;
    }
    for (const auto& [key, value] : j.items()) {
      if (std::find(allowed.begin(), allowed.end(), key) == allowed.end())
        error(key_path(path, text_excerpt(key)), fmt::format("unknown key (valid here: {})", join(allowed, ", ")));
    }
    return true;
  }

  const json* member(const json& obj, const std::string& path, const char* key, bool required) {
    auto it = obj.find(key);
    if (it == obj.end()) {
      if (required) error(key_path(path, key), "is required");
      return nullptr;
    }
    return &*it;
  }

  // A number in [lo, hi] (inclusive unless open_lo); `fallback` when absent or invalid.
  double number(const json& obj, const std::string& path, const char* key, double fallback, double lo, double hi,
                bool required = false, bool open_lo = false) {
    const json* j = member(obj, path, key, required);
    if (!j) return fallback;
    return number_value(*j, key_path(path, key), fallback, lo, hi, open_lo);
  }

  double number_value(const json& j, const std::string& path, double fallback, double lo, double hi,
                      bool open_lo = false) {
    if (!j.is_number()) {
      error(path, fmt::format("must be a number, got {}", describe(j)));
      return fallback;
    }
    const double v = j.get<double>();
    if (!std::isfinite(v)) {
      error(path, "must be finite");
      return fallback;
    }
    if (open_lo ? !(v > lo) : !(v >= lo)) {
      error(path, fmt::format("must be {} {}, got {}", open_lo ? ">" : ">=", lo, v));
      return fallback;
    }
    if (v > hi) {
      error(path, fmt::format("must be <= {}, got {}", hi, v));
      return fallback;
    }
    return v;
  }

  int integer(const json& obj, const std::string& path, const char* key, int fallback, int lo, int hi,
              bool required = false) {
    const json* j = member(obj, path, key, required);
    if (!j) return fallback;
    if (!j->is_number_integer()) {
      error(key_path(path, key), fmt::format("must be an integer, got {}", describe(*j)));
      return fallback;
    }
    const int64_t v = j->get<int64_t>();
    if (v < lo || v > hi) {
      error(key_path(path, key), fmt::format("must be in [{}, {}], got {}", lo, hi, v));
      return fallback;
    }
    return int(v);
  }

  bool boolean(const json& obj, const std::string& path, const char* key, bool fallback) {
    const json* j = member(obj, path, key, false);
    if (!j) return fallback;
    if (!j->is_boolean()) {
      error(key_path(path, key), fmt::format("must be true or false, got {}", describe(*j)));
      return fallback;
    }
    return j->get<bool>();
  }

  std::string string(const json& obj, const std::string& path, const char* key, const std::string& fallback,
                     bool required = false) {
    const json* j = member(obj, path, key, required);
    if (!j) return fallback;
    if (!j->is_string()) {
      error(key_path(path, key), fmt::format("must be a string, got {}", describe(*j)));
      return fallback;
    }
    return j->get<std::string>();
  }

  // [x, y, z] with every component in [lo, hi].
  glm::vec3 vec3(const json& obj, const std::string& path, const char* key, glm::vec3 fallback, bool required = false,
                 double lo = -1e9, double hi = 1e9) {
    const json* j = member(obj, path, key, required);
    if (!j) return fallback;
    return vec3_value(*j, key_path(path, key), fallback, lo, hi);
  }

  glm::vec3 vec3_value(const json& j, const std::string& p, glm::vec3 fallback, double lo, double hi) {
    if (!j.is_array() || j.size() != 3) {
      error(p, fmt::format("must be an array of 3 numbers, got {}", describe(j)));
      return fallback;
    }
    glm::vec3 v;
    const size_t before = errors_.size();
    for (int i = 0; i < 3; ++i) v[i] = float(number_value(j[size_t(i)], index_path(p, size_t(i)), 0.0, lo, hi));
    return errors_.size() == before ? v : fallback;
  }

  // A value in a message: at most 40 characters, however long or deep the value is.
  static std::string describe(const json& j) {
    std::string s = json_excerpt(j, 40);
    if (s.size() > 40) s = s.substr(0, 37) + "...";
    return s;
  }

 private:
  std::string file_;
  std::vector<std::string> errors_;
};

// --- transforms --------------------------------------------------------------------------------

struct Trs {
  glm::vec3 translate{0.0f};
  glm::quat rotate{1.0f, 0.0f, 0.0f, 0.0f};
  glm::vec3 scale{1.0f};
  glm::mat4 matrix() const {
    return glm::translate(glm::mat4(1.0f), translate) * glm::mat4_cast(rotate) * glm::scale(glm::mat4(1.0f), scale);
  }
};

// Euler angles in degrees, applied x first, then y, then z (R = Rz Ry Rx).
glm::quat euler_xyz_deg(const glm::vec3& deg) {
  const glm::vec3 r = glm::radians(deg);
  return glm::angleAxis(r.z, glm::vec3(0, 0, 1)) * glm::angleAxis(r.y, glm::vec3(0, 1, 0)) *
         glm::angleAxis(r.x, glm::vec3(1, 0, 0));
}

// "scale": a number (uniform) or [x, y, z]; every component > 0.
glm::vec3 read_scale(Reader& r, const json& obj, const std::string& path, const char* key) {
  const json* j = r.member(obj, path, key, false);
  if (!j) return glm::vec3(1.0f);
  const std::string p = Reader::key_path(path, key);
  if (j->is_number()) return glm::vec3(float(r.number_value(*j, p, 1.0, 0.0, 1e6, true)));
  if (j->is_array() && j->size() == 3) {
    glm::vec3 v;
    for (int i = 0; i < 3; ++i)
      v[i] = float(r.number_value((*j)[size_t(i)], Reader::index_path(p, size_t(i)), 1.0, 0.0, 1e6, true));
    return v;
  }
  r.error(p, fmt::format("must be a number > 0 or an array of 3 numbers > 0, got {}", Reader::describe(*j)));
  return glm::vec3(1.0f);
}

Trs read_trs(Reader& r, const json& obj, const std::string& path) {
  Trs t;
  t.translate = r.vec3(obj, path, "translate", glm::vec3(0.0f));
  t.rotate = euler_xyz_deg(r.vec3(obj, path, "rotate_deg", glm::vec3(0.0f), false, -1e5, 1e5));
  t.scale = read_scale(r, obj, path, "scale");
  return t;
}

// Applies a transform to a mesh in place (positions, normals; winding when it mirrors).
void transform_mesh(Mesh& m, const glm::mat4& xf) {
  if (xf == glm::mat4(1.0f)) return;
  const glm::mat3 m3(xf);
  const glm::mat3 nm = glm::transpose(glm::inverse(m3));
  for (auto& p : m.positions) p = glm::vec3(xf * glm::vec4(p, 1.0f));
  for (auto& n : m.normals) n = glm::normalize(nm * n);
  if (glm::determinant(m3) < 0.0f)
    for (auto& t : m.triangles) std::swap(t.y, t.z);
}

// --- the scene builder --------------------------------------------------------------------------

struct Loader {
  Reader r;
  const SceneSearchPath& search;
  std::string base_dir;
  Scene scene;
  std::map<std::string, uint32_t> material_by_name;
  struct CachedModel {
    ImportedModel model;
    bool appended = false;       // its materials and textures are in the scene
    uint32_t material_base = 0;  // where its materials start in Scene::materials
  };
  std::map<std::string, CachedModel> models;  // by resolved path

  Loader(const std::string& file, const SceneSearchPath& s) : r(file), search(s) {
    base_dir = fs::path(file).parent_path().string();
  }

  std::optional<std::string> resolve(const std::string& path_in_json, const std::string& rel) {
    std::vector<std::string> looked;
    if (auto p = search.find(rel, base_dir, &looked)) return p;
    r.error(path_in_json, fmt::format("'{}' not found; looked in: {}", rel, join(looked, ", ")));
    return std::nullopt;
  }

  void read_materials(const json& root) {
    // The implicit default material for shapes that name none.
    scene.materials.push_back(Material{"default", glm::vec3(0.8f), -1, false, 0.5f, false});
    material_by_name["default"] = 0;
    const json* mats = r.member(root, "", "materials", false);
    if (!mats) return;
    if (!mats->is_object()) {
      r.error("materials", "must be an object mapping names to materials");
      return;
    }
    std::map<std::string, int> texture_by_path;
    for (const auto& [name, j] : mats->items()) {
      const std::string p = Reader::key_path("materials", name);
      if (!r.object(j, p, {"albedo", "texture", "alpha_cutout", "alpha_threshold", "emitter"})) continue;
      Material m;
      m.name = name;
      m.albedo = r.vec3(j, p, "albedo", glm::vec3(0.8f), false, 0.0, 1.0);
      m.alpha_cutout = r.boolean(j, p, "alpha_cutout", false);
      m.alpha_threshold = float(r.number(j, p, "alpha_threshold", 0.5, 0.0, 1.0));
      m.emitter = r.boolean(j, p, "emitter", name.rfind("emitter_", 0) == 0);
      const std::string tex = r.string(j, p, "texture", "");
      if (!tex.empty()) {
        if (auto file = resolve(Reader::key_path(p, "texture"), tex)) {
          auto it = texture_by_path.find(*file);
          if (it == texture_by_path.end()) {
            try {
              scene.textures.push_back(load_texture(*file));
              it = texture_by_path.emplace(*file, int(scene.textures.size() - 1)).first;
            } catch (const Error& e) {
              r.error(Reader::key_path(p, "texture"), e.what());
            }
          }
          if (it != texture_by_path.end()) m.texture = it->second;
        }
      }
      if (name == "default") {
        scene.materials[0] = m;
      } else {
        material_by_name[name] = uint32_t(scene.materials.size());
        scene.materials.push_back(m);
      }
    }
  }

  std::optional<Animation> read_animation(const json& g, const std::string& path) {
    const json* a = r.member(g, path, "animation", false);
    if (!a) return std::nullopt;
    const std::string p = Reader::key_path(path, "animation");
    if (!r.object(*a, p, {"loop", "keys"})) return std::nullopt;
    Animation anim;
    anim.loop = r.boolean(*a, p, "loop", false);
    const json* keys = r.member(*a, p, "keys", true);
    if (!keys) return std::nullopt;
    const std::string kp = Reader::key_path(p, "keys");
    if (!keys->is_array() || keys->empty()) {
      r.error(kp, "must be a non-empty array of keys");
      return std::nullopt;
    }
    for (size_t i = 0; i < keys->size(); ++i) {
      const std::string ip = Reader::index_path(kp, i);
      const json& k = (*keys)[i];
      if (!r.object(k, ip, {"t_s", "translate", "rotate_deg", "scale"})) continue;
      TransformKey key;
      key.time_s = r.number(k, ip, "t_s", 0.0, 0.0, 1e6, true);
      const Trs t = read_trs(r, k, ip);
      key.translation = t.translate;
      key.rotation = t.rotate;
      key.scale = t.scale;
      if (!anim.keys.empty() && !(key.time_s > anim.keys.back().time_s))
        r.error(Reader::key_path(ip, "t_s"),
                fmt::format("must be greater than the previous key's {}", anim.keys.back().time_s));
      anim.keys.push_back(key);
    }
    return anim;
  }

  // The triangles a shape will have, computed before generating it.
  static size_t shape_triangles(const std::string& type, int segments, int rings, bool caps) {
    if (type == "box") return 12;
    if (type == "plane") return 2;
    if (type == "sphere") return size_t(2) * size_t(segments) * size_t(rings - 1);
    if (type == "cylinder") return size_t(2) * size_t(segments) * (caps ? 2 : 1);
    return 0;
  }

  void read_geometry(const json& root) {
    const json* geo = r.member(root, "", "geometry", true);
    if (!geo) return;
    if (!geo->is_array() || geo->empty()) {
      r.error("geometry", "must be a non-empty array");
      return;
    }
    size_t total_tris = 0;
    for (size_t gi = 0; gi < geo->size(); ++gi) {
      const std::string p = Reader::index_path("geometry", gi);
      const json& g = (*geo)[gi];
      if (!g.is_object()) {
        r.error(p, "must be an object");
        continue;
      }
      const std::string type = r.string(g, p, "type", "", true);
      std::vector<std::string> allowed = {"type", "name", "transform", "repeat", "animation"};
      if (type == "box")
        allowed.insert(allowed.end(), {"size_m", "material"});
      else if (type == "sphere")
        allowed.insert(allowed.end(), {"radius_m", "segments", "rings", "material"});
      else if (type == "plane")
        allowed.insert(allowed.end(), {"size_m", "material"});
      else if (type == "cylinder")
        allowed.insert(allowed.end(), {"radius_m", "height_m", "segments", "caps", "material"});
      else if (type == "mesh")
        allowed.insert(allowed.end(), {"file"});
      else if (g.contains("type")) {
        r.error(Reader::key_path(p, "type"),
                fmt::format("'{}' is not one of box, sphere, plane, cylinder, mesh", type));
        continue;
      } else {
        continue;
      }
      if (!r.object(g, p, allowed)) continue;
      const size_t errors_before = r.errors().size();
      const std::string name = r.string(g, p, "name", fmt::format("{}{}", type, gi));

      Trs trs;
      if (const json* t = r.member(g, p, "transform", false)) {
        const std::string tp = Reader::key_path(p, "transform");
        if (r.object(*t, tp, {"translate", "rotate_deg", "scale"})) trs = read_trs(r, *t, tp);
      }
      int count = 1;
      glm::vec3 offset(0.0f);
      if (const json* rep = r.member(g, p, "repeat", false)) {
        const std::string rp = Reader::key_path(p, "repeat");
        if (r.object(*rep, rp, {"count", "offset"})) {
          count = r.integer(*rep, rp, "count", 1, 1, kMaxRepeat, true);
          offset = r.vec3(*rep, rp, "offset", glm::vec3(0.0f), true);
        }
      }
      std::optional<Animation> anim = read_animation(g, p);

      // The object-space meshes (one per object) and their materials.
      // (mesh, material) per object: shapes own their mesh here, mesh files point into the
      // model cache (copied once, into the Object).
      std::vector<Mesh> owned;
      owned.reserve(1);  // one shape per entry: the pointer below stays valid
      std::vector<std::pair<const Mesh*, uint32_t>> parts;
      std::vector<std::string> part_names;
      if (type == "mesh") {
        const std::string file = r.string(g, p, "file", "", true);
        if (file.empty()) continue;
        auto resolved = resolve(Reader::key_path(p, "file"), file);
        if (!resolved) continue;
        auto it = models.find(*resolved);
        if (it == models.end()) {
          try {
            it = models.emplace(*resolved, CachedModel{import_model(*resolved), false, 0}).first;
          } catch (const Error& e) {
            r.error(Reader::key_path(p, "file"), e.what());
            continue;
          }
        }
        CachedModel& cached = it->second;
        const ImportedModel& model = cached.model;
        if (total_tris + model.triangle_count() * size_t(count) > kMaxSceneTriangles) {
          r.error(p, fmt::format("the scene would exceed {} triangles", kMaxSceneTriangles));
          continue;
        }
        // Materials and textures of a model file are appended once, however often it is used.
        if (!cached.appended) {
          cached.material_base = uint32_t(scene.materials.size());
          const int tex_base = int(scene.textures.size());
          for (const auto& t : model.textures) scene.textures.push_back(t);
          for (Material m : model.materials) {
            if (m.texture >= 0) m.texture += tex_base;
            scene.materials.push_back(m);
          }
          cached.appended = true;
        }
        for (const auto& o : model.objects) {
          parts.emplace_back(&o.mesh, cached.material_base + o.material);
          part_names.push_back(name + "/" + o.name);
        }
      } else {
        const std::string mat = r.string(g, p, "material", "default");
        uint32_t mi = 0;
        if (auto it = material_by_name.find(mat); it != material_by_name.end()) {
          mi = it->second;
        } else {
          std::vector<std::string> names;
          for (const auto& [k, v] : material_by_name) names.push_back(k);
          r.error(Reader::key_path(p, "material"),
                  fmt::format("unknown material '{}' (defined: {})", mat, join(names, ", ")));
        }
        int segments = 0, rings = 0;
        bool caps = true;
        glm::vec3 size(1.0f);
        float radius = 1.0f, height = 1.0f;
        if (type == "box") size = r.vec3(g, p, "size_m", glm::vec3(1.0f), true, 1e-6, 1e6);
        if (type == "plane") {
          const json* s = r.member(g, p, "size_m", true);
          if (s) {
            const std::string sp = Reader::key_path(p, "size_m");
            if (!s->is_array() || s->size() != 2) {
              r.error(sp, "must be [size_x, size_z]");
            } else {
              size.x = float(r.number_value((*s)[0], sp + "[0]", 1.0, 1e-6, 1e6));
              size.z = float(r.number_value((*s)[1], sp + "[1]", 1.0, 1e-6, 1e6));
            }
          }
        }
        if (type == "sphere" || type == "cylinder") radius = float(r.number(g, p, "radius_m", 1.0, 1e-6, 1e6, true));
        if (type == "cylinder") height = float(r.number(g, p, "height_m", 1.0, 1e-6, 1e6, true));
        if (type == "sphere") {
          segments = r.integer(g, p, "segments", 32, 3, kMaxShapeSegments);
          rings = r.integer(g, p, "rings", 16, 2, kMaxShapeSegments);
        }
        if (type == "cylinder") {
          segments = r.integer(g, p, "segments", 24, 3, kMaxShapeSegments);
          caps = r.boolean(g, p, "caps", true);
        }
        if (r.errors().size() != errors_before) continue;
        const size_t tris = shape_triangles(type, segments, rings, caps) * size_t(count);
        if (total_tris + tris > kMaxSceneTriangles) {
          r.error(p, fmt::format("the scene would exceed {} triangles", kMaxSceneTriangles));
          continue;
        }
        Mesh m;
        if (type == "box")
          m = make_box(size);
        else if (type == "sphere")
          m = make_sphere(radius, segments, rings);
        else if (type == "plane")
          m = make_plane(size.x, size.z);
        else
          m = make_cylinder(radius, height, segments, caps);
        owned.push_back(std::move(m));
        parts.emplace_back(&owned.back(), mi);
        part_names.push_back(name);
      }
      if (r.errors().size() != errors_before) continue;

      const glm::mat4 xf = trs.matrix();
      for (int c = 0; c < count; ++c) {
        const glm::vec3 shift = offset * float(c);
        for (size_t k = 0; k < parts.size(); ++k) {
          Object o;
          o.name = count > 1 ? fmt::format("{}#{}", part_names[k], c) : part_names[k];
          o.material = parts[k].second;
          o.mesh = *parts[k].first;
          if (anim) {
            // Moving: the transform shapes the object-space mesh; the animation (shifted per
            // copy) places it in the world.
            transform_mesh(o.mesh, xf);
            Animation a = *anim;
            for (auto& key : a.keys) key.translation += shift;
            o.animation = std::move(a);
          } else {
            transform_mesh(o.mesh, glm::translate(glm::mat4(1.0f), shift) * xf);
          }
          total_tris += o.mesh.triangles.size();
          o.id = uint32_t(scene.objects.size() + 1);
          scene.objects.push_back(std::move(o));
        }
      }
    }
  }

  void read_lights(const json& root) {
    const json* lights = r.member(root, "", "lights", false);
    if (!lights) return;
    if (!lights->is_array()) {
      r.error("lights", "must be an array");
      return;
    }
    for (size_t i = 0; i < lights->size(); ++i) {
      const std::string p = Reader::index_path("lights", i);
      const json& j = (*lights)[i];
      if (!j.is_object()) {
        r.error(p, "must be an object");
        continue;
      }
      const std::string type = r.string(j, p, "type", "", true);
      Light l;
      std::vector<std::string> allowed = {"type", "name", "colour", "intensity", "notes"};
      if (type == "sphere") {
        l.type = LightType::Sphere;
        allowed.insert(allowed.end(), {"position", "radius_m", "range_m"});
      } else if (type == "distant") {
        l.type = LightType::Distant;
        allowed.insert(allowed.end(), {"direction", "angular_radius_deg"});
      } else {
        if (j.contains("type"))
          r.error(Reader::key_path(p, "type"), fmt::format("'{}' is not one of sphere, distant", type));
        continue;
      }
      if (!r.object(j, p, allowed)) continue;
      r.string(j, p, "notes", "");
      l.name = r.string(j, p, "name", fmt::format("light{}", i));
      l.colour = r.vec3(j, p, "colour", glm::vec3(1.0f), false, 0.0, 1e6);
      l.intensity = float(r.number(j, p, "intensity", 1.0, 0.0, 1e12));
      if (l.type == LightType::Sphere) {
        l.position = r.vec3(j, p, "position", glm::vec3(0.0f), true);
        l.radius_m = float(r.number(j, p, "radius_m", 0.0, 0.0, 1e6));
        l.range_m = float(r.number(j, p, "range_m", 0.0, 0.0, 1e9));
        if (l.range_m > 0.0f && l.range_m <= l.radius_m)
          r.error(Reader::key_path(p, "range_m"), fmt::format("must be 0 (unbounded) or > radius_m {}", l.radius_m));
      } else {
        const glm::vec3 d = r.vec3(j, p, "direction", glm::vec3(0, 1, 0), true);
        if (!(glm::length(d) > 1e-6f))
          r.error(Reader::key_path(p, "direction"), "must not be zero");
        else
          l.direction = glm::normalize(d);
        l.angular_radius_deg = float(r.number(j, p, "angular_radius_deg", 0.0, 0.0, 45.0));
      }
      scene.lights.push_back(l);
    }
  }

  void read_camera(const json& root) {
    const json* cam = r.member(root, "", "camera", true);
    if (!cam) return;
    if (!r.object(*cam, "camera", {"vfov_deg", "near_m", "far_m", "up", "path", "notes"})) return;
    r.string(*cam, "camera", "notes", "");
    CameraPath& c = scene.camera;
    c.vfov_deg = float(r.number(*cam, "camera", "vfov_deg", 60.0, 0.0, 179.0, false, true));
    c.near_m = float(r.number(*cam, "camera", "near_m", 0.05, 0.0, 1e6, false, true));
    c.far_m = float(r.number(*cam, "camera", "far_m", 1000.0, 0.0, 1e9, false, true));
    if (!(c.far_m > c.near_m)) r.error("camera.far_m", fmt::format("must be > near_m {}", c.near_m));
    const glm::vec3 up = r.vec3(*cam, "camera", "up", glm::vec3(0, 1, 0));
    if (!(glm::length(up) > 1e-6f))
      r.error("camera.up", "must not be zero");
    else
      c.up = glm::normalize(up);
    const json* path = r.member(*cam, "camera", "path", true);
    if (!path || !r.object(*path, "camera.path", {"loop", "keys"})) return;
    c.loop = r.boolean(*path, "camera.path", "loop", false);
    const json* keys = r.member(*path, "camera.path", "keys", true);
    if (!keys) return;
    if (!keys->is_array() || keys->empty()) {
      r.error("camera.path.keys", "must be a non-empty array");
      return;
    }
    for (size_t i = 0; i < keys->size(); ++i) {
      const std::string p = Reader::index_path("camera.path.keys", i);
      const json& k = (*keys)[i];
      if (!r.object(k, p, {"t_s", "position", "target"})) continue;
      CameraKey key;
      key.time_s = r.number(k, p, "t_s", 0.0, 0.0, 1e6, true);
      key.position = r.vec3(k, p, "position", glm::vec3(0.0f), true);
      key.target = r.vec3(k, p, "target", glm::vec3(0, 0, -1), true);
      if (glm::length(key.target - key.position) < 1e-6f) r.error(p, "target equals position");
      if (!c.keys.empty() && !(key.time_s > c.keys.back().time_s))
        r.error(Reader::key_path(p, "t_s"),
                fmt::format("must be greater than the previous key's {}", c.keys.back().time_s));
      c.keys.push_back(key);
    }
  }

  void read_root(const json& root) {
    if (!r.object(
            root, "",
            {"version", "name", "notes", "geometry", "materials", "lights", "ambient", "ao", "background", "camera"}))
      return;
    const json* version = r.member(root, "", "version", true);
    if (version && (!version->is_number_integer() || version->get<int64_t>() != 1))
      r.error("version",
              fmt::format("{} is not a supported version (this reader knows version 1)", Reader::describe(*version)));
    scene.name = r.string(root, "", "name", fs::path(r.file()).stem().string());
    r.string(root, "", "notes", "");
    read_materials(root);
    read_geometry(root);
    read_lights(root);
    if (const json* a = r.member(root, "", "ambient", false)) {
      if (r.object(*a, "ambient", {"colour", "intensity"}))
        scene.ambient = r.vec3(*a, "ambient", "colour", glm::vec3(1.0f), false, 0.0, 1e6) *
                        float(r.number(*a, "ambient", "intensity", 1.0, 0.0, 1e6));
    }
    if (const json* a = r.member(root, "", "ao", false)) {
      if (r.object(*a, "ao", {"radius_m", "rays"})) {
        AoSettings ao;
        ao.radius_m = float(r.number(*a, "ao", "radius_m", 1.0, 0.0, 1e6, true, true));
        ao.rays = r.integer(*a, "ao", "rays", 8, 1, 255);
        scene.ao = ao;
      }
    }
    scene.background = r.vec3(root, "", "background", glm::vec3(0.0f), false, 0.0, 1e6);
    read_camera(root);
  }
};

void throw_if_errors(const std::vector<std::string>& errors, const std::string& file) {
  if (errors.empty()) return;
  if (errors.size() == 1) throw Error(errors[0]);
  throw Error(fmt::format("{}: {} problems:\n{}", file, errors.size(), join(errors, "\n")));
}

bool is_regular(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

std::vector<std::string> json_files_in(const fs::path& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec))
    if (e.is_regular_file() && e.path().extension() == ".json") out.push_back(e.path().string());
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

SceneSearchPath SceneSearchPath::standard(const std::vector<std::string>& command_line) {
  SceneSearchPath s;
  for (const auto& d : command_line)
    if (!d.empty()) s.dirs.push_back(d);
  if (const char* env = std::getenv("DHR_SCENE_PATH"); env && *env) {
    std::stringstream ss(env);
    for (std::string d; std::getline(ss, d, ':');)
      if (!d.empty()) s.dirs.push_back(d);
  }
  s.dirs.push_back(DHR_SOURCE_DIR "/../shared/scenes");
  return s;
}

std::optional<std::string> SceneSearchPath::find(const std::string& relative, const std::string& base_dir,
                                                 std::vector<std::string>* looked) const {
  if (relative.empty()) return std::nullopt;
  const fs::path rel(relative);
  if (rel.is_absolute()) {
    if (is_regular(rel)) return relative;
    if (looked) looked->push_back(relative);
    return std::nullopt;
  }
  std::vector<fs::path> candidates;
  candidates.push_back(base_dir.empty() ? rel : fs::path(base_dir) / rel);
  for (const auto& d : dirs) candidates.push_back(fs::path(d) / rel);
  for (const auto& c : candidates) {
    if (is_regular(c)) return c.lexically_normal().string();
    if (looked) looked->push_back(c.lexically_normal().string());
  }
  return std::nullopt;
}

Scene load_scene(const std::string& path, const SceneSearchPath& search) {
  std::error_code ec;
  if (!is_regular(path)) fail("{}: scene file not found", path);
  const uint64_t bytes = fs::file_size(path, ec);
  if (ec || bytes > kMaxSceneFileBytes)
    fail("{}: scene file unreadable or larger than {} bytes", path, kMaxSceneFileBytes);
  // Depth-bounded; every parse error (a number out of range such as 1e400 too) names the file.
  const json root = read_json_file(path);
  Loader loader(path, search);
  loader.read_root(root);
  throw_if_errors(loader.r.errors(), path);
  Scene scene = std::move(loader.scene);
  scene.source_path = path;
  return scene;
}

Scene load_model_as_scene(const std::string& path, const SceneSearchPath& search) {
  std::vector<std::string> looked;
  const auto file = search.find(path, "", &looked);
  if (!file) fail("{}: model file not found; looked in: {}", path, join(looked, ", "));
  ImportedModel model = import_model(*file);
  Scene scene;
  scene.name = fs::path(*file).stem().string();
  scene.source_path = *file;
  scene.materials = std::move(model.materials);
  scene.textures = std::move(model.textures);
  glm::vec3 lo(std::numeric_limits<float>::max()), hi(-std::numeric_limits<float>::max());
  for (auto& o : model.objects) {
    for (const auto& p : o.mesh.positions) {
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
    o.id = uint32_t(scene.objects.size() + 1);
    scene.objects.push_back(std::move(o));
  }
  const glm::vec3 centre = 0.5f * (lo + hi);
  const float radius = std::max(0.5f * glm::length(hi - lo), 1e-3f);
  // Camera: the bounding sphere fills the view from a diagonal; a 10 s orbit of 90 degrees.
  CameraPath& cam = scene.camera;
  cam.vfov_deg = 45.0f;
  const float dist = radius / std::sin(glm::radians(cam.vfov_deg * 0.5f)) * 1.05f;
  cam.near_m = std::max(dist * 1e-3f, 1e-4f);
  cam.far_m = dist * 10.0f;
  const int steps = 4;
  for (int i = 0; i <= steps; ++i) {
    const float a = glm::radians(45.0f + 90.0f * float(i) / float(steps));
    const glm::vec3 dir = glm::normalize(glm::vec3(std::cos(a), 0.55f, std::sin(a)));
    cam.keys.push_back({10.0 * double(i) / steps, centre + dir * dist, centre});
  }
  // One sphere light above: irradiance ~2.5 at the centre (radiant intensity falls off as 1/d^2).
  Light light;
  light.name = "key";
  light.position = centre + glm::vec3(0.3f * radius, 1.5f * radius, 0.4f * radius);
  light.radius_m = 0.05f * radius;
  light.intensity = 2.5f * glm::dot(light.position - centre, light.position - centre);
  scene.lights.push_back(light);
  scene.ambient = glm::vec3(0.15f);
  scene.ao = AoSettings{0.2f * radius, 8};
  scene.background = glm::vec3(0.05f);
  return scene;
}

Scene load_scene_or_model(const std::string& path, const SceneSearchPath& search) {
  std::string file = path;
  if (!is_regular(file)) {
    std::vector<std::string> looked{path};
    std::optional<std::string> found;
    if (fs::path(path).extension().empty()) {
      for (const char* sub : {"/scenes/", "/scenes/real/"}) {
        const std::string c = std::string(DHR_SOURCE_DIR) + sub + path + ".json";
        if (is_regular(c)) {
          found = c;
          break;
        }
        looked.push_back(c);
      }
    }
    if (!found) found = search.find(path, "", &looked);
    if (!found) fail("{}: scene or model not found; looked in: {}", path, join(looked, ", "));
    file = *found;
  }
  std::string ext = fs::path(file).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".json" ? load_scene(file, search) : load_model_as_scene(file, search);
}

std::vector<std::string> builtin_scene_files() { return json_files_in(fs::path(DHR_SOURCE_DIR) / "scenes"); }
std::vector<std::string> real_scene_files() { return json_files_in(fs::path(DHR_SOURCE_DIR) / "scenes" / "real"); }

}  // namespace dhr
