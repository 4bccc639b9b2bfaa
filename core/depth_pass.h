// The remote baseline's depth pass: the server's view depth, sent with its colour frame so that
// the client can reproject that frame with the camera's translation (backends/predict/
// depth_warp.cpp), as production XR streaming does. Its bytes are counted like any pass.
//
// Code: 16 bits per pixel. 0 means no surface (background). A surface at view depth z is
//   q = 1 + round(65534 * ln(clamp(z, near, far) / near) / ln(far / near))
// with near and far the camera's (Camera::near_m, far_m), so the relative step is the same at
// every depth: ln(far / near) / 65534 (1.5e-4 for the default 0.05..1000 m, 0.015 % of z).
// Stored as two 8-bit planes (PassKind::Depth): the high bytes of every pixel, then the low
// bytes; the high plane is smooth and compresses well with a lossless codec. Lossy codecs refuse
// it (a lossy step in the high byte moves a pixel by 1/256 of the depth range).
#pragma once

#include "core/camera.h"
#include "core/image.h"
#include "core/pass_buffer.h"

#include <cstdint>

namespace dhr {

// The code of view depth `z` for `camera` (0 for kBackgroundDepth or anything not finite and
// positive).
uint16_t depth_code(float z, const Camera& camera);
// The view depth of code `q` (kBackgroundDepth for 0).
float depth_of_code(uint16_t q, const Camera& camera);

// The depth pass of a G-buffer's view depth, rendered for `camera`.
PassBuffer pack_depth(const ImageF& depth, const Camera& camera);
// The view depth a depth pass carries, for the camera it was rendered for. Throws dhr::Error
// when `pass` is not a well-formed depth pass.
ImageF unpack_depth(const PassBuffer& pass, const Camera& camera);

}  // namespace dhr
