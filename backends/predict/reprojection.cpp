// reprojection: carries a lighting pass computed for an older client frame j to the frame k
// being displayed, through the client's own G-buffers of both frames (DHR-S paper, section
// 4.1, Fig. 5 against Fig. 6: each lighting pass is predicted for the current frame, so late
// buffers still land on the right surfaces). The validity tests (object id, depth, normal)
// are the reprojection tests of SVGF's temporal accumulation (Schied et al. 2017, section
// 4.1), which the paper's modified SVGF uses too (section 3.3).
//
// Method, per pixel of dst (frame k):
// - Background (object id kBackgroundId): fully lit (every light's bit, soft = full_scale,
//   AO = full_scale): nothing there is shaded, and it is not counted.
// - Covered: its world point P = dst.position is projected through src.camera (frame j's
//   camera) to the image point q and the view depth z. This is exact for static geometry under
//   any camera motion and any age j < k, the main case. For an object that moved between j
//   and k it is an approximation: q is where P's world position was seen in frame j, not
//   where the object's surface point was; the id/depth/normal tests then usually reject the
//   sample (another object or surface is there: a disocclusion, filled) or accept a nearby
//   part of the same object. Motion vectors are not used: dst.motion points to the frame
//   right before k, and the predictor is not told whether j = k - 1.
// - The 2x2 source taps around q (bilinear footprint, pixel centres at x + 0.5) are tested
//   against P: same object id; depth agreement, |d| <= depth_tolerance * z where d is P's
//   distance from the tap's surface plane (its world position and geometric normal; that is
//   the tap's depth extrapolated to q along its own surface, so a grazing surface does not
//   fail for a sub-pixel offset the way a plain |z_tap - z| test does; a tap without a usable
//   geometric normal falls back to |src.depth - z| <= depth_tolerance * z); normal
//   agreement, dot(n_src, n_dst) >= normal_threshold (shading normals). A tap with zero
//   bilinear weight or outside the image does not take part.
// - Visibility bitmasks take the valid tap of largest bilinear weight (the nearest valid one;
//   bits cannot be interpolated). SoftVisibility and Ao take the same tap (filter = nearest)
//   or the bilinear mean of the valid taps, renormalised and rounded (filter = bilinear).
// - No valid tap, q off-screen or behind the src camera, or a covered dst pixel with
//   non-finite data: a disocclusion (counted), filled by `fill`:
//     nearest_valid: the valid source pixel (same tests) nearest to q within a square window
//       of fill_radius_px; the local fallback when there is none;
//     local: the local fallback, fully lit (all bits set / soft = full_scale, AO = full_scale).
// Colour buffers are refused (the hybrid client never receives colour; the remote baseline
// uses rotation_warp). Sizes of received, src and dst must agree. Rows run in parallel with
// TBB; every pixel is computed on its own, so the result is bit-identical at any thread count.
//
// Parameters: filter (nearest|bilinear, default bilinear), fill (nearest_valid|local, default
// nearest_valid), fill_radius_px (1..16, default 3), depth_tolerance (0.0001..1, default
// 0.02), normal_threshold (-1..1, default 0.9).
// Example: {"name": "reprojection", "params": {"filter": "nearest", "fill": "local"}}
#include "backends/predict/warp.h"

#include <algorithm>
#include <cstring>
#include <span>
#include <vector>

