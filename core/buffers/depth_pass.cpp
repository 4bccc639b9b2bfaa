#include "core/buffers/depth_pass.h"

#include "core/base/error.h"
#include "core/buffers/gbuffer.h"

#include <algorithm>
#include <cmath>

namespace dhr {

namespace {

// M * near, the scale of the codes (M = 2^bits - 1).
struct Scale {
  double m, m_near;
};

Scale scale_of(const Camera& c, int bits) {
  if (!(c.near_m > 0.0f) || !std::isfinite(c.near_m))
    fail("depth pass: the camera's near {} must be finite and positive", c.near_m);
  if (bits < 8 || bits > 16) fail("depth pass: codes of {} bits (valid: 8..16)", bits);
  const double m = double((1 << bits) - 1);
  return {m, m * double(c.near_m)};
}

uint16_t code_of(float z, const Scale& s) {
  if (!(z > 0.0f) || !std::isfinite(z)) return 0;
  return uint16_t(std::clamp(std::round(s.m_near / double(z)), 1.0, s.m));
}

float z_of(uint16_t q, const Scale& s) { return q == 0 ? kBackgroundDepth : float(s.m_near / double(q)); }

}  // namespace

uint16_t depth_code(float z, const Camera& c, int bits) { return code_of(z, scale_of(c, bits)); }

float depth_of_code(uint16_t q, const Camera& c, int bits) { return z_of(q, scale_of(c, bits)); }

PassBuffer pack_depth(const ImageF& depth, const Camera& camera, int bits) {
  const Scale scale = scale_of(camera, bits);
  PassBuffer out;
  out.desc = {PassKind::Depth, depth.width(), depth.height(), 2, bits};
  const size_t n = depth.size();
  out.bytes.resize(2 * n);
  for (size_t i = 0; i < n; ++i) {
    const uint16_t q = code_of(depth[i], scale);
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
  const Scale scale = scale_of(camera, pass.desc.full_scale);
  ImageF out(pass.desc.width, pass.desc.height);
  const size_t n = out.size();
  for (size_t i = 0; i < n; ++i) {
    out[i] = z_of(uint16_t((unsigned(pass.bytes[i]) << 8) | pass.bytes[n + i]), scale);
  }
  return out;
}

}  // namespace dhr
