#include "core/config/cache_keys.h"

#include <fmt/format.h>

namespace dhr {

namespace {

// Every traced setting of the run: the first part of the local reference's key.
std::string trace_key(const std::string& scene_key, const SimConfig& c, int frame) {
  return fmt::format("trace{}|{}|f{}|{}", kTraceCacheVersion, scene_key, frame, settings_key(c, kInTraceKey));
}

}  // namespace

SimConfig keyed_config(const SimConfig& config, const Scene& scene) {
  SimConfig k = config;
  // The AO rays and radius plan_passes resolves (the AO pass on, so that a run that switches it
  // off is keyed the same way).
  TraceSettings with_ao = config.trace;
  with_ao.ao_pass = true;
  if (const PassPlan plan = plan_passes(scene, with_ao); plan.ao) {
    k.trace.ao_rays = plan.ao_rays;
    k.trace.ao_radius_m = plan.ao_radius_m;
  }
  return k;
}

bool scores_frame(const SimConfig& c, int frame) { return frame % c.score_every == 0; }
bool scores_ground_truth(const SimConfig& c, int frame) {
  return scores_frame(c, frame) && c.ground_truth_every > 0 && frame % c.ground_truth_every == 0;
}

CacheKeys CacheKeys::of(const RunPlan& plan, std::string scene_key) {
  return of(plan.config, *plan.scene, std::move(scene_key));
}

CacheKeys CacheKeys::of(const SimConfig& config, const Scene& scene, std::string scene_key) {
  return {std::move(scene_key), keyed_config(config, scene)};
}

std::string CacheKeys::pass_trace(int frame, std::string_view pass) const {
  return fmt::format("trace{}|{}|f{}|pass={}|{}", kTraceCacheVersion, scene_key, frame, pass,
                     pass_settings_key(keyed, pass));
}

std::string CacheKeys::local_reference(int frame) const {
  std::string denoisers;
  for (const PassType& t : pass_types()) {
    const BackendChoice& d = keyed.pass(t.name).denoiser;
    denoisers += fmt::format("|{}={}:{}", t.name, d.name, d.params.dump());
  }
  const std::string upsample = keyed.trace.ao_scale > 1 ? "|upsample=" + keyed.ao_upsample : "";
  return fmt::format("local|{}{}{}", trace_key(scene_key, keyed, frame), denoisers, upsample);
}

std::string CacheKeys::denoise_chain(std::string_view pass) const {
  const BackendChoice& d = keyed.pass(pass).denoiser;
  return fmt::format("denoise{}|{}|pass={}|{}|denoiser={}:{}", kTraceCacheVersion, scene_key, pass,
                     pass_settings_key(keyed, pass), d.name, d.params.dump());
}

std::string CacheKeys::truth(int frame) const {
  return fmt::format("truth|{}|f{}|{}", scene_key, frame, settings_key(keyed, kInTruthKey));
}

std::vector<std::string> CacheKeys::flip_references() const {
  std::vector<std::string> keys;
  if (keyed.score_every <= 0) return keys;  // not validated yet
  for (int a = keyed.warmup_frames; a < keyed.warmup_frames + keyed.frames; ++a) {
    const int frame = a - keyed.warmup_frames;
    if (!scores_frame(keyed, frame)) continue;
    keys.push_back(local_reference(a));
    if (scores_ground_truth(keyed, frame)) keys.push_back(truth(a));
  }
  return keys;
}

}  // namespace dhr
