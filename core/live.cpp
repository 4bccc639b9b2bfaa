#include "core/live.h"

#include "core/assembler.h"
#include "core/composite.h"
#include "core/error.h"
#include "core/frame_loop.h"
#include "core/image_io.h"
#include "core/json_io.h"
#include "core/live_protocol.h"
#include "core/metrics.h"
#include "core/packet.h"
#include "core/pipeline.h"
#include "core/pass_receiver.h"
#include "core/raster.h"
#include "core/rng.h"
#include "core/rt_scene.h"
#include "core/trace.h"

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

namespace dhr {

namespace {

using Clock = std::chrono::steady_clock;

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

template <class... Args>
void say(bool quiet, const char* who, fmt::format_string<Args...> f, Args&&... args) {
  if (quiet) return;
  fmt::print(stderr, "{}: {}\n", who, fmt::format(f, std::forward<Args>(args)...));
  std::fflush(stderr);
}

void write_port_file(const std::string& path, const Endpoint& e) {
  if (path.empty()) return;
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp);
    f << e.port() << "\n";
    if (!f) fail("cannot write the port file '{}'", path);
  }
  std::filesystem::rename(tmp, path);  // whole, so a reader never sees a partial number
}

void write_text(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
  if (!f) fail("cannot write '{}'", path);
}

// The wildcard address of the server's family, port 0 (a client's local socket).
Endpoint any_endpoint_like(const Endpoint& peer) {
  return resolve_endpoint(peer.addr.ss_family == AF_INET6 ? "[::]:0" : "0.0.0.0:0", true);
}

// Median and p95 as the simulator's stage statistics compute them (StageStats), plus max, mean, n.
nlohmann::json percentiles(std::vector<double> v) {
  if (v.empty()) return nullptr;
  const StageStats s{std::move(v)};
  const double max = *std::max_element(s.samples_ms.begin(), s.samples_ms.end());
  const double n = double(s.samples_ms.size());
  return {{"median", s.median()}, {"p95", s.p95()}, {"max", max}, {"mean", s.total() / n}, {"n", s.samples_ms.size()}};
}

int slot_of(PassKind k) { return pass_slot(k); }
// The stream (0: visibility, 1: ao) of a planned pass: the protocol's slots (core/live_protocol.h).
int stream_slot(const PlannedPass& p) { return p.meaning == PassMeaning::Visibility ? 0 : 1; }
constexpr const char* kSlotName[2] = {"visibility", "ao"};

ControlMessage msg(ControlType type, uint32_t session, std::string text = {}) {
  ControlMessage m;
  m.type = type;
  m.session = session;
  m.text = std::move(text);
  return m;
}

ControlMessage camera_msg(uint32_t session, const CameraUpdate& cu) {
  ControlMessage m = msg(ControlType::Camera, session);
  m.camera = cu;
  return m;
}

uint16_t stream_of(uint32_t session) { return uint16_t(session & 0xffffu); }

// Bytes a datagram of `udp_payload_bytes` occupies on the wire: the simulator's definition
// (core/packet.h): the IPv4 and UDP headers, kIpUdpOverheadBytes, are counted.
uint64_t on_the_wire(uint64_t udp_payload_bytes, uint64_t datagrams) {
  return udp_payload_bytes + datagrams * kIpUdpOverheadBytes;
}

std::optional<DatagramMac> load_key(const std::string& path) {
  if (path.empty()) return std::nullopt;
  return DatagramMac::from_file(path);
}

const char* authentication_name(const std::optional<DatagramMac>& mac) {
  return mac ? "hmac-sha256-128" : "token";
}

// Map of counters by reason, as JSON.
nlohmann::json counts_json(const std::map<std::string, uint64_t>& m) {
  nlohmann::json out = nlohmann::json::object();
  for (const auto& [k, v] : m) out[k] = v;
  return out;
}

}  // namespace

// ---- the offer ---------------------------------------------------------------------------

nlohmann::json session_offer(const SimConfig& c, const Registries& r, const std::string& scene_name,
                             const std::string& scene_key) {
  nlohmann::json offer{{"protocol", kLiveProtocolVersion}, {"scene", scene_name}, {"scene_hash", scene_key}};
  // The settings flagged kInLiveOffer (core/run_config.cpp), backends with their effective
  // parameters. A backend goes under its version-1 key ("ao_codec"): the offer's wire format
  // (parse_offer_json) is unchanged by the per-pass keys of experiment files.
  for (const RunSetting& s : run_settings()) {
    if (!s.has(kInLiveOffer)) continue;
    nlohmann::json value = s.get(c);
    if (s.type == SettingType::Backend) {
      const std::string name = value.at("name").get<std::string>();
      Params p;
      if (s.kind == "codec") r.codecs.create(name, value.at("params"), &p);
      else if (s.kind == "denoiser") r.denoisers.create(name, value.at("params"), &p);
      else r.predictors.create(name, value.at("params"), &p);
      value = {{"name", name}, {"params", p.effective()}};
    }
    const std::string key = s.v1_key.empty() ? s.key : s.v1_key;
    nlohmann::json* node = &offer;
    size_t start = 0;
    for (size_t dot; (dot = key.find('.', start)) != std::string::npos; start = dot + 1) node = &(*node)[key.substr(start, dot - start)];
    (*node)[key.substr(start)] = std::move(value);
  }
  return offer;
}

std::vector<std::string> offer_mismatches(const nlohmann::json& client, const nlohmann::json& server) {
  std::vector<std::string> out;
  auto walk = [&](auto& self, const nlohmann::json& a, const nlohmann::json& b, const std::string& path) -> void {
    if (a.is_object() && b.is_object()) {
      std::set<std::string> keys;
      for (auto it = a.begin(); it != a.end(); ++it) keys.insert(it.key());
      for (auto it = b.begin(); it != b.end(); ++it) keys.insert(it.key());
      for (const std::string& k : keys) {
        if (path.empty() && k == "scene") continue;  // the name may differ; the hash may not
        const std::string p = path.empty() ? k : path + "." + k;
        self(self, a.contains(k) ? a[k] : nlohmann::json(), b.contains(k) ? b[k] : nlohmann::json(), p);
      }
      return;
    }
    if (a != b) out.push_back(fmt::format("{}: client {}, server {}", path, json_excerpt(a, 200), json_excerpt(b, 200)));
  };
  walk(walk, client, server, "");
  // Never throws, whatever the shapes: a field that is absent or not a string reads as "?".
  auto text = [](const nlohmann::json& o, const char* key) {
    if (!o.is_object()) return std::string("?");
    const auto it = o.find(key);
    return it != o.end() && it->is_string() ? json_excerpt(*it, 200) : std::string("?");
  };
  if (!out.empty() && text(client, "scene_hash") != text(server, "scene_hash"))
    out.insert(out.begin(), fmt::format("scene: client {}, server {} (different content)", text(client, "scene"),
                                        text(server, "scene")));
  return out;
}

std::vector<std::string> live_ignored_fields(const SimConfig& c) {
  const SimConfig d;
  std::vector<std::string> out;
  // The settings with a live_ignored reason (core/run_config.cpp), set to other than their defaults.
  for (const RunSetting& s : run_settings())
    if (!s.live_ignored.empty() && s.get(c) != s.get(d)) out.push_back(fmt::format("{} ({})", s.key, s.live_ignored));
  return out;
}

// ---- server ------------------------------------------------------------------------------

