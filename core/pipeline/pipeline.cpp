#include "core/pipeline/pipeline.h"

#include "core/base/error.h"
#include "core/buffers/depth_pass.h"
#include "core/buffers/upsample.h"
#include "core/net/fec.h"
#include "core/net/packet.h"
#include "core/pass/composite.h"
#include "core/raster/raster.h"
#include "core/trace/rt_scene.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <span>

namespace dhr {

namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

}  // namespace

TraceFn direct_tracer(RtScene& rt, const RunPlan& plan) {
  return [&rt, &plan](uint32_t frame, const GBuffer& gbuf) {
    TraceResult r = trace_passes(rt, gbuf, plan.passes, plan.config.trace_for_frame(frame));
    return std::make_shared<const TracedPasses>(std::move(static_cast<TracedPasses&>(r)));
  };
}

// ---- reduced resolution

int reduced_scale(const GBuffer& gbuf, const PassDesc& desc) {
  const int s = pass_scale(gbuf.width(), gbuf.height(), desc.width, desc.height);
  if (s == 0)
    fail("a {}x{} {} pass is no reduced resolution of the {}x{} G-buffer (1/1..1/{})", desc.width, desc.height,
         pass_kind_name(desc.kind), gbuf.width(), gbuf.height(), kMaxPassScale);
  return s;
}

namespace {

// Whether `buffer` was traced at reduced resolution for `gbuf`'s frame.
bool is_reduced(const PassBuffer& buffer, const GBuffer& gbuf) {
  return buffer.desc.width != gbuf.width() || buffer.desc.height != gbuf.height();
}

// A pass traced at reduced resolution for `gbuf`'s frame, upsampled to its size with `filter`
// (core/buffers/upsample.h).
PassBuffer upsampled(const PassBuffer& buffer, const GBuffer& gbuf, UpsampleFilter filter) {
  return upsample_pass(buffer, gbuf, reduced_scale(gbuf, buffer.desc), filter);
}

}  // namespace

// ---- denoising

DenoiseStage::DenoiseStage(const RunPlan& plan, const Registries& r) {
  for (const PlannedPass& p : plan.traced) {
    planes_.emplace_back();
    names_.push_back(p.name);
    if (p.layout() != PassLayout::Planes8) continue;
    const BackendChoice& denoiser = plan.choice(p).denoiser;
    for (int plane = 0; plane < p.desc.channels; ++plane)
      planes_.back().push_back(r.denoisers.create(denoiser.name, denoiser.params));
  }
  chains_.resize(planes_.size());
}

void DenoiseStage::share(DenoiseSharing sharing) {
  if (!sharing.memo || !sharing.raster || !sharing.trace || sharing.pass_keys.size() != planes_.size())
    fail("internal: DenoiseStage::share needs a memo, a raster and a trace function and a key per traced pass");
  sharing_ = std::move(sharing);
  for (size_t i = 0; i < planes_.size(); ++i) {
    // Only temporal denoisers are shared: a per-frame filter costs what a copy from the memo does.
    const bool temporal =
        std::any_of(planes_[i].begin(), planes_[i].end(), [](const auto& d) { return d->keeps_history(); });
    chains_[i].reset();
    if (temporal && !sharing_.pass_keys[i].empty()) {
      chains_[i].emplace();
      chains_[i]->base = sharing_.pass_keys[i];
    }
  }
}

// The frames fed so far, as ranges ("0-11,13-33"): with the base, all a shared pass's next output
// depends on. A frame's G-buffer takes its motion from the frame fed before it (the first frame's:
// from itself); one that takes it from another time is written with that time ("12@0x1.2p+0").
std::string DenoiseStage::Chain::open_range() const {
  return first == last ? std::to_string(first) : std::to_string(first) + "-" + std::to_string(last);
}

std::string DenoiseStage::Chain::key() const { return base + "|fed=" + closed + (first >= 0 ? open_range() : ""); }

void DenoiseStage::Chain::append(uint32_t frame, const RasterFrame& raster) {
  const bool fed = first >= 0 || !closed.empty();
  const bool usual = raster.prev_time_s == (fed ? last_time_s : raster.time_s);
  last_time_s = raster.time_s;
  if (usual && first >= 0 && int64_t(frame) == last + 1) {
    last = frame;
    return;
  }
  if (first >= 0) closed += open_range() + ",";
  first = last = -1;
  if (usual)
    first = last = frame;
  else
    closed += fmt::format("{}@{:a},", frame, raster.prev_time_s);
}

