// Live mode: the DHR server and client as two processes over real UDP sockets, with an
// optional impairment relay between them (dhrbench serve / client / relay). The simulator's
// stages (core/pipeline/pipeline.h: ServerPipeline, ClientPipeline, LocalReference) run on the wall
// clock instead of the virtual one; live mode adds only the sockets and the handshake:
//
//   client, every 1/display_hz s:  camera -> Camera message (uplink); rasterize; receive and
//          reassemble pass packets (core/net/assembler.h); ClientPipeline decodes, predicts the
//          newest buffer of each pass to this frame and composites; record. After the session
//          each scored frame is compared with the LocalReference, as in the simulator
//   server, for the newest camera that arrived (older ones are dropped, counted):
//          ServerPipeline rasterizes, traces, denoises, encodes and packetizes; every packet
//          is sent at once
//   relay: each datagram through a seeded core/net/network.h Link per direction (loss, delay,
//          jitter, reordering, bandwidth cap with a bounded queue), plus duplication
//
// Session: Hello / Welcome / Refuse / Camera / Bye (core/live/live_protocol.h). The client's offer
// names the scene (with its content hash), resolution, display rate, seed, trace settings,
// codecs, denoisers and payload size; the server refuses any difference, listing each one.
//
// Memory is bounded on every side: the server keeps only the newest camera (a slow or flooding
// client cannot queue work); the client's assembler has fixed limits; the relay's queue is
// capped in bytes; the kernel's socket buffers are fixed.
//
// Trust (docs/live-security.md): a session is bound to its peer's address and to a random
// token; with a key file, every datagram also carries an HMAC. Server and client accept data
// and control only from the peer, with the token (and the MAC), inside bounded windows of
// frame ids and sequence numbers; everything else is counted by reason and dropped, and never
// changes what is displayed, counts as loss, or ends a session. No datagram ends a process.
// Either side ends the session with Bye, or by silence: the other side notices after
// idle_timeout_s and ends cleanly with a message.
#pragma once

#include "core/backend/backend.h"
#include "core/config/run_config.h"
#include "core/net/network.h"
#include "core/net/udp.h"
#include "core/scene/scene.h"

#include <nlohmann/json.hpp>

#include <atomic>
#include <string>
#include <vector>

namespace dhr {

// 2: the Hello carries a nonce, the Welcome a body with the first sequence numbers.
// 3: a Camera carries, per pass stream, the newest frame the client holds (CameraUpdate::holds).
constexpr int kLiveProtocolVersion = 3;

// What client and server must agree on, as JSON: the SimConfig fields that change what the
// server sends or how the client reads it, with effective backend parameters, plus the scene's
// name and content hash. Throws dhr::Error for an unknown backend or parameter.
nlohmann::json session_offer(const SimConfig& config, const Registries& registries, const std::string& scene_name,
                             const std::string& scene_key);
// Every field where the two offers disagree, as "field: client X, server Y" (empty: agree).
std::vector<std::string> offer_mismatches(const nlohmann::json& client, const nlohmann::json& server);
// The SimConfig fields live mode ignores, set to other than their defaults in `config` (the
// network is the real one or the relay's; the client runs frames in real time).
std::vector<std::string> live_ignored_fields(const SimConfig& config);

struct LiveScene {
  const Scene* scene = nullptr;
  std::string name;  // as given on the command line
  std::string key;   // content hash (hex)
};

// ---- server ----
struct ServeOptions {
  Endpoint bind;                // where to listen
  std::string port_file;        // when set: the bound port is written there (for scripts)
  std::string out_dir;          // when set: server.json and server_frames.csv per session
  double idle_timeout_s = 5.0;  // a session ends when its client is silent this long
  int sessions = 1;             // sessions to serve before exiting (0: until stopped)
  std::string key_file;         // when set: every datagram carries an HMAC with this key
  bool quiet = false;
};
// Runs until `sessions` sessions ended or `stop` becomes true (then a Bye is sent). Returns
// the process exit code: 0 when every session ended by a Bye or silence.
int run_live_server(const SimConfig& config, const Registries& registries, const LiveScene& scene,
                    const ServeOptions& options, const std::atomic<bool>& stop);

// ---- client ----
struct ClientOptions {
  Endpoint server;
  int frames = 300;  // displayed frames (the session lasts frames / display_hz)
  std::string out_dir = "out/live";
  int score_every = 10;            // SSIM against the local reference every n-th frame (0: never)
  int save_every = 30;             // PNG of every n-th displayed frame (0: none)
  double connect_timeout_s = 5.0;  // Hello is repeated until then
  double idle_timeout_s = 5.0;     // the server silent this long after Welcome ends the session
  std::string key_file;            // when set: every datagram carries an HMAC with this key
  std::string port_file;           // when set: the client's local port, written after the Welcome
  bool quiet = false;
};
// Returns the exit code: 0 when the session ran (to the end, or until the server said Bye or
// fell silent: the reason is printed and written); 2 when the server refused the offer; 1 when
// no server answered.
int run_live_client(const SimConfig& config, const Registries& registries, const LiveScene& scene,
                    const ClientOptions& options, const std::atomic<bool>& stop);

// ---- relay ----
// The relay carries one session between two fixed peers: the server, and the first address that
// sends it a well-formed Hello. Datagrams from any other address are dropped and counted; a Bye
// ends the relay only when it carries the session's token (learnt from the Welcome).
struct RelayOptions {
  Endpoint listen;  // the client sends here
  Endpoint server;  // and the relay forwards to here
  LinkConfig uplink, downlink;
  double duplicate_rate = 0.0;  // probability a delivered datagram arrives twice
  uint64_t seed = 1;
  size_t max_queue_bytes = size_t(64) << 20;  // datagrams waiting for their arrival time
  double idle_timeout_s = 10.0;               // exit when no datagram came this long (after the first)
  std::string port_file;
  std::string out_file;  // when set: relay.json with the counts per direction
  bool quiet = false;
};
int run_live_relay(const RelayOptions& options, const std::atomic<bool>& stop);

}  // namespace dhr
