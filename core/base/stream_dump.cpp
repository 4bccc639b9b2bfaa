#include "core/base/stream_dump.h"

#include "core/base/error.h"

#include <array>

namespace dhr {
namespace {

template <size_t N>
void put_le(std::array<char, N>& b, size_t at, uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) b[at + size_t(i)] = char((v >> (8 * i)) & 0xFF);
}

}  // namespace

StreamDump::StreamDump(const std::string& path, const std::string& format, int width, int height, int fps)
    : path_(path), ivf_(format == "ivf") {
  if (format != "h264" && format != "hevc" && format != "ivf")
    fail("stream dump {}: unknown stream format '{}' (valid: h264, hevc, ivf)", path, format);
  out_.open(path, std::ios::binary | std::ios::trunc);
  if (!out_) fail("stream dump: cannot create {}", path);
  if (!ivf_) return;
  std::array<char, 32> h{};
  h[0] = 'D', h[1] = 'K', h[2] = 'I', h[3] = 'F';
  put_le(h, 4, 0, 2);   // version
  put_le(h, 6, 32, 2);  // header size
  h[8] = 'A', h[9] = 'V', h[10] = '0', h[11] = '1';
  put_le(h, 12, uint64_t(width), 2);
  put_le(h, 14, uint64_t(height), 2);
  put_le(h, 16, uint64_t(fps), 4);  // time base: fps / 1, one tick per frame
  put_le(h, 20, 1, 4);
  put_le(h, 24, 0, 4);  // frame count: readers do not need it
  out_.write(h.data(), h.size());
  if (!out_) fail("stream dump: cannot write {}", path);
}

void StreamDump::append(std::span<const uint8_t> frame, uint64_t pts) {
  if (ivf_) {
    std::array<char, 12> h{};
    put_le(h, 0, frame.size(), 4);
    put_le(h, 4, pts, 8);
    out_.write(h.data(), h.size());
  }
  out_.write(reinterpret_cast<const char*>(frame.data()), std::streamsize(frame.size()));
  if (!out_) fail("stream dump: cannot write {}", path_);
}

}  // namespace dhr
