// The reference frames of the predicting codecs: see reference_frames.h.
#include "backends/codec/reference_frames.h"

#include "core/buffers/upsample.h"

#include <algorithm>

namespace dhr {

void put_u32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
void put_u64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = uint8_t(v >> (8 * i));
}
uint32_t get_u32(const uint8_t* p) {
  return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}
uint64_t get_u64(const uint8_t* p) { return uint64_t(get_u32(p)) | uint64_t(get_u32(p + 4)) << 32; }

void put_frame_start(uint8_t* p, const FrameStart& start) {
  p[0] = start.keyframe ? kKeyframeType : kDeltaType;
  put_u32(p + 1, start.index);
  put_u32(p + 5, start.keyframe ? start.index : start.reference);
}

std::string read_frame_start(const std::string& codec, std::span<const uint8_t> in, size_t header_bytes,
                             FrameStart& start) {
  if (in.size() < header_bytes)
    return fmt::format("{}: {} bytes, shorter than the {}-byte header", codec, in.size(), header_bytes);
  const uint8_t type = in[0];
  if (type != kKeyframeType && type != kDeltaType) return fmt::format("{}: unknown frame type {:#04x}", codec, type);
  start = {type == kKeyframeType, get_u32(in.data() + 1), get_u32(in.data() + 5)};
  if (start.keyframe && start.reference != start.index) return codec + ": corrupt keyframe header";
  return {};
}

std::string find_delta_reference(const std::string& codec, const std::deque<Reference>& refs, const FrameStart& start,
                                 const PassDesc& desc, const FrameContext& ctx, bool needs_gbuffer,
                                 const Reference*& ref) {
  if (start.reference >= start.index)
    return fmt::format("{}: frame {} claims to be predicted from the later frame {}", codec, start.index,
                       start.reference);
  ref = find_reference(refs, start.reference, desc);
  if (!ref)
    return fmt::format("{}: frame {} needs frame {}, the decoder holds {}", codec, start.index, start.reference,
                       held_text(refs));
  if (needs_gbuffer)
    if (std::string why = reprojection_context_problem(ctx, start.index, start.reference, desc); !why.empty())
      return codec + ": " + why;
  return {};
}

const Reference* find_reference(const std::deque<Reference>& refs, uint32_t frame, const PassDesc& desc) {
  for (const Reference& r : refs)
    if (r.frame == frame && r.buffer.desc == desc) return &r;
  return nullptr;
}

std::string held_text(const std::deque<Reference>& refs) {
  if (refs.empty()) return "none";
  std::string s;
  for (const Reference& r : refs) s += (s.empty() ? "" : ", ") + std::to_string(r.frame);
  return s;
}

int newest_reference(const std::deque<Reference>& refs) {
  int newest = -1;
  for (const Reference& r : refs) newest = std::max(newest, int(r.frame));
  return newest;
}

void keep_reference(std::deque<Reference>& refs, Reference r, int limit) {
  std::erase_if(refs, [&](const Reference& x) { return x.frame == r.frame; });
  refs.push_back(std::move(r));
  while (int(refs.size()) > limit) refs.pop_front();
}

uint32_t coded_frame_index(const std::string& codec, const PassBuffer& in, const EncodeOptions& options,
                           bool needs_gbuffer, uint32_t next_index, const std::deque<Reference>& coded) {
  if (std::string why = in.desc.validate(); !why.empty()) fail("{}: invalid buffer description: {}", codec, why);
  if (in.bytes.size() != in.desc.byte_size())
    fail("{}: a {}x{} {} buffer holds {} bytes, {} expected", codec, in.desc.width, in.desc.height,
         pass_kind_name(in.desc.kind), in.bytes.size(), in.desc.byte_size());
  const FrameContext& ctx = options.context;
  if (needs_gbuffer && !ctx.gbuf)
    fail("{}: predictor reprojection needs the frame's G-buffer (FrameContext), none was given", codec);
  const uint32_t index = ctx.gbuf ? ctx.frame : next_index;
  if (!coded.empty() && index <= coded.back().frame)
    fail("{}: frame {} coded after frame {} (frames must come in increasing order)", codec, index, coded.back().frame);
  return index;
}

ChosenReference choose_reference(const std::deque<Reference>& coded, const EncodeOptions& options, const PassDesc& desc,
                                 bool keyframe_due, bool needs_gbuffer) {
  ChosenReference c;
  if (options.client_holds >= 0)
    c.ref = find_reference(coded, uint32_t(options.client_holds), desc);
  else if (!options.force_keyframe && !coded.empty())
    c.ref = find_reference(coded, coded.back().frame, desc);
  if (keyframe_due) c.ref = nullptr;
  if (c.ref && needs_gbuffer) {
    const FrameContext& ctx = options.context;
    c.gbuf = ctx.gbuffer_of ? ctx.gbuffer_of(c.ref->frame) : nullptr;
    if (!c.gbuf) c.ref = nullptr;
  }
  return c;
}

std::string reprojection_context_problem(const FrameContext& ctx, uint32_t index, uint32_t reference,
                                         const PassDesc& desc) {
  const GBuffer* ref_gbuf = ctx.gbuffer_of ? ctx.gbuffer_of(reference) : nullptr;
  if (!ctx.gbuf || ctx.frame != index || !ref_gbuf)
    return fmt::format(
        "frame {} is predicted from frame {} by reprojection: the client's G-buffers of both frames "
        "are needed ({} given)",
        index, reference, !ctx.gbuf || ctx.frame != index ? "not this frame's" : "not the reference's");
  if (ref_gbuf->width() != ctx.gbuf->width() || ref_gbuf->height() != ctx.gbuf->height() ||
      pass_scale(ctx.gbuf->width(), ctx.gbuf->height(), desc.width, desc.height) == 0)
    return fmt::format(
        "a {}x{} pass with G-buffers of {}x{} (this frame) and {}x{} (frame {}); both must be the "
        "pass's size, or a multiple of it up to {} (a reduced-resolution pass)",
        desc.width, desc.height, ctx.gbuf->width(), ctx.gbuf->height(), ref_gbuf->width(), ref_gbuf->height(),
        reference, kMaxPassScale);
  return {};
}

PassBuffer& ReferenceCarrier::carry(const Reference& ref, const GBuffer& ref_gbuf, uint32_t frame,
                                    const GBuffer& gbuf) {
  const PassDesc& d = ref.buffer.desc;
  if (d.width == gbuf.width() && d.height == gbuf.height()) {
    predictor_->predict({ref.buffer, ref_gbuf, gbuf}, prediction_);
    return prediction_;
  }
  const int scale = pass_scale(gbuf.width(), gbuf.height(), d.width, d.height);
  if (scale == 0 || ref_gbuf.width() != gbuf.width() || ref_gbuf.height() != gbuf.height())
    fail(
        "{}: a {}x{} pass cannot be reprojected with G-buffers of {}x{} and {}x{} (valid: two G-buffers of one "
        "size, of which the pass is 1/1..1/{} in each side)",
        owner_, d.width, d.height, ref_gbuf.width(), ref_gbuf.height(), gbuf.width(), gbuf.height(), kMaxPassScale);
  const bool kept = sampled_ && sampled_->first == ref.frame && sampled_->second.width() == d.width &&
                    sampled_->second.height() == d.height;
  const GBuffer src = kept ? std::move(sampled_->second) : downsample_gbuffer(ref_gbuf, scale);
  GBuffer dst = downsample_gbuffer(gbuf, scale);
  predictor_->predict({ref.buffer, src, dst}, prediction_);
  sampled_.emplace(frame, std::move(dst));
  return prediction_;
}

}  // namespace dhr