namespace dhr {
namespace {

constexpr const char* kName = "reprojection";

struct ReprojectionSettings {
  bool bilinear = true;
  bool fill_nearest_valid = true;
  int fill_radius_px = 3;
  float depth_tolerance = 0.02f;
  float normal_threshold = 0.9f;
};

void check_gbuffer(const char* which, const GBuffer& g) {
  const int w = g.width(), h = g.height();
  if (!g.position.same_size(w, h) || !g.normal.same_size(w, h) || !g.geo_normal.same_size(w, h) ||
      !g.object_id.same_size(w, h))
    fail("predictor '{}': the {} G-buffer's planes differ in size (depth {}x{}, position {}x{}, normal {}x{}, "
         "geo_normal {}x{}, object_id {}x{})",
         kName, which, w, h, g.position.width(), g.position.height(), g.normal.width(), g.normal.height(),
         g.geo_normal.width(), g.geo_normal.height(), g.object_id.width(), g.object_id.height());
  predict::check_camera(kName, which, g.camera);
  if (g.camera.width != w || g.camera.height != h)
    fail("predictor '{}': the {} G-buffer is {}x{} but its camera is {}x{} (they must agree)", kName, which, w, h,
         g.camera.width, g.camera.height);
}

// The source side of one dst pixel for the passes that blend (8-bit, filter bilinear): the valid
// taps with their renormalised weights, in tap order.
struct Taps {
  uint32_t index[4] = {0, 0, 0, 0};
  float weight[4] = {0, 0, 0, 0};
  int count = 0;
};

// One pass of those predicted together: where it reads and writes, and how.
struct PassIo {
  const uint8_t* in = nullptr;
  uint8_t* out = nullptr;
  bool bitmask = false;
  bool nearest = false;  // takes the valid tap of largest weight (bitmasks always; 8-bit with filter nearest)
  int bpp = 1;           // bitmask: bytes per pixel
  uint8_t lit[8] = {};   // bitmask: every light's bit
  predict::Layout8 lay;  // 8-bit
  uint8_t full = 255;    // 8-bit: full_scale
};

class Reprojection final : public Predictor {
 public:
  explicit Reprojection(const ReprojectionSettings& s) : s_(s) {}

  PredictStats predict(const PredictInput& in, PassBuffer& out) override {
    const PassBuffer* received[1] = {&in.received};
    PassBuffer* outs[1] = {&out};
    return predict_passes(in.src, in.dst, received, outs)[0];
  }

  // The taps, their tests and the fill depend on the G-buffers only: found once per pixel for
  // every pass, each pass then reads them its own way.
  bool predicts_passes_together() const override { return true; }

  std::vector<PredictStats> predict_passes(const GBuffer& src, const GBuffer& dst,
                                           std::span<const PassBuffer* const> received,
                                           std::span<PassBuffer* const> out) override {
    check_gbuffer("src", src);
    check_gbuffer("dst", dst);
    const int w = dst.width(), h = dst.height();
    std::vector<PassBuffer> temps(received.size());
    std::vector<PassBuffer*> results;
    std::vector<PassIo> io;
    for (size_t k = 0; k < received.size(); ++k) {
      const PassBuffer& rb = *received[k];
      predict::check_buffer(kName, rb);
      if (rb.desc.layout() == PassLayout::Rgb8)
        fail("predictor '{}' refuses a colour buffer: it reprojects the hybrid client's lighting passes "
             "(visibility, soft_visibility, ao) through G-buffers; the remote-rendering baseline's colour "
             "frame is warped by 'rotation_warp'",
             kName);
      if (rb.desc.width != src.width() || rb.desc.height != src.height() || src.width() != w || src.height() != h)
        fail("predictor '{}': sizes differ: received buffer {}x{}, src G-buffer {}x{}, dst G-buffer {}x{} (all "
             "three must agree)",
             kName, rb.desc.width, rb.desc.height, src.width(), src.height(), w, h);
      PassBuffer& result = predict::output_buffer(rb, *out[k], temps[k], w, h);
      results.push_back(&result);
      PassIo p;
      p.in = rb.bytes.data();
      p.out = result.bytes.data();
      p.bitmask = rb.desc.layout() == PassLayout::Bitmask;
      p.nearest = p.bitmask || !s_.bilinear;
      if (p.bitmask) {
        p.bpp = (rb.desc.channels + 7) / 8;
        const uint64_t lit_bits = predict::fully_lit_bits(rb.desc.channels);
        for (int b = 0; b < 8; ++b) p.lit[b] = uint8_t(lit_bits >> (8 * b));
      } else {
        p.lay = predict::layout8(rb.desc);
        p.full = uint8_t(rb.desc.full_scale);
      }
      io.push_back(p);
    }

    std::vector<uint32_t> covered(size_t(h), 0), disoccluded(size_t(h), 0);
    run(src, dst, io, covered, disoccluded);

    PredictStats stats;
    for (int y = 0; y < h; ++y) {
      stats.pixels += covered[size_t(y)];
      stats.disoccluded += disoccluded[size_t(y)];
    }
    for (size_t k = 0; k < received.size(); ++k)
      if (results[k] == &temps[k]) *out[k] = std::move(temps[k]);
    return std::vector<PredictStats>(received.size(), stats);
  }

