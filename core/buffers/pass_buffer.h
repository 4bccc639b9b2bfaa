// What a server pass produces and a codec carries. Canonical layouts (row-major, top row first):
// - Visibility: the paper's bitmask, interleaved per pixel: ceil(channels/8) bytes per pixel,
//   bit l (little-endian across the pixel's bytes) = light l visible. channels = lights, 1..64.
// - SoftVisibility: one 8-bit plane per light (planar), values 0..full_scale = visible fraction.
// - Ao: one byte per pixel, 0..full_scale; O = value / full_scale (full_scale = N rays before
//   denoising, 255 after).
// - Colour: RGB8 interleaved, sRGB encoded (the remote-rendering baseline's frame).
// - Depth: the remote baseline's depth, sent with its colour when the client's predictor
//   reprojects with depth (core/buffers/depth_pass.h): a code of full_scale bits (8..16) per pixel (0: no
//   surface, else inverse depth) as two planes, the high bytes, then the low bytes. channels = 2.
//
// A kind is one row of one table (pass_kinds() in core/buffers/pass_buffer.cpp): its name, its layout
// (what codecs and predictors see: they test the layout, never the kind), its meaning (what the
// denoise stage and the composite use) and the channel counts and full scales it accepts. The
// kind is in every packet header: it tells the receiver which pass a packet belongs to.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace dhr {

enum class PassKind : uint8_t { Visibility = 1, SoftVisibility = 2, Ao = 3, Colour = 4, Depth = 5 };

// How a pass's bytes are laid out: all that codecs and predictors may depend on.
enum class PassLayout : uint8_t {
  Bitmask,  // ceil(channels / 8) bytes per pixel, one bit per channel
  Planes8,  // one 8-bit plane per channel (planar), values 0..full_scale meaning 0..1
  Rgb8,     // 8-bit RGB interleaved, sRGB encoded
  Code16,   // one code of full_scale bits per pixel as two 8-bit planes: high bytes, then low bytes
};
// What a pass is for: the denoise stage and the composite pick their work by meaning.
enum class PassMeaning : uint8_t { Visibility, Ao, Colour, Depth };

// One row of the kind table.
struct PassKindInfo {
  PassKind kind;
  const char* name;  // in messages and stream dumps: "soft_visibility"
  PassLayout layout;
  PassMeaning meaning;
  int min_channels, max_channels;      // the channel counts a description may have
  const char* channels_error;          // fmt string of the refusal, given the channel count
  int min_full_scale, max_full_scale;  // checked when min <= max
  const char* full_scale_error;        // fmt string of the refusal, given the full scale
};

// Every kind, in the order of their values; null for a value that names no kind.
const std::vector<PassKindInfo>& pass_kinds();
const PassKindInfo* find_pass_kind(uint8_t kind);

const char* pass_kind_name(PassKind kind);  // "unknown" for a value that names no kind
PassLayout pass_layout(PassKind kind);      // Planes8 for a value that names no kind
PassMeaning pass_meaning(PassKind kind);    // Ao for a value that names no kind
const char* pass_meaning_name(PassMeaning meaning);

struct PassDesc {
  PassKind kind = PassKind::Ao;
  int width = 0;
  int height = 0;
  int channels = 1;      // lights for (Soft)Visibility, 1 for Ao, 3 for Colour, 2 for Depth
  int full_scale = 255;  // Ao and SoftVisibility: the value that means 1.0; Depth: its code's bits
  PassLayout layout() const { return pass_layout(kind); }
  size_t pixel_bytes() const;  // bytes of one pixel: ceil(lights / 8) for a bitmask, else channels
  size_t byte_size() const;    // exact size of a buffer with this description
  // Empty when valid; else what is wrong (channels out of range, sizes out of range).
  std::string validate() const;
  friend bool operator==(const PassDesc&, const PassDesc&) = default;
};

struct PassBuffer {
  PassDesc desc;
  std::vector<uint8_t> bytes;  // desc.byte_size() bytes
};

class BitImage;
template <class T>
class Image;
// Plane `index` of an 8-bit buffer (Planes8: the channel; Code16: 0 high, 1 low bytes; Rgb8: 0,
// the interleaved bytes' first third) as an image, values as stored. Throws dhr::Error for a
// bitmask or an index out of range.
Image<uint8_t> pass_plane(const PassBuffer& buffer, int index);

}  // namespace dhr
