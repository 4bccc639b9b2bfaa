// rotation_warp: the remote-rendering baseline's client-side prediction. That client has no
// scene and no G-buffer (DHR-S paper, section 4.1: "for remote rendering, it is more difficult
// for the client to perform prediction since it only receives colour data of the final
// frame"), so the only correction it can make is for the camera's rotation, as VR runtimes'
// rotational timewarp does: for a pure rotation (and a change of field of view) the image
// moves by a homography, H = K_src R K_dst^-1, independent of depth. Translation is ignored
// (it would need depth).
//
// Only the cameras are read (src.camera: the one the received frame was rendered for;
// dst.camera: the one being displayed), never the G-buffers' images, which this client does
// not have. For each dst pixel centre, its viewing ray is expressed in the src camera's frame
// and projected; the received buffer is sampled there bilinearly (each channel / plane on its
// own, rounded to nearest). Points outside the source image rectangle [0, W] x [0, H] (or
// behind the src camera) are counted as disoccluded and filled by `fill`: clamp takes the
// nearest edge of the source image (the point clamped into the rectangle), black writes 0.
// Accepts any 8-bit pass: colour (RGB interleaved), ao, soft_visibility (per plane);
// visibility bitmasks are refused (bits cannot be interpolated). Output size = dst camera
// size. Rows in parallel (TBB); bit-identical at any thread count.
//
// Parameters: fill (clamp|black, default clamp).
// Example: {"name": "rotation_warp", "params": {"fill": "black"}}
#include "backends/predict/warp.h"
#include "core/base/vec8.h"

#include <algorithm>
#include <vector>

namespace dhr {
namespace {

constexpr const char* kName = "rotation_warp";

// One coordinate of the dst pixel's ray in the src camera's frame, affine in the pixel point.
struct Affine {
  double k0 = 0, kx = 0, ky = 0;
  double at(double px, double py) const { return k0 + kx * px + ky * py; }
};

// What one row of the warp reads: the three coordinates' affine maps, the src projection, the
// buffers and their layouts.
struct Warp {
  Affine ca, cb, cc;
  double half_ws, half_hs, sx, sy;
  int ws, hs, wd;
  predict::Layout8 lin, lout;
  const uint8_t* src;
  uint8_t* dst;
  bool black;
};

// Row y of the warp; returns how many of its pixels fell outside the source image. Cloned for
// AVX2 and the baseline (DHR_VEC8_TARGETS, core/base/vec8.h): with AVX2 std::floor is one
// instruction instead of a library call; neither clone has FMA, so both give the same bits.
DHR_VEC8_TARGETS uint32_t warp_row(const Warp& w, int y) {
  uint32_t row_outside = 0;
  const double py = y + 0.5;
  for (int x = 0; x < w.wd; ++x) {
    const double px = x + 0.5;
    const double a = w.ca.at(px, py), b = w.cb.at(px, py);
    double c = w.cc.at(px, py);
    const bool behind = !(c > 0.0);
    if (behind) c = 1e-12;  // keeps the direction of (a, b): clamping then picks that edge
    double qx = w.half_ws + w.sx * a / c, qy = w.half_hs - w.sy * b / c;
    const size_t o = size_t(y) * size_t(w.wd) + size_t(x);
    if (behind || !(qx >= 0.0 && qx <= w.ws && qy >= 0.0 && qy <= w.hs)) {
      ++row_outside;
      if (w.black) {
        for (int ch = 0; ch < w.lout.planes; ++ch)
          w.dst[o * w.lout.pixel_stride + size_t(ch) * w.lout.plane_stride] = 0;
        continue;
      }
      qx = std::clamp(qx, 0.0, double(w.ws));
      qy = std::clamp(qy, 0.0, double(w.hs));
    }
    // Bilinear with clamp-to-edge addressing (pixel centres at x + 0.5).
    const double u = qx - 0.5, v = qy - 0.5;
    const double x0f = std::floor(u), y0f = std::floor(v);
    const float fx = float(u - x0f), fy = float(v - y0f);
    const int x0 = int(x0f), y0 = int(y0f);
    const int xa = std::clamp(x0, 0, w.ws - 1), xb = std::clamp(x0 + 1, 0, w.ws - 1);
    const int ya = std::clamp(y0, 0, w.hs - 1), yb = std::clamp(y0 + 1, 0, w.hs - 1);
    const size_t i00 = (size_t(ya) * size_t(w.ws) + size_t(xa)) * w.lin.pixel_stride;
    const size_t i10 = (size_t(ya) * size_t(w.ws) + size_t(xb)) * w.lin.pixel_stride;
    const size_t i01 = (size_t(yb) * size_t(w.ws) + size_t(xa)) * w.lin.pixel_stride;
    const size_t i11 = (size_t(yb) * size_t(w.ws) + size_t(xb)) * w.lin.pixel_stride;
    const float w00 = (1 - fx) * (1 - fy), w10 = fx * (1 - fy), w01 = (1 - fx) * fy, w11 = fx * fy;
    for (int ch = 0; ch < w.lin.planes; ++ch) {
      const uint8_t* p = w.src + size_t(ch) * w.lin.plane_stride;
      const float val = w00 * p[i00] + w10 * p[i10] + w01 * p[i01] + w11 * p[i11];
      w.dst[o * w.lout.pixel_stride + size_t(ch) * w.lout.plane_stride] = predict::round_u8(val);
    }
  }
  return row_outside;
}

class RotationWarp final : public Predictor {
 public:
  explicit RotationWarp(bool fill_black) : fill_black_(fill_black) {}

