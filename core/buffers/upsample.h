// Reduced-resolution passes (docs/architecture.md, "Reduced-resolution AO").
// The server may trace the AO pass at 1/s of the width and height (trace.ao_scale = s): low-res
// pixel (X, Y) is the full-res pixel (X s + s/2, Y s + s/2) (clamped to the image), so the
// server traces, denoises and codes a G-buffer of those pixels (downsample_gbuffer), and the
// client, which holds the full-res G-buffer of the frame it receives, upsamples the pass back
// with a filter guided by that G-buffer (upsample_pass): each full-res pixel blends the four
// low-res samples around it with bilinear weights times how well each sample's surface matches
// its own (the distance from its point to the sample's tangent plane, relative to its depth,
// and the angle between their normals). Samples of another surface get no weight, so AO does
// not bleed across silhouettes; a pixel none of whose four samples lies on its surface takes
// the sample nearest its surface.
#pragma once

#include "core/buffers/gbuffer.h"
#include "core/buffers/pass_buffer.h"

#include <string_view>

namespace dhr {

// The size of a side of `full` pixels at 1/scale (rounded up: every full-res pixel has a sample).
inline int reduced_size(int full, int scale) { return (full + scale - 1) / scale; }

// The full-res pixel that low-res pixel `low` of a side of `full` pixels samples.
inline int sample_of(int low, int scale, int full) {
  const int p = low * scale + scale / 2;
  return p < full ? p : full - 1;
}

// The scale s in 1..kMaxPassScale at which a full_w x full_h G-buffer gives a w x h pass, or 0.
inline constexpr int kMaxPassScale = 8;
int pass_scale(int full_w, int full_h, int w, int h);

// The G-buffer of the low-res pixels at 1/scale: every plane sampled at sample_of; the camera
// sized to match; motion in low-res pixels (the sample's previous position, in low-res pixel
// units, less its low-res pixel centre). scale 1: a copy.
GBuffer downsample_gbuffer(const GBuffer& full, int scale);

enum class UpsampleFilter : uint8_t {
  JointBilateral,  // bilinear weights times the surface match (above)
  Bilinear,        // bilinear weights only: AO bleeds across silhouettes
  Nearest,         // the sample of the pixel's own block
};
// "joint_bilateral" | "bilinear" | "nearest"; dhr::Error naming the valid ones otherwise.
UpsampleFilter upsample_filter_of(std::string_view name);
const char* upsample_filter_name(UpsampleFilter filter);

// `low` (8-bit planes, traced at 1/scale of `full`) upsampled to full's size, plane by plane.
// dhr::Error when `low` is not an 8-bit-planes pass of reduced_size(full's size, scale).
// Deterministic, whatever the thread count.
PassBuffer upsample_pass(const PassBuffer& low, const GBuffer& full, int scale, UpsampleFilter filter);

}  // namespace dhr
