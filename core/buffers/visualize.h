// False-colour views of G-buffer channels and passes, for `dhrbench render` and reports.
#pragma once

#include "core/buffers/gbuffer.h"
#include "core/buffers/image.h"

namespace dhr {

// Depth as grey: near = white, far = black, scaled between the 1st and 99th percentile of
// the covered pixels' log depth; background black.
ImageU8 visualize_depth(const ImageF& depth);
// Unit normals mapped from [-1, 1] to [0, 255] per axis; background black.
ImageRGB8 visualize_normals(const ImageVec3& normal, const ImageU32& object_id);
// Linear albedo to sRGB.
ImageRGB8 visualize_albedo(const ImageVec3& albedo);
// A distinct colour per object id (hashed); background black.
ImageRGB8 visualize_ids(const ImageU32& id);
// Motion as hue (direction) and brightness (magnitude, saturating at max_px pixels);
// no motion = black.
ImageRGB8 visualize_motion(const ImageVec2& motion, float max_px = 16.0f);
// Linear [0, 1] to 8-bit sRGB.
uint8_t linear_to_srgb8(float v);

}  // namespace dhr
