// libFuzzer target: live mode's control path as the server and the client read it
// (read_control: the header, then the body typed by its message type; offer_mismatches; the
// MAC). Structure-aware: a fuzzer cannot forge a CRC, and random bytes are almost never JSON,
// let alone an offer, so the input describes a message and this target builds it with a valid
// header and CRC:
//   byte 0   bits 0-2: the type (1..5 Hello..Bye; 0, 6, 7: a header type out of range)
//            bit 3: the body is built as JSON from the rest (else: the rest is the body's bytes)
//            bit 4: seal with a MAC, then flip one byte of the datagram chosen by byte 5
//            bit 5: send the body through a raw header (no length limit: bodies > 8192 reach
//                   the length check)
//   bytes 1-4 the header's token / nonce, little-endian
//   byte 5   MAC mode: which byte to flip
//   then     JSON mode: a program that starts from the real offer (or a Welcome around it) and
//            replaces, removes or adds fields with arbitrary JSON values (any type, nesting up
//            to 80 levels, so that the depth limit is crossed too); else the body's bytes
// Checked: nothing throws or crashes; an accepted Hello/Welcome has every typed field in its
// range and re-encodes to the same typed values; Refuse/Bye reasons are printable ASCII that
// a JSON writer accepts; offer_mismatches never throws for any shape; a sealed datagram
// verifies and a flipped one does not.
#include "backends/register_all.h"
#include "core/base/json_io.h"
#include "core/live/live.h"
#include "core/live/live_protocol.h"
#include "core/sim/frame_loop.h"
#include "tests/fuzz/fuzz_common.h"

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

