// Live mode (core/live/live.h): the control protocol, the session offer, and server, relay and client
// as three real processes over loopback UDP -- through loss, jitter, reordering and
// duplication -- checked against the simulator's accounting of the same frames. Then the trust
// checks (docs/live-security.md): every malformed control message class refused with its
// reason, the pass-packet windows, the MAC, and a session that a third socket attacks with
// forged, malformed and random datagrams while it runs, ending exactly as a clean one.
#include "backends/register_all.h"
#include "core/base/json_io.h"
#include "core/experiment/experiment.h"
#include "core/live/live.h"
#include "core/live/live_protocol.h"
#include "core/net/packet.h"
#include "core/net/udp.h"
#include "core/pass/reference.h"
#include "core/scene/scene_load.h"
#include "core/sim/frame_loop.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <bit>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <thread>

extern char** environ;

namespace dhr {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// ---- protocol -----------------------------------------------------------------------------

CameraUpdate sample_camera() {
  CameraUpdate c;
  c.frame = 42;
  c.keyframe_request = true;
  c.scene_time_s = 0.7;
  c.camera = Camera::look_at({1.5f, 2.0f, -3.25f}, {0.0f, 1.0f, 0.0f}, {0, 1, 0}, 55.0f, 320, 180, 0.05f, 200.0f);
  c.holds[1] = 39;  // the AO stream's decoder holds frame 39
  c.holds[kPassSlots - 1] = 0;
  return c;
}

TEST(LiveProtocol, EveryMessageRoundTripsBitForBit) {
  for (ControlType t :
       {ControlType::Hello, ControlType::Welcome, ControlType::Refuse, ControlType::Camera, ControlType::Bye}) {
    ControlMessage m;
    m.type = t;
    m.session = 0xdeadbeef;
    m.text = t == ControlType::Camera ? "" : "{\"x\": 1} text";
    m.camera = sample_camera();
    const std::vector<uint8_t> d = encode_control(m);
    ControlMessage back;
    ASSERT_EQ(parse_control(d, back), ControlParse::Ok) << control_type_name(t);
    EXPECT_EQ(back.type, t);
    EXPECT_EQ(back.session, m.session);
    if (t == ControlType::Camera) {
      EXPECT_EQ(back.camera.frame, 42u);
      EXPECT_TRUE(back.camera.keyframe_request);
      EXPECT_EQ(back.camera.scene_time_s, 0.7);
      EXPECT_EQ(std::memcmp(&back.camera.camera.position, &m.camera.camera.position, sizeof(glm::vec3)), 0);
      EXPECT_EQ(std::memcmp(&back.camera.camera.forward, &m.camera.camera.forward, sizeof(glm::vec3)), 0);
      EXPECT_EQ(back.camera.camera.vfov_deg, m.camera.camera.vfov_deg);
      EXPECT_EQ(back.camera.camera.width, 320);
      EXPECT_EQ(back.camera.camera.height, 180);
      EXPECT_EQ(back.camera.holds, m.camera.holds);
      EXPECT_EQ(back.camera.holds[0], -1);
    } else {
      EXPECT_EQ(back.text, m.text);
    }
  }
}

TEST(LiveProtocol, DamagedAndForeignDatagramsAreRefused) {
  ControlMessage m;
  m.type = ControlType::Camera;
  m.session = 7;
  m.camera = sample_camera();
  const std::vector<uint8_t> good = encode_control(m);
  ControlMessage out;
  // Every single bit flip is caught (the checksum covers header and body).
  int accepted = 0;
  for (size_t bit = 0; bit < good.size() * 8; ++bit) {
    std::vector<uint8_t> d = good;
    d[bit / 8] ^= uint8_t(1u << (bit % 8));
    accepted += parse_control(d, out) == ControlParse::Ok;
  }
  EXPECT_EQ(accepted, 0);
  // Truncated, extended, empty, a pass packet.
  EXPECT_NE(parse_control(std::span(good).first(good.size() - 1), out), ControlParse::Ok);
  std::vector<uint8_t> longer = good;
  longer.push_back(0);
  EXPECT_NE(parse_control(longer, out), ControlParse::Ok);
  EXPECT_EQ(parse_control({}, out), ControlParse::NotControl);
  PacketMeta pm;
  pm.desc = {PassKind::Ao, 4, 4, 1, 8};
  const auto packets = packetize(pm, std::vector<uint8_t>(16, 3));
  EXPECT_EQ(parse_control(packets[0], out), ControlParse::NotControl);
  // A camera that would poison the server: non-finite, not unit, a zero-sized image, a held
  // frame that is not older than the camera's.
  for (int bad = 0; bad < 6; ++bad) {
    ControlMessage c = m;
    if (bad == 0) c.camera.camera.position.x = NAN;
    if (bad == 1) c.camera.camera.forward = {0, 0, -2};
    if (bad == 2) c.camera.camera.width = 0;
    if (bad == 3) c.camera.scene_time_s = INFINITY;
    if (bad == 4) c.camera.holds[0] = int32_t(c.camera.frame);
    if (bad == 5) c.camera.holds[2] = int32_t(c.camera.frame) + 5;
    EXPECT_EQ(parse_control(encode_control(c), out), ControlParse::BadBody) << bad;
  }
}

TEST(LiveOffer, MismatchesNameEveryField) {
  SimConfig a, b;
  b.width = 640;
  b.pass("ao").codec.name = "zstd";
  const json oa = session_offer(a, registries(), "room", "abc"),
             ob = session_offer(b, registries(), "scenes/room.json", "abc");
  EXPECT_TRUE(offer_mismatches(oa, session_offer(a, registries(), "other-name", "abc")).empty())
      << "the name alone may differ";
  const auto why = offer_mismatches(oa, ob);
  // width, ao_codec.name, and each of the codecs' parameters that differ (lz4 and zstd have
  // different ones): every line names its dotted field.
  std::string all;
  int params = 0;
  for (const auto& w : why) {
    all += w + "\n";
    params += w.rfind("ao_codec.params.", 0) == 0;
  }
  EXPECT_EQ(why.size(), size_t(2 + params)) << all;
  EXPECT_GE(params, 1) << all;
  EXPECT_NE(all.find("width: client 320, server 640"), std::string::npos) << all;
  EXPECT_NE(all.find("ao_codec.name: client \"lz4\", server \"zstd\""), std::string::npos) << all;
  // Effective parameters: an explicit default equals an omitted one.
  SimConfig c = a;
  c.pass("ao").codec.params = {{"mode", "fast"}};
  EXPECT_TRUE(offer_mismatches(oa, session_offer(c, registries(), "room", "abc")).empty());
  const auto scene = offer_mismatches(oa, session_offer(a, registries(), "room", "def"));
  ASSERT_FALSE(scene.empty());
  EXPECT_NE(scene[0].find("different content"), std::string::npos);
}

// ---- trust: typed control messages ----------------------------------------------------------

std::vector<uint8_t> control(ControlType type, uint32_t session, const std::string& body) {
  ControlMessage m;
  m.type = type;
  m.session = session;
  m.text = body;
  return encode_control(m);
}

// A control datagram whose body is `body` whatever its length (encode_control refuses bodies
// above kMaxControlBody; a sender need not): a valid header and CRC.
std::vector<uint8_t> raw_control(ControlType type, uint32_t session, const std::string& body) {
  std::vector<uint8_t> d(kControlHeaderBytes + body.size(), 0);
  std::memcpy(d.data(), kControlMagic, 4);
  d[4] = kControlVersion;
  d[5] = uint8_t(type);
  for (int i = 0; i < 4; ++i) d[size_t(8 + i)] = uint8_t(session >> (8 * i));
  d[12] = uint8_t(body.size() & 0xff);
  d[13] = uint8_t((body.size() >> 8) & 0xff);
  std::memcpy(d.data() + kControlHeaderBytes, body.data(), body.size());
  seal_control(d);
  return d;
}

json good_offer() { return session_offer(SimConfig{}, registries(), "room", "abc"); }

std::string welcome_for(uint32_t session) {
  WelcomeBody w;
  w.session = session;
  w.offer.json = good_offer();
  return welcome_text(w);
}

std::string name_of(const char* why) { return why ? why : "ok"; }

std::string with_field(const std::string& dotted, const json& value) {
  json o = good_offer();
  json* at = &o;
  std::string rest = dotted;
  for (size_t dot; (dot = rest.find('.')) != std::string::npos; rest = rest.substr(dot + 1))
    at = &(*at)[rest.substr(0, dot)];
  if (value.is_discarded())
    at->erase(rest);
  else
    (*at)[rest] = value;
  return o.dump();
}

// The reports for adaptive bitrate after a Camera's fixed body: they round-trip bit for bit,
// at most kMaxFrameReports go (the newest), and a bad field refuses the whole camera.
TEST(LiveProtocol, CameraReportsRoundTripAndBadOnesAreRefused) {
  ControlMessage m;
  m.type = ControlType::Camera;
  m.session = 9;
  m.camera = sample_camera();
  m.camera.has_reports = true;
  m.camera.datagrams_received = 123456789012ull;
  m.camera.datagrams_lost = 77;
  for (uint32_t f = 0; f < 70; ++f) m.camera.reports.push_back({f, int(f % 2), f % 5 == 0, 1000.25 + f});
  ControlMessage back;
  ASSERT_EQ(parse_control(encode_control(m), back), ControlParse::Ok);
  ASSERT_TRUE(back.camera.has_reports);
  EXPECT_EQ(back.camera.datagrams_received, 123456789012ull);
  EXPECT_EQ(back.camera.datagrams_lost, 77u);
  ASSERT_EQ(back.camera.reports.size(), kMaxFrameReports);
  for (size_t i = 0; i < kMaxFrameReports; ++i) {
    const FrameReport& want = m.camera.reports[70 - kMaxFrameReports + i];
    EXPECT_EQ(back.camera.reports[i].frame, want.frame);
    EXPECT_EQ(back.camera.reports[i].pass, want.pass);
    EXPECT_EQ(back.camera.reports[i].lost, want.lost);
    EXPECT_EQ(back.camera.reports[i].arrival_ms, want.arrival_ms);
  }
  // Without reports the body is the fixed one.
  ControlMessage plain = m;
  plain.camera.has_reports = false;
  ASSERT_EQ(parse_control(encode_control(plain), back), ControlParse::Ok);
  EXPECT_FALSE(back.camera.has_reports);
  EXPECT_TRUE(back.camera.reports.empty());
  // Bad fields: a slot past the streams, a lost flag of 2, a non-finite time, a reserved byte,
  // a count that disagrees with the length.
  m.camera.reports.resize(3);
  const std::vector<uint8_t> good = encode_control(m);
  const size_t first = kControlHeaderBytes + kCameraBodyBytes + kReportsHeadBytes;
  for (int bad = 0; bad < 5; ++bad) {
    std::vector<uint8_t> d = good;
    if (bad == 0) d[first + 4] = kPassSlots;
    if (bad == 1) d[first + 5] = 2;
    if (bad == 2) {
      const uint64_t nan = std::bit_cast<uint64_t>(std::numeric_limits<double>::quiet_NaN());
      for (int k = 0; k < 8; ++k) d[first + 8 + size_t(k)] = uint8_t(nan >> (8 * k));
    }
    if (bad == 3) d[first + 6] = 1;
    if (bad == 4) d[kControlHeaderBytes + kCameraBodyBytes + 16] = 4;  // count 4, three reports
    seal_control(d);
    EXPECT_EQ(parse_control(d, back), ControlParse::BadBody) << bad;
  }
}

TEST(LiveTrust, EveryMalformedControlMessageClassIsRefusedWithItsReason) {
  const json drop = json(json::value_t::discarded);
  struct Case {
    ControlType type;
    std::string body;
    std::string reason;
    std::string field;
  };
  const std::string deep_in_a_datagram = std::string(4000, '[') + std::string(4000, ']');
  const std::vector<Case> cases = {
      {ControlType::Hello, "[1]", "hello_not_an_object", ""},
      {ControlType::Hello, "null", "hello_not_an_object", ""},
      {ControlType::Hello, "5", "hello_not_an_object", ""},
      {ControlType::Hello, "\"offer\"", "hello_not_an_object", ""},
      {ControlType::Hello, "{\"a\":", "hello_not_json", ""},
      {ControlType::Hello, "", "hello_not_json", ""},
      {ControlType::Hello, "{\"width\": 1e400}", "hello_not_json", ""},
      {ControlType::Hello, "{\"width\": \"\xff\xfe\"}", "hello_not_json", ""},  // invalid UTF-8
      {ControlType::Hello, deep_in_a_datagram, "hello_too_deep", ""},
      {ControlType::Hello, "{}", "hello_missing_field", "protocol"},
      {ControlType::Hello, with_field("max_payload_bytes", drop), "hello_missing_field", "max_payload_bytes"},
      {ControlType::Hello, with_field("width", "96"), "hello_wrong_type", "width"},
      {ControlType::Hello, with_field("width", 96.5), "hello_wrong_type", "width"},
      {ControlType::Hello, with_field("scene_hash", 7), "hello_wrong_type", "scene_hash"},
      {ControlType::Hello, with_field("trace", json::array()), "hello_wrong_type", "trace"},
      {ControlType::Hello, with_field("ao_codec", "lz4"), "hello_wrong_type", "ao_codec"},
      {ControlType::Hello, with_field("ao_codec.name", json::array({1})), "hello_wrong_type", "ao_codec.name"},
      {ControlType::Hello, with_field("ao_codec.params", json::array()), "hello_wrong_type", "ao_codec.params"},
      {ControlType::Hello, with_field("visibility_denoiser.name", drop), "hello_missing_field",
       "visibility_denoiser.name"},
      {ControlType::Hello, with_field("display_hz", nullptr), "hello_wrong_type", "display_hz"},
      {ControlType::Hello, with_field("width", -96), "hello_bad_value", "width"},
      {ControlType::Hello, with_field("width", 18446744073709551615ull), "hello_bad_value", "width"},
      {ControlType::Hello, with_field("display_hz", 0), "hello_bad_value", "display_hz"},
      {ControlType::Hello, with_field("seed", -1), "hello_bad_value", "seed"},
      {ControlType::Hello, with_field("max_payload_bytes", 0), "hello_bad_value", "max_payload_bytes"},
      {ControlType::Welcome, "[1]", "welcome_not_an_object", ""},
      {ControlType::Welcome, "{\"a\":", "welcome_not_json", ""},
      {ControlType::Welcome, welcome_for(9), "welcome_bad_value", "session"},  // the header says 7
      {ControlType::Welcome, "{\"session\": 7}", "welcome_missing_field", "client_nonce"},
      {ControlType::Welcome, "{\"session\": \"7\"}", "welcome_wrong_type", "session"},
      {ControlType::Welcome,
       R"({"session": 7, "client_nonce": 1, "first_sequence": {"visibility": 0, "ao": "x"}, "offer": {}})",
       "welcome_wrong_type", "first_sequence.ao"},
      {ControlType::Welcome,
       R"({"session": 7, "client_nonce": 1, "first_sequence": {"visibility": 0, "ao": 4294967296}, "offer": {}})",
       "welcome_bad_value", "first_sequence.ao"},
      {ControlType::Welcome,
       R"({"session": 7, "client_nonce": 1, "first_sequence": {"visibility": 0, "ao": 1}, "offer": {}})",
       "welcome_missing_field", "offer.protocol"},
      {ControlType::Welcome,
       R"({"session": 7, "client_nonce": 1, "first_sequence": {"visibility": 0, "ao": 1}, "offer": 5})",
       "welcome_wrong_type", "offer"},
  };
  for (const Case& c : cases) {
    TypedControl out;
    const char* why = read_control(control(c.type, 7, c.body), out);
    ASSERT_NE(why, nullptr) << c.body.substr(0, 80);
    EXPECT_EQ(std::string(why), c.reason) << c.body.substr(0, 80);
    EXPECT_EQ(out.field, c.field) << c.body.substr(0, 80);
  }
  // Deeper than a datagram can carry: the typed parser alone (100k levels), and a Hello whose
  // body is longer than the limit: refused by its length before anything reads it.
  SessionOffer offer;
  EXPECT_EQ(parse_offer(std::string(100000, '[') + std::string(100000, ']'), offer).reject, BodyReject::TooDeep);
  EXPECT_EQ(parse_offer(std::string(100000, '{'), offer).reject, BodyReject::TooDeep);
  TypedControl out;
  EXPECT_STREQ(read_control(raw_control(ControlType::Hello, 0, std::string(65000, '[')), out), "bad_length");
  // A camera that would poison the server.
  ControlMessage cam;
  cam.type = ControlType::Camera;
  cam.camera = sample_camera();
  cam.camera.camera.near_m = -1.0f;
  EXPECT_STREQ(read_control(encode_control(cam), out), "bad_body");
  // Refuse and Bye: any reason is accepted, made printable (no terminal escapes, valid JSON).
  for (ControlType t : {ControlType::Refuse, ControlType::Bye}) {
    ASSERT_EQ(read_control(control(t, 7, "done\x1b[2J\xff\n" + std::string(5000, 'x')), out), nullptr);
    EXPECT_EQ(out.message.text.substr(0, 8), "done?[2J");
    EXPECT_EQ(out.message.text.find_first_of("\x1b\xff\n"), std::string::npos);
    EXPECT_LE(out.message.text.size(), kMaxReasonChars + 3);
    EXPECT_NO_THROW((void)json(out.message.text).dump());
  }
  // The real offer and Welcome are accepted, typed.
  ASSERT_EQ(read_control(control(ControlType::Hello, 5, good_offer().dump()), out), nullptr);
  EXPECT_EQ(out.offer.width, 320);
  EXPECT_EQ(out.offer.ao_codec.name, "lz4");
  EXPECT_TRUE(offer_mismatches(out.offer.json, good_offer()).empty());
  WelcomeBody w;
  w.session = 0xabcdef01;
  w.client_nonce = 5;
  w.first_sequence[0] = 4000000000u;
  w.first_sequence[1] = 17;
  w.offer.json = good_offer();
  ASSERT_EQ(read_control(control(ControlType::Welcome, w.session, welcome_text(w)), out), nullptr);
  EXPECT_EQ(out.welcome.client_nonce, 5u);
  EXPECT_EQ(out.welcome.first_sequence[0], 4000000000u);
  EXPECT_EQ(out.welcome.offer.scene_hash, "abc");
}

TEST(LiveTrust, OfferComparisonNeverThrowsWhateverTheShapes) {
  for (const json& odd : {json::array({1}), json(nullptr), json(5), json("x"), json::object(),
                          json{{"scene_hash", 5}, {"scene", json::array()}}, json{{"trace", {{"spp", "many"}}}}}) {
    std::vector<std::string> why;
    EXPECT_NO_THROW(why = offer_mismatches(odd, good_offer())) << odd.dump();
    EXPECT_FALSE(why.empty()) << odd.dump();
    EXPECT_NO_THROW(why = offer_mismatches(good_offer(), odd)) << odd.dump();
  }
}

// A pass packet of the session's stream, parsed (its payload points into `storage`).
ParsedPacket pass_packet(std::vector<uint8_t>& storage, uint16_t stream, PassKind kind, uint32_t frame,
                         uint32_t sequence, const char* codec = "lz4") {
  PacketMeta m;
  m.stream_id = stream;
  m.desc = {kind, 96, 64, 1, kind == PassKind::Ao ? 8 : 1};
  m.frame_id = frame;
  m.codec_id = codec_id(codec);
  m.first_sequence = sequence;
  storage = packetize(m, std::vector<uint8_t>(40, 1))[0];
  ParsedPacket p;
  EXPECT_EQ(parse_packet(storage, p), ParseResult::Ok);
  return p;
}

TEST(LiveTrust, ThePassGateRefusesWhatTheSessionDidNotAskFor) {
  const uint32_t token = 0x12345678;
  const std::array<uint32_t, kPassSlots> first{4294967000u, 1000}, codecs{codec_id("lz4"), codec_id("lz4")};
  const std::array<bool, kPassSlots> streams{false, true};  // AO only
  PassGate gate(token, first, codecs, streams);
  std::vector<uint8_t> b;
  const uint16_t stream = 0x5678;
  auto check = [&](const ParsedPacket& p) { return name_of(gate.check(p)); };
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 0, 1000)), "packet_frame_ahead");  // no camera sent yet
  gate.camera_sent(0);
  gate.camera_sent(3);
  EXPECT_EQ(check(pass_packet(b, 0x5679, PassKind::Ao, 0, 1000)), "packet_wrong_token");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Visibility, 0, 1000)), "packet_unexpected_pass");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 0, 1000, "zstd")), "packet_wrong_codec");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 4, 1000)), "packet_frame_ahead");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 999670, 1000)), "packet_frame_ahead");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 3, 999)), "packet_sequence_out_of_window");  // before the first
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 3, 1000 + PassGate::kSequenceWindow)),
            "packet_sequence_out_of_window");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 3, 1000 + 5)), "ok");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 2, 1000)), "ok");  // behind the newest: the assembler judges
  // The window moves with what was accepted, and nothing refused moved it.
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 3, 1000 + 5 + PassGate::kSequenceWindow)), "ok");
  EXPECT_EQ(check(pass_packet(b, stream, PassKind::Ao, 3, 1000 + 6 + 2 * PassGate::kSequenceWindow)),
            "packet_sequence_out_of_window");
  // Sequence numbers wrap modulo 2^32 (the visibility stream's first one is close to the top).
  const std::array<bool, kPassSlots> both{true, true};
  PassGate wrap(token, first, codecs, both);
  wrap.camera_sent(0);
  EXPECT_EQ(name_of(wrap.check(pass_packet(b, stream, PassKind::Visibility, 0, 4294967000u))), "ok");
  EXPECT_EQ(name_of(wrap.check(pass_packet(b, stream, PassKind::Visibility, 0, 100))), "ok");
  EXPECT_STREQ(wrap.check(pass_packet(b, stream, PassKind::Visibility, 0, 4294966000u)),
               "packet_sequence_out_of_window");
}

