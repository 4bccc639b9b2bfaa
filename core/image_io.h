// Reading and writing images through OpenImageIO: PNG for 8-bit, EXR for float.
// Every failure throws dhr::Error naming the file and what went wrong.
#pragma once

#include "core/image.h"

#include <string>

namespace dhr {

void write_png(const std::string& path, const ImageU8& image);
void write_png(const std::string& path, const ImageRGB8& image);
void write_exr(const std::string& path, const ImageF& image);
void write_exr(const std::string& path, const ImageVec3& image);

// Any format OpenImageIO reads, converted to 8-bit RGB (grey is replicated, alpha dropped).
ImageRGB8 read_rgb8(const std::string& path);

// 8 bits per channel, RGBA (alpha 255 where the file has none). Sizes are checked before
// allocating. `has_alpha` tells whether the file had an alpha channel.
struct Rgba8Image {
  int width = 0;
  int height = 0;
  bool has_alpha = false;
  std::vector<uint8_t> rgba;
};
Rgba8Image read_rgba8(const std::string& path);

}  // namespace dhr
