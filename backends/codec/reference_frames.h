// What the codecs that predict from a frame the client holds share (delta, delta_video; see
// docs/architecture.md, "Pass coding against what the client holds"): the frames either end
// keeps as references, the little-endian fields of their headers, the check that a decoder
// has the G-buffers a reprojected prediction needs, and the carrying of a reference to this
// frame by the registered predictor, at full or reduced resolution (core/upsample.h).
#pragma once

#include "core/backend.h"

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <utility>

namespace dhr {

void put_u32(uint8_t* p, uint32_t v);
void put_u64(uint8_t* p, uint64_t v);
uint32_t get_u32(const uint8_t* p);
uint64_t get_u64(const uint8_t* p);

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
