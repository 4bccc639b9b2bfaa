#include "core/buffers/image_io.h"

#include "core/base/error.h"
#include "core/buffers/visualize.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <vector>

namespace dhr {

namespace {

// A PNG file's chunk structure, checked before libpng sees it: the signature, every chunk's
// length within the file and its CRC-32, ending with IEND. A cut-short or bit-flipped file (a
// damaged cache entry) is then an error of ours; libpng's own error path longjmps out of
// OpenImageIO's read callback and leaks its message string (LeakSanitizer sees it).
constexpr uint8_t kPngSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

bool starts_as_png(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  uint8_t head[8] = {};
  return in.read(reinterpret_cast<char*>(head), 8) && std::equal(head, head + 8, kPngSignature);
}

// `b`: a whole PNG file of `size` bytes. Empty when intact, else what is wrong.
std::string png_damage(const uint8_t* b, size_t size) {
  static const std::array<uint32_t, 256> table = [] {
    std::array<uint32_t, 256> t{};
    for (uint32_t n = 0; n < 256; ++n) {
      uint32_t c = n;
      for (int k = 0; k < 8; ++k) c = c & 1 ? 0xedb88320u ^ (c >> 1) : c >> 1;
      t[n] = c;
    }
    return t;
  }();
  auto be32 = [&](size_t at) {
    return uint32_t(b[at]) << 24 | uint32_t(b[at + 1]) << 16 | uint32_t(b[at + 2]) << 8 | b[at + 3];
  };
  size_t at = 8;
  while (at + 12 <= size) {
    const uint64_t length = be32(at);
    if (length > size - at - 12) return fmt::format("a chunk at byte {} runs past the end of the file", at);
    uint32_t crc = 0xffffffffu;
    for (size_t i = at + 4; i < at + 8 + length; ++i) crc = table[(crc ^ b[i]) & 0xff] ^ (crc >> 8);
    if ((crc ^ 0xffffffffu) != be32(at + 8 + size_t(length)))
      return fmt::format("the CRC of the chunk at byte {} does not match", at);
    const bool end = b[at + 4] == 'I' && b[at + 5] == 'E' && b[at + 6] == 'N' && b[at + 7] == 'D';
    at += 12 + size_t(length);
    if (end) return "";
  }
  return "the file ends before its IEND chunk";
}

template <class T>
void write_image(const std::string& path, int width, int height, int channels, OIIO::TypeDesc type, const T* data) {
  if (width <= 0 || height <= 0) fail("{}: cannot write an empty {}x{} image", path, width, height);
  const auto parent = std::filesystem::path(path).parent_path();
  if (!parent.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(parent, ec);
    if (ec) fail("{}: cannot create folder {}: {}", path, parent.string(), ec.message());
  }
  auto out = OIIO::ImageOutput::create(path);
  if (!out) fail("{}: no image writer for this file name ({})", path, OIIO::geterror());
  OIIO::ImageSpec spec(width, height, channels, type);
  if (!out->open(path, spec)) fail("{}: cannot open for writing: {}", path, out->geterror());
  if (!out->write_image(type, data)) fail("{}: write failed: {}", path, out->geterror());
  if (!out->close()) fail("{}: close failed: {}", path, out->geterror());
}

}  // namespace

void write_png(const std::string& path, const ImageU8& image) {
  write_image(path, image.width(), image.height(), 1, OIIO::TypeDesc::UINT8, image.data());
}
void write_png(const std::string& path, const ImageRGB8& image) {
  write_image(path, image.width(), image.height(), 3, OIIO::TypeDesc::UINT8, image.data());
}
void write_exr(const std::string& path, const ImageF& image) {
  write_image(path, image.width(), image.height(), 1, OIIO::TypeDesc::FLOAT, image.data());
}
void write_exr(const std::string& path, const ImageVec3& image) {
  write_image(path, image.width(), image.height(), 3, OIIO::TypeDesc::FLOAT, image.data());
}

namespace {

// Every channel of every pixel of the open image, as `type`.
template <class T>
std::vector<T> read_pixels(OIIO::ImageInput& in, const std::string& path, size_t count, OIIO::TypeDesc type) {
  std::vector<T> raw(count);
  if (!in.read_image(0, 0, 0, in.spec().nchannels, type, raw.data())) fail("{}: read failed: {}", path, in.geterror());
  in.close();
  return raw;
}

// Decodes the image `open_name` (a file name, or a name with the format's extension when read
// from `proxy`); `path` names it in errors.
Rgba8Image decode_rgba8(const std::string& path, const std::string& open_name, OIIO::Filesystem::IOProxy* proxy) {
  // Alpha as the file stores it (unassociated in PNG, TIFF, ...): OpenImageIO premultiplies the
  // colour by alpha unless told not to, which darkened every partly transparent texel.
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  // With a configuration, OpenImageIO's readers take the proxy from it (else they open the name).
  if (proxy) config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &proxy);
  auto in = OIIO::ImageInput::open(open_name, &config, proxy);
  if (!in) fail("{}: cannot read image: {}", path, OIIO::geterror());
  const OIIO::ImageSpec& spec = in->spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0 || spec.depth != 1)
    fail("{}: unsupported image shape {}x{}x{} with {} channels", path, spec.width, spec.height, spec.depth,
         spec.nchannels);
  check_image_size(spec.width, spec.height);
  const int nc = spec.nchannels;
  if (nc > 64) fail("{}: {} channels (at most 64 are read: colour, alpha and a few more)", path, nc);
  const size_t n = size_t(spec.width) * spec.height;
  const int alpha = spec.alpha_channel >= 0 && spec.alpha_channel < nc ? spec.alpha_channel
                    : nc == 4 || nc == 2                               ? nc - 1
                                                                       : -1;
  Rgba8Image img;
  img.width = spec.width;
  img.height = spec.height;
  img.has_alpha = alpha >= 0;
  img.rgba.resize(n * 4);
  // Which source channel feeds R, G, B (grey replicated).
  const int src[3] = {0, nc >= 3 ? 1 : 0, nc >= 3 ? 2 : 0};
  if (spec.format.is_floating_point()) {
    // Float images (OpenEXR, float TIFF, HDR) hold linear light; OpenEXR's colour is associated
    // with alpha (premultiplied). Colour is divided by alpha where alpha > 0, clamped to [0, 1]
    // and encoded with the sRGB curve, as an 8-bit image of the same scene would be; alpha is
    // clamped and scaled. A NaN or infinite value has no such meaning: it is refused.
    const std::vector<float> raw = read_pixels<float>(*in, path, n * size_t(nc), OIIO::TypeDesc::FLOAT);
    for (size_t i = 0; i < n; ++i) {
      const float* s = &raw[i * size_t(nc)];
      for (int c = 0; c < nc; ++c)
        if (!std::isfinite(s[c]))
          fail("{}: pixel ({}, {}) channel {} is {}: an image must hold finite values", path, i % size_t(spec.width),
               i / size_t(spec.width), c, s[c]);
      const float a = alpha >= 0 ? std::clamp(s[alpha], 0.0f, 1.0f) : 1.0f;
      uint8_t* d = &img.rgba[i * 4];
      for (int c = 0; c < 3; ++c) d[c] = linear_to_srgb8(a > 0.0f && alpha >= 0 ? s[src[c]] / a : s[src[c]]);
      d[3] = uint8_t(std::lround(a * 255.0f));
    }
    return img;
  }
  const std::vector<uint8_t> raw = read_pixels<uint8_t>(*in, path, n * size_t(nc), OIIO::TypeDesc::UINT8);
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* s = &raw[i * size_t(nc)];
    uint8_t* d = &img.rgba[i * 4];
    for (int c = 0; c < 3; ++c) d[c] = s[src[c]];
    d[3] = alpha >= 0 ? s[alpha] : 255;
  }
  return img;
}

}  // namespace

