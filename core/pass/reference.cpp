// Ground truth and local references (see core/pass/reference.h).
#include "core/pass/reference.h"

#include "core/base/error.h"
#include "core/base/rng.h"
#include "core/buffers/image_io.h"
#include "core/pass/passes.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <random>
#include <atomic>
#include <system_error>

#include <unistd.h>

namespace dhr {

namespace {

// A 64-bit streaming hash: 8-byte words folded through the SplitMix64 finalizer (core/base/rng.h).
// Not cryptographic; collisions between the few thousand references of a project are not a
// concern at 64 bits.
class Hasher {
 public:
  void bytes(const void* data, size_t n) {
    const auto* p = static_cast<const uint8_t*>(data);
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
      uint64_t w;
      std::memcpy(&w, p + i, 8);
      word(w);
    }
    uint64_t tail = 0;
    std::memcpy(&tail, p + i, n - i);
    word(tail ^ (uint64_t(n - i) << 56));
    word(n);
  }
  template <class T>
  void pod(const T& v) {
    bytes(&v, sizeof(T));
  }
  template <class T, class A>
  void vec(const std::vector<T, A>& v) {
    pod(v.size());
    if (!v.empty()) bytes(v.data(), v.size() * sizeof(T));
  }
  void str(const std::string& s) { bytes(s.data(), s.size()); }
  uint64_t value() const { return mix64(h_); }

 private:
  void word(uint64_t w) { h_ = mix64(h_ ^ w) + 0x9E3779B97F4A7C15ull; }
  uint64_t h_ = 0x243F6A8885A308D3ull;
};

void hash_camera(Hasher& h, const Camera& c) {
  h.pod(c.position);
  h.pod(c.forward);
  h.pod(c.up);
  h.pod(c.vfov_deg);
  h.pod(c.near_m);
  h.pod(c.far_m);
  h.pod(c.width);
  h.pod(c.height);
}

}  // namespace

std::string default_cache_dir() {
  const char* env = std::getenv("DHR_CACHE_DIR");
  if (env && *env) return env;
  return std::string(DHR_SOURCE_DIR) + "/cache";
}

uint64_t scene_content_hash(const Scene& s) {
  Hasher h;
  for (const Object& o : s.objects) {
    h.str(o.name);
    h.pod(o.id);
    h.pod(o.material);
    h.vec(o.mesh.positions);
    h.vec(o.mesh.normals);
    h.vec(o.mesh.uvs);
    h.vec(o.mesh.triangles);
    h.pod(o.animation.has_value());
    if (o.animation) {
      h.pod(o.animation->loop);
      for (const TransformKey& k : o.animation->keys) {
        h.pod(k.time_s);
        h.pod(k.translation);
        h.pod(k.rotation);
        h.pod(k.scale);
      }
    }
  }
  for (const Material& m : s.materials) {
    h.str(m.name);
    h.pod(m.albedo);
    h.pod(m.texture);
    h.pod(m.alpha_cutout);
    h.pod(m.alpha_threshold);
    h.pod(m.emitter);
  }
  for (const Texture& t : s.textures) {
    h.pod(t.width);
    h.pod(t.height);
    h.pod(t.has_alpha);
    h.vec(t.texels);
  }
  for (const Light& l : s.lights) {
    h.pod(l.type);
    h.pod(l.position);
    h.pod(l.direction);
    h.pod(l.colour);
    h.pod(l.intensity);
    h.pod(l.radius_m);
    h.pod(l.angular_radius_deg);
    h.pod(l.range_m);
  }
  h.pod(s.ambient);
  h.pod(s.background);
  h.pod(s.ao.has_value());
  if (s.ao) {
    h.pod(s.ao->radius_m);
    h.pod(s.ao->rays);
  }
  if (!s.source_path.empty()) {
    std::ifstream in(s.source_path, std::ios::binary);
    if (in) {
      const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      h.str(bytes);
    }
  }
  return h.value();
}

std::string reference_key(const Scene& scene, const GBuffer& g, const ReferenceSettings& s, const std::string& tracer) {
  Hasher h;
  h.pod(kReferenceVersion);
  h.pod(scene_content_hash(scene));
  hash_camera(h, g.camera);
  h.pod(g.time_s);
  h.pod(g.width());
  h.pod(g.height());
  h.vec(g.object_id.pixels());
  h.vec(g.prim_id.pixels());
  h.vec(g.bary.pixels());
  h.vec(g.position.pixels());
  h.vec(g.normal.pixels());
  h.vec(g.albedo.pixels());
  h.pod(s.ao_rays);
  h.pod(s.samples_per_light);
  h.pod(s.seed);
  h.pod(s.composite.exposure);
  h.str(tracer);
  if (s.lattice) h.str("lattice");  // independent uniforms keep the keys they had
  return fmt::format("{:016x}", h.value());
}

