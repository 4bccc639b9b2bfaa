#include "core/base/json_io.h"

#include "core/base/error.h"

#include <filesystem>
#include <fstream>
#include <sstream>

namespace dhr {

int json_depth(std::string_view text, int limit) {
  int depth = 0, deepest = 0;
  bool in_string = false, escaped = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char ch = text[i];
    if (in_string) {
      if (escaped)
        escaped = false;
      else if (ch == '\\')
        escaped = true;
      else if (ch == '"')
        in_string = false;
      continue;
    }
    if (ch == '/' && i + 1 < text.size() && (text[i + 1] == '/' || text[i + 1] == '*')) {
      // A comment, skipped as nlohmann skips it: a quote inside must not start a string that
      // would hide the brackets after it. (Outside strings '/' is never valid JSON, so this
      // changes nothing for documents read without comments: their parse fails there.)
      if (text[i + 1] == '/') {
        i = text.find_first_of("\n\r", i + 2);
      } else {
        i = text.find("*/", i + 2);
        if (i != std::string_view::npos) ++i;
      }
      if (i == std::string_view::npos) break;
      continue;
    }
    if (ch == '"') {
      in_string = true;
    } else if (ch == '[' || ch == '{') {
      deepest = std::max(deepest, ++depth);
      if (deepest > limit) return deepest;
    } else if (ch == ']' || ch == '}') {
      if (depth > 0) --depth;
    }
  }
  return deepest;
}

namespace {

// nlohmann's messages quote the token being read, which may be a whole long string: keep them short.
std::string short_message(const std::string& what) {
  constexpr size_t kMax = 240;
  return what.size() <= kMax ? what : what.substr(0, kMax) + "...";
}

}  // namespace

nlohmann::json parse_json(std::string_view text, const std::string& source, bool allow_comments, int max_depth) {
  // The depth scan skips comments (and strings), so that neither can hide brackets from it.
  if (json_depth(text, max_depth) > max_depth)
    fail("{}: JSON nested deeper than {} levels of arrays and objects (the limit for every JSON dhrbench reads)",
         source, max_depth);
  try {
    return nlohmann::json::parse(text.begin(), text.end(), nullptr, true, allow_comments);
  } catch (const nlohmann::json::exception& e) {
    fail("{}: not valid JSON: {}", source, short_message(e.what()));
  }
}

std::string read_text_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail("{}: cannot open the file", path);
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) fail("{}: cannot read the file", path);
  return ss.str();
}

nlohmann::json read_json_file(const std::string& path, bool allow_comments, int max_depth) {
  return parse_json(read_text_file(path), path, allow_comments, max_depth);
}

std::string text_excerpt(std::string_view text, size_t max_chars) {
  return text.size() <= max_chars ? std::string(text) : std::string(text.substr(0, max_chars)) + "...";
}

std::string json_excerpt(const nlohmann::json& value, size_t max_chars) {
  std::string s = value.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  if (s.size() > max_chars) s = s.substr(0, max_chars) + "...";
  return s;
}

void make_output_dir(const std::string& dir, const std::string& option) {
  namespace fs = std::filesystem;
  if (dir.empty()) fail("{}: an empty folder name", option);
  std::error_code ec;
  // The first part of the path that exists must be a folder (or a link to one).
  for (fs::path p = fs::path(dir).lexically_normal(); !p.empty(); p = p.parent_path()) {
    if (fs::exists(p, ec)) {
      if (!fs::is_directory(p, ec))
        fail("{} {}: {} is a file, not a folder: give a folder's name", option, text_excerpt(dir, 200),
             text_excerpt(p.string(), 200));
      break;
    }
    if (p == p.parent_path()) break;
  }
  fs::create_directories(dir, ec);
  if (ec) fail("{} {}: cannot create the folder: {}", option, text_excerpt(dir, 200), ec.message());
}

}  // namespace dhr
