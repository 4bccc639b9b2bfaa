// Helpers shared by the tests: where the repository and the real scenes are.
#pragma once

#include <string>

namespace dhr::test {

// The repository root (tests run from the build tree).
std::string source_dir();
// ../shared/scenes beside the checkout, or $DHR_SCENE_PATH's first entry when set.
std::string shared_scenes_dir();

}  // namespace dhr::test