void DenoiseStage::feed(const GBuffer& gbuf, uint32_t frame, size_t pass, PassBuffer& buf) {
  const auto& denoisers = planes_.at(pass);
  if (buf.desc.layout() != PassLayout::Planes8 || size_t(buf.desc.channels) != denoisers.size())
    fail("denoise: a {} pass of {} planes, planned for {}", pass_kind_name(buf.desc.kind), buf.desc.channels,
         denoisers.size());
  const size_t n = size_t(buf.desc.width) * size_t(buf.desc.height);
  // A pass traced at reduced resolution is denoised with the G-buffer of its samples.
  std::optional<GBuffer> reduced;
  if (is_reduced(buf, gbuf)) reduced = downsample_gbuffer(gbuf, reduced_scale(gbuf, buf.desc));
  int scale = buf.desc.full_scale;
  for (size_t plane = 0; plane < denoisers.size(); ++plane) {
    ImageU8 out;
    const ImageU8 noisy = pass_plane(buf, int(plane));
    denoisers[plane]->denoise({reduced ? *reduced : gbuf, noisy, buf.desc.full_scale, frame, true}, out);
    std::copy(out.pixels().begin(), out.pixels().end(), buf.bytes.begin() + std::ptrdiff_t(plane * n));
    scale = denoisers[plane]->output_full_scale(buf.desc.full_scale);
  }
  buf.desc.full_scale = scale;
}

// Feeds a shared pass's denoisers the frames it took from the memo, in order: their state is
// then what computing every frame would have left (their outputs, the memo's, are dropped).
void DenoiseStage::catch_up(size_t pass) {
  Chain& chain = *chains_[pass];
  for (const Skipped& s : chain.skipped) {
    const Rastered r = sharing_.raster(s.raster);
    const std::shared_ptr<const TracedPasses> traced = sharing_.trace(s.frame, *r.gbuf);
    const PassBuffer* b = traced->find(names_[pass]);
    if (!b) fail("internal: frame {} has no traced {} pass to feed its denoiser again", s.frame, names_[pass]);
    PassBuffer copy = *b;
    feed(*r.gbuf, s.frame, pass, copy);
  }
  chain.skipped.clear();
}

double DenoiseStage::run(const RasterFrame& raster, const GBuffer& gbuf, uint32_t frame, size_t pass,
                         const PassBuffer& traced, PassBuffer& out) {
  if (planes_.at(pass).empty()) {
    out = traced;
    return 0.0;
  }
  std::optional<Chain>& chain = chains_[pass];
  std::string key;
  if (chain) {
    chain->append(frame, raster);
    key = chain->key();
    std::shared_ptr<const DenoisedPass> hit = sharing_.memo->find(key);
    std::shared_ptr<void> claim;
    if (!hit) {  // a run beside this one may be making it: look again once this caller holds the key
      claim = sharing_.memo->claim(key);
      hit = sharing_.memo->find(key);
    }
    if (hit) {
      out = hit->buffer;
      chain->skipped.push_back({frame, raster});
      return hit->ms;
    }
    catch_up(pass);
  }
  out = traced;
  const auto t0 = Clock::now();
  feed(gbuf, frame, pass, out);
  const double ms = ms_since(t0);
  if (chain) sharing_.memo->insert(key, std::make_shared<const DenoisedPass>(DenoisedPass{out, ms}));
  return ms;
}

bool DenoiseStage::keeps_history() const {
  for (const auto& pass : planes_)
    for (const auto& d : pass)
      if (d->keeps_history()) return true;
  return false;
}

