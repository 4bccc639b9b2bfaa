#include "core/buffers/upsample.h"

#include "core/base/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace dhr {

int pass_scale(int full_w, int full_h, int w, int h) {
  for (int s = 1; s <= kMaxPassScale; ++s)
    if (reduced_size(full_w, s) == w && reduced_size(full_h, s) == h) return s;
  return 0;
}

GBuffer downsample_gbuffer(const GBuffer& full, int scale) {
  if (scale < 1 || scale > kMaxPassScale) fail("downsample_gbuffer: scale {} out of range 1..{}", scale, kMaxPassScale);
  if (scale == 1) return full;
  const int fw = full.width(), fh = full.height();
  const int w = reduced_size(fw, scale), h = reduced_size(fh, scale);
  GBuffer g;
  g.camera = full.camera;
  g.camera.width = w;
  g.camera.height = h;
  g.time_s = full.time_s;
  g.resize(w, h);
  const float inv = 1.0f / float(scale);
  for (int y = 0; y < h; ++y) {
    const int sy = sample_of(y, scale, fh);
    for (int x = 0; x < w; ++x) {
      const int sx = sample_of(x, scale, fw);
      g.depth(x, y) = full.depth(sx, sy);
      g.position(x, y) = full.position(sx, sy);
      g.normal(x, y) = full.normal(sx, sy);
      g.geo_normal(x, y) = full.geo_normal(sx, sy);
      g.albedo(x, y) = full.albedo(sx, sy);
      g.object_id(x, y) = full.object_id(sx, sy);
      g.prim_id(x, y) = full.prim_id(sx, sy);
      g.bary(x, y) = full.bary(sx, sy);
      // Low-res coordinates put sample (x, y) at its pixel centre: full = (u - 0.5) s + s/2 + 0.5.
      const glm::vec2 m = full.motion(sx, sy);
      g.motion(x, y) = {(float(sx - x * scale - scale / 2) + m.x) * inv,
                        (float(sy - y * scale - scale / 2) + m.y) * inv};
    }
  }
  return g;
}

UpsampleFilter upsample_filter_of(std::string_view name) {
  if (name == "joint_bilateral") return UpsampleFilter::JointBilateral;
  if (name == "bilinear") return UpsampleFilter::Bilinear;
  if (name == "nearest") return UpsampleFilter::Nearest;
  fail("upsample filter '{}': valid are joint_bilateral, bilinear, nearest", name);
}

const char* upsample_filter_name(UpsampleFilter filter) {
  switch (filter) {
    case UpsampleFilter::JointBilateral: return "joint_bilateral";
    case UpsampleFilter::Bilinear: return "bilinear";
    case UpsampleFilter::Nearest: return "nearest";
  }
  return "?";
}

namespace {

// The two low-res samples around full-res coordinate `x` on a side of `w` samples, and the
// bilinear weight of the second. Sample X sits at full-res pixel centre X s + s/2 + 0.5.
struct Span {
  int a, b;
  float f;
};
Span span_of(int x, int scale, int w) {
  const float u = float(x - scale / 2) / float(scale);
  int a = int(std::floor(u));
  float f = u - float(a);
  if (a < 0) {
    a = 0;
    f = 0.0f;
  }
  if (a >= w - 1) {
    a = w - 1;
    f = 0.0f;
  }
  return {a, std::min(a + 1, w - 1), f};
}

// How well sample q's surface matches pixel p's, in 0..1: the farther of the two points from the
// other's tangent plane against sigma, and the angle between the normals.
float surface_match(const glm::vec3& pp, const glm::vec3& np, const glm::vec3& pq, const glm::vec3& nq, float sigma) {
  const glm::vec3 d = pp - pq;
  const float plane = std::max(std::fabs(glm::dot(nq, d)), std::fabs(glm::dot(np, d))) / sigma;
  const float c = std::max(0.0f, glm::dot(np, nq));
  const float c2 = c * c, c4 = c2 * c2, c8 = c4 * c4;
  return std::exp(-plane * plane) * c8 * c8;
}

}  // namespace

