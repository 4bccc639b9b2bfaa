// Loading scenes: the versioned JSON scene format (docs/scene-format.md) and model files
// loaded directly (framed by a default camera, light and AO).
//
// Relative asset paths (mesh files, textures) are looked up first in the scene file's own
// folder, then in the folders of a SceneSearchPath, in order. A missing asset is an error that
// lists every place looked. Every problem in a scene file is collected and reported together
// in one dhr::Error, one line each, naming the file and the JSON path:
//   scenes/room.json: lights[2].radius_m: must be >= 0
#pragma once

#include "core/scene/scene.h"

#include <optional>
#include <string>
#include <vector>

namespace dhr {

struct SceneSearchPath {
  std::vector<std::string> dirs;  // tried in order after the scene file's own folder

  // The standard path: the given folders (a command-line option), then the entries of the
  // environment variable DHR_SCENE_PATH (colon-separated), then ../shared/scenes beside the
  // checkout (DHR_SOURCE_DIR "/../shared/scenes").
  static SceneSearchPath standard(const std::vector<std::string>& command_line = {});

  // Finds `relative` (returned unchanged when absolute or empty base) in base_dir, then in
  // dirs. Returns the first existing regular file; otherwise nullopt, with every candidate
  // path tried appended to `looked` when given.
  std::optional<std::string> find(const std::string& relative, const std::string& base_dir,
                                  std::vector<std::string>* looked = nullptr) const;
};

// Loads a JSON scene file. Throws dhr::Error listing every problem found.
Scene load_scene(const std::string& path, const SceneSearchPath& search);

// Loads a model file (OBJ, glTF, GLB, ...) as a scene: a default camera looking at the
// bounding box from a diagonal with a 10 s orbit, one sphere light above it, an ambient term
// and an AO block sized to the bounding box.
Scene load_model_as_scene(const std::string& path, const SceneSearchPath& search);

// .json -> load_scene, anything else -> load_model_as_scene. The path itself is found like an
// asset (as given, then in the search path's folders), and a bare name of a built-in scene
// ("room", "temple", "street", "living-room", ...) finds DHR_SOURCE_DIR/scenes/NAME.json or
// DHR_SOURCE_DIR/scenes/real/NAME.json.
Scene load_scene_or_model(const std::string& path, const SceneSearchPath& search);

// The built-in scene files: DHR_SOURCE_DIR/scenes/*.json (procedural, no external files)
// and DHR_SOURCE_DIR/scenes/real/*.json (real scenes that need ../shared/scenes), sorted.
std::vector<std::string> builtin_scene_files();
std::vector<std::string> real_scene_files();

}  // namespace dhr