TEST(LiveTrust, TheMacRefusesTamperedReflectedAndOtherSessionsDatagrams) {
  std::vector<uint8_t> key(32);
  for (size_t i = 0; i < key.size(); ++i) key[i] = uint8_t(i * 7 + 1);
  const DatagramMac mac(key);
  std::vector<uint8_t> d = control(ControlType::Bye, 99, "done");
  const size_t inner = d.size();
  mac.seal(d, Direction::ToServer, mac_token(d, 99));
  ASSERT_EQ(d.size(), inner + kMacBytes);
  EXPECT_TRUE(mac.verify(d, Direction::ToServer, 99));
  EXPECT_FALSE(mac.verify(d, Direction::ToClient, 99)) << "reflected back";
  EXPECT_FALSE(mac.verify(d, Direction::ToServer, 98)) << "another session's token";
  EXPECT_FALSE(mac.verify(std::span(d).first(d.size() - 1), Direction::ToServer, 99));
  EXPECT_FALSE(mac.verify(std::span(d).first(kMacBytes - 1), Direction::ToServer, 99));
  EXPECT_FALSE(mac.verify({}, Direction::ToServer, 99));
  int accepted = 0;
  for (size_t bit = 0; bit < d.size() * 8; ++bit) {
    std::vector<uint8_t> t = d;
    t[bit / 8] ^= uint8_t(1u << (bit % 8));
    accepted += mac.verify(t, Direction::ToServer, 99);
  }
  EXPECT_EQ(accepted, 0);
  key[0] ^= 1;
  EXPECT_FALSE(DatagramMac(key).verify(d, Direction::ToServer, 99)) << "another key";
  // Hello, Welcome and Refuse are sealed before a token exists.
  EXPECT_EQ(mac_token(control(ControlType::Hello, 5, "{}"), 99), 0u);
  EXPECT_EQ(mac_token(control(ControlType::Camera, 5, ""), 99), 99u);
  EXPECT_EQ(mac_token(std::vector<uint8_t>(50, 0), 99), 99u);
  // Keys: too short, too long, from a file.
  EXPECT_THROW(DatagramMac(std::vector<uint8_t>(15, 1)), Error);
  EXPECT_THROW(DatagramMac(std::vector<uint8_t>(kMaxKeyBytes + 1, 1)), Error);
  const fs::path f = fs::temp_directory_path() / ("dhr_live_key_" + std::to_string(getpid()));
  std::ofstream(f, std::ios::binary) << "0123456789abcdef";
  EXPECT_NO_THROW(DatagramMac::from_file(f.string()));
  std::ofstream(f, std::ios::binary) << "short";
  EXPECT_THROW(DatagramMac::from_file(f.string()), Error);
  EXPECT_THROW(DatagramMac::from_file(f.string() + ".missing"), Error);
  fs::remove(f);
}

