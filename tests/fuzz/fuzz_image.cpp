// libFuzzer target: the image reader (core/buffers/image_io.h) on arbitrary PNG bytes, as it reads
// scene textures and 'dhrbench compare' inputs: the chunk structure and CRCs are checked before
// the decoder sees them. Every input either decodes (a width x height RGBA image of the size it
// says) or throws one dhr::Error naming the image; anything else is a finding.
#include "core/base/error.h"
#include "core/buffers/image_io.h"
#include "tests/fuzz/fuzz_files.h"

#include <string>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const dhr::Rgba8Image img = dhr::read_rgba8_memory("fuzz-image", "png", data, size);
    DHR_FUZZ_CHECK(img.width > 0 && img.height > 0);
    DHR_FUZZ_CHECK(img.rgba.size() == size_t(img.width) * size_t(img.height) * 4);
  } catch (const dhr::Error& e) {
    dhr::fuzz::check_message(e.what(), "fuzz-image", 600);
  }
  return 0;
}
