// The remote baseline's depth pass: the server's view depth, sent with its colour frame so that
// the client can reproject that frame with the camera's translation (backends/predict/
// depth_warp.cpp), as production XR streaming does. Its bytes are counted like any pass.
//
// Code: B bits per pixel (B = 8..16, PassDesc::full_scale; the predictor asks for it:
// Predictor::depth_bits), inverse depth (disparity). 0 means no surface (background). With
// M = 2^B - 1, a surface at view depth z is
//   q = clamp(round(M * near / z), 1, M)
// with near the camera's (Camera::near_m): z = M * near / q. Inverse depth (not depth, nor its
// logarithm) is the usual choice: it is affine in the image over any plane of the scene, and its
// step is finest near the camera, where a depth error moves a reprojected point most. At 16 bits
// and zstd level 3 it coded 2.4x smaller than a logarithmic code (room, 320x180: 13.1 against
// 31.4 KB per frame; 14 bits: 10.2, 12 bits: 5.9, 10 bits: 2.5 KB). Half a step is an inverse-depth
// error of 0.5 / (M * near) per metre: a camera translation T then moves a reprojected point by
// at most f * T * 0.5 / (M * near) pixels (f: the focal length in pixels); for B = 12, near
// = 0.05 m, T = 0.1 m and f = 277 px (320 pixels wide, 60 degrees vertical), 0.07 px. Surfaces
// nearer than near take code M; beyond M * near, code 1.
// Stored as two 8-bit planes (PassKind::Depth): the high bytes of every pixel, then the low
// bytes. Lossy codecs refuse it (a lossy step in the high byte moves the depth by 1/256 of its
// range).
#pragma once

#include "core/buffers/camera.h"
#include "core/buffers/image.h"
#include "core/buffers/pass_buffer.h"

#include <cstdint>

namespace dhr {

// The code of view depth `z` for `camera` (0 for kBackgroundDepth or anything not finite and
// positive). Throws dhr::Error when the camera's near is not finite and positive or `bits` is
// outside 8..16.
uint16_t depth_code(float z, const Camera& camera, int bits);
// The view depth of code `q` (kBackgroundDepth for 0).
float depth_of_code(uint16_t q, const Camera& camera, int bits);

// The depth pass of a G-buffer's view depth, rendered for `camera`, with codes of `bits` bits
// (8..16; else dhr::Error).
PassBuffer pack_depth(const ImageF& depth, const Camera& camera, int bits);
// The view depth a depth pass carries, for the camera it was rendered for. Throws dhr::Error
// when `pass` is not a well-formed depth pass.
ImageF unpack_depth(const PassBuffer& pass, const Camera& camera);

}  // namespace dhr
