// Procedural meshes (see core/scene/shapes.h). Winding is made consistent at the end by
// orient_outward(): every triangle is turned so that its geometric normal agrees with the
// sum of its vertex normals, which for these convex shapes point outward by construction.
#include "core/scene/shapes.h"

#include "core/base/error.h"

#include <glm/gtc/constants.hpp>

#include <cmath>

namespace dhr {

namespace {

constexpr int kMaxSegments = 4096;

void check_extent(const char* what, float v) {
  if (!(std::isfinite(v) && v > 0.0f)) fail("{}: {} must be finite and > 0", what, v);
}

void orient_outward(Mesh& m) {
  for (auto& t : m.triangles) {
    const glm::vec3 g = glm::cross(m.positions[t.y] - m.positions[t.x], m.positions[t.z] - m.positions[t.x]);
    const glm::vec3 n = m.normals[t.x] + m.normals[t.y] + m.normals[t.z];
    if (glm::dot(g, n) < 0.0f) std::swap(t.y, t.z);
  }
}

uint32_t add_vertex(Mesh& m, glm::vec3 p, glm::vec3 n, glm::vec2 uv) {
  m.positions.push_back(p);
  m.normals.push_back(n);
  m.uvs.push_back(uv);
  return uint32_t(m.positions.size() - 1);
}

}  // namespace

Mesh make_box(glm::vec3 size_m) {
  check_extent("make_box: size x", size_m.x);
  check_extent("make_box: size y", size_m.y);
  check_extent("make_box: size z", size_m.z);
  const glm::vec3 h = size_m * 0.5f;
  struct Face {
    glm::vec3 n, u, v;  // cross(u, v) == n
  };
  const Face faces[6] = {
      {{1, 0, 0}, {0, 0, -1}, {0, 1, 0}}, {{-1, 0, 0}, {0, 0, 1}, {0, 1, 0}}, {{0, 1, 0}, {1, 0, 0}, {0, 0, -1}},
      {{0, -1, 0}, {1, 0, 0}, {0, 0, 1}}, {{0, 0, 1}, {1, 0, 0}, {0, 1, 0}},  {{0, 0, -1}, {-1, 0, 0}, {0, 1, 0}},
  };
  Mesh m;
  for (const Face& f : faces) {
    const glm::vec3 c = f.n * h;
    const glm::vec3 du = f.u * h;
    const glm::vec3 dv = f.v * h;
    const uint32_t a = add_vertex(m, c - du - dv, f.n, {0, 0});
    add_vertex(m, c + du - dv, f.n, {1, 0});
    add_vertex(m, c + du + dv, f.n, {1, 1});
    add_vertex(m, c - du + dv, f.n, {0, 1});
    m.triangles.push_back({a, a + 1, a + 2});
    m.triangles.push_back({a, a + 2, a + 3});
  }
  return m;
}

Mesh make_sphere(float radius_m, int segments, int rings) {
  check_extent("make_sphere: radius", radius_m);
  if (segments < 3 || segments > kMaxSegments)
    fail("make_sphere: segments {} must be in [3, {}]", segments, kMaxSegments);
  if (rings < 2 || rings > kMaxSegments) fail("make_sphere: rings {} must be in [2, {}]", rings, kMaxSegments);
  Mesh m;
  const float pi = glm::pi<float>();
  for (int i = 0; i <= rings; ++i) {
    const float theta = pi * float(i) / float(rings);  // 0 at +y
    for (int j = 0; j <= segments; ++j) {
      const float phi = 2.0f * pi * float(j) / float(segments);
      const glm::vec3 n(std::sin(theta) * std::sin(phi), std::cos(theta), std::sin(theta) * std::cos(phi));
      add_vertex(m, n * radius_m, n, {float(j) / float(segments), 1.0f - float(i) / float(rings)});
    }
  }
  const uint32_t row = uint32_t(segments + 1);
  for (int i = 0; i < rings; ++i) {
    for (int j = 0; j < segments; ++j) {
      const uint32_t a = uint32_t(i) * row + uint32_t(j), b = a + 1, c = a + row, d = c + 1;
      if (i != 0) m.triangles.push_back({a, b, c});          // skip the degenerate top fan half
      if (i != rings - 1) m.triangles.push_back({b, d, c});  // and the bottom one
    }
  }
  orient_outward(m);
  return m;
}

Mesh make_plane(float size_x_m, float size_z_m) {
  check_extent("make_plane: size_x", size_x_m);
  check_extent("make_plane: size_z", size_z_m);
  const float hx = size_x_m * 0.5f, hz = size_z_m * 0.5f;
  const glm::vec3 n(0, 1, 0);
  Mesh m;
  add_vertex(m, {-hx, 0, hz}, n, {0, 0});
  add_vertex(m, {hx, 0, hz}, n, {1, 0});
  add_vertex(m, {hx, 0, -hz}, n, {1, 1});
  add_vertex(m, {-hx, 0, -hz}, n, {0, 1});
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  return m;
}

Mesh make_cylinder(float radius_m, float height_m, int segments, bool caps) {
  check_extent("make_cylinder: radius", radius_m);
  check_extent("make_cylinder: height", height_m);
  if (segments < 3 || segments > kMaxSegments)
    fail("make_cylinder: segments {} must be in [3, {}]", segments, kMaxSegments);
  const float h = height_m * 0.5f;
  const float pi = glm::pi<float>();
  Mesh m;
  for (int j = 0; j <= segments; ++j) {
    const float phi = 2.0f * pi * float(j) / float(segments);
    const glm::vec3 n(std::sin(phi), 0.0f, std::cos(phi));
    const float u = float(j) / float(segments);
    const uint32_t a = add_vertex(m, n * radius_m + glm::vec3(0, -h, 0), n, {u, 0});
    add_vertex(m, n * radius_m + glm::vec3(0, h, 0), n, {u, 1});
    if (j > 0) {
      const uint32_t pa = a - 2, pb = a - 1, b = a + 1;
      m.triangles.push_back({pa, a, b});
      m.triangles.push_back({pa, b, pb});
    }
  }
  if (caps) {
    for (int side = 0; side < 2; ++side) {
      const float y = side == 0 ? h : -h;
      const glm::vec3 n(0, side == 0 ? 1.0f : -1.0f, 0);
      const uint32_t centre = add_vertex(m, {0, y, 0}, n, {0.5f, 0.5f});
      for (int j = 0; j <= segments; ++j) {
        const float phi = 2.0f * pi * float(j) / float(segments);
        const float s = std::sin(phi), c = std::cos(phi);
        const uint32_t v = add_vertex(m, {s * radius_m, y, c * radius_m}, n, {0.5f + 0.5f * s, 0.5f + 0.5f * c});
        if (j > 0) m.triangles.push_back({centre, v - 1, v});
      }
    }
  }
  orient_outward(m);
  return m;
}

}  // namespace dhr
