// Loading model files (OBJ+MTL, glTF, GLB, and whatever else assimp reads) into scene
// objects, materials and textures, with every mesh validated before it is trusted.
//
// What is checked (a failure throws dhr::Error "FILE: problem" and nothing is repaired
// silently):
//   - the file exists, is not larger than ModelLimits::max_file_bytes, and for formats whose
//     header declares element counts (OFF, PLY) those counts fit the file size (a lying header
//     would otherwise make assimp try to allocate terabytes); a GLB's chunks lie within the
//     file and every glTF buffer's byteLength within what it refers to (BIN chunk, file, URI);
//   - OBJ: every face index within the vertices, texture coordinates and normals defined
//     before it, and every mtllib file present (the importer drops either in silence);
//   - assimp's own warnings that it dropped faces or vertices (out-of-range indices, vertex
//     counts that do not fit the primitive mode) reject the file: the model is broken;
//   - the node hierarchy is at most max_node_depth deep (recursive node graphs);
//   - sizes are bounded before anything is allocated (max_triangles, max_vertices);
//   - every mesh: at least one triangle, indices in range, positions finite with |x| < 1e18,
//     uvs (when present) finite and one per vertex.
// What is repaired, because it does not change geometry: normals that are missing, not
// finite or not unit length are recomputed (non-unit but finite ones are renormalised; zero
// or non-finite ones are replaced by the area-weighted normal of the adjacent triangles).
// Points and lines in a mesh are skipped (only triangles are rendered).
//
// Conventions: node transforms are applied (objects come out in the model's world space),
// triangles are wound counter-clockwise around their normals, uv (0, 0) is the bottom-left
// of a texture. MTL Kd / glTF baseColorFactor -> Material::albedo, map_Kd / baseColorTexture
// -> Material::texture, map_d (or an alpha channel in the albedo texture, or glTF alphaMode
// MASK/BLEND) -> alpha_cutout; materials named "emitter_*" are emitters.
#pragma once

#include "core/scene/scene.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dhr {

struct ModelLimits {
  uint64_t max_file_bytes = uint64_t(4) << 30;
  size_t max_triangles = 50'000'000;  // over all objects (instances counted)
  size_t max_vertices = 50'000'000;
  int max_node_depth = 256;
  size_t max_objects = 1'000'000;
};

struct ImportedModel {
  std::vector<Object> objects;  // world space; id 0 (the scene loader numbers them); material indexes `materials`
  std::vector<Material> materials;
  std::vector<Texture> textures;  // Material::texture indexes this
  size_t normals_repaired = 0;    // vertices whose normal was recomputed or renormalised
  size_t triangle_count() const {
    size_t n = 0;
    for (const auto& o : objects) n += o.mesh.triangles.size();
    return n;
  }
};

// Loads a model file. Throws dhr::Error "PATH: problem" for anything unreadable or invalid.
ImportedModel import_model(const std::string& path, const ModelLimits& limits = {});

// Validates a mesh (see the list above); `what` names it in messages ("file.obj: mesh 3").
// Returns the number of vertex normals it recomputed or renormalised.
size_t validate_mesh(Mesh& mesh, const std::string& what);

// Loads a texture file (any format OpenImageIO reads) into a Texture.
Texture load_texture(const std::string& path);

}  // namespace dhr