namespace {

class LiveServer {
 public:
  LiveServer(const SimConfig& c, const Registries& r, const LiveScene& s, const ServeOptions& o)
      : c_(c), registries_(r), scene_(s), o_(o), offer_(session_offer(c, r, s.name, s.key)), plan_(plan_passes(*s.scene, c.trace)),
        socket_(o.bind), mac_(load_key(o.key_file)) {
    if (c.mode != "hybrid") fail("live mode serves hybrid rendering only (mode '{}' given)", c.mode);
    rt_ = std::make_unique<RtScene>(*s.scene);
    write_port_file(o.port_file, socket_.local());
    say(o_.quiet, "serve", "listening on UDP {} (scene {}, {}x{} at {} Hz, passes:{}{}; {})", socket_.local().to_string(),
        s.name, c.width, c.height, c.display_hz, plan_.visibility() ? " visibility" : "", plan_.ao ? " ao" : "",
        mac_ ? "every datagram authenticated (HMAC-SHA256)" : "no key: sessions bound by address and token");
  }

  int run(const std::atomic<bool>& stop) {
    while (!stop.load()) {
      socket_.wait_readable(20);
      drain();
      if (session_ && session_->pending) serve(*session_);
      if (session_ && ms_between(session_->last_heard, Clock::now()) > o_.idle_timeout_s * 1000.0)
        end_session(fmt::format("the client was silent for {:.1f} s", o_.idle_timeout_s));
      if (o_.sessions > 0 && sessions_done_ >= o_.sessions) break;
    }
    if (session_) {
      send_control(msg(ControlType::Bye, session_->id, "server stopping"), session_->peer);
      end_session("the server was stopped");
    }
    say(o_.quiet, "serve", "exiting after {} session(s)", sessions_done_);
    return 0;
  }

 private:
  struct Session {
    uint32_t id = 0;     // the session token (random, from the OS)
    uint32_t nonce = 0;  // the client's Hello nonce (a repeated Hello gets the Welcome again)
    Endpoint peer;
    std::unique_ptr<ServerPipeline> pipeline;  // core/pipeline.h: the simulator's server stages
    uint32_t first_sequence[2] = {0, 0};       // per stream (visibility, ao): random, sent in the Welcome
    int64_t last_frame = -1;
    std::optional<CameraUpdate> pending;
    bool keyframe = false;
    Clock::time_point started, last_heard;
    uint64_t cameras = 0, cameras_superseded = 0, cameras_stale = 0, frames_served = 0;
    uint64_t datagrams_sent = 0, bytes_sent = 0, send_dropped = 0;
    std::vector<double> compute_ms;  // the first kMaxSamples frames (for percentiles)
    std::ofstream log;               // server_frames.csv, written as frames are sent
  };
  static constexpr size_t kMaxSamples = 100000;

  // Seals (with a key) and sends; the token is the session's for Camera/Bye/passes (mac_token).
  SendResult send_datagram(std::vector<uint8_t> d, const Endpoint& to, uint32_t token) {
    if (mac_) mac_->seal(d, Direction::ToClient, mac_token(d, token));
    return socket_.send_to(d, to);
  }
  void send_control(const ControlMessage& m, const Endpoint& to) {
    send_datagram(encode_control(m), to, session_ ? session_->id : 0);
  }
  size_t mac_bytes() const { return mac_ ? kMacBytes : 0; }

  void drain() {
    // At most this many datagrams before serving a frame again: a flood cannot starve it.
    for (int i = 0; i < 4096; ++i) {
      Endpoint from;
      const ReceiveResult r = socket_.receive(buffer_, from);
      if (r == ReceiveResult::Empty) return;
      if (r == ReceiveResult::Error) continue;
      if (r == ReceiveResult::Truncated) {
        ++bad_["truncated"];
        continue;
      }
      // Every datagram's checks return outcomes; this only keeps a bug (or a full disk when a
      // session opens its log) from ending the server: it is reported and counted.
      try {
        handle(from);
      } catch (const std::exception& e) {
        ++bad_["handler_error"];
        say(false, "serve", "error handling a datagram from {}: {}", from.to_string(), e.what());
      }
    }
  }

  // The server's checks, cheapest first: the MAC (with a key), the header and the body's types
  // (read_control); a Hello may come from anyone; everything else only from the session's peer,
  // with its token.
  void handle(const Endpoint& from) {
    std::span<const uint8_t> d = buffer_;
    if (mac_) {
      if (d.size() < kMacBytes ||
          !mac_->verify(d, Direction::ToServer, mac_token(d.first(d.size() - kMacBytes), session_ ? session_->id : 0))) {
        ++bad_["bad_mac"];
        return;
      }
      d = d.first(d.size() - kMacBytes);
    }
    TypedControl m;
    if (const char* why = read_control(d, m)) {
      ++bad_[std::strcmp(why, "not_control") == 0 ? "not_a_control_message" : why];
      // The first few are told (a client with other settings learns which field); a flood is
      // only counted.
      if (!m.field.empty() && ++told_ <= 10)
        say(o_.quiet, "serve", "dropped a datagram from {}: {} ({}){}", from.to_string(), why, m.field,
            told_ == 10 ? "; further ones are only counted" : "");
      return;
    }
    const ControlType type = m.message.type;
    if (type == ControlType::Hello) return on_hello(m, from);
    if (!session_) {
      ++bad_[std::string(control_type_name(type)) + "_without_session"];
      return;
    }
    if (!(from == session_->peer)) {
      ++bad_["foreign_address"];
      return;
    }
    if (m.message.session != session_->id) {
      ++bad_["wrong_token"];
      return;
    }
    switch (type) {
      case ControlType::Camera: return on_camera(m.message);
      case ControlType::Bye: return end_session("the client said bye: " + m.message.text);
      default: ++bad_["unexpected_" + std::string(control_type_name(type))];
    }
  }

  // The Refuse goes to an address nothing has verified: it is never longer than the Hello
  // (at least 256 bytes), so that a spoofed Hello cannot make the server send more than it got.
  void refuse(const Endpoint& to, uint32_t nonce, std::string text) {
    const size_t limit = std::min(kMaxControlBody, std::max<size_t>(256, buffer_.size()) - kControlHeaderBytes);
    if (text.size() > limit) text.resize(limit);
    send_datagram(encode_control(msg(ControlType::Refuse, nonce, std::move(text))), to, 0);
    ++refused_;
  }