namespace {

// Frame `frame`'s traced passes in the order of `traced` (null where one was not traced),
// denoised by `denoise`; `ms`: the denoisers' wall time (DenoiseStage::run).
std::vector<std::optional<PassBuffer>> denoised(DenoiseStage& denoise, const std::vector<PlannedPass>& traced,
                                                const TracedPasses& passes, const RasterFrame& raster,
                                                const GBuffer& gbuf, uint32_t frame, double& ms) {
  std::vector<std::optional<PassBuffer>> buffers;
  ms = 0.0;
  for (size_t i = 0; i < traced.size(); ++i) {
    const PassBuffer* b = passes.find(traced[i].name);
    buffers.emplace_back();
    if (b) ms += denoise.run(raster, gbuf, frame, i, *b, buffers.back().emplace());
  }
  return buffers;
}

std::vector<CompositePass> composite_inputs(const std::vector<PlannedPass>& passes,
                                            const std::vector<std::optional<PassBuffer>>& buffers) {
  std::vector<CompositePass> inputs;
  for (size_t i = 0; i < passes.size(); ++i) inputs.push_back({passes[i].meaning, buffers[i] ? &*buffers[i] : nullptr});
  return inputs;
}

// The composite of `buffers` (the traced passes of `gbuf`'s frame), those at reduced
// resolution upsampled first.
ImageRGB8 composite_traced(const GBuffer& gbuf, const Scene& scene, const std::vector<PlannedPass>& traced,
                           std::vector<std::optional<PassBuffer>> buffers, UpsampleFilter filter) {
  for (auto& b : buffers)
    if (b && is_reduced(*b, gbuf)) b = upsampled(*b, gbuf, filter);
  return composite(gbuf, scene, composite_inputs(traced, buffers));
}

}  // namespace

// ---- server

Rastered rasterize_now(const RasterFrame& frame) {
  const auto t0 = Clock::now();
  auto g = std::make_shared<GBuffer>();
  rasterize(frame, *g);
  return {std::move(g), ms_since(t0)};
}

ServerPipeline::ServerPipeline(const RunPlan& plan, const Registries& r, TraceFn trace, uint16_t stream_id,
                               RasterFn raster)
    : plan_(plan),
      c_(plan.config),
      trace_(std::move(trace)),
      raster_(raster ? std::move(raster) : RasterFn(rasterize_now)),
      stream_id_(stream_id),
      denoise_(plan, r) {
  for (const PlannedPass& p : plan_.sent) {
    const BackendChoice& codec = plan_.choice(p).codec;
    codecs_.push_back(r.codecs.create(codec.name, codec.params));
    codec_ids_.push_back(codec_id(codec.name));
    sequence_.push_back(0);
    gbuffers_kept_ = std::max(gbuffers_kept_, codecs_.back()->gbuffers_referenced());
  }
  dumps_.resize(plan_.sent.size());
  depth_pass_ = find_pass(plan_.sent, PassMeaning::Depth);
  // (plan_run made sure one takes the budget when there is one.)
  for (const auto& codec : codecs_) budgeted_.push_back(c_.stream_kbps > 0.0 && codec->takes_target_kbps());
  stream_kbps_ = c_.stream_kbps;
}

// The bit budget's share of each budgeted pass (kbit/s): the budget per frame at display_hz,
// less what the other passes used per frame over the last second and the budgeted passes' own
// packet overhead, split evenly; at least 1 % of the budget.
double ServerPipeline::budget_share_kbps() const {
  const double frame_bytes = stream_kbps_ * 1000.0 / 8.0 / c_.display_hz;
  double others = 0.0;
  int shares = 0;
  for (size_t i = 0; i < plan_.sent.size(); ++i) shares += budgeted_[i] ? 1 : 0;
  for (const std::vector<size_t>& frame : wire_history_)
    for (size_t i = 0; i < frame.size(); ++i) others += double(frame[i]);
  if (!wire_history_.empty()) others /= double(wire_history_.size());
  const double share_bytes = (frame_bytes - others) / double(std::max(shares, 1));
  return std::max(0.01 * stream_kbps_, share_bytes * 8.0 * c_.display_hz / 1000.0);
}

// --dump-streams: the pass's encoded frames as <dir>/<pass>.<format>, for a codec whose frames
// make a standard stream (others write nothing).
void ServerPipeline::dump(size_t pass, const PassDesc& desc, uint32_t frame, std::span<const uint8_t> encoded) {
  const std::string format = codecs_[pass]->stream_format();
  if (format.empty()) return;
  if (!dumps_[pass]) {
    std::error_code ec;
    std::filesystem::create_directories(c_.dump_streams_dir, ec);
    if (ec) fail("--dump-streams: cannot create {}: {}", c_.dump_streams_dir, ec.message());
    const int height = desc.layout() == PassLayout::Planes8 ? desc.height * desc.channels : desc.height;
    dumps_[pass] = std::make_unique<StreamDump>(
        (std::filesystem::path(c_.dump_streams_dir) / (plan_.sent[pass].name + "." + format)).string(), format,
        desc.width, height, int(std::lround(c_.display_hz)));
  }
  dumps_[pass]->append(encoded, frame);
}