 private:
  void run(const GBuffer& src, const GBuffer& dst, const std::vector<PassIo>& io, std::vector<uint32_t>& covered,
           std::vector<uint32_t>& disoccluded) const {
    const int w = dst.width(), h = dst.height();
    const predict::Projector proj(src.camera);
    const ReprojectionSettings s = s_;

    const uint32_t* sid = src.object_id.data();
    const glm::vec3* spos = src.position.data();
    const glm::vec3* snrm = src.normal.data();
    const glm::vec3* sgeo = src.geo_normal.data();
    const float* sdep = src.depth.data();

    // The tests of one source tap j against the dst surface point (P, normal nd with squared
    // length ln, view depth z in src, object id). Squared forms of
    //   dot(ns, nd) / (|ns| |nd|) >= normal_threshold   and   |dot(P - Ps, g)| / |g| <= tol z
    // (no square roots in the inner loop); written so that any NaN fails them.
    const float thr = s.normal_threshold, thr2_ = thr * thr, tol = s.depth_tolerance, tol2 = tol * tol;
    const bool thr_nonneg = thr >= 0.0f;
    auto valid_tap = [=](size_t j, const glm::vec3& p, const glm::vec3& nd, float ln, float z, uint32_t id) {
      if (sid[j] != id) return false;
      const glm::vec3 ns = snrm[j];
      const float ls = glm::dot(ns, ns);
      if (!(ls >= 0.25f && ls <= 4.0f)) return false;
      const float d = glm::dot(ns, nd), bound = thr2_ * ls * ln;
      if (!(thr_nonneg ? (d >= 0.0f && d * d >= bound) : (d >= 0.0f || d * d <= bound))) return false;
      const glm::vec3 g = sgeo[j];
      const float lg = glm::dot(g, g);
      if (lg >= 0.25f && lg <= 4.0f) {
        const float e = glm::dot(p - spos[j], g);
        return e * e <= tol2 * z * z * lg;
      }
      return std::fabs(sdep[j] - z) <= tol * z;
    };

    // Whether any pass takes the nearest tap, any the bilinear mean (then all four taps are tested).
    bool any_nearest = false, any_bilinear = false;
    for (const PassIo& p : io) (p.nearest ? any_nearest : any_bilinear) = true;

    auto write_lit = [&](size_t i) {
      for (const PassIo& p : io) {
        if (p.bitmask) {
          if (p.bpp == 1)  // up to 8 lights: one byte, no call
            p.out[i] = p.lit[0];
          else
            std::memcpy(p.out + i * size_t(p.bpp), p.lit, size_t(p.bpp));
        } else {
          for (int c = 0; c < p.lay.planes; ++c) p.out[i + size_t(c) * p.lay.plane_stride] = p.full;
        }
      }
    };
    auto write_tap = [](const PassIo& p, size_t i, size_t j) {
      if (p.bitmask) {
        if (p.bpp == 1)
          p.out[i] = p.in[j];
        else
          std::memcpy(p.out + i * size_t(p.bpp), p.in + j * size_t(p.bpp), size_t(p.bpp));
      } else {
        for (int c = 0; c < p.lay.planes; ++c) p.out[i + size_t(c) * p.lay.plane_stride] = p.in[j + size_t(c) * p.lay.plane_stride];
      }
    };

    const float fw = float(w), fh = float(h);
    const int radius = s.fill_radius_px;
    predict::parallel_rows(h, [&](int y) {
      uint32_t row_covered = 0, row_disoccluded = 0;
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * size_t(w) + size_t(x);
        const uint32_t id = dst.object_id[i];
        if (id == kBackgroundId) {
          write_lit(i);
          continue;
        }
        ++row_covered;
        const glm::vec3 p = dst.position[i];
        const glm::vec3 nd = dst.normal[i];
        const float ln = glm::dot(nd, nd);
        Taps t;                // the bilinear passes' taps
        int64_t nearest = -1;  // the nearest passes' tap
        float qx = 0.0f, qy = 0.0f, z = 0.0f;
        bool projected = false;
        if (predict::finite3(p) && ln >= 0.25f && ln <= 4.0f) {
          const glm::vec3 q = proj.project(p);
          qx = q.x;
          qy = q.y;
          z = q.z;
          // Inside the image rectangle and in front of the camera (NaN fails every test).
          projected = z > 0.0f && std::isfinite(z) && std::isfinite(qx) && std::isfinite(qy);
          if (projected && qx >= 0.0f && qx < fw && qy >= 0.0f && qy < fh) {
            const float u = qx - 0.5f, v = qy - 0.5f;
            const float x0f = std::floor(u), y0f = std::floor(v);
            const float ax = u - x0f, ay = v - y0f;
            const int x0 = int(x0f), y0 = int(y0f);
            const float bw[4] = {(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay};
            // Tap k's index when it lies in the image, has weight and passes the tests; else -1.
            auto tap = [&](int k) -> int64_t {
              const int tx = x0 + (k & 1), ty = y0 + (k >> 1);
              if (!(bw[k] > 0.0f) || tx < 0 || ty < 0 || tx >= w || ty >= h) return -1;
              const size_t j = size_t(ty) * size_t(w) + size_t(tx);
              return valid_tap(j, p, nd, ln, z, id) ? int64_t(j) : -1;
            };
            // The nearest: the valid tap of largest weight, ties in tap order. The nearest tap
            // (largest weight) is tried first: it passes almost always, and the common path
            // then has no data-dependent branch. `valid(k)`: tap k's index or -1.
            const int kn = int(ax > 0.5f) | (int(ay > 0.5f) << 1);
            auto nearest_of = [&](auto&& valid) {
              int64_t j = valid(kn);
              if (j < 0) {
                int order[4] = {0, 1, 2, 3};  // stable insertion sort by decreasing weight
                for (int a = 1; a < 4; ++a) {
                  const int k = order[a];
                  int b = a;
                  for (; b > 0 && bw[order[b - 1]] < bw[k]; --b) order[b] = order[b - 1];
                  order[b] = k;
                }
                for (int r = 0; r < 4 && j < 0; ++r)
                  if (order[r] != kn) j = valid(order[r]);
              }
              return j;
            };
            if (!any_bilinear) {
              nearest = nearest_of(tap);
            } else {
              int64_t taps[4];
              float sum = 0.0f;
              for (int k = 0; k < 4; ++k) {
                taps[k] = tap(k);
                if (taps[k] >= 0) sum += bw[k];
              }
              // Each weight divided as it is stored: dividing the stored weights afterwards
              // compiled to one vector load of the four scalar stores just made, a
              // store-forwarding stall that was a tenth of the pass (perf, bench_predict).
              for (int k = 0; k < 4; ++k) {
                if (taps[k] < 0) continue;
                t.index[t.count] = uint32_t(taps[k]);
                t.weight[t.count] = bw[k] / sum;
                ++t.count;
              }
              if (any_nearest) nearest = nearest_of([&](int k) { return taps[k]; });
            }
          }
        }
        if (any_bilinear ? t.count == 0 : nearest < 0) {  // no valid tap (the same for every pass)
          ++row_disoccluded;
          bool filled = false;
          if (s.fill_nearest_valid && projected && qx > -float(radius + 1) && qx < fw + float(radius + 1) &&
              qy > -float(radius + 1) && qy < fh + float(radius + 1)) {
            // Nearest valid source pixel in the window, by distance from q to its centre;
            // ties keep the first in scan order.
            const int cx = int(std::floor(qx)), cy = int(std::floor(qy));
            float best_d2 = INFINITY;
            size_t best = 0;
            for (int ty = std::max(0, cy - radius); ty <= std::min(h - 1, cy + radius); ++ty)
              for (int tx = std::max(0, cx - radius); tx <= std::min(w - 1, cx + radius); ++tx) {
                const float dx = float(tx) + 0.5f - qx, dy = float(ty) + 0.5f - qy;
                const float d2 = dx * dx + dy * dy;
                if (d2 >= best_d2) continue;
                const size_t j = size_t(ty) * size_t(w) + size_t(tx);
                if (!valid_tap(j, p, nd, ln, z, id)) continue;
                best_d2 = d2;
                best = j;
              }
            if (best_d2 < INFINITY) {
              for (const PassIo& io_pass : io) write_tap(io_pass, i, best);
              filled = true;
            }
          }
          if (!filled) write_lit(i);
          continue;
        }
        for (const PassIo& pass : io) {
          if (pass.nearest) {
            write_tap(pass, i, size_t(nearest));
          } else if (t.count == 1) {
            write_tap(pass, i, t.index[0]);
          } else {
            for (int c = 0; c < pass.lay.planes; ++c) {
              const uint8_t* plane = pass.in + size_t(c) * pass.lay.plane_stride;
              float v = 0.0f;
              for (int k = 0; k < t.count; ++k) v += t.weight[k] * float(plane[t.index[k]]);
              pass.out[i + size_t(c) * pass.lay.plane_stride] = predict::round_u8(v);
            }
          }
        }
      }
      covered[size_t(y)] = row_covered;
      disoccluded[size_t(y)] = row_disoccluded;
    });
  }

