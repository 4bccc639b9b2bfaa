// dhrbench serve / client / relay: live mode over real UDP (core/live/live.h). Server and client
// take the same settings (a JSON object shaped like an experiment's "run", from --config,
// plus --set overrides) and refuse to start a session when they disagree.
#include "backends/register_all.h"
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/experiment/experiment.h"
#include "core/live/live.h"
#include "core/pass/reference.h"
#include "core/scene/scene_load.h"
#include "experiments/cli/commands.h"

#include <fmt/format.h>

#include <atomic>
#include <csignal>
#include <fstream>
#include <memory>

namespace dhr::cli {

namespace {

std::atomic<bool> g_stop{false};

void on_signal(int) { g_stop.store(true); }

void install_signal_handlers() {
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = 0;  // no SA_RESTART: a waiting poll() returns, and the loop sees the flag
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  std::signal(SIGPIPE, SIG_IGN);
}

struct Common {
  std::string scene, config;
  std::vector<std::string> sets, scene_path;
  bool quiet = false;
};

void add_common(CLI::App* cmd, Common& c) {
  cmd->add_option("--scene", c.scene,
                  "Scene: a built-in name (room, temple, street, living-room, ...), a .json file or a model")
      ->required();
  cmd->add_option(
      "--config", c.config,
      "JSON file with the run settings, shaped like an experiment's \"run\" object: width, height, "
      "display_hz, seed, trace {...}, passes {visibility, ao: {codec, denoiser, predictor}} each {name, params}, "
      "max_payload_bytes, ... (see core/experiment/experiment.h)");
  cmd->add_option(
      "--set", c.sets,
      "Override one setting: dotted.key=value (repeatable), e.g. --set width=640 --set passes.ao.codec.name=zstd "
      "(every key: dhrbench settings; the version-1 keys such as ao_codec are accepted too)");
  cmd->add_option("--scene-path", c.scene_path, "Folder to look for scene assets in (repeatable)");
  cmd->add_flag("--quiet", c.quiet, "Only errors on stderr");
}

struct Loaded {
  Scene scene;
  SimConfig config;
  LiveScene live;
};

std::unique_ptr<Loaded> load(const Common& c, const char* who) {
  nlohmann::json run = nlohmann::json::object();
  if (!c.config.empty()) {
    run = read_json_file(c.config);  // errors name the file
    if (!run.is_object()) fail("{}: --config '{}' must hold a JSON object (the run settings)", who, c.config);
  }
  nlohmann::json wrapper{{"run", run}};
  for (const std::string& s : c.sets) apply_override(wrapper, s, "run");  // errors name what was typed
  std::vector<std::string> problems;
  auto out = std::make_unique<Loaded>();
  out->config = sim_config_from_json(wrapper["run"], c.config.empty() ? "settings" : c.config, problems);
  if (!problems.empty()) {
    std::string msg = fmt::format("{}: {} problem(s) in the settings:", who, problems.size());
    for (const auto& p : problems) msg += "\n  " + p;
    throw Error(msg);
  }
  out->scene = load_scene_or_model(c.scene, SceneSearchPath::standard(c.scene_path));
  out->live = {&out->scene, c.scene, fmt::format("{:016x}", scene_content_hash(out->scene))};
  for (const std::string& f : live_ignored_fields(out->config))
    fmt::print(stderr, "{}: note: live mode ignores {}\n", who, f);
  return out;
}

}  // namespace

Runner add_serve_command(CLI::App& app) {
  struct Options {
    Common common;
    std::string bind = "0.0.0.0:47000", port_file, out;
    double idle_timeout_s = 5.0;
    int sessions = 1;
    std::string key_file;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "serve",
      "Live mode, server side: listen on UDP for a dhrbench client, agree on the session (scene, resolution,\n"
      "passes, codecs), then for the newest camera the client sent: rasterize, trace, denoise, encode and send\n"
      "the passes as packets. Ends a session on the client's bye or after --idle-timeout s of silence.\n"
      "A session accepts datagrams only from its client's address with its random token (and, with --key-file,\n"
      "a valid HMAC); everything else is dropped and counted (docs/live-security.md).\n"
      "Examples:\n"
      "  dhrbench serve --scene room\n"
      "  dhrbench serve --scene living-room --set width=640 --set height=360 --bind 0.0.0.0:47000 --out out/serve\n"
      "  (then on the client machine: dhrbench client --scene living-room --set width=640 --set height=360 \\\n"
      "     --server SERVER_IP:47000)");
  add_common(cmd, o->common);
  cmd->add_option("--bind", o->bind, "Address and UDP port to listen on (port 0: any free port)")
      ->capture_default_str();
  cmd->add_option("--port-file", o->port_file, "Write the bound port to this file (for scripts using port 0)");
  cmd->add_option("--out", o->out, "Folder for server.json and server_frames.csv (what was sent per frame)");
  cmd->add_option("--idle-timeout", o->idle_timeout_s, "Seconds of client silence that end a session")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  cmd->add_option("--sessions", o->sessions, "Sessions to serve before exiting (0: until Ctrl-C)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--key-file", o->key_file,
                  "Authenticate every datagram with HMAC-SHA256 keyed by this file's bytes (16..4096; the client "
                  "needs the same file; make one with: head -c 32 /dev/urandom > live.key). See docs/live-security.md");
  return [o]() {
    auto loaded = load(o->common, "serve");
    ServeOptions so;
    so.bind = resolve_endpoint(o->bind, true);
    so.port_file = o->port_file;
    so.out_dir = o->out;
    so.idle_timeout_s = o->idle_timeout_s;
    so.sessions = o->sessions;
    so.key_file = o->key_file;
    so.quiet = o->common.quiet;
    install_signal_handlers();
    return run_live_server(loaded->config, registries(), loaded->live, so, g_stop);
  };
}

Runner add_client_command(CLI::App& app) {
  struct Options {
    Common common;
    std::string server, out = "out/live", key_file, port_file;
    int frames = 300, score_every = 10, save_every = 30;
    double connect_timeout_s = 5.0, idle_timeout_s = 5.0;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "client",
      "Live mode, client side: connect to 'dhrbench serve', then at the display rate in real time send the\n"
      "camera, rasterize, reassemble and decode the passes that arrive, predict them to the displayed frame and\n"
      "composite. Writes live.json (socket rates, loss, buffer age, round trip, quality), frames.csv, socket.csv,\n"
      "received_passes.csv and PNG frames. Quality (SSIM against the local reference) is computed after the\n"
      "session so that it never slows the real-time loop.\n"
      "Examples:\n"
      "  dhrbench client --scene room --server 127.0.0.1:47000 --frames 600\n"
      "  dhrbench client --scene room --server 127.0.0.1:47001 --out out/live-lossy   (through dhrbench relay)");
  add_common(cmd, o->common);
  cmd->add_option("--server", o->server, "The server's (or relay's) address, host:port")->required();
  cmd->add_option("--frames", o->frames, "Frames to display (the session lasts frames / display_hz s)")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  cmd->add_option("--out", o->out, "Output folder")->capture_default_str();
  cmd->add_option("--score-every", o->score_every, "Score every n-th frame against the local reference (0: never)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--save-every", o->save_every, "Write every n-th displayed frame as PNG (0: none)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--connect-timeout", o->connect_timeout_s, "Seconds to wait for the server's answer")
      ->check(CLI::Range(0.1, 600.0))
      ->capture_default_str();
  cmd->add_option("--idle-timeout", o->idle_timeout_s, "Seconds of server silence that end the session")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  cmd->add_option("--key-file", o->key_file,
                  "Authenticate every datagram with HMAC-SHA256 keyed by this file's bytes (the server's --key-file). "
                  "See docs/live-security.md");
  cmd->add_option("--port-file", o->port_file,
                  "Write the client's local UDP port to this file once the session started");
  return [o]() {
    auto loaded = load(o->common, "client");
    ClientOptions co;
    co.server = resolve_endpoint(o->server);
    co.frames = o->frames;
    co.out_dir = o->out;
    co.score_every = o->score_every;
    co.save_every = o->save_every;
    co.connect_timeout_s = o->connect_timeout_s;
    co.idle_timeout_s = o->idle_timeout_s;
    co.key_file = o->key_file;
    co.port_file = o->port_file;
    co.quiet = o->common.quiet;
    install_signal_handlers();
    return run_live_client(loaded->config, registries(), loaded->live, co, g_stop);
  };
}

Runner add_relay_command(CLI::App& app) {
  struct Options {
    std::string listen = "0.0.0.0:47001", server, uplink, downlink, port_file, out;
    double duplicate_rate = 0.0, idle_timeout_s = 10.0;
    uint64_t seed = 1;
    size_t max_queue_mb = 64;
    bool quiet = false;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "relay",
      "An impairment relay between client and server (this kernel has no netem): every datagram goes through a\n"
      "seeded link per direction (the simulator's core/net/network.h: loss, latency with jitter or a trace,\n"
      "reordering when order is not preserved, a bandwidth cap with a bounded queue) and may be duplicated.\n"
      "Links are JSON objects with the simulator's keys (latency: constant|normal|trace, latency_ms, jitter_ms,\n"
      "loss: none|independent|gilbert_elliott, loss_rate, bandwidth_mbps, queue_limit_bytes, preserve_order, ...),\n"
      "given inline or as a file name.\n"
      "It carries one session between two fixed peers, the server and the first address that sends it a Hello:\n"
      "datagrams from any other address are dropped and counted (docs/live-security.md).\n"
      "Exits after the session's bye has passed and the queue drained, or after --idle-timeout s without traffic.\n"
      "Example:\n"
      "  dhrbench relay --listen 0.0.0.0:47001 --server 127.0.0.1:47000 \\\n"
      "    --downlink '{\"latency_ms\": 20, \"loss\": \"independent\", \"loss_rate\": 0.02}' \\\n"
      "    --uplink '{\"latency_ms\": 20}' --duplicate-rate 0.01");
  cmd->add_option("--listen", o->listen, "Address and UDP port the client sends to")->capture_default_str();
  cmd->add_option("--server", o->server, "The server's address, host:port")->required();
  cmd->add_option("--uplink", o->uplink, "Client-to-server link: JSON text or a JSON file");
  cmd->add_option("--downlink", o->downlink, "Server-to-client link: JSON text or a JSON file");
  cmd->add_option("--duplicate-rate", o->duplicate_rate, "Probability that a delivered datagram arrives twice")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "Seed of the impairments")->capture_default_str();
  cmd->add_option("--max-queue-mb", o->max_queue_mb, "Datagrams waiting for their arrival time, at most (MB)")
      ->check(CLI::Range(1, 4096))
      ->capture_default_str();
  cmd->add_option("--idle-timeout", o->idle_timeout_s,
                  "Seconds without traffic (after the first datagram) that end the relay")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  cmd->add_option("--port-file", o->port_file, "Write the bound port to this file (for scripts using port 0)");
  cmd->add_option("--out", o->out, "Write the relay's counts per direction to this JSON file");
  cmd->add_flag("--quiet", o->quiet, "Only errors on stderr");
  return [o]() {
    auto link = [](const std::string& text, const char* name) {
      if (text.empty()) return LinkConfig{};
      const bool inline_json = text.find('{') != std::string::npos;
      if (!inline_json && !std::ifstream(text))
        fail("relay: --{}: cannot open '{}' (give a JSON object or a file holding one)", name, text);
      const nlohmann::json j = inline_json ? parse_json(text, fmt::format("relay: --{}", name)) : read_json_file(text);
      return LinkConfig::from_json(j, std::string("--") + name);
    };
    RelayOptions ro;
    ro.listen = resolve_endpoint(o->listen, true);
    ro.server = resolve_endpoint(o->server);
    ro.uplink = link(o->uplink, "uplink");
    ro.downlink = link(o->downlink, "downlink");
    ro.duplicate_rate = o->duplicate_rate;
    ro.seed = o->seed;
    ro.max_queue_bytes = o->max_queue_mb << 20;
    ro.idle_timeout_s = o->idle_timeout_s;
    ro.port_file = o->port_file;
    ro.out_file = o->out;
    ro.quiet = o->quiet;
    install_signal_handlers();
    return run_live_relay(ro, g_stop);
  };
}

}  // namespace dhr::cli
