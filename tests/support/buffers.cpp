#include "tests/support_buffers.h"

#include "core/base/error.h"
#include "core/base/rng.h"
#include "core/buffers/image.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace dhr::test {
namespace {

constexpr double kRefWidth = 1280.0, kRefHeight = 720.0;
constexpr double kCreaseY = 470.0;  // wall above, floor below

struct Shape {
  bool sphere;
  double cx, cy, a, b;  // sphere: centre, radius a; box: centre, half sizes a x b
};

constexpr std::array<Shape, 7> kShapes{{
    {true, 300, 520, 70, 0},
    {true, 760, 560, 90, 0},
    {true, 1080, 430, 55, 0},
    {true, 520, 300, 45, 0},
    {false, 175, 470, 55, 90},
    {false, 945, 315, 65, 65},
    {false, 650, 645, 50, 45},
}};

constexpr std::array<std::array<uint8_t, 3>, 7> kShapeColours{
    {{200, 60, 50}, {60, 140, 200}, {230, 200, 70}, {90, 180, 90}, {150, 90, 170}, {220, 130, 60}, {120, 120, 130}}};

double size_of(const Shape& s) { return s.sphere ? s.a : std::min(s.a, s.b); }

// Signed distance (negative inside) from (x, y) to shape s moved by (dx, dy).
double sdf(const Shape& s, double x, double y, double dx = 0, double dy = 0) {
  const double px = x - s.cx - dx, py = y - s.cy - dy;
  if (s.sphere) return std::hypot(px, py) - s.a;
  const double qx = std::abs(px) - s.a, qy = std::abs(py) - s.b;
  return std::hypot(std::max(qx, 0.0), std::max(qy, 0.0)) + std::min(std::max(qx, qy), 0.0);
}

// Index of the shape covering (x, y) (objects stand in front of wall and floor), or -1.
int shape_at(double x, double y, double& inside_depth) {
  for (size_t i = 0; i < kShapes.size(); ++i)
    if (double d = sdf(kShapes[i], x, y); d < 0) {
      inside_depth = -d;
      return int(i);
    }
  return -1;
}

double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

double distance_to_grid(double v, double spacing) {
  const double m = std::fmod(std::abs(v), spacing);
  return std::min(m, spacing - m);
}

struct Light {
  double x, y, range;
};

Light light_of(uint64_t seed, int l) {
  const RngKey k{seed, uint32_t(l), 0, 0, kStreamLightBase + uint32_t(l)};
  return {80 + 1120 * double(rng_uniform(k, 0)), 40 + 380 * double(rng_uniform(k, 1)),
          450 + 700 * double(rng_uniform(k, 2))};
}

// Visible fraction of light `L` at (x, y); penumbra_scale 0 gives hard (0/1) shadows.
double light_visibility(const Light& L, double x, double y, bool soft) {
  const double dist = std::hypot(x - L.x, y - L.y);
  double range = soft ? smoothstep(L.range, L.range - 80, dist) : (dist < L.range ? 1.0 : 0.0);
  if (range <= 0) return 0.0;
  double depth = 0;
  if (int i = shape_at(x, y, depth); i >= 0) {
    // An object's surface is lit on the side facing the light.
    const Shape& s = kShapes[size_t(i)];
    const double nx = x - s.cx, ny = y - s.cy, lx = L.x - s.cx, ly = L.y - s.cy;
    const double cosine = (nx * lx + ny * ly) / (std::hypot(nx, ny) * std::hypot(lx, ly) + 1e-9);
    return range * (soft ? smoothstep(-0.15, 0.15, cosine) : (cosine > 0 ? 1.0 : 0.0));
  }
  // Shadows: each object swept away from the light, wider with distance (a point light's
  // shadow of an object standing on the floor, flattened into the image plane).
  double min_d = std::numeric_limits<double>::max(), penumbra = 1;
  for (const Shape& s : kShapes) {
    const double ox = s.cx - L.x, oy = s.cy - L.y, od = std::hypot(ox, oy) + 1e-9;
    if (od > L.range) continue;
    const double reach = 40 + 0.3 * od;
    for (double t : {0.35, 0.7, 1.0}) {
      const double d = sdf(s, x, y, ox / od * reach * t, oy / od * reach * t) - 0.1 * size_of(s) * t;
      if (d < min_d) {
        min_d = d;
        penumbra = 3 + 0.05 * od * t;
      }
    }
  }
  const double lit = soft ? smoothstep(-penumbra, penumbra, min_d) : (min_d > 0 ? 1.0 : 0.0);
  return range * lit;
}

// Reference-frame coordinates of the centre of pixel (x, y) of `view`.
void to_ref(const SyntheticView& v, int x, int y, double& rx, double& ry) {
  rx = (x + 0.5 + v.shift_x_px) * (kRefWidth / std::max(v.width, 1));
  ry = (y + 0.5 + v.shift_y_px) * (kRefHeight / std::max(v.height, 1));
}

template <class PerRow>
void for_rows(int height, PerRow&& per_row) {
  tbb::parallel_for(0, height, [&](int y) { per_row(y); });
}

uint8_t to_u8(double v, int full_scale) { return uint8_t(std::lround(std::clamp(v, 0.0, 1.0) * full_scale)); }

// Binomial(n, p) from n counter-based uniforms.
int binomial(const RngKey& base, int n, double p) {
  int count = 0;
  RngKey k = base;
  for (int s = 0; s < n; ++s) {
    k.sample = uint32_t(s);
    count += rng_uniform_double(k) < p;
  }
  return count;
}

void check_view(const SyntheticView& v, const char* what) {
  if (v.width < 0 || v.height < 0 || v.width > kMaxImageSide || v.height > kMaxImageSide)
    fail("{}: size {}x{} out of range", what, v.width, v.height);
}

}  // namespace