Rgba8Image read_rgba8(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) fail("{}: image file not found", path);
  // A PNG is read once: checked (png_damage), then decoded from those bytes.
  std::vector<uint8_t> png;
  std::unique_ptr<OIIO::Filesystem::IOMemReader> memory;
  if (starts_as_png(path)) {
    std::ifstream file(path, std::ios::binary);
    png.assign(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
    if (const std::string damage = png_damage(png.data(), png.size()); !damage.empty())
      fail("{}: damaged PNG: {}", path, damage);
    memory = std::make_unique<OIIO::Filesystem::IOMemReader>(png.data(), png.size());
  }
  return decode_rgba8(path, path, memory.get());
}

Rgba8Image read_rgba8_memory(const std::string& name, const std::string& format, const uint8_t* data, size_t size) {
  if (size >= 8 && std::equal(data, data + 8, kPngSignature))
    if (const std::string damage = png_damage(data, size); !damage.empty()) fail("{}: damaged PNG: {}", name, damage);
  OIIO::Filesystem::IOMemReader reader(data, size);
  return decode_rgba8(name, "embedded." + format, &reader);
}

ImageRGB8 read_rgb8(const std::string& path) {
  Rgba8Image src = read_rgba8(path);
  ImageRGB8 out(src.width, src.height);
  for (size_t i = 0; i < out.size(); ++i) out[i] = {src.rgba[i * 4], src.rgba[i * 4 + 1], src.rgba[i * 4 + 2]};
  return out;
}

}  // namespace dhr
