// Typed 2D buffers and views. Pixel (0, 0) is the top-left corner; rows are contiguous.
// Sizes are checked before anything is allocated (see check_image_size).
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <type_traits>
#include <utility>
#include <vector>

namespace dhr {

struct Rgb8 {
  uint8_t r = 0, g = 0, b = 0;
  friend bool operator==(const Rgb8&, const Rgb8&) = default;
};

// Largest image any buffer may have: 16384 px a side, 2^26 pixels (8192x8192) in all.
constexpr int kMaxImageSide = 16384;
constexpr int64_t kMaxImagePixels = int64_t(1) << 26;
// Throws dhr::Error when width or height is negative, above kMaxImageSide, or the product
// is above kMaxImagePixels.
void check_image_size(int width, int height);

// The allocator of image storage: growing a vector without a value default-initialises the new
// elements, so a trivially constructible pixel (float, integers, glm vectors) is left unwritten
// and its page untouched. Image::resize then writes its fill value with for_chunks, so that the
// first touch of a large new buffer, where the kernel zeroes each page, runs on every core instead
// of one (docs/performance.md, "Fresh memory, touched in parallel").
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <class U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    std::construct_at(p, std::forward<Args>(args)...);
  }
};
template <class T>
using PixelVector = std::vector<T, DefaultInitAllocator<T>>;

// Calls fn(begin, end) on pieces of [0, n) that together cover it once: on one thread when the n
// elements of elem_bytes each take less than 1 MiB, otherwise in parallel (TBB) in pieces of
// 256 KiB. For writes whose result does not depend on the order, such as a fill.
void for_chunks(size_t n, size_t elem_bytes, const std::function<void(size_t, size_t)>& fn);

// v becomes n copies of value. When it must grow, the old storage is freed first and nothing is
// copied; the values are written by for_chunks, in parallel for a large vector.
template <class T>
void fill_parallel(PixelVector<T>& v, size_t n, const T& value) {
  if (v.capacity() < n) v = PixelVector<T>();
  v.resize(n);
  T* d = v.data();
  for_chunks(n, sizeof(T), [d, &value](size_t b, size_t e) { std::fill(d + b, d + e, value); });
}

template <class T>
struct ImageView {
  T* data = nullptr;
  int width = 0;
  int height = 0;
  std::ptrdiff_t stride = 0;  // elements between rows

  T& operator()(int x, int y) const { return data[y * stride + x]; }
  std::span<T> row(int y) const { return {data + y * stride, size_t(width)}; }
  ImageView sub(int x, int y, int w, int h) const { return {data + y * stride + x, w, h, stride}; }
};

template <class T>
class Image {
 public:
  using value_type = T;
  Image() = default;
  Image(int width, int height, const T& fill = T{}) { resize(width, height, fill); }

  // Every pixel is `fill` afterwards (written in parallel for a large image: for_chunks).
  void resize(int width, int height, const T& fill = T{}) {
    check_image_size(width, height);
    width_ = height_ = 0;
    fill_parallel(pixels_, size_t(width) * size_t(height), fill);
    width_ = width;
    height_ = height;
  }
  // The size only: a pixel's value is unspecified until written, for a caller that writes every
  // pixel itself (the rasterizer's tiles). The old pixels are not kept.
  void resize_for_overwrite(int width, int height) {
    check_image_size(width, height);
    const size_t n = size_t(width) * size_t(height);
    width_ = height_ = 0;
    if (pixels_.capacity() < n) pixels_ = PixelVector<T>();  // freed first, and nothing copied
    pixels_.resize(n);
    width_ = width;
    height_ = height;
  }
  int width() const { return width_; }
  int height() const { return height_; }
  size_t size() const { return pixels_.size(); }
  bool empty() const { return pixels_.empty(); }
  bool same_size(int w, int h) const { return width_ == w && height_ == h; }
  template <class U>
  bool same_size(const Image<U>& other) const {
    return same_size(other.width(), other.height());
  }

  T* data() { return pixels_.data(); }
  const T* data() const { return pixels_.data(); }
  T& operator()(int x, int y) { return pixels_[size_t(y) * width_ + x]; }
  const T& operator()(int x, int y) const { return pixels_[size_t(y) * width_ + x]; }
  T& operator[](size_t i) { return pixels_[i]; }
  const T& operator[](size_t i) const { return pixels_[i]; }
  std::span<T> row(int y) { return {pixels_.data() + size_t(y) * width_, size_t(width_)}; }
  std::span<const T> row(int y) const { return {pixels_.data() + size_t(y) * width_, size_t(width_)}; }
  PixelVector<T>& pixels() { return pixels_; }
  const PixelVector<T>& pixels() const { return pixels_; }
  void fill(const T& value) { std::fill(pixels_.begin(), pixels_.end(), value); }

  ImageView<T> view() { return {pixels_.data(), width_, height_, width_}; }
  ImageView<const T> view() const { return {pixels_.data(), width_, height_, width_}; }

  friend bool operator==(const Image& a, const Image& b) {
    return a.width_ == b.width_ && a.height_ == b.height_ && a.pixels_ == b.pixels_;
  }

 private:
  int width_ = 0;
  int height_ = 0;
  PixelVector<T> pixels_;
};

using ImageF = Image<float>;
using ImageU8 = Image<uint8_t>;
using ImageU32 = Image<uint32_t>;
using ImageU64 = Image<uint64_t>;
using ImageRGB8 = Image<Rgb8>;
using ImageVec2 = Image<glm::vec2>;
using ImageVec3 = Image<glm::vec3>;

// One bit per pixel (one light's visibility plane), rows padded to whole 64-bit words.
class BitImage {
 public:
  BitImage() = default;
  BitImage(int width, int height) { resize(width, height); }
  void resize(int width, int height);
  int width() const { return width_; }
  int height() const { return height_; }
  int words_per_row() const { return words_per_row_; }
  bool get(int x, int y) const { return (words_[size_t(y) * words_per_row_ + (x >> 6)] >> (x & 63)) & 1u; }
  void set(int x, int y, bool value) {
    uint64_t& w = words_[size_t(y) * words_per_row_ + (x >> 6)];
    const uint64_t bit = uint64_t(1) << (x & 63);
    w = value ? (w | bit) : (w & ~bit);
  }
  size_t count_set() const;
  std::vector<uint64_t>& words() { return words_; }
  const std::vector<uint64_t>& words() const { return words_; }
  friend bool operator==(const BitImage&, const BitImage&) = default;

 private:
  int width_ = 0;
  int height_ = 0;
  int words_per_row_ = 0;
  std::vector<uint64_t> words_;
};

}  // namespace dhr