double synthetic_ao(double x, double y) {
  double depth = 0;
  if (int i = shape_at(x, y, depth); i >= 0) {
    // An object's own surface: darker near its outline (a hard edge against the contact
    // shadow around it), brighter towards its centre.
    return std::clamp(0.9 - 0.35 * std::exp(-depth / (0.3 * size_of(kShapes[size_t(i)]))), 0.0, 1.0);
  }
  double ao = 1 - 0.45 * std::exp(-std::abs(y - kCreaseY) / 35);
  if (y < kCreaseY)
    ao *= 1 - 0.35 * std::exp(-distance_to_grid(x, 160) / 5);  // wall panel grooves
  else
    ao *= 1 - 0.15 * std::exp(-std::min(distance_to_grid(x, 120), distance_to_grid(y - kCreaseY, 120)) / 3);
  for (const Shape& s : kShapes) ao *= 1 - 0.65 * std::exp(-sdf(s, x, y) / (0.4 * size_of(s)));
  return std::clamp(ao, 0.0, 1.0);
}

PassBuffer make_constant(const PassDesc& desc, uint8_t value) {
  if (std::string why = desc.validate(); !why.empty()) fail("make_constant: {}", why);
  PassBuffer b{desc, std::vector<uint8_t>(desc.byte_size(), value)};
  if (desc.kind == PassKind::Visibility && desc.channels % 8 != 0) {
    const size_t bpp = size_t(desc.channels + 7) / 8;
    const uint8_t keep = uint8_t(0xFFu >> (8 - desc.channels % 8));
    for (size_t i = bpp - 1; i < b.bytes.size(); i += bpp) b.bytes[i] &= keep;
  }
  if (desc.kind == PassKind::Ao || desc.kind == PassKind::SoftVisibility)
    std::fill(b.bytes.begin(), b.bytes.end(), std::min<uint8_t>(value, uint8_t(desc.full_scale)));
  return b;
}