ServerFrame ServerPipeline::run(uint32_t frame, const Camera& camera, double time_s, bool keyframe,
                                std::span<const int> client_holds) {
  ServerFrame out;
  out.frame = frame;
  auto stage = [&](const char* name, double ms) {
    out.stages.push_back({name, ms});
    out.compute_ms += ms;
  };

  const RasterFrame raster{plan_.scene, camera, time_s, has_prev_ ? prev_camera_ : camera,
                           has_prev_ ? prev_time_s_ : time_s};
  Rastered rastered = raster_(raster);
  std::shared_ptr<const GBuffer> kept = std::move(rastered.gbuf);
  const GBuffer& gbuf = *kept;
  stage("server_rasterize", rastered.ms);
  has_prev_ = true;
  prev_camera_ = camera;
  prev_time_s_ = time_s;

  const std::shared_ptr<const TracedPasses> traced = trace_(frame, gbuf);
  out.trace = traced->stats;
  for (const TracedPass& p : traced->passes) stage(find_pass_type(p.name)->stage, p.ms);

  double denoise_ms = 0.0;
  std::vector<std::optional<PassBuffer>> buffers =
      denoised(denoise_, plan_.traced, *traced, raster, gbuf, frame, denoise_ms);
  if (!plan_.traced.empty()) stage("denoise", denoise_ms);

  // Remote: the denoised passes become the colour pass (and the depth pass beside it).
  auto t0 = Clock::now();
  if (plan_.server_does(ServerStage::Composite)) {
    const ImageRGB8 img =
        composite_traced(gbuf, *plan_.scene, plan_.traced, std::move(buffers), upsample_filter_of(c_.ao_upsample));
    PassBuffer colour;
    colour.desc = plan_.sent[0].desc;
    colour.bytes.resize(colour.desc.byte_size());
    std::memcpy(colour.bytes.data(), img.data(), colour.bytes.size());
    buffers.assign(1, std::move(colour));
    stage("server_composite", ms_since(t0));
  }
  if (plan_.server_does(ServerStage::PackDepth)) {  // for a client that reprojects with depth
    t0 = Clock::now();
    buffers.resize(plan_.sent.size());
    buffers[size_t(depth_pass_)] = pack_depth(gbuf.depth, camera, plan_.sent[size_t(depth_pass_)].desc.full_scale);
    stage("pack_depth", ms_since(t0));
  }

  EncodeOptions options;
  options.force_keyframe = keyframe;
  options.context = {frame, &gbuf, [this](uint32_t f) -> const GBuffer* {
                       for (const auto& [kept_frame, g] : gbuffers_)
                         if (kept_frame == f) return g.get();
                       return nullptr;
                     }};
  const double share_kbps = c_.stream_kbps > 0.0 ? budget_share_kbps() : 0.0;
  std::vector<size_t> wire(plan_.sent.size(), 0);  // this frame's: other passes whole, budgeted passes' overhead
  for (size_t i = 0; i < plan_.sent.size(); ++i) {
    if (!buffers[i]) continue;
    const PassBuffer& buf = *buffers[i];
    std::vector<uint8_t> encoded;
    options.client_holds = i < client_holds.size() ? client_holds[i] : -1;
    options.target_kbps = budgeted_[i] ? share_kbps : 0.0;
    t0 = Clock::now();
    codecs_[i]->encode(buf, options, encoded);
    stage("encode", ms_since(t0));
    if (!c_.dump_streams_dir.empty()) dump(i, buf.desc, frame, encoded);
    PacketMeta meta;
    meta.stream_id = stream_id_;
    meta.desc = buf.desc;
    meta.frame_id = frame;
    meta.codec_id = codec_ids_[i];
    meta.first_sequence = sequence_[i];
    const PassChoice& choice = plan_.choice(plan_.sent[i]);
    const int parity = fec_parity_count(int(packet_count(encoded.size(), c_.max_payload_bytes)), choice.fec_parity,
                                        choice.fec_min_parity);
    SentPass sent{plan_.sent[i].name, buf.desc, encoded.size(), packetize(meta, encoded, c_.max_payload_bytes, parity)};
    sequence_[i] += uint32_t(sent.packets.size());
    for (const auto& packet : sent.packets) wire[i] += packet.size() + kIpUdpOverheadBytes;
    if (budgeted_[i]) wire[i] -= sent.encoded_bytes;
    out.passes.push_back(std::move(sent));
  }
  if (c_.stream_kbps > 0.0) {
    wire_history_.push_back(std::move(wire));
    while (double(wire_history_.size()) > std::max(1.0, std::round(c_.display_hz))) wire_history_.pop_front();
  }
  if (gbuffers_kept_ > 0) {
    gbuffers_.emplace_back(frame, std::move(kept));
    while (int(gbuffers_.size()) > gbuffers_kept_) gbuffers_.pop_front();
  }
  return out;
}

