// Shared helpers of the predictors (reprojection, rotation_warp, depth_warp): input checks with messages
// that name the predictor and both sizes, a pinhole projector with its constants hoisted out
// of the per-pixel loop, the byte layouts of the pass kinds, and a row-parallel loop.
//
// Internal to backends/predict/: not a public API.
#pragma once

#include "core/backend/backend.h"
#include "core/base/error.h"
#include "core/buffers/camera.h"
#include "core/buffers/gbuffer.h"
#include "core/buffers/pass_buffer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

namespace dhr::predict {

// Rows are computed independently (each writes only its own output row and its own counter
// slot), so results are bit-identical for any thread count and any split.
template <class Body>
void parallel_rows(int height, Body&& body) {
  tbb::parallel_for(tbb::blocked_range<int>(0, height, 2), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) body(y);
  });
}

// Tests only: on, reprojection takes its scalar path on every pixel, also where the CPU has
// AVX-512 (its 16-lane kernel must give the same bytes: tests/backends/test_predictors.cpp).
void force_scalar_reprojection(bool on);

inline bool finite3(const glm::vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// A camera usable for projection: finite pose, unit-ish orthogonal axes, fov in (0, 180),
// positive size. Throws dhr::Error naming the predictor and which camera (`which`) is bad.
inline void check_camera(const char* predictor, const char* which, const Camera& c) {
  const float lf = glm::dot(c.forward, c.forward), lu = glm::dot(c.up, c.up);
  if (!finite3(c.position) || !finite3(c.forward) || !finite3(c.up) || std::fabs(lf - 1.0f) > 1e-3f ||
      std::fabs(lu - 1.0f) > 1e-3f || std::fabs(glm::dot(c.forward, c.up)) > 1e-3f)
    fail("predictor '{}': the {} camera's position/forward/up are not finite, unit and orthogonal", predictor, which);
  if (!(c.vfov_deg > 0.0f && c.vfov_deg < 180.0f))
    fail("predictor '{}': the {} camera's vfov_deg {} is out of range (0, 180)", predictor, which, c.vfov_deg);
  if (c.width <= 0 || c.height <= 0)
    fail("predictor '{}': the {} camera's size {}x{} must be positive", predictor, which, c.width, c.height);
}

// The received buffer must be well formed: a valid description and exactly its byte size. A
// depth pass is never predicted itself (its two byte planes are one 16-bit code, which no
// per-byte resampling keeps; depth_warp reads it as src.depth).
inline void check_buffer(const char* predictor, const PassBuffer& b) {
  if (std::string why = b.desc.validate(); !why.empty())
    fail("predictor '{}': invalid received {} buffer: {}", predictor, pass_kind_name(b.desc.kind), why);
  if (b.desc.layout() == PassLayout::Code16)
    fail(
        "predictor '{}' refuses a depth pass: it is read beside the colour frame (depth_warp's src.depth), never "
        "predicted itself (valid: visibility, soft_visibility, ao, colour, as the predictor accepts)",
        predictor);
  if (b.bytes.size() != b.desc.byte_size())
    fail("predictor '{}': received {} buffer has {} bytes, {} expected for {}x{} with {} channels", predictor,
         pass_kind_name(b.desc.kind), b.bytes.size(), b.desc.byte_size(), b.desc.width, b.desc.height, b.desc.channels);
}

// The checks of a warp of the remote client's colour frame (rotation_warp, depth_warp): both
// cameras usable, the received buffer the size of the src camera it was rendered for, the dst
// camera's size in range. Throws dhr::Error naming `predictor`.
inline void check_warp(const char* predictor, const PassBuffer& received, const Camera& src, const Camera& dst) {
  check_camera(predictor, "src", src);
  check_camera(predictor, "dst", dst);
  if (received.desc.width != src.width || received.desc.height != src.height)
    fail("predictor '{}': the received buffer is {}x{} but the src camera it was rendered for is {}x{}", predictor,
         received.desc.width, received.desc.height, src.width, src.height);
  check_image_size(dst.width, dst.height);
}

// The buffer a predictor writes: `out` sized for `width` x `height` with `received`'s layout, or
// `temp` when `out` is `received` itself (writing into the buffer being read would corrupt it;
// the caller then moves `temp` into `out`).
inline PassBuffer& output_buffer(const PassBuffer& received, PassBuffer& out, PassBuffer& temp, int width, int height) {
  PassBuffer& result = (&out == &received) ? temp : out;
  result.desc = received.desc;
  result.desc.width = width;
  result.desc.height = height;
  result.bytes.resize(result.desc.byte_size());
  return result;
}

// Image point (pixel units, pixel centre = x + 0.5) of a world point, exactly the formula of
// Camera::project with right(), tan(fov / 2) and the divisions by aspect hoisted out.
struct Projector {
  glm::vec3 position{0.0f}, right{1, 0, 0}, up{0, 1, 0}, forward{0, 0, -1};
  float fx = 1.0f, fy = 1.0f;  // pixels per unit of (lateral offset / depth)
  float cx = 0.0f, cy = 0.0f;  // image centre in pixels

  explicit Projector(const Camera& c) : position(c.position), right(c.right()), up(c.up), forward(c.forward) {
    const float tan_half = std::tan(glm::radians(c.vfov_deg) * 0.5f);
    cx = 0.5f * float(c.width);
    cy = 0.5f * float(c.height);
    fx = cx / (tan_half * c.aspect());
    fy = cy / tan_half;
  }
  // x, y: image point; z: view depth (<= 0 or NaN: not in front of the camera).
  glm::vec3 project(const glm::vec3& world) const {
    const glm::vec3 d = world - position;
    const float z = glm::dot(d, forward);
    const float inv_z = 1.0f / z;
    return {cx + glm::dot(d, right) * fx * inv_z, cy - glm::dot(d, up) * fy * inv_z, z};
  }
};

// Where byte (pixel i, plane c) of an 8-bit pass lies: i * pixel_stride + c * plane_stride.
// SoftVisibility and Ao are planar (one plane per light), Colour is interleaved RGB.
struct Layout8 {
  int planes = 1;
  size_t pixel_stride = 1;
  size_t plane_stride = 0;
};

inline Layout8 layout8(const PassDesc& d) {
  const size_t n = size_t(d.width) * size_t(d.height);
  switch (d.layout()) {
    case PassLayout::Planes8: return {d.channels, 1, n};
    case PassLayout::Rgb8: return {3, 3, 1};
    case PassLayout::Bitmask:
    case PassLayout::Code16: break;
  }
  return {1, 1, n};
}

// The "nothing known, assume unshadowed" value of one pixel: every light's bit set (bitmask;
// padding bits beyond `channels` stay 0) or full_scale (SoftVisibility, Ao).
inline uint64_t fully_lit_bits(int channels) { return channels >= 64 ? ~uint64_t(0) : (uint64_t(1) << channels) - 1; }

inline uint8_t round_u8(float v) {
  const float r = v + 0.5f;
  return uint8_t(r >= 0.0f ? (r < 255.0f ? r : 255.0f) : 0.0f);  // NaN -> 0
}

}  // namespace dhr::predict
