// depth_warp: the remote-rendering baseline's best client-side prediction: the colour frame is
// reprojected with the depth the server sent beside it (core/buffers/depth_pass.h), so the camera's
// translation is corrected as well as its rotation, as production XR streaming does
// (positional timewarp). rotation_warp corrects the rotation only. Choosing this predictor for
// passes.colour makes remote mode send the depth pass; its bytes count in the run's bandwidth.
//
// Method (a forward warp, depth-image-based rendering):
// 1. Splat: every source pixel centre is lifted to its world point with its view depth through
//    the src camera (background pixels, depth code 0, become directions at infinity, which move
//    with the rotation only) and projected into the dst camera; the dst pixel it falls in keeps
//    the nearest such point (smallest view depth; ties: lowest source index), by an atomic
//    minimum on (depth bits, source index), so the result does not depend on the order or the
//    thread count. Points behind the dst camera's near plane are dropped.
// 2. Cracks: where the source grid maps sparser than the dst grid (a surface seen larger or at
//    another angle), single dst pixels receive no point, or a point from behind the surface. A
//    dst pixel with no point between two kept ones (left and right, or above and below), or whose
//    point is more than crack_ratio times as far as both of those neighbours' while theirs come
//    from touching source pixels (so nothing of the source lies between them), takes its left
//    (upper) neighbour's point. These are not counted as disocclusions.
// 3. Holes (no point landed, wider than a crack: a disocclusion, counted): filled along the row from the nearest
//    kept point on either side, the farther of the two (what is uncovered is behind); a row
//    with no kept point takes the source pixel that the rotation alone maps there (clamped
//    into the source image).
// Each dst pixel takes its point's source pixel as it is (nearest; a pure rotation of a
// received frame is therefore not filtered as rotation_warp's bilinear sampling is).
// With no depth for the received frame (its depth pass did not arrive, or the predictor is
// used where no depth is sent) it falls back to rotation_warp (bilinear, clamp).
// Accepts any 8-bit pass (colour RGB interleaved, ao, soft_visibility per plane); bitmasks are
// refused. src.depth must be the received buffer's size when present.
//
// Parameters: depth_bits (8..16, default 12: the depth pass's precision, core/buffers/depth_pass.h),
// crack_ratio (1.01..10, default 1.1).
// Example: {"name": "depth_warp", "params": {"depth_bits": 14}}
#include "backends/predict/warp.h"

#include "backends/register_all.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <limits>
#include <memory>
#include <vector>

namespace dhr {
namespace {

constexpr const char* kName = "depth_warp";
constexpr uint64_t kEmpty = std::numeric_limits<uint64_t>::max();

// The ray through pixel centre (px, py) with forward component 1: its world point at view depth
// z is position + z * ray.
struct Rays {
  glm::dvec3 forward, right_step, up_step, origin;  // ray(px, py) = origin + px * right_step + py * up_step
  explicit Rays(const Camera& c) {
    const double t = std::tan(glm::radians(double(c.vfov_deg)) * 0.5), a = double(c.width) / c.height;
    const glm::dvec3 r(c.right()), u(c.up), f(c.forward);
    forward = f;
    right_step = 2.0 * t * a / c.width * r;
    up_step = -2.0 * t / c.height * u;
    origin = f - t * a * r + t * u;
  }
  glm::dvec3 at(double px, double py) const { return origin + px * right_step + py * up_step; }
};

class DepthWarp final : public Predictor {
 public:
  DepthWarp(int depth_bits, double crack_ratio) : depth_bits_(depth_bits), crack_ratio_(crack_ratio) {}

  int depth_bits() const override { return depth_bits_; }