  PredictStats predict(const PredictInput& in, PassBuffer& out) override {
    const PassBuffer& rb = in.received;
    predict::check_buffer(kName, rb);
    if (rb.desc.layout() == PassLayout::Bitmask)
      fail(
          "predictor '{}' refuses a visibility bitmask: it resamples bilinearly and bits cannot be "
          "interpolated (valid: colour, ao, soft_visibility)",
          kName);
    const Camera& cs = in.src.camera;
    const Camera& cd = in.dst.camera;
    predict::check_warp(kName, rb, cs, cd);

    PassBuffer temp;
    PassBuffer& result = predict::output_buffer(rb, out, temp, cd.width, cd.height);

    // dir(px, py) = F_d + (2 px / W_d - 1) T_d A_d R_d + (1 - 2 py / H_d) T_d U_d (Camera::
    // primary_ray before normalising), dotted with each src axis.
    const double td = std::tan(glm::radians(double(cd.vfov_deg)) * 0.5), ad = double(cd.width) / cd.height;
    const double ts = std::tan(glm::radians(double(cs.vfov_deg)) * 0.5), as = double(cs.width) / cs.height;
    const glm::dvec3 rd(cd.right()), ud(cd.up), fd(cd.forward);
    const glm::dvec3 rs(cs.right()), us(cs.up), fs(cs.forward);
    auto affine = [&](const glm::dvec3& axis) {
      const double r = glm::dot(rd, axis), u = glm::dot(ud, axis), f = glm::dot(fd, axis);
      return Affine{f - td * ad * r + td * u, 2.0 * td * ad / cd.width * r, -2.0 * td / cd.height * u};
    };
    const Affine ca = affine(rs), cb = affine(us), cc = affine(fs);
    const double half_ws = 0.5 * cs.width, half_hs = 0.5 * cs.height;
    const double sx = half_ws / (ts * as), sy = half_hs / ts;

    const int hd = cd.height;
    const Warp w{ca,
                 cb,
                 cc,
                 half_ws,
                 half_hs,
                 sx,
                 sy,
                 cs.width,
                 cs.height,
                 cd.width,
                 predict::layout8(rb.desc),
                 predict::layout8(result.desc),
                 rb.bytes.data(),
                 result.bytes.data(),
                 fill_black_};
    std::vector<uint32_t> outside(size_t(hd), 0);
    predict::parallel_rows(hd, [&](int y) { outside[size_t(y)] = warp_row(w, y); });

    if (&result == &temp) out = std::move(temp);
    PredictStats stats;
    stats.pixels = uint64_t(cd.width) * uint64_t(hd);
    for (uint32_t v : outside) stats.disoccluded += v;
    return stats;
  }

 private:
  bool fill_black_;
};

}  // namespace

PredictorEntry make_rotation_warp_predictor() {
  return {kName,
          "remote-rendering baseline: warp the last colour frame by the camera rotation (homography, "
          "translation ignored, cameras only)",
          {ParamSpec::choice("fill", "clamp", {"clamp", "black"},
                             "dst pixels whose ray leaves the source image: nearest source edge, or 0")},
          [](const Params& p) { return std::make_unique<RotationWarp>(p.get_string("fill") == "black"); }};
}

}  // namespace dhr