  void on_hello(const TypedControl& m, const Endpoint& from) {
    const uint32_t nonce = m.message.session;
    std::vector<std::string> why = offer_mismatches(m.offer.json, offer_);
    if (!why.empty()) {
      std::string text = "the session offers differ: ";
      for (size_t i = 0; i < why.size(); ++i) text += (i ? "; " : "") + why[i];
      text += ". Start client and server with the same scene and settings.";
      say(o_.quiet, "serve", "refused {}: {}", from.to_string(), printable_reason(text));
      refuse(from, nonce, text);
      return;
    }
    if (session_) {
      if (from == session_->peer && nonce == session_->nonce) {  // the Welcome was lost: send it again
        send_datagram(encode_control(msg(ControlType::Welcome, session_->id, welcome_body())), from, 0);
      } else {
        // Neither the peer's address nor anything else about the session is told.
        refuse(from, nonce, "the server is busy with another client");
      }
      return;
    }
    auto s = std::make_unique<Session>();
    // The token and the first sequence numbers come from the OS's random source, so that an
    // off-path sender cannot guess them (docs/live-security.md); they also tell stale packets
    // of an earlier session apart. 0 is never a token.
    s->id = os_random_u32();
    s->nonce = nonce;
    s->peer = from;
    for (int slot = 0; slot < 2; ++slot) s->first_sequence[slot] = os_random_u32();
    s->pipeline = std::make_unique<ServerPipeline>(c_, *scene_.scene, registries_, direct_tracer(*rt_, c_), stream_of(s->id));
    for (size_t i = 0; i < s->pipeline->passes().size(); ++i)
      s->pipeline->set_next_sequence(i, s->first_sequence[stream_slot(s->pipeline->passes()[i])]);
    s->started = s->last_heard = Clock::now();
    if (!o_.out_dir.empty()) {
      std::filesystem::create_directories(o_.out_dir);
      const bool first = sessions_done_ == 0;
      s->log.open(o_.out_dir + "/server_frames.csv", first ? std::ios::trunc : std::ios::app);
      if (!s->log) fail("serve: cannot write '{}/server_frames.csv'", o_.out_dir);
      if (first) s->log << "session,frame,pass,encoded_bytes,packets,wire_bytes\n";
    }
    session_ = std::move(s);
    send_datagram(encode_control(msg(ControlType::Welcome, session_->id, welcome_body())), from, 0);
    say(o_.quiet, "serve", "session {:08x} with {}", session_->id, from.to_string());
  }

  std::string welcome_body() const {
    WelcomeBody w;
    w.session = session_->id;
    w.client_nonce = session_->nonce;
    w.first_sequence[0] = session_->first_sequence[0];
    w.first_sequence[1] = session_->first_sequence[1];
    w.offer.json = offer_;
    return welcome_text(w);
  }

  void on_camera(const ControlMessage& m) {
    Session& s = *session_;
    if (m.camera.camera.width != c_.width || m.camera.camera.height != c_.height) {
      ++bad_["camera_wrong_size"];
      return;
    }
    // A frame id far beyond the newest would make every later camera look stale.
    if (int64_t(m.camera.frame) > std::max<int64_t>(s.last_frame, s.pending ? s.pending->frame : -1) +
                                      int64_t(kMaxCameraFramesAhead)) {
      ++bad_["camera_frame_ahead"];
      return;
    }
    s.last_heard = Clock::now();
    ++s.cameras;
    if (int64_t(m.camera.frame) <= s.last_frame || (s.pending && m.camera.frame <= s.pending->frame)) {
      ++s.cameras_stale;  // reordered or duplicated: a newer camera was seen already
      return;
    }
    if (s.pending) ++s.cameras_superseded;  // the server was busy: only the newest is served
    s.keyframe = s.keyframe || m.camera.keyframe_request;
    s.pending = m.camera;
  }

  void serve(Session& s) {
    const CameraUpdate cam = *s.pending;
    s.pending.reset();
    const bool keyframe = s.keyframe;
    s.keyframe = false;
    const auto t0 = Clock::now();
    // The same stages, seed and frame index as the simulator: the same camera gives the same
    // passes and the same bytes.
    ServerFrame f = s.pipeline->run(cam.frame, cam.camera, cam.scene_time_s, keyframe);
    if (s.log.is_open())
      for (const SentPass& p : f.passes)
        s.log << fmt::format("{:08x},{},{},{},{},{}\n", s.id, cam.frame, p.name, p.encoded_bytes, p.packets.size(),
                             wire_bytes_of_pass(p.encoded_bytes, c_.max_payload_bytes) + p.packets.size() * mac_bytes());
    if (s.compute_ms.size() < kMaxSamples) s.compute_ms.push_back(ms_between(t0, Clock::now()));
    for (SentPass& pass : f.passes)
      for (auto& p : pass.packets) {
        const size_t bytes = p.size() + mac_bytes();
        const SendResult r = send_datagram(std::move(p), s.peer, s.id);
        if (r == SendResult::Sent) {
          ++s.datagrams_sent;
          s.bytes_sent += bytes;
        } else {
          ++s.send_dropped;  // the kernel's send buffer was full: a lost datagram
        }
      }
    s.last_frame = cam.frame;
    ++s.frames_served;
  }

  void end_session(const std::string& reason) {
    Session& s = *session_;
    const double seconds = ms_between(s.started, Clock::now()) / 1000.0;
    say(o_.quiet, "serve", "session {:08x} ended: {} ({} frames served in {:.1f} s, {} datagrams, {:.2f} MB sent{})",
        s.id, reason, s.frames_served, seconds, s.datagrams_sent, double(s.bytes_sent) / 1e6,
        s.send_dropped ? fmt::format(", {} dropped by a full send buffer", s.send_dropped) : "");
    ++sessions_done_;
    if (!o_.out_dir.empty()) {
      std::filesystem::create_directories(o_.out_dir);
      summaries_.push_back({{"session", s.id},
                            {"client", s.peer.to_string()},
                            {"end_reason", reason},
                            {"duration_s", seconds},
                            {"cameras_received", s.cameras},
                            {"cameras_superseded", s.cameras_superseded},
                            {"cameras_stale", s.cameras_stale},
                            {"frames_served", s.frames_served},
                            {"datagrams_sent", s.datagrams_sent},
                            {"bytes_sent", s.bytes_sent},
                            {"wire_bytes_sent", on_the_wire(s.bytes_sent, s.datagrams_sent)},
                            {"mbps_sent", seconds > 0 ? double(on_the_wire(s.bytes_sent, s.datagrams_sent)) * 8.0 / 1e6 / seconds : 0.0},
                            {"datagrams_dropped_by_send_buffer", s.send_dropped},
                            {"compute_ms", percentiles(s.compute_ms)},
                            {"bad_or_foreign_datagrams", counts_json(bad_)},
                            {"refused_hellos", refused_}});
      const nlohmann::json notes = {
          {"bytes_sent", "pass packets' UDP payload bytes (dhrbench header, payload, and the MAC with a key)"},
          {"wire_bytes_sent", "bytes_sent plus 28 bytes of IPv4 and UDP headers per datagram (kIpUdpOverheadBytes), as the simulator counts"},
          {"mbps_sent", "wire_bytes_sent in Mb/s over duration_s"},
          {"bad_or_foreign_datagrams", "datagrams dropped since the server started, by reason (docs/live-security.md)"}};
      write_text(o_.out_dir + "/server.json", nlohmann::json{{"role", "server"},
                                                             {"authentication", authentication_name(mac_)},
                                                             {"offer", offer_},
                                                             {"field_notes", notes},
                                                             {"sessions", summaries_}}
                                                      .dump(2) + "\n");
      s.log.close();
    }
    session_.reset();
  }

  const SimConfig& c_;
  const Registries& registries_;
  LiveScene scene_;
  ServeOptions o_;
  nlohmann::json offer_;
  PassPlan plan_;
  UdpSocket socket_;
  std::optional<DatagramMac> mac_;
  std::unique_ptr<RtScene> rt_;
  std::unique_ptr<Session> session_;
  std::vector<uint8_t> buffer_;
  std::map<std::string, uint64_t> bad_;
  uint64_t refused_ = 0, told_ = 0;
  int sessions_done_ = 0;
  std::vector<nlohmann::json> summaries_;
};

}  // namespace

