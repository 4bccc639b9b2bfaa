// dhrbench serve: the live server (core/live/live.h).
#include "core/config/run_plan.h"
#include "core/live/live.h"
#include "core/live/live_detail.h"
#include "core/live/live_stats.h"
#include "core/pipeline/pipeline.h"
#include "core/trace/rt_scene.h"

namespace dhr {

using namespace live_detail;

// ---- server ------------------------------------------------------------------------------

namespace {

class LiveServer {
 public:
  LiveServer(const RunPlan& plan, const Registries& r, const LiveScene& s, const ServeOptions& o)
      : plan_(plan),
        c_(plan.config),
        registries_(r),
        scene_(s),
        o_(o),
        offer_(session_offer(c_, r, s.name, s.key)),
        socket_(o.bind),
        mac_(load_key(o.key_file)) {
    if (plan.remote()) fail("live mode serves hybrid rendering only (mode '{}' given)", c_.mode);
    rt_ = std::make_unique<RtScene>(*s.scene);
    write_port_file(o.port_file, socket_.local());
    std::string passes;
    for (const PlannedPass& p : plan_.traced) passes += " " + p.name;
    say(o_.quiet, "serve", "listening on UDP {} (scene {}, {}x{} at {} Hz, passes:{}; {})", socket_.local().to_string(),
        s.name, c_.width, c_.height, c_.display_hz, passes,
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
    std::unique_ptr<ServerPipeline> pipeline;           // core/pipeline/pipeline.h: the simulator's server stages
    std::array<uint32_t, kPassSlots> first_sequence{};  // per stream: random, sent in the Welcome
    int64_t last_frame = -1;
    std::optional<CameraUpdate> pending;
    bool keyframe = false;
    // Per stream: the newest frame the client reported holding since the last frame served.
    std::array<int32_t, kPassSlots> holds = filled<int32_t>(-1);
    Clock::time_point started, last_heard;
    uint64_t cameras = 0, cameras_superseded = 0, cameras_stale = 0, frames_served = 0;
    uint64_t frames_after_held_report = 0;  // served with a frame the client reported holding
    uint64_t datagrams_sent = 0, bytes_sent = 0, send_dropped = 0;
    std::vector<double> compute_ms;     // the first kMaxSamples frames (for percentiles)
    std::ofstream log;                  // server_frames.csv, written as frames are sent
    std::optional<RateController> abr;  // abr on: the stream budget from the client's reports
    double abr_kbps_lowest = 0.0;
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
          !mac_->verify(d, Direction::ToServer,
                        mac_token(d.first(d.size() - kMacBytes), session_ ? session_->id : 0))) {
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
    for (int slot = 0; slot < pass_slot_count(); ++slot) s->first_sequence[slot] = os_random_u32();
    s->pipeline = std::make_unique<ServerPipeline>(plan_, registries_, direct_tracer(*rt_, plan_), stream_of(s->id));
    if (const auto rs = plan_.abr()) {  // the simulator's controller, on this server's clock
      s->abr.emplace(*rs);
      s->abr_kbps_lowest = s->abr->rate_kbps();
    }
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
    w.first_sequence = session_->first_sequence;
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
    if (int64_t(m.camera.frame) >
        std::max<int64_t>(s.last_frame, s.pending ? s.pending->frame : -1) + int64_t(kMaxCameraFramesAhead)) {
      ++bad_["camera_frame_ahead"];
      return;
    }
    s.last_heard = Clock::now();
    ++s.cameras;
    // The reports ride on every camera, a stale one too (the counts only grow; a frame reported
    // twice is dropped by the controller).
    if (s.abr && m.camera.has_reports) {
      for (const FrameReport& r : m.camera.reports) s.abr->on_report(r);
      s.abr->on_counts(m.camera.datagrams_received, m.camera.datagrams_lost);
    }
    if (int64_t(m.camera.frame) <= s.last_frame || (s.pending && m.camera.frame <= s.pending->frame)) {
      ++s.cameras_stale;  // reordered or duplicated: a newer camera was seen already
      return;
    }
    if (s.pending) ++s.cameras_superseded;  // the server was busy: only the newest is served
    s.keyframe = s.keyframe || m.camera.keyframe_request;
    for (size_t i = 0; i < s.holds.size(); ++i) s.holds[i] = std::max(s.holds[i], m.camera.holds[i]);
    s.pending = m.camera;
  }

  void serve(Session& s) {
    const CameraUpdate cam = *s.pending;
    s.pending.reset();
    const bool keyframe = s.keyframe;
    s.keyframe = false;
    // The client's held frames, by the pipeline's pass order (the codec checks that it still
    // keeps the frame; an unknown one gives a keyframe).
    std::vector<int> holds;
    for (const PlannedPass& p : s.pipeline->passes()) holds.push_back(s.holds[size_t(stream_slot(p))]);
    if (std::any_of(holds.begin(), holds.end(), [](int h) { return h >= 0; })) ++s.frames_after_held_report;
    s.holds = filled<int32_t>(-1);
    const auto t0 = Clock::now();
    if (s.abr) {
      s.pipeline->set_stream_kbps(s.abr->update(ms_between(s.started, t0)));
      s.abr_kbps_lowest = std::min(s.abr_kbps_lowest, s.abr->rate_kbps());
    }
    // The same stages, seed and frame index as the simulator: the same camera gives the same
    // passes and the same bytes.
    ServerFrame f = s.pipeline->run(cam.frame, cam.camera, cam.scene_time_s, keyframe, holds);
    if (s.log.is_open())
      for (const SentPass& p : f.passes)
        s.log << fmt::format("{:08x},{},{},{},{},{}\n", s.id, cam.frame, p.name, p.encoded_bytes, p.packets.size(),
                             wire_bytes_of_packets(p.packets, mac_bytes()));
    if (s.compute_ms.size() < kMaxSamples) s.compute_ms.push_back(ms_between(t0, Clock::now()));
    if (s.abr) {  // sent now, by stream slot (the client reports slots)
      const double sent_ms = ms_between(s.started, Clock::now());
      for (size_t i = 0; i < f.passes.size(); ++i)
        s.abr->on_sent(cam.frame, stream_slot(s.pipeline->passes()[i]),
                       wire_bytes_of_packets(f.passes[i].packets, mac_bytes()), sent_ms);
    }
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
      summaries_.push_back(
          {{"session", s.id},
           {"client", s.peer.to_string()},
           {"end_reason", reason},
           {"duration_s", seconds},
           {"cameras_received", s.cameras},
           {"cameras_superseded", s.cameras_superseded},
           {"cameras_stale", s.cameras_stale},
           {"frames_served", s.frames_served},
           {"frames_after_held_report", s.frames_after_held_report},
           {"abr", s.abr ? nlohmann::json{{"updates", s.abr->updates()},
                                          {"reports_dropped", s.abr->reports_dropped()},
                                          {"kbps_lowest", s.abr_kbps_lowest},
                                          {"kbps_last", s.abr->rate_kbps()}}
                         : nlohmann::json()},
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
          {"wire_bytes_sent",
           "bytes_sent plus 28 bytes of IPv4 and UDP headers per datagram (kIpUdpOverheadBytes), as the simulator "
           "counts"},
          {"mbps_sent", "wire_bytes_sent in Mb/s over duration_s"},
          {"bad_or_foreign_datagrams",
           "datagrams dropped since the server started, by reason (docs/live-security.md)"}};
      write_text(o_.out_dir + "/server.json", nlohmann::json{{"role", "server"},
                                                             {"authentication", authentication_name(mac_)},
                                                             {"offer", offer_},
                                                             {"field_notes", notes},
                                                             {"sessions", summaries_}}
                                                      .dump(2) +
                                                  "\n");
      s.log.close();
    }
    session_.reset();
  }

  const RunPlan& plan_;
  const SimConfig& c_;  // plan_.config
  const Registries& registries_;
  LiveScene scene_;
  ServeOptions o_;
  nlohmann::json offer_;
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
  const RunPlan plan = plan_run(config, *scene.scene, registries);
  LiveServer server(plan, registries, scene, options);
  return server.run(stop);
}

}  // namespace dhr
