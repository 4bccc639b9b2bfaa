#include "core/buffers/visualize.h"

#include "core/base/rng.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace dhr {

uint8_t linear_to_srgb8(float v) {
  if (!(v > 0.0f)) return 0;  // also maps NaN to 0
  if (v >= 1.0f) return 255;
  const float s = v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
  return uint8_t(std::lround(s * 255.0f));
}

ImageU8 visualize_depth(const ImageF& depth) {
  ImageU8 out(depth.width(), depth.height(), 0);
  std::vector<float> logs;
  logs.reserve(depth.size());
  for (float d : depth.pixels())
    if (std::isfinite(d) && d > 0.0f) logs.push_back(std::log(d));
  if (logs.empty()) return out;
  std::sort(logs.begin(), logs.end());
  const float lo = logs[logs.size() / 100];
  const float hi = logs[logs.size() - 1 - logs.size() / 100];
  const float range = std::max(hi - lo, 1e-6f);
  for (size_t i = 0; i < depth.size(); ++i) {
    const float d = depth[i];
    if (!(std::isfinite(d) && d > 0.0f)) continue;
    const float t = std::clamp((std::log(d) - lo) / range, 0.0f, 1.0f);
    out[i] = uint8_t(std::lround(255.0f - 235.0f * t));  // far stays distinguishable from background
  }
  return out;
}

ImageRGB8 visualize_normals(const ImageVec3& normal, const ImageU32& object_id) {
  ImageRGB8 out(normal.width(), normal.height());
  auto to8 = [](float c) { return uint8_t(std::lround(std::clamp((c * 0.5f + 0.5f), 0.0f, 1.0f) * 255.0f)); };
  for (size_t i = 0; i < normal.size(); ++i) {
    if (object_id[i] == kBackgroundId) continue;
    const glm::vec3 n = normal[i];
    out[i] = {to8(n.x), to8(n.y), to8(n.z)};
  }
  return out;
}

ImageRGB8 visualize_albedo(const ImageVec3& albedo) {
  ImageRGB8 out(albedo.width(), albedo.height());
  for (size_t i = 0; i < albedo.size(); ++i)
    out[i] = {linear_to_srgb8(albedo[i].x), linear_to_srgb8(albedo[i].y), linear_to_srgb8(albedo[i].z)};
  return out;
}

ImageRGB8 visualize_ids(const ImageU32& id) {
  ImageRGB8 out(id.width(), id.height());
  for (size_t i = 0; i < id.size(); ++i) {
    if (id[i] == kBackgroundId) continue;
    const uint64_t h = mix64(id[i]);
    out[i] = {uint8_t(64 + (h & 191)), uint8_t(64 + ((h >> 8) & 191)), uint8_t(64 + ((h >> 16) & 191))};
  }
  return out;
}

ImageRGB8 visualize_motion(const ImageVec2& motion, float max_px) {
  ImageRGB8 out(motion.width(), motion.height());
  for (size_t i = 0; i < motion.size(); ++i) {
    const glm::vec2 m = motion[i];
    const float mag = std::sqrt(m.x * m.x + m.y * m.y);
    if (!(mag > 1e-4f) || !std::isfinite(mag)) continue;
    const float v = std::min(mag / max_px, 1.0f);
    const float hue = (std::atan2(m.y, m.x) / 6.2831853f + 0.5f) * 6.0f;  // 0..6
    const float f = hue - std::floor(hue);
    const int sector = int(hue) % 6;
    float r = 0, g = 0, b = 0;
    switch (sector) {
      case 0:
        r = 1;
        g = f;
        break;
      case 1:
        r = 1 - f;
        g = 1;
        break;
      case 2:
        g = 1;
        b = f;
        break;
      case 3:
        g = 1 - f;
        b = 1;
        break;
      case 4:
        r = f;
        b = 1;
        break;
      default:
        r = 1;
        b = 1 - f;
        break;
    }
    out[i] = {uint8_t(r * v * 255), uint8_t(g * v * 255), uint8_t(b * v * 255)};
  }
  return out;
}

}  // namespace dhr
