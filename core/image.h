// Typed 2D buffers and views. Pixel (0, 0) is the top-left corner; rows are contiguous.
// Sizes are checked before anything is allocated (see check_image_size).
#pragma once

#include <glm/glm.hpp>

#include <cstddef>
#include <cstdint>
#include <span>
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

  void resize(int width, int height, const T& fill = T{}) {
    check_image_size(width, height);
    width_ = width;
    height_ = height;
    pixels_.assign(size_t(width) * size_t(height), fill);
  }
  int width() const { return width_; }
  int height() const { return height_; }
  size_t size() const { return pixels_.size(); }
  bool empty() const { return pixels_.empty(); }
  bool same_size(int w, int h) const { return width_ == w && height_ == h; }
  template <class U>
  bool same_size(const Image<U>& other) const { return same_size(other.width(), other.height()); }

  T* data() { return pixels_.data(); }
  const T* data() const { return pixels_.data(); }
  T& operator()(int x, int y) { return pixels_[size_t(y) * width_ + x]; }
  const T& operator()(int x, int y) const { return pixels_[size_t(y) * width_ + x]; }
  T& operator[](size_t i) { return pixels_[i]; }
  const T& operator[](size_t i) const { return pixels_[i]; }
  std::span<T> row(int y) { return {pixels_.data() + size_t(y) * width_, size_t(width_)}; }
  std::span<const T> row(int y) const { return {pixels_.data() + size_t(y) * width_, size_t(width_)}; }
  std::vector<T>& pixels() { return pixels_; }
  const std::vector<T>& pixels() const { return pixels_; }
  void fill(const T& value) { std::fill(pixels_.begin(), pixels_.end(), value); }

  ImageView<T> view() { return {pixels_.data(), width_, height_, width_}; }
  ImageView<const T> view() const { return {pixels_.data(), width_, height_, width_}; }

  friend bool operator==(const Image& a, const Image& b) {
    return a.width_ == b.width_ && a.height_ == b.height_ && a.pixels_ == b.pixels_;
  }

 private:
  int width_ = 0;
  int height_ = 0;
  std::vector<T> pixels_;
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
  bool get(int x, int y) const {
    return (words_[size_t(y) * words_per_row_ + (x >> 6)] >> (x & 63)) & 1u;
  }
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
