#include "core/image.h"

#include "core/error.h"

#include <bit>

namespace dhr {

void check_image_size(int width, int height) {
  if (width < 0 || height < 0 || width > kMaxImageSide || height > kMaxImageSide ||
      int64_t(width) * int64_t(height) > kMaxImagePixels) {
    fail("image size {}x{} is out of range: each side must be 0..{} and the area at most {} pixels",
         width, height, kMaxImageSide, kMaxImagePixels);
  }
}

void BitImage::resize(int width, int height) {
  check_image_size(width, height);
  width_ = width;
  height_ = height;
  words_per_row_ = (width + 63) / 64;
  words_.assign(size_t(words_per_row_) * size_t(height), 0);
}

size_t BitImage::count_set() const {
  size_t n = 0;
  for (uint64_t w : words_) n += size_t(std::popcount(w));
  return n;
}

}  // namespace dhr