int run_live_server(const SimConfig& config, const Registries& registries, const LiveScene& scene,
                    const ServeOptions& options, const std::atomic<bool>& stop) {
  validate_sim_config(config, *scene.scene, registries);
  LiveServer server(config, registries, scene, options);
  return server.run(stop);
}

// ---- client ------------------------------------------------------------------------------

namespace {

class LiveClient {
 public:
  LiveClient(const SimConfig& c, const Registries& r, const LiveScene& s, const ClientOptions& o)
      : c_(c), registries_(r), scene_(s), o_(o), offer_(session_offer(c, r, s.name, s.key)), plan_(plan_passes(*s.scene, c.trace)),
        socket_(any_endpoint_like(o.server)), mac_(load_key(o.key_file)), client_(c, *s.scene, r) {
    if (c.mode != "hybrid") fail("live mode is hybrid rendering only (mode '{}' given)", c.mode);
    if (o.frames < 1) fail("client: --frames must be at least 1 (got {})", o.frames);
    for (size_t i = 0; i < client_.passes().size(); ++i) pass_of_slot_[stream_slot(client_.passes()[i])] = int(i);
    AssemblerConfig ac;
    ac.max_payload_bytes = c.max_payload_bytes;
    ac.timeout_ms = 500;
    assembler_ = Assembler(ac);
  }

  int run(const std::atomic<bool>& stop) {
    if (int rc = handshake(stop); rc != 0) return rc;
    const double period_ms = 1000.0 / c_.display_hz;
    t0_ = Clock::now();
    last_heard_ = t0_;
    send_ms_.assign(size_t(o_.frames), -1.0);
    for (int a = 0; a < o_.frames && end_reason_.empty(); ++a) {
      if (stop.load()) {
        end_reason_ = "the client was stopped";
        break;
      }
      const double deadline = double(a) * period_ms;
      if (now_ms() > deadline + period_ms) {
        ++frames_skipped_;  // this machine cannot keep the display rate: the frame is dropped
        continue;
      }
      pump_until(deadline, stop);
      if (!end_reason_.empty()) break;
      display(a);
      if (ms_between(last_heard_, Clock::now()) > o_.idle_timeout_s * 1000.0)
        end_reason_ = fmt::format("the server was silent for {:.1f} s", o_.idle_timeout_s);
    }
    const bool server_gone = end_reason_.rfind("the server", 0) == 0;
    if (end_reason_.empty()) {
      end_reason_ = fmt::format("all {} frames displayed", o_.frames);
      await_last_passes(stop);
    }
    if (!server_gone)
      for (int i = 0; i < 3; ++i)  // UDP may lose one; the server's idle timeout is the fallback
        send_control(msg(ControlType::Bye, session_, "client done"));
    session_seconds_ = now_ms() / 1000.0;
    AssemblerEvents rest = assembler_.flush(int64_t(now_ms()));
    count_lost(rest);
    say(o_.quiet, "client", "session ended: {}", end_reason_);
    score();
    write_outputs();
    return 0;
  }

 private:
  struct Row {
    int frame = 0;
    double t_ms = 0, client_ms = 0;
    int source_frame[2] = {-1, -1};
    double age_ms[2] = {0, 0};
    uint64_t disoccluded[2] = {0, 0};
    bool scored = false;
    double ssim = 0, psnr = 0;
  };

  double now_ms() const { return ms_between(t0_, Clock::now()); }
  double frame_time_s(int a) const { return c_.start_time_s + double(a) / c_.display_hz; }
  Camera camera(int a) const { return scene_.scene->camera.at(frame_time_s(a), c_.width, c_.height); }

  // Seals (with a key) and sends to the server.
  SendResult send_control(const ControlMessage& m) {
    std::vector<uint8_t> d = encode_control(m);
    if (mac_) mac_->seal(d, Direction::ToServer, mac_token(d, session_));
    return socket_.send_to(d, o_.server);
  }

  // The first checks of every datagram: its sender is the server (the address the client sends
  // to: the server's or the relay's) and, with a key, its MAC. Returns the datagram without
  // the MAC, or nullopt (counted).
  std::optional<std::span<const uint8_t>> from_peer(const Endpoint& from) {
    std::span<const uint8_t> d = buffer_;
    if (!(from == o_.server)) {
      ++bad_["foreign_address"];
      return std::nullopt;
    }
    if (mac_) {
      if (d.size() < kMacBytes ||
          !mac_->verify(d, Direction::ToClient, mac_token(d.first(d.size() - kMacBytes), session_))) {
        ++bad_["bad_mac"];
        return std::nullopt;
      }
      d = d.first(d.size() - kMacBytes);
    }
    return d;
  }

  int handshake(const std::atomic<bool>& stop) {
    const auto start = Clock::now();
    // The nonce binds the answer to this Hello: a Welcome or Refuse must echo it.
    const uint32_t nonce = os_random_u32();
    say(o_.quiet, "client", "connecting to {} ...", o_.server.to_string());
    double next_hello_ms = 0;
    while (!stop.load()) {
      const double t = ms_between(start, Clock::now());
      if (t > o_.connect_timeout_s * 1000.0) break;
      if (t >= next_hello_ms) {
        send_control(msg(ControlType::Hello, nonce, offer_.dump()));
        next_hello_ms = t + 250.0;  // Hello or its answer may be lost: repeat
      }
      if (!socket_.wait_readable(int(std::max(1.0, next_hello_ms - t)))) continue;
      Endpoint from;
      for (int i = 0; i < 4096; ++i) {
        const ReceiveResult r = socket_.receive(buffer_, from);
        if (r == ReceiveResult::Empty) break;
        if (r != ReceiveResult::Received) {
          ++bad_[r == ReceiveResult::Truncated ? "truncated" : "receive_error"];
          continue;
        }
        const auto d = from_peer(from);
        if (!d) continue;
        TypedControl m;
        if (const char* why = read_control(*d, m)) {
          ++bad_[std::string("control_") + why];
          continue;
        }
        if (m.message.type == ControlType::Refuse && m.message.session == nonce) {
          fmt::print(stderr, "client: the server at {} refused the session: {}\n", o_.server.to_string(), m.message.text);
          return 2;
        }
        if (m.message.type == ControlType::Welcome && m.welcome.client_nonce == nonce) {
          if (const auto why = offer_mismatches(offer_, m.welcome.offer.json); !why.empty()) {
            fmt::print(stderr, "client: the server at {} welcomed another session: {}\n", o_.server.to_string(),
                       printable_reason(why.front()));
            return 2;
          }
          start_session(m.welcome);
          say(o_.quiet, "client", "session {:08x} with {} after {:.0f} ms", session_, o_.server.to_string(),
              ms_between(start, Clock::now()));
          write_port_file(o_.port_file, socket_.local());
          return 0;
        }
        ++bad_[std::string("handshake_unexpected_") + control_type_name(m.message.type)];
      }
    }
    fmt::print(stderr,
               "client: no answer from a dhrbench server at {} within {:.1f} s (is 'dhrbench serve' running there, "
               "does UDP reach it{}?)\n",
               o_.server.to_string(), o_.connect_timeout_s, mac_ ? ", and does it use the same --key-file" : "");
    return 1;
  }