PassBuffer make_random(const PassDesc& desc, uint64_t seed) {
  if (std::string why = desc.validate(); !why.empty()) fail("make_random: {}", why);
  PassBuffer b{desc, std::vector<uint8_t>(desc.byte_size())};
  for (size_t i = 0; i < b.bytes.size(); i += 8) {
    uint64_t r = rng_bits(RngKey{seed, uint32_t(i >> 3), uint32_t(i >> 35), 0, 0});
    for (size_t j = i; j < std::min(i + 8, b.bytes.size()); ++j, r >>= 8) b.bytes[j] = uint8_t(r);
  }
  if (desc.kind == PassKind::Visibility) {
    const PassBuffer mask = make_constant(desc, 0xFF);  // clears the unused bits
    for (size_t i = 0; i < b.bytes.size(); ++i) b.bytes[i] &= mask.bytes[i];
  }
  if ((desc.kind == PassKind::Ao || desc.kind == PassKind::SoftVisibility) && desc.full_scale < 255)
    for (auto& v : b.bytes) v = uint8_t(v % (desc.full_scale + 1));
  return b;
}

PassBuffer make_noisy_ao(const SyntheticView& v, int rays) {
  check_view(v, "make_noisy_ao");
  if (rays < 1 || rays > 255) fail("make_noisy_ao: {} rays out of range 1..255", rays);
  PassBuffer b{{PassKind::Ao, v.width, v.height, 1, rays}, {}};
  b.bytes.resize(b.desc.byte_size());
  for_rows(v.height, [&](int y) {
    for (int x = 0; x < v.width; ++x) {
      double rx, ry;
      to_ref(v, x, y, rx, ry);
      const RngKey k{v.seed, uint32_t(y * v.width + x), v.frame, 0, kStreamAo};
      b.bytes[size_t(y) * v.width + x] = uint8_t(binomial(k, rays, synthetic_ao(rx, ry)));
    }
  });
  return b;
}

PassBuffer make_smooth_ao(const SyntheticView& v) {
  check_view(v, "make_smooth_ao");
  PassBuffer b{{PassKind::Ao, v.width, v.height, 1, 255}, {}};
  b.bytes.resize(b.desc.byte_size());
  for_rows(v.height, [&](int y) {
    for (int x = 0; x < v.width; ++x) {
      double rx, ry;
      to_ref(v, x, y, rx, ry);
      b.bytes[size_t(y) * v.width + x] = to_u8(synthetic_ao(rx, ry), 255);
    }
  });
  return b;
}

PassBuffer make_hard_visibility(const SyntheticView& v, int lights) {
  check_view(v, "make_hard_visibility");
  if (lights < 1 || lights > 64) fail("make_hard_visibility: {} lights out of range 1..64", lights);
  PassBuffer b{{PassKind::Visibility, v.width, v.height, lights, 255}, {}};
  b.bytes.resize(b.desc.byte_size());
  const size_t bpp = size_t(lights + 7) / 8;
  std::vector<Light> ls;
  for (int l = 0; l < lights; ++l) ls.push_back(light_of(v.seed, l));
  for_rows(v.height, [&](int y) {
    for (int x = 0; x < v.width; ++x) {
      double rx, ry;
      to_ref(v, x, y, rx, ry);
      uint8_t* px = &b.bytes[(size_t(y) * v.width + x) * bpp];
      for (int l = 0; l < lights; ++l)
        if (light_visibility(ls[size_t(l)], rx, ry, false) > 0.5) px[l / 8] |= uint8_t(1u << (l % 8));
    }
  });
  return b;
}

PassBuffer make_soft_visibility(const SyntheticView& v, int lights, int samples) {
  check_view(v, "make_soft_visibility");
  if (lights < 1 || lights > 64) fail("make_soft_visibility: {} lights out of range 1..64", lights);
  if (samples < 0 || samples > 255) fail("make_soft_visibility: {} samples out of range 0..255", samples);
  const int full_scale = samples ? samples : 255;
  PassBuffer b{{PassKind::SoftVisibility, v.width, v.height, lights, full_scale}, {}};
  b.bytes.resize(b.desc.byte_size());
  const size_t plane = size_t(v.width) * size_t(v.height);
  std::vector<Light> ls;
  for (int l = 0; l < lights; ++l) ls.push_back(light_of(v.seed, l));
  for_rows(v.height, [&](int y) {
    for (int x = 0; x < v.width; ++x) {
      double rx, ry;
      to_ref(v, x, y, rx, ry);
      const size_t i = size_t(y) * v.width + x;
      for (int l = 0; l < lights; ++l) {
        const double f = light_visibility(ls[size_t(l)], rx, ry, true);
        b.bytes[size_t(l) * plane + i] =
            samples ? uint8_t(binomial({v.seed, uint32_t(i), v.frame, 0, kStreamLightBase + uint32_t(l)}, samples, f))
                    : to_u8(f, full_scale);
      }
    }
  });
  return b;
}

