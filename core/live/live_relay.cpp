// dhrbench relay: the impairment relay between a live client and server (core/live/live.h).
#include "core/base/rng.h"
#include "core/live/live.h"
#include "core/live/live_detail.h"

namespace dhr {

using namespace live_detail;

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
    return {{"received", received},         {"received_bytes", received_bytes},
            {"forwarded", forwarded},       {"forwarded_bytes", forwarded_bytes},
            {"dropped_loss", dropped_loss}, {"dropped_link_queue", dropped_link_queue},
            {"dropped_mtu", dropped_mtu},   {"dropped_relay_queue", dropped_relay_queue},
            {"duplicated", duplicated},     {"send_failed", send_failed}};
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
  UdpSocket front(o.listen);                    // faces the client
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
      if (d.reason == DropReason::Loss)
        ++s.dropped_loss;
      else if (d.reason == DropReason::QueueFull)
        ++s.dropped_link_queue;
      else
        ++s.dropped_mtu;
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