  ReprojectionSettings s_;
};

}  // namespace

PredictorEntry make_reprojection_predictor() {
  return {kName,
          "reproject the received lighting pass through the client's G-buffers (world position to the "
          "old camera; id/depth/normal tests; disocclusions filled)",
          {ParamSpec::choice("filter", "bilinear", {"nearest", "bilinear"},
                             "8-bit passes (soft_visibility, ao): nearest valid tap, or bilinear mean of the valid "
                             "taps (visibility bitmasks are always nearest: bits cannot be interpolated)"),
           ParamSpec::choice("fill", "nearest_valid", {"nearest_valid", "local"},
                             "disocclusions: nearest valid source pixel within fill_radius_px (else local), or "
                             "local: fully lit / AO = full_scale"),
           ParamSpec::integer("fill_radius_px", 3, 1, 16,
                              "fill = nearest_valid: half-size of the square search window around the projected "
                              "point, in pixels"),
           ParamSpec::real("depth_tolerance", 0.02, 0.0001, 1.0,
                           "a tap is valid when the dst surface point lies within tolerance x view depth of the "
                           "tap's surface plane"),
           ParamSpec::real("normal_threshold", 0.9, -1.0, 1.0,
                           "a tap is valid when dot(n_src, n_dst) >= threshold")},
          [](const Params& p) {
            ReprojectionSettings s;
            s.bilinear = p.get_string("filter") == "bilinear";
            s.fill_nearest_valid = p.get_string("fill") == "nearest_valid";
            s.fill_radius_px = p.get_int("fill_radius_px");
            s.depth_tolerance = float(p.get_float("depth_tolerance"));
            s.normal_threshold = float(p.get_float("normal_threshold"));
            return std::make_unique<Reprojection>(s);
          }};
}

}  // namespace dhr