TEST(LiveTrust, TokensComeFromTheOsAndAreNeverZero) {
  std::set<uint32_t> seen;
  for (int i = 0; i < 64; ++i) {
    const uint32_t v = os_random_u32();
    EXPECT_NE(v, 0u);
    seen.insert(v);
  }
  EXPECT_GE(seen.size(), 63u);
}

// ---- processes ----------------------------------------------------------------------------

struct Process {
  pid_t pid = -1;
  std::string log;
  int exit_code = -1;

  static Process start(const std::vector<std::string>& args, const std::string& log) {
    Process p;
    p.log = log;
    std::vector<char*> argv;
    std::vector<std::string> all{DHR_CLI};
    all.insert(all.end(), args.begin(), args.end());
    for (auto& a : all) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    if (posix_spawn(&p.pid, DHR_CLI, &fa, nullptr, argv.data(), environ) != 0) p.pid = -1;
    posix_spawn_file_actions_destroy(&fa);
    return p;
  }
  // Waits up to `seconds`; kills the process when it does not exit in time (a hang: returns false).
  bool wait(double seconds) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < end) {
      int status = 0;
      if (waitpid(pid, &status, WNOHANG) == pid) {
        exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        pid = -1;
        return true;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    kill(pid, SIGKILL);
    waitpid(pid, nullptr, 0);
    pid = -1;
    return false;
  }
  std::string output() const {
    std::ifstream in(log);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  }
  ~Process() {
    if (pid > 0) {
      kill(pid, SIGKILL);
      waitpid(pid, nullptr, 0);
    }
  }
};

