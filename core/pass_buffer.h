// What a server pass produces and a codec carries. Canonical layouts (row-major, top row first):
// - Visibility: the paper's bitmask, interleaved per pixel: ceil(channels/8) bytes per pixel,
//   bit l (little-endian across the pixel's bytes) = light l visible. channels = lights, 1..64.
// - SoftVisibility: one 8-bit plane per light (planar), values 0..full_scale = visible fraction.
// - Ao: one byte per pixel, 0..full_scale; O = value / full_scale (full_scale = N rays before
//   denoising, 255 after).
// - Colour: RGB8 interleaved, sRGB encoded (the remote-rendering baseline's frame).
// - Depth: the remote baseline's depth, sent with its colour when the client's predictor
//   reprojects with depth (core/depth_pass.h): a code of full_scale bits (8..16) per pixel (0: no
//   surface, else inverse depth) as two planes, the high bytes, then the low bytes. channels = 2.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace dhr {

enum class PassKind : uint8_t { Visibility = 1, SoftVisibility = 2, Ao = 3, Colour = 4, Depth = 5 };

const char* pass_kind_name(PassKind kind);

struct PassDesc {
  PassKind kind = PassKind::Ao;
  int width = 0;
  int height = 0;
  int channels = 1;      // lights for (Soft)Visibility, 1 for Ao, 3 for Colour, 2 for Depth
  int full_scale = 255;  // Ao and SoftVisibility: the value that means 1.0; Depth: its code's bits
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
// Plane `index` of an 8-bit buffer (Ao: 0; SoftVisibility: the light) as an image, values as
// stored (0..full_scale). Throws dhr::Error for a bitmask (Visibility) or an index out of range.
Image<uint8_t> pass_plane(const PassBuffer& buffer, int index);

}  // namespace dhr
