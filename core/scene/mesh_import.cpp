// Model import through assimp, with validation (see core/scene/mesh_import.h for the policy).
#include "core/scene/mesh_import.h"

#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/buffers/image.h"
#include "core/buffers/image_io.h"

#include <assimp/DefaultLogger.hpp>
#include <assimp/GltfMaterial.h>
#include <assimp/Importer.hpp>
#include <assimp/Logger.hpp>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <string_view>

namespace dhr {

namespace {

namespace fs = std::filesystem;

// --- assimp's log: warnings that say the importer dropped data are errors for us --------------

bool is_data_loss_warning(const std::string& m) {
  std::string s = m;
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s.find("dropped") != std::string::npos || s.find("out-of-range") != std::string::npos ||
         s.find("out of range") != std::string::npos;
}

// Messages of the import running on this thread (assimp logs on the importing thread).
thread_local std::vector<std::string>* t_log_sink = nullptr;

class CollectingLogger : public Assimp::Logger {
 public:
  CollectingLogger() : Assimp::Logger(Assimp::Logger::NORMAL) {}
  bool attachStream(Assimp::LogStream* stream, unsigned int) override {
    delete stream;  // we own no streams; take ownership as the interface demands
    return true;
  }
  bool detachStream(Assimp::LogStream*, unsigned int) override { return true; }
  void OnDebug(const char*) override {}
  void OnVerboseDebug(const char*) override {}
  void OnInfo(const char*) override {}
  void OnWarn(const char* message) override { collect(message); }
  void OnError(const char* message) override { collect(message); }

