// The table of run settings (core/config/run_config.h) and everything driven by it: the JSON reader and
// writer, the range checks and the cache keys.
#include "core/config/run_config.h"

#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/buffers/upsample.h"
#include "core/net/fec.h"
#include "core/net/packet.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <utility>

namespace dhr {

namespace {

std::string join(const std::vector<std::string>& items, const char* separator = ", ") {
  std::string s;
  for (const auto& item : items) s += (s.empty() ? "" : separator) + item;
  return s;
}

// A setting whose value is a plain field reached by `ref` (a generic lambda, so that one
// accessor serves the const getter and the setter).
template <class Ref>
RunSetting field(const char* key, SettingType type, const char* doc, Ref ref) {
  RunSetting s;
  s.key = key;
  s.type = type;
  s.doc = doc;
  s.get = [ref](const SimConfig& c) { return nlohmann::json(ref(c)); };
  s.set = [ref](SimConfig& c, const nlohmann::json& v) {
    auto& out = ref(c);
    out = v.get<std::decay_t<decltype(out)>>();
  };
  return s;
}

template <class Ref>
RunSetting ranged(const char* key, SettingType type, double lo, double hi, const char* doc, Ref ref) {
  RunSetting s = field(key, type, doc, ref);
  s.lo = lo;
  s.hi = hi;
  return s;
}

template <class Ref>
RunSetting backend(const char* key, const char* kind, const char* v1_key, const char* doc, Ref ref) {
  RunSetting s;
  s.key = key;
  s.type = SettingType::Backend;
  s.kind = kind;
  s.v1_key = v1_key;
  s.doc = doc;
  s.get = [ref](const SimConfig& c) {
    const BackendChoice& b = ref(c);
    return nlohmann::json{{"name", b.name}, {"params", b.params}};
  };
  s.set = [ref](SimConfig& c, const nlohmann::json& v) {
    BackendChoice& b = ref(c);
    if (v.contains("name")) b.name = v.at("name").get<std::string>();  // absent: the default's
    b.params = v.contains("params") ? v.at("params") : nlohmann::json::object();
  };
  return s;
}

template <class Ref>
RunSetting link(const char* key, const char* doc, Ref ref) {
  RunSetting s;
  s.key = key;
  s.type = SettingType::Link;
  s.doc = doc;
  s.get = [ref](const SimConfig& c) { return ref(c).to_json(); };
  s.set = [ref, key](SimConfig& c, const nlohmann::json& v) { ref(c) = LinkConfig::from_json(v, key); };
  return s;
}

RunSetting with(RunSetting s, unsigned flags, std::string live_ignored = {}) {
  s.flags = flags;
  s.live_ignored = std::move(live_ignored);
  return s;
}

// A kInTraceKey setting that changes one traced pass only.
RunSetting of_pass(RunSetting s, std::string pass) {
  s.traced_pass = std::move(pass);
  return s;
}

std::vector<RunSetting> make_settings() {
  constexpr unsigned kTraced = kInLiveOffer | kInTraceKey;
  std::vector<RunSetting> v;
  RunSetting mode = field(
      "mode", SettingType::Choice, "hybrid: the server streams passes; remote: one colour frame (the baseline)",
      [](auto& c) -> auto& { return c.mode; });
  mode.choices = {"hybrid", "remote"};
  v.push_back(mode);
  v.push_back(with(
      ranged(
          "width", SettingType::Integer, 8, 7680, "image width in pixels", [](auto& c) -> auto& { return c.width; }),
      kTraced | kInTruthKey));
  v.push_back(with(
      ranged(
          "height", SettingType::Integer, 8, 4320, "image height in pixels", [](auto& c) -> auto& { return c.height; }),
      kTraced | kInTruthKey));
  v.push_back(ranged(
      "frames", SettingType::Integer, 1, 100000, "displayed and scored frames",
      [](auto& c) -> auto& { return c.frames; }));
  v.push_back(
      with(ranged(
               "warmup_frames", SettingType::Integer, 0, 100000, "frames run before them, not scored, not counted",
               [](auto& c) -> auto& { return c.warmup_frames; }),
           0, "the client runs --frames frames in real time"));
  v.push_back(field(
      "score_startup", SettingType::Boolean,
      "score frames shown before the first server frame can arrive (a startup study); false: an experiment "
      "refuses a warmup_frames that ends before then",
      [](auto& c) -> auto& { return c.score_startup; }));
  v.push_back(with(ranged(
                       "display_hz", SettingType::Number, 1, 1000, "the client's display rate (virtual clock)",
                       [](auto& c) -> auto& { return c.display_hz; }),
                   kTraced | kInTruthKey));
  v.push_back(with(ranged(
                       "start_time_s", SettingType::Number, 0, 1e6, "scene time of the first (warm-up) frame",
                       [](auto& c) -> auto& { return c.start_time_s; }),
                   kTraced | kInTruthKey));
  v.push_back(with(ranged(
                       "camera_speed", SettingType::Number, 0.1, 10,
                       "the camera path's speed against the scene clock (2: the same path twice as fast; moving "
                       "objects keep the scene's clock)",
                       [](auto& c) -> auto& { return c.camera_speed; }),
                   kTraced | kInTruthKey));
  v.push_back(with(ranged(
                       "seed", SettingType::Integer, 0, 9.007e15, "seed of every random number (tracing, network)",
                       [](auto& c) -> auto& { return c.seed; }),
                   kTraced | kInTruthKey));
  v.push_back(
      of_pass(with(ranged(
                       "trace.ao_rays", SettingType::Integer, 0, 255, "AO rays per pixel; 0: the scene's ao.rays",
                       [](auto& c) -> auto& { return c.trace.ao_rays; }),
                   kTraced),
              "ao"));
  v.push_back(of_pass(
      with(ranged(
               "trace.ao_radius_m", SettingType::Number, 0, 1e6, "AO ray length in metres; 0: the scene's ao.radius_m",
               [](auto& c) -> auto& { return c.trace.ao_radius_m; }),
           kTraced),
      "ao"));
  v.push_back(of_pass(with(field(
                               "trace.soft_shadows", SettingType::Boolean,
                               "area lights give soft shadows (else hard, one ray per light)",
                               [](auto& c) -> auto& { return c.trace.soft_shadows; }),
                           kTraced),
                      "visibility"));
  v.push_back(of_pass(with(ranged(
                               "trace.samples_per_light", SettingType::Integer, 1, 1024,
                               "shadow rays per area light and pixel (1: a bitmask, more: 8-bit soft visibility)",
                               [](auto& c) -> auto& { return c.trace.samples_per_light; }),
                           kTraced),
                      "visibility"));
  v.push_back(of_pass(with(field(
                               "trace.visibility_fraction", SettingType::Boolean,
                               "send the visibility pass as 8 bits per light even with one ray per light (for a "
                               "denoiser and lossy video codecs); false: a bitmask, 1 bit per light (the paper's)",
                               [](auto& c) -> auto& { return c.trace.visibility_fraction; }),
                           kTraced),
                      "visibility"));
  v.push_back(of_pass(
      with(field(
               "trace.visibility_pass", SettingType::Boolean, "trace the visibility pass (when the scene has lights)",
               [](auto& c) -> auto& { return c.trace.visibility_pass; }),
           kTraced),
      "visibility"));
  v.push_back(
      of_pass(with(field(
                       "trace.ao_pass", SettingType::Boolean, "trace the AO pass (when the scene has an ao block)",
                       [](auto& c) -> auto& { return c.trace.ao_pass; }),
                   kTraced),
              "ao"));
  v.push_back(
      of_pass(with(ranged(
                       "trace.ao_scale", SettingType::Integer, 1, kMaxPassScale,
                       "the AO pass traced, denoised and sent at 1/ao_scale of the width and height, upsampled by "
                       "the client (ao_upsample)",
                       [](auto& c) -> auto& { return c.trace.ao_scale; }),
                   kTraced),
              "ao"));
  RunSetting upsample = field(
      "ao_upsample", SettingType::Choice,
      "trace.ao_scale > 1: the client's upsampling of the AO pass: joint_bilateral (guided by its "
      "G-buffer's depth and normals), bilinear or nearest",
      [](auto& c) -> auto& { return c.ao_upsample; });
  upsample.choices = {"joint_bilateral", "bilinear", "nearest"};
  v.push_back(upsample);
  // passes.<name>.{codec,denoiser,predictor} for every pass of the table, then colour's codec
  // and predictor. The passes of version-1 files keep their version-1 keys.
  const auto pass_backend = [](const std::string& pass, const char* kind, BackendChoice PassChoice::*member,
                               std::string v1_key, std::string doc) {
    RunSetting s = backend(("passes." + pass + "." + kind).c_str(), kind, v1_key.c_str(), doc.c_str(),
                           [ pass, member ](auto& c) -> auto& { return c.pass(pass).*member; });
    return s;
  };
  for (const PassType& t : pass_types()) {
    const std::string n = t.name;
    const bool v1 = n == "visibility" || n == "ao";  // the passes version-1 files know
    v.push_back(with(pass_backend(n, "codec", &PassChoice::codec, v1 ? n + "_codec" : "", "the " + n + " pass's codec"),
                     kInLiveOffer));
    v.push_back(with(pass_backend(n, "denoiser", &PassChoice::denoiser, v1 ? n + "_denoiser" : "",
                                  "the server's denoiser of the " + n +
                                      " pass's 8-bit planes (bitmasks are never denoised; remote mode too)"),
                     kInLiveOffer));
    v.push_back(pass_backend(n, "predictor", &PassChoice::predictor, v1 ? "predictor" : "",
                             "the client's predictor of the " + n + " pass"));
  }
  v.push_back(pass_backend(kColourPassName, "codec", &PassChoice::codec, "colour_codec",
                           "remote mode: the colour frame's codec"));
  v.push_back(pass_backend(kColourPassName, "predictor", &PassChoice::predictor, "colour_predictor",
                           "remote mode: the client's predictor of the colour frame"));
  v.push_back(pass_backend(kDepthPassName, "codec", &PassChoice::codec, "",
                           "remote mode with a colour predictor that reads depth (depth_warp): the depth pass's codec "
                           "(lossless)"));
  // passes.<name>.fec_parity and fec_min_parity for every pass that is sent.
  for (const std::string& n : all_pass_names()) {
    v.push_back(with(
        ranged(("passes." + n + ".fec_parity").c_str(), SettingType::Number, 0, 1,
               ("Reed-Solomon parity packets of the " + n +
                " pass per FEC block, as a fraction of its data packets (core/net/fec.h; parity counts as wire bytes)")
                   .c_str(),
               [n](auto& c) -> auto& { return c.pass(n).fec_parity; }),
        kInLiveOffer));
    v.push_back(with(
        ranged(("passes." + n + ".fec_min_parity").c_str(), SettingType::Integer, 0, kFecMaxShards - 1,
               ("the least parity packets per FEC block of the " + n + " pass (with fec_parity: the larger)").c_str(),
               [n](auto& c) -> auto& { return c.pass(n).fec_min_parity; }),
        kInLiveOffer));
  }
  RunSetting timing;
  timing.key = "server_timing";
  timing.type = SettingType::Choice;
  timing.choices = {"fixed", "measured"};
  timing.doc =
      "the server's compute time per frame: fixed (server_fixed_ms, virtual; results repeat on any machine) or "
      "measured (the wall time of its stages on this machine: results then depend on the machine and its load)";
  timing.live_ignored = "the server takes the time it takes";
  timing.get = [](const SimConfig& c) {
    return nlohmann::json(c.server_timing == SimConfig::ServerTiming::Fixed ? "fixed" : "measured");
  };
  timing.set = [](SimConfig& c, const nlohmann::json& j) {
    c.server_timing = j == "fixed" ? SimConfig::ServerTiming::Fixed : SimConfig::ServerTiming::Measured;
  };
  v.push_back(timing);
  v.push_back(
      with(ranged(
               "server_fixed_ms", SettingType::Number, 0, 1e5, "server_timing fixed: its compute time per frame (ms)",
               [](auto& c) -> auto& { return c.server_fixed_ms; }),
           0, "the server takes the time it takes"));
  RunSetting pose = field(
      "server_pose_prediction", SettingType::Choice,
      "remote: server-side pose prediction, as CloudXR does: the server renders for the newest "
      "camera it received extrapolated ahead at its velocity, and the client warps from that "
      "camera. off: the camera as received; delay: ahead by the expected delay from camera to "
      "display (uplink + server_fixed_ms + downlink latency, their means, rounded up to whole "
      "display intervals); lead: ahead by server_pose_lead_ms",
      [](auto& c) -> auto& { return c.server_pose_prediction; });
  pose.choices = {"off", "delay", "lead"};
  v.push_back(with(pose, 0, "live mode is hybrid only"));
  v.push_back(with(ranged(
                       "server_pose_lead_ms", SettingType::Number, 0, 1000,
                       "server_pose_prediction lead: how far ahead the server renders (ms)",
                       [](auto& c) -> auto& { return c.server_pose_lead_ms; }),
                   0, "live mode is hybrid only"));
  v.push_back(
      with(link(
               "uplink", "the client-to-server link (core/net/network.h)", [](auto& c) -> auto& { return c.uplink; }),
           0, "the network is the real one, or dhrbench relay's"));
  v.push_back(with(
      link(
          "downlink", "the server-to-client link (core/net/network.h)", [](auto& c) -> auto& { return c.downlink; }),
      0, "the network is the real one, or dhrbench relay's"));
  v.push_back(with(ranged(
                       "max_payload_bytes", SettingType::Integer, 1, double(kMaxPayloadLimitBytes),
                       "payload bytes per datagram (plus the header and IP/UDP: at most the downlink MTU)",
                       [](auto& c) -> auto& { return c.max_payload_bytes; }),
                   kInLiveOffer));
  v.push_back(with(ranged(
                       "stream_kbps", SettingType::Number, 0, 1e7,
                       "a bit budget for the whole stream on the wire in kbit/s (0: none): the passes whose codec "
                       "takes a target bitrate (h264 with rate_control bitrate) share, frame by frame, what the other "
                       "passes used over the last second",
                       [](auto& c) -> auto& { return c.stream_kbps; }),
                   kInLiveOffer));
  RunSetting abr = field(
      "abr", SettingType::Choice,
      "adaptive bitrate (core/net/rate_controller.h): off, or latency: the server moves the "
      "stream budget (stream_kbps, its start) from the client's reports of each frame's delivery "
      "delay and loss: down to 0.85 of the received rate when the link's queue passes "
      "abr_target_queue_ms, down by half the datagram loss above 10 % loss, up 8 % per second below 2 %",
      [](auto& c) -> auto& { return c.abr; });
  abr.choices = {"off", "latency"};
  v.push_back(with(abr, kInLiveOffer));
  v.push_back(with(ranged(
                       "abr_min_kbps", SettingType::Number, 1, 1e7, "abr: the lowest stream budget (kbit/s)",
                       [](auto& c) -> auto& { return c.abr_min_kbps; }),
                   kInLiveOffer));
  v.push_back(
      with(ranged(
               "abr_max_kbps", SettingType::Number, 0, 1e7, "abr: the highest stream budget (kbit/s; 0: stream_kbps)",
               [](auto& c) -> auto& { return c.abr_max_kbps; }),
           kInLiveOffer));
  v.push_back(with(ranged(
                       "abr_target_queue_ms", SettingType::Number, 0, 1e4,
                       "abr: the queueing delay (delivery delay above the smallest seen) that makes it back off (ms)",
                       [](auto& c) -> auto& { return c.abr_target_queue_ms; }),
                   kInLiveOffer));
  v.push_back(with(ranged(
                       "abr_interval_ms", SettingType::Number, 1, 1e5,
                       "abr: the shortest time between two changes of the budget (ms of server time)",
                       [](auto& c) -> auto& { return c.abr_interval_ms; }),
                   kInLiveOffer));
  v.push_back(ranged(
      "history_frames", SettingType::Integer, 1, 1024, "client G-buffers kept for prediction",
      [](auto& c) -> auto& { return c.history_frames; }));
  v.push_back(ranged(
      "stall_after_frames", SettingType::Integer, 1, 1000,
      "a pass stalls when its newest data stays the same for more than this many display intervals "
      "(the metrics stalls, stall_ms_total, stall_ms_longest, frames_frozen)",
      [](auto& c) -> auto& { return c.stall_after_frames; }));
  v.push_back(ranged(
      "score_every", SettingType::Integer, 1, 1e9, "score against the local reference on every n-th frame",
      [](auto& c) -> auto& { return c.score_every; }));
  v.push_back(with(ranged(
                       "ground_truth_every", SettingType::Integer, 0, 1e9,
                       "score against the ground truth on every n-th frame (0: never)",
                       [](auto& c) -> auto& { return c.ground_truth_every; }),
                   0, "the client scores against the local reference only"));
  v.push_back(with(ranged(
                       "ground_truth_ao_rays", SettingType::Integer, 1, 65535, "AO rays per pixel of the ground truth",
                       [](auto& c) -> auto& { return c.ground_truth_ao_rays; }),
                   kInTruthKey));
  v.push_back(with(ranged(
                       "ground_truth_samples_per_light", SettingType::Integer, 1, 65535,
                       "shadow rays per area light and pixel of the ground truth",
                       [](auto& c) -> auto& { return c.ground_truth_samples_per_light; }),
                   kInTruthKey));
  RunSetting truth_sampling = field(
      "ground_truth_sampling", SettingType::Choice,
      "the ground truth's samples of a pixel: lattice (a shifted R2 lattice per pixel and light) or "
      "random (independent uniforms); both unbiased, the lattice converges faster per ray "
      "(scripts/ground_truth_sampling.py)",
      [](auto& c) -> auto& { return c.ground_truth_sampling; });
  truth_sampling.choices = sampling_names();
  v.push_back(with(truth_sampling, kInTruthKey));
  v.push_back(field(
      "cache_dir", SettingType::String, "ground truths on disk; empty: $DHR_CACHE_DIR or cache/",
      [](auto& c) -> auto& { return c.cache_dir; }));
  return v;
}

// The value at a dotted `key` of `j`, or nullptr.
const nlohmann::json* find_dotted(const nlohmann::json& j, const std::string& key) {
  const nlohmann::json* node = &j;
  size_t start = 0;
  for (;;) {
    const size_t dot = key.find('.', start);
    if (!node->is_object()) return nullptr;
    const auto it = node->find(key.substr(start, dot == std::string::npos ? std::string::npos : dot - start));
    if (it == node->end()) return nullptr;
    node = &*it;
    if (dot == std::string::npos) return node;
    start = dot + 1;
  }
}

void put_dotted(nlohmann::json& j, const std::string& key, nlohmann::json value) {
  nlohmann::json* node = &j;
  size_t start = 0;
  for (size_t dot; (dot = key.find('.', start)) != std::string::npos; start = dot + 1)
    node = &(*node)[key.substr(start, dot - start)];
  (*node)[key.substr(start)] = std::move(value);
}

bool is_v1_key(const std::string& k) {
  for (const auto& [old, replacements] : v1_run_keys())
    if (old == k) return true;
  return false;
}

// The keys valid directly under `prefix` ("" for the top of "run").
std::vector<std::string> children(const std::string& prefix, int version) {
  std::vector<std::string> out;
  for (const RunSetting& s : run_settings()) {
    if (!prefix.empty() && s.key.rfind(prefix + ".", 0) != 0) continue;
    const std::string rest = prefix.empty() ? s.key : s.key.substr(prefix.size() + 1);
    const std::string child = rest.substr(0, rest.find('.'));
    if (std::find(out.begin(), out.end(), child) == out.end()) out.push_back(child);
  }
  if (prefix.empty() && version == 1)
    for (const auto& [old, replacements] : v1_run_keys()) out.push_back(old);
  return out;
}

void check_keys(const nlohmann::json& obj, const std::string& prefix, const std::string& where, int version,
                std::vector<std::string>& problems) {
  for (const auto& [k, v] : obj.items()) {
    const std::string full = prefix.empty() ? k : prefix + "." + k;
    if (find_run_setting(full)) continue;
    if (prefix.empty() && is_v1_key(k)) {
      if (version != 1)
        problems.push_back(
            fmt::format("{}.{}: a version-1 key; version {} writes it {}", where, k, version, v2_spelling(k)));
      continue;
    }
    const bool group = std::any_of(run_settings().begin(), run_settings().end(),
                                   [&](const RunSetting& s) { return s.key.rfind(full + ".", 0) == 0; });
    if (group && v.is_object()) {
      check_keys(v, full, where, version, problems);
    } else if (group) {
      problems.push_back(fmt::format("{}.{} = {}: must be a JSON object with keys {}", where, full, json_excerpt(v),
                                     join(children(full, version))));
    } else {
      problems.push_back(
          fmt::format("{}.{}: unknown key (valid: {})", where, text_excerpt(full), join(children(prefix, version))));
    }
  }
}

}  // namespace

std::map<std::string, PassChoice, std::less<>> default_pass_choices() {
  std::map<std::string, PassChoice, std::less<>> out;
  for (const PassType& t : pass_types()) out[t.name] = {{t.codec}, {t.denoiser}, {t.predictor}};
  out[kColourPassName] = {{"h264"}, {"none"}, {"none"}};
  out[kDepthPassName] = {{"zstd"}, {"none"}, {"none"}};
  return out;
}

const PassChoice& SimConfig::pass(std::string_view name) const {
  const auto it = passes.find(name);
  if (it == passes.end()) fail("run settings: no pass '{}' (passes: {})", name, join(all_pass_names()));
  return it->second;
}

PassChoice& SimConfig::pass(std::string_view name) { return const_cast<PassChoice&>(std::as_const(*this).pass(name)); }

const char* setting_type_name(SettingType type) {
  switch (type) {
    case SettingType::Integer: return "integer";
    case SettingType::Number: return "number";
    case SettingType::Boolean: return "boolean";
    case SettingType::Choice: return "choice";
    case SettingType::String: return "string";
    case SettingType::Backend: return "backend";
    case SettingType::Link: return "link";
  }
  return "?";
}

std::string RunSetting::range_text() const {
  switch (type) {
    case SettingType::Integer: return fmt::format("an integer in {}..{}", lo, hi);
    case SettingType::Number: return fmt::format("a number in {}..{}", lo, hi);
    case SettingType::Boolean: return "true or false";
    case SettingType::Choice: return "one of " + join(choices);
    case SettingType::String: return "a string";
    case SettingType::Backend: return fmt::format("{{\"name\": a {} (dhrbench list), \"params\": {{...}}}}", kind);
    case SettingType::Link: return "a link {...} (core/net/network.h: LinkConfig)";
  }
  return "?";
}

std::optional<std::string> RunSetting::check_value(const nlohmann::json& v, const std::string& at) const {
  bool ok = true;
  switch (type) {
    case SettingType::Integer:
    case SettingType::Number:
      ok = v.is_number() && (type == SettingType::Number || v.is_number_integer()) && std::isfinite(v.get<double>()) &&
           v.get<double>() >= lo && v.get<double>() <= hi;
      break;
    case SettingType::Boolean: ok = v.is_boolean(); break;
    case SettingType::Choice:
      ok = v.is_string() && std::find(choices.begin(), choices.end(), v.get<std::string>()) != choices.end();
      break;
    case SettingType::String: ok = v.is_string(); break;
    case SettingType::Backend: {
      if (!v.is_object()) {
        ok = false;
        break;
      }
      std::vector<std::string> why;
      for (const auto& [k, x] : v.items())
        if (k != "name" && k != "params")
          why.push_back(fmt::format("{}.{}: unknown key (valid: name, params)", at, text_excerpt(k)));
      if (v.contains("name") && !v.at("name").is_string())
        why.push_back(fmt::format("{}.name = {}: must be a string", at, json_excerpt(v.at("name"))));
      if (v.contains("params") && !v.at("params").is_object()) why.push_back(at + ".params: must be a JSON object");
      if (why.empty()) return std::nullopt;
      return join(why, "\n");
    }
    case SettingType::Link:
      try {
        (void)LinkConfig::from_json(v, at);
        return std::nullopt;
      } catch (const Error& e) {
        return std::string(e.what());
      }
  }
  if (ok) return std::nullopt;
  return fmt::format("{} = {}: must be {}", at, json_excerpt(v), range_text());
}

const std::vector<RunSetting>& run_settings() {
  static const std::vector<RunSetting> settings = make_settings();
  return settings;
}

const RunSetting* find_run_setting(const std::string& key) {
  for (const RunSetting& s : run_settings())
    if (s.key == key) return &s;
  return nullptr;
}

const std::vector<std::pair<std::string, std::vector<std::string>>>& v1_run_keys() {
  static const auto keys = [] {
    std::vector<std::pair<std::string, std::vector<std::string>>> out;
    for (const RunSetting& s : run_settings()) {
      if (s.v1_key.empty()) continue;
      auto it = std::find_if(out.begin(), out.end(), [&](const auto& p) { return p.first == s.v1_key; });
      if (it == out.end())
        out.push_back({s.v1_key, {s.key}});
      else
        it->second.push_back(s.key);
    }
    return out;
  }();
  return keys;
}

std::string v2_spelling(const std::string& dotted) {
  const size_t dot = dotted.find('.');
  const std::string head = dotted.substr(0, dot), rest = dot == std::string::npos ? "" : dotted.substr(dot);
  for (const auto& [old, replacements] : v1_run_keys()) {
    if (old != head) continue;
    std::vector<std::string> out;
    for (const auto& r : replacements) out.push_back(r + rest);
    return join(out, " and ");
  }
  return {};
}

SimConfig sim_config_from_json(const nlohmann::json& j, const std::string& where, std::vector<std::string>& problems,
                               int version) {
  SimConfig c;
  if (!j.is_object()) {
    problems.push_back(fmt::format("{}: must be a JSON object, got {}", where, json_excerpt(j)));
    return c;
  }
  check_keys(j, "", where, version, problems);
  for (const RunSetting& s : run_settings()) {
    const nlohmann::json* v = find_dotted(j, s.key);
    std::string at = s.key;
    if (version == 1 && !s.v1_key.empty() && j.contains(s.v1_key)) {
      if (v) {
        problems.push_back(fmt::format("{}.{} and {}.{}: both given (write one)", where, s.v1_key, where, s.key));
        continue;
      }
      v = &j.at(s.v1_key);
      at = s.v1_key;
    }
    if (!v) continue;
    if (auto why = s.check_value(*v, where + "." + at)) {
      for (size_t start = 0, nl; start <= why->size(); start = nl + 1) {  // a Backend's may be several lines
        nl = std::min(why->find('\n', start), why->size());
        problems.push_back(why->substr(start, nl - start));
      }
      continue;
    }
    s.set(c, *v);
  }
  return c;
}

nlohmann::json SimConfig::to_json() const {
  nlohmann::json out = nlohmann::json::object();
  for (const RunSetting& s : run_settings()) put_dotted(out, s.key, s.get(*this));
  return out;
}

std::vector<std::string> setting_range_problems(const SimConfig& c) {
  std::vector<std::string> out;
  for (const RunSetting& s : run_settings())
    if (auto why = s.check_value(s.get(c), s.key)) out.push_back(*why);
  return out;
}

namespace {

// "key=value|key=value|..." over the settings `take` accepts, in the table's order.
template <class Take>
std::string settings_key_of(const SimConfig& c, Take take) {
  std::string key;
  for (const RunSetting& s : run_settings())
    if (take(s)) key += (key.empty() ? "" : "|") + s.key + "=" + s.get(c).dump();
  return key;
}

}  // namespace

std::string settings_key(const SimConfig& c, SettingFlag flag) {
  return settings_key_of(c, [flag](const RunSetting& s) { return s.has(flag); });
}

std::string pass_settings_key(const SimConfig& c, std::string_view pass) {
  return settings_key_of(c, [pass](const RunSetting& s) {
    return s.has(kInTraceKey) && (s.traced_pass.empty() || s.traced_pass == pass);
  });
}

}  // namespace dhr
