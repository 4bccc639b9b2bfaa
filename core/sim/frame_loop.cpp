#include "core/sim/frame_loop.h"

#include "core/base/checksum.h"
#include "core/base/error.h"
#include "core/config/cache_keys.h"
#include "core/metrics/metrics.h"
#include "core/net/assembler.h"
#include "core/net/fec.h"
#include "core/net/packet.h"
#include "core/net/rate_controller.h"
#include "core/pass/composite.h"
#include "core/pass/reference.h"
#include "core/pipeline/pipeline.h"
#include "core/raster/raster.h"
#include "core/trace/rt_scene.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cstring>
#include <cmath>
#include <deque>
#include <filesystem>
#include <fstream>
#include <thread>
#include <queue>
#include <random>

namespace dhr {

namespace {

// The camera uplink: one small datagram per client frame.
constexpr uint64_t kCameraMessageBytes = 96;  // frame id, time, position, orientation, fov, flags

struct CameraMessage {
  int frame = 0;
  double arrival_ms = 0.0;
  bool keyframe_request = false;
  std::vector<int> holds;            // per pass: the newest frame its decoder holds, after a loss (-1: none)
  std::vector<FrameReport> reports;  // abr: the pass frames completed or lost since the last message
  uint64_t datagrams_received = 0, datagrams_lost = 0;  // abr: the client's running counts
};

struct Datagram {
  double arrival_ms = 0.0;
  uint64_t order = 0;  // send order, breaks ties deterministically
  std::vector<uint8_t> bytes;
  bool operator>(const Datagram& o) const {
    return arrival_ms != o.arrival_ms ? arrival_ms > o.arrival_ms : order > o.order;
  }
};

}  // namespace

// ---- small pieces ---------------------------------------------------------------------------

namespace {

// What each kind of cached value holds, for the cache's bound.
size_t bytes_of(const TraceCache::Entry& e) {
  size_t n = 0;
  for (const TracedPass& t : e.passes) n += t.buffer.bytes.size();
  return n;
}
size_t bytes_of(const ImageRGB8& image) { return image.size() * sizeof(Rgb8); }
size_t bytes_of(const FlipFeatures& f) { return f.bytes(); }
size_t bytes_of(const DenoisedPass& d) { return d.buffer.bytes.size(); }

// One of the cache's maps (key -> last use, value), the caller holding the lock: the value under
// `key`, marked as used now, or nullptr.
template <class Map>
typename Map::mapped_type::second_type lookup(Map& map, const std::string& key, uint64_t& tick) {
  auto it = map.find(key);
  if (it == map.end()) return nullptr;
  it->second.first = ++tick;
  return it->second.second;
}

// Adds `value` under `key` unless there is one; false when there was.
template <class Map, class Value>
bool add(Map& map, const std::string& key, Value value, uint64_t& tick, size_t& bytes) {
  if (map.count(key)) return false;
  bytes += bytes_of(*value);
  map[key] = {++tick, std::move(value)};
  return true;
}

// The least recently used entry of one of the cache's maps (end() when empty).
template <class Map>
typename Map::iterator oldest(Map& map) {
  return std::min_element(map.begin(), map.end(),
                          [](const auto& a, const auto& b) { return a.second.first < b.second.first; });
}

}  // namespace

std::shared_ptr<const TraceCache::Entry> TraceCache::find(const std::string& key) {
  {
    std::lock_guard lock(mutex_);
    if (auto hit = lookup(entries_, key, tick_)) return hit;
  }
  if (disk_dir_.empty()) return nullptr;
  auto entry = read_disk(key);
  if (entry) {
    std::lock_guard lock(mutex_);
    if (add(entries_, key, entry, tick_, bytes_)) evict_locked();
  }
  return entry;
}

namespace {

// A cache file: this magic, the entry (key, stats, the number of passes, then per pass its
// name, kernel time, description and bytes), then the CRC-32C of the entry (core/base/checksum.h).
// Version 02 added the checksum, 03 the pass list; files of older versions are traced again.
constexpr char kTraceFileMagic[8] = {'D', 'H', 'R', 'T', 'R', 'C', '0', '3'};
constexpr uint32_t kMaxCachedPasses = 64;

uint64_t fnv1a64(const std::string& s) {
  uint64_t h = 0xcbf29ce484222325ull;
  for (unsigned char ch : s) h = (h ^ ch) * 0x100000001b3ull;
  return h;
}

template <class T>
void put(std::string& out, const T& v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

template <class T>
bool get(const std::string& in, size_t& pos, T& v) {
  if (in.size() - pos < sizeof(T)) return false;
  std::memcpy(&v, in.data() + pos, sizeof(T));
  pos += sizeof(T);
  return true;
}

}  // namespace

void TraceCache::set_disk_dir(std::string dir) {
  disk_tag_ = dir.empty() ? std::string() : fmt::format("|{}", embree_tracer());
  disk_dir_ = std::move(dir);
}

void TraceCache::write_disk(const std::string& memory_key, const Entry& e) const {
  namespace fs = std::filesystem;
  const std::string key = memory_key + disk_tag_;
  std::string out(kTraceFileMagic, sizeof(kTraceFileMagic));
  put(out, uint32_t(key.size()));
  out += key;
  put(out, e.stats);
  put(out, uint32_t(e.passes.size()));
  for (const TracedPass& t : e.passes) {
    const PassBuffer& p = t.buffer;
    put(out, uint32_t(t.name.size()));
    out += t.name;
    put(out, t.ms);
    put(out, uint8_t(p.desc.kind));
    put(out, int32_t(p.desc.width));
    put(out, int32_t(p.desc.height));
    put(out, int32_t(p.desc.channels));
    put(out, int32_t(p.desc.full_scale));
    put(out, uint64_t(p.bytes.size()));
    out.append(reinterpret_cast<const char*>(p.bytes.data()), p.bytes.size());
  }
  put(out, crc32c({reinterpret_cast<const uint8_t*>(out.data()) + sizeof(kTraceFileMagic),
                   out.size() - sizeof(kTraceFileMagic)}));
  // Written whole under a name no other writer uses (this process, a random number drawn once
  // per process, a counter: processes on several machines may share the folder), then renamed
  // over the entry: a reader sees the old file or the new one, never a part. Two writers of one
  // entry both rename; the last wins, and both wrote the same entry.
  static const uint64_t process_random = std::random_device{}() | (uint64_t(std::random_device{}()) << 32);
  static std::atomic<uint64_t> counter{0};
  std::error_code ec;
  fs::create_directories(disk_dir_, ec);
  const fs::path path = fs::path(disk_dir_) / fmt::format("{:016x}.bin", fnv1a64(key));
  const fs::path tmp = fs::path(disk_dir_) /
                       fmt::format(".{:016x}.tmp.{}.{:016x}.{}", fnv1a64(key), ::getpid(), process_random, counter++);
  {
    std::ofstream f(tmp, std::ios::binary);
    f.write(out.data(), std::streamsize(out.size()));
    f.close();
    if (!f) {  // a cache that cannot be written is only slower
      fs::remove(tmp, ec);
      return;
    }
  }
  fs::rename(tmp, path, ec);
  if (ec) fs::remove(tmp, ec);
}

std::shared_ptr<const TraceCache::Entry> TraceCache::read_disk(const std::string& memory_key) const {
  namespace fs = std::filesystem;
  const std::string key = memory_key + disk_tag_;
  const fs::path path = fs::path(disk_dir_) / fmt::format("{:016x}.bin", fnv1a64(key));
  std::ifstream f(path, std::ios::binary);
  if (!f) return nullptr;
  std::string in((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  size_t pos = sizeof(kTraceFileMagic);
  uint32_t crc = 0;
  if (in.size() < pos + sizeof(crc) || std::memcmp(in.data(), kTraceFileMagic, pos) != 0) return nullptr;
  std::memcpy(&crc, in.data() + in.size() - sizeof(crc), sizeof(crc));
  in.resize(in.size() - sizeof(crc));
  if (crc32c({reinterpret_cast<const uint8_t*>(in.data()) + pos, in.size() - pos}) != crc) return nullptr;
  uint32_t key_size = 0;
  if (!get(in, pos, key_size) || in.size() - pos < key_size || in.compare(pos, key_size, key) != 0) return nullptr;
  pos += key_size;
  auto e = std::make_shared<Entry>();
  if (!get(in, pos, e->stats)) return nullptr;
  uint32_t count = 0;
  if (!get(in, pos, count) || count > kMaxCachedPasses) return nullptr;
  for (uint32_t i = 0; i < count; ++i) {
    uint32_t name_size = 0;
    if (!get(in, pos, name_size) || in.size() - pos < name_size) return nullptr;
    TracedPass t;
    t.name = in.substr(pos, name_size);
    pos += name_size;
    const PassType* type = find_pass_type(t.name);
    if (!type) return nullptr;  // a pass this build does not know
    t.meaning = type->meaning;
    PassBuffer& p = t.buffer;
    uint8_t kind = 0;
    int32_t w = 0, h = 0, ch = 0, fs_ = 0;
    uint64_t n = 0;
    if (!get(in, pos, t.ms) || !get(in, pos, kind) || !get(in, pos, w) || !get(in, pos, h) || !get(in, pos, ch) ||
        !get(in, pos, fs_) || !get(in, pos, n))
      return nullptr;
    p.desc = {PassKind(kind), w, h, ch, fs_};
    if (!p.desc.validate().empty() || n != p.desc.byte_size() || in.size() - pos < n) return nullptr;
    p.bytes.assign(in.begin() + std::ptrdiff_t(pos), in.begin() + std::ptrdiff_t(pos + n));
    pos += n;
    e->passes.push_back(std::move(t));
  }
  return pos == in.size() ? e : nullptr;
}

TraceCache::Claim::Claim(TraceCache& cache, std::string key) : cache_(cache), key_(std::move(key)) {
  std::unique_lock lock(cache_.mutex_);
  cache_.claim_released_.wait(lock, [&] { return !cache_.claimed_.count(key_); });
  cache_.claimed_.insert(key_);
}

TraceCache::Claim::~Claim() {
  {
    std::lock_guard lock(cache_.mutex_);
    cache_.claimed_.erase(key_);
  }
  cache_.claim_released_.notify_all();
}

std::shared_ptr<const ImageRGB8> TraceCache::find_image(const std::string& key) {
  std::lock_guard lock(mutex_);
  return lookup(images_, key, tick_);
}

void TraceCache::insert(const std::string& key, std::shared_ptr<const Entry> entry) {
  if (!disk_dir_.empty()) write_disk(key, *entry);
  std::lock_guard lock(mutex_);
  if (add(entries_, key, std::move(entry), tick_, bytes_)) evict_locked();
}

void TraceCache::insert_image(const std::string& key, std::shared_ptr<const ImageRGB8> image) {
  std::lock_guard lock(mutex_);
  if (add(images_, key, std::move(image), tick_, bytes_)) evict_locked();
}

std::shared_ptr<const FlipFeatures> TraceCache::find_flip(const std::string& key) {
  std::lock_guard lock(mutex_);
  std::shared_ptr<const FlipFeatures> hit = lookup(flips_, key, tick_);
  if (!flip_reads_announced_) return hit;
  const auto it = flip_reads_.find(key);
  if (it == flip_reads_.end()) {
    ++flip_reads_unannounced_;
  } else if (--it->second == 0) {  // the last read: its caller holds what it needs
    flip_reads_.erase(it);
    if (const auto f = flips_.find(key); f != flips_.end()) {
      bytes_ -= bytes_of(*f->second.second);
      flips_.erase(f);
    }
  }
  return hit;
}

void TraceCache::insert_flip(const std::string& key, std::shared_ptr<const FlipFeatures> features) {
  std::lock_guard lock(mutex_);
  if (flip_reads_announced_ && !flip_reads_.count(key)) return;  // nobody reads it again
  if (add(flips_, key, std::move(features), tick_, bytes_)) evict_locked();
}

void TraceCache::expect_flip_reads(const std::string& key, int reads) {
  std::lock_guard lock(mutex_);
  flip_reads_announced_ = true;
  if (reads > 0) flip_reads_[key] += reads;
}

size_t TraceCache::flip_reads_pending() const {
  std::lock_guard lock(mutex_);
  size_t n = 0;
  for (const auto& [key, reads] : flip_reads_) n += size_t(reads);
  return n;
}

uint64_t TraceCache::flip_reads_unannounced() const {
  std::lock_guard lock(mutex_);
  return flip_reads_unannounced_;
}

size_t TraceCache::flips_held() const {
  std::lock_guard lock(mutex_);
  return flips_.size();
}

Rastered TraceCache::find_raster(const std::string& scene_key, const RasterFrame& frame) {
  std::lock_guard lock(mutex_);
  if (scene_key != raster_scene_) return {};
  for (const KeptRaster& k : rasters_)
    if (same_raster_frame(k.frame, frame)) {
      ++raster_hits_;
      return k.rastered;
    }
  return {};
}

void TraceCache::keep_raster(const std::string& scene_key, const RasterFrame& frame, const Rastered& rastered,
                             size_t capacity) {
  std::lock_guard lock(mutex_);
  if (max_bytes_ == 0 || !rastered.gbuf) return;
  if (!rasters_.empty() && (scene_key != raster_scene_ || rasters_.front().frame.scene != frame.scene ||
                            rasters_.front().frame.camera.width != frame.camera.width ||
                            rasters_.front().frame.camera.height != frame.camera.height))
    rasters_.clear();  // another scene or size: start over
  raster_scene_ = scene_key;
  if (rasters_.size() >= capacity) return;
  for (const KeptRaster& k : rasters_)
    if (same_raster_frame(k.frame, frame)) return;
  rasters_.push_back({frame, rastered});
}

uint64_t TraceCache::raster_hits() const {
  std::lock_guard lock(mutex_);
  return raster_hits_;
}

std::shared_ptr<const DenoisedPass> TraceCache::find_denoised(const std::string& key) {
  std::lock_guard lock(mutex_);
  return lookup(denoised_, key, tick_);
}

void TraceCache::insert_denoised(const std::string& key, std::shared_ptr<const DenoisedPass> pass) {
  std::lock_guard lock(mutex_);
  if (add(denoised_, key, std::move(pass), tick_, bytes_)) evict_locked();
}

namespace {

// The last use of `map`'s entry `it` (UINT64_MAX: none).
template <class Map>
uint64_t tick_of(const Map& map, typename Map::iterator it) {
  return it == map.end() ? UINT64_MAX : it->second.first;
}

// Erases `map`'s entry `it` when its last use is `tick`; true when it did.
template <class Map>
bool erase_at(Map& map, typename Map::iterator it, uint64_t tick, size_t& bytes) {
  if (it == map.end() || it->second.first != tick) return false;
  bytes -= bytes_of(*it->second.second);
  map.erase(it);
  return true;
}

}  // namespace

void TraceCache::evict_locked() {
  while (bytes_ > max_bytes_ && (!entries_.empty() || !images_.empty() || !flips_.empty() || !denoised_.empty())) {
    // The least recently used of the four maps (each scanned once).
    const auto e = oldest(entries_);
    const auto i = oldest(images_);
    const auto f = oldest(flips_);
    const auto d = oldest(denoised_);
    const uint64_t tick =
        std::min({tick_of(entries_, e), tick_of(images_, i), tick_of(flips_, f), tick_of(denoised_, d)});
    erase_at(entries_, e, tick, bytes_) || erase_at(images_, i, tick, bytes_) || erase_at(flips_, f, tick, bytes_) ||
        erase_at(denoised_, d, tick, bytes_);
  }
}

// ---- the loop -----------------------------------------------------------------------------

namespace {

class Simulation {
 public:
  Simulation(const RunPlan& plan, const std::string& scene_key, TraceCache& cache, const Registries& registries)
      : plan_(plan),
        c_(plan.config),
        scene_(*plan.scene),
        scene_key_(scene_key),
        keys_(CacheKeys::of(plan, scene_key)),
        cache_(cache),
        uplink_(c_.uplink, c_.seed, 0),
        downlink_(c_.downlink, c_.seed, 1),
        server_(
            plan, registries, [this](uint32_t frame, const GBuffer& g) { return traced(int(frame), g); }, 0,
            [this](const RasterFrame& f) { return server_raster(f); }),
        client_(plan, registries),
        local_(plan, registries) {
    // The server and the local reference share their temporal denoisers' outputs with the
    // other runs of the sweep (DenoiseStage::share).
    std::vector<std::string> denoise_keys;
    for (const PlannedPass& p : plan_.traced) denoise_keys.push_back(keys_.denoise_chain(p.name));
    // (Under pose prediction the server's frames are not the path's: its denoisers see a
    // sequence of their own, shared with no other run.)
    if (!predicts_pose()) server_.share_denoised(&memo_, denoise_keys);
    if (c_.server_pose_prediction == "delay") {  // pose_lead_ms reads the links' latency traces
      if (c_.uplink.latency_model == LinkConfig::Latency::Trace) up_trace_ = load_latency_trace(c_.uplink.trace_file);
      if (c_.downlink.latency_model == LinkConfig::Latency::Trace)
        down_trace_ = load_latency_trace(c_.downlink.trace_file);
    }
    local_.share_denoised({&memo_, denoise_keys, [this](const RasterFrame& f) { return server_raster(f); },
                           [this](uint32_t frame, const GBuffer& g) { return traced(int(frame), g); }});
    AssemblerConfig ac;
    ac.max_payload_bytes = c_.max_payload_bytes;
    ac.timeout_ms = 500;
    assembler_ = Assembler(ac);
    // Hybrid runs report both pass streams, planned or not (zero traffic when not planned);
    // remote runs the colour stream and, when sent, the depth stream.
    if (plan_.remote())
      for (const PlannedPass& p : server_.passes()) traffic_.push_back({p.name});
    else
      for (const PassType& t : pass_types()) traffic_.push_back({t.name});
    for (const PlannedPass& p : server_.passes()) traffic_index_.push_back(traffic_of(p.name));
    client_holds_.assign(server_.passes().size(), -1);
    if (const auto rs = plan_.abr()) {
      abr_.emplace(*rs);
      result_.abr_kbps_lowest = abr_->rate_kbps();
    }
    result_.config = c_.to_json();
    result_.plan = plan_.passes;
  }

  RunResult run(const ProgressFn& progress) {
    const int total = c_.warmup_frames + c_.frames;
    take_cached_local_reference(total);
    for (int a = 0; a < total; ++a) {
      client_frame(a);
      if (progress) progress(a + 1, total);
    }
    result_.duration_ms = double(c_.frames) * 1000.0 / c_.display_hz;
    result_.traffic = traffic_;
    result_.receiver_packets_lost = assembler_.stats().packets_lost;
    if (abr_) {
      result_.abr_updates = abr_->updates();
      result_.abr_reports_dropped = abr_->reports_dropped();
    }
    for (auto& [name, s] : stages_) result_.stages[name] = s;
    return std::move(result_);
  }

 private:
  double frame_ms(int a) const { return double(a) * 1000.0 / c_.display_hz; }
  double frame_time_s(int a) const { return c_.start_time_s + double(a) / c_.display_hz; }
  Camera camera(int a) const { return scene_.camera.at(c_.camera_time_s(frame_time_s(a)), c_.width, c_.height); }
  bool scored(int a) const { return a >= c_.warmup_frames; }
  void stage(const char* name, double ms, bool count) {
    if (count) stages_[name].samples_ms.push_back(ms);
  }
  size_t traffic_of(const std::string& name) const {
    for (size_t i = 0; i < traffic_.size(); ++i)
      if (traffic_[i].pass == name) return i;
    fail("internal: no traffic record for pass '{}'", name);
  }

  RtScene& rt() {
    if (!rt_) rt_ = std::make_unique<RtScene>(scene_);
    return *rt_;
  }

  std::string local_key(int a) const { return keys_.local_reference(a); }

  // When the cache holds the local reference of every frame this run scores, the run takes them
  // all from there and never runs its own (a temporal denoiser must see every frame from the
  // first, so a run takes all or none).
  void take_cached_local_reference(int total) {
    for (int a = c_.warmup_frames; a < total; ++a) {
      if (!scores_frame(c_, a - c_.warmup_frames)) continue;
      std::shared_ptr<const ImageRGB8> image = cache_.find_image(local_key(a));
      if (!image) {
        local_cached_.clear();
        return;
      }
      local_cached_[a] = std::move(image);
    }
  }

  // The traced passes of client frame a. Each pass is cached on its own: it depends on nothing
  // but the scene, the frame's camera and its settings (pass_trace_key), so the runs of a sweep
  // that differ in one pass's settings trace the other once (trace_passes with `only`, joined:
  // the same bits as tracing them together). The server and the local reference both ask for a
  // frame: the last join is kept, so a frame's buffers are copied into one entry once.
  // A G-buffer for another camera than the path's at frame a (the server's, under pose
  // prediction) is keyed by that camera too.
  std::shared_ptr<const TraceCache::Entry> traced(int a, const GBuffer& gbuf) {
    const std::string pose = pose_key(a, gbuf.camera);
    if (joined_.first == a && joined_pose_ == pose) return joined_.second;
    const TraceSettings settings = c_.trace_for_frame(uint32_t(a));
    std::vector<std::shared_ptr<const TraceCache::Entry>> parts;
    for (const PlannedPass& p : plan_.traced) {
      const std::string key = keys_.pass_trace(a, p.name) + pose;
      parts.push_back(cache_.find_or_make(
          key, [&] { return cache_.find(key); },
          [&] {
            auto made = std::make_shared<const TraceCache::Entry>(
                static_cast<TracedPasses&&>(trace_passes(rt(), gbuf, plan_.passes, settings, p.name)));
            cache_.insert(key, made);
            return made;
          }));
    }
    if (parts.size() == 1) return parts.front();
    std::vector<const TracedPasses*> list;
    for (const auto& part : parts) list.push_back(part.get());
    joined_ = {a, std::make_shared<const TraceCache::Entry>(join_traced(list, gbuf))};
    joined_pose_ = pose;
    return joined_.second;
  }

  // Empty for the path's camera at frame a; else "|pose=" and the camera's floats, exactly.
  std::string pose_key(int a, const Camera& cam) const {
    const Camera path = camera(a);
    if (cam.position == path.position && cam.forward == path.forward && cam.up == path.up) return {};
    std::string key = "|pose=";
    for (const glm::vec3* v : {&cam.position, &cam.forward, &cam.up})
      for (int i = 0; i < 3; ++i) key += fmt::format("{:a},", (*v)[i]);
    return key;
  }

  // The camera the server renders frame j for: the path's (as received), or under pose
  // prediction that camera extrapolated from the one received before it by the lead.
  Camera server_camera(int j) {
    const Camera received = camera(j);
    if (!predicts_pose()) return received;
    Camera rendered = received;
    if (last_received_ >= 0 && last_received_ < j)
      rendered = extrapolate_pose(camera(last_received_), frame_ms(last_received_), received, frame_ms(j),
                                  frame_ms(j) + pose_lead_ms(j));
    last_received_ = j;
    rendered_cameras_[j] = rendered;  // one per server frame of the run: the client may show any of them
    return rendered;
  }
  bool predicts_pose() const { return c_.server_pose_prediction != "off"; }
  // How far ahead the server renders client frame j's camera: server_pose_lead_ms, or the
  // expected delay until the frame is shown: the links' mean latencies (a trace's value when
  // the camera and the frame leave) and the server's fixed time, rounded up to whole display
  // intervals (the frame waits for the next one).
  double pose_lead_ms(int j) const {
    if (c_.server_pose_prediction == "lead") return c_.server_pose_lead_ms;
    auto latency = [&](const LinkConfig& l, const std::optional<SampleTrace>& trace, double t_ms) {
      return trace ? trace->at(t_ms + l.trace_offset_ms) : l.latency_ms;
    };
    const double sent = frame_ms(j), up = latency(c_.uplink, up_trace_, sent);
    const double down = latency(c_.downlink, down_trace_, sent + up + c_.server_fixed_ms);
    const double interval = 1000.0 / c_.display_hz;
    return std::ceil((up + c_.server_fixed_ms + down) / interval - 1e-9) * interval;
  }
  // The camera the client warps frame j from: the one the server rendered it for.
  Camera source_camera(int j) const {
    auto it = rendered_cameras_.find(j);
    return it != rendered_cameras_.end() ? it->second : camera(j);
  }

  // Ground truth: converged visibility and AO (no denoiser), composited (core/pass/reference.h,
  // cached on disk there and in memory here).
  std::shared_ptr<const ImageRGB8> ground_truth(int a, const GBuffer& gbuf) {
    const std::string key = keys_.truth(a);
    return cache_.find_or_make(
        key, [&] { return cache_.find_image(key); },
        [&] {
          ReferenceSettings rs;
          rs.ao_rays = c_.ground_truth_ao_rays;
          rs.samples_per_light = c_.ground_truth_samples_per_light;
          rs.lattice = is_lattice(c_.ground_truth_sampling);
          rs.cache_dir = c_.cache_dir;
          auto img = std::make_shared<const ImageRGB8>(dhr::ground_truth(rt(), gbuf, rs).image);
          cache_.insert_image(key, img);
          return img;
        });
  }

  // FLIP's half of the work on the reference image under `key` (a local reference's or a ground
  // truth's), kept for the other runs that score against it: computed once.
  std::shared_ptr<const FlipFeatures> flip_features_of(const std::string& key, const ImageRGB8& reference) {
    if (auto hit = cache_.find_flip(key)) return hit;
    auto features = std::make_shared<const FlipFeatures>(flip_features(reference));
    cache_.insert_flip(key, features);
    return features;
  }

  // ---- server: the schedule (the stages are core/pipeline/pipeline.h's ServerPipeline)

  // The server's G-buffer of `f`: the client's of the same RasterFrame when it rasterized one
  // (the server's frame j follows its frame j - 1, as the client's does, unless it skipped
  // frames), else a rasterization now. Computed once: the same bits (same_raster_frame), and
  // the server's stage time is the client's rasterization of it.
  Rastered server_raster(const RasterFrame& f) {
    for (const RasterMemo& m : rasters_)
      if (same_raster_frame(m.frame, f)) return m.rastered;
    if (Rastered kept = cache_.find_raster(scene_key_, f); kept.gbuf) return kept;
    return rasterize_now(f);
  }
  // The client's G-buffer of `f`: an earlier run's of the same frame (TraceCache::find_raster),
  // else rasterized now and offered to the cache, which keeps the first frames up to as many as
  // this run's client holds itself (remember_raster). A kept one's time is the time its
  // rasterization took.
  Rastered client_raster(const RasterFrame& f) {
    if (Rastered kept = cache_.find_raster(scene_key_, f); kept.gbuf) return kept;
    Rastered r = rasterize_now(f);
    cache_.keep_raster(scene_key_, f, r, raster_history());
    return r;
  }
  // (A client that predicts with its G-buffers keeps history_frames; one that does not, a few.)
  size_t raster_history() const { return plan_.client_does(ClientStage::Rasterize) ? size_t(c_.history_frames) : 8; }
  // Keeps the client's last G-buffers for server_raster: as many as the hybrid client keeps for
  // prediction (shared with those: no more memory), a few in remote mode (which keeps none).
  void remember_raster(const RasterFrame& f, const Rastered& r) {
    rasters_.push_back({f, r});
    while (rasters_.size() > raster_history()) rasters_.pop_front();
  }

  void server_advance(double until_ms) {
    for (;;) {
      double earliest = INFINITY;
      for (const auto& m : inbox_)
        if (m.frame > server_last_frame_) earliest = std::min(earliest, m.arrival_ms);
      if (!std::isfinite(earliest)) return;
      const double start = std::max(server_free_ms_, earliest);
      if (start > until_ms) return;
      int newest = -1;
      double camera_arrival = start;  // the newest camera's (PassFrameRecord::uplink_ms)
      bool keyframe = false;
      std::vector<int> holds(client_holds_.size(), -1);
      for (const auto& m : inbox_)
        if (m.arrival_ms <= start && m.frame > server_last_frame_) {
          if (m.frame > newest) {
            newest = m.frame;
            camera_arrival = m.arrival_ms;
          }
          keyframe = keyframe || m.keyframe_request;
          for (size_t i = 0; i < m.holds.size() && i < holds.size(); ++i) holds[i] = std::max(holds[i], m.holds[i]);
        }
      for (const auto& m : inbox_)
        if (m.arrival_ms <= start && m.frame > server_last_frame_ && m.frame < newest && scored(newest))
          ++result_.cameras_dropped;
      if (abr_) {  // the reports every message that arrived carries, then the budget from now on
        for (const auto& m : inbox_)
          if (m.arrival_ms <= start) {
            for (const FrameReport& r : m.reports) abr_->on_report(r);
            abr_->on_counts(m.datagrams_received, m.datagrams_lost);
          }
        server_.set_stream_kbps(abr_->update(start));
        if (scored(newest)) result_.abr_kbps_lowest = std::min(result_.abr_kbps_lowest, abr_->rate_kbps());
      }
      std::erase_if(inbox_, [&](const CameraMessage& m) { return m.arrival_ms <= start && m.frame <= newest; });
      server_times_[newest] = {camera_arrival, start, 0.0};
      server_job(newest, start, keyframe, holds);
    }
  }

  void server_job(int j, double start_ms, bool keyframe, const std::vector<int>& holds) {
    const bool count = scored(j);
    ServerFrame f = server_.run(uint32_t(j), server_camera(j), frame_time_s(j), keyframe, holds);
    for (const StageTime& s : f.stages) stage(s.name, s.ms, count);
    if (count) {
      result_.trace_stats.add(f.trace);
      result_.server_frames_wall.samples_ms.push_back(f.compute_ms);
    }
    const double finish =
        start_ms + (c_.server_timing == SimConfig::ServerTiming::Fixed ? c_.server_fixed_ms : f.compute_ms);
    for (size_t i = 0; i < f.passes.size(); ++i) {
      SentPass& p = f.passes[i];
      PassTraffic& t = traffic_[traffic_index_[i]];
      if (count) {
        ++t.server_frames;
        t.encoded_bytes += p.encoded_bytes;
        result_.server_log.push_back({j, t.pass, p.encoded_bytes, p.packets.size(), wire_bytes_of_packets(p.packets)});
      }
    }
    // All packets leave when the server finishes.
    for (size_t i = 0; i < f.passes.size(); ++i) {
      PassTraffic& t = traffic_[traffic_index_[i]];
      if (abr_) abr_->on_sent(uint32_t(j), int(i), wire_bytes_of_packets(f.passes[i].packets), finish);
      std::vector<bool> arrived;
      for (auto& packet : f.passes[i].packets) {
        const uint64_t wire = packet.size() + kIpUdpOverheadBytes;
        if (count) {
          t.wire_bytes += wire;
          ++t.packets;
        }
        const Delivery d = downlink_.send(wire, finish);
        if (d.delivered) in_flight_.push({d.arrival_ms, send_order_++, std::move(packet)});
        arrived.push_back(d.delivered);
      }
      // The simulator knows which datagrams the link dropped: a frame with any of them lost
      // can never complete, unless its parity packets rebuild them (core/net/fec.h). (The receiver
      // sees a loss as a gap in the sequence numbers.)
      if (count && std::find(arrived.begin(), arrived.end(), false) != arrived.end()) {
        const int data = int(packet_count(f.passes[i].encoded_bytes, c_.max_payload_bytes));
        FecLayout fec;
        const bool rebuilt = fec_layout(data, int(arrived.size()) - data, fec) && fec_can_rebuild(fec, arrived);
        ++(rebuilt ? t.frames_recovered : t.frames_lost);
      }
    }
    server_free_ms_ = finish;
    server_times_[j].finish_ms = finish;
    while (server_times_.size() > kLatencyMemory) server_times_.erase(server_times_.begin());
    server_last_frame_ = j;
    if (count) ++result_.server_frames;
  }

  // The stages of a displayed buffer's age (PassFrameRecord), from the times this run recorded
  // for its server frame and its completion at the client; left NaN when they are gone.
  void break_down_age(PassFrameRecord& p, int pass, double now) const {
    const auto st = server_times_.find(p.source_frame);
    const auto done = completed_.find({p.source_frame, pass});
    if (st == server_times_.end() || done == completed_.end()) return;
    const ServerTimes& t = st->second;
    p.uplink_ms = t.camera_arrival_ms - frame_ms(p.source_frame);
    p.server_wait_ms = t.start_ms - t.camera_arrival_ms;
    p.server_ms = t.finish_ms - t.start_ms;
    // (The assembler stamps a completion with the arrival's whole millisecond.)
    p.downlink_ms = done->second - t.finish_ms;
    p.display_wait_ms = now - done->second;
  }

  // ---- client: the clock and the links (the stages are core/pipeline/pipeline.h's ClientPipeline)

  void receive(double now_ms, bool count) {
    while (!in_flight_.empty() && in_flight_.top().arrival_ms <= now_ms) {
      const Datagram& d = in_flight_.top();
      assembler_.push(d.bytes, int64_t(std::floor(d.arrival_ms)));
      in_flight_.pop();
    }
    AssemblerEvents events = assembler_.poll(int64_t(std::floor(now_ms)));
    for (const LostFrame& lost : events.lost) {
      const int pass = client_.pass_of(lost.meta.desc.kind);
      if (pass >= 0 && abr_) reports_.push_back({lost.meta.frame_id, pass, true, 0.0});
      if (pass >= 0 && count) ++traffic_[traffic_index_[size_t(pass)]].frames_given_up;
    }
    for (AssembledFrame& f : events.completed) {
      const int pass = client_.pass_of(f.meta.desc.kind);
      if (pass < 0) continue;
      PassTraffic& t = traffic_[traffic_index_[size_t(pass)]];
      if (count) ++t.frames_completed;
      if (abr_) reports_.push_back({f.meta.frame_id, pass, false, double(f.completed_ms)});
      completed_[{int(f.meta.frame_id), pass}] = double(f.completed_ms);
      while (completed_.size() > kLatencyMemory) completed_.erase(completed_.begin());
      const PassReceiver::Outcome o = client_.receive(pass, f);
      client_decode_ms_ += o.decode_ms;
      keyframe_request_ = keyframe_request_ || o.keyframe_request;
      if (o.keyframe_request) client_holds_[size_t(pass)] = o.holds;
      if (count) {
        t.decode_errors += o.decode_error ? 1 : 0;
        t.keyframe_requests += o.gap_reset ? 1 : 0;
      }
    }
  }

  void client_frame(int a) {
    const bool count = scored(a);
    const double now = frame_ms(a);
    const Camera cam = camera(a);
    const Camera prev = a > 0 ? camera(a - 1) : cam;
    FrameRecord rec;
    rec.frame = a - c_.warmup_frames;
    rec.t_ms = now;
    double client_ms = 0;

    const RasterFrame raster_frame{&scene_, cam, frame_time_s(a), prev, a > 0 ? frame_time_s(a - 1) : frame_time_s(a)};
    const Rastered rastered = client_raster(raster_frame);
    const double raster_ms = rastered.ms;
    remember_raster(raster_frame, rastered);
    // The hybrid client keeps its G-buffers for predicting later frames (this one included:
    // with zero latency the server's frame for this very camera may arrive now). The remote
    // client does not rasterize: this G-buffer only scores it.
    const bool rasterizes = plan_.client_does(ClientStage::Rasterize);
    if (rasterizes) client_.keep(a, rastered.gbuf);
    const GBuffer& gbuf = *rastered.gbuf;
    stage("rasterize", raster_ms, count);
    if (rasterizes) client_ms += raster_ms;

    // Uplink: this frame's camera (and a keyframe request after a loss).
    const Delivery up =
        uplink_.send(kCameraMessageBytes + (abr_ ? kReportsHeadBytes + kFrameReportWireBytes * reports_.size() : 0) +
                         kIpUdpOverheadBytes,
                     now);
    if (up.delivered) {
      inbox_.push_back({a, up.arrival_ms, keyframe_request_, client_holds_, std::move(reports_),
                        assembler_.stats().datagrams, assembler_.stats().packets_lost});
      keyframe_request_ = false;
      std::fill(client_holds_.begin(), client_holds_.end(), -1);
    } else if (count) {
      ++result_.cameras_lost;
    }
    reports_.clear();  // sent with this camera, or lost with it

    server_advance(now);
    client_decode_ms_ = 0;
    receive(now, count);
    stage("decode", client_decode_ms_, count);
    client_ms += client_decode_ms_;

    // Local reference: this frame's own passes, denoised by the client-side sequence.
    const bool score_now = count && scores_frame(c_, rec.frame);
    std::optional<ImageRGB8> local_image;
    if (!local_cached_.empty()) {
      if (score_now) local_image = *local_cached_.at(a);
    } else if (local_.needs_every_frame() || score_now) {
      local_image = local_.frame(uint32_t(a), raster_frame, gbuf, *traced(a, gbuf), score_now);
      if (score_now) cache_.insert_image(local_key(a), std::make_shared<const ImageRGB8>(*local_image));
    }

    // Predict each pass and composite.
    ClientFrame shown = client_.display(a, gbuf, [this](int frame) { return source_camera(frame); });
    if (client_.upsamples()) {
      stage("upsample", shown.upsample_ms, count);
      client_ms += shown.upsample_ms;
    }
    stage("predict", shown.predict_ms, count);
    client_ms += shown.predict_ms;
    if (shown.composited) {
      stage("composite", shown.composite_ms, count);
      client_ms += shown.composite_ms;
    }
    if (count) {
      result_.frames_without_data += shown.passes_without_data > 0 ? 1 : 0;
      for (size_t i = 0; i < shown.without_data.size(); ++i)
        traffic_[traffic_index_[i]].frames_without_data += shown.without_data[i] ? 1 : 0;
    }
    for (size_t i = 0; i < client_.passes().size(); ++i) {
      PassFrameRecord p{client_.passes()[i].name, shown.source_frame[i], 0.0, shown.disoccluded[i]};
      if (p.source_frame >= 0) {
        p.age_ms = now - frame_ms(p.source_frame);
        break_down_age(p, int(i), now);
      }
      rec.passes.push_back(std::move(p));
    }
    rec.client_wall_ms = client_ms;
    const ImageRGB8& image = shown.image;

    if (score_now) {
      rec.scored = true;
      const auto local_flip = flip_features_of(local_key(a), *local_image);
      rec.local = score_frame(ScoreReference{*local_image, local_flip.get()}, image,
                              prev_local_ ? &*prev_local_ : nullptr, prev_shown_ ? &*prev_shown_ : nullptr);
      prev_local_ = *local_image;  // the step metrics' previous scored frame
      prev_shown_ = image;
      if (scores_ground_truth(c_, rec.frame)) {
        auto truth = ground_truth(a, gbuf);
        rec.scored_ground_truth = true;
        const auto truth_flip = flip_features_of(keys_.truth(a), *truth);
        rec.ground_truth = score_frame(ScoreReference{*truth, truth_flip.get()}, image);
        if (c_.keep_images) result_.ground_truth_images = {*truth};
      }
      // Keep the images of the last frame scored against the ground truth (or, without ground
      // truth, of the last scored frame): one frame per run, for the report's image grids.
      if (c_.keep_images && (rec.scored_ground_truth || c_.ground_truth_every == 0)) {
        result_.images = {image};
        result_.local_images = {*local_image};
        result_.kept_frame = rec.frame;
      }
    }
    if (count) result_.frames.push_back(rec);
  }

  const RunPlan& plan_;
  const SimConfig& c_;  // plan_.config
  const Scene& scene_;  // *plan_.scene
  std::string scene_key_;
  CacheKeys keys_;                                                // what names its cached values
  std::optional<ImageRGB8> prev_local_, prev_shown_;              // the last scored frame's reference and image
  std::map<int, std::shared_ptr<const ImageRGB8>> local_cached_;  // the local references taken from the cache
  TraceCache& cache_;
  // The cache as the denoisers' memo.
  struct Memo final : DenoiseMemo {
    explicit Memo(TraceCache& c) : cache(c) {}
    std::shared_ptr<const DenoisedPass> find(const std::string& key) override { return cache.find_denoised(key); }
    void insert(const std::string& key, std::shared_ptr<const DenoisedPass> value) override {
      cache.insert_denoised(key, std::move(value));
    }
    std::shared_ptr<void> claim(const std::string& key) override {
      return std::make_shared<TraceCache::Claim>(cache, key);
    }
    TraceCache& cache;
  } memo_{cache_};
  Link uplink_, downlink_;
  std::unique_ptr<RtScene> rt_;
  std::pair<int, std::shared_ptr<const TraceCache::Entry>> joined_{-1, nullptr};  // traced()'s last join
  std::string joined_pose_;                                                       // and its pose_key
  // Pose prediction: the newest camera frame the server received, and the cameras it rendered.
  int last_received_ = -1;
  std::map<int, Camera> rendered_cameras_;
  std::optional<SampleTrace> up_trace_, down_trace_;  // the links' latency traces, for pose_lead_ms
  struct RasterMemo {
    RasterFrame frame;
    Rastered rastered;
  };
  std::deque<RasterMemo> rasters_;  // before server_, which calls server_raster
  ServerPipeline server_;
  ClientPipeline client_;
  LocalReference local_;
  std::vector<PassTraffic> traffic_;
  std::vector<size_t> traffic_index_;  // per pass of the list: its record in traffic_
  Assembler assembler_;
  RunResult result_;
  std::map<std::string, StageStats> stages_;

  // server schedule
  std::vector<CameraMessage> inbox_;
  double server_free_ms_ = 0.0;
  int server_last_frame_ = -1;
  std::priority_queue<Datagram, std::vector<Datagram>, std::greater<Datagram>> in_flight_;
  uint64_t send_order_ = 0;

  // client state
  bool keyframe_request_ = false;
  std::vector<int> client_holds_;  // per pass, sent with the next camera (CameraMessage::holds)
  double client_decode_ms_ = 0.0;
  std::vector<FrameReport> reports_;  // abr: for the next camera message

  std::optional<RateController> abr_;  // abr on: the server's bitrate controller

  // The times behind each displayed buffer's age (break_down_age), for the last frames.
  static constexpr size_t kLatencyMemory = 4096;
  struct ServerTimes {
    double camera_arrival_ms = 0.0, start_ms = 0.0, finish_ms = 0.0;
  };
  std::map<int, ServerTimes> server_times_;          // per server frame
  std::map<std::pair<int, int>, double> completed_;  // (server frame, pass) -> completed at the client
};

}  // namespace

RunResult run_simulation(const RunPlan& plan, const std::string& scene_key, TraceCache& cache,
                         const Registries& registries, const ProgressFn& progress) {
  Simulation sim(plan, scene_key, cache, registries);
  return sim.run(progress);
}

RunResult run_simulation(const SimConfig& config, const Scene& scene, const std::string& scene_key, TraceCache& cache,
                         const Registries& registries, const ProgressFn& progress) {
  return run_simulation(plan_run(config, scene, registries), scene_key, cache, registries, progress);
}

}  // namespace dhr
