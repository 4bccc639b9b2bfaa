#include "core/pipeline.h"

#include "core/composite.h"
#include "core/error.h"
#include "core/packet.h"
#include "core/raster.h"
#include "core/rt_scene.h"

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

TraceFn direct_tracer(RtScene& rt, const SimConfig& config) {
  return [&rt, &config](uint32_t frame, const GBuffer& gbuf) {
    TraceResult r = trace_passes(rt, gbuf, config.trace_for_frame(frame));
    auto t = std::make_shared<TracedPasses>();
    t->visibility = std::move(r.visibility);
    t->ao = std::move(r.ao);
    t->stats = r.stats;
    return std::shared_ptr<const TracedPasses>(std::move(t));
  };
}

// ---- denoising

DenoiseStage::DenoiseStage(const SimConfig& c, const PassPlan& plan, const Registries& r) {
  if (plan.ao) ao_ = r.denoisers.create(c.ao_denoiser.name, c.ao_denoiser.params);
  if (plan.visibility() && plan.visibility_kind() == PassKind::SoftVisibility)
    for (int l = 0; l < plan.lights; ++l)
      soft_.push_back(r.denoisers.create(c.visibility_denoiser.name, c.visibility_denoiser.params));
}

void DenoiseStage::run(const GBuffer& gbuf, uint32_t frame, PassMeaning meaning, PassBuffer& buf) {
  if (meaning == PassMeaning::Ao && ao_) {
    ImageU8 out;
    const ImageU8 noisy = pass_plane(buf, 0);
    ao_->denoise({gbuf, noisy, buf.desc.full_scale, frame, true}, out);
    buf.bytes.assign(out.pixels().begin(), out.pixels().end());
    buf.desc.full_scale = ao_->output_full_scale(buf.desc.full_scale);
  } else if (meaning == PassMeaning::Visibility && buf.desc.kind == PassKind::SoftVisibility) {
    const int lights = buf.desc.channels;
    if (int(soft_.size()) < lights) fail("denoise: a soft visibility pass of {} lights, planned for {}", lights, soft_.size());
    const size_t n = size_t(buf.desc.width) * size_t(buf.desc.height);
    int scale = buf.desc.full_scale;
    for (int l = 0; l < lights; ++l) {
      ImageU8 out;
      const ImageU8 noisy = pass_plane(buf, l);
      soft_[size_t(l)]->denoise({gbuf, noisy, buf.desc.full_scale, frame, true}, out);
      std::copy(out.pixels().begin(), out.pixels().end(), buf.bytes.begin() + std::ptrdiff_t(size_t(l) * n));
      scale = soft_[size_t(l)]->output_full_scale(buf.desc.full_scale);
    }
    buf.desc.full_scale = scale;
  }
}

bool DenoiseStage::keeps_history() const {
  if (ao_ && ao_->keeps_history()) return true;
  return std::any_of(soft_.begin(), soft_.end(), [](const auto& d) { return d->keeps_history(); });
}

// ---- server

ServerPipeline::ServerPipeline(const SimConfig& c, const Scene& scene, const Registries& r, TraceFn trace,
                               uint16_t stream_id)
    : c_(c), scene_(scene), plan_(plan_passes(scene, c.trace)), traced_(traced_passes(plan_, c.width, c.height)),
      sent_(sent_passes(plan_, c.mode == "remote", c.width, c.height)), trace_(std::move(trace)),
      stream_id_(stream_id), denoise_(c, plan_, r) {
  for (const PlannedPass& p : sent_) {
    const BackendChoice codec = c.choice(p.meaning).codec;
    codecs_.push_back(r.codecs.create(codec.name, codec.params));
    codec_ids_.push_back(codec_id(codec.name));
    sequence_.push_back(0);
  }
  dumps_.resize(sent_.size());
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
    const int height = desc.kind == PassKind::SoftVisibility ? desc.height * desc.channels : desc.height;
    dumps_[pass] = std::make_unique<StreamDump>(
        (std::filesystem::path(c_.dump_streams_dir) / (sent_[pass].name + "." + format)).string(), format, desc.width,
        height, int(std::lround(c_.display_hz)));
  }
  dumps_[pass]->append(encoded, frame);
}

