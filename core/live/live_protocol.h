// Live mode's control messages (dhrbench serve / client / relay), beside the pass packets of
// core/net/packet.h. Every control message is one datagram with a fixed little-endian header
// that is checked before anything in it is used:
//
//   offset size field
//        0    4 magic "DHRC"
//        4    1 version (kControlVersion)
//        5    1 type (ControlType)
//        6    2 reserved, 0
//        8    4 session token (Hello, Refuse: the client's nonce instead)
//       12    2 body bytes (<= kMaxControlBody)
//       14    2 reserved, 0
//       16    4 CRC-32C of bytes 0..15 followed by the body
//       20      body
//
// The session: the client sends Hello (a random nonce in the token field; its offer: a JSON
// object naming the scene and its content hash, resolution, display rate, passes and codecs;
// see live.h) until the server answers Welcome (the session token, drawn from the OS's random
// source, in the header; a JSON object echoing the nonce, with the first sequence number of
// each pass stream and the server's view of the offer) or Refuse (the nonce; why, naming every
// field that disagrees). Then the client sends one Camera per displayed frame and the server
// streams the passes as pass packets whose stream id is the token's low 16 bits. Either side
// ends with Bye (a reason); silence for the idle timeout ends it too.
//
// Nothing in a datagram is trusted (docs/live-security.md): the header is checked here, every
// body is parsed into a typed struct with each field's type checked (parse_offer,
// parse_welcome, read_control), and the session's checks (the peer's address, the token, the
// windows of frame ids and sequence numbers, the optional MAC) refuse anything else, each with
// a reason that is counted. No function here throws for any datagram.
#pragma once

#include "core/buffers/camera.h"
#include "core/net/packet.h"
#include "core/net/rate_controller.h"