  void start_session(const WelcomeBody& w) {
    session_ = w.session;
    uint32_t codec_ids[kPassSlots] = {0, 0};
    bool streams[kPassSlots] = {false, false};
    const BackendChoice* codecs[kPassSlots] = {&c_.visibility_codec, &c_.ao_codec};
    for (int slot = 0; slot < kPassSlots; ++slot) {
      streams[slot] = pass_of_slot_[slot] >= 0;
      codec_ids[slot] = codec_id(codecs[slot]->name);
      if (streams[slot]) client_.receiver(pass_of_slot_[slot]).expected_sequence = w.first_sequence[slot];
    }
    gate_ = PassGate(session_, w.first_sequence, codec_ids, streams);
  }

  // Receives until `deadline_ms` (session time), or only what is waiting when it has passed.
  void pump_until(double deadline_ms, const std::atomic<bool>& stop) {
    for (;;) {
      receive_waiting();
      const double left = deadline_ms - now_ms();
      if (left <= 0 || !end_reason_.empty() || stop.load()) return;
      socket_.wait_readable(int(std::ceil(std::min(left, 50.0))));
    }
  }

  // After the last displayed frame: the passes of the last camera are on their way. Receiving
  // them (for at most a second) before the Bye makes what the client counts received equal
  // to what the server sent on a link that loses nothing.
  void await_last_passes(const std::atomic<bool>& stop) {
    if (!gate_camera_sent_) return;
    const double until = now_ms() + std::min(1000.0, o_.idle_timeout_s * 1000.0);
    auto done = [&] {
      for (int slot = 0; slot < kPassSlots; ++slot)
        if (pass_of_slot_[slot] >= 0 && newest_completed_[slot] < int64_t(last_camera_)) return false;
      return true;
    };
    while (!done() && end_reason_.rfind("all ", 0) == 0 && !stop.load() && now_ms() < until) {
      socket_.wait_readable(int(std::ceil(std::clamp(until - now_ms(), 1.0, 20.0))));
      receive_waiting();
    }
  }

  void receive_waiting() {
    for (int i = 0; i < 65536; ++i) {
      Endpoint from;
      const ReceiveResult r = socket_.receive(buffer_, from);
      if (r == ReceiveResult::Empty) return;
      if (r == ReceiveResult::Error) {
        ++bad_["receive_error"];
        continue;
      }
      const double t = now_ms();
      const size_t second = size_t(std::max(0.0, t / 1000.0));
      if (per_second_.size() <= second) per_second_.resize(second + 1);
      per_second_[second].datagrams += 1;
      per_second_[second].bytes += buffer_.size();
      ++datagrams_;
      bytes_ += buffer_.size();
      if (r == ReceiveResult::Truncated) {
        ++bad_["truncated"];
        continue;
      }
      const auto d = from_peer(from);
      if (!d) continue;
      if (on_datagram(*d, t)) {
        // The session's: from the peer, with its token (and MAC), inside the windows.
        ++session_datagrams_;
        session_bytes_ += buffer_.size();
        per_second_[second].session_datagrams += 1;
        per_second_[second].session_bytes += buffer_.size();
        last_heard_ = Clock::now();
      }
    }
  }

  // `d`: a datagram from the server (MAC removed). True when it is the session's.
  bool on_datagram(std::span<const uint8_t> d, double t) {
    if (looks_like_control(d)) {
      TypedControl m;
      if (const char* why = read_control(d, m)) {
        ++bad_[std::string("control_") + why];
        return false;
      }
      if (m.message.session != session_) {
        ++bad_["control_wrong_token"];
        return false;
      }
      if (m.message.type == ControlType::Bye) {
        end_reason_ = "the server ended the session: " + m.message.text;
      } else if (m.message.type != ControlType::Welcome) {  // a repeated Welcome is harmless
        ++bad_[std::string("unexpected_") + control_type_name(m.message.type)];
        return false;
      }
      return true;
    }
    ParsedPacket pkt;
    const ParseResult pr = parse_packet(d, pkt);
    if (pr != ParseResult::Ok) {
      ++bad_[std::string("packet_") + parse_result_name(pr)];
      return false;
    }
    if (const char* why = gate_.check(pkt)) {
      ++bad_[why];
      return false;
    }
    ++session_pass_datagrams_;
    session_pass_bytes_ += buffer_.size();
    const PacketFate fate = assembler_.push(d, int64_t(t));
    if (fate == PacketFate::Accepted || fate == PacketFate::Completed) {
      const int slot = slot_of(pkt.meta.desc.kind);
      if (slot >= 0) {
        auto& b = socket_bytes_[{slot, pkt.meta.frame_id}];
        b.first += buffer_.size();
        b.second += 1;
        if (fate == PacketFate::Completed)
          newest_completed_[slot] = std::max(newest_completed_[slot], int64_t(pkt.meta.frame_id));
      }
    }
    return true;
  }

  void count_lost(const AssemblerEvents& events) {
    for (const LostFrame& l : events.lost) {
      const int slot = slot_of(l.meta.desc.kind);
      if (slot < 0) continue;
      ++frames_lost_[slot];
      socket_bytes_.erase({slot, l.meta.frame_id});
    }
  }

  void display(int a) {
    const auto start = Clock::now();
    Row row;
    row.frame = a;
    row.t_ms = now_ms();
    // Uplink: this frame's camera, with a keyframe request after a loss.
    CameraUpdate cu;
    cu.frame = uint32_t(a);
    cu.keyframe_request = keyframe_request_;
    cu.scene_time_s = frame_time_s(a);
    cu.camera = camera(a);
    gate_.camera_sent(cu.frame);
    gate_camera_sent_ = true;
    last_camera_ = cu.frame;
    if (send_control(camera_msg(session_, cu)) == SendResult::Sent) keyframe_request_ = false;
    send_ms_[size_t(a)] = row.t_ms;

    GBuffer g;
    rasterize({scene_.scene, cu.camera, cu.scene_time_s, has_prev_ ? prev_camera_ : cu.camera,
               has_prev_ ? prev_time_s_ : cu.scene_time_s},
              g);
    has_prev_ = true;
    prev_camera_ = cu.camera;
    prev_time_s_ = cu.scene_time_s;
    client_.keep(a, std::move(g));
    const GBuffer& gbuf = *client_.gbuffer(a);

    receive_waiting();
    AssemblerEvents events = assembler_.poll(int64_t(now_ms()));
    count_lost(events);
    for (AssembledFrame& f : events.completed) {
      const int slot = slot_of(f.meta.desc.kind);
      if (slot < 0 || pass_of_slot_[slot] < 0) continue;
      ++frames_completed_[slot];
      const uint32_t frame_id = f.meta.frame_id;
      if (frame_id < send_ms_.size() && send_ms_[frame_id] >= 0)
        round_trip_ms_[slot].push_back(double(f.completed_ms) - send_ms_[frame_id]);
      const PassReceiver::Outcome out = client_.receive(pass_of_slot_[slot], f);
      keyframe_request_ = keyframe_request_ || out.keyframe_request;
      decode_errors_[slot] += out.decode_error ? 1 : 0;
      auto it = socket_bytes_.find({slot, frame_id});
      if (it != socket_bytes_.end()) {
        completed_log_.push_back({int(frame_id), slot, it->second.first, it->second.second});
        socket_bytes_.erase(it);
      }
    }
    // Partial frames' byte counts older than the history are no longer needed.
    while (!socket_bytes_.empty() && int64_t(socket_bytes_.begin()->first.second) + 4 * c_.history_frames < a)
      socket_bytes_.erase(socket_bytes_.begin());

    // Predict and composite: the simulator's client stages (core/pipeline.h).
    ClientFrame shown = client_.display(a, gbuf, [this](int frame) { return camera(frame); });
    without_data_ += shown.passes_without_data > 0 ? 1 : 0;
    for (size_t i = 0; i < client_.passes().size(); ++i)
      pass_without_data_[stream_slot(client_.passes()[i])] += shown.without_data[i] ? 1 : 0;
    for (size_t i = 0; i < client_.passes().size(); ++i) {
      const int slot = stream_slot(client_.passes()[i]);
      row.source_frame[slot] = shown.source_frame[i];
      row.disoccluded[slot] = shown.disoccluded[i];
      if (shown.source_frame[i] >= 0) row.age_ms[slot] = double(a - shown.source_frame[i]) * 1000.0 / c_.display_hz;
    }
    ImageRGB8& image = shown.image;
    row.client_ms = ms_between(start, Clock::now());
    if (o_.score_every > 0 && a % o_.score_every == 0) {
      row.scored = true;
      kept_[a] = image;
    }
    if (o_.save_every > 0 && a % o_.save_every == 0) kept_[a] = std::move(image);
    rows_.push_back(row);
  }

