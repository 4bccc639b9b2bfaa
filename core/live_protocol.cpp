#include "core/live_protocol.h"

#include "core/byte_order.h"
#include "core/checksum.h"
#include "core/error.h"

#include <bit>
#include <cmath>
#include <cstring>

namespace dhr {
namespace {

using le::get16;
using le::get32;
using le::put16;
using le::get64;
using le::put32;
using le::put64;

constexpr size_t kOffVersion = 4, kOffType = 5, kOffReserved1 = 6, kOffSession = 8, kOffBodyLen = 12,
                 kOffReserved2 = 14, kOffChecksum = 16;
static_assert(kOffChecksum + 4 == kControlHeaderBytes);

uint32_t checksum(std::span<const uint8_t> d) {
  return crc32c(d.subspan(kControlHeaderBytes), crc32c(d.first(kOffChecksum)));
}

void put_float(uint8_t*& p, float f) {
  put32(p, std::bit_cast<uint32_t>(f));
  p += 4;
}
float get_float(const uint8_t*& p) {
  const float f = std::bit_cast<float>(get32(p));
  p += 4;
  return f;
}

std::vector<uint8_t> camera_body(const CameraUpdate& c) {
  std::vector<uint8_t> b(kCameraBodyBytes, 0);
  uint8_t* p = b.data();
  put32(p, c.frame);
  p[4] = c.keyframe_request ? 1 : 0;  // bytes 5..7 reserved
  put64(p + 8, std::bit_cast<uint64_t>(c.scene_time_s));
  p += 16;
  for (const glm::vec3& v : {c.camera.position, c.camera.forward, c.camera.up})
    for (int i = 0; i < 3; ++i) put_float(p, v[i]);
  put_float(p, c.camera.vfov_deg);
  put_float(p, c.camera.near_m);
  put_float(p, c.camera.far_m);
  put16(p, uint32_t(c.camera.width));
  put16(p + 2, uint32_t(c.camera.height));
  return b;
}

bool parse_camera(std::span<const uint8_t> b, CameraUpdate& c) {
  if (b.size() != kCameraBodyBytes) return false;
  const uint8_t* p = b.data();
  c.frame = get32(p);
  if (p[4] > 1 || p[5] || p[6] || p[7]) return false;
  c.keyframe_request = p[4] == 1;
  c.scene_time_s = std::bit_cast<double>(get64(p + 8));
  p += 16;
  for (glm::vec3* v : {&c.camera.position, &c.camera.forward, &c.camera.up})
    for (int i = 0; i < 3; ++i) (*v)[i] = get_float(p);
  c.camera.vfov_deg = get_float(p);
  c.camera.near_m = get_float(p);
  c.camera.far_m = get_float(p);
  c.camera.width = get16(p);
  c.camera.height = get16(p + 2);
  // Everything the server will compute with is checked here: finite values, unit axes, a
  // usable projection, a non-empty image.
  const Camera& k = c.camera;
  auto finite3 = [](const glm::vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
  auto unit = [](const glm::vec3& v) { return std::fabs(glm::length(v) - 1.0f) < 1e-3f; };
  return std::isfinite(c.scene_time_s) && finite3(k.position) && std::fabs(k.position.x) < 1e18f &&
         std::fabs(k.position.y) < 1e18f && std::fabs(k.position.z) < 1e18f && finite3(k.forward) && finite3(k.up) &&
         unit(k.forward) && unit(k.up) && std::fabs(glm::dot(k.forward, k.up)) < 1e-3f && k.vfov_deg > 0.0f &&
         k.vfov_deg < 180.0f && k.near_m > 0.0f && k.far_m > k.near_m && std::isfinite(k.far_m) && k.width > 0 &&
         k.height > 0;
}

}  // namespace

const char* control_type_name(ControlType t) {
  switch (t) {
    case ControlType::Hello: return "hello";
    case ControlType::Welcome: return "welcome";
    case ControlType::Refuse: return "refuse";
    case ControlType::Camera: return "camera";
    case ControlType::Bye: return "bye";
  }
  return "?";
}

const char* control_parse_name(ControlParse r) {
  switch (r) {
    case ControlParse::Ok: return "ok";
    case ControlParse::NotControl: return "not_control";
    case ControlParse::BadVersion: return "bad_version";
    case ControlParse::BadChecksum: return "bad_checksum";
    case ControlParse::BadLength: return "bad_length";
    case ControlParse::BadType: return "bad_type";
    case ControlParse::BadBody: return "bad_body";
    case ControlParse::BadReserved: return "bad_reserved";
  }
  return "?";
}

bool looks_like_control(std::span<const uint8_t> d) {
  return d.size() >= 4 && std::memcmp(d.data(), kControlMagic, 4) == 0;
}

std::vector<uint8_t> encode_control(const ControlMessage& m) {
  std::vector<uint8_t> body;
  if (m.type == ControlType::Camera)
    body = camera_body(m.camera);
  else
    body.assign(m.text.begin(), m.text.end());
  if (body.size() > kMaxControlBody)
    fail("control message '{}': body of {} bytes exceeds the limit of {}", control_type_name(m.type), body.size(),
         kMaxControlBody);
  std::vector<uint8_t> d(kControlHeaderBytes + body.size(), 0);
  std::memcpy(d.data(), kControlMagic, 4);
  d[kOffVersion] = kControlVersion;
  d[kOffType] = uint8_t(m.type);
  put32(d.data() + kOffSession, m.session);
  put16(d.data() + kOffBodyLen, uint32_t(body.size()));
  if (!body.empty()) std::memcpy(d.data() + kControlHeaderBytes, body.data(), body.size());
  put32(d.data() + kOffChecksum, checksum(d));
  return d;
}

void seal_control(std::span<uint8_t> d) { put32(d.data() + kOffChecksum, checksum(d)); }

ControlParse parse_control(std::span<const uint8_t> d, ControlMessage& out) {
  if (d.size() < kControlHeaderBytes || !looks_like_control(d)) return ControlParse::NotControl;
  if (d[kOffVersion] != kControlVersion) return ControlParse::BadVersion;
  if (get32(d.data() + kOffChecksum) != checksum(d)) return ControlParse::BadChecksum;
  const size_t body_len = get16(d.data() + kOffBodyLen);
  if (body_len != d.size() - kControlHeaderBytes || body_len > kMaxControlBody) return ControlParse::BadLength;
  if (get16(d.data() + kOffReserved1) || get16(d.data() + kOffReserved2)) return ControlParse::BadReserved;
  const uint8_t type = d[kOffType];
  if (type < uint8_t(ControlType::Hello) || type > uint8_t(ControlType::Bye)) return ControlParse::BadType;
  out.type = ControlType(type);
  out.session = get32(d.data() + kOffSession);
  const std::span<const uint8_t> body = d.subspan(kControlHeaderBytes);
  out.text.clear();
  if (out.type == ControlType::Camera) {
    if (!parse_camera(body, out.camera)) return ControlParse::BadBody;
  } else {
    out.text.assign(body.begin(), body.end());
  }
  return ControlParse::Ok;
}

}  // namespace dhr