namespace {

using namespace dhr;
using nlohmann::json;

const json& reference_offer() {
  static const json offer = session_offer(SimConfig{}, registries(), "room", "0123456789abcdef");
  return offer;
}

const DatagramMac& test_mac() {
  static const DatagramMac mac(std::vector<uint8_t>(32, 0x5a));
  return mac;
}

// Field names worth hitting: the offer's and the Welcome's, and a few nested ones.
const char* const kKeys[] = {"protocol",
                             "scene",
                             "scene_hash",
                             "width",
                             "height",
                             "display_hz",
                             "start_time_s",
                             "seed",
                             "trace",
                             "visibility_codec",
                             "ao_codec",
                             "ao_denoiser",
                             "visibility_denoiser",
                             "max_payload_bytes",
                             "name",
                             "params",
                             "session",
                             "client_nonce",
                             "first_sequence",
                             "visibility",
                             "ao",
                             "offer",
                             "x"};
constexpr size_t kKeyCount = sizeof kKeys / sizeof kKeys[0];

json any_value(fuzz::Reader& in, int depth) {
  const uint8_t kind = in.u8();
  switch (kind % 12) {
    case 0: return nullptr;
    case 1: return (kind & 0x10) != 0;
    case 2: return int64_t(int32_t(in.u16() | (uint32_t(in.u16()) << 16)));
    case 3: return uint64_t(in.u16()) << (in.u8() % 49);
    case 4: return double(int16_t(in.u16())) / 7.0;
    case 5: return std::string(kKeys[in.u8() % kKeyCount]);
    case 6: {
      const auto bytes = in.take(in.u8() % 24);
      return std::string(bytes.begin(), bytes.end());  // maybe invalid UTF-8: dump must not throw later
    }
    case 7:
    case 8: {
      json a = json::array();
      const int n = depth >= 80 ? 0 : in.u8() % 4;
      for (int i = 0; i < n && !in.empty(); ++i) a.push_back(any_value(in, depth + 1));
      if ((kind & 0x20) && depth < 80) a = json::array({any_value(in, depth + 1)});  // deep chains
      return a;
    }
    default: {
      json o = json::object();
      const int n = depth >= 80 ? 0 : in.u8() % 4;
      for (int i = 0; i < n && !in.empty(); ++i) o[kKeys[in.u8() % kKeyCount]] = any_value(in, depth + 1);
      return o;
    }
  }
}

// Edits `j` along a path of known keys: set a value, erase a key, or descend.
void edit(json& j, fuzz::Reader& in) {
  json* at = &j;
  for (int depth = 0; depth < 4 && !in.empty(); ++depth) {
    const uint8_t op = in.u8();
    const char* key = kKeys[in.u8() % kKeyCount];
    if (!at->is_object()) {
      *at = any_value(in, depth);
      return;
    }
    if (op % 4 == 0) {
      at->erase(key);
      return;
    }
    if (op % 4 == 1 || !at->contains(key)) {
      (*at)[key] = any_value(in, depth);
      return;
    }
    at = &(*at)[key];
  }
}

std::string json_body(ControlType type, uint32_t token, fuzz::Reader& in) {
  const uint8_t start = in.u8();
  json j;
  if (start % 4 == 0) {
    j = any_value(in, 0);
  } else if (type == ControlType::Welcome) {
    WelcomeBody w;
    w.session = token;
    w.client_nonce = uint32_t(in.u16());
    w.first_sequence[0] = uint32_t(in.u16()) << 16;
    w.first_sequence[1] = in.u16();
    w.offer.json = reference_offer();
    j = json::parse(welcome_text(w));
  } else {
    j = reference_offer();
  }
  const int edits = start / 4 % 8;
  for (int i = 0; i < edits && !in.empty(); ++i) edit(j, in);
  // Invalid UTF-8 in a generated string: a sender's bytes would carry it; dump replaces it so
  // that this target can build the text (the parser then sees valid JSON).
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

std::vector<uint8_t> raw_control(uint8_t type, uint32_t token, const std::string& body) {
  std::vector<uint8_t> d(kControlHeaderBytes + body.size(), 0);
  std::memcpy(d.data(), kControlMagic, 4);
  d[4] = kControlVersion;
  d[5] = type;
  for (int i = 0; i < 4; ++i) d[size_t(8 + i)] = uint8_t(token >> (8 * i));
  d[12] = uint8_t(body.size() & 0xff);
  d[13] = uint8_t((body.size() >> 8) & 0xff);
  if (!body.empty()) std::memcpy(d.data() + kControlHeaderBytes, body.data(), body.size());
  seal_control(d);
  return d;
}

bool printable(const std::string& s) {
  for (char ch : s)
    if (static_cast<unsigned char>(ch) < 0x20 || static_cast<unsigned char>(ch) >= 0x7f) return false;
  return true;
}

void check_offer(const SessionOffer& o) {
  DHR_FUZZ_CHECK(o.json.is_object());
  DHR_FUZZ_CHECK(o.width >= 1 && o.width <= (1 << 16) && o.height >= 1 && o.height <= (1 << 16));
  DHR_FUZZ_CHECK(std::isfinite(o.display_hz) && o.display_hz > 0 && std::isfinite(o.start_time_s));
  DHR_FUZZ_CHECK(o.max_payload_bytes >= 1 && o.max_payload_bytes <= int64_t(kMaxPayloadLimitBytes));
  DHR_FUZZ_CHECK(o.trace.is_object() && o.ao_codec.params.is_object() && o.visibility_codec.params.is_object());
  // The server compares it with its own, both ways round, and dumps every difference.
  for (const std::string& line : offer_mismatches(o.json, reference_offer())) DHR_FUZZ_CHECK(!line.empty());
  (void)offer_mismatches(reference_offer(), o.json);
  // Typed values survive a re-encode.
  SessionOffer again;
  DHR_FUZZ_CHECK(parse_offer(o.json.dump(), again).ok());
  DHR_FUZZ_CHECK(again.width == o.width && again.seed == o.seed && again.ao_codec.name == o.ao_codec.name);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 6) return 0;
  fuzz::Reader in(data, size);
  const uint8_t mode = in.u8();
  uint32_t token = in.u8();
  token |= uint32_t(in.u8()) << 8;
  token |= uint32_t(in.u8()) << 16;
  token |= uint32_t(in.u8()) << 24;
  const uint8_t flip = in.u8();
  const uint8_t type = mode & 7;
  const bool known_type = type >= 1 && type <= 5;
  std::string body;
  if ((mode & 8) && known_type) {
    body = json_body(ControlType(type), token, in);
  } else {
    const auto rest = in.rest();
    body.assign(rest.begin(), rest.end());
  }
  std::vector<uint8_t> d;
  if ((mode & 32) || !known_type || body.size() > kMaxControlBody || type == uint8_t(ControlType::Camera)) {
    d = raw_control(type, token, body.substr(0, 65000));
  } else {
    ControlMessage m;
    m.type = ControlType(type);
    m.session = token;
    m.text = body;
    d = encode_control(m);
  }

  // What the server and the client do with a datagram: the MAC first (with a key), then
  // read_control, then the typed message.
  if (mode & 16) {
    std::vector<uint8_t> sealed = d;
    const uint32_t session = token ^ 0x9e3779b9u;
    test_mac().seal(sealed, Direction::ToServer, mac_token(d, session));
    DHR_FUZZ_CHECK(test_mac().verify(sealed, Direction::ToServer, mac_token(d, session)));
    DHR_FUZZ_CHECK(!test_mac().verify(sealed, Direction::ToClient, mac_token(d, session)));
    sealed[flip % sealed.size()] ^= uint8_t(1u << (flip % 8));
    DHR_FUZZ_CHECK(!test_mac().verify(sealed, Direction::ToServer, mac_token(d, session)));
  }
  TypedControl out;
  const char* why = read_control(d, out);
  if (why) {
    DHR_FUZZ_CHECK(std::strlen(why) > 0);
    return 0;
  }
  DHR_FUZZ_CHECK(known_type && out.message.type == ControlType(type) && out.message.session == token);
  switch (out.message.type) {
    case ControlType::Hello: check_offer(out.offer); break;
    case ControlType::Welcome: {
      DHR_FUZZ_CHECK(out.welcome.session == token && token != 0);
      check_offer(out.welcome.offer);
      WelcomeBody again;
      DHR_FUZZ_CHECK(parse_welcome(welcome_text(out.welcome), again).ok());
      DHR_FUZZ_CHECK(again.client_nonce == out.welcome.client_nonce &&
                     again.first_sequence[0] == out.welcome.first_sequence[0] &&
                     again.first_sequence[1] == out.welcome.first_sequence[1]);
      break;
    }
    case ControlType::Refuse:
    case ControlType::Bye:
      DHR_FUZZ_CHECK(printable(out.message.text) && out.message.text.size() <= kMaxReasonChars + 3);
      (void)json(out.message.text).dump();  // server.json and live.json hold it: must not throw
      break;
    case ControlType::Camera: DHR_FUZZ_CHECK(std::isfinite(out.message.camera.scene_time_s)); break;
  }
  // Any shape at all, compared as the server would if it skipped the typed check.
  json any;
  try {
    any = parse_json(body, "fuzz");
  } catch (const Error&) {
    return 0;
  }
  (void)offer_mismatches(any, reference_offer());
  return 0;
}