// The port a process wrote to its --port-file (waits for it: loading and the BVH come first).
int wait_port(const fs::path& file, const Process& p, double seconds = 60) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    std::ifstream in(file);
    int port = 0;
    if (in >> port && port > 0) return port;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ADD_FAILURE() << "no port in " << file << " after " << seconds << " s; log:\n" << p.output();
  return 0;
}

json read_json(const fs::path& p) {
  std::ifstream in(p);
  if (!in) {
    ADD_FAILURE() << "missing " << p;
    return json::object();
  }
  return json::parse(in);
}

std::vector<std::map<std::string, std::string>> read_csv(const fs::path& p) {
  std::ifstream in(p);
  std::string line;
  std::vector<std::string> header;
  std::vector<std::map<std::string, std::string>> rows;
  auto split = [](const std::string& s) {
    std::vector<std::string> out;
    std::stringstream ss(s);
    for (std::string f; std::getline(ss, f, ',');) out.push_back(f);
    return out;
  };
  if (std::getline(in, line)) header = split(line);
  while (std::getline(in, line)) {
    const auto f = split(line);
    std::map<std::string, std::string> row;
    for (size_t i = 0; i < header.size() && i < f.size(); ++i) row[header[i]] = f[i];
    rows.push_back(row);
  }
  return rows;
}

// Client frames.csv rows: whether both passes ever arrived, and how many displayed frames after
// the first arrival lacked one of them (the client must keep predicting from what it has).
struct PassGaps {
  bool arrived = false;
  int gaps = 0;
};
PassGaps pass_gaps(const std::vector<std::map<std::string, std::string>>& frames) {
  PassGaps g;
  for (const auto& row : frames) {
    const bool have = std::stoi(row.at("visibility_source_frame")) >= 0 && std::stoi(row.at("ao_source_frame")) >= 0;
    g.arrived = g.arrived || have;
    g.gaps += g.arrived && !have;
  }
  return g;
}

// Small frames keep the test fast, also under the sanitizers.
const std::vector<std::string> kSettings{"--scene", "room", "--set", "width=96", "--set", "height=64"};