 private:
  static void collect(const char* message);
};

// Only the warnings that reject a file are kept (the first one is reported).
void CollectingLogger::collect(const char* message) {
  if (t_log_sink && t_log_sink->size() < 16 && is_data_loss_warning(message)) t_log_sink->emplace_back(message);
}

void install_logger_once() {
  static std::once_flag once;
  // DefaultLogger::set takes ownership; the logger lives for the whole process.
  std::call_once(once, [] { Assimp::DefaultLogger::set(new CollectingLogger()); });
}

// --- header pre-scan: declared element counts must fit the file --------------------------------

std::string lower_extension(const std::string& path) {
  std::string e = fs::path(path).extension().string();
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return e;
}

// OFF: "[ST][C][N][4][n]OFF" then "vertices faces edges" (possibly on the same line).
// Every vertex needs at least 6 bytes ("0 0 0\n") and every face at least 8 ("3 0 1 2\n").
void prescan_off(const std::string& path, uint64_t bytes) {
  std::ifstream in(path);
  std::string token;
  if (!(in >> token)) fail("{}: empty OFF file", path);
  if (token.find("OFF") == std::string::npos) return;  // let assimp report it
  long double nv = 0, nf = 0;
  for (std::string t; in >> t;) {
    if (t[0] == '#') {
      std::getline(in, t);
      continue;
    }
    try {
      size_t used = 0;
      nv = std::stold(t, &used);
      if (!(in >> nf)) fail("{}: OFF header has no face count", path);
    } catch (const std::logic_error&) {
      fail("{}: OFF header: '{}' is not a vertex count", path, t);
    }
    break;
  }
  if (!(nv >= 0 && nf >= 0) || nv * 6 > (long double)bytes || nf * 8 > (long double)bytes)
    fail("{}: OFF header declares {} vertices and {} faces, more than a {}-byte file can hold", path, double(nv),
         double(nf), bytes);
}

// PLY: "element NAME COUNT" lines before "end_header"; every element takes at least one byte.
void prescan_ply(const std::string& path, uint64_t bytes) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  for (int n = 0; n < 10000 && std::getline(in, line); ++n) {
    if (line.rfind("end_header", 0) == 0) return;
    if (line.rfind("element", 0) == 0) {
      std::istringstream ls(line);
      std::string kw, name;
      long double count = 0;
      ls >> kw >> name >> count;
      if (!(count >= 0) || count > (long double)bytes)
        fail("{}: PLY header declares {} '{}' elements, more than a {}-byte file can hold", path, double(count), name,
             bytes);
    }
  }
}

// OBJ: every index of a face, line or point refers to a vertex, texture coordinate or normal
// defined before it (1..count, or -count..-1 counted back), and every mtllib file exists. The
// importer drops a mesh's texture coordinates or normals in silence when one index is out of
// range, and renders without materials when the MTL file is missing: both are errors naming
// the line.
void prescan_obj(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  uint64_t count[3] = {0, 0, 0};  // v, vt, vn
  const char* names[3] = {"vertex (v)", "texture coordinate (vt)", "normal (vn)"};
  std::string line;
  for (uint64_t number = 1; std::getline(in, line); ++number) {
    size_t at = line.find_first_not_of(" \t");
    if (at == std::string::npos) continue;
    const size_t end = line.find_first_of(" \t\r", at);
    const std::string_view key(line.data() + at, (end == std::string::npos ? line.size() : end) - at);
    if (key == "v")
      ++count[0];
    else if (key == "vt")
      ++count[1];
    else if (key == "vn")
      ++count[2];
    else if (key == "mtllib") {
      std::string rest = line.substr(std::min(line.size(), at + 6));
      while (!rest.empty() && std::isspace(static_cast<unsigned char>(rest.back()))) rest.pop_back();
      rest.erase(0, std::min(rest.size(), rest.find_first_not_of(" \t")));
      std::error_code ec;
      if (rest.empty() || !fs::is_regular_file(fs::path(path).parent_path() / rest, ec))
        fail("{}:{}: mtllib '{}': no such material file beside the model (its materials would be lost)", path, number,
             text_excerpt(rest));
    } else if (key == "f" || key == "l" || key == "p") {
      std::istringstream tokens(line.substr(at + key.size()));
      for (std::string token; tokens >> token;) {
        size_t start = 0;
        for (int k = 0; k < 3 && start <= token.size(); ++k) {
          const size_t slash = token.find('/', start);
          const std::string part = token.substr(start, slash == std::string::npos ? std::string::npos : slash - start);
          start = slash == std::string::npos ? token.size() + 1 : slash + 1;
          if (part.empty()) continue;
          long long index = 0;
          try {
            size_t used = 0;
            index = std::stoll(part, &used);
            if (used != part.size()) throw std::invalid_argument(part);
          } catch (const std::logic_error&) {
            fail("{}:{}: '{}' is not an index", path, number, text_excerpt(part));
          }
          const long long n = (long long)count[k];
          if (index == 0 || index > n || index < -n)
            fail("{}:{}: {} index {} is out of range: the file defines {} before this line (valid: 1..{} or -{}..-1)",
                 path, number, names[k], index, n, n, n);
        }
      }
    }
  }
}

// glTF's buffers: each "byteLength" must fit what it refers to: a GLB's BIN chunk (a buffer
// without "uri" in a GLB), a local file (its size) or a data: URI (its base64 length x 3 / 4),
// since the importer allocates byteLength bytes before it reads them.
void check_gltf_buffers(const std::string& path, const nlohmann::json& j, uint64_t bin_chunk_bytes) {
  if (!j.is_object() || !j.contains("buffers")) return;
  const auto& buffers = j.at("buffers");
  if (!buffers.is_array()) fail("{}: glTF \"buffers\" must be a list", path);
  for (size_t i = 0; i < buffers.size(); ++i) {
    const auto& b = buffers[i];
    if (!b.is_object() || !b.contains("byteLength") || !b.at("byteLength").is_number_unsigned())
      fail("{}: glTF buffers[{}].byteLength must be a whole number >= 0", path, i);
    const uint64_t length = b.at("byteLength").get<uint64_t>();
    uint64_t available = bin_chunk_bytes;
    std::string what = "the GLB's BIN chunk";
    if (b.contains("uri")) {
      if (!b.at("uri").is_string()) fail("{}: glTF buffers[{}].uri must be a string", path, i);
      const std::string uri = b.at("uri").get<std::string>();
      if (uri.rfind("data:", 0) == 0) {
        available = (uri.size() - std::min(uri.size(), uri.find(',') + 1)) / 4 * 3 + 3;
        what = "its data: URI";
      } else {
        std::error_code ec;
        const fs::path file = fs::path(path).parent_path() / uri;
        available = fs::is_regular_file(file, ec) ? fs::file_size(file, ec) : 0;
        if (ec) available = 0;
        what = "its file " + text_excerpt(uri);
      }
    }
    if (length > available)
      fail("{}: glTF buffers[{}] claims {} bytes, more than {} holds ({} bytes)", path, i, length, what, available);
  }
}

// GLB: a 12-byte header ("glTF", version, length) and chunks of (length, type, data); every
// length must lie within the file. The JSON chunk's buffers are checked as for .gltf.
void prescan_glb(const std::string& path, uint64_t bytes) {
  std::ifstream in(path, std::ios::binary);
  auto u32 = [&](uint64_t at) {
    uint8_t b[4] = {};
    in.seekg(std::streamoff(at));
    if (!in.read(reinterpret_cast<char*>(b), 4)) fail("{}: GLB cut short at byte {}", path, at);
    return uint32_t(b[0]) | uint32_t(b[1]) << 8 | uint32_t(b[2]) << 16 | uint32_t(b[3]) << 24;
  };
  if (bytes < 12 || u32(0) != 0x46546C67u) return;  // not a binary glTF: let the importer say what it is
  const uint64_t total = u32(8);
  if (total != bytes) fail("{}: the GLB header says {} bytes, the file has {}", path, total, bytes);
  nlohmann::json gltf;
  uint64_t bin = 0;
  for (uint64_t at = 12; at + 8 <= bytes;) {
    const uint64_t length = u32(at), type = u32(at + 4);
    if (length > bytes - at - 8)
      fail("{}: the GLB chunk at byte {} claims {} bytes, more than the {} left in the file", path, at, length,
           bytes - at - 8);
    if (type == 0x4E4F534Au && gltf.is_null()) {  // "JSON"
      std::string text(size_t(length), '\0');
      in.seekg(std::streamoff(at + 8));
      in.read(text.data(), std::streamsize(length));
      gltf = parse_json(text, path + " (JSON chunk)");
    } else if (type == 0x004E4942u && bin == 0) {  // "BIN\0"
      bin = length;
    }
    at += 8 + length;
  }
  check_gltf_buffers(path, gltf, bin);
}

void prescan_gltf(const std::string& path) { check_gltf_buffers(path, read_json_file(path), 0); }

// --- geometry -----------------------------------------------------------------------------------

bool finite3(const glm::vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

glm::mat4 to_glm(const aiMatrix4x4& m) {
  // assimp matrices are row-major (a1..a4 is the first row); glm is column-major.
  return glm::mat4(m.a1, m.b1, m.c1, m.d1, m.a2, m.b2, m.c2, m.d2, m.a3, m.b3, m.c3, m.d3, m.a4, m.b4, m.c4, m.d4);
}

// --- textures -----------------------------------------------------------------------------------

Texture texture_from_rgba8(const std::string& name, const Rgba8Image& img) {
  Texture t;
  t.path = name;
  t.width = img.width;
  t.height = img.height;
  t.has_alpha = img.has_alpha;
  t.texels.resize(size_t(img.width) * size_t(img.height));
  std::memcpy(t.texels.data(), img.rgba.data(), t.texels.size() * 4);
  return t;
}

// An embedded (GLB) texture: either compressed bytes (mHeight == 0) decoded through
// OpenImageIO from memory, or raw BGRA texels.
Texture embedded_texture(const std::string& model, const std::string& ref, const aiTexture& tex) {
  const std::string name = model + ":" + ref;
  if (tex.mHeight == 0) {
    const std::string hint = tex.achFormatHint[0] ? std::string(tex.achFormatHint) : std::string("png");
    const Rgba8Image img =
        read_rgba8_memory(name, hint, reinterpret_cast<const uint8_t*>(tex.pcData), size_t(tex.mWidth));
    return texture_from_rgba8(name, img);
  }
  check_image_size(int(tex.mWidth), int(tex.mHeight));
  Rgba8Image img;
  img.width = int(tex.mWidth);
  img.height = int(tex.mHeight);
  img.has_alpha = true;
  img.rgba.resize(size_t(img.width) * size_t(img.height) * 4);
  for (size_t i = 0, n = size_t(img.width) * size_t(img.height); i < n; ++i) {
    const aiTexel& s = tex.pcData[i];
    img.rgba[i * 4 + 0] = s.r;
    img.rgba[i * 4 + 1] = s.g;
    img.rgba[i * 4 + 2] = s.b;
    img.rgba[i * 4 + 3] = s.a;
  }
  return texture_from_rgba8(name, img);
}

class TextureTable {
 public:
  TextureTable(const std::string& model, const aiScene& scene, std::vector<Texture>& out)
      : model_(model), scene_(scene), out_(out), folder_(fs::path(model).parent_path()) {}

  // Index of the texture a material refers to (loaded once per distinct reference).
  int get(const std::string& material, const std::string& ref) {
    if (auto it = index_.find(ref); it != index_.end()) return it->second;
    Texture t;
    if (const aiTexture* emb = scene_.GetEmbeddedTexture(ref.c_str())) {
      t = embedded_texture(model_, ref, *emb);
    } else {
      std::string rel = ref;
      std::replace(rel.begin(), rel.end(), '\\', '/');
      const fs::path p = fs::path(rel).is_absolute() ? fs::path(rel) : folder_ / rel;
      if (!fs::is_regular_file(p))
        fail("{}: material '{}': texture '{}' not found (looked for {})", model_, material, ref, p.string());
      t = load_texture(p.string());
    }
    out_.push_back(std::move(t));
    const int i = int(out_.size() - 1);
    index_[ref] = i;
    return i;
  }

 private:
  const std::string& model_;
  const aiScene& scene_;
  std::vector<Texture>& out_;
  fs::path folder_;
  std::map<std::string, int> index_;
};

// Moves the opacity map's alpha (its alpha channel, or its grey level when it has none) into
// the albedo texture's alpha. Sizes may differ: the opacity map is sampled nearest.
Texture merge_opacity(const Texture& albedo, const Texture& opacity) {
  Texture t = albedo;
  t.path = albedo.path + "+" + opacity.path;
  t.has_alpha = true;
  for (int y = 0; y < t.height; ++y) {
    const int oy = int((int64_t(y) * opacity.height) / t.height);
    for (int x = 0; x < t.width; ++x) {
      const int ox = int((int64_t(x) * opacity.width) / t.width);
      const glm::u8vec4 o = opacity.texels[size_t(oy) * size_t(opacity.width) + size_t(ox)];
      t.texels[size_t(y) * size_t(t.width) + size_t(x)].w = opacity.has_alpha ? o.w : o.x;
    }
  }
  return t;
}

Material convert_material(const std::string& model, const aiMaterial& am, TextureTable& table,
                          std::vector<Texture>& textures) {
  Material m;
  aiString name;
  if (am.Get(AI_MATKEY_NAME, name) == AI_SUCCESS) m.name = name.C_Str();
  aiColor4D base;
  aiColor3D kd;
  if (am.Get(AI_MATKEY_BASE_COLOR, base) == AI_SUCCESS) {
    m.albedo = {base.r, base.g, base.b};
  } else if (am.Get(AI_MATKEY_COLOR_DIFFUSE, kd) == AI_SUCCESS) {
    m.albedo = {kd.r, kd.g, kd.b};
  }
  if (!finite3(m.albedo)) fail("{}: material '{}': albedo is not finite", model, m.name);
  m.albedo = glm::clamp(m.albedo, glm::vec3(0.0f), glm::vec3(1.0f));
  aiString tex;
  if (am.GetTexture(aiTextureType_BASE_COLOR, 0, &tex) == AI_SUCCESS ||
      am.GetTexture(aiTextureType_DIFFUSE, 0, &tex) == AI_SUCCESS) {
    m.texture = table.get(m.name, tex.C_Str());
  }
  aiString opacity;
  if (am.GetTexture(aiTextureType_OPACITY, 0, &opacity) == AI_SUCCESS) {
    const int o = table.get(m.name, opacity.C_Str());
    if (m.texture < 0) {
      // Opacity without albedo texture: a white texture carrying the opacity.
      Texture white = textures[size_t(o)];
      for (auto& t : white.texels) t = {255, 255, 255, t.w};
      m.texture = int(textures.size());
      textures.push_back(merge_opacity(white, textures[size_t(o)]));
    } else if (std::string(opacity.C_Str()) != std::string(tex.C_Str()) || !textures[size_t(m.texture)].has_alpha) {
      const Texture merged = merge_opacity(textures[size_t(m.texture)], textures[size_t(o)]);
      m.texture = int(textures.size());
      textures.push_back(merged);
    }
    m.alpha_cutout = true;
  }
  if (m.texture >= 0 && textures[size_t(m.texture)].has_alpha) m.alpha_cutout = true;
  aiString alpha_mode;
  if (am.Get(AI_MATKEY_GLTF_ALPHAMODE, alpha_mode) == AI_SUCCESS) {
    const std::string mode = alpha_mode.C_Str();
    m.alpha_cutout = mode == "MASK" || mode == "BLEND";
    float cutoff = 0.5f;
    if (mode == "MASK" && am.Get(AI_MATKEY_GLTF_ALPHACUTOFF, cutoff) == AI_SUCCESS && std::isfinite(cutoff))
      m.alpha_threshold = std::clamp(cutoff, 0.0f, 1.0f);
  }
  m.emitter = m.name.rfind("emitter_", 0) == 0;
  return m;
}

}  // namespace

// --- public -------------------------------------------------------------------------------------

Texture load_texture(const std::string& path) { return texture_from_rgba8(path, read_rgba8(path)); }

size_t validate_mesh(Mesh& mesh, const std::string& what) {
  const size_t nv = mesh.positions.size();
  if (mesh.triangles.empty()) fail("{}: no triangles", what);
  if (nv == 0) fail("{}: no vertices", what);
  for (size_t i = 0; i < nv; ++i) {
    const glm::vec3& p = mesh.positions[i];
    if (!finite3(p) || std::abs(p.x) >= 1e18f || std::abs(p.y) >= 1e18f || std::abs(p.z) >= 1e18f)
      fail("{}: vertex {} position ({}, {}, {}) is not finite or beyond 1e18", what, i, p.x, p.y, p.z);
  }
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const glm::uvec3& t = mesh.triangles[i];
    if (t.x >= nv || t.y >= nv || t.z >= nv)
      fail("{}: triangle {} has index ({}, {}, {}) out of range (the mesh has {} vertices)", what, i, t.x, t.y, t.z,
           nv);
  }
  if (!mesh.uvs.empty()) {
    if (mesh.uvs.size() != nv) fail("{}: {} uvs for {} vertices", what, mesh.uvs.size(), nv);
    for (size_t i = 0; i < nv; ++i)
      if (!std::isfinite(mesh.uvs[i].x) || !std::isfinite(mesh.uvs[i].y)) fail("{}: uv {} is not finite", what, i);
  }
  // Normals: keep good ones; renormalise finite non-unit ones; recompute the rest from the
  // area-weighted normals of the adjacent triangles (geometry is untouched).
  const bool all_missing = mesh.normals.size() != nv;
  if (all_missing) mesh.normals.assign(nv, glm::vec3(0.0f));
  std::vector<uint8_t> bad(nv, 0);
  size_t repaired = 0;
  for (size_t i = 0; i < nv; ++i) {
    glm::vec3& n = mesh.normals[i];
    const float len = all_missing ? 0.0f : glm::length(n);
    if (std::isfinite(len) && len > 1e-12f && finite3(n)) {
      if (std::abs(len - 1.0f) > 1e-3f) {
        n /= len;
        ++repaired;
      }
    } else {
      bad[i] = 1;
    }
  }
  if (std::find(bad.begin(), bad.end(), uint8_t(1)) != bad.end()) {
    std::vector<glm::vec3> acc(nv, glm::vec3(0.0f));
    for (const auto& t : mesh.triangles) {
      const glm::vec3 g =
          glm::cross(mesh.positions[t.y] - mesh.positions[t.x], mesh.positions[t.z] - mesh.positions[t.x]);
      if (!finite3(g)) continue;
      acc[t.x] += g;
      acc[t.y] += g;
      acc[t.z] += g;
    }
    for (size_t i = 0; i < nv; ++i) {
      if (!bad[i]) continue;
      const float len = glm::length(acc[i]);
      // A vertex used only by degenerate triangles has no direction: any unit vector is as
      // good as another, since those triangles cover no area.
      mesh.normals[i] = (std::isfinite(len) && len > 0.0f) ? acc[i] / len : glm::vec3(0.0f, 1.0f, 0.0f);
      ++repaired;
    }
  }
  return repaired;
}

