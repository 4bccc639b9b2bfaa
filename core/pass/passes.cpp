#include "core/pass/passes.h"

#include "core/base/error.h"
#include "core/buffers/upsample.h"
#include "core/trace/trace.h"

#include <algorithm>
#include <chrono>

namespace dhr {

std::vector<CompositePass> composite_inputs(const TracedPasses& traced) {
  std::vector<CompositePass> inputs;
  for (const TracedPass& p : traced.passes) inputs.push_back({p.meaning, &p.buffer});
  return inputs;
}

namespace {

std::optional<PassDesc> visibility_desc(const PassPlan& plan, int width, int height) {
  if (!plan.visibility()) return std::nullopt;
  return plan.visibility_desc(width, height);
}

std::optional<PassDesc> ao_desc(const PassPlan& plan, int width, int height) {
  if (!plan.ao) return std::nullopt;
  return plan.ao_desc(width, height);
}

}  // namespace

// The table of traced passes. A new pass is one entry here (its kernel in its own file).
const std::vector<PassType>& pass_types() {
  static const std::vector<PassType> types = {
      {"visibility", PassMeaning::Visibility, "trace_shadows", visibility_desc, trace_visibility, converged_visibility,
       "lz4", "none", "reprojection",
       "shadow visibility per light (paper 3.1): a bitmask, or 8-bit fractions with several rays"},
      {"ao", PassMeaning::Ao, "trace_ao", ao_desc, trace_ao, converged_ao, "lz4", "none", "reprojection",
       "ray-traced ambient occlusion (paper 3.2): the count of unoccluded rays in 8 bits"},
  };
  return types;
}

const PassType* find_pass_type(std::string_view name) {
  for (const PassType& t : pass_types())
    if (name == t.name) return &t;
  return nullptr;
}

std::vector<std::string> all_pass_names() {
  std::vector<std::string> names;
  for (const PassType& t : pass_types()) names.push_back(t.name);
  names.push_back(kColourPassName);
  names.push_back(kDepthPassName);
  return names;
}

std::vector<PlannedPass> traced_passes(const PassPlan& plan, int width, int height) {
  std::vector<PlannedPass> passes;
  for (const PassType& t : pass_types())
    if (const std::optional<PassDesc> desc = t.desc(plan, width, height)) passes.push_back({t.name, t.meaning, *desc});
  return passes;
}

std::vector<PlannedPass> sent_passes(const PassPlan& plan, bool remote, int remote_depth_bits, int width, int height) {
  if (!remote) return traced_passes(plan, width, height);
  std::vector<PlannedPass> passes = {{kColourPassName, PassMeaning::Colour, {PassKind::Colour, width, height, 3, 255}}};
  if (remote_depth_bits > 0)
    passes.push_back({kDepthPassName, PassMeaning::Depth, {PassKind::Depth, width, height, 2, remote_depth_bits}});
  return passes;
}

int find_pass(const std::vector<PlannedPass>& passes, PassMeaning meaning) {
  for (size_t i = 0; i < passes.size(); ++i)
    if (passes[i].meaning == meaning) return int(i);
  return -1;
}

const PassBuffer* TracedPasses::find(std::string_view name) const {
  for (const TracedPass& p : passes)
    if (p.name == name) return &p.buffer;
  return nullptr;
}

double TracedPasses::total_ms() const {
  double ms = 0.0;
  for (const TracedPass& p : passes) ms += p.ms;
  return ms;
}

namespace {

bool full_size(const PassBuffer& buffer, const GBuffer& g) {
  return buffer.desc.width == g.width() && buffer.desc.height == g.height();
}

// Adds one pass's statistics to its frame's: pixels and covered pixels are per G-buffer, not per
// pass (the largest covered count of the passes traced at full size), unresolved pixels the
// first pass's.
void add_pass_stats(TraceStats& frame, TraceStats pass, bool first, bool full) {
  if (full) frame.covered_pixels = std::max(frame.covered_pixels, pass.covered_pixels);
  if (!first) pass.unresolved_pixels = 0;
  pass.pixels = pass.covered_pixels = 0;
  frame.add(pass);
}

// A frame whose passes were all traced at reduced size counts its covered pixels on the
// G-buffer, as a full-size trace would.
void count_covered(TraceStats& frame, bool any_reduced, const GBuffer& g) {
  if (any_reduced && frame.covered_pixels == 0)
    for (uint32_t id : g.object_id.pixels()) frame.covered_pixels += id != kBackgroundId ? 1 : 0;
}

}  // namespace

TraceResult trace_passes(RtScene& rt, const GBuffer& g, const TraceSettings& settings, std::string_view only) {
  return trace_passes(rt, g, plan_passes(rt.scene(), settings), settings, only);
}

TraceResult trace_passes(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                         std::string_view only) {
  TraceResult r;
  r.plan = plan;
  r.stats.pixels = uint64_t(g.width()) * uint64_t(g.height());
  bool any_reduced = false;
  std::optional<GBuffer> reduced;  // the sampled G-buffer of a pass traced at reduced resolution
  for (const PassType& t : pass_types()) {
    if (!only.empty() && only != t.name) continue;
    const std::optional<PassDesc> desc = t.desc(r.plan, g.width(), g.height());
    if (!desc) continue;
    TraceStats st;
    const auto t0 = std::chrono::steady_clock::now();
    const bool full = desc->width == g.width() && desc->height == g.height();
    if (!full && (!reduced || reduced->width() != desc->width || reduced->height() != desc->height))
      reduced = downsample_gbuffer(g, pass_scale(g.width(), g.height(), desc->width, desc->height));
    PassBuffer buffer = t.trace(rt, full ? g : *reduced, r.plan, settings, st);
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    any_reduced = any_reduced || !full;
    add_pass_stats(r.stats, st, r.passes.empty(), full);
    r.passes.push_back({t.name, t.meaning, std::move(buffer), ms});
  }
  count_covered(r.stats, any_reduced, g);
  return r;
}

TracedPasses join_traced(const std::vector<const TracedPasses*>& parts, const GBuffer& g) {
  TracedPasses r;
  r.stats.pixels = uint64_t(g.width()) * uint64_t(g.height());
  bool any_reduced = false;
  for (const TracedPasses* part : parts) {
    if (part->passes.size() != 1)
      fail("join_traced: a part holds {} passes (one each: trace_passes with `only`)", part->passes.size());
    const TracedPass& p = part->passes.front();
    const bool full = full_size(p.buffer, g);
    any_reduced = any_reduced || !full;
    // A one-pass trace's statistics are its pass's own (its covered count the pass's when at
    // full size, unused otherwise; its unresolved count the pass's, as the first pass).
    add_pass_stats(r.stats, part->stats, r.passes.empty(), full);
    r.passes.push_back(p);
  }
  count_covered(r.stats, any_reduced, g);
  return r;
}

}  // namespace dhr
