// Server-side pose prediction's extrapolation (core/buffers/camera.h, extrapolate_pose): a
// camera moving and turning at constant velocity is predicted where it will be.
#include "core/buffers/camera.h"

#include <glm/gtc/constants.hpp>
#include <glm/gtc/quaternion.hpp>
#include <gtest/gtest.h>

#include <cmath>

namespace dhr {
namespace {

// A camera at time t on a path that moves at 2 m/s along x and turns about a tilted axis at
// 0.8 rad/s, starting from a view with a roll-free up.
Camera on_path(double t) {
  const Camera start = Camera::look_at({0, 1.5f, 4}, {0.3f, 1.2f, 0}, {0, 1, 0}, 60, 64, 36, 0.05f, 100);
  const glm::dvec3 axis = glm::normalize(glm::dvec3(0.2, 1.0, 0.1));
  const glm::dquat turn = glm::angleAxis(0.8 * t, axis);
  Camera c = start;
  c.position = start.position + glm::vec3(float(2.0 * t), 0, 0);
  c.forward = glm::vec3(turn * glm::dvec3(start.forward));
  c.up = glm::vec3(turn * glm::dvec3(start.up));
  return c;
}

void expect_near(const glm::vec3& a, const glm::vec3& b, float tol, const char* what) {
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(a[i], b[i], tol) << what << " [" << i << "]";
}

TEST(Camera, ExtrapolatedPoseFollowsAConstantVelocity) {
  const Camera a = on_path(1.0), b = on_path(1.05);
  for (double ahead : {0.0, 0.016, 0.1, 0.25}) {
    const Camera want = on_path(1.05 + ahead), got = extrapolate_pose(a, 1.0, b, 1.05, 1.05 + ahead);
    expect_near(got.position, want.position, 1e-5f, "position");
    expect_near(got.forward, want.forward, 1e-5f, "forward");
    expect_near(got.up, want.up, 1e-5f, "up");
    EXPECT_NEAR(glm::dot(got.forward, got.up), 0.0f, 1e-6f);
    EXPECT_NEAR(glm::length(got.forward), 1.0f, 1e-6f);
  }
}

TEST(Camera, ExtrapolationWithoutAStepKeepsTheNewestPose) {
  const Camera a = on_path(1.0), b = on_path(1.05);
  const Camera same = extrapolate_pose(b, 1.05, b, 1.05, 1.2);  // no time between the poses
  EXPECT_EQ(same.position, b.position);
  EXPECT_EQ(same.forward, b.forward);
  const Camera still = extrapolate_pose(b, 1.0, b, 1.05, 1.2);  // no motion
  expect_near(still.position, b.position, 0.0f, "position");
  expect_near(still.forward, b.forward, 0.0f, "forward");
  const Camera now = extrapolate_pose(a, 1.0, b, 1.05, 1.05);  // no lead
  EXPECT_EQ(now.forward, b.forward);
  EXPECT_EQ(now.position, b.position);
}

}  // namespace
}  // namespace dhr