#include <nlohmann/json.hpp>

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace dhr {

constexpr uint8_t kControlMagic[4] = {'D', 'H', 'R', 'C'};
constexpr uint8_t kControlVersion = 1;
constexpr size_t kControlHeaderBytes = 20;
constexpr size_t kMaxControlBody = 8192;

enum class ControlType : uint8_t { Hello = 1, Welcome = 2, Refuse = 3, Camera = 4, Bye = 5 };
const char* control_type_name(ControlType t);

// Pass streams of a session: slot i carries pass_types()[i] (core/pass/passes.h); kPassSlots is
// their most (pass_types() checks it).
constexpr int kPassSlots = 8;
int pass_slot(PassKind kind);  // -1 for a pass live mode does not stream (colour)
int pass_slot_count();         // pass_types().size()
// A per-slot array with every entry `value` (-1: "none" for indices and frames).
template <class T>
constexpr std::array<T, kPassSlots> filled(T value) {
  std::array<T, kPassSlots> a{};
  a.fill(value);
  return a;
}

// One displayed client frame's camera: the server renders its passes for exactly this camera.
struct CameraUpdate {
  uint32_t frame = 0;  // the client's frame index (the pass packets' frame id)
  bool keyframe_request = false;
  double scene_time_s = 0.0;  // scene time of the frame (animation)
  Camera camera;              // every field, bit for bit
  // Per pass stream (slot), after a loss: the newest frame its decoder still holds, which the
  // server may predict from instead of sending a keyframe (Codec::holds; -1: none). On the
  // wire 0xffffffff; any other value must be older than `frame`.
  std::array<int32_t, kPassSlots> holds = filled<int32_t>(-1);
  // Adaptive bitrate (the session's abr setting, core/net/rate_controller.h): the client's running
  // counts of datagrams received and lost, and its reports of the pass frames completed or lost
  // since the last camera (FrameReport::pass is the stream slot; arrival_ms the client's clock).
  // On the wire after the fixed body: u64 received, u64 lost, u16 count, then per report u32
  // frame, u8 slot, u8 lost (0 or 1), u16 reserved 0, f64 arrival_ms (finite); at most
  // kMaxFrameReports. Absent (a body of kCameraBodyBytes) when has_reports is false.
  bool has_reports = false;
  uint64_t datagrams_received = 0, datagrams_lost = 0;
  std::vector<FrameReport> reports;
};
constexpr size_t kCameraBodyBytes = 4 + 4 + 8 + 12 * 4 + 2 * 2 + 4 * kPassSlots;
constexpr size_t kMaxFrameReports = 64;

struct ControlMessage {
  ControlType type = ControlType::Hello;
  uint32_t session = 0;
  std::string text;     // Hello, Welcome: JSON; Refuse, Bye: the reason
  CameraUpdate camera;  // Camera
};

enum class ControlParse : uint8_t {
  Ok = 0,
  NotControl,  // too short or another magic (e.g. a pass packet): not for this parser
  BadVersion,
  BadChecksum,
  BadLength,  // body length disagrees with the datagram
  BadType,
  BadBody,  // a Camera body with non-finite values, a bad camera, a wrong size
  BadReserved,
};
const char* control_parse_name(ControlParse r);

std::vector<uint8_t> encode_control(const ControlMessage& m);
// Never throws; on anything but Ok, `out` is unspecified.
ControlParse parse_control(std::span<const uint8_t> datagram, ControlMessage& out);
// Recomputes the checksum in place (for tests and fuzzers that craft messages; the datagram
// must be at least a header long).
void seal_control(std::span<uint8_t> datagram);
// True when the datagram starts with the control magic (cheap dispatch before parsing).
bool looks_like_control(std::span<const uint8_t> datagram);

// ---- typed bodies ---------------------------------------------------------------------------

// Why a control message's body was refused. Counted as "<type>_<reason>" (e.g.
// "hello_not_an_object"), so the set of counter names is fixed.
enum class BodyReject : uint8_t {
  Ok = 0,
  NotJson,       // not valid JSON (or a number out of range)
  TooDeep,       // nested deeper than kMaxJsonDepth
  NotObject,     // valid JSON, but not an object ([1], null, 5, "x")
  MissingField,  // a field the message needs is absent
  WrongType,     // a field of another JSON type ("width": "96")
  BadValue,      // a field of the right type out of its range, or disagreeing with the header
};
const char* body_reject_name(BodyReject r);

struct BodyCheck {
  BodyReject reject = BodyReject::Ok;
  std::string field;  // the offending field (dotted), for messages
  bool ok() const { return reject == BodyReject::Ok; }
};

// A backend choice in an offer: its registry name and effective parameters (an object).
struct OfferBackend {
  std::string name;
  nlohmann::json params = nlohmann::json::object();
};

// The Hello's offer (and the Welcome's copy), typed. `json` keeps the object as received: the
// server compares it field by field with its own (offer_mismatches in live.h), so that every
// difference, unknown fields included, is named in the Refuse.
struct SessionOffer {
  int64_t protocol = 0;
  std::string scene, scene_hash;
  int64_t width = 0, height = 0;
  double display_hz = 0.0, start_time_s = 0.0;
  uint64_t seed = 0;
  nlohmann::json trace = nlohmann::json::object();  // an object; compared, never read
  OfferBackend visibility_codec, ao_codec, ao_denoiser, visibility_denoiser;
  int64_t max_payload_bytes = 0;
  nlohmann::json json = nlohmann::json::object();
};
// Parses the text of a Hello body (through dhr::parse_json: depth-bounded) and checks every
// field's type: integers are integers, numbers finite, names strings, backends objects with a
// string name and an object of params. Never throws.
BodyCheck parse_offer(std::string_view text, SessionOffer& out);
BodyCheck parse_offer_json(const nlohmann::json& offer, SessionOffer& out);

struct WelcomeBody {
  uint32_t session = 0;                               // equals the header's token
  uint32_t client_nonce = 0;                          // the nonce of the Hello it answers
  std::array<uint32_t, kPassSlots> first_sequence{};  // random, per stream (see PassGate)
  SessionOffer offer;                                 // the server's
};
std::string welcome_text(const WelcomeBody& w);
BodyCheck parse_welcome(std::string_view text, WelcomeBody& out);

// Refuse's and Bye's reason, made printable ASCII: control bytes (terminal escapes) and bytes
// above 0x7e (which could be invalid UTF-8, that a JSON writer refuses) become '?'; at most
// kMaxReasonChars are kept. Never refuses.
constexpr size_t kMaxReasonChars = 1024;
std::string printable_reason(std::string_view text);

// A control datagram read whole: the header (parse_control), then its body typed by its type.
struct TypedControl {
  ControlMessage message;  // type, token, camera; text: Refuse/Bye reason, printable
  SessionOffer offer;      // Hello
  WelcomeBody welcome;     // Welcome
  std::string field;       // when refused for a body field: which
};
// Returns nullptr when the datagram is a well-formed control message of its type, else the
// counter name of why not: a ControlParse name ("bad_checksum", "not_control", ...) or
// "<type>_<BodyReject name>" ("hello_not_an_object", "welcome_wrong_type"). The names come
// from fixed tables (the returned pointer stays valid). Never throws. The server, the client
// and fuzz_live_control all read control datagrams through this.
const char* read_control(std::span<const uint8_t> datagram, TypedControl& out);

// ---- the session's pass packets ----------------------------------------------------------------

// The client's check that a pass packet (already through parse_packet) is its session's: the
// stream id is the token's low 16 bits, the pass is one the session streams with the codec it
// agreed, the frame id is one the client has asked for (no later than its newest camera), and
// the sequence number lies between the stream's first one (from the Welcome) and
// kSequenceWindow packets past the newest accepted. Anything else is refused with a reason and
// changes nothing: a forged packet cannot push the assembler's loss count or its newest frame.
class PassGate {
 public:
  // Far enough ahead to pass any burst of loss the session survives (its idle timeout ends it
  // first at any realistic rate); bounded so that a packet outside it cannot count as loss.
  static constexpr uint32_t kSequenceWindow = 1u << 16;

  PassGate() = default;
  // codec_ids[slot] == 0 and streams[slot] false: that pass is not streamed.
  PassGate(uint32_t token, const std::array<uint32_t, kPassSlots>& first_sequence,
           const std::array<uint32_t, kPassSlots>& codec_ids, const std::array<bool, kPassSlots>& streams);
  void camera_sent(uint32_t frame);
  // nullptr: accepted (the stream's newest sequence number advances); else the counter name:
  // "packet_wrong_token", "packet_unexpected_pass", "packet_wrong_codec", "packet_frame_ahead",
  // "packet_sequence_out_of_window".
  const char* check(const ParsedPacket& p);

 private:
  uint16_t stream_ = 0;
  bool streams_[kPassSlots] = {};
  uint32_t codec_[kPassSlots] = {};
  uint32_t first_[kPassSlots] = {};
  uint64_t newest_offset_[kPassSlots] = {};  // past the newest accepted, from first_
  bool any_camera_ = false;
  uint32_t newest_camera_ = 0;
};

// A camera frame id further than this ahead of the server's newest one is refused
// ("camera_frame_ahead"): the client's frames are consecutive, and a forged far-future frame
// would make every later camera look stale.
constexpr uint32_t kMaxCameraFramesAhead = 1u << 14;

// ---- randomness and authentication -----------------------------------------------------------

// A uniformly random 32-bit value from the OS (getrandom(2), else /dev/urandom), never 0.
// Throws dhr::Error only when the OS has no random source.
uint32_t os_random_u32();

// Which way a datagram goes, mixed into its MAC so that nothing can be reflected back.
enum class Direction : uint8_t { ToServer = 'S', ToClient = 'C' };

// Optional authentication (--key-file): every datagram carries a trailer of kMacBytes, the
// first 16 bytes of HMAC-SHA256(key, direction || token || datagram), where token is the
// session token (little-endian) for Camera, Bye and pass packets and 0 for Hello, Welcome and
// Refuse (their headers, which the MAC covers, carry the nonce or the new token). The trailer
// sits after the datagram, so the packet and control formats are unchanged inside it.
constexpr size_t kMacBytes = 16;
constexpr size_t kMinKeyBytes = 16, kMaxKeyBytes = 4096;
class DatagramMac {
 public:
  // Throws dhr::Error for a key outside kMinKeyBytes..kMaxKeyBytes or an OpenSSL failure.
  explicit DatagramMac(std::span<const uint8_t> key);
  // The key is the file's bytes, as they are (e.g. head -c 32 /dev/urandom > live.key).
  static DatagramMac from_file(const std::string& path);
  // Appends the trailer.
  void seal(std::vector<uint8_t>& datagram, Direction dir, uint32_t session_token) const;
  // True when the last kMacBytes of `datagram` are the MAC of the rest (compared in constant
  // time). Never throws.
  bool verify(std::span<const uint8_t> datagram, Direction dir, uint32_t session_token) const;

 private:
  bool mac(std::span<const uint8_t> inner, Direction dir, uint32_t token, uint8_t out[32]) const;
  std::shared_ptr<void> ctx_;  // an initialized EVP_MAC_CTX (HMAC-SHA256 with the key)
};
// The token a datagram's MAC uses (see DatagramMac), from its (unauthenticated) type byte: a
// wrong guess only fails the check.
uint32_t mac_token(std::span<const uint8_t> inner, uint32_t session_token);

}  // namespace dhr
