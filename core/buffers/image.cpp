#include "core/buffers/image.h"

#include "core/base/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <bit>

namespace dhr {

void check_image_size(int width, int height) {
  if (width < 0 || height < 0 || width > kMaxImageSide || height > kMaxImageSide ||
      int64_t(width) * int64_t(height) > kMaxImagePixels) {
    fail("image size {}x{} is out of range: each side must be 0..{} and the area at most {} pixels", width, height,
         kMaxImageSide, kMaxImagePixels);
  }
}

void for_chunks(size_t n, size_t elem_bytes, const std::function<void(size_t, size_t)>& fn) {
  const size_t bytes = n * elem_bytes;
  if (bytes < (size_t(1) << 20)) {
    if (n) fn(0, n);
    return;
  }
  const size_t piece = std::max<size_t>(1, (size_t(256) << 10) / std::max<size_t>(1, elem_bytes));
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, piece),
                    [&](const tbb::blocked_range<size_t>& r) { fn(r.begin(), r.end()); });
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
