#include "core/results/results_check.h"

#include "core/base/error.h"
#include "core/base/json_io.h"

#include <set>

namespace dhr {

void check_results_json(const nlohmann::json& r, const std::string& path) {
  if (!r.is_object()) fail("{}: must be a JSON object (context, experiment, runs), got {}", path, json_excerpt(r));
  for (const char* key : {"context", "experiment"})
    if (!r.contains(key) || !r.at(key).is_object())
      fail("{}: \"{}\" must be a JSON object, got {}", path, key,
           r.contains(key) ? json_excerpt(r.at(key)) : "nothing");
  if (!r.contains("runs") || !r.at("runs").is_array())
    fail("{}: \"runs\" must be a list of run records, got {}", path,
         r.contains("runs") ? json_excerpt(r.at("runs")) : "nothing");
  std::set<std::string> ids;
  const auto& runs = r.at("runs");
  for (size_t i = 0; i < runs.size(); ++i) {
    const auto& run = runs[i];
    if (!run.is_object()) fail("{}: runs[{}] must be a JSON object (a run record), got {}", path, i, json_excerpt(run));
    for (const char* key : {"id", "scene", "label"})
      if (!run.contains(key) || !run.at(key).is_string())
        fail("{}: runs[{}].{} must be a string, got {}", path, i, key,
             run.contains(key) ? json_excerpt(run.at(key)) : "nothing");
    const std::string id = run.at("id").get<std::string>();
    if (id.empty() || id == "." || id == ".." ||
        id.find_first_of(std::string_view("/\\\0,\"\n\r", 7)) != std::string::npos)
      fail(
          "{}: runs[{}].id {} cannot name a run (it names the run's files and frames.csv rows: no '/', '\\', ',', "
          "quote, newline or NUL)",
          path, i, json_excerpt(run.at("id")));
    if (!ids.insert(id).second) fail("{}: runs[{}]: the run id '{}' is given twice", path, i, text_excerpt(id));
    const bool has_metrics = run.contains("metrics"), has_error = run.contains("error");
    if (has_error && !run.at("error").is_string())
      fail("{}: runs[{}] ({}).error must be a string, got {}", path, i, id, json_excerpt(run.at("error")));
    if (!has_metrics && !has_error)
      fail(
          "{}: runs[{}] ({}) has neither \"metrics\" nor \"error\": the record is incomplete (a run always records "
          "one of them)",
          path, i, id);
    if (has_metrics) {
      const auto& m = run.at("metrics");
      if (!m.is_object()) fail("{}: runs[{}] ({}).metrics must be a JSON object, got {}", path, i, id, json_excerpt(m));
      if (!m.contains("frames_displayed") || !m.at("frames_displayed").is_number_unsigned())
        fail("{}: runs[{}] ({}).metrics.frames_displayed must be a whole number >= 0, got {}", path, i, id,
             m.contains("frames_displayed") ? json_excerpt(m.at("frames_displayed")) : "nothing");
    }
  }
}

FramesCsv check_frames_csv(std::string_view text, const nlohmann::json& results, const std::string& path) {
  FramesCsv out;
  std::map<std::string, uint64_t> expected;  // run id -> rows
  for (const auto& run : results.at("runs"))
    expected[run.at("id").get<std::string>()] =
        run.contains("metrics") ? run.at("metrics").at("frames_displayed").get<uint64_t>() : 0;
  // One pass, RFC 4180: a comma or newline inside double quotes belongs to the field.
  size_t header_fields = 0, fields = 1, quoted_newlines = 0;
  size_t line = 1;  // of the record's first line
  bool quoted = false;
  size_t start = 0;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '"')
      quoted = !quoted;
    else if (quoted)
      quoted_newlines += c == '\n';
    else if (c == ',')
      ++fields;
    if (c != '\n' || quoted) continue;
    std::string_view record = text.substr(start, i - start);
    if (!record.empty() && record.back() == '\r') record.remove_suffix(1);
    if (start == 0) {
      if (record.substr(0, 4) != "run," && record != "run")
        fail("{}: line 1: the header must start with the column \"run\", got {}", path, text_excerpt(record));
      header_fields = fields;
      out.header = std::string(text.substr(0, i + 1));
    } else {
      if (fields != header_fields)
        fail("{}: line {}: {} fields where the header has {}", path, line, fields, header_fields);
      const std::string id(record.substr(0, record.find(',')));
      if (!expected.count(id))
        fail("{}: line {}: a row of run '{}', which results.json does not hold", path, line, text_excerpt(id));
      out.rows[id].emplace_back(text.substr(start, i + 1 - start));
    }
    line += quoted_newlines + 1;
    fields = 1;
    quoted_newlines = 0;
    start = i + 1;
  }
  if (start < text.size())
    fail("{}: line {}: the file ends inside this record (cut short{}): a complete record ends with a newline", path,
         line, quoted ? ", with a quoted field open" : "");
  if (out.header.empty()) fail("{}: empty (a header is expected)", path);
  for (const auto& [id, rows] : expected) {
    const auto it = out.rows.find(id);
    const uint64_t have = it == out.rows.end() ? 0 : it->second.size();
    if (have != rows)
      fail("{}: run {} has {} row(s), but results.json says it displayed {} frame(s){}", path, id, have, rows,
           have < rows ? " (rows are missing: the file is incomplete)" : "");
  }
  return out;
}

}  // namespace dhr
