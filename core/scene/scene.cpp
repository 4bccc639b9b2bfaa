// Member functions of the scene model (core/scene/scene.h): keyframe animation of moving objects,
// the camera path, and texture lookup.
#include "core/scene/scene.h"

#include "core/base/error.h"

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>

#include <algorithm>
#include <array>
#include <cmath>

namespace dhr {

namespace {

// Maps a time onto the key range: wrapped into [t0, t1) when looping, clamped otherwise.
double key_time(double time_s, double t0, double t1, bool loop) {
  if (!std::isfinite(time_s)) fail("animation: time {} is not finite", time_s);
  const double span = t1 - t0;
  if (!(span > 0.0)) return t0;
  if (loop) {
    double r = std::fmod(time_s - t0, span);
    if (r < 0.0) r += span;
    return t0 + r;
  }
  return std::clamp(time_s, t0, t1);
}

// Index i of the segment [keys[i], keys[i+1]] holding t (keys sorted, t inside the range).
template <class Key>
size_t segment_of(const std::vector<Key>& keys, double t) {
  const auto it = std::upper_bound(keys.begin(), keys.end(), t, [](double v, const Key& k) { return v < k.time_s; });
  size_t i = size_t(it - keys.begin());
  i = i == 0 ? 0 : i - 1;
  return std::min(i, keys.size() - 2);
}

glm::mat4 compose(const glm::vec3& t, const glm::quat& r, const glm::vec3& s) {
  return glm::translate(glm::mat4(1.0f), t) * glm::mat4_cast(r) * glm::scale(glm::mat4(1.0f), s);
}

// One centripetal Catmull-Rom segment between p1 and p2 (Barry-Goldman pyramidal
// formulation), u in [0, 1]. Centripetal parameterisation (alpha = 0.5) avoids cusps and
// self-intersections when keys are unevenly spaced.
glm::vec3 catmull_rom(const glm::vec3& p0, const glm::vec3& p1, const glm::vec3& p2, const glm::vec3& p3, float u) {
  auto knot = [](const glm::vec3& a, const glm::vec3& b) { return std::max(std::sqrt(glm::length(b - a)), 1e-4f); };
  const float t0 = 0.0f;
  const float t1 = t0 + knot(p0, p1);
  const float t2 = t1 + knot(p1, p2);
  const float t3 = t2 + knot(p2, p3);
  const float t = t1 + (t2 - t1) * u;
  const glm::vec3 a1 = ((t1 - t) * p0 + (t - t0) * p1) / (t1 - t0);
  const glm::vec3 a2 = ((t2 - t) * p1 + (t - t1) * p2) / (t2 - t1);
  const glm::vec3 a3 = ((t3 - t) * p2 + (t - t2) * p3) / (t3 - t2);
  const glm::vec3 b1 = ((t2 - t) * a1 + (t - t0) * a2) / (t2 - t0);
  const glm::vec3 b2 = ((t3 - t) * a2 + (t - t1) * a3) / (t3 - t1);
  return ((t2 - t) * b1 + (t - t1) * b2) / (t2 - t1);
}

float srgb_to_linear(float c) { return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f); }

// Alpha of an 8-bit texel, float(i) / 255.0f: looked up instead of divided per fetch.
const std::array<float, 256>& alpha_table() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int i = 0; i < 256; ++i) t[size_t(i)] = float(i) / 255.0f;
    return t;
  }();
  return table;
}

}  // namespace

const std::array<float, 256>& srgb_table() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int i = 0; i < 256; ++i) t[size_t(i)] = srgb_to_linear(float(i) / 255.0f);
    return t;
  }();
  return table;
}

glm::mat4 Animation::at(double time_s) const {
  if (keys.empty()) fail("animation: no keys");
  if (keys.size() == 1) return compose(keys[0].translation, keys[0].rotation, keys[0].scale);
  const double t = key_time(time_s, keys.front().time_s, keys.back().time_s, loop);
  const size_t i = segment_of(keys, t);
  const TransformKey& a = keys[i];
  const TransformKey& b = keys[i + 1];
  const double span = b.time_s - a.time_s;
  const float u = span > 0.0 ? float(std::clamp((t - a.time_s) / span, 0.0, 1.0)) : 1.0f;
  // glm::slerp takes the short way round (it flips the sign of b when the dot is negative).
  return compose(glm::mix(a.translation, b.translation, u), glm::slerp(a.rotation, b.rotation, u),
                 glm::mix(a.scale, b.scale, u));
}