ServerFrame ServerPipeline::run(uint32_t frame, const Camera& camera, double time_s, bool keyframe) {
  ServerFrame out;
  out.frame = frame;
  auto stage = [&](const char* name, double ms) {
    out.stages.push_back({name, ms});
    out.compute_ms += ms;
  };

  auto t0 = Clock::now();
  GBuffer gbuf;
  rasterize({&scene_, camera, time_s, has_prev_ ? prev_camera_ : camera, has_prev_ ? prev_time_s_ : time_s}, gbuf);
  stage("server_rasterize", ms_since(t0));
  has_prev_ = true;
  prev_camera_ = camera;
  prev_time_s_ = time_s;

  const std::shared_ptr<const TracedPasses> traced = trace_(frame, gbuf);
  out.trace = traced->stats;
  if (plan_.visibility()) out.stages.push_back({"trace_shadows", traced->stats.shadow_ms});
  if (plan_.ao) out.stages.push_back({"trace_ao", traced->stats.ao_ms});
  out.compute_ms += traced->stats.shadow_ms + traced->stats.ao_ms;

  std::vector<std::optional<PassBuffer>> buffers;
  t0 = Clock::now();
  for (const PlannedPass& p : traced_) {
    buffers.push_back(traced->of(p.meaning));
    if (buffers.back()) denoise_.run(gbuf, frame, p.meaning, *buffers.back());
  }
  if (!traced_.empty()) stage("denoise", ms_since(t0));

  if (c_.mode == "remote") {
    t0 = Clock::now();
    std::vector<CompositePass> inputs;
    for (size_t i = 0; i < traced_.size(); ++i)
      inputs.push_back({traced_[i].meaning, buffers[i] ? &*buffers[i] : nullptr});
    const ImageRGB8 img = composite(gbuf, scene_, inputs);
    PassBuffer colour;
    colour.desc = sent_[0].desc;
    colour.bytes.resize(colour.desc.byte_size());
    std::memcpy(colour.bytes.data(), img.data(), colour.bytes.size());
    buffers.assign(1, std::move(colour));
    stage("server_composite", ms_since(t0));
  }

  for (size_t i = 0; i < sent_.size(); ++i) {
    if (!buffers[i]) continue;
    const PassBuffer& buf = *buffers[i];
    std::vector<uint8_t> encoded;
    t0 = Clock::now();
    codecs_[i]->encode(buf, {keyframe}, encoded);
    stage("encode", ms_since(t0));
    if (!c_.dump_streams_dir.empty()) dump(i, buf.desc, frame, encoded);
    PacketMeta meta;
    meta.stream_id = stream_id_;
    meta.desc = buf.desc;
    meta.frame_id = frame;
    meta.codec_id = codec_ids_[i];
    meta.first_sequence = sequence_[i];
    SentPass sent{sent_[i].name, buf.desc, encoded.size(), packetize(meta, encoded, c_.max_payload_bytes)};
    sequence_[i] += uint32_t(sent.packets.size());
    out.passes.push_back(std::move(sent));
  }
  return out;
}

// ---- client

ClientPipeline::ClientPipeline(const SimConfig& c, const Scene& scene, const Registries& r)
    : c_(c), scene_(scene), remote_(c.mode == "remote"),
      passes_(sent_passes(plan_passes(scene, c.trace), remote_, c.width, c.height)) {
  for (const PlannedPass& p : passes_) {
    const PassChoice choice = c.choice(p.meaning);
    receivers_.emplace_back();
    receivers_.back().codec = r.codecs.create(choice.codec.name, choice.codec.params);
    predictors_.push_back(r.predictors.create(choice.predictor.name, choice.predictor.params));
  }
}

int ClientPipeline::pass_of(PassKind kind) const { return find_pass(passes_, pass_meaning(kind)); }

void ClientPipeline::keep(int frame, GBuffer gbuf) {
  history_.emplace_back(frame, std::move(gbuf));
  while (int(history_.size()) > c_.history_frames) history_.pop_front();
}

const GBuffer* ClientPipeline::gbuffer(int frame) const {
  for (const auto& [f, g] : history_)
    if (f == frame) return &g;
  return nullptr;
}

ClientFrame ClientPipeline::display(int frame, const GBuffer& gbuf, const std::function<Camera(int)>& camera_of) {
  ClientFrame out;
  out.source_frame.assign(passes_.size(), -1);
  out.disoccluded.assign(passes_.size(), 0);
  out.without_data.assign(passes_.size(), false);
  auto t0 = Clock::now();
  if (remote_) {
    out.image = ImageRGB8(c_.width, c_.height);  // nothing received yet: black
    const PassReceiver& r = receivers_[0];
    if (r.frame >= 0) {
      GBuffer src_cams, dst_cams;  // the remote client knows cameras only
      src_cams.camera = camera_of(r.frame);
      dst_cams.camera = camera_of(frame);
      PassBuffer predicted;
      predictors_[0]->predict({r.buffer, src_cams, dst_cams}, predicted);
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
  std::vector<std::optional<PassBuffer>> predicted(passes_.size());
  for (size_t i = 0; i < passes_.size(); ++i) {
    const PassReceiver& r = receivers_[i];
    const GBuffer* src = r.frame >= 0 ? gbuffer(r.frame) : nullptr;
    if (!src) {
      ++out.passes_without_data;  // the local fallback: fully lit / AO 1
      out.without_data[i] = true;
      continue;
    }
    out.source_frame[i] = r.frame;
    predicted[i] = predict_pass(*predictors_[i], r, *src, gbuf, r.frame == frame, out.disoccluded[i]);
  }
  out.predict_ms = ms_since(t0);
  t0 = Clock::now();
  std::vector<CompositePass> inputs;
  for (size_t i = 0; i < passes_.size(); ++i)
    inputs.push_back({passes_[i].meaning, predicted[i] ? &*predicted[i] : nullptr});
  out.image = composite(gbuf, scene_, inputs);
  out.composite_ms = ms_since(t0);
  out.composited = true;
  return out;
}

// ---- local reference

LocalReference::LocalReference(const SimConfig& c, const Scene& scene, const Registries& r)
    : scene_(scene), plan_(plan_passes(scene, c.trace)), traced_(traced_passes(plan_, c.width, c.height)),
      denoise_(c, plan_, r) {}

std::optional<ImageRGB8> LocalReference::frame(uint32_t frame, const GBuffer& gbuf, const TracedPasses& traced,
                                               bool want_image) {
  std::vector<std::optional<PassBuffer>> buffers;
  for (const PlannedPass& p : traced_) {
    buffers.push_back(traced.of(p.meaning));
    if (buffers.back()) denoise_.run(gbuf, frame, p.meaning, *buffers.back());
  }
  if (!want_image) return std::nullopt;
  std::vector<CompositePass> inputs;
  for (size_t i = 0; i < traced_.size(); ++i) inputs.push_back({traced_[i].meaning, buffers[i] ? &*buffers[i] : nullptr});
  return composite(gbuf, scene_, inputs);
}

}  // namespace dhr
