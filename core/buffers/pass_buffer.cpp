#include "core/buffers/pass_buffer.h"

#include "core/base/error.h"
#include "core/buffers/image.h"

#include <algorithm>

#include <fmt/format.h>

namespace dhr {

const std::vector<PassKindInfo>& pass_kinds() {
  // A new kind is one value in PassKind and one row here, in the order of the values.
  static const std::vector<PassKindInfo> kinds = {
      {PassKind::Visibility, "visibility", PassLayout::Bitmask, PassMeaning::Visibility, 1, 64,
       "{} lights out of range 1..64", 1, 0, ""},
      {PassKind::SoftVisibility, "soft_visibility", PassLayout::Planes8, PassMeaning::Visibility, 1, 64,
       "{} lights out of range 1..64", 1, 255, "full_scale {} out of range 1..255"},
      {PassKind::Ao, "ao", PassLayout::Planes8, PassMeaning::Ao, 1, 1, "ao has 1 channel, not {}", 1, 255,
       "full_scale {} out of range 1..255"},
      {PassKind::Colour, "colour", PassLayout::Rgb8, PassMeaning::Colour, 3, 3, "colour has 3 channels, not {}", 1, 0,
       ""},
      {PassKind::Depth, "depth", PassLayout::Code16, PassMeaning::Depth, 2, 2, "depth has 2 byte planes, not {}", 8, 16,
       "depth code of {} bits out of range 8..16"},
  };
  return kinds;
}

// The rows are in the order of their values, 1, 2, ...: the row of value v is row v - 1.
const PassKindInfo* find_pass_kind(uint8_t kind) {
  const std::vector<PassKindInfo>& kinds = pass_kinds();
  if (kind < 1 || kind > kinds.size()) return nullptr;
  const PassKindInfo& k = kinds[kind - 1u];
  return uint8_t(k.kind) == kind ? &k : nullptr;
}

const char* pass_kind_name(PassKind kind) {
  const PassKindInfo* k = find_pass_kind(uint8_t(kind));
  return k ? k->name : "unknown";
}

PassLayout pass_layout(PassKind kind) {
  const PassKindInfo* k = find_pass_kind(uint8_t(kind));
  return k ? k->layout : PassLayout::Planes8;
}

PassMeaning pass_meaning(PassKind kind) {
  const PassKindInfo* k = find_pass_kind(uint8_t(kind));
  return k ? k->meaning : PassMeaning::Ao;
}

const char* pass_meaning_name(PassMeaning meaning) {
  switch (meaning) {
    case PassMeaning::Visibility: return "visibility";
    case PassMeaning::Ao: return "ao";
    case PassMeaning::Colour: return "colour";
    case PassMeaning::Depth: return "depth";
  }
  return "?";
}

size_t PassDesc::pixel_bytes() const {
  const PassKindInfo* k = find_pass_kind(uint8_t(kind));
  if (!k) return 0;
  // A kind of one channel count has that many bytes whatever `channels` says (a description
  // is validated before its buffer is read).
  const int c = k->min_channels == k->max_channels ? k->min_channels : channels;
  return k->layout == PassLayout::Bitmask ? size_t((c + 7) / 8) : size_t(c);
}

size_t PassDesc::byte_size() const { return size_t(width) * size_t(height) * pixel_bytes(); }

std::string PassDesc::validate() const {
  if (width < 0 || height < 0 || width > kMaxImageSide || height > kMaxImageSide ||
      int64_t(width) * height > kMaxImagePixels)
    return fmt::format("size {}x{} out of range (each side 0..{})", width, height, kMaxImageSide);
  const PassKindInfo* k = find_pass_kind(uint8_t(kind));
  if (!k) return "unknown pass kind";
  if (channels < k->min_channels || channels > k->max_channels)
    return fmt::format(fmt::runtime(k->channels_error), channels);
  if (k->min_full_scale <= k->max_full_scale && (full_scale < k->min_full_scale || full_scale > k->max_full_scale))
    return fmt::format(fmt::runtime(k->full_scale_error), full_scale);
  return {};
}

}  // namespace dhr

namespace dhr {

ImageU8 pass_plane(const PassBuffer& b, int index) {
  const PassLayout layout = b.desc.layout();
  if (layout == PassLayout::Bitmask)
    fail("pass_plane: a {} bitmask has no 8-bit planes (unpack its bits instead)", pass_kind_name(b.desc.kind));
  const int planes = layout == PassLayout::Planes8 || layout == PassLayout::Code16 ? b.desc.channels : 1;
  if (index < 0 || index >= planes) fail("pass_plane: plane {} out of range 0..{}", index, planes - 1);
  ImageU8 img(b.desc.width, b.desc.height);
  const size_t n = img.size();
  if (b.bytes.size() < (size_t(index) + 1) * n)
    fail("pass_plane: buffer holds {} bytes, plane {} needs {}", b.bytes.size(), index, (size_t(index) + 1) * n);
  std::copy_n(b.bytes.begin() + std::ptrdiff_t(size_t(index) * n), n, img.data());
  return img;
}

}  // namespace dhr
