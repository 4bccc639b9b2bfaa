#include "core/live/live_protocol.h"

#include "core/base/byte_order.h"
#include "core/base/checksum.h"
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/pass/passes.h"

#include <fcntl.h>
#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/params.h>
#include <sys/random.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>

namespace dhr {
namespace {

using le::get16;
using le::get32;
using le::get64;
using le::put16;
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
  p += 4;
  for (int32_t h : c.holds) {
    put32(p, h < 0 ? 0xffffffffu : uint32_t(h));
    p += 4;
  }
  if (!c.has_reports) return b;
  const size_t n = std::min(c.reports.size(), kMaxFrameReports);
  b.resize(kCameraBodyBytes + kReportsHeadBytes + n * kFrameReportWireBytes, 0);
  p = b.data() + kCameraBodyBytes;
  put64(p, c.datagrams_received);
  put64(p + 8, c.datagrams_lost);
  put16(p + 16, uint32_t(n));
  p += kReportsHeadBytes;
  for (size_t i = c.reports.size() - n; i < c.reports.size(); ++i) {  // the newest n
    const FrameReport& r = c.reports[i];
    put32(p, r.frame);
    p[4] = uint8_t(r.pass);
    p[5] = r.lost ? 1 : 0;
    put64(p + 8, std::bit_cast<uint64_t>(r.arrival_ms));
    p += kFrameReportWireBytes;
  }
  return b;
}

// The reports after a Camera's fixed body (CameraUpdate::has_reports); false on any bad field.
bool parse_reports(std::span<const uint8_t> b, CameraUpdate& c) {
  c.has_reports = false;
  c.reports.clear();
  if (b.empty()) return true;
  if (b.size() < kReportsHeadBytes) return false;
  const uint8_t* p = b.data();
  c.datagrams_received = get64(p);
  c.datagrams_lost = get64(p + 8);
  const size_t n = get16(p + 16);
  if (n > kMaxFrameReports || b.size() != kReportsHeadBytes + n * kFrameReportWireBytes) return false;
  p += kReportsHeadBytes;
  for (size_t i = 0; i < n; ++i, p += kFrameReportWireBytes) {
    FrameReport r;
    r.frame = get32(p);
    if (p[4] >= kPassSlots || p[5] > 1 || p[6] || p[7]) return false;
    r.pass = p[4];
    r.lost = p[5] == 1;
    r.arrival_ms = std::bit_cast<double>(get64(p + 8));
    if (!std::isfinite(r.arrival_ms)) return false;
    c.reports.push_back(r);
  }
  c.has_reports = true;
  return true;
}

bool parse_camera(std::span<const uint8_t> b, CameraUpdate& c) {
  if (b.size() < kCameraBodyBytes || !parse_reports(b.subspan(kCameraBodyBytes), c)) return false;
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
  p += 4;
  for (int32_t& h : c.holds) {
    const uint32_t v = get32(p);
    p += 4;
    if (v != 0xffffffffu && (v >= c.frame || v > 0x7fffffffu)) return false;  // older than this camera
    h = v == 0xffffffffu ? -1 : int32_t(v);
  }
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

// ---- typed bodies --------------------------------------------------------------------------

const char* body_reject_name(BodyReject r) {
  switch (r) {
    case BodyReject::Ok: return "ok";
    case BodyReject::NotJson: return "not_json";
    case BodyReject::TooDeep: return "too_deep";
    case BodyReject::NotObject: return "not_an_object";
    case BodyReject::MissingField: return "missing_field";
    case BodyReject::WrongType: return "wrong_type";
    case BodyReject::BadValue: return "bad_value";
  }
  return "?";
}

namespace {

BodyCheck refuse(BodyReject r, std::string field = {}) { return {r, std::move(field)}; }

// Parses a body as JSON without throwing: the depth is checked first (so that the reason can
// be told), then dhr::parse_json.
BodyCheck parse_body_json(std::string_view text, const char* what, nlohmann::json& out) {
  if (json_depth(text) > kMaxJsonDepth) return refuse(BodyReject::TooDeep);
  try {
    out = parse_json(text, what);
  } catch (const std::exception&) {
    return refuse(BodyReject::NotJson);
  }
  return {};
}

// Typed getters over an object `o` (checked to be one by the caller). Each returns false and
// fills `check` when the field is missing or of another type; none throws.
struct Fields {
  const nlohmann::json& o;
  std::string prefix;
  BodyCheck check;

  const nlohmann::json* find(const char* key) {
    if (!check.ok()) return nullptr;
    const auto it = o.find(key);
    if (it == o.end()) {
      check = refuse(BodyReject::MissingField, prefix + key);
      return nullptr;
    }
    return &*it;
  }
  bool wrong(const char* key) {
    check = refuse(BodyReject::WrongType, prefix + key);
    return false;
  }
  bool bad(const char* key) {
    check = refuse(BodyReject::BadValue, prefix + key);
    return false;
  }
  bool string(const char* key, std::string& out) {
    const nlohmann::json* v = find(key);
    if (!v) return false;
    if (!v->is_string()) return wrong(key);
    out = v->get_ref<const std::string&>();
    return true;
  }
  bool int64(const char* key, int64_t& out, int64_t lo, int64_t hi) {
    const nlohmann::json* v = find(key);
    if (!v) return false;
    if (v->is_number_unsigned()) {
      const uint64_t u = v->get<uint64_t>();
      if (u > uint64_t(hi)) return bad(key);
      out = int64_t(u);
    } else if (v->is_number_integer()) {
      out = v->get<int64_t>();
    } else {
      return wrong(key);
    }
    if (out < lo || out > hi) return bad(key);
    return true;
  }
  bool uint64(const char* key, uint64_t& out, uint64_t hi = std::numeric_limits<uint64_t>::max()) {
    const nlohmann::json* v = find(key);
    if (!v) return false;
    if (v->is_number_unsigned())
      out = v->get<uint64_t>();
    else if (v->is_number_integer() && v->get<int64_t>() >= 0)
      out = uint64_t(v->get<int64_t>());
    else if (v->is_number_integer())
      return bad(key);
    else
      return wrong(key);
    if (out > hi) return bad(key);
    return true;
  }
  bool uint32(const char* key, uint32_t& out) {
    uint64_t v = 0;
    if (!uint64(key, v, UINT32_MAX)) return false;
    out = uint32_t(v);
    return true;
  }
  bool number(const char* key, double& out) {
    const nlohmann::json* v = find(key);
    if (!v) return false;
    if (!v->is_number()) return wrong(key);
    out = v->get<double>();
    if (!std::isfinite(out)) return bad(key);
    return true;
  }
  bool object(const char* key, nlohmann::json& out) {
    const nlohmann::json* v = find(key);
    if (!v) return false;
    if (!v->is_object()) return wrong(key);
    out = *v;
    return true;
  }
  bool backend(const char* key, OfferBackend& out) {
    const nlohmann::json* v = find(key);
    if (!v) return false;
    if (!v->is_object()) return wrong(key);
    Fields inner{*v, prefix + key + ".", {}};
    nlohmann::json params;
    const bool ok = inner.string("name", out.name) && inner.object("params", params);
    if (!ok) {
      check = inner.check;
      return false;
    }
    out.params = std::move(params);
    return true;
  }
};

}  // namespace

BodyCheck parse_offer_json(const nlohmann::json& j, SessionOffer& out) {
  if (!j.is_object()) return refuse(BodyReject::NotObject);
  Fields f{j, "", {}};
  // The limits are the header's and the simulator's: a value outside them cannot be a real
  // offer, and the typed copy must never overflow when used.
  const bool ok = f.int64("protocol", out.protocol, 0, 1 << 30) && f.string("scene", out.scene) &&
                  f.string("scene_hash", out.scene_hash) && f.int64("width", out.width, 1, 1 << 16) &&
                  f.int64("height", out.height, 1, 1 << 16) && f.number("display_hz", out.display_hz) &&
                  f.number("start_time_s", out.start_time_s) && f.uint64("seed", out.seed) &&
                  f.object("trace", out.trace) && f.backend("visibility_codec", out.visibility_codec) &&
                  f.backend("ao_codec", out.ao_codec) && f.backend("ao_denoiser", out.ao_denoiser) &&
                  f.backend("visibility_denoiser", out.visibility_denoiser) &&
                  f.int64("max_payload_bytes", out.max_payload_bytes, 1, int64_t(kMaxPayloadLimitBytes));
  if (!ok) return f.check;
  if (!(out.display_hz > 0.0)) return refuse(BodyReject::BadValue, "display_hz");
  out.json = j;
  return {};
}

BodyCheck parse_offer(std::string_view text, SessionOffer& out) {
  nlohmann::json j;
  if (BodyCheck c = parse_body_json(text, "hello offer", j); !c.ok()) return c;
  return parse_offer_json(j, out);
}

int pass_slot(PassKind kind) {
  const PassMeaning meaning = pass_meaning(kind);
  for (size_t i = 0; i < pass_types().size(); ++i)
    if (pass_types()[i].meaning == meaning) return int(i);
  return -1;
}

int pass_slot_count() {
  static const int n = [] {
    if (pass_types().size() > size_t(kPassSlots))
      fail("live: {} pass types, at most {} streams", pass_types().size(), kPassSlots);
    return int(pass_types().size());
  }();
  return n;
}

std::string welcome_text(const WelcomeBody& w) {
  nlohmann::json first_sequences = nlohmann::json::object();
  for (int i = 0; i < pass_slot_count(); ++i) first_sequences[pass_types()[size_t(i)].name] = w.first_sequence[i];
  return nlohmann::json{{"session", w.session},
                        {"client_nonce", w.client_nonce},
                        {"first_sequence", first_sequences},
                        {"offer", w.offer.json}}
      .dump();
}

BodyCheck parse_welcome(std::string_view text, WelcomeBody& out) {
  nlohmann::json j;
  if (BodyCheck c = parse_body_json(text, "welcome", j); !c.ok()) return c;
  if (!j.is_object()) return refuse(BodyReject::NotObject);
  Fields f{j, "", {}};
  nlohmann::json seq, offer;
  if (!(f.uint32("session", out.session) && f.uint32("client_nonce", out.client_nonce) &&
        f.object("first_sequence", seq) && f.object("offer", offer)))
    return f.check;
  Fields s{seq, "first_sequence.", {}};
  for (int i = 0; i < pass_slot_count(); ++i)
    if (!s.uint32(pass_types()[size_t(i)].name, out.first_sequence[i])) return s.check;
  BodyCheck c = parse_offer_json(offer, out.offer);
  if (!c.ok()) c.field = "offer." + c.field;
  return c;
}

std::string printable_reason(std::string_view text) {
  std::string out(text.substr(0, kMaxReasonChars));
  for (char& ch : out)
    if (static_cast<unsigned char>(ch) < 0x20 || static_cast<unsigned char>(ch) >= 0x7f) ch = '?';
  if (text.size() > kMaxReasonChars) out += "...";
  return out;
}

const char* read_control(std::span<const uint8_t> d, TypedControl& out) {
  const ControlParse p = parse_control(d, out.message);
  if (p != ControlParse::Ok) return control_parse_name(p);
  out.field.clear();
  BodyCheck c;
  switch (out.message.type) {
    case ControlType::Hello: c = parse_offer(out.message.text, out.offer); break;
    case ControlType::Welcome:
      c = parse_welcome(out.message.text, out.welcome);
      if (c.ok() && out.welcome.session != out.message.session) c = refuse(BodyReject::BadValue, "session");
      if (c.ok() && out.welcome.session == 0) c = refuse(BodyReject::BadValue, "session");
      break;
    case ControlType::Refuse:
    case ControlType::Bye: out.message.text = printable_reason(out.message.text); break;
    case ControlType::Camera: break;  // typed and checked by parse_control
  }
  if (c.ok()) return nullptr;
  out.field = c.field;
  // Fixed names: "<type>_<reason>" for the five types and seven reasons.
  static const auto names = [] {
    std::array<std::array<std::string, 7>, 6> n;
    for (int t = 1; t <= 5; ++t)
      for (int r = 0; r < 7; ++r)
        n[size_t(t)][size_t(r)] =
            std::string(control_type_name(ControlType(t))) + "_" + body_reject_name(BodyReject(r));
    return n;
  }();
  return names[size_t(out.message.type)][size_t(c.reject)].c_str();
}

// ---- the session's pass packets ------------------------------------------------------------

PassGate::PassGate(uint32_t token, const std::array<uint32_t, kPassSlots>& first_sequence,
                   const std::array<uint32_t, kPassSlots>& codec_ids, const std::array<bool, kPassSlots>& streams)
    : stream_(uint16_t(token & 0xffffu)) {
  for (int s = 0; s < kPassSlots; ++s) {
    streams_[s] = streams[s];
    codec_[s] = codec_ids[s];
    first_[s] = first_sequence[s];
  }
}

void PassGate::camera_sent(uint32_t frame) {
  if (!any_camera_ || frame > newest_camera_) newest_camera_ = frame;
  any_camera_ = true;
}

const char* PassGate::check(const ParsedPacket& p) {
  if (p.meta.stream_id != stream_) return "packet_wrong_token";
  const int slot = pass_slot(p.meta.desc.kind);
  if (slot < 0 || !streams_[slot]) return "packet_unexpected_pass";
  if (p.meta.codec_id != codec_[slot]) return "packet_wrong_codec";
  if (!any_camera_ || p.meta.frame_id > newest_camera_) return "packet_frame_ahead";
  // Offsets from the stream's first sequence number, modulo 2^32 (a session sends far fewer
  // than 2^32 packets per stream); the packet's first sequence (its pass's packet 0) must lie in
  // the window too, so that the assembler's view of the pass is inside it as well.
  const uint64_t offset = uint32_t(p.sequence - first_[slot]);
  const uint64_t pass_offset = uint32_t(p.meta.first_sequence - first_[slot]);
  const uint64_t limit = newest_offset_[slot] + kSequenceWindow;
  if (offset >= limit || pass_offset > offset) return "packet_sequence_out_of_window";
  newest_offset_[slot] = std::max(newest_offset_[slot], offset + 1);
  return nullptr;
}

// ---- randomness and authentication -----------------------------------------------------------

uint32_t os_random_u32() {
  for (;;) {
    uint32_t v = 0;
    ssize_t n = -1;
    do {
      n = ::getrandom(&v, sizeof v, 0);
    } while (n < 0 && errno == EINTR);
    if (n != ssize_t(sizeof v)) {
      const int fd = ::open("/dev/urandom", O_RDONLY | O_CLOEXEC);
      if (fd < 0) fail("no random source: getrandom() and /dev/urandom both failed ({})", std::strerror(errno));
      n = ::read(fd, &v, sizeof v);
      ::close(fd);
      if (n != ssize_t(sizeof v)) fail("no random source: a short read from /dev/urandom");
    }
    if (v != 0) return v;
  }
}

namespace {

// The HMAC-SHA256 context with the key set, copied (EVP_MAC_CTX_dup) for every datagram.
EVP_MAC_CTX* hmac_ctx(const std::shared_ptr<void>& p) { return static_cast<EVP_MAC_CTX*>(p.get()); }

}  // namespace

DatagramMac::DatagramMac(std::span<const uint8_t> key) {
  if (key.size() < kMinKeyBytes || key.size() > kMaxKeyBytes)
    fail("a MAC key of {} bytes: it must have {}..{} bytes (e.g. head -c 32 /dev/urandom > live.key)", key.size(),
         kMinKeyBytes, kMaxKeyBytes);
  EVP_MAC* mac = EVP_MAC_fetch(nullptr, OSSL_MAC_NAME_HMAC, nullptr);
  if (!mac) fail("OpenSSL has no HMAC");
  EVP_MAC_CTX* ctx = EVP_MAC_CTX_new(mac);
  EVP_MAC_free(mac);  // the context holds its own reference
  if (!ctx) fail("OpenSSL: cannot create an HMAC context");
  ctx_ = std::shared_ptr<void>(ctx, [](void* c) { EVP_MAC_CTX_free(static_cast<EVP_MAC_CTX*>(c)); });
  char digest[] = "SHA256";
  const OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string(OSSL_MAC_PARAM_DIGEST, digest, 0),
                               OSSL_PARAM_construct_end()};
  if (EVP_MAC_init(ctx, key.data(), key.size(), params) != 1) fail("OpenSSL: cannot set the HMAC-SHA256 key");
}

DatagramMac DatagramMac::from_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail("--key-file '{}': cannot open the file", path);
  std::vector<uint8_t> key;
  char ch = 0;
  while (key.size() <= kMaxKeyBytes && in.get(ch)) key.push_back(uint8_t(ch));
  if (in.bad()) fail("--key-file '{}': cannot read the file", path);
  if (key.size() < kMinKeyBytes || key.size() > kMaxKeyBytes)
    fail("--key-file '{}': {}{} bytes; a key has {}..{} bytes (make one with: head -c 32 /dev/urandom > {})", path,
         key.size() > kMaxKeyBytes ? "more than " : "", std::min(key.size(), kMaxKeyBytes), kMinKeyBytes, kMaxKeyBytes,
         path);
  return DatagramMac(key);
}