ImportedModel import_model(const std::string& path, const ModelLimits& limits) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) fail("{}: model file not found", path);
  const uint64_t bytes = fs::file_size(path, ec);
  if (ec) fail("{}: cannot read the file size: {}", path, ec.message());
  if (bytes == 0) fail("{}: the file is empty", path);
  if (bytes > limits.max_file_bytes)
    fail("{}: {} bytes is above the limit of {} bytes", path, bytes, limits.max_file_bytes);
  const std::string ext = lower_extension(path);
  if (ext == ".off") prescan_off(path, bytes);
  if (ext == ".ply") prescan_ply(path, bytes);
  if (ext == ".obj") prescan_obj(path);
  if (ext == ".glb") prescan_glb(path, bytes);
  if (ext == ".gltf") prescan_gltf(path);

  install_logger_once();
  std::vector<std::string> log;
  t_log_sink = &log;
  struct ResetSink {
    ~ResetSink() { t_log_sink = nullptr; }
  } reset_sink;

  Assimp::Importer importer;
  // GenSmoothNormals only adds normals where a mesh has none (it never changes positions);
  // 80 degrees keeps hard edges hard. FindInvalidData / FixInfacingNormals are deliberately
  // not used: they change data silently.
  importer.SetPropertyFloat(AI_CONFIG_PP_GSN_MAX_SMOOTHING_ANGLE, 80.0f);
  const unsigned flags = aiProcess_Triangulate | aiProcess_JoinIdenticalVertices | aiProcess_ValidateDataStructure |
                         aiProcess_GenSmoothNormals;
  const aiScene* scene = nullptr;
  try {
    scene = importer.ReadFile(path, flags);
  } catch (const std::exception& e) {
    fail("{}: the importer failed: {}", path, e.what());
  }
  if (!scene) fail("{}: {}", path, importer.GetErrorString());
  if (!log.empty()) fail("{}: broken model (the importer reports: {})", path, log.front());
  if (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE) fail("{}: the importer marked the scene incomplete", path);
  if (!scene->mRootNode) fail("{}: no root node", path);

  // Walk the node tree (bounded depth and count) to find every mesh instance and its world
  // transform, counting sizes before allocating anything.
  struct Instance {
    unsigned mesh;
    glm::mat4 world;
    std::string node;
  };
  std::vector<Instance> instances;
  size_t total_tris = 0, total_verts = 0;
  struct Pending {
    const aiNode* node;
    glm::mat4 parent;
    int depth;
  };
  std::vector<Pending> stack{{scene->mRootNode, glm::mat4(1.0f), 0}};
  size_t visited = 0;
  while (!stack.empty()) {
    const Pending p = stack.back();
    stack.pop_back();
    if (p.depth > limits.max_node_depth)
      fail("{}: node hierarchy deeper than {} (recursive nodes?)", path, limits.max_node_depth);
    if (++visited > limits.max_objects) fail("{}: more than {} nodes", path, limits.max_objects);
    const glm::mat4 world = p.parent * to_glm(p.node->mTransformation);
    for (unsigned k = 0; k < p.node->mNumMeshes; ++k) {
      const unsigned mi = p.node->mMeshes[k];
      if (mi >= scene->mNumMeshes)
        fail("{}: node '{}' refers to mesh {} of {}", path, p.node->mName.C_Str(), mi, scene->mNumMeshes);
      const aiMesh* am = scene->mMeshes[mi];
      if (!(am->mPrimitiveTypes & aiPrimitiveType_TRIANGLE) && am->mNumFaces > 0 &&
          (am->mPrimitiveTypes & (aiPrimitiveType_POINT | aiPrimitiveType_LINE)))
        continue;  // a point or line set: nothing to render
      total_tris += am->mNumFaces;
      total_verts += am->mNumVertices;
      if (total_tris > limits.max_triangles) fail("{}: more than {} triangles", path, limits.max_triangles);
      if (total_verts > limits.max_vertices) fail("{}: more than {} vertices", path, limits.max_vertices);
      if (instances.size() >= limits.max_objects) fail("{}: more than {} mesh instances", path, limits.max_objects);
      instances.push_back({mi, world, p.node->mName.C_Str()});
    }
    for (unsigned c = 0; c < p.node->mNumChildren; ++c) {
      if (!p.node->mChildren[c]) fail("{}: node '{}' has a null child", path, p.node->mName.C_Str());
      stack.push_back({p.node->mChildren[c], world, p.depth + 1});
    }
  }
  if (instances.empty()) fail("{}: no triangle meshes in the scene", path);

  ImportedModel out;
  TextureTable table(path, *scene, out.textures);
  std::vector<int> material_index(scene->mNumMaterials, -1);
  // Instances come off the stack in reverse; restore file order for stable object ids.
  std::reverse(instances.begin(), instances.end());
  std::stable_sort(instances.begin(), instances.end(),
                   [](const Instance& a, const Instance& b) { return a.mesh < b.mesh; });
  out.objects.reserve(instances.size());
  for (const Instance& inst : instances) {
    const aiMesh& am = *scene->mMeshes[inst.mesh];
    const std::string what = fmt::format("{}: mesh {} '{}'", path, inst.mesh, am.mName.C_Str());
    if (!am.mVertices || am.mNumVertices == 0) fail("{}: no vertices", what);
    const glm::mat4& w = inst.world;
    const glm::mat3 w3(w);
    const float det = glm::determinant(w3);
    if (!std::isfinite(det) || std::abs(det) < 1e-30f)
      fail("{}: node '{}' transform is singular or not finite", what, inst.node);
    const glm::mat3 normal_matrix = glm::transpose(glm::inverse(w3));

    Object obj;
    obj.name = am.mName.length > 0 ? am.mName.C_Str() : inst.node;
    Mesh& m = obj.mesh;
    m.positions.resize(am.mNumVertices);
    for (unsigned i = 0; i < am.mNumVertices; ++i) {
      const aiVector3D& v = am.mVertices[i];
      const glm::vec3 p(v.x, v.y, v.z);
      // Check before transforming: a huge coordinate must be reported, not turned into inf.
      if (!finite3(p) || std::abs(p.x) >= 1e18f || std::abs(p.y) >= 1e18f || std::abs(p.z) >= 1e18f)
        fail("{}: vertex {} position ({}, {}, {}) is not finite or beyond 1e18", what, i, p.x, p.y, p.z);
      m.positions[i] = glm::vec3(w * glm::vec4(p, 1.0f));
    }
    if (am.mNormals) {
      m.normals.resize(am.mNumVertices);
      for (unsigned i = 0; i < am.mNumVertices; ++i) {
        const aiVector3D& n = am.mNormals[i];
        const glm::vec3 t = normal_matrix * glm::vec3(n.x, n.y, n.z);
        const float len = glm::length(t);
        // Keep bad normals bad (zero) so that validate_mesh recomputes them.
        m.normals[i] = (std::isfinite(len) && len > 1e-12f) ? t / len : glm::vec3(0.0f);
        if (!(std::isfinite(n.x) && std::isfinite(n.y) && std::isfinite(n.z))) m.normals[i] = glm::vec3(0.0f);
      }
    }
    if (am.mTextureCoords[0]) {
      m.uvs.resize(am.mNumVertices);
      for (unsigned i = 0; i < am.mNumVertices; ++i) m.uvs[i] = {am.mTextureCoords[0][i].x, am.mTextureCoords[0][i].y};
    }
    m.triangles.reserve(am.mNumFaces);
    const bool mirror = det < 0.0f;  // a mirroring transform reverses the winding
    for (unsigned f = 0; f < am.mNumFaces; ++f) {
      const aiFace& face = am.mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines
      glm::uvec3 t(face.mIndices[0], face.mIndices[1], face.mIndices[2]);
      if (mirror) std::swap(t.y, t.z);
      m.triangles.push_back(t);
    }
    // Before the validation repairs normals: normals that came in bad (zero after the checks
    // above) are counted by validate_mesh.
    out.normals_repaired += validate_mesh(m, what);

    if (am.mMaterialIndex >= scene->mNumMaterials) fail("{}: material index {} out of range", what, am.mMaterialIndex);
    int& mi = material_index[am.mMaterialIndex];
    if (mi < 0) {
      out.materials.push_back(convert_material(path, *scene->mMaterials[am.mMaterialIndex], table, out.textures));
      mi = int(out.materials.size() - 1);
    }
    obj.material = uint32_t(mi);
    out.objects.push_back(std::move(obj));
  }
  return out;
}

}  // namespace dhr