  PredictStats predict(const PredictInput& in, PassBuffer& out) override {
    const PassBuffer& rb = in.received;
    predict::check_buffer(kName, rb);
    if (rb.desc.layout() == PassLayout::Bitmask)
      fail("predictor '{}' refuses a visibility bitmask (valid: colour, ao, soft_visibility)", kName);
    const Camera& cs = in.src.camera;
    const Camera& cd = in.dst.camera;
    predict::check_warp(kName, rb, cs, cd);
    const ImageF& depth = in.src.depth;
    if (depth.empty()) {
      if (!rotation_) rotation_ = registries().predictors.create("rotation_warp", nlohmann::json::object());
      return rotation_->predict(in, out);
    }
    if (!depth.same_size(cs.width, cs.height))
      fail("predictor '{}': the received depth is {}x{} but the colour frame is {}x{}", kName, depth.width(),
           depth.height(), cs.width, cs.height);

    const int ws = cs.width, hs = cs.height, wd = cd.width, hd = cd.height;
    const size_t nd = size_t(wd) * size_t(hd);
    splat(in, depth, nd);

    // 2. cracks: a kept point far behind both neighbours on a row or a column.
    resolved_.assign(nd, kEmpty);
    const double ratio = crack_ratio_;
    auto z_of = [](uint64_t key) { return std::bit_cast<float>(uint32_t(key >> 32)); };
    predict::parallel_rows(hd, [&](int y) {
      for (int x = 0; x < wd; ++x) {
        const size_t o = size_t(y) * size_t(wd) + size_t(x);
        const uint64_t k = keys_[o].load(std::memory_order_relaxed);
        resolved_[o] = k;
        if (k == kEmpty) {  // a one-pixel gap between kept points: a crack of the pixel grid
          auto kept = [&](size_t a) { return keys_[a].load(std::memory_order_relaxed) != kEmpty; };
          if (x > 0 && x + 1 < wd && kept(o - 1) && kept(o + 1))
            resolved_[o] = keys_[o - 1].load(std::memory_order_relaxed);
          else if (y > 0 && y + 1 < hd && kept(o - size_t(wd)) && kept(o + size_t(wd)))
            resolved_[o] = keys_[o - size_t(wd)].load(std::memory_order_relaxed);
          continue;
        }
        const double z = z_of(k);
        // A crack: both neighbours' points are nearer and come from touching source pixels, so
        // no source pixel lies between them (a thin gap that the source shows stays).
        auto behind = [&](size_t a, size_t b) {
          const uint64_t ka = keys_[a].load(std::memory_order_relaxed), kb = keys_[b].load(std::memory_order_relaxed);
          if (ka == kEmpty || kb == kEmpty || !(z > ratio * std::max<double>(z_of(ka), z_of(kb)))) return false;
          const uint32_t ia = uint32_t(ka), ib = uint32_t(kb);
          const int ax = int(ia % uint32_t(ws)), ay = int(ia / uint32_t(ws)), bx = int(ib % uint32_t(ws)),
                    by = int(ib / uint32_t(ws));
          return std::abs(ax - bx) <= 1 && std::abs(ay - by) <= 1;
        };
        if (x > 0 && x + 1 < wd && behind(o - 1, o + 1))
          resolved_[o] = keys_[o - 1].load(std::memory_order_relaxed);
        else if (y > 0 && y + 1 < hd && behind(o - size_t(wd), o + size_t(wd)))
          resolved_[o] = keys_[o - size_t(wd)].load(std::memory_order_relaxed);
      }
    });

    // 3. holes, then the output.
    PassBuffer temp;
    PassBuffer& result = predict::output_buffer(rb, out, temp, wd, hd);
    const predict::Layout8 lin = predict::layout8(rb.desc), lout = predict::layout8(result.desc);
    const uint8_t* src = rb.bytes.data();
    uint8_t* dst = result.bytes.data();
    const Rays dst_rays(cd);
    const glm::dvec3 rs(cs.right()), us(cs.up), fs(cs.forward);
    const double ts = std::tan(glm::radians(double(cs.vfov_deg)) * 0.5), as = double(ws) / hs;
    std::vector<uint32_t> holes(size_t(hd), 0);
    nearest_right_.resize(nd);
    predict::parallel_rows(hd, [&](int y) {
      const uint64_t* row = resolved_.data() + size_t(y) * size_t(wd);
      int* right = nearest_right_.data() + size_t(y) * size_t(wd);  // the nearest kept point at or right of x
      for (int x = wd - 1, r = wd; x >= 0; --x) {
        if (row[x] != kEmpty) r = x;
        right[x] = r;
      }
      uint32_t row_holes = 0;
      int left = -1;  // the nearest kept point left of x
      for (int x = 0; x < wd; ++x) {
        uint64_t k = row[x];
        if (k == kEmpty) {
          ++row_holes;
          const int r = right[x];
          if (left >= 0 && r < wd)
            k = z_of(row[left]) >= z_of(row[r]) ? row[left] : row[r];
          else if (left >= 0)
            k = row[left];
          else if (r < wd)
            k = row[r];
        } else {
          left = x;
        }
        size_t si = 0;
        if (k != kEmpty) {
          si = size_t(uint32_t(k));
        } else {  // an empty row: the source pixel the rotation alone maps here
          const glm::dvec3 d = dst_rays.at(x + 0.5, y + 0.5);
          const double c = std::max(glm::dot(d, fs), 1e-12);
          const double qx = 0.5 * ws * (1.0 + glm::dot(d, rs) / (c * ts * as));
          const double qy = 0.5 * hs * (1.0 - glm::dot(d, us) / (c * ts));
          const int sx = std::clamp(int(std::floor(std::clamp(qx, 0.0, double(ws)))), 0, ws - 1);
          const int sy = std::clamp(int(std::floor(std::clamp(qy, 0.0, double(hs)))), 0, hs - 1);
          si = size_t(sy) * size_t(ws) + size_t(sx);
        }
        const size_t o = size_t(y) * size_t(wd) + size_t(x);
        for (int ch = 0; ch < lin.planes; ++ch)
          dst[o * lout.pixel_stride + size_t(ch) * lout.plane_stride] =
              src[si * lin.pixel_stride + size_t(ch) * lin.plane_stride];
      }
      holes[size_t(y)] = row_holes;
    });
    if (&result == &temp) out = std::move(temp);
    PredictStats stats;
    stats.pixels = nd;
    for (uint32_t v : holes) stats.disoccluded += v;
    return stats;
  }