PassBuffer make_colour(const SyntheticView& v) {
  check_view(v, "make_colour");
  PassBuffer b{{PassKind::Colour, v.width, v.height, 3, 255}, {}};
  b.bytes.resize(b.desc.byte_size());
  const Light key = light_of(v.seed, 0), fill = light_of(v.seed, 1);
  for_rows(v.height, [&](int y) {
    for (int x = 0; x < v.width; ++x) {
      double rx, ry;
      to_ref(v, x, y, rx, ry);
      double depth = 0;
      const int shape = shape_at(rx, ry, depth);
      std::array<double, 3> albedo;
      if (shape >= 0) {
        for (int c = 0; c < 3; ++c) albedo[size_t(c)] = kShapeColours[size_t(shape)][size_t(c)] / 255.0;
      } else if (ry < kCreaseY) {
        albedo = {0.80, 0.72, 0.60};
      } else {
        const bool dark = (int(std::floor(rx / 120)) + int(std::floor((ry - kCreaseY) / 120))) & 1;
        albedo = dark ? std::array<double, 3>{0.45, 0.34, 0.25} : std::array<double, 3>{0.62, 0.50, 0.36};
      }
      // Fixed surface texture: keyed by scene position, so it moves with the camera.
      const RngKey tk{v.seed, uint32_t(int64_t(std::floor(rx / 2)) & 0xFFFFFFFF),
                      uint32_t(int64_t(std::floor(ry / 2)) & 0xFFFFFFFF), 0, 7};
      const double texture = 0.94 + 0.12 * double(rng_uniform(tk));
      const double light =
          0.25 + 0.55 * light_visibility(key, rx, ry, true) + 0.2 * light_visibility(fill, rx, ry, true);
      const double shade = synthetic_ao(rx, ry) * light * texture;
      uint8_t* px = &b.bytes[(size_t(y) * v.width + x) * 3];
      for (int c = 0; c < 3; ++c) px[c] = to_u8(std::pow(albedo[size_t(c)] * shade, 1 / 2.2), 255);
    }
  });
  return b;
}

double buffer_psnr_db(const PassBuffer& a, const PassBuffer& b) {
  if (a.bytes.size() != b.bytes.size())
    fail("buffer_psnr_db: buffers of {} and {} bytes", a.bytes.size(), b.bytes.size());
  double sum = 0;
  for (size_t i = 0; i < a.bytes.size(); ++i) {
    const double d = double(a.bytes[i]) - double(b.bytes[i]);
    sum += d * d;
  }
  if (sum == 0 || a.bytes.empty()) return std::numeric_limits<double>::infinity();
  return 10 * std::log10(255.0 * 255.0 / (sum / double(a.bytes.size())));
}

PassBuffer make_world_pass(const GBuffer& g, PassKind kind) {
  if (kind != PassKind::Ao && kind != PassKind::Visibility) throw Error("make_world_pass: Ao or Visibility only");
  PassBuffer b;
  b.desc = {kind, g.width(), g.height(), 1, 255};
  b.bytes.assign(b.desc.byte_size(), 0);
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) {
      const size_t i = size_t(y) * size_t(g.width()) + size_t(x);
      if (!g.covered(x, y)) {
        b.bytes[i] = kind == PassKind::Visibility ? 1 : 255;
        continue;
      }
      const glm::vec3 p = g.position(x, y);
      if (kind == PassKind::Visibility)
        b.bytes[i] =
            uint8_t((int(std::floor(p.x * 2.0f)) + int(std::floor(p.y * 2.0f)) + int(std::floor(p.z * 2.0f))) & 1);
      else
        b.bytes[i] = uint8_t(128.0f + 100.0f * std::sin(p.x * 1.7f) * std::cos(p.z * 1.3f + p.y));
    }
  return b;
}

}  // namespace dhr::test