  // Quality after the session (so that scoring never slows the real-time loop): each scored
  // frame against the local reference, defined as in the simulator (core/pipeline.h,
  // LocalReference): the frame's own passes traced for its camera and denoised by a sequence of
  // their own that, with a temporal denoiser, runs over every frame index in order.
  void score() {
    if (o_.score_every <= 0 || rows_.empty()) return;
    say(o_.quiet, "client", "scoring {} frames against the local reference ...",
        std::count_if(rows_.begin(), rows_.end(), [](const Row& r) { return r.scored; }));
    RtScene rt(*scene_.scene);
    const TraceFn trace = direct_tracer(rt, c_);
    LocalReference local(c_, *scene_.scene, registries_);
    std::map<int, Row*> scored;
    for (Row& row : rows_)
      if (row.scored) scored[row.frame] = &row;
    if (scored.empty()) return;
    const int last = scored.rbegin()->first;
    for (int a = local.needs_every_frame() ? 0 : scored.begin()->first; a <= last; ++a) {
      auto it = scored.find(a);
      if (it == scored.end() && !local.needs_every_frame()) continue;
      const Camera cam = camera(a), prev = a > 0 ? camera(a - 1) : cam;
      GBuffer g;
      rasterize({scene_.scene, cam, frame_time_s(a), prev, a > 0 ? frame_time_s(a - 1) : frame_time_s(a)}, g);
      const std::optional<ImageRGB8> ref = local.frame(uint32_t(a), g, *trace(uint32_t(a), g), it != scored.end());
      if (!ref) continue;
      const QualityScores q = compare_images(*ref, kept_.at(a));
      it->second->ssim = q.ssim;
      it->second->psnr = q.psnr_db;
    }
  }

  void write_outputs() {
    namespace fs = std::filesystem;
    fs::create_directories(o_.out_dir);
    if (o_.save_every > 0) {
      fs::create_directories(o_.out_dir + "/frames");
      for (const auto& [a, img] : kept_)
        if (a % o_.save_every == 0) write_png(fmt::format("{}/frames/frame_{:05d}.png", o_.out_dir, a), img);
    }
    std::string csv = "frame,t_ms,client_ms,vis_source_frame,vis_age_ms,ao_source_frame,ao_age_ms,scored,ssim_local,psnr_local\n";
    std::vector<double> client_ms, ssim, psnr, age[2];
    for (const Row& r : rows_) {
      csv += fmt::format("{},{:.3f},{:.3f},{},{:.1f},{},{:.1f},{},{},{}\n", r.frame, r.t_ms, r.client_ms, r.source_frame[0],
                         r.age_ms[0], r.source_frame[1], r.age_ms[1], r.scored ? 1 : 0,
                         r.scored ? fmt::format("{:.6f}", r.ssim) : "", r.scored ? fmt::format("{:.3f}", r.psnr) : "");
      client_ms.push_back(r.client_ms);
      if (r.scored) {
        ssim.push_back(r.ssim);
        psnr.push_back(psnr_for_mean(r.psnr));
      }
      for (int s = 0; s < 2; ++s)
        if (r.source_frame[s] >= 0) age[s].push_back(r.age_ms[s]);
    }
    write_text(o_.out_dir + "/frames.csv", csv);
    // Per second: everything read from the socket, then the session's datagrams and their Mb/s
    // on the wire (UDP payload + 28 bytes of IPv4/UDP headers each, as the simulator counts).
    std::string sock = "second,datagrams,bytes,session_datagrams,session_bytes,mbps\n";
    for (size_t i = 0; i < per_second_.size(); ++i) {
      const Second& p = per_second_[i];
      sock += fmt::format("{},{},{},{},{},{:.3f}\n", i, p.datagrams, p.bytes, p.session_datagrams, p.session_bytes,
                          double(on_the_wire(p.session_bytes, p.session_datagrams)) * 8.0 / 1e6);
    }
    write_text(o_.out_dir + "/socket.csv", sock);
    std::string passes_csv = "frame,pass,socket_bytes,packets\n";
    for (const auto& r : completed_log_)
      passes_csv += fmt::format("{},{},{},{}\n", r.frame, kSlotName[r.slot], r.socket_bytes, r.packets);
    write_text(o_.out_dir + "/received_passes.csv", passes_csv);

    const AssemblerStats& as = assembler_.stats();
    nlohmann::json fates = nlohmann::json::object();
    for (int f = 0; f < kPacketFateCount; ++f)
      if (as.packets[size_t(f)]) fates[packet_fate_name(PacketFate(f))] = as.packets[size_t(f)];
    nlohmann::json lost_by = nlohmann::json::object();
    for (int r = 0; r < kLossReasonCount; ++r)
      if (as.frames_lost[size_t(r)]) lost_by[loss_reason_name(LossReason(r))] = as.frames_lost[size_t(r)];
    nlohmann::json passes = nlohmann::json::object();
    for (int s = 0; s < 2; ++s) {
      if (pass_of_slot_[s] < 0) continue;
      passes[kSlotName[s]] = {{"frames_completed", frames_completed_[s]},
                              {"frames_lost", frames_lost_[s]},
                              {"frames_without_data", pass_without_data_[s]},
                              {"decode_errors", decode_errors_[s]},
                              {"age_ms", percentiles(age[s])},
                              {"round_trip_ms", percentiles(round_trip_ms_[s])}};
    }
    const uint64_t received_packets = as.count(PacketFate::Accepted) + as.count(PacketFate::Completed);
    const uint64_t wire = on_the_wire(session_bytes_, session_datagrams_);
    const nlohmann::json notes = {
        {"socket.datagrams, socket.bytes", "everything read from the socket (UDP payload bytes), foreign datagrams included"},
        {"socket.session_datagrams, socket.session_bytes",
         "the session's datagrams: from the server's address, with the session's token (and MAC), inside the windows"},
        {"socket.session_pass_datagrams, socket.session_pass_bytes",
         "the pass packets among them; server.json's datagrams_sent and bytes_sent on a link that loses nothing"},
        {"socket.wire_bytes", "session_bytes plus 28 bytes of IPv4 and UDP headers per datagram (kIpUdpOverheadBytes): "
                              "bandwidth on the wire as the simulator counts it (with a key, the 16-byte MAC is in session_bytes)"},
        {"socket.mbps, socket.bytes_per_s, socket.datagrams_per_s", "the session's, on the wire, over duration_s"},
        {"socket.bad_or_foreign", "datagrams dropped, by reason (docs/live-security.md); none counts as loss"}};
    const double seconds = std::max(1e-9, session_seconds_);
    const nlohmann::json out = {
        {"role", "client"},
        {"server", o_.server.to_string()},
        {"session", session_},
        {"end_reason", end_reason_},
        {"offer", offer_},
        {"predictor", {{"visibility", {{"name", c_.predictor.name}, {"params", c_.predictor.params}}},
                       {"ao", {{"name", c_.ao_predictor.name}, {"params", c_.ao_predictor.params}}}}},
        {"frames",
         {{"requested", o_.frames},
          {"displayed", rows_.size()},
          {"skipped_late", frames_skipped_},
          {"without_data", without_data_},
          {"scored", ssim.size()}}},
        {"quality", {{"ssim_local", percentiles(ssim)}, {"psnr_local_db", percentiles(psnr)}}},
        {"client_ms", percentiles(client_ms)},
        {"authentication", authentication_name(mac_)},
        {"socket",
         {{"duration_s", session_seconds_},
          {"datagrams", datagrams_},
          {"bytes", bytes_},
          {"session_datagrams", session_datagrams_},
          {"session_bytes", session_bytes_},
          {"session_pass_datagrams", session_pass_datagrams_},
          {"session_pass_bytes", session_pass_bytes_},
          {"wire_bytes", wire},
          {"datagrams_per_s", double(session_datagrams_) / seconds},
          {"bytes_per_s", double(wire) / seconds},
          {"mbps", double(wire) * 8.0 / 1e6 / seconds},
          {"receive_buffer_bytes", socket_.receive_buffer_bytes()},
          {"bad_or_foreign", counts_json(bad_)}}},
        {"packets",
         {{"received", received_packets},
          {"fates", fates},
          {"lost", as.packets_lost},
          {"loss_rate", received_packets + as.packets_lost
                            ? double(as.packets_lost) / double(received_packets + as.packets_lost)
                            : 0.0},
          {"frames_lost_by_reason", lost_by}}},
        {"passes", passes},
        {"field_notes", notes}};
    write_text(o_.out_dir + "/live.json", out.dump(2) + "\n");
    say(o_.quiet, "client",
        "{} of {} frames displayed ({} skipped late), {} without data; {:.2f} Mb/s on the wire, {} datagrams, {} packets lost "
        "({:.2f} %); SSIM {}; results in {}",
        rows_.size(), o_.frames, frames_skipped_, without_data_, out["socket"]["mbps"].get<double>(), session_datagrams_,
        as.packets_lost, 100.0 * out["packets"]["loss_rate"].get<double>(),
        ssim.empty() ? std::string("not scored") : fmt::format("{:.4f} (mean of {})", out["quality"]["ssim_local"]["mean"].get<double>(), ssim.size()),
        o_.out_dir);
  }

