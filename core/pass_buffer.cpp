#include "core/pass_buffer.h"

#include "core/error.h"
#include "core/image.h"

#include <algorithm>

#include <fmt/format.h>

namespace dhr {

const char* pass_kind_name(PassKind kind) {
  switch (kind) {
    case PassKind::Visibility: return "visibility";
    case PassKind::SoftVisibility: return "soft_visibility";
    case PassKind::Ao: return "ao";
    case PassKind::Colour: return "colour";
    case PassKind::Depth: return "depth";
  }
  return "unknown";
}

size_t PassDesc::pixel_bytes() const {
  switch (kind) {
    case PassKind::Visibility: return size_t((channels + 7) / 8);
    case PassKind::SoftVisibility: return size_t(channels);
    case PassKind::Ao: return 1;
    case PassKind::Colour: return 3;
    case PassKind::Depth: return 2;
  }
  return 0;
}

size_t PassDesc::byte_size() const { return size_t(width) * size_t(height) * pixel_bytes(); }

std::string PassDesc::validate() const {
  if (width < 0 || height < 0 || width > kMaxImageSide || height > kMaxImageSide ||
      int64_t(width) * height > kMaxImagePixels)
    return fmt::format("size {}x{} out of range (each side 0..{})", width, height, kMaxImageSide);
  switch (kind) {
    case PassKind::Visibility:
    case PassKind::SoftVisibility:
      if (channels < 1 || channels > 64) return fmt::format("{} lights out of range 1..64", channels);
      break;
    case PassKind::Ao:
      if (channels != 1) return fmt::format("ao has 1 channel, not {}", channels);
      break;
    case PassKind::Colour:
      if (channels != 3) return fmt::format("colour has 3 channels, not {}", channels);
      break;
    case PassKind::Depth:
      if (channels != 2) return fmt::format("depth has 2 byte planes, not {}", channels);
      break;
    default: return "unknown pass kind";
  }
  if ((kind == PassKind::Ao || kind == PassKind::SoftVisibility) && (full_scale < 1 || full_scale > 255))
    return fmt::format("full_scale {} out of range 1..255", full_scale);
  if (kind == PassKind::Depth && (full_scale < 8 || full_scale > 16))
    return fmt::format("depth code of {} bits out of range 8..16", full_scale);
  return {};
}

}  // namespace dhr

namespace dhr {

ImageU8 pass_plane(const PassBuffer& b, int index) {
  if (b.desc.kind == PassKind::Visibility)
    fail("pass_plane: a visibility bitmask has no 8-bit planes (unpack its bits instead)");
  const int planes = b.desc.kind == PassKind::SoftVisibility || b.desc.kind == PassKind::Depth ? b.desc.channels : 1;
  if (index < 0 || index >= planes) fail("pass_plane: plane {} out of range 0..{}", index, planes - 1);
  ImageU8 img(b.desc.width, b.desc.height);
  const size_t n = img.size();
  if (b.bytes.size() < (size_t(index) + 1) * n)
    fail("pass_plane: buffer holds {} bytes, plane {} needs {}", b.bytes.size(), index, (size_t(index) + 1) * n);
  std::copy_n(b.bytes.begin() + std::ptrdiff_t(size_t(index) * n), n, img.data());
  return img;
}

}  // namespace dhr
