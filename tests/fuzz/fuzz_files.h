// For the targets that fuzz file readers (fuzz_scene_load, fuzz_experiment): the input is
// written to a file in a private, otherwise empty folder, so that the reader runs exactly as it
// does on a user's file (opening, size checks, parsing) and no relative path inside it can
// reach another file.
#pragma once

#include "tests/fuzz/fuzz_common.h"

#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

namespace dhr::fuzz {

class InputFile {
 public:
  explicit InputFile(const char* name) {
    const char* tmp = std::getenv("TMPDIR");
    std::string dir = std::string(tmp && *tmp ? tmp : "/tmp") + "/dhr_fuzz_XXXXXX";
    DHR_FUZZ_CHECK(mkdtemp(dir.data()) != nullptr);
    dir_ = dir;
    path_ = dir + "/" + name;
  }
  ~InputFile() {
    std::remove(path_.c_str());
    std::remove(dir_.c_str());
  }
  const std::string& write(const uint8_t* data, size_t size) {
    std::FILE* f = std::fopen(path_.c_str(), "wb");
    DHR_FUZZ_CHECK(f != nullptr);
    DHR_FUZZ_CHECK(size == 0 || std::fwrite(data, 1, size, f) == size);
    DHR_FUZZ_CHECK(std::fclose(f) == 0);
    return path_;
  }

 private:
  std::string dir_, path_;
};

// The readers' promise about their messages: each names the file, and no line is longer than a
// few hundred characters however long the values in the file are (every value is an excerpt).
inline void check_message(std::string_view message, const std::string& path, size_t max_line) {
  DHR_FUZZ_CHECK(!message.empty());
  DHR_FUZZ_CHECK(message.find(path) != std::string_view::npos);
  size_t start = 0;
  while (start <= message.size()) {
    size_t end = message.find('\n', start);
    if (end == std::string_view::npos) end = message.size();
    if (end - start > max_line) {
      std::fprintf(stderr, "message line of %zu characters: %.200s...\n", end - start, message.data() + start);
      DHR_FUZZ_CHECK(end - start <= max_line);
    }
    start = end + 1;
  }
}

}  // namespace dhr::fuzz
