// dhrbench client: the live client (core/live/live.h).
#include "core/buffers/image_io.h"
#include "core/config/run_plan.h"
#include "core/live/live.h"
#include "core/live/live_detail.h"
#include "core/live/live_stats.h"
#include "core/metrics/metrics.h"
#include "core/net/assembler.h"
#include "core/pass/passes.h"
#include "core/pipeline/pass_receiver.h"
#include "core/pipeline/pipeline.h"
#include "core/raster/raster.h"
#include "core/results/results.h"
#include "core/trace/rt_scene.h"

#include <cmath>

namespace dhr {

using namespace live_detail;

// ---- client ------------------------------------------------------------------------------

namespace {

class LiveClient {
 public:
  LiveClient(const RunPlan& plan, const Registries& r, const LiveScene& s, const ClientOptions& o)
      : plan_(plan),
        c_(plan.config),
        registries_(r),
        scene_(s),
        o_(o),
        offer_(session_offer(c_, r, s.name, s.key)),
        socket_(any_endpoint_like(o.server)),
        mac_(load_key(o.key_file)),
        client_(plan, r) {
    if (plan.remote()) fail("live mode is hybrid rendering only (mode '{}' given)", c_.mode);
    if (o.frames < 1) fail("client: --frames must be at least 1 (got {})", o.frames);
    for (size_t i = 0; i < client_.passes().size(); ++i) pass_of_slot_[stream_slot(client_.passes()[i])] = int(i);
    AssemblerConfig ac;
    ac.max_payload_bytes = c_.max_payload_bytes;
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
  // A displayed frame is recorded as the simulator records it (core/results/results.h), t_ms and ages in
  // wall time since the session began.
  using Row = FrameRecord;

  double now_ms() const { return ms_between(t0_, Clock::now()); }
  double frame_time_s(int a) const { return c_.start_time_s + double(a) / c_.display_hz; }
  Camera camera(int a) const { return scene_.scene->camera.at(c_.camera_time_s(frame_time_s(a)), c_.width, c_.height); }

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
          fmt::print(stderr, "client: the server at {} refused the session: {}\n", o_.server.to_string(),
                     m.message.text);
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
    std::array<uint32_t, kPassSlots> codec_ids{};
    std::array<bool, kPassSlots> streams{};
    for (int slot = 0; slot < pass_slot_count(); ++slot) {
      streams[slot] = pass_of_slot_[slot] >= 0;
      codec_ids[slot] = codec_id(c_.pass(slot_name(slot)).codec.name);
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
      for (int slot = 0; slot < pass_slot_count(); ++slot)
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

  // Keeps the newest kMaxFrameReports reports for the next camera (a camera the socket could not
  // send loses them, as a lost datagram would).
  void report(const FrameReport& r) {
    if (reports_.size() == kMaxFrameReports) reports_.erase(reports_.begin());
    reports_.push_back(r);
  }

  void count_lost(const AssemblerEvents& events) {
    for (const LostFrame& l : events.lost) {
      const int slot = slot_of(l.meta.desc.kind);
      if (slot < 0) continue;
      ++frames_lost_[slot];
      socket_bytes_.erase({slot, l.meta.frame_id});
      if (c_.abr != "off") report({l.meta.frame_id, slot, true, 0.0});
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
    cu.holds = holds_;
    if (c_.abr != "off") {  // the reports for the server's bitrate controller
      cu.has_reports = true;
      cu.datagrams_received = assembler_.stats().datagrams;
      cu.datagrams_lost = assembler_.stats().packets_lost;
      cu.reports = std::move(reports_);
      reports_.clear();
    }
    cu.scene_time_s = frame_time_s(a);
    cu.camera = camera(a);
    gate_.camera_sent(cu.frame);
    gate_camera_sent_ = true;
    last_camera_ = cu.frame;
    if (send_control(camera_msg(session_, cu)) == SendResult::Sent) {
      keyframe_request_ = false;
      holds_ = filled<int32_t>(-1);
    }
    send_ms_[size_t(a)] = row.t_ms;

    auto g = std::make_shared<GBuffer>();
    rasterize({scene_.scene, cu.camera, cu.scene_time_s, has_prev_ ? prev_camera_ : cu.camera,
               has_prev_ ? prev_time_s_ : cu.scene_time_s},
              *g);
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
      if (c_.abr != "off") report({frame_id, slot, false, double(f.completed_ms)});
      if (frame_id < send_ms_.size() && send_ms_[frame_id] >= 0)
        round_trip_ms_[slot].push_back(double(f.completed_ms) - send_ms_[frame_id]);
      const PassReceiver::Outcome out = client_.receive(pass_of_slot_[slot], f);
      keyframe_request_ = keyframe_request_ || out.keyframe_request;
      if (out.keyframe_request) holds_[size_t(slot)] = out.holds;  // the server may predict from it
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

    // Predict and composite: the simulator's client stages (core/pipeline/pipeline.h).
    ClientFrame shown = client_.display(a, gbuf, [this](int frame) { return camera(frame); });
    without_data_ += shown.passes_without_data > 0 ? 1 : 0;
    for (size_t i = 0; i < client_.passes().size(); ++i)
      pass_without_data_[stream_slot(client_.passes()[i])] += shown.without_data[i] ? 1 : 0;
    for (size_t i = 0; i < client_.passes().size(); ++i) {
      PassFrameRecord p{client_.passes()[i].name, shown.source_frame[i], 0.0, shown.disoccluded[i]};
      if (p.source_frame >= 0) p.age_ms = double(a - p.source_frame) * 1000.0 / c_.display_hz;
      row.passes.push_back(std::move(p));
    }
    ImageRGB8& image = shown.image;
    row.client_wall_ms = ms_between(start, Clock::now());
    if (o_.score_every > 0 && a % o_.score_every == 0) {
      row.scored = true;
      kept_[a] = image;
    }
    if (o_.save_every > 0 && a % o_.save_every == 0) kept_[a] = std::move(image);
    rows_.push_back(row);
  }

  // Quality after the session (so that scoring never slows the real-time loop): each scored
  // frame against the local reference, defined as in the simulator (core/pipeline/pipeline.h,
  // LocalReference): the frame's own passes traced for its camera and denoised by a sequence of
  // their own that, with a temporal denoiser, runs over every frame index in order.
  void score() {
    if (o_.score_every <= 0 || rows_.empty()) return;
    say(o_.quiet, "client", "scoring {} frames against the local reference ...",
        std::count_if(rows_.begin(), rows_.end(), [](const Row& r) { return r.scored; }));
    RtScene rt(*scene_.scene);
    const TraceFn trace = direct_tracer(rt, plan_);
    LocalReference local(plan_, registries_);
    std::map<int, Row*> scored;
    for (Row& row : rows_)
      if (row.scored) scored[row.frame] = &row;
    if (scored.empty()) return;
    const int last = scored.rbegin()->first;
    std::optional<ImageRGB8> prev_ref;
    const ImageRGB8* prev_shown = nullptr;
    for (int a = local.needs_every_frame() ? 0 : scored.begin()->first; a <= last; ++a) {
      auto it = scored.find(a);
      if (it == scored.end() && !local.needs_every_frame()) continue;
      const Camera cam = camera(a), prev = a > 0 ? camera(a - 1) : cam;
      GBuffer g;
      const RasterFrame rf{scene_.scene, cam, frame_time_s(a), prev, a > 0 ? frame_time_s(a - 1) : frame_time_s(a)};
      rasterize(rf, g);
      const std::optional<ImageRGB8> ref = local.frame(uint32_t(a), rf, g, *trace(uint32_t(a), g), it != scored.end());
      if (!ref) continue;
      it->second->local = score_frame(*ref, kept_.at(a), prev_ref ? &*prev_ref : nullptr, prev_shown);
      prev_ref = *ref;  // the step metrics' previous scored frame
      prev_shown = &kept_.at(a);
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
    // frames.csv as `dhrbench run` writes it (core/results/results.h), one row per displayed frame.
    const std::vector<std::string> pass_names = all_pass_names();
    std::string csv = frames_csv_header({}, pass_names);
    std::vector<double> client_ms, age[kPassSlots];
    std::vector<std::vector<double>> scores(image_metrics().size());  // per metric, as averaged
    for (const Row& r : rows_) {
      csv += frames_csv_row({}, r, pass_names);
      client_ms.push_back(r.client_wall_ms);
      for (size_t i = 0; i < r.local.size(); ++i) {
        const ImageMetric& m = image_metrics()[i];
        if (std::isnan(r.local[i])) continue;  // no value on this frame (a step metric's first frame)
        scores[i].push_back(m.for_mean ? m.for_mean(r.local[i]) : r.local[i]);
      }
      for (int s = 0; s < pass_slot_count(); ++s) {
        const PassFrameRecord p = r.pass(slot_name(s));
        if (p.source_frame >= 0) age[s].push_back(p.age_ms);
      }
    }
    nlohmann::json quality = nlohmann::json::object();
    for (size_t i = 0; i < scores.size(); ++i)
      quality[image_metrics()[i].column(Against::Local)] = percentiles(scores[i]);
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
      passes_csv += fmt::format("{},{},{},{}\n", r.frame, slot_name(r.slot), r.socket_bytes, r.packets);
    write_text(o_.out_dir + "/received_passes.csv", passes_csv);

    const AssemblerStats& as = assembler_.stats();
    nlohmann::json fates = nlohmann::json::object();
    for (int f = 0; f < kPacketFateCount; ++f)
      if (as.packets[size_t(f)]) fates[packet_fate_name(PacketFate(f))] = as.packets[size_t(f)];
    nlohmann::json lost_by = nlohmann::json::object();
    for (int r = 0; r < kLossReasonCount; ++r)
      if (as.frames_lost[size_t(r)]) lost_by[loss_reason_name(LossReason(r))] = as.frames_lost[size_t(r)];
    nlohmann::json passes = nlohmann::json::object();
    for (int s = 0; s < pass_slot_count(); ++s) {
      if (pass_of_slot_[s] < 0) continue;
      passes[slot_name(s)] = {{"frames_completed", frames_completed_[s]},
                              {"frames_lost", frames_lost_[s]},
                              {"frames_without_data", pass_without_data_[s]},
                              {"decode_errors", decode_errors_[s]},
                              {"age_ms", percentiles(age[s])},
                              {"round_trip_ms", percentiles(round_trip_ms_[s])}};
    }
    const uint64_t received_packets = as.count(PacketFate::Accepted) + as.count(PacketFate::Completed);
    const uint64_t wire = on_the_wire(session_bytes_, session_datagrams_);
    const nlohmann::json notes = {
        {"socket.datagrams, socket.bytes",
         "everything read from the socket (UDP payload bytes), foreign datagrams included"},
        {"socket.session_datagrams, socket.session_bytes",
         "the session's datagrams: from the server's address, with the session's token (and MAC), inside the windows"},
        {"socket.session_pass_datagrams, socket.session_pass_bytes",
         "the pass packets among them; server.json's datagrams_sent and bytes_sent on a link that loses nothing"},
        {"socket.wire_bytes",
         "session_bytes plus 28 bytes of IPv4 and UDP headers per datagram (kIpUdpOverheadBytes): "
         "bandwidth on the wire as the simulator counts it (with a key, the 16-byte MAC is in session_bytes)"},
        {"socket.mbps, socket.bytes_per_s, socket.datagrams_per_s", "the session's, on the wire, over duration_s"},
        {"socket.bad_or_foreign", "datagrams dropped, by reason (docs/live-security.md); none counts as loss"}};
    const double seconds = std::max(1e-9, session_seconds_);
    nlohmann::json predictors = nlohmann::json::object();
    for (int s = 0; s < pass_slot_count(); ++s) {
      const BackendChoice& p = c_.pass(slot_name(s)).predictor;
      predictors[slot_name(s)] = {{"name", p.name}, {"params", p.params}};
    }
    const nlohmann::json out = {
        {"role", "client"},
        {"server", o_.server.to_string()},
        {"session", session_},
        {"end_reason", end_reason_},
        {"offer", offer_},
        {"predictor", predictors},
        {"frames",
         {{"requested", o_.frames},
          {"displayed", rows_.size()},
          {"skipped_late", frames_skipped_},
          {"without_data", without_data_},
          {"scored", scores.front().size()}}},
        {"quality", quality},
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
          {"recovered", as.packets_recovered},
          {"frames_recovered", as.frames_recovered},
          {"loss_rate", received_packets + as.packets_lost
                            ? double(as.packets_lost) / double(received_packets + as.packets_lost)
                            : 0.0},
          {"frames_lost_by_reason", lost_by}}},
        {"passes", passes},
        {"field_notes", notes}};
    write_text(o_.out_dir + "/live.json", out.dump(2) + "\n");
    say(o_.quiet, "client",
        "{} of {} frames displayed ({} skipped late), {} without data; {:.2f} Mb/s on the wire, {} datagrams, {} "
        "packets lost "
        "({:.2f} %); SSIM {}; results in {}",
        rows_.size(), o_.frames, frames_skipped_, without_data_, out["socket"]["mbps"].get<double>(),
        session_datagrams_, as.packets_lost, 100.0 * out["packets"]["loss_rate"].get<double>(),
        scores.front().empty() ? std::string("not scored")
                               : fmt::format("{:.4f} (mean of {})", out["quality"]["ssim_local"]["mean"].get<double>(),
                                             scores.front().size()),
        o_.out_dir);
  }

  struct Second {
    uint64_t datagrams = 0, bytes = 0, session_datagrams = 0, session_bytes = 0;
  };

  const RunPlan& plan_;
  const SimConfig& c_;  // plan_.config
  const Registries& registries_;
  LiveScene scene_;
  ClientOptions o_;
  nlohmann::json offer_;
  UdpSocket socket_;
  std::optional<DatagramMac> mac_;
  uint32_t session_ = 0;
  PassGate gate_;
  bool gate_camera_sent_ = false;
  uint32_t last_camera_ = 0;
  std::array<int64_t, kPassSlots> newest_completed_ =
      filled<int64_t>(-1);  // per pass: the newest frame whose packets all arrived
  Clock::time_point t0_, last_heard_;
  std::string end_reason_;
  double session_seconds_ = 0;
  std::vector<uint8_t> buffer_;
  Assembler assembler_;
  ClientPipeline client_;  // core/pipeline/pipeline.h: decode, predict, composite, the G-buffer history
  std::array<int, kPassSlots> pass_of_slot_ = filled<int>(-1);  // per stream: its pass in client_, -1: none
  bool keyframe_request_ = false;
  std::array<int32_t, kPassSlots> holds_ = filled<int32_t>(-1);  // per stream, with the next camera
  std::vector<FrameReport> reports_;                             // abr: with the next camera
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
  uint64_t frames_completed_[kPassSlots] = {}, frames_lost_[kPassSlots] = {}, decode_errors_[kPassSlots] = {};
  uint64_t pass_without_data_[kPassSlots] = {};  // displayed frames that showed the pass's local fallback
  std::vector<double> round_trip_ms_[kPassSlots];
};

}  // namespace

int run_live_client(const SimConfig& config, const Registries& registries, const LiveScene& scene,
                    const ClientOptions& options, const std::atomic<bool>& stop) {
  const RunPlan plan = plan_run(config, *scene.scene, registries);
  LiveClient client(plan, registries, scene, options);
  return client.run(stop);
}

}  // namespace dhr