ReferenceResult ground_truth(RtScene& rt, const GBuffer& g, const ReferenceSettings& s) {
  if (s.ao_rays < 1 || s.ao_rays > 65535) fail("reference: ao_rays {} out of range 1..65535", s.ao_rays);
  if (s.samples_per_light < 1 || s.samples_per_light > 65535)
    fail("reference: samples_per_light {} out of range 1..65535", s.samples_per_light);
  const Scene& scene = rt.scene();
  ReferenceResult out;
  out.key = reference_key(scene, g, s, rt.tracer());
  namespace fs = std::filesystem;
  fs::path file;
  if (s.use_cache) {
    const fs::path dir = fs::path(s.cache_dir.empty() ? default_cache_dir() : s.cache_dir) / "reference";
    file = dir / (out.key + ".png");
    out.path = file.string();
    std::error_code ec;
    if (fs::exists(file, ec)) {
      // A damaged file (PNG checks a CRC-32 per chunk and zlib an Adler-32 of the pixels) or one
      // of another size is computed again and replaced.
      std::optional<ImageRGB8> img;
      try {
        img = read_rgb8(file.string());
      } catch (const Error&) {}
      if (img && img->same_size(g.width(), g.height())) {
        out.image = std::move(*img);
        out.from_cache = true;
        return out;
      }
    }
  }

  // Converged estimates: the plan of the scene with soft shadows and S samples per area light.
  TraceSettings ts;
  ts.seed = s.seed;
  ts.soft_shadows = true;
  ts.samples_per_light = 1;  // plan_passes caps S at 1024; the counts path takes any S
  const PassPlan plan = plan_passes(scene, ts);
  std::vector<std::pair<PassMeaning, std::vector<float>>> estimates;
  for (const PassType& t : pass_types())
    if (t.desc(plan, g.width(), g.height()))  // else the scene does not call for it
      estimates.emplace_back(t.meaning, t.converged(rt, g, plan, ts, s, out.stats));
  std::vector<CompositeFractions> passes;
  for (const auto& [meaning, values] : estimates) passes.push_back({meaning, values});
  out.image = composite_fractions(g, scene, passes, s.composite);

  if (s.use_cache) {
    std::error_code ec;
    fs::create_directories(file.parent_path(), ec);
    if (ec) fail("reference: cannot create cache folder {}: {}", file.parent_path().string(), ec.message());
    // Write to a temporary name, then rename: a concurrent reader never sees half a file. The
    // name is this writer's alone (process, a random number per process, a counter), also when
    // processes on several machines share the folder (core/sim/frame_loop.h, TraceCache).
    static const uint64_t process_random = std::random_device{}() | (uint64_t(std::random_device{}()) << 32);
    static std::atomic<uint64_t> counter{0};
    const std::string unique = fmt::format("{}.{:016x}.{}", ::getpid(), process_random, counter++);
    const fs::path tmp = file.parent_path() / fmt::format("{}.tmp{}.png", out.key, unique);
    write_png(tmp.string(), out.image);
    fs::rename(tmp, file, ec);
    if (ec) fail("reference: cannot move {} to {}: {}", tmp.string(), file.string(), ec.message());
    nlohmann::json meta = {{"version", kReferenceVersion},
                           {"scene", scene.name},
                           {"scene_file", scene.source_path},
                           {"scene_hash", fmt::format("{:016x}", scene_content_hash(scene))},
                           {"time_s", g.time_s},
                           {"width", g.width()},
                           {"height", g.height()},
                           {"camera_position", {g.camera.position.x, g.camera.position.y, g.camera.position.z}},
                           {"camera_forward", {g.camera.forward.x, g.camera.forward.y, g.camera.forward.z}},
                           {"ao_rays", s.ao_rays},
                           {"samples_per_light", s.samples_per_light},
                           {"seed", s.seed},
                           {"sampling", sampling_name(s.lattice)},
                           {"exposure", s.composite.exposure},
                           {"tracer", rt.tracer()},
                           {"shadow_rays", out.stats.shadow_rays},
                           {"ao_rays_traced", out.stats.ao_rays}};
    const fs::path meta_file = fs::path(file).replace_extension(".json");
    const fs::path meta_tmp = file.parent_path() / fmt::format("{}.tmp{}.json", out.key, unique);
    std::ofstream(meta_tmp) << meta.dump(2) << "\n";
    fs::rename(meta_tmp, meta_file, ec);
    if (ec) fs::remove(meta_tmp, ec);  // the description is for people; the image is the entry
  }
  return out;
}

ImageRGB8 local_reference(RtScene& rt, const GBuffer& g, const TraceSettings& settings,
                          const CompositeSettings& composite_settings, TraceStats* stats) {
  const TraceResult r = trace_passes(rt, g, settings);
  if (stats) stats->add(r.stats);
  return composite(g, rt.scene(), composite_inputs(r), composite_settings);
}

}  // namespace dhr
