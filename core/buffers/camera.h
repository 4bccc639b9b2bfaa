// A pinhole camera. Right-handed world, y up; the camera looks down its -z axis (GLM's
// convention). Pixel (0, 0) is the top-left; pixel centres are at (x + 0.5, y + 0.5).
// Linear view depth is the distance along the viewing direction, positive in front.
#pragma once

#include <glm/glm.hpp>

namespace dhr {

struct Ray {
  glm::vec3 origin{0.0f};
  glm::vec3 direction{0.0f, 0.0f, -1.0f};  // unit length
};

struct Camera {
  glm::vec3 position{0.0f};
  glm::vec3 forward{0.0f, 0.0f, -1.0f};  // unit
  glm::vec3 up{0.0f, 1.0f, 0.0f};        // unit, orthogonal to forward
  float vfov_deg = 60.0f;
  float near_m = 0.05f;
  float far_m = 1000.0f;
  int width = 1280;
  int height = 720;

  // Throws dhr::Error when position is not finite, target equals position, fov is outside
  // (0, 180), or near/far are not 0 < near < far.
  static Camera look_at(const glm::vec3& position, const glm::vec3& target, const glm::vec3& up, float vfov_deg,
                        int width, int height, float near_m, float far_m);

  glm::vec3 right() const { return glm::normalize(glm::cross(forward, up)); }
  float aspect() const { return float(width) / float(height); }
  glm::mat4 view() const;
  glm::mat4 projection() const;  // OpenGL clip space: NDC z in [-1, 1]
  glm::mat4 view_projection() const { return projection() * view(); }

  // The ray through image point (px, py) in pixel units (pixel centre = x + 0.5).
  Ray primary_ray(float px, float py) const;
  // Linear view depth of a world point (positive in front of the camera).
  float view_depth(const glm::vec3& world) const { return glm::dot(world - position, forward); }
  // Image point (pixel units) of a world point in front of the camera; z = view depth.
  glm::vec3 project(const glm::vec3& world) const;
};

// Server-side pose prediction (the server renders for where the head will be, as CloudXR
// does): the pose at time `t` extrapolated from two received poses, `a` at `ta` and `b` at `tb`
// (ta < tb), at their constant velocity: the position along a straight line, the orientation by
// the rotation from a to b about its axis, scaled by (t - tb) / (tb - ta). Field of view, clip
// planes and size are b's. Returns b when t == tb, or when tb <= ta (nothing to extrapolate from).
Camera extrapolate_pose(const Camera& a, double ta, const Camera& b, double tb, double t);

}  // namespace dhr
