// What the live-mode sources share (core/live/live.cpp: the offer; core/live/live_server.cpp,
// core/live/live_client.cpp, core/live/live_relay.cpp): clock helpers, output files, control messages,
// the stream slots and the wire-byte definition. Internal: included by those files only.
#pragma once

#include "core/base/error.h"
#include "core/live/live_protocol.h"
#include "core/net/packet.h"
#include "core/net/udp.h"
#include "core/pass/passes.h"

#include <fmt/format.h>
#include <poll.h>
#include <sys/socket.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <queue>
#include <set>

namespace dhr::live_detail {

using Clock = std::chrono::steady_clock;

inline double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

template <class... Args>
inline void say(bool quiet, const char* who, fmt::format_string<Args...> f, Args&&... args) {
  if (quiet) return;
  fmt::print(stderr, "{}: {}\n", who, fmt::format(f, std::forward<Args>(args)...));
  std::fflush(stderr);
}

inline void write_port_file(const std::string& path, const Endpoint& e) {
  if (path.empty()) return;
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp);
    f << e.port() << "\n";
    if (!f) fail("cannot write the port file '{}'", path);
  }
  std::filesystem::rename(tmp, path);  // whole, so a reader never sees a partial number
}

inline void write_text(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
  if (!f) fail("cannot write '{}'", path);
}

// The wildcard address of the server's family, port 0 (a client's local socket).
inline Endpoint any_endpoint_like(const Endpoint& peer) {
  return resolve_endpoint(peer.addr.ss_family == AF_INET6 ? "[::]:0" : "0.0.0.0:0", true);
}

inline int slot_of(PassKind k) { return pass_slot(k); }
// The stream of a planned pass: its index in pass_types(), the protocol's slots
// (core/live/live_protocol.h).
inline int stream_slot(const PlannedPass& p) {
  for (int i = 0; i < pass_slot_count(); ++i)
    if (p.name == pass_types()[size_t(i)].name) return i;
  fail("live: the pass '{}' has no stream", p.name);
}
inline const char* slot_name(int slot) { return pass_types()[size_t(slot)].name; }

inline ControlMessage msg(ControlType type, uint32_t session, std::string text = {}) {
  ControlMessage m;
  m.type = type;
  m.session = session;
  m.text = std::move(text);
  return m;
}

inline ControlMessage camera_msg(uint32_t session, const CameraUpdate& cu) {
  ControlMessage m = msg(ControlType::Camera, session);
  m.camera = cu;
  return m;
}

inline uint16_t stream_of(uint32_t session) { return uint16_t(session & 0xffffu); }

// Bytes a datagram of `udp_payload_bytes` occupies on the wire: the simulator's definition
// (core/net/packet.h): the IPv4 and UDP headers, kIpUdpOverheadBytes, are counted.
inline uint64_t on_the_wire(uint64_t udp_payload_bytes, uint64_t datagrams) {
  return udp_payload_bytes + datagrams * kIpUdpOverheadBytes;
}

inline std::optional<DatagramMac> load_key(const std::string& path) {
  if (path.empty()) return std::nullopt;
  return DatagramMac::from_file(path);
}

inline const char* authentication_name(const std::optional<DatagramMac>& mac) {
  return mac ? "hmac-sha256-128" : "token";
}

// Map of counters by reason, as JSON.
inline nlohmann::json counts_json(const std::map<std::string, uint64_t>& m) {
  nlohmann::json out = nlohmann::json::object();
  for (const auto& [k, v] : m) out[k] = v;
  return out;
}

}  // namespace dhr::live_detail
