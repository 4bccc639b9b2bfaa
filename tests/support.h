// Helpers shared by the tests: where the repository and the real scenes are.
#pragma once

#include "core/scene.h"

#include <functional>
#include <string>

namespace dhr::test {

// The repository root (tests run from the build tree).
std::string source_dir();
// ../shared/scenes beside the checkout, or $DHR_SCENE_PATH's first entry when set.
std::string shared_scenes_dir();

// A static scene object with id `id`: `mesh` moved by `offset` (world space), with `material`.
Object make_object(uint32_t id, Mesh mesh, glm::vec3 offset, uint32_t material = 0);

// A sphere light at `p` (radius 0: a point light) and a distant light shining along `dir`
// (angular radius 0: hard), as the trace tests build them.
Light sphere_light(glm::vec3 p, float radius_m, float intensity);
Light distant_light(glm::vec3 dir, float angular_radius_deg = 0.0f);

// The message of the dhr::Error that `f` throws; "" when it throws none.
std::string error_of(const std::function<void()>& f);

}  // namespace dhr::test
