// The client's CPU rasterizer: writes the G-buffer (core/buffers/gbuffer.h) of a scene for a camera,
// the first stage of every client frame in the DHR frame loop (docs/architecture.md, "The frame
// loop"; the paper's client rasterizes the scene itself and composites the server's shading
// terms).
//
// Pipeline (tile-binned, sort-middle, after Larrabee/CUDA software rasterizers):
//   1. vertices: moving objects are placed at time_s, every vertex goes to camera space
//      (parallel over vertex ranges);
//   2. triangles: trivial frustum reject, near-plane (and guard-band) clipping in homogeneous
//      space, snapping to 1/256 px, bounding box, binning into 64x64 tiles (parallel over
//      fixed ranges of triangles, so the per-tile order is the scene order whatever the
//      thread count);
//   3. tiles, in parallel: a visibility pass (fixed-point edge functions stepped
//      incrementally, top-left fill rule, early depth test on 1/w before anything else is
//      interpolated) keeps the nearest triangle per pixel, then one resolve pass writes every
//      G-buffer field once per pixel.
//
// Conventions (shared with the Embree G-buffer of core/trace/rt_scene.h):
// - Samples at pixel centres (x + 0.5, y + 0.5), with Camera::project's pixel mapping. The
//   written position lies on Camera::primary_ray through the pixel centre (to float
//   rounding), depth == Camera::view_depth(position); kBackgroundDepth where nothing is hit.
// - Attributes use the ORIGINAL mesh triangle's perspective-correct barycentrics (2D
//   homogeneous rasterization, Olano & Greer 1997), also for the pieces of a clipped
//   triangle: (1-b1-b2) v0 + b1 v1 + b2 v2 == position; prim id = mesh triangle index.
// - Visible range: view depth in [near_m, far_m] (near by clipping, far per fragment).
// - No back-face culling. The geometric normal (from the world-space triangle) and the
//   shading normal (interpolated vertex normals; the geometric normal where the mesh has
//   none) are each flipped to face the camera: dot(n, camera.position - position) >= 0.
// - Depth ties (equal 1/w) go to the smaller (object id, prim id): the result does not depend
//   on the order of Scene::objects nor on the thread count (bit-identical).
// - Alpha cut-out applies to a material with alpha_cutout, a texture with alpha and a mesh
//   with per-vertex uvs: fragments whose bilinear alpha < alpha_threshold are discarded.
// - Albedo = material albedo x bilinear texture colour (when the mesh has uvs).
// - Motion: the surface point is mapped to the previous frame (object space through
//   world_from_object(time_s)^-1, then world_from_object(prev_time_s)) and projected through
//   prev_camera, scaled to this frame's pixel grid when the resolutions differ. Exactly
//   (0, 0) for static geometry when prev_camera equals camera. A point behind the previous
//   camera gets motion (-1e6, -1e6) (far off-screen: "was not visible"); components are
//   clamped to +-1e6 px. Background pixels have motion (0, 0).
// - Triangles with an index out of range, a non-finite vertex or a coordinate with
//   |c| >= 1e18 are skipped and counted as culled (like RtScene's build).
#pragma once

#include "core/buffers/camera.h"
#include "core/buffers/gbuffer.h"
#include "core/scene/scene.h"

#include <cstdint>

namespace dhr {

constexpr int kRasterTileSize = 64;  // pixels a side of a binning tile

struct RasterFrame {
  const Scene* scene = nullptr;
  Camera camera;
  double time_s = 0.0;
  Camera prev_camera;  // for motion vectors: set it to `camera` on a first frame
  double prev_time_s = 0.0;
};

struct RasterStats {
  uint64_t triangles_in = 0;       // mesh triangles in the scene
  uint64_t triangles_clipped = 0;  // went through near-plane / guard-band clipping
  uint64_t triangles_culled = 0;   // outside the frustum, covering no pixel centre, degenerate or invalid
  uint64_t fragments = 0;          // covered pixel samples, before the depth test
  double ms = 0.0;                 // wall time of the call
};

// Rasterizes frame.scene for frame.camera at frame.time_s into `out`: resizes it to
// camera.width x camera.height (reusing its memory when the size is unchanged), sets
// out.camera and out.time_s and writes every field of every pixel. Uses TBB (the current
// arena and global_control limits); the output is bit-identical for any thread count.
// Throws dhr::Error when the scene is null, a camera is invalid (resolution, fov, near/far,
// non-finite basis), an object's material or a material's texture index is out of range, a
// texture is inconsistent, or a mesh has normals or uvs whose count differs from its positions.
RasterStats rasterize(const RasterFrame& frame, GBuffer& out);

// Whether two frames rasterize to the same G-buffer: the same scene, times and cameras (every
// field equal). The rasterizer is deterministic, so one's G-buffer stands for the other's.
bool same_raster_frame(const RasterFrame& a, const RasterFrame& b);

}  // namespace dhr
