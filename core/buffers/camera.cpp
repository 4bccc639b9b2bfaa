#include "core/buffers/camera.h"

#include "core/base/error.h"

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>

#include <algorithm>
#include <cmath>

namespace dhr {

namespace {
bool finite(const glm::vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }
}  // namespace

Camera Camera::look_at(const glm::vec3& position, const glm::vec3& target, const glm::vec3& up, float vfov_deg,
                       int width, int height, float near_m, float far_m) {
  if (!finite(position) || !finite(target) || !finite(up)) fail("camera: position, target and up must be finite");
  if (!(vfov_deg > 0.0f && vfov_deg < 180.0f)) fail("camera: vfov_deg {} is out of range (0, 180)", vfov_deg);
  if (!(near_m > 0.0f && far_m > near_m && std::isfinite(far_m)))
    fail("camera: need 0 < near_m < far_m (finite), got near_m {} far_m {}", near_m, far_m);
  if (width <= 0 || height <= 0) fail("camera: resolution {}x{} must be positive", width, height);
  const glm::vec3 d = target - position;
  const float len = glm::length(d);
  if (!(len > 0.0f)) fail("camera: target equals position");
  Camera c;
  c.position = position;
  c.forward = d / len;
  glm::vec3 r = glm::cross(c.forward, up);
  if (glm::length(r) < 1e-6f) {  // looking along up: pick any perpendicular
    r = glm::cross(c.forward, std::abs(c.forward.y) < 0.9f ? glm::vec3(0, 1, 0) : glm::vec3(1, 0, 0));
  }
  r = glm::normalize(r);
  c.up = glm::normalize(glm::cross(r, c.forward));
  c.vfov_deg = vfov_deg;
  c.width = width;
  c.height = height;
  c.near_m = near_m;
  c.far_m = far_m;
  return c;
}

glm::mat4 Camera::view() const { return glm::lookAt(position, position + forward, up); }

glm::mat4 Camera::projection() const { return glm::perspective(glm::radians(vfov_deg), aspect(), near_m, far_m); }

Ray Camera::primary_ray(float px, float py) const {
  const float tan_half = std::tan(glm::radians(vfov_deg) * 0.5f);
  const float sx = (2.0f * px / float(width) - 1.0f) * tan_half * aspect();
  const float sy = (1.0f - 2.0f * py / float(height)) * tan_half;
  return {position, glm::normalize(forward + sx * right() + sy * up)};
}

glm::vec3 Camera::project(const glm::vec3& world) const {
  const glm::vec3 d = world - position;
  const float z = glm::dot(d, forward);
  const float tan_half = std::tan(glm::radians(vfov_deg) * 0.5f);
  const float sx = glm::dot(d, right()) / (z * tan_half * aspect());
  const float sy = glm::dot(d, up) / (z * tan_half);
  return {(sx + 1.0f) * 0.5f * float(width), (1.0f - sy) * 0.5f * float(height), z};
}

Camera extrapolate_pose(const Camera& a, double ta, const Camera& b, double tb, double t) {
  if (!(tb > ta) || t == tb) return b;
  const double s = (t - tb) / (tb - ta);
  Camera out = b;
  out.position = glm::vec3(glm::dvec3(b.position) + (glm::dvec3(b.position) - glm::dvec3(a.position)) * s);
  // The orientations as rotations of the camera's frame (right, up, -forward); the step a -> b
  // as a quaternion, its angle scaled by s.
  auto frame_of = [](const Camera& c) {
    const glm::dvec3 f(c.forward), u(c.up);
    return glm::dmat3(glm::normalize(glm::cross(f, u)), u, -f);
  };
  const glm::dquat qa = glm::quat_cast(frame_of(a)), qb = glm::quat_cast(frame_of(b));
  glm::dquat step = qb * glm::conjugate(qa);
  if (step.w < 0.0) step = -step;  // the short way round
  const double angle = 2.0 * std::acos(std::clamp(step.w, -1.0, 1.0));
  const glm::dvec3 v(step.x, step.y, step.z);
  const double len = glm::length(v);
  if (angle > 0.0 && len > 0.0) {
    const glm::dquat ahead = glm::angleAxis(angle * s, v / len);
    out.forward = glm::vec3(glm::normalize(ahead * glm::dvec3(b.forward)));
    const glm::dvec3 up = ahead * glm::dvec3(b.up);
    // Orthogonal to forward again (rounding).
    out.up = glm::vec3(glm::normalize(up - glm::dot(up, glm::dvec3(out.forward)) * glm::dvec3(out.forward)));
  }
  return out;
}

}  // namespace dhr
