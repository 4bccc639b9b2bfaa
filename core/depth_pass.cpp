#include "core/depth_pass.h"

#include "core/error.h"
#include "core/gbuffer.h"

#include <algorithm>
#include <cmath>

namespace dhr {

namespace {

constexpr double kSteps = 65534.0;  // codes 1..65535 for surfaces

double log_range(const Camera& c) {
  if (!(c.near_m > 0.0f && c.far_m > c.near_m && std::isfinite(c.far_m)))
    fail("depth pass: the camera's near {} and far {} must satisfy 0 < near < far (finite)", c.near_m, c.far_m);
  return std::log(double(c.far_m) / double(c.near_m));
}

uint16_t code_of(float z, double near, double far, double range) {
  if (!(z > 0.0f) || !std::isfinite(z)) return 0;
  return uint16_t(1.0 + std::round(kSteps * std::log(std::clamp(double(z), near, far) / near) / range));
}

float z_of(uint16_t q, double near, double range) {
  return q == 0 ? kBackgroundDepth : float(near * std::exp(double(q - 1) / kSteps * range));
}

}  // namespace

uint16_t depth_code(float z, const Camera& c) { return code_of(z, c.near_m, c.far_m, log_range(c)); }

float depth_of_code(uint16_t q, const Camera& c) { return z_of(q, c.near_m, log_range(c)); }

PassBuffer pack_depth(const ImageF& depth, const Camera& camera) {
  PassBuffer out;
  out.desc = {PassKind::Depth, depth.width(), depth.height(), 2, 255};
  const size_t n = depth.size();
  out.bytes.resize(2 * n);
  const double range = log_range(camera);
  for (size_t i = 0; i < n; ++i) {
    const uint16_t q = code_of(depth[i], camera.near_m, camera.far_m, range);
    out.bytes[i] = uint8_t(q >> 8);
    out.bytes[n + i] = uint8_t(q & 0xff);
  }
  return out;
}

ImageF unpack_depth(const PassBuffer& pass, const Camera& camera) {
  if (pass.desc.kind != PassKind::Depth)
    fail("depth pass: a {} buffer is not a depth pass", pass_kind_name(pass.desc.kind));
  if (std::string why = pass.desc.validate(); !why.empty()) fail("depth pass: {}", why);
  if (pass.bytes.size() != pass.desc.byte_size())
    fail("depth pass: {} bytes, {} expected for {}x{}", pass.bytes.size(), pass.desc.byte_size(), pass.desc.width,
         pass.desc.height);
  const double range = log_range(camera);
  ImageF out(pass.desc.width, pass.desc.height);
  const size_t n = out.size();
  for (size_t i = 0; i < n; ++i) {
    out[i] = z_of(uint16_t((unsigned(pass.bytes[i]) << 8) | pass.bytes[n + i]), camera.near_m, range);
  }
  return out;
}

}  // namespace dhr
