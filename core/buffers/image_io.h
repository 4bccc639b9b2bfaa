// Reading and writing images through OpenImageIO: PNG for 8-bit, EXR for float.
// Every failure throws dhr::Error naming the file and what went wrong.
#pragma once

#include "core/buffers/image.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dhr {

void write_png(const std::string& path, const ImageU8& image);
void write_png(const std::string& path, const ImageRGB8& image);
void write_exr(const std::string& path, const ImageF& image);
void write_exr(const std::string& path, const ImageVec3& image);

// Any format OpenImageIO reads, converted to 8-bit RGB (grey is replicated, alpha dropped: the
// colour is taken as stored, never composited over a background or multiplied by alpha).
ImageRGB8 read_rgb8(const std::string& path);

// 8 bits per channel, RGBA with unassociated alpha (the colour as stored in PNG and other 8-bit
// files, not premultiplied; alpha 255 where the file has none). Float files (EXR, float TIFF,
// HDR) are linear: colour divided by alpha where OpenEXR premultiplied it, clamped to [0, 1] and
// encoded with the sRGB curve; a NaN or infinite value is refused, naming the pixel. Sizes are
// checked before allocating. `has_alpha` tells whether the file had an alpha channel.
struct Rgba8Image {
  int width = 0;
  int height = 0;
  bool has_alpha = false;
  std::vector<uint8_t> rgba;
};
Rgba8Image read_rgba8(const std::string& path);
// The same, from an image file's bytes in memory (a model's embedded texture); `format` is the
// file's extension ("png", "jpg"), `name` names it in errors.
Rgba8Image read_rgba8_memory(const std::string& name, const std::string& format, const uint8_t* data, size_t size);

}  // namespace dhr
