// Live mode (core/live.h): the control protocol, the session offer, and server, relay and client
// as three real processes over loopback UDP -- through loss, jitter, reordering and
// duplication -- checked against the simulator's accounting of the same frames.
#include "core/experiment.h"
#include "backends/register_all.h"
#include "core/live.h"
#include "core/live_protocol.h"
#include "core/packet.h"
#include "core/reference.h"
#include "core/scene_load.h"
#include "core/udp.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
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
  return c;
}

TEST(LiveProtocol, EveryMessageRoundTripsBitForBit) {
  for (ControlType t : {ControlType::Hello, ControlType::Welcome, ControlType::Refuse, ControlType::Camera, ControlType::Bye}) {
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
  // A camera that would poison the server: non-finite, not unit, a zero-sized image.
  for (int bad = 0; bad < 4; ++bad) {
    ControlMessage c = m;
    if (bad == 0) c.camera.camera.position.x = NAN;
    if (bad == 1) c.camera.camera.forward = {0, 0, -2};
    if (bad == 2) c.camera.camera.width = 0;
    if (bad == 3) c.camera.scene_time_s = INFINITY;
    EXPECT_EQ(parse_control(encode_control(c), out), ControlParse::BadBody) << bad;
  }
}

TEST(LiveOffer, MismatchesNameEveryField) {
  SimConfig a, b;
  b.width = 640;
  b.ao_codec.name = "zstd";
  const json oa = session_offer(a, registries(), "room", "abc"), ob = session_offer(b, registries(), "scenes/room.json", "abc");
  EXPECT_TRUE(offer_mismatches(oa, session_offer(a, registries(), "other-name", "abc")).empty()) << "the name alone may differ";
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
  c.ao_codec.params = {{"mode", "fast"}};
  EXPECT_TRUE(offer_mismatches(oa, session_offer(c, registries(), "room", "abc")).empty());
  const auto scene = offer_mismatches(oa, session_offer(a, registries(), "room", "def"));
  ASSERT_FALSE(scene.empty());
  EXPECT_NE(scene[0].find("different content"), std::string::npos);
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

TEST(LiveMode, ThroughALossyRelayTheSocketBytesMatchTheSimulator) {
  const fs::path dir = fresh_dir("relay");
  Process server = Process::start(with({"serve"}, with(kSettings, {"--bind", "127.0.0.1:0", "--port-file",
                                                                    (dir / "server.port").string(), "--out",
                                                                    (dir / "server").string(), "--idle-timeout", "20"})),
                                  (dir / "server.log").string());
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
  Process relay = Process::start({"relay", "--listen", "127.0.0.1:0", "--server", "127.0.0.1:" + std::to_string(server_port),
                                  "--port-file", (dir / "relay.port").string(), "--out", (dir / "relay.json").string(),
                                  "--downlink", downlink, "--uplink", R"({"latency_ms": 10})", "--duplicate-rate", "0.03",
                                  "--seed", "5", "--idle-timeout", "20"},
                                 (dir / "relay.log").string());
  const int relay_port = wait_port(dir / "relay.port", relay);
  ASSERT_GT(relay_port, 0);

  constexpr int kFrames = 90;  // 1.5 s at 60 Hz
  Process client = Process::start(with({"client"}, with(kSettings, {"--server", "127.0.0.1:" + std::to_string(relay_port),
                                                                     "--frames", std::to_string(kFrames), "--out",
                                                                     (dir / "client").string(), "--score-every", "15",
                                                                     "--save-every", "45", "--connect-timeout", "30"})),
                                  (dir / "client.log").string());
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
  bool arrived = false;
  int gaps = 0;
  for (const auto& row : frames) {
    const bool have = std::stoi(row.at("vis_source_frame")) >= 0 && std::stoi(row.at("ao_source_frame")) >= 0;
    arrived = arrived || have;
    gaps += arrived && !have;
  }
  EXPECT_TRUE(arrived);
  EXPECT_EQ(gaps, 0);
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
  const RunResult rr = run_simulation(sim, scene, fmt::format("{:016x}", scene_content_hash(scene)), cache, registries());
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

TEST(LiveMode, AMismatchedOfferIsRefusedWithTheReason) {
  const fs::path dir = fresh_dir("refuse");
  Process server = Process::start(with({"serve"}, with(kSettings, {"--bind", "127.0.0.1:0", "--port-file",
                                                                    (dir / "server.port").string()})),
                                  (dir / "server.log").string());
  const int port = wait_port(dir / "server.port", server);
  ASSERT_GT(port, 0);
  Process client = Process::start({"client", "--scene", "room", "--set", "width=128", "--set", "height=64", "--set",
                                   "ao_codec.name=zstd", "--server", "127.0.0.1:" + std::to_string(port), "--frames", "5",
                                   "--out", (dir / "client").string(), "--connect-timeout", "30"},
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
  Process server = Process::start(with({"serve"}, with(kSettings, {"--bind", "127.0.0.1:0", "--port-file",
                                                                    (dir / "server.port").string()})),
                                  (dir / "server.log").string());
  const int port = wait_port(dir / "server.port", server);
  ASSERT_GT(port, 0);
  Process client = Process::start(with({"client"}, with(kSettings, {"--server", "127.0.0.1:" + std::to_string(port),
                                                                     "--frames", "100000", "--out", (dir / "client").string(),
                                                                     "--idle-timeout", "1", "--score-every", "0",
                                                                     "--connect-timeout", "30"})),
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

}  // namespace
}  // namespace dhr
