// Helpers shared by the tests: where the repository and the real scenes are.
#pragma once

#include "core/scene.h"

#include <string>

namespace dhr::test {

// The repository root (tests run from the build tree).
std::string source_dir();
// ../shared/scenes beside the checkout, or $DHR_SCENE_PATH's first entry when set.
std::string shared_scenes_dir();

// A static scene object with id `id`: `mesh` moved by `offset` (world space), with `material`.
Object make_object(uint32_t id, Mesh mesh, glm::vec3 offset, uint32_t material = 0);

}  // namespace dhr::test
