// Reading JSON that comes from outside (scene and experiment files, results, --set values, link
// configurations, live control messages): every such document goes through parse_json, which
// bounds its nesting depth before parsing, names its source in every error, and never prints
// more than a short excerpt of a value (docs/architecture.md, "Untrusted input").
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <string_view>

namespace dhr {

// The deepest nesting of arrays and objects accepted. The project's own files nest at most 6
// levels; 64 leaves room for any hand-written file and keeps every recursive walk (dumping,
// comparing, destroying) far from the stack's limit.
constexpr int kMaxJsonDepth = 64;

// Parses `text` as one JSON document. Throws dhr::Error naming `source` (a file path, or a
// description such as "--set run.frames") when the text is nested deeper than `max_depth`,
// is not valid JSON, or holds a number out of range (1e400). With `allow_comments`, // and /* */
// comments are skipped.
nlohmann::json parse_json(std::string_view text, const std::string& source, bool allow_comments = false,
                          int max_depth = kMaxJsonDepth);

// Reads and parses the file at `path` (errors name the path; a missing or unreadable file too).
// A whole file's bytes; throws dhr::Error naming the file when it cannot be opened or read.
std::string read_text_file(const std::string& path);

nlohmann::json read_json_file(const std::string& path, bool allow_comments = false, int max_depth = kMaxJsonDepth);

// The nesting depth of `text` (arrays and objects, outside strings and // or /* */ comments),
// counted without parsing; stops counting at `limit` + 1.
int json_depth(std::string_view text, int limit = kMaxJsonDepth);

// A value for an error message: its JSON text, cut to `max_chars` with "..." when longer.
std::string json_excerpt(const nlohmann::json& value, size_t max_chars = 60);

// A string from a file for an error message (a key, a name): cut to `max_chars` with "..." when longer.
std::string text_excerpt(std::string_view text, size_t max_chars = 60);

// Creates the output folder `dir` (and its parents) for the command-line option `option`
// ("--out"). Throws dhr::Error naming both when a file of that name is in the way or the
// folder cannot be created, instead of a raw filesystem exception.
void make_output_dir(const std::string& dir, const std::string& option);

}  // namespace dhr