PassBuffer upsample_pass(const PassBuffer& low, const GBuffer& full, int scale, UpsampleFilter filter) {
  const int fw = full.width(), fh = full.height();
  if (scale < 1 || scale > kMaxPassScale) fail("upsample_pass: scale {} out of range 1..{}", scale, kMaxPassScale);
  const int w = reduced_size(fw, scale), h = reduced_size(fh, scale);
  if (low.desc.layout() != PassLayout::Planes8)
    fail("upsample_pass: a {} pass; only 8-bit planes (AO, soft visibility) are upsampled",
         pass_kind_name(low.desc.kind));
  if (low.desc.width != w || low.desc.height != h || low.bytes.size() != low.desc.byte_size())
    fail("upsample_pass: a {}x{} pass of {} bytes, {}x{} expected for {}x{} at 1/{}", low.desc.width, low.desc.height,
         low.bytes.size(), w, h, fw, fh, scale);
  PassBuffer out;
  out.desc = low.desc;
  out.desc.width = fw;
  out.desc.height = fh;
  if (scale == 1) {
    out.bytes = low.bytes;
    return out;
  }
  out.bytes.resize(out.desc.byte_size());
  const int channels = low.desc.channels;
  const size_t low_plane = size_t(w) * size_t(h), full_plane = size_t(fw) * size_t(fh);
  // A pixel's footprint at depth 1 (metres per pixel); sigma is the sample spacing at its depth.
  const float footprint = 2.0f * std::tan(glm::radians(full.camera.vfov_deg) * 0.5f) / float(fh);
  tbb::parallel_for(tbb::blocked_range<int>(0, fh), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      const Span sy = span_of(y, scale, h);
      for (int x = 0; x < fw; ++x) {
        const size_t o = size_t(y) * size_t(fw) + size_t(x);
        if (filter == UpsampleFilter::Nearest || !full.covered(x, y)) {  // the sample of its own block
          const int nx = std::min(x / scale, w - 1), ny = std::min(y / scale, h - 1);
          for (int c = 0; c < channels; ++c)
            out.bytes[size_t(c) * full_plane + o] =
                low.bytes[size_t(c) * low_plane + size_t(ny) * size_t(w) + size_t(nx)];
          continue;
        }
        const Span sx = span_of(x, scale, w);
        const int qx[4] = {sx.a, sx.b, sx.a, sx.b}, qy[4] = {sy.a, sy.a, sy.b, sy.b};
        float wt[4] = {(1 - sx.f) * (1 - sy.f), sx.f * (1 - sy.f), (1 - sx.f) * sy.f, sx.f * sy.f};
        if (filter == UpsampleFilter::JointBilateral) {
          const glm::vec3 pp = full.position(x, y), np = full.normal(x, y);
          const float sigma = footprint * full.depth(x, y) * float(scale);
          float match[4], sum = 0.0f;
          int best = 0;
          for (int k = 0; k < 4; ++k) {
            const int gx = sample_of(qx[k], scale, fw), gy = sample_of(qy[k], scale, fh);
            match[k] =
                full.covered(gx, gy) ? surface_match(pp, np, full.position(gx, gy), full.normal(gx, gy), sigma) : 0.0f;
            wt[k] *= match[k];
            sum += wt[k];
            if (match[k] > match[best]) best = k;
          }
          if (!(sum > 1e-6f))  // no sample of this surface around it: the one that matches best
            for (int k = 0; k < 4; ++k) wt[k] = k == best ? 1.0f : 0.0f;
        }
        float sum = 0.0f;
        for (float v : wt) sum += v;
        for (int c = 0; c < channels; ++c) {
          const uint8_t* plane = low.bytes.data() + size_t(c) * low_plane;
          float v = 0.0f;
          for (int k = 0; k < 4; ++k) v += wt[k] * float(plane[size_t(qy[k]) * size_t(w) + size_t(qx[k])]);
          out.bytes[size_t(c) * full_plane + o] = uint8_t(std::clamp(std::floor(v / sum + 0.5f), 0.0f, 255.0f));
        }
      }
    }
  });
  return out;
}

}  // namespace dhr