// ---- client

ClientPipeline::ClientPipeline(const RunPlan& plan, const Registries& r)
    : plan_(plan), c_(plan.config), filter_(upsample_filter_of(c_.ao_upsample)) {
  depth_pass_ = find_pass(plan_.sent, PassMeaning::Depth);
  upsampled_.assign(plan_.sent.size(), {-1, PassBuffer{}});
  for (const PlannedPass& p : plan_.sent) {
    const PassChoice& choice = plan_.choice(p);
    receivers_.emplace_back();
    receivers_.back().codec = r.codecs.create(choice.codec.name, choice.codec.params);
    predictors_.push_back(r.predictors.create(choice.predictor.name, choice.predictor.params));
  }
}

bool ClientPipeline::upsamples() const { return plan_.client_does(ClientStage::Upsample); }

int ClientPipeline::pass_of(PassKind kind) const { return find_pass(plan_.sent, pass_meaning(kind)); }

PassReceiver::Outcome ClientPipeline::receive(int pass, AssembledFrame& frame) {
  const FrameContext context{frame.meta.frame_id, gbuffer(int(frame.meta.frame_id)),
                             [this](uint32_t f) { return gbuffer(int(f)); }};
  PassReceiver& r = receivers_[size_t(pass)];
  // A frame of another layout than the pass's plan (a damaged or foreign sender) is refused
  // before it reaches the decoder: the stages after it rely on the planned size.
  const PassDesc& planned = plan_.sent[size_t(pass)].desc;
  const PassDesc& got = frame.meta.desc;
  if (got.kind != planned.kind || got.width != planned.width || got.height != planned.height ||
      got.channels != planned.channels) {
    PassReceiver::Outcome refused;
    refused.decode_error = true;
    return refused;
  }
  PassReceiver::Outcome o = r.on_frame(frame, context);
  // A frame held for recovery is of use only while this client still keeps its G-buffer (a
  // codec that predicts through G-buffers needs it again): else ask for a keyframe.
  if (o.holds >= 0 && r.codec->gbuffers_referenced() > 0 && !gbuffer(o.holds)) {
    r.codec->reset();
    o.holds = -1;
  }
  return o;
}

void ClientPipeline::keep(int frame, std::shared_ptr<const GBuffer> gbuf) {
  history_.emplace_back(frame, std::move(gbuf));
  while (int(history_.size()) > c_.history_frames) history_.pop_front();
}

const GBuffer* ClientPipeline::gbuffer(int frame) const {
  for (const auto& [f, g] : history_)
    if (f == frame) return g.get();
  return nullptr;
}

