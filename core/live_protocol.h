// Live mode's control messages (dhrbench serve / client / relay), beside the pass packets of
// core/packet.h. Every control message is one datagram with a fixed little-endian header
// that is checked before anything in it is used:
//
//   offset size field
//        0    4 magic "DHRC"
//        4    1 version (kControlVersion)
//        5    1 type (ControlType)
//        6    2 reserved, 0
//        8    4 session id (0 in Hello)
//       12    2 body bytes (<= kMaxControlBody)
//       14    2 reserved, 0
//       16    4 CRC-32C of bytes 0..15 followed by the body
//       20      body
//
// The session: the client sends Hello (its offer: a JSON object naming the scene and its
// content hash, resolution, display rate, passes and codecs; see live.h) until the server
// answers Welcome (a session id and the server's view of the same object) or Refuse (why,
// naming every field that disagrees). Then the client sends one Camera per displayed frame
// and the server streams the passes as pass packets whose stream id is the session id's low 16
// bits. Either side ends with Bye (a reason); silence for the idle timeout ends it too.
#pragma once

#include "core/camera.h"

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace dhr {

constexpr uint8_t kControlMagic[4] = {'D', 'H', 'R', 'C'};
constexpr uint8_t kControlVersion = 1;
constexpr size_t kControlHeaderBytes = 20;
constexpr size_t kMaxControlBody = 8192;

enum class ControlType : uint8_t { Hello = 1, Welcome = 2, Refuse = 3, Camera = 4, Bye = 5 };
const char* control_type_name(ControlType t);

// One displayed client frame's camera: the server renders its passes for exactly this camera.
struct CameraUpdate {
  uint32_t frame = 0;          // the client's frame index (the pass packets' frame id)
  bool keyframe_request = false;
  double scene_time_s = 0.0;   // scene time of the frame (animation)
  Camera camera;               // every field, bit for bit
};
constexpr size_t kCameraBodyBytes = 4 + 4 + 8 + 12 * 4 + 2 * 2;

struct ControlMessage {
  ControlType type = ControlType::Hello;
  uint32_t session = 0;
  std::string text;      // Hello, Welcome: JSON; Refuse, Bye: the reason
  CameraUpdate camera;  // Camera
};

enum class ControlParse : uint8_t {
  Ok = 0,
  NotControl,   // too short or another magic (e.g. a pass packet): not for this parser
  BadVersion,
  BadChecksum,
  BadLength,    // body length disagrees with the datagram
  BadType,
  BadBody,      // a Camera body with non-finite values, a bad camera, a wrong size
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

}  // namespace dhr
