// The G-buffer: what the client rasterizes for every frame, and what the server recomputes
// for the camera it traces (both must agree exactly). Plain data, filled by the rasterizer
// (core/raster/raster.h) or by Embree primary rays (core/trace/rt_scene.h).
#pragma once

#include "core/buffers/camera.h"
#include "core/buffers/image.h"

#include <cstdint>
#include <limits>

namespace dhr {

constexpr uint32_t kBackgroundId = 0;  // object ids of scene objects start at 1
constexpr float kBackgroundDepth = std::numeric_limits<float>::infinity();

struct GBuffer {
  Camera camera;         // the camera this was rendered for
  double time_s = 0.0;   // scene time (dynamic objects are placed at this time)
  ImageF depth;          // linear view depth in metres; kBackgroundDepth where nothing was hit
  ImageVec3 position;    // world position of the visible surface
  ImageVec3 normal;      // shading normal, unit, flipped to face the camera
  ImageVec3 geo_normal;  // geometric normal, unit, flipped to face the camera
  ImageVec3 albedo;      // linear albedo (texture x material colour)
  ImageU32 object_id;    // Object::id, or kBackgroundId
  ImageU32 prim_id;      // triangle index within the object's mesh
  ImageVec2 bary;        // barycentrics (b1, b2) of the hit: p = (1-b1-b2) v0 + b1 v1 + b2 v2
  ImageVec2 motion;      // screen-space motion in pixels: this pixel's surface point was at
                         // (x + 0.5, y + 0.5) + motion in the previous frame (camera and object motion)

  int width() const { return depth.width(); }
  int height() const { return depth.height(); }
  bool covered(int x, int y) const { return object_id(x, y) != kBackgroundId; }
  // f(plane) for every plane, in declaration order.
  template <class F>
  void for_each_plane(F&& f) const {
    planes_of(*this, f);
  }
  template <class F>
  void for_each_plane(F&& f) {
    planes_of(*this, f);
  }
  // Every plane sized; values unspecified until written (the rasterizer writes every pixel).
  void resize_for_overwrite(int width, int height) {
    for_each_plane([&](auto& plane) { plane.resize_for_overwrite(width, height); });
  }
  void resize(int width, int height) {
    depth.resize(width, height, kBackgroundDepth);
    position.resize(width, height);
    normal.resize(width, height);
    geo_normal.resize(width, height);
    albedo.resize(width, height);
    object_id.resize(width, height, kBackgroundId);
    prim_id.resize(width, height);
    bary.resize(width, height);
    motion.resize(width, height);
  }

 private:
  template <class G, class F>
  static void planes_of(G& g, F& f) {
    f(g.depth);
    f(g.position);
    f(g.normal);
    f(g.geo_normal);
    f(g.albedo);
    f(g.object_id);
    f(g.prim_id);
    f(g.bary);
    f(g.motion);
  }
};

}  // namespace dhr