std::vector<std::string> with(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

fs::path fresh_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("dhr_live_" + name + "_" + std::to_string(getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// dhrbench serve with the test's settings on a loopback port the kernel picks, its port in
// DIR/server.port and its output in DIR/server.log; `extra` options are appended.
Process start_server(const fs::path& dir, const std::vector<std::string>& extra = {}) {
  return Process::start(
      with({"serve"},
           with(kSettings, with({"--bind", "127.0.0.1:0", "--port-file", (dir / "server.port").string()}, extra))),
      (dir / "server.log").string());
}

// dhrbench client with the test's settings and `extra` options, to 127.0.0.1:port, its output in
// DIR/client.log.
Process start_client(const fs::path& dir, int port, const std::vector<std::string>& extra) {
  return Process::start(
      with({"client"},
           with(kSettings, with({"--server", "127.0.0.1:" + std::to_string(port), "--connect-timeout", "30"}, extra))),
      (dir / "client.log").string());
}

// dhrbench relay in front of the server at 127.0.0.1:server_port with these link models; its
// port in DIR/relay.port, its results in DIR/relay.json, its output in DIR/relay.log.
Process start_relay(const fs::path& dir, int server_port, const std::string& downlink, const std::string& uplink,
                    const std::vector<std::string>& extra) {
  return Process::start(
      with({"relay", "--listen", "127.0.0.1:0", "--server", "127.0.0.1:" + std::to_string(server_port), "--port-file",
            (dir / "relay.port").string(), "--out", (dir / "relay.json").string(), "--downlink", downlink, "--uplink",
            uplink, "--idle-timeout", "20"},
           extra),
      (dir / "relay.log").string());
}

// FEC in live mode: server and client agree on the passes' parity (a kInLiveOffer setting), and
// through a relay that loses 5 % of the downlink's datagrams the client rebuilds frames from
// their parity packets.
TEST(LiveMode, ThroughALossyRelayFecRebuildsFrames) {
  const fs::path dir = fresh_dir("relay_fec");
  const std::vector<std::string> fec{"--set", "passes.visibility.fec_parity=0.5", "--set", "passes.ao.fec_parity=0.5"};
  Process server = start_server(dir, with({"--out", (dir / "server").string(), "--idle-timeout", "20"}, fec));
  ASSERT_GT(server.pid, 0);
  const int server_port = wait_port(dir / "server.port", server);
  ASSERT_GT(server_port, 0);
  Process relay = start_relay(dir, server_port, R"({"latency_ms": 10, "loss": "independent", "loss_rate": 0.05})",
                              R"({"latency_ms": 10})", {"--seed", "9"});
  const int relay_port = wait_port(dir / "relay.port", relay);
  ASSERT_GT(relay_port, 0);
  Process client = start_client(dir, relay_port, with({"--frames", "90", "--out", (dir / "client").string()}, fec));
  ASSERT_TRUE(client.wait(120)) << "the client hung:\n" << client.output();
  ASSERT_TRUE(server.wait(30)) << server.output();
  ASSERT_TRUE(relay.wait(30)) << relay.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  const json c = read_json(dir / "client" / "live.json");
  const json r = read_json(dir / "relay.json");
  EXPECT_GT(r["server_to_client"]["dropped_loss"].get<uint64_t>(), 0u) << r.dump(2);
  EXPECT_GT(c["packets"]["frames_recovered"].get<uint64_t>(), 0u) << c["packets"].dump(2);
  EXPECT_GT(c["packets"]["recovered"].get<uint64_t>(), 0u) << c["packets"].dump(2);
  std::printf("live, FEC 50 %%, 5 %% loss: %llu datagrams dropped by the relay, %llu frames rebuilt (%llu packets)\n",
              (unsigned long long)r["server_to_client"]["dropped_loss"].get<uint64_t>(),
              (unsigned long long)c["packets"]["frames_recovered"].get<uint64_t>(),
              (unsigned long long)c["packets"]["recovered"].get<uint64_t>());
}

// Adaptive bitrate in live mode: the client's reports ride on its cameras, and the server's
// controller lowers the stream budget when a relay's 0.4 Mb/s link queues what a 1.5 Mb/s
// budget sends.
TEST(LiveMode, TheServerFollowsTheClientsReportsDownToTheLink) {
  const fs::path dir = fresh_dir("relay_abr");
  const std::vector<std::string> abr{"--set", "abr=latency",
                                     "--set", "stream_kbps=1500",
                                     "--set", R"(passes.ao.codec={"name":"h264","params":{"rate_control":"bitrate"}})"};
  Process server = start_server(dir, with({"--out", (dir / "server").string(), "--idle-timeout", "20"}, abr));
  ASSERT_GT(server.pid, 0);
  const int server_port = wait_port(dir / "server.port", server);
  ASSERT_GT(server_port, 0);
  Process relay =
      start_relay(dir, server_port, R"({"latency_ms": 10, "bandwidth_mbps": 0.4, "queue_limit_bytes": 30000})",
                  R"({"latency_ms": 10})", {"--seed", "3"});
  const int relay_port = wait_port(dir / "relay.port", relay);
  ASSERT_GT(relay_port, 0);
  Process client = start_client(dir, relay_port, with({"--frames", "120", "--out", (dir / "client").string()}, abr));
  ASSERT_TRUE(client.wait(120)) << "the client hung:\n" << client.output();
  ASSERT_TRUE(server.wait(30)) << server.output();
  ASSERT_TRUE(relay.wait(30)) << relay.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  EXPECT_EQ(server.exit_code, 0) << server.output();
  const json s = read_json(dir / "server" / "server.json");
  ASSERT_EQ(s["sessions"].size(), 1u);
  const json a = s["sessions"][0]["abr"];
  ASSERT_TRUE(a.is_object()) << s.dump(2);
  std::printf("live abr: %llu updates, %llu reports dropped, budget lowest %.0f kbit/s, last %.0f kbit/s\n",
              (unsigned long long)a["updates"].get<uint64_t>(),
              (unsigned long long)a["reports_dropped"].get<uint64_t>(), a["kbps_lowest"].get<double>(),
              a["kbps_last"].get<double>());
  EXPECT_GT(a["updates"].get<uint64_t>(), 3u);
  EXPECT_LT(a["kbps_lowest"].get<double>(), 0.8 * 1500);
}

TEST(LiveMode, ThroughALossyRelayTheSocketBytesMatchTheSimulator) {
  const fs::path dir = fresh_dir("relay");
  Process server = start_server(dir, {"--out", (dir / "server").string(), "--idle-timeout", "20"});
  ASSERT_GT(server.pid, 0);
  const int server_port = wait_port(dir / "server.port", server);
  ASSERT_GT(server_port, 0);

  // Foreign and broken datagrams at the server: counted and dropped, the session unharmed.
  {
    UdpSocket probe(resolve_endpoint("127.0.0.1:0", true));
    const Endpoint to = resolve_endpoint("127.0.0.1:" + std::to_string(server_port));
    for (int i = 0; i < 5; ++i) probe.send_to(std::vector<uint8_t>(size_t(10 + i * 7), uint8_t(i)), to);
    ControlMessage cam;
    cam.type = ControlType::Camera;
    cam.session = 12345;  // no such session
    cam.camera = sample_camera();
    probe.send_to(encode_control(cam), to);
  }

  const std::string downlink =
      R"({"latency": "normal", "latency_ms": 15, "jitter_ms": 4, "preserve_order": false, "loss": "independent", "loss_rate": 0.05})";
  Process relay =
      start_relay(dir, server_port, downlink, R"({"latency_ms": 10})", {"--duplicate-rate", "0.03", "--seed", "5"});
  const int relay_port = wait_port(dir / "relay.port", relay);
  ASSERT_GT(relay_port, 0);

  constexpr int kFrames = 90;  // 1.5 s at 60 Hz
  Process client = start_client(dir, relay_port,
                                {"--frames", std::to_string(kFrames), "--out", (dir / "client").string(),
                                 "--score-every", "15", "--save-every", "45"});
  ASSERT_TRUE(client.wait(120)) << "the client hung:\n" << client.output();
  ASSERT_TRUE(server.wait(30)) << "the server did not end after the client's bye:\n" << server.output();
  ASSERT_TRUE(relay.wait(30)) << "the relay did not end after the bye:\n" << relay.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  EXPECT_EQ(server.exit_code, 0) << server.output();
  EXPECT_EQ(relay.exit_code, 0) << relay.output();

  const json c = read_json(dir / "client" / "live.json");
  const json s = read_json(dir / "server" / "server.json");
  const json r = read_json(dir / "relay.json");
  ASSERT_TRUE(c.contains("frames") && s.contains("sessions") && r.contains("server_to_client"));
  EXPECT_EQ(c["end_reason"], "all 90 frames displayed");
  ASSERT_EQ(s["sessions"].size(), 1u);
  EXPECT_NE(s["sessions"][0]["end_reason"].get<std::string>().find("bye"), std::string::npos);
  EXPECT_NE(r["end_reason"].get<std::string>().find("bye"), std::string::npos);
  // Six bad datagrams: five that are nothing, one camera of no session.
  uint64_t bad = 0;
  for (const auto& [k, v] : s["sessions"][0]["bad_or_foreign_datagrams"].items()) bad += v.get<uint64_t>();
  EXPECT_EQ(bad, 6u) << s.dump(2);

  // The impairments happened, and the receiver saw them.
  EXPECT_GT(r["server_to_client"]["dropped_loss"].get<uint64_t>(), 0u) << r.dump(2);
  EXPECT_GT(r["server_to_client"]["duplicated"].get<uint64_t>(), 0u) << r.dump(2);
  EXPECT_GT(c["packets"]["lost"].get<uint64_t>(), 0u) << c.dump(2);
  EXPECT_GT(c["packets"]["fates"].value("duplicate", 0), 0) << c.dump(2);

  // The client kept displaying through loss: every displayed frame after the first arrival
  // has both passes (predicted from the newest that arrived).
  const auto frames = read_csv(dir / "client" / "frames.csv");
  EXPECT_EQ(c["frames"]["displayed"].get<int>() + c["frames"]["skipped_late"].get<int>(), kFrames);
  ASSERT_GE(frames.size(), 10u) << "too few frames displayed: " << c["frames"].dump();
  const PassGaps g = pass_gaps(frames);
  EXPECT_TRUE(g.arrived);
  EXPECT_EQ(g.gaps, 0);
  EXPECT_GT(c["quality"]["ssim_local"]["mean"].get<double>(), 0.5);
  EXPECT_TRUE(fs::exists(dir / "client" / "frames" / "frame_00000.png"));

  // Bytes on the socket, per completed pass: exactly what the server's packet layer sent for
  // that frame, i.e. the encoded pass plus one dhrbench header per packet.
  std::map<std::pair<int, std::string>, std::map<std::string, std::string>> sent;
  for (const auto& row : read_csv(dir / "server" / "server_frames.csv"))
    sent[{std::stoi(row.at("frame")), row.at("pass")}] = row;
  const auto received = read_csv(dir / "client" / "received_passes.csv");
  ASSERT_GE(received.size(), 4u);
  int max_frame = 0;
  for (const auto& row : received) {
    const auto key = std::make_pair(std::stoi(row.at("frame")), row.at("pass"));
    ASSERT_TRUE(sent.count(key)) << "received frame " << key.first << " " << key.second << " the server never sent";
    const auto& srv = sent.at(key);
    const uint64_t packets = std::stoull(srv.at("packets"));
    EXPECT_EQ(std::stoull(row.at("packets")), packets);
    EXPECT_EQ(std::stoull(row.at("socket_bytes")), std::stoull(srv.at("encoded_bytes")) + packets * kPacketHeaderBytes);
  }
  for (const auto& [key, row] : sent) max_frame = std::max(max_frame, key.first);

  // The simulator's accounting of the same frames: the same configuration, every frame served
  // (no latency, no loss, no server time), gives the same encoded bytes and packets per pass.
  SimConfig sim;
  sim.width = 96;
  sim.height = 64;
  sim.frames = max_frame + 1;
  sim.server_fixed_ms = 0.0;
  sim.score_every = 1000000;
  const Scene scene = load_scene_or_model("room", SceneSearchPath::standard());
  TraceCache cache;
  const RunResult rr =
      run_simulation(sim, scene, fmt::format("{:016x}", scene_content_hash(scene)), cache, registries());
  std::map<std::pair<int, std::string>, ServerPassRecord> simulated;
  for (const ServerPassRecord& p : rr.server_log) simulated[{p.frame, p.pass}] = p;
  int compared = 0;
  for (const auto& [key, row] : sent) {
    ASSERT_TRUE(simulated.count(key)) << "the simulator did not serve frame " << key.first;
    const ServerPassRecord& p = simulated.at(key);
    EXPECT_EQ(std::stoull(row.at("encoded_bytes")), p.encoded_bytes) << key.second << " frame " << key.first;
    EXPECT_EQ(std::stoull(row.at("packets")), p.packets);
    EXPECT_EQ(std::stoull(row.at("wire_bytes")), p.wire_bytes);
    ++compared;
  }
  EXPECT_GE(compared, 4);
}

// AO traced at half resolution in live mode: the offer carries trace.ao_scale, the server sends
// the 48x32 pass, the client upsamples it and displays every frame after the first arrival with
// both passes, and the server's AO frames are as small as the simulator's.
TEST(LiveMode, AReducedResolutionAoPassStreamsAndIsUpsampled) {
  const fs::path dir = fresh_dir("reduced");
  const std::vector<std::string> half{"--set", "trace.ao_scale=2"};
  Process server = start_server(dir, with({"--out", (dir / "server").string(), "--idle-timeout", "20"}, half));
  const int port = wait_port(dir / "server.port", server);
  ASSERT_GT(port, 0);
  Process client = start_client(
      dir, port, with(half, {"--frames", "40", "--out", (dir / "client").string(), "--score-every", "10"}));
  ASSERT_TRUE(client.wait(120)) << "the client hung:\n" << client.output();
  ASSERT_TRUE(server.wait(30)) << server.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  EXPECT_EQ(server.exit_code, 0) << server.output();
  const json c = read_json(dir / "client" / "live.json");
  EXPECT_EQ(c["end_reason"], "all 40 frames displayed");
  const PassGaps g = pass_gaps(read_csv(dir / "client" / "frames.csv"));
  EXPECT_TRUE(g.arrived);
  EXPECT_EQ(g.gaps, 0);
  EXPECT_GT(c["quality"]["ssim_local"]["mean"].get<double>(), 0.5);
  int ao_frames = 0;
  for (const auto& row : read_csv(dir / "server" / "server_frames.csv")) {
    if (row.at("pass") != "ao") continue;
    ++ao_frames;
    // 48x32 one-byte samples: LZ4 of them cannot exceed that size by much.
    EXPECT_LT(std::stoull(row.at("encoded_bytes")), 48u * 32u + 64u) << "frame " << row.at("frame");
  }
  EXPECT_GT(ao_frames, 0);
}

// Recovery from the frame the client holds: with the reprojected delta on both
// passes through a lossy relay, the client's keyframe requests carry the newest frame each
// decoder holds and the server predicts from it; the session keeps displaying both passes.
TEST(LiveMode, AfterALossTheServerHearsWhichFrameTheClientHolds) {
  const fs::path dir = fresh_dir("holds");
  const std::vector<std::string> delta{
      "--set", R"(passes.visibility.codec={"name": "delta", "params": {"inner": "zstd", "predictor": "reprojection"}})",
      "--set", R"(passes.ao.codec={"name": "delta", "params": {"inner": "zstd", "predictor": "reprojection"}})"};
  Process server = start_server(dir, with({"--out", (dir / "server").string(), "--idle-timeout", "20"}, delta));
  const int server_port = wait_port(dir / "server.port", server);
  ASSERT_GT(server_port, 0);
  Process relay = start_relay(dir, server_port, R"({"latency_ms": 10, "loss": "independent", "loss_rate": 0.08})",
                              R"({"latency_ms": 10})", {"--seed", "3"});
  const int relay_port = wait_port(dir / "relay.port", relay);
  ASSERT_GT(relay_port, 0);
  Process client = start_client(
      dir, relay_port, with(delta, {"--frames", "90", "--out", (dir / "client").string(), "--score-every", "0"}));
  ASSERT_TRUE(client.wait(120)) << "the client hung:\n" << client.output();
  ASSERT_TRUE(server.wait(30)) << server.output();
  ASSERT_TRUE(relay.wait(30)) << relay.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  EXPECT_EQ(server.exit_code, 0) << server.output();
  const json c = read_json(dir / "client" / "live.json");
  const json s = read_json(dir / "server" / "server.json");
  EXPECT_GT(c["packets"]["lost"].get<uint64_t>(), 0u) << c.dump(2);
  ASSERT_EQ(s["sessions"].size(), 1u);
  EXPECT_GT(s["sessions"][0]["frames_after_held_report"].get<uint64_t>(), 0u) << s.dump(2);
  const PassGaps g = pass_gaps(read_csv(dir / "client" / "frames.csv"));
  EXPECT_TRUE(g.arrived);
  EXPECT_EQ(g.gaps, 0);
}

TEST(LiveMode, AMismatchedOfferIsRefusedWithTheReason) {
  const fs::path dir = fresh_dir("refuse");
  Process server = start_server(dir);
  const int port = wait_port(dir / "server.port", server);
  ASSERT_GT(port, 0);
  Process client = Process::start({"client", "--scene", "room", "--set", "width=128", "--set", "height=64", "--set",
                                   "ao_codec.name=zstd", "--server", "127.0.0.1:" + std::to_string(port), "--frames",
                                   "5", "--out", (dir / "client").string(), "--connect-timeout", "30"},
                                  (dir / "client.log").string());
  ASSERT_TRUE(client.wait(60)) << client.output();
  EXPECT_EQ(client.exit_code, 2) << client.output();
  const std::string out = client.output();
  EXPECT_NE(out.find("refused the session"), std::string::npos) << out;
  EXPECT_NE(out.find("width: client 128, server 96"), std::string::npos) << out;
  EXPECT_NE(out.find("ao_codec.name: client \"zstd\", server \"lz4\""), std::string::npos) << out;
  // The server is still there; stopping it is clean.
  kill(server.pid, SIGTERM);
  ASSERT_TRUE(server.wait(30)) << server.output();
  EXPECT_EQ(server.exit_code, 0) << server.output();
}

TEST(LiveMode, TheClientEndsCleanlyWhenTheServerDies) {
  const fs::path dir = fresh_dir("dies");
  Process server = start_server(dir);
  const int port = wait_port(dir / "server.port", server);
  ASSERT_GT(port, 0);
  Process client =
      Process::start(with({"client"}, with(kSettings, {"--server", "127.0.0.1:" + std::to_string(port), "--frames",
                                                       "100000", "--out", (dir / "client").string(), "--idle-timeout",
                                                       "1", "--score-every", "0", "--connect-timeout", "30"})),
                     (dir / "client.log").string());
  // Let the session run, then kill the server without a word (no bye).
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (!fs::exists(dir / "client.log") || client.output().find("session") == std::string::npos) {
    ASSERT_LT(std::chrono::steady_clock::now(), end) << client.output();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  kill(server.pid, SIGKILL);
  server.wait(10);
  ASSERT_TRUE(client.wait(60)) << "the client did not notice the server had gone:\n" << client.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  const json c = read_json(dir / "client" / "live.json");
  EXPECT_EQ(c.value("end_reason", ""), "the server was silent for 1.0 s") << client.output();
}

// The session token the server printed ("session 1a2b3c4d with ..."): an attacker who can read
// it (on the path) still sends from another address.
uint32_t wait_token(const Process& server, double seconds = 60) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    const std::string log = server.output();
    const size_t at = log.find("session ");
    if (at != std::string::npos && log.find(" with ", at) != std::string::npos)
      return uint32_t(std::stoul(log.substr(at + 8, 8), nullptr, 16));
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ADD_FAILURE() << "no session in the server's log:\n" << server.output();
  return 0;
}

uint64_t sum_counts(const json& counts) {
  uint64_t n = 0;
  for (const auto& [k, v] : counts.items()) n += v.get<uint64_t>();
  return n;
}

TEST(LiveTrust, ASessionUnderAttackFromAThirdSocketEndsAsACleanOne) {
  const fs::path dir = fresh_dir("attack");
  Process server = start_server(dir, {"--out", (dir / "server").string(), "--idle-timeout", "20"});
  const int server_port = wait_port(dir / "server.port", server);
  ASSERT_GT(server_port, 0);
  // A relay that impairs nothing: the loopback link loses nothing, so a clean session counts
  // no loss and receives every datagram the server sent.
  Process relay = Process::start(
      {"relay", "--listen", "127.0.0.1:0", "--server", "127.0.0.1:" + std::to_string(server_port), "--port-file",
       (dir / "relay.port").string(), "--out", (dir / "relay.json").string(), "--idle-timeout", "20"},
      (dir / "relay.log").string());
  const int relay_port = wait_port(dir / "relay.port", relay);
  ASSERT_GT(relay_port, 0);
  constexpr int kFrames = 120;  // 2 s at 60 Hz
  Process client = Process::start(
      with({"client"},
           with(kSettings, {"--server", "127.0.0.1:" + std::to_string(relay_port), "--frames", std::to_string(kFrames),
                            "--out", (dir / "client").string(), "--score-every", "0", "--save-every", "0",
                            "--connect-timeout", "30", "--port-file", (dir / "client.port").string()})),
      (dir / "client.log").string());
  const int client_port = wait_port(dir / "client.port", client);
  ASSERT_GT(client_port, 0);
  const uint32_t token = wait_token(server);
  ASSERT_NE(token, 0u);

  // The attacker: a third socket on another port, knowing the token.
  UdpSocket attacker(resolve_endpoint("127.0.0.1:0", true));
  const Endpoint to_client = resolve_endpoint("127.0.0.1:" + std::to_string(client_port));
  const Endpoint to_server = resolve_endpoint("127.0.0.1:" + std::to_string(server_port));
  const Endpoint to_relay = resolve_endpoint("127.0.0.1:" + std::to_string(relay_port));
  std::map<std::string, int> sent_to_server, sent_to_client;
  int sent_to_relay = 0;
  auto send = [&](const std::vector<uint8_t>& d, const Endpoint& to) {
    ASSERT_EQ(attacker.send_to(d, to), SendResult::Sent);
  };
  std::mt19937 rng(7);
  auto random_bytes = [&](size_t n) {
    std::vector<uint8_t> d(n);
    for (auto& b : d) b = uint8_t(rng());
    d[0] = 'x';  // never a magic
    return d;
  };
  // Forged AO pass packets of the session's stream with far-future frame ids (accepted, they
  // would freeze the pass: docs/live-security.md).
  for (int i = 0; i < 20; ++i) {
    PacketMeta m;
    m.stream_id = uint16_t(token & 0xffff);
    m.desc = {PassKind::Ao, 96, 64, 1, 8};
    m.frame_id = 999670u + uint32_t(i);
    m.codec_id = codec_id("lz4");
    m.first_sequence = 1000000u * uint32_t(i + 1);
    send(packetize(m, std::vector<uint8_t>(300, uint8_t(i)))[0], to_client);
    ++sent_to_client["pass packets, far-future frames"];
  }
  for (int i = 0; i < 3; ++i) {
    send(control(ControlType::Bye, token, "forged"), to_client);
    ++sent_to_client["bye with the token"];
    send(control(ControlType::Refuse, token, "forged"), to_client);
    ++sent_to_client["refuse"];
    send(control(ControlType::Welcome, token, welcome_for(token)), to_client);
    ++sent_to_client["welcome"];
    send(control(ControlType::Bye, token, "forged"), to_server);
    ++sent_to_server["foreign_address"];
    ControlMessage cam;
    cam.type = ControlType::Camera;
    cam.session = token;
    cam.camera = sample_camera();
    cam.camera.frame = 4000000000u;
    cam.camera.camera.width = 96;
    cam.camera.camera.height = 64;
    send(encode_control(cam), to_server);
    ++sent_to_server["foreign_address"];
    send(control(ControlType::Bye, token, "forged"), to_relay);
    ++sent_to_relay;
  }
  // Malformed Hellos (a Hello may come from anyone, so each is read and refused by its shape).
  for (const char* body : {"[1]", "null", "5"}) {
    send(control(ControlType::Hello, 1, body), to_server);
    ++sent_to_server["hello_not_an_object"];
  }
  send(control(ControlType::Hello, 1, "{\"a\":"), to_server);
  ++sent_to_server["hello_not_json"];
  send(control(ControlType::Hello, 1, std::string(8000, '[')), to_server);
  ++sent_to_server["hello_too_deep"];
  send(raw_control(ControlType::Hello, 1, std::string(65000, '[')), to_server);  // as deep as a datagram allows
  ++sent_to_server["bad_length"];
  for (const auto& [field, value] : std::vector<std::pair<std::string, json>>{
           {"width", "96"}, {"ao_codec.params", json::array()}, {"seed", 1.5}, {"scene", nullptr}}) {
    send(control(ControlType::Hello, 1, with_field(field, value)), to_server);
    ++sent_to_server["hello_wrong_type"];
    send(control(ControlType::Hello, 1, with_field(field, value)), to_client);
    ++sent_to_client["hello"];
  }
  for (int i = 0; i < 20; ++i) {
    send(random_bytes(1 + rng() % 1400), to_client);
    ++sent_to_client["random"];
    send(random_bytes(1 + rng() % 1400), to_server);
    ++sent_to_server["not_a_control_message"];
    if (i < 5) {
      send(random_bytes(1 + rng() % 1400), to_relay);
      ++sent_to_relay;
    }
  }
  // A well-formed Hello from the attacker: refused as busy, the session not taken over.
  {
    SimConfig sim;
    sim.width = 96;
    sim.height = 64;
    const Scene scene = load_scene_or_model("room", SceneSearchPath::standard());
    send(control(ControlType::Hello, 77,
                 session_offer(sim, registries(), "room", fmt::format("{:016x}", scene_content_hash(scene))).dump()),
         to_server);
  }
  UdpSocket* probe = &attacker;
  int refusals = 0;
  for (int i = 0; i < 100 && !refusals; ++i) {
    if (!probe->wait_readable(50)) continue;
    std::vector<uint8_t> d;
    Endpoint from;
    if (probe->receive(d, from) != ReceiveResult::Received) continue;
    TypedControl m;
    if (read_control(d, m) == nullptr && m.message.type == ControlType::Refuse) {
      ++refusals;
      EXPECT_EQ(m.message.session, 77u) << "the Refuse echoes the nonce";
      EXPECT_NE(m.message.text.find("busy"), std::string::npos) << m.message.text;
      EXPECT_EQ(m.message.text.find("127.0.0.1"), std::string::npos) << "the peer is not told: " << m.message.text;
    }
  }
  EXPECT_EQ(refusals, 1);

  ASSERT_TRUE(client.wait(120)) << "the client hung:\n" << client.output();
  ASSERT_TRUE(server.wait(30)) << server.output();
  ASSERT_TRUE(relay.wait(30)) << relay.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  EXPECT_EQ(server.exit_code, 0) << server.output();
  EXPECT_EQ(relay.exit_code, 0) << relay.output();
  const json c = read_json(dir / "client" / "live.json");
  const json s = read_json(dir / "server" / "server.json");
  const json r = read_json(dir / "relay.json");
  ASSERT_TRUE(c.contains("socket") && s.contains("sessions") && r.contains("foreign_by_reason")) << c.dump(2);
  ASSERT_EQ(s["sessions"].size(), 1u);
  const json& ss = s["sessions"][0];

  // The session ran to its end: no forged Bye ended it on either side or at the relay.
  EXPECT_EQ(c["end_reason"], fmt::format("all {} frames displayed", kFrames));
  EXPECT_EQ(ss["end_reason"], "the client said bye: client done");
  EXPECT_EQ(r["end_reason"], "the client said bye");
  EXPECT_EQ(c["frames"]["displayed"].get<int>() + c["frames"]["skipped_late"].get<int>(), kFrames);
  // As a clean session on a link that loses nothing: no loss, and every pass packet the server
  // sent (its log) received from the peer, byte for byte.
  EXPECT_EQ(c["packets"]["lost"], 0) << c["packets"].dump(2);
  EXPECT_EQ(c["packets"]["frames_lost_by_reason"], json::object()) << c["packets"].dump(2);
  for (const char* pass : {"visibility", "ao"}) EXPECT_EQ(c["passes"][pass]["frames_lost"], 0) << pass;
  EXPECT_EQ(c["socket"]["session_pass_datagrams"], ss["datagrams_sent"]);
  EXPECT_EQ(c["socket"]["session_pass_bytes"], ss["bytes_sent"]);
  uint64_t logged_packets = 0, logged_wire = 0;
  for (const auto& row : read_csv(dir / "server" / "server_frames.csv")) {
    logged_packets += std::stoull(row.at("packets"));
    logged_wire += std::stoull(row.at("wire_bytes"));
  }
  EXPECT_EQ(logged_packets, ss["datagrams_sent"].get<uint64_t>());
  EXPECT_EQ(logged_wire, ss["wire_bytes_sent"].get<uint64_t>());
  // Bandwidth on the wire: 28 bytes of IPv4/UDP per datagram, as the simulator counts.
  const json& sock = c["socket"];
  EXPECT_EQ(sock["wire_bytes"].get<uint64_t>(),
            sock["session_bytes"].get<uint64_t>() + kIpUdpOverheadBytes * sock["session_datagrams"].get<uint64_t>());
  EXPECT_NEAR(sock["mbps"].get<double>(), sock["wire_bytes"].get<double>() * 8e-6 / sock["duration_s"].get<double>(),
              1e-9);
  // AO never froze: every displayed frame after the first arrival has both passes, and the
  // last ones are recent.
  const auto frames = read_csv(dir / "client" / "frames.csv");
  ASSERT_GE(frames.size(), 10u);
  const PassGaps g = pass_gaps(frames);
  EXPECT_TRUE(g.arrived);
  EXPECT_EQ(g.gaps, 0);
  EXPECT_GE(std::stoi(frames.back().at("ao_source_frame")), std::stoi(frames.back().at("frame")) - 30);

  // Every attacker datagram dropped, counted by reason; the counts are what it sent.
  int to_client_total = 0;
  for (const auto& [k, n] : sent_to_client) to_client_total += n;
  EXPECT_EQ(c["socket"]["bad_or_foreign"], (json{{"foreign_address", to_client_total}})) << c["socket"].dump(2);
  json expected_server = json::object();
  for (const auto& [k, n] : sent_to_server) expected_server[k] = n;
  EXPECT_EQ(ss["bad_or_foreign_datagrams"], expected_server);
  EXPECT_EQ(ss["refused_hellos"], 1);
  EXPECT_EQ(r["foreign_by_reason"], (json{{"client_side_foreign_address", sent_to_relay}})) << r.dump(2);
  EXPECT_EQ(r["byes_ignored"], 0) << "the relay never saw the forged Byes: they came from a third address";
}

TEST(LiveTrust, AKeyedSessionAuthenticatesEveryDatagram) {
  const fs::path dir = fresh_dir("keyed");
  const fs::path key = dir / "live.key", other = dir / "other.key";
  std::ofstream(key, std::ios::binary) << "0123456789abcdef0123456789abcdef";
  std::ofstream(other, std::ios::binary) << "fedcba9876543210fedcba9876543210";
  Process server =
      start_server(dir, {"--out", (dir / "server").string(), "--idle-timeout", "20", "--key-file", key.string()});
  const int port = wait_port(dir / "server.port", server);
  ASSERT_GT(port, 0);
  const std::string at = "127.0.0.1:" + std::to_string(port);
  // Another key, and no key: the server never answers (every Hello fails its MAC).
  Process wrong = Process::start(
      with({"client"}, with(kSettings, {"--server", at, "--frames", "5", "--out", (dir / "wrong").string(),
                                        "--connect-timeout", "1", "--key-file", other.string()})),
      (dir / "wrong.log").string());
  ASSERT_TRUE(wrong.wait(60)) << wrong.output();
  EXPECT_EQ(wrong.exit_code, 1) << wrong.output();
  EXPECT_NE(wrong.output().find("same --key-file"), std::string::npos) << wrong.output();
  {
    UdpSocket probe(resolve_endpoint("127.0.0.1:0", true));
    probe.send_to(control(ControlType::Hello, 1, good_offer().dump()), resolve_endpoint(at));  // unauthenticated
  }
  constexpr int kFrames = 40;
  Process client =
      Process::start(with({"client"}, with(kSettings, {"--server", at, "--frames", std::to_string(kFrames), "--out",
                                                       (dir / "client").string(), "--score-every", "0", "--save-every",
                                                       "0", "--connect-timeout", "30", "--key-file", key.string()})),
                     (dir / "client.log").string());
  ASSERT_TRUE(client.wait(120)) << client.output();
  ASSERT_TRUE(server.wait(30)) << server.output();
  EXPECT_EQ(client.exit_code, 0) << client.output();
  EXPECT_EQ(server.exit_code, 0) << server.output();
  const json c = read_json(dir / "client" / "live.json");
  const json s = read_json(dir / "server" / "server.json");
  ASSERT_TRUE(c.contains("socket") && s.contains("sessions"));
  EXPECT_EQ(c["authentication"], "hmac-sha256-128");
  EXPECT_EQ(s["authentication"], "hmac-sha256-128");
  EXPECT_EQ(c["end_reason"], fmt::format("all {} frames displayed", kFrames));
  EXPECT_EQ(c["packets"]["lost"], 0);
  EXPECT_EQ(c["socket"]["bad_or_foreign"], json::object()) << c["socket"].dump(2);
  const json& ss = s["sessions"][0];
  EXPECT_GE(ss["bad_or_foreign_datagrams"].value("bad_mac", 0), 2) << ss.dump(2);
  EXPECT_EQ(sum_counts(ss["bad_or_foreign_datagrams"]), ss["bad_or_foreign_datagrams"].value("bad_mac", 0u));
  EXPECT_EQ(c["socket"]["session_pass_datagrams"], ss["datagrams_sent"]);
  EXPECT_EQ(c["socket"]["session_pass_bytes"], ss["bytes_sent"]);
  // The MAC is on the wire: 16 bytes more per packet than the simulator's figure.
  std::map<std::pair<int, std::string>, std::map<std::string, std::string>> sent;
  for (const auto& row : read_csv(dir / "server" / "server_frames.csv")) {
    const uint64_t encoded = std::stoull(row.at("encoded_bytes")), packets = std::stoull(row.at("packets"));
    EXPECT_EQ(std::stoull(row.at("wire_bytes")), wire_bytes_of_pass(encoded) + packets * kMacBytes);
    sent[{std::stoi(row.at("frame")), row.at("pass")}] = row;
  }
  const auto received = read_csv(dir / "client" / "received_passes.csv");
  ASSERT_GE(received.size(), 4u);
  for (const auto& row : received) {
    const auto& srv = sent.at({std::stoi(row.at("frame")), row.at("pass")});
    EXPECT_EQ(std::stoull(row.at("socket_bytes")),
              std::stoull(srv.at("encoded_bytes")) + std::stoull(srv.at("packets")) * (kPacketHeaderBytes + kMacBytes));
  }
}

}  // namespace
}  // namespace dhr