Camera CameraPath::at(double time_s, int width, int height) const {
  if (keys.empty()) fail("camera path: no keys");
  const size_t n = keys.size();
  if (n == 1) return Camera::look_at(keys[0].position, keys[0].target, up, vfov_deg, width, height, near_m, far_m);
  const double t = key_time(time_s, keys.front().time_s, keys.back().time_s, loop);
  const size_t i = segment_of(keys, t);
  const double span = keys[i + 1].time_s - keys[i].time_s;
  const float u = span > 0.0 ? float(std::clamp((t - keys[i].time_s) / span, 0.0, 1.0)) : 1.0f;
  // Neighbours of the segment: a looping path whose last key repeats the first (the usual
  // way to close a loop) wraps around skipping the duplicate; an open path mirrors its end
  // points so that the curve still passes through them with a sensible tangent.
  const bool closed = loop && n >= 3 && glm::length(keys.front().position - keys.back().position) < 1e-5f &&
                      glm::length(keys.front().target - keys.back().target) < 1e-5f;
  auto neighbour = [&](long j, bool target) -> glm::vec3 {
    const long ln = long(n);
    if (closed) {
      const long m = ln - 1;  // distinct keys
      j = ((j % m) + m) % m;
    } else if (j < 0 || j >= ln) {
      const long inside = j < 0 ? 0 : ln - 1;
      const long next = j < 0 ? 1 : ln - 2;
      const glm::vec3 e = target ? keys[size_t(inside)].target : keys[size_t(inside)].position;
      const glm::vec3 f = target ? keys[size_t(next)].target : keys[size_t(next)].position;
      return 2.0f * e - f;
    }
    return target ? keys[size_t(j)].target : keys[size_t(j)].position;
  };
  const long li = long(i);
  const glm::vec3 pos = catmull_rom(neighbour(li - 1, false), neighbour(li, false), neighbour(li + 1, false),
                                    neighbour(li + 2, false), u);
  glm::vec3 tgt =
      catmull_rom(neighbour(li - 1, true), neighbour(li, true), neighbour(li + 1, true), neighbour(li + 2, true), u);
  if (glm::length(tgt - pos) < 1e-6f) tgt = pos + (keys[i + 1].target - keys[i + 1].position);
  return Camera::look_at(pos, tgt, up, vfov_deg, width, height, near_m, far_m);
}

glm::vec4 Texture::sample_bilinear(glm::vec2 uv) const {
  if (width <= 0 || height <= 0 || texels.size() != size_t(width) * size_t(height))
    fail("texture {}: empty or inconsistent ({}x{}, {} texels)", path, width, height, texels.size());
  if (!std::isfinite(uv.x) || !std::isfinite(uv.y)) return glm::vec4(0.0f, 0.0f, 0.0f, 1.0f);
  // Texel centres sit at (i + 0.5) / width; v is flipped because row 0 is the top.
  const float x = (uv.x - std::floor(uv.x)) * float(width) - 0.5f;
  const float y = (1.0f - (uv.y - std::floor(uv.y))) * float(height) - 0.5f;
  const float fx = std::floor(x), fy = std::floor(y);
  const float wx = x - fx, wy = y - fy;
  // x and y lie in [-0.5, size - 0.5): v is almost always within one size of the range, where
  // the two modulos (integer divisions) are not needed; same result.
  auto wrap = [](long v, int size) {
    if (v >= 0 && v < size) return int(v);
    if (v < 0 && v >= -long(size)) return int(v + size);
    if (v >= size && v < 2 * long(size)) return int(v - size);
    return int(((v % size) + size) % size);
  };
  const int x0 = wrap(long(fx), width), x1 = wrap(long(fx) + 1, width);
  const int y0 = wrap(long(fy), height), y1 = wrap(long(fy) + 1, height);
  const auto& lut = srgb_table();
  const auto& alpha = alpha_table();
  auto fetch = [&](int xi, int yi) {
    const glm::u8vec4 t = texels[size_t(yi) * size_t(width) + size_t(xi)];
    return glm::vec4(lut[t.x], lut[t.y], lut[t.z], alpha[t.w]);
  };
  return glm::mix(glm::mix(fetch(x0, y0), fetch(x1, y0), wx), glm::mix(fetch(x0, y1), fetch(x1, y1), wx), wy);
}

}  // namespace dhr
