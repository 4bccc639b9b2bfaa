// Checks of a results folder written by `dhrbench run` (results.json and frames.csv) before
// anything reads it for a report or a merge: every problem is a dhr::Error naming the file, and
// the line, run or field (docs/architecture.md, "Untrusted input"). A folder that passes holds
// every run once, each with its metrics or its error, and exactly one well-formed frames.csv row
// per displayed frame of each run.
#pragma once

#include <nlohmann/json.hpp>

#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace dhr {

// results.json's shape: an object with "context" and "experiment" objects and a "runs" list of
// run records, each with a unique "id" that can name a file (no '/', not "." or ".."), a
// "scene" and a "label" string, and either "metrics" (an object whose "frames_displayed" is a
// whole number >= 0) or "error" (a string). `path` names the file in errors.
void check_results_json(const nlohmann::json& results, const std::string& path);

// frames.csv split into records (RFC 4180 quoting; a newline inside quotes belongs to the field).
struct FramesCsv {
  std::string header;                                    // with its newline
  std::map<std::string, std::vector<std::string>> rows;  // run id -> its records, with newlines
};

// Parses `text` (the content of frames.csv at `path`) against the run records of a
// results.json that passed check_results_json: a header whose first column is "run"; every
// record complete (ends with a newline, closes its quotes) with as many fields as the header;
// every record of a run of results.json; per run with metrics exactly metrics.frames_displayed
// records, and none for a run that failed.
FramesCsv check_frames_csv(std::string_view text, const nlohmann::json& results, const std::string& path);

}  // namespace dhr