  void reset() override {
    if (rotation_) rotation_->reset();
  }

 private:
  // 1. Every source pixel to the dst pixel it lands in; keys_[o]: the nearest point's
  // (view depth bits << 32 | source index), kEmpty where none landed.
  void splat(const PredictInput& in, const ImageF& depth, size_t nd) {
    const Camera& cs = in.src.camera;
    const Camera& cd = in.dst.camera;
    const int ws = cs.width, hs = cs.height, wd = cd.width, hd = cd.height;
    if (keys_size_ != nd) {
      keys_ = std::make_unique<std::atomic<uint64_t>[]>(nd);
      keys_size_ = nd;
    }
    for (size_t i = 0; i < nd; ++i) keys_[i].store(kEmpty, std::memory_order_relaxed);
    const Rays src_rays(cs);
    const glm::dvec3 ps(cs.position), pd(cd.position), rd(cd.right()), ud(cd.up), fd(cd.forward);
    const double td = std::tan(glm::radians(double(cd.vfov_deg)) * 0.5), ad = double(wd) / hd;
    const double fx = 0.5 * wd / (td * ad), fy = 0.5 * hd / td, cx = 0.5 * wd, cy = 0.5 * hd;
    const double near = cd.near_m;
    predict::parallel_rows(hs, [&](int y) {
      for (int x = 0; x < ws; ++x) {
        const glm::dvec3 ray = src_rays.at(x + 0.5, y + 0.5);
        const float z = depth(x, y);
        const bool surface = std::isfinite(z) && z > 0.0f;
        // From the dst camera: the surface point, or the background's direction at infinity.
        const glm::dvec3 rel = surface ? ps + double(z) * ray - pd : ray;
        const double zd = glm::dot(rel, fd);
        if (surface ? !(zd >= near) : !(zd > 0.0)) continue;
        const float key_z = surface ? float(zd) : std::numeric_limits<float>::infinity();
        const double qx = cx + glm::dot(rel, rd) * fx / zd, qy = cy - glm::dot(rel, ud) * fy / zd;
        if (!(qx >= 0.0 && qx < wd && qy >= 0.0 && qy < hd)) continue;
        const size_t o = size_t(int(qy)) * size_t(wd) + size_t(int(qx));
        const uint64_t key =
            (uint64_t(std::bit_cast<uint32_t>(key_z)) << 32) | uint64_t(size_t(y) * size_t(ws) + size_t(x));
        std::atomic<uint64_t>& slot = keys_[o];
        uint64_t cur = slot.load(std::memory_order_relaxed);
        while (key < cur && !slot.compare_exchange_weak(cur, key, std::memory_order_relaxed)) {}
      }
    });
  }

  int depth_bits_;
  double crack_ratio_;
  std::unique_ptr<std::atomic<uint64_t>[]> keys_;
  size_t keys_size_ = 0;
  std::vector<uint64_t> resolved_;
  std::vector<int> nearest_right_;
  std::unique_ptr<Predictor> rotation_;  // no depth for the received frame
};

}  // namespace

PredictorEntry make_depth_warp_predictor() {
  return {
      kName,
      "remote-rendering baseline: reproject the last colour frame with the depth sent beside it (rotation "
      "and translation; remote mode then sends a depth pass, counted)",
      {ParamSpec::integer("depth_bits", 12, 8, 16,
                          "the precision of the inverse depth the server sends (core/buffers/depth_pass.h): more bits, "
                          "less parallax error and more bytes"),
       ParamSpec::real("crack_ratio", 1.1, 1.01, 10.0,
                       "a kept point this many times as far as both neighbours (row or column) is a crack and "
                       "takes its neighbour's point")},
      [](const Params& p) { return std::make_unique<DepthWarp>(p.get_int("depth_bits"), p.get_float("crack_ratio")); }};
}

}  // namespace dhr
