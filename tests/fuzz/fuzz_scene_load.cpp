// libFuzzer target: load_scene() on arbitrary scene files. Every input either loads or throws
// one dhr::Error whose message names the file with no overlong line; any other exception, a
// crash, a hang or a sanitizer report is a finding. Two kinds of input are only parsed, since
// they would fuzz something other than the reader: a string that could reach a file outside
// the input's empty folder (absolute, or with ".."), which would import any model or image on
// the machine; and large repeat counts or shape resolutions, legal but building millions of
// triangles.
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/scene/scene_load.h"
#include "tests/fuzz/fuzz_files.h"

#include <string>

namespace {

bool only_parse(const nlohmann::json& j) {
  if (j.is_string()) {
    const std::string& s = j.get_ref<const std::string&>();
    return (!s.empty() && s[0] == '/') || s.find("..") != std::string::npos;
  }
  if (j.is_object()) {
    for (const auto& [k, v] : j.items()) {
      if ((k == "count" || k == "segments" || k == "rings") && v.is_number() && v.get<double>() > 64 &&
          v.get<double>() <= 10000)
        return true;
      if (only_parse(v)) return true;
    }
  } else if (j.is_array()) {
    for (const auto& v : j)
      if (only_parse(v)) return true;
  }
  return false;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static dhr::fuzz::InputFile file("fuzz-input-scene.json");
  const std::string& path = file.write(data, size);
  try {
    // The recursion in only_parse is bounded: read_json_file refuses more than 64 levels.
    if (only_parse(dhr::read_json_file(path))) return 0;
  } catch (const dhr::Error& e) {
    dhr::fuzz::check_message(e.what(), path, 600);  // load_scene must fail the same way below
  }
  try {
    const dhr::Scene scene = dhr::load_scene(path, dhr::SceneSearchPath{});
    DHR_FUZZ_CHECK(scene.source_path == path);
  } catch (const dhr::Error& e) {
    dhr::fuzz::check_message(e.what(), path, 1200);
  }
  return 0;
}
