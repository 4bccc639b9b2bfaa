// What the codecs that predict from a frame the client holds share (delta, delta_video; see
// docs/architecture.md, "Pass coding against what the client holds"): the frames either end
// keeps as references, the little-endian fields of their headers, the check that a decoder
// has the G-buffers a reprojected prediction needs, and the carrying of a reference to this
// frame by the registered predictor, at full or reduced resolution (core/buffers/upsample.h).
#pragma once

#include "core/backend/backend.h"

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <utility>

namespace dhr {

void put_u32(uint8_t* p, uint32_t v);
void put_u64(uint8_t* p, uint64_t v);
uint32_t get_u32(const uint8_t* p);
uint64_t get_u64(const uint8_t* p);

// Every frame of a predicting codec starts with its type, its index and the index of the frame
// it was predicted from (uint32 little-endian each; a keyframe names itself).
constexpr uint8_t kKeyframeType = 'K', kDeltaType = 'D';
constexpr size_t kFrameStartBytes = 9;
struct FrameStart {
  bool keyframe = true;
  uint32_t index = 0, reference = 0;
};
void put_frame_start(uint8_t* p, const FrameStart& start);

// One frame either end keeps as a reference.
struct Reference {
  uint32_t frame = 0;
  PassBuffer buffer;
};

// The kept reference of `frame` with this buffer description, or null.
const Reference* find_reference(const std::deque<Reference>& refs, uint32_t frame, const PassDesc& desc);
// "3, 4, 5" (the frames kept), or "none": for error messages.
std::string held_text(const std::deque<Reference>& refs);
// The newest frame kept (-1: none): Codec::holds().
int newest_reference(const std::deque<Reference>& refs);
// Keeps `r` as the newest reference, at most `limit` of them; a frame index seen again (a
// resent or reordered frame) replaces the older entry.
void keep_reference(std::deque<Reference>& refs, Reference r, int limit);

// The index an encoder codes `in` under: the context's frame when it has a G-buffer, else
// `next_index` (a count of coded frames). Throws dhr::Error, prefixed with `codec`, on a buffer
// that does not match its description, a missing G-buffer when `needs_gbuffer`, or a frame not
// after the last one coded.
uint32_t coded_frame_index(const std::string& codec, const PassBuffer& in, const EncodeOptions& options,
                           bool needs_gbuffer, uint32_t next_index, const std::deque<Reference>& coded);

// What an encoder predicts the frame from: the frame the client reported holding after a loss
// (EncodeOptions::client_holds), else the newest coded frame; none (a keyframe) when one is due
// or forced, or the frame is no longer kept, or (`needs_gbuffer`) its G-buffer is not.
struct ChosenReference {
  const Reference* ref = nullptr;
  const GBuffer* gbuf = nullptr;  // the reference frame's G-buffer (with needs_gbuffer)
};
ChosenReference choose_reference(const std::deque<Reference>& coded, const EncodeOptions& options, const PassDesc& desc,
                                 bool keyframe_due, bool needs_gbuffer);

// Reads the frame start of `in`, a frame whose whole header is `header_bytes` long. Empty when
// it is whole and consistent; else the error, prefixed with `codec`.
std::string read_frame_start(const std::string& codec, std::span<const uint8_t> in, size_t header_bytes,
                             FrameStart& start);
// A delta frame's reference among the decoder's `refs` and, with `needs_gbuffer`, the check that
// the context holds both frames' G-buffers (reprojection_context_problem). Empty with `ref` set,
// or the error, prefixed with `codec`.
std::string find_delta_reference(const std::string& codec, const std::deque<Reference>& refs, const FrameStart& start,
                                 const PassDesc& desc, const FrameContext& ctx, bool needs_gbuffer,
                                 const Reference*& ref);

// Empty when a decoder of a `desc` pass, frame `index` predicted by reprojection from frame
// `reference`, has both frames' G-buffers in `ctx` at a size the pass can be predicted on (the
// pass's own, or a multiple of it up to kMaxPassScale); else what is missing, for the error.
std::string reprojection_context_problem(const FrameContext& ctx, uint32_t index, uint32_t reference,
                                         const PassDesc& desc);

// Carries a reference frame to a later frame through both frames' G-buffers with a registered
// predictor, as the client's display does. A pass traced at reduced resolution is carried
// between the G-buffers of its samples (downsample_gbuffer), which both ends derive alike from
// their full-resolution ones; the sampled G-buffer of the frame last carried to is kept, since
// the next frame is usually predicted from it.
class ReferenceCarrier {
 public:
  // `owner` (the codec's name) prefixes error messages.
  ReferenceCarrier(std::string owner, std::unique_ptr<Predictor> predictor)
      : owner_(std::move(owner)), predictor_(std::move(predictor)) {}
  // The reference carried to frame `frame` (the caller may edit it; valid until the next call).
  // Throws dhr::Error when the G-buffers' sizes do not fit the pass.
  PassBuffer& carry(const Reference& ref, const GBuffer& ref_gbuf, uint32_t frame, const GBuffer& gbuf);
  void reset() { sampled_.reset(); }

 private:
  std::string owner_;
  std::unique_ptr<Predictor> predictor_;
  PassBuffer prediction_;
  std::optional<std::pair<uint32_t, GBuffer>> sampled_;
};

}  // namespace dhr