ClientFrame ClientPipeline::display(int frame, const GBuffer& gbuf,
                                    const std::function<Camera(int)>& source_camera_of) {
  ClientFrame out;
  const size_t passes = plan_.sent.size();
  out.source_frame.assign(passes, -1);
  out.disoccluded.assign(passes, 0);
  out.without_data.assign(passes, false);
  auto t0 = Clock::now();
  if (!plan_.client_does(ClientStage::Composite)) {  // remote: the colour frame, warped
    out.image = ImageRGB8(c_.width, c_.height);      // nothing received yet: black
    const PassReceiver& r = receivers_[0];
    if (r.frame >= 0) {
      // The remote client knows cameras only (and the depth it received).
      const bool has_depth = depth_pass_ >= 0 && receivers_[size_t(depth_pass_)].frame == r.frame;
      if (r.frame != remote_src_frame_ || has_depth != remote_src_has_depth_) {
        remote_src_.camera = source_camera_of(r.frame);
        remote_src_.depth =
            has_depth ? unpack_depth(receivers_[size_t(depth_pass_)].buffer, remote_src_.camera) : ImageF();
        remote_src_frame_ = r.frame;
        remote_src_has_depth_ = has_depth;
      }
      GBuffer dst_cams;
      dst_cams.camera = gbuf.camera;
      PassBuffer predicted;
      predictors_[0]->predict({r.buffer, remote_src_, dst_cams}, predicted);
      std::memcpy(out.image.data(), predicted.bytes.data(),
                  std::min(predicted.bytes.size(), out.image.size() * sizeof(Rgb8)));
      out.source_frame[0] = r.frame;
    } else {
      ++out.passes_without_data;
      out.without_data[0] = true;
    }
    out.predict_ms = ms_since(t0);
    return out;
  }
  std::vector<std::optional<PassBuffer>> predicted(passes);
  std::vector<const PassBuffer*> to_predict(passes, nullptr);  // and the G-buffer it was made for:
  std::vector<const GBuffer*> sources(passes, nullptr);
  for (size_t i = 0; i < passes; ++i) {
    const PassReceiver& r = receivers_[i];
    const GBuffer* src = r.frame >= 0 ? gbuffer(r.frame) : nullptr;
    if (!src) {
      ++out.passes_without_data;  // the local fallback: fully lit / AO 1
      out.without_data[i] = true;
      continue;
    }
    out.source_frame[i] = r.frame;
    // A pass traced at reduced resolution is upsampled with the G-buffer it was traced for,
    // once per received frame.
    const PassBuffer* buffer = &r.buffer;
    if (is_reduced(r.buffer, *src)) {
      auto& [full_frame, full] = upsampled_[i];
      if (full_frame != r.frame) {
        const auto t_up = Clock::now();
        full = upsampled(r.buffer, *src, filter_);
        full_frame = r.frame;
        out.upsample_ms += ms_since(t_up);
      }
      buffer = &full;
    }
    // This very frame's buffer is shown as it is (reprojection onto the same camera is the
    // identity only up to rounding); the others are predicted below.
    if (r.frame == frame) {
      predicted[i] = *buffer;
    } else {
      to_predict[i] = buffer;
      sources[i] = src;
    }
  }
  // Passes received for the same frame whose predictors have the same settings and predict
  // together (Predictor::predicts_passes_together) go through one call: the shared work once.
  for (size_t i = 0; i < passes; ++i) {
    if (!to_predict[i]) continue;
    const BackendChoice& choice = plan_.choice(plan_.sent[i]).predictor;
    const bool together = predictors_[i]->predicts_passes_together();
    std::vector<size_t> group{i};
    for (size_t k = i + 1; k < passes && together; ++k) {
      const BackendChoice& other = plan_.choice(plan_.sent[k]).predictor;
      if (to_predict[k] && receivers_[k].frame == receivers_[i].frame && other.name == choice.name &&
          other.params == choice.params)
        group.push_back(k);
    }
    std::vector<const PassBuffer*> received;
    std::vector<PassBuffer*> outputs;
    for (size_t k : group) {
      received.push_back(to_predict[k]);
      outputs.push_back(&predicted[k].emplace());
      to_predict[k] = nullptr;
    }
    const std::vector<PredictStats> stats = predictors_[i]->predict_passes(*sources[i], gbuf, received, outputs);
    for (size_t g = 0; g < group.size(); ++g) out.disoccluded[group[g]] = stats[g].disoccluded;
  }
  out.predict_ms = ms_since(t0) - out.upsample_ms;
  t0 = Clock::now();
  out.image = composite(gbuf, *plan_.scene, composite_inputs(plan_.sent, predicted));
  out.composite_ms = ms_since(t0);
  out.composited = true;
  return out;
}

// ---- local reference

LocalReference::LocalReference(const RunPlan& plan, const Registries& r)
    : plan_(plan), denoise_(plan, r), filter_(upsample_filter_of(plan.config.ao_upsample)) {}

std::optional<ImageRGB8> LocalReference::frame(uint32_t frame, const RasterFrame& raster, const GBuffer& gbuf,
                                               const TracedPasses& traced, bool want_image) {
  double ms = 0.0;
  std::vector<std::optional<PassBuffer>> buffers = denoised(denoise_, plan_.traced, traced, raster, gbuf, frame, ms);
  if (!want_image) return std::nullopt;
  return composite_traced(gbuf, *plan_.scene, plan_.traced, std::move(buffers), filter_);
}

}  // namespace dhr
