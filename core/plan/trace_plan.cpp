#include "core/plan/trace_plan.h"

#include "core/base/error.h"
#include "core/buffers/upsample.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace dhr {

const char* shadow_mode_name(ShadowMode mode) {
  switch (mode) {
    case ShadowMode::None: return "none";
    case ShadowMode::Hard: return "hard";
    case ShadowMode::SoftBit: return "soft_bit";
    case ShadowMode::SoftFraction: return "soft_fraction";
  }
  return "unknown";
}

int PassPlan::visibility_full_scale() const {
  return shadow == ShadowMode::SoftFraction ? std::min(samples_per_light, 255) : 1;
}

PassDesc PassPlan::visibility_desc(int width, int height) const {
  PassDesc d;
  d.kind = visibility_kind();
  d.width = width;
  d.height = height;
  d.channels = lights;
  d.full_scale = shadow == ShadowMode::SoftFraction ? visibility_full_scale() : 255;
  return d;
}

PassDesc PassPlan::ao_desc(int width, int height) const {
  PassDesc d;
  d.kind = PassKind::Ao;
  d.width = reduced_size(width, ao_scale);
  d.height = reduced_size(height, ao_scale);
  d.channels = 1;
  d.full_scale = ao_rays;
  return d;
}

std::string PassPlan::describe() const {
  std::string s;
  for (const auto& r : reasons) {
    if (!s.empty()) s += "; ";
    s += r;
  }
  return s;
}

void TraceStats::add(const TraceStats& o) {
  pixels += o.pixels;
  covered_pixels += o.covered_pixels;
  shadow_rays += o.shadow_rays;
  ao_rays += o.ao_rays;
  invalid_rays += o.invalid_rays;
  unresolved_pixels += o.unresolved_pixels;
  shadow_skipped_facing += o.shadow_skipped_facing;
  shadow_skipped_range += o.shadow_skipped_range;
  shadow_inside_light += o.shadow_inside_light;
}

PassPlan plan_passes(const Scene& scene, const TraceSettings& s) {
  if (s.ao_rays < 0 || s.ao_rays > 255)
    fail("trace settings: ao_rays {} out of range 1..255 (0 = the scene's)", s.ao_rays);
  if (!(s.ao_radius_m >= 0.0f) || !std::isfinite(s.ao_radius_m))
    fail("trace settings: ao_radius_m {} must be finite and > 0 (0 = the scene's)", s.ao_radius_m);
  if (s.samples_per_light < 1 || s.samples_per_light > 1024)
    fail("trace settings: samples_per_light {} out of range 1..1024", s.samples_per_light);
  if (s.threads < 0) fail("trace settings: threads {} must be >= 0 (0 = the scene's arena)", s.threads);
  if (scene.lights.size() > 64)
    fail("scene '{}': {} lights, at most 64 are supported", scene.name, scene.lights.size());

  PassPlan plan;
  plan.lights = int(scene.lights.size());
  if (scene.lights.empty()) {
    plan.reasons.push_back("no lights: no visibility pass");
  } else if (!s.visibility_pass) {
    plan.reasons.push_back("visibility pass switched off by the run's settings");
  } else {
    bool any_area = false;
    for (const Light& l : scene.lights) {
      const bool soft = s.soft_shadows && !l.is_point();
      plan.light_soft.push_back(soft ? 1 : 0);
      any_area = any_area || !l.is_point();
    }
    if (!any_area) {
      plan.shadow = ShadowMode::Hard;
      plan.samples_per_light = 1;
      plan.reasons.push_back(fmt::format("{} point light(s) only: hard shadows, one ray per light", plan.lights));
    } else if (!s.soft_shadows) {
      plan.shadow = ShadowMode::Hard;
      plan.samples_per_light = 1;
      plan.reasons.push_back("soft shadows off: hard shadows, one ray to each light's centre");
    } else if (s.samples_per_light == 1) {
      plan.shadow = ShadowMode::SoftBit;
      plan.samples_per_light = 1;
      plan.reasons.push_back("area light(s): soft shadows, one jittered ray per light (bitmask)");
    } else {
      plan.shadow = ShadowMode::SoftFraction;
      plan.samples_per_light = s.samples_per_light;
      plan.reasons.push_back(
          fmt::format("area light(s): soft shadows, {} rays per light (8-bit fraction)", s.samples_per_light));
    }
    if (s.visibility_fraction && plan.shadow != ShadowMode::SoftFraction) {
      plan.shadow = ShadowMode::SoftFraction;  // one ray per light, sent as 8 bits (0 or 1 of 1)
      plan.reasons.push_back("visibility_fraction: 8 bits per light (0 or 1 of 1 ray) for a denoiser or a lossy codec");
    }
  }
  if (!scene.ao) {
    plan.reasons.push_back("no ao block: no AO pass");
  } else if (!s.ao_pass) {
    plan.reasons.push_back("AO pass switched off by the run's settings");
  } else {
    plan.ao = true;
    plan.ao_rays = s.ao_rays > 0 ? s.ao_rays : scene.ao->rays;
    plan.ao_radius_m = s.ao_radius_m > 0.0f ? s.ao_radius_m : scene.ao->radius_m;
    if (plan.ao_rays < 1 || plan.ao_rays > 255)
      fail("scene '{}': ao.rays {} out of range 1..255", scene.name, plan.ao_rays);
    if (!(plan.ao_radius_m > 0.0f) || !std::isfinite(plan.ao_radius_m))
      fail("scene '{}': ao.radius_m {} must be finite and > 0", scene.name, plan.ao_radius_m);
    if (s.ao_scale < 1 || s.ao_scale > kMaxPassScale)
      fail("trace.ao_scale {} out of range 1..{}", s.ao_scale, kMaxPassScale);
    plan.ao_scale = s.ao_scale;
    plan.reasons.push_back(fmt::format("ao: {} rays, radius {} m", plan.ao_rays, plan.ao_radius_m) +
                           (s.ao_scale > 1 ? fmt::format(", at 1/{} resolution", s.ao_scale) : std::string()));
  }
  return plan;
}

}  // namespace dhr