  struct Second {
    uint64_t datagrams = 0, bytes = 0, session_datagrams = 0, session_bytes = 0;
  };

  const SimConfig& c_;
  const Registries& registries_;
  LiveScene scene_;
  ClientOptions o_;
  nlohmann::json offer_;
  PassPlan plan_;
  UdpSocket socket_;
  std::optional<DatagramMac> mac_;
  uint32_t session_ = 0;
  PassGate gate_;
  bool gate_camera_sent_ = false;
  uint32_t last_camera_ = 0;
  int64_t newest_completed_[kPassSlots] = {-1, -1};  // per pass: the newest frame whose packets all arrived
  Clock::time_point t0_, last_heard_;
  std::string end_reason_;
  double session_seconds_ = 0;
  std::vector<uint8_t> buffer_;
  Assembler assembler_;
  ClientPipeline client_;       // core/pipeline.h: decode, predict, composite, the G-buffer history
  int pass_of_slot_[2] = {-1, -1};  // per stream (visibility, ao): its pass in client_, -1: none
  bool keyframe_request_ = false;
  bool has_prev_ = false;
  Camera prev_camera_;
  double prev_time_s_ = 0;
  std::vector<double> send_ms_;
  std::vector<Row> rows_;
  std::map<int, ImageRGB8> kept_;  // bounded: frames / score_every + frames / save_every images
  std::map<std::pair<int, uint32_t>, std::pair<uint64_t, uint64_t>> socket_bytes_;  // (slot, frame) -> bytes, packets
  struct ReceivedPass {
    int frame = 0;
    int slot = 0;
    uint64_t socket_bytes = 0;  // the datagrams' bytes as read from the socket (dhrbench header included)
    uint64_t packets = 0;
  };
  std::vector<ReceivedPass> completed_log_;  // per completed pass
  std::vector<Second> per_second_;
  std::map<std::string, uint64_t> bad_;
  uint64_t datagrams_ = 0, bytes_ = 0, frames_skipped_ = 0, without_data_ = 0;
  uint64_t session_datagrams_ = 0, session_bytes_ = 0, session_pass_datagrams_ = 0, session_pass_bytes_ = 0;
  uint64_t frames_completed_[2] = {0, 0}, frames_lost_[2] = {0, 0}, decode_errors_[2] = {0, 0};
  uint64_t pass_without_data_[2] = {0, 0};  // displayed frames that showed the pass's local fallback
  std::vector<double> round_trip_ms_[2];
};

}  // namespace

int run_live_client(const SimConfig& config, const Registries& registries, const LiveScene& scene,
                    const ClientOptions& options, const std::atomic<bool>& stop) {
  validate_sim_config(config, *scene.scene, registries);
  LiveClient client(config, registries, scene, options);
  return client.run(stop);
}

// ---- relay -------------------------------------------------------------------------------

namespace {

struct Scheduled {
  double due_ms = 0;
  uint64_t order = 0;
  int direction = 0;  // 0: client -> server, 1: server -> client
  std::vector<uint8_t> bytes;
  bool operator>(const Scheduled& o) const { return due_ms != o.due_ms ? due_ms > o.due_ms : order > o.order; }
};

struct DirectionStats {
  uint64_t received = 0, received_bytes = 0, forwarded = 0, forwarded_bytes = 0;
  uint64_t dropped_loss = 0, dropped_link_queue = 0, dropped_mtu = 0, dropped_relay_queue = 0, duplicated = 0;
  uint64_t send_failed = 0;
  nlohmann::json to_json() const {
    return {{"received", received},
            {"received_bytes", received_bytes},
            {"forwarded", forwarded},
            {"forwarded_bytes", forwarded_bytes},
            {"dropped_loss", dropped_loss},
            {"dropped_link_queue", dropped_link_queue},
            {"dropped_mtu", dropped_mtu},
            {"dropped_relay_queue", dropped_relay_queue},
            {"duplicated", duplicated},
            {"send_failed", send_failed}};
  }
};

// Reads a datagram as a control message of `type`, as sent with or without a MAC trailer (the
// relay holds no key: it reads headers only to find its peers and the end of the session).
bool reads_as(std::span<const uint8_t> d, ControlType type, ControlMessage& m) {
  if (!looks_like_control(d)) return false;
  if (parse_control(d, m) == ControlParse::Ok) return m.type == type;
  return d.size() >= kMacBytes && parse_control(d.first(d.size() - kMacBytes), m) == ControlParse::Ok && m.type == type;
}

}  // namespace