bool DatagramMac::mac(std::span<const uint8_t> inner, Direction dir, uint32_t token, uint8_t out[32]) const {
  EVP_MAC_CTX* c = EVP_MAC_CTX_dup(hmac_ctx(ctx_));
  if (!c) return false;
  uint8_t prefix[5] = {uint8_t(dir), 0, 0, 0, 0};
  put32(prefix + 1, token);
  size_t len = 0;
  const bool ok = EVP_MAC_update(c, prefix, sizeof prefix) == 1 && EVP_MAC_update(c, inner.data(), inner.size()) == 1 &&
                  EVP_MAC_final(c, out, &len, 32) == 1 && len == 32;
  EVP_MAC_CTX_free(c);
  return ok;
}

void DatagramMac::seal(std::vector<uint8_t>& d, Direction dir, uint32_t token) const {
  uint8_t m[32];
  if (!mac(d, dir, token, m)) fail("OpenSSL: computing an HMAC failed");
  d.insert(d.end(), m, m + kMacBytes);
}

bool DatagramMac::verify(std::span<const uint8_t> d, Direction dir, uint32_t token) const {
  if (d.size() < kMacBytes) return false;
  const std::span<const uint8_t> inner = d.first(d.size() - kMacBytes);
  uint8_t m[32];
  if (!mac(inner, dir, token, m)) return false;
  return CRYPTO_memcmp(m, d.data() + inner.size(), kMacBytes) == 0;
}

uint32_t mac_token(std::span<const uint8_t> inner, uint32_t session_token) {
  if (inner.size() > kOffType && looks_like_control(inner)) {
    const uint8_t t = inner[kOffType];
    if (t == uint8_t(ControlType::Hello) || t == uint8_t(ControlType::Welcome) || t == uint8_t(ControlType::Refuse))
      return 0;
  }
  return session_token;
}

}  // namespace dhr
