// Procedural meshes for the built-in scenes and the tests. Every shape is centred at the
// origin, has per-vertex unit normals pointing outward, per-vertex uvs, and triangles wound
// counter-clockwise seen from outside (so cross(b - a, c - a) points along the normal).
// Faces with different normals do not share vertices (hard edges stay hard).
#pragma once

#include "core/scene/scene.h"

#include <glm/glm.hpp>

namespace dhr {

// An axis-aligned box of the given full extents (metres): 24 vertices, 12 triangles.
// Throws dhr::Error unless every extent is finite and > 0.
Mesh make_box(glm::vec3 size_m);

// A UV sphere: `segments` around the y axis (>= 3), `rings` from pole to pole (>= 2).
// Throws dhr::Error unless radius > 0 and the counts are in range (<= 4096 each).
Mesh make_sphere(float radius_m, int segments = 32, int rings = 16);

// A plane in y = 0 with normal +y, spanning size_x by size_z metres; uvs span [0, 1].
Mesh make_plane(float size_x_m, float size_z_m);

// A cylinder along y from -height/2 to +height/2, `segments` around (>= 3), with or without
// the two end caps.
Mesh make_cylinder(float radius_m, float height_m, int segments = 24, bool caps = true);

}  // namespace dhr