int run_live_relay(const RelayOptions& o, const std::atomic<bool>& stop) {
  if (!(o.duplicate_rate >= 0.0 && o.duplicate_rate <= 1.0))
    fail("relay: duplicate rate {} is outside 0..1", o.duplicate_rate);
  UdpSocket front(o.listen);                     // faces the client
  UdpSocket back(any_endpoint_like(o.server));  // faces the server
  write_port_file(o.port_file, front.local());
  say(o.quiet, "relay", "listening on {}, forwarding to {}", front.local().to_string(), o.server.to_string());
  Link links[2] = {Link(o.uplink, o.seed, 100), Link(o.downlink, o.seed, 101)};
  DirectionStats stats[2];
  std::priority_queue<Scheduled, std::vector<Scheduled>, std::greater<Scheduled>> queue;
  size_t queued_bytes = 0, peak_queued_bytes = 0;
  uint64_t order = 0, foreign = 0, duplicate_index = 0, byes_ignored = 0;
  std::map<std::string, uint64_t> dropped;  // by reason
  uint32_t token = 0;                       // the session's, from the server's Welcome
  Endpoint client;
  const auto t0 = Clock::now();
  auto last_traffic = t0;
  bool any_traffic = false;
  double bye_seen_ms = -1;
  std::string end_reason;
  std::vector<uint8_t> buf;

  auto accept = [&](int dir, double now) {
    DirectionStats& s = stats[dir];
    ++s.received;
    s.received_bytes += buf.size();
    last_traffic = Clock::now();
    any_traffic = true;
    ControlMessage m;
    if (dir == 1 && token == 0 && reads_as(buf, ControlType::Welcome, m)) token = m.session;
    if (reads_as(buf, ControlType::Bye, m)) {
      // Only a Bye with the session's token ends the relay (it is forwarded either way: the
      // endpoints decide whether it is the session's).
      if (token != 0 && m.session == token && bye_seen_ms < 0) {
        bye_seen_ms = now;
        end_reason = fmt::format("the {} said bye", dir == 0 ? "client" : "server");
      } else if (token == 0 || m.session != token) {
        ++byes_ignored;
      }
    }
    const Delivery d = links[dir].send(buf.size() + kIpUdpOverheadBytes, now);
    if (!d.delivered) {
      if (d.reason == DropReason::Loss) ++s.dropped_loss;
      else if (d.reason == DropReason::QueueFull) ++s.dropped_link_queue;
      else ++s.dropped_mtu;
      return;
    }
    // Seeded duplication: a second copy right after the first (a duplicated datagram on a
    // real path arrives close behind the original).
    const uint64_t n = duplicate_index++;
    const bool dup = o.duplicate_rate > 0 &&
                     rng_uniform_double({o.seed, uint32_t(n), uint32_t(n >> 32), uint32_t(dir), 7}) < o.duplicate_rate;
    for (int copy = 0; copy < (dup ? 2 : 1); ++copy) {
      if (queued_bytes + buf.size() > o.max_queue_bytes) {
        ++s.dropped_relay_queue;
        continue;
      }
      if (copy) ++s.duplicated;
      queued_bytes += buf.size();
      peak_queued_bytes = std::max(peak_queued_bytes, queued_bytes);
      queue.push({d.arrival_ms + 0.05 * copy, order++, dir, buf});
    }
  };

  while (!stop.load()) {
    const double now = ms_between(t0, Clock::now());
    // Forward what is due.
    while (!queue.empty() && queue.top().due_ms <= now) {
      const Scheduled& s = queue.top();
      UdpSocket& out = s.direction == 0 ? back : front;
      const Endpoint& to = s.direction == 0 ? o.server : client;
      DirectionStats& st = stats[s.direction];
      if (to.valid() && out.send_to(s.bytes, to) == SendResult::Sent) {
        ++st.forwarded;
        st.forwarded_bytes += s.bytes.size();
      } else {
        ++st.send_failed;
      }
      queued_bytes -= s.bytes.size();
      queue.pop();
    }
    if (bye_seen_ms >= 0 && queue.empty() && now - bye_seen_ms > 500.0) break;  // drained after a Bye
    if (any_traffic && ms_between(last_traffic, Clock::now()) > o.idle_timeout_s * 1000.0) {
      end_reason = fmt::format("no traffic for {:.1f} s", o.idle_timeout_s);
      break;
    }
    const double wait = queue.empty() ? 20.0 : std::clamp(queue.top().due_ms - now, 0.0, 20.0);
    pollfd fds[2] = {{front.fd(), POLLIN, 0}, {back.fd(), POLLIN, 0}};
    ::poll(fds, 2, int(std::ceil(wait)));
    for (int side = 0; side < 2; ++side) {
      UdpSocket& in = side == 0 ? front : back;
      for (int i = 0; i < 4096; ++i) {
        Endpoint from;
        const ReceiveResult r = in.receive(buf, from);
        if (r == ReceiveResult::Empty) break;
        if (r != ReceiveResult::Received) continue;
        // Two fixed peers: the server, and the first address that sent a Hello. Anything from
        // another address is dropped here, so no third party can send into the session through
        // the relay (the endpoints check the token and MAC of what the peers send).
        if (side == 0) {
          ControlMessage m;
          if (!client.valid() && reads_as(buf, ControlType::Hello, m)) {
            client = from;
            say(o.quiet, "relay", "client {}", client.to_string());
          } else if (!client.valid()) {
            ++foreign;
            ++dropped["client_side_before_hello"];
            continue;
          } else if (!(from == client)) {
            ++foreign;  // another sender: this relay carries one session
            ++dropped["client_side_foreign_address"];
            continue;
          }
        } else if (!(from == o.server)) {
          ++foreign;
          ++dropped["server_side_foreign_address"];
          continue;
        }
        accept(side, ms_between(t0, Clock::now()));
      }
    }
  }
  if (end_reason.empty()) end_reason = stop.load() ? "the relay was stopped" : "done";
  const nlohmann::json out = {{"role", "relay"},
                              {"end_reason", end_reason},
                              {"client_to_server", stats[0].to_json()},
                              {"server_to_client", stats[1].to_json()},
                              {"uplink", o.uplink.to_json()},
                              {"downlink", o.downlink.to_json()},
                              {"duplicate_rate", o.duplicate_rate},
                              {"seed", o.seed},
                              {"foreign_datagrams", foreign},
                              {"foreign_by_reason", counts_json(dropped)},
                              {"byes_ignored", byes_ignored},
                              {"peak_queued_bytes", peak_queued_bytes}};
  if (!o.out_file.empty()) {
    const std::filesystem::path p(o.out_file);
    if (p.has_parent_path()) std::filesystem::create_directories(p.parent_path());
    write_text(o.out_file, out.dump(2) + "\n");
  }
  say(o.quiet, "relay",
      "ended: {}; client->server {} in, {} out ({} lost, {} duplicated); server->client {} in, {} out ({} lost, {} "
      "duplicated, {} over the relay queue)",
      end_reason, stats[0].received, stats[0].forwarded, stats[0].dropped_loss, stats[0].duplicated, stats[1].received,
      stats[1].forwarded, stats[1].dropped_loss, stats[1].duplicated, stats[1].dropped_relay_queue);
  return 0;
}

}  // namespace dhr
