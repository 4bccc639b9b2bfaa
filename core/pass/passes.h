// The passes of a run as a list. One table, pass_types(), says which passes the server can
// trace: each entry is a name, a meaning, the plan's say on whether the scene calls for it
// (its description, or none), its kernel and its default backends. Everything else loops
// over that list: tracing (trace_passes), the trace cache, denoising, coding, sending,
// prediction, the composite (by meaning), the settings passes.<name>.{codec,denoiser,predictor},
// live mode's streams and the results' per-pass columns. docs/architecture.md shows how to
// add a pass.
//
// A planned pass is {name, meaning, desc}: the byte layout in `desc` (a bitmask, 8-bit planes,
// RGB) is what codecs and predictors see; the meaning (visibility, ao, colour) is what the
// denoise stage and the composite use.
#pragma once

#include "core/buffers/gbuffer.h"
#include "core/buffers/pass_buffer.h"
#include "core/pass/composite.h"
#include "core/plan/trace_plan.h"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace dhr {

class RtScene;  // core/trace/rt_scene.h: the kernels' scene

struct BackendChoice {
  std::string name;
  nlohmann::json params = nlohmann::json::object();
};

// The backends of one pass: how it is coded, denoised (on the server) and predicted (on the
// client).
struct PassChoice {
  BackendChoice codec, denoiser, predictor;
  // Forward error correction of its packets (core/net/fec.h): parity packets per FEC block, at least
  // fec_min_parity and at least fec_parity x the block's data packets (0 and 0: none).
  double fec_parity = 0.0;
  int fec_min_parity = 0;
};

// One kind of traced pass.
struct PassType {
  const char* name;  // the key of its settings, its results and its live stream: "ao"
  PassMeaning meaning;
  const char* stage;  // its kernel's name in the server's stage times: "trace_ao"
  // Its description in `plan` at width x height, or none when the plan leaves it out.
  std::optional<PassDesc> (*desc)(const PassPlan& plan, int width, int height);
  // The kernel: the pass's buffer for one G-buffer (raw counts; statistics added to `stats`).
  PassBuffer (*trace)(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan, const TraceSettings& settings,
                      TraceStats& stats);
  // The ground truth's estimate of the pass (core/pass/reference.h): converged, as fractions in
  // [0, 1], planar [channel][pixel] at the G-buffer's size; `plan` has soft shadows on.
  std::vector<float> (*converged)(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan, const TraceSettings& settings,
                                  const ReferenceRays& reference, TraceStats& stats);
  const char* codec;      // default backends: passes.<name>.codec
  const char* denoiser;   // passes.<name>.denoiser (8-bit planes only; bitmasks are never denoised)
  const char* predictor;  // passes.<name>.predictor
  const char* doc;        // one line, for `dhrbench settings`
};

// The traced passes, in the order the server traces and sends them.
const std::vector<PassType>& pass_types();
const PassType* find_pass_type(std::string_view name);

// The remote baseline's pass: the composited frame, coded as video.
inline constexpr const char* kColourPassName = "colour";
// The remote baseline's depth, sent with the colour when the client's colour predictor
// reprojects with depth (Predictor::depth_bits: depth_warp); core/buffers/depth_pass.h.
inline constexpr const char* kDepthPassName = "depth";

// Every pass name, traced ones first, then colour and depth: the pass column groups of
// frames.csv and the passes of results.json.
std::vector<std::string> all_pass_names();

struct PlannedPass {
  std::string name;  // the key of its settings and of its results: "visibility", "ao", "colour"
  PassMeaning meaning = PassMeaning::Ao;
  PassDesc desc;  // layout, size, channels and full scale as traced (before denoising)
  PassLayout layout() const { return pass_layout(desc.kind); }
};

// What the server traces for `plan` at width x height, in the order of pass_types().
std::vector<PlannedPass> traced_passes(const PassPlan& plan, int width, int height);

// What the server sends: hybrid mode sends the traced passes; remote mode composites them and
// sends one colour pass, followed by a depth pass of `remote_depth_bits` bits when that is not 0
// (the client's colour predictor reads depth).
std::vector<PlannedPass> sent_passes(const PassPlan& plan, bool remote, int remote_depth_bits, int width, int height);

// The index in `passes` of the pass with `meaning`, or -1.
int find_pass(const std::vector<PlannedPass>& passes, PassMeaning meaning);

// One traced pass of one frame: as traced (raw counts), with its kernel's wall time.
struct TracedPass {
  std::string name;
  PassMeaning meaning = PassMeaning::Ao;
  PassBuffer buffer;
  double ms = 0.0;
};

// The traced passes of one frame with the trace's statistics.
struct TracedPasses {
  std::vector<TracedPass> passes;  // the planned ones, in the order of pass_types()
  TraceStats stats;
  // The buffer of the pass `name`, or null when it was not traced.
  const PassBuffer* find(std::string_view name) const;
  double total_ms() const;
};

// The passes as the composite's inputs (core/pass/composite.h), in their order.
std::vector<CompositePass> composite_inputs(const TracedPasses& traced);

// Everything the plan asks for: every planned pass's kernel, in order. Moves the scene to
// gbuf.time_s. With `only`, the planned pass of that name alone (none when it is not planned):
// each pass's kernel reads the plan and the settings and nothing another pass computes, so the
// passes of a frame traced one at a time and joined by join_traced are the trace of them all,
// bit for bit, statistics included (FrameLoop.PassesTracedAloneAndJoinedAreTheTraceOfAll in
// tests/core/sim/test_frame_loop.cpp). The runner caches each
// pass on its own that way (docs/performance.md).
struct TraceResult : TracedPasses {
  PassPlan plan;
};
TraceResult trace_passes(RtScene& rt, const GBuffer& gbuf, const TraceSettings& settings, std::string_view only = {});
// The same with the plan made once for a run (plan_passes(rt.scene(), settings) of any frame's
// settings: the seed and frame do not change it), so that no frame plans again.
TraceResult trace_passes(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan, const TraceSettings& settings,
                         std::string_view only = {});

// The one-pass traces of one frame (trace_passes with `only`, in the order of pass_types()),
// joined into the trace of all of them: their passes and the statistics trace_passes gives.
TracedPasses join_traced(const std::vector<const TracedPasses*>& parts, const GBuffer& gbuf);

}  // namespace dhr
