// libFuzzer target: the checks 'dhrbench report' and 'dhrbench merge' run on a results folder
// (core/results/results_check.h). The input is results.json, then a line "#frames.csv", then frames.csv.
// Every input either passes (and then every run has its metrics or its error, and frames.csv
// holds exactly one row per displayed frame of each run) or throws one dhr::Error naming the
// file; any other exception, a crash, a hang or a sanitizer report is a finding.
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/results/results_check.h"
#include "tests/fuzz/fuzz_files.h"

#include <string>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const std::string sep = "\n#frames.csv\n";
  const size_t at = text.find(sep);
  const std::string results_text = text.substr(0, at);
  const std::string frames_text = at == std::string::npos ? "" : text.substr(at + sep.size());
  const std::string results_path = "fuzz/results.json", frames_path = "fuzz/frames.csv";
  nlohmann::json results;
  try {
    results = dhr::parse_json(results_text, results_path);
    dhr::check_results_json(results, results_path);
  } catch (const dhr::Error& e) {
    dhr::fuzz::check_message(e.what(), results_path, 600);
    return 0;
  }
  try {
    const dhr::FramesCsv frames = dhr::check_frames_csv(frames_text, results, frames_path);
    size_t rows = 0;
    for (const auto& [id, records] : frames.rows) {
      rows += records.size();
      for (const auto& r : records) DHR_FUZZ_CHECK(!r.empty() && r.back() == '\n');
    }
    size_t expected = 0;
    for (const auto& run : results.at("runs"))
      if (run.contains("metrics")) expected += run.at("metrics").at("frames_displayed").get<size_t>();
    DHR_FUZZ_CHECK(rows == expected);
  } catch (const dhr::Error& e) {
    dhr::fuzz::check_message(e.what(), frames_path, 600);
  }
  return 0;
}
