// libFuzzer target: load_experiment() on arbitrary experiment files, with and without --set
// overrides taken from the input's last line. Every input either loads (and then every run's
// settings are in range) or throws one dhr::Error whose message names the file or the --set
// key with no overlong line; any other exception, a crash, a hang or a sanitizer report is a
// finding.
#include "core/base/error.h"
#include "core/experiment/experiment.h"
#include "tests/fuzz/fuzz_files.h"

#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static dhr::fuzz::InputFile file("fuzz-input-experiment.json");
  const std::string& path = file.write(data, size);
  std::vector<std::string> overrides;
  // A last line "#set key=value" also goes through --set (apply_override); the JSON reader
  // sees it as a syntax error unless it is inside a comment, so seeds put it after "//".
  const std::string text(reinterpret_cast<const char*>(data), size);
  if (const size_t at = text.rfind("#set "); at != std::string::npos && text.find('\n', at) == std::string::npos)
    overrides.push_back(text.substr(at + 5));
  try {
    const dhr::Experiment e = dhr::load_experiment(path, overrides);
    DHR_FUZZ_CHECK(!e.scenes.empty());
    DHR_FUZZ_CHECK(e.runs.size() <= 10000);
    for (const auto& run : e.runs) {
      DHR_FUZZ_CHECK(run.config.width >= 8 && run.config.width <= 7680);
      DHR_FUZZ_CHECK(run.config.frames >= 1 && run.config.frames <= 100000);
      DHR_FUZZ_CHECK(run.config.downlink.loss_rate >= 0.0 && run.config.downlink.loss_rate <= 1.0);
    }
  } catch (const dhr::Error& e) {
    const std::string m = e.what();
    // Problems of a --set value name its key; all others name the file.
    if (m.rfind("--set '", 0) == 0)
      dhr::fuzz::check_message(m, "", 600);
    else
      dhr::fuzz::check_message(m, path, 1200);
  }
  return 0;
}
