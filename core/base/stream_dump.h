// Writes a video pass's encoded frames as a file that standard tools read (dhrbench run
// --dump-streams; docs/adding-a-backend.md): the frames one after the other for an Annex B
// format ("h264", "hevc"), or an IVF file ("ivf": the 32-byte header, then per frame a 12-byte
// header of size and timestamp; fourcc AV01) for AV1, whose temporal units have no start codes.
#pragma once

#include <cstdint>
#include <fstream>
#include <span>
#include <string>

namespace dhr {

class StreamDump {
 public:
  // Creates `path` (truncating it); `format` is a Codec::stream_format(). Throws dhr::Error when
  // the file cannot be written or the format is unknown.
  StreamDump(const std::string& path, const std::string& format, int width, int height, int fps);
  // Appends one encode() output with its frame index as timestamp.
  void append(std::span<const uint8_t> frame, uint64_t pts);

 private:
  std::string path_;
  bool ivf_ = false;
  std::ofstream out_;
};

}  // namespace dhr
