#include "core/experiment/experiment.h"

#include "core/base/error.h"
#include "core/base/json_io.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>

namespace dhr {

namespace {

std::string join_keys(const std::vector<std::string>& keys) {
  std::string s;
  for (const auto& k : keys) s += (s.empty() ? "" : ", ") + k;
  return s;
}

// Typed readers that record problems instead of throwing, so that all are reported at once.
struct Reader {
  const nlohmann::json& j;
  std::string where;
  std::vector<std::string>& problems;

  void keys(const std::vector<std::string>& valid) {
    if (!j.is_object()) {
      problems.push_back(fmt::format("{}: must be a JSON object, got {}", where, json_excerpt(j)));
      return;
    }
    for (const auto& [k, v] : j.items())
      if (std::find(valid.begin(), valid.end(), k) == valid.end())
        problems.push_back(fmt::format("{}.{}: unknown key (valid: {})", where, text_excerpt(k), join_keys(valid)));
  }
  bool has(const char* k) const { return j.is_object() && j.contains(k); }
  void string(const char* k, std::string& out, const std::vector<std::string>& choices = {}) {
    if (!has(k)) return;
    const auto& v = j.at(k);
    if (!v.is_string() ||
        (!choices.empty() && std::find(choices.begin(), choices.end(), v.get<std::string>()) == choices.end())) {
      problems.push_back(fmt::format("{}.{} = {}: must be {}", where, k, json_excerpt(v),
                                     choices.empty() ? "a string" : "one of " + join_keys(choices)));
      return;
    }
    out = v.get<std::string>();
  }
};

// A relative data path (a latency trace) as given when it exists from the working folder,
// else beside the experiment file, else in the repository.
std::string resolve_data_path(const std::string& file, const std::string& experiment_path) {
  namespace fs = std::filesystem;
  if (file.empty() || fs::path(file).is_absolute() || fs::exists(file)) return file;
  for (const fs::path& base : {fs::path(experiment_path).parent_path(), fs::path(DHR_SOURCE_DIR)}) {
    if (fs::exists(base / file)) return (base / file).string();
  }
  return file;  // validation reports it missing
}

// How a version-1 file's keys for per-pass backends are written in version 2, one line per key
// used (in "run", in configurations' "set" and in "sweep").
std::vector<std::string> v1_key_hints(const nlohmann::json& j) {
  std::vector<std::string> hints;
  auto note = [&](const std::string& where, const std::string& key) {
    const std::string v2 = v2_spelling(key);
    if (v2.empty()) return;
    const std::string hint = fmt::format("{}: \"{}\" is written \"{}\" in version 2", where, key, v2);
    if (std::find(hints.begin(), hints.end(), hint) == hints.end()) hints.push_back(hint);
  };
  if (!j.is_object()) return hints;
  if (j.contains("run") && j.at("run").is_object())
    for (const auto& [k, v] : j.at("run").items()) note("run", k);
  if (j.contains("configurations") && j.at("configurations").is_array())
    for (const auto& c : j.at("configurations"))
      if (c.is_object() && c.contains("set") && c.at("set").is_object())
        for (const auto& [k, v] : c.at("set").items()) note("configurations", k);
  if (j.contains("sweep") && j.at("sweep").is_object())
    for (const auto& [k, v] : j.at("sweep").items()) note("sweep", k);
  return hints;
}

}  // namespace

void set_dotted(nlohmann::json& target, const std::string& dotted, const nlohmann::json& value) {
  nlohmann::json* node = &target;
  size_t start = 0;
  for (;;) {
    const size_t dot = dotted.find('.', start);
    const std::string key = dotted.substr(start, dot == std::string::npos ? std::string::npos : dot - start);
    if (key.empty()) fail("'{}': empty component in a dotted key", text_excerpt(dotted));
    if (!node->is_object()) *node = nlohmann::json::object();
    if (dot == std::string::npos) {
      (*node)[key] = value;
      return;
    }
    node = &(*node)[key];
    start = dot + 1;
  }
}

void apply_override(nlohmann::json& experiment, const std::string& assignment, const std::string& under) {
  const size_t eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    fail("--set '{}': expected key=value, e.g. {}", text_excerpt(assignment),
         under.empty() ? "run.frames=10 or run.passes.ao.codec.name=zstd" : "frames=10 or passes.ao.codec.name=zstd");
  const std::string key = assignment.substr(0, eq), text = assignment.substr(eq + 1);
  // A value nested too deeply is refused, not taken as a string: it was meant as JSON.
  if (json_depth(text) > kMaxJsonDepth)
    fail(
        "--set '{}': the value is nested deeper than {} levels of arrays and objects (the limit for every JSON "
        "dhrbench reads)",
        text_excerpt(key), kMaxJsonDepth);
  nlohmann::json value = nlohmann::json::parse(text, nullptr, false);
  if (value.is_discarded()) value = text;  // a bare word: a string
  try {
    if (under.empty()) {
      set_dotted(experiment, key, value);
    } else {
      if (!experiment.contains(under) || !experiment.at(under).is_object())
        experiment[under] = nlohmann::json::object();
      set_dotted(experiment.at(under), key, value);
    }
  } catch (const Error& e) {
    fail("--set {}", e.what());
  }
}

bool is_plain_name(const std::string& name) {
  if (name.empty() || name.size() > 64) return false;
  auto alnum = [](char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9'); };
  if (!alnum(name[0]) && name[0] != '_') return false;
  for (char c : name)
    if (!alnum(c) && c != '_' && c != '-' && c != '.' && c != '+') return false;
  return true;
}

Experiment load_experiment(const std::string& path, const std::vector<std::string>& overrides) {
  // Depth-bounded, comments allowed; every parse error names the file.
  nlohmann::json j = read_json_file(path, /*allow_comments=*/true);
  for (const auto& o : overrides) apply_override(j, o);

  Experiment e;
  e.path = path;
  e.source = j;
  std::vector<std::string> problems;
  Reader top{j, path, problems};
  top.keys({"version", "name", "description", "scenes", "run", "networks", "sweep", "configurations", "curves",
            "answer", "notes"});
  if (!j.is_object()) fail("{}: an experiment must be a JSON object", path);
  int version = kExperimentVersion;
  if (!j.contains("version")) {
    problems.push_back(fmt::format("{}: \"version\": {} is required", path, kExperimentVersion));
  } else if (!j.at("version").is_number_integer() || j.at("version").get<int64_t>() < 1 ||
             j.at("version").get<int64_t>() > kExperimentVersion) {
    problems.push_back(fmt::format("{}: version {} is not supported (this dhrbench reads versions 1..{})", path,
                                   json_excerpt(j.at("version")), kExperimentVersion));
  } else {
    version = j.at("version").get<int>();
  }
  if (version == 1) e.hints = v1_key_hints(j);
  top.string("name", e.name);
  top.string("description", e.description);
  const bool named = !e.name.empty();
  if (!named) e.name = std::filesystem::path(path).stem().string();
  // The name becomes a folder (out/<name>) and part of file names: a plain name only.
  if (!is_plain_name(e.name))
    problems.push_back(fmt::format("{}: {} '{}' is not a plain name: {} (it names the output folder out/<name>)", path,
                                   named ? "\"name\"" : "the file's stem (no \"name\" given)", text_excerpt(e.name),
                                   kPlainNameRule));
  if (!j.contains("scenes") || !j.at("scenes").is_array() || j.at("scenes").empty()) {
    problems.push_back(fmt::format("{}.scenes: must be a non-empty list of scene files or built-in names", path));
  } else {
    for (const auto& s : j.at("scenes")) {
      if (!s.is_string())
        problems.push_back(fmt::format("{}.scenes: {} is not a string", path, json_excerpt(s)));
      else
        e.scenes.push_back(s.get<std::string>());
    }
  }
  const nlohmann::json base = j.value("run", nlohmann::json::object());
  const nlohmann::json networks = j.value("networks", nlohmann::json::object());
  if (!networks.is_object()) problems.push_back(fmt::format("{}.networks: must be an object of named networks", path));

  // Configurations: each is a set of dotted assignments.
  struct Configuration {
    std::string name, family;
    nlohmann::json set;
    std::vector<std::string> scenes;  // empty: every scene
  };
  std::vector<Configuration> configs;
  if (j.contains("configurations")) {
    const auto& list = j.at("configurations");
    if (!list.is_array() || list.empty()) {
      problems.push_back(fmt::format("{}.configurations: must be a non-empty list", path));
    } else {
      for (size_t i = 0; i < list.size(); ++i) {
        Reader r{list[i], fmt::format("{}.configurations[{}]", path, i), problems};
        r.keys({"name", "family", "set", "scenes"});
        std::string name = fmt::format("c{}", i);
        r.string("name", name);
        std::string family = name;
        r.string("family", family);
        nlohmann::json set =
            list[i].is_object() ? list[i].value("set", nlohmann::json::object()) : nlohmann::json::object();
        if (!set.is_object()) problems.push_back(fmt::format("{}.configurations[{}].set: must be an object", path, i));
        std::vector<std::string> only;
        if (r.has("scenes")) {
          const auto& sc = list[i].at("scenes");
          if (!sc.is_array())
            problems.push_back(fmt::format("{}.configurations[{}].scenes: must be a list of scenes", path, i));
          else
            for (const auto& x : sc) {
              if (!x.is_string() || std::find(e.scenes.begin(), e.scenes.end(), x.get<std::string>()) == e.scenes.end())
                problems.push_back(fmt::format("{}.configurations[{}].scenes: {} is not one of the experiment's scenes",
                                               path, i, json_excerpt(x)));
              else
                only.push_back(x.get<std::string>());
            }
        }
        for (const auto& c : configs)
          if (c.name == name)
            problems.push_back(
                fmt::format("{}.configurations[{}]: the name '{}' is given twice: configurations are told "
                            "apart by name (in the tables and the report's curves)",
                            path, i, text_excerpt(name)));
        configs.push_back({name, family, set.is_object() ? set : nlohmann::json::object(), only});
      }
    }
  } else {
    configs.push_back({"", "", nlohmann::json::object(), {}});
  }
  // The sweep: a Cartesian product, applied on top of each configuration.
  std::vector<std::pair<std::string, std::vector<nlohmann::json>>> axes;
  if (j.contains("sweep")) {
    const auto& sweep = j.at("sweep");
    if (!sweep.is_object())
      problems.push_back(fmt::format("{}.sweep: must be an object of dotted key: [values]", path));
    else
      for (const auto& [k, v] : sweep.items()) {
        if (!v.is_array() || v.empty())
          problems.push_back(fmt::format("{}.sweep.{}: must be a non-empty list of values", path, text_excerpt(k)));
        else
          axes.emplace_back(k, std::vector<nlohmann::json>(v.begin(), v.end()));
      }
  }
  // Configurations x sweep values x scenes, counted without overflow: the count stops growing
  // once it passes the limit (8 keys of 256 values would wrap a 64-bit product to 0).
  size_t product = std::max<size_t>(1, e.scenes.size());
  bool over = false;
  for (size_t factor : [&] {
         std::vector<size_t> f{configs.size()};
         for (const auto& a : axes) f.push_back(a.second.size());
         return f;
       }()) {
    if (factor != 0 && product > kMaxRuns / factor)
      over = true;
    else
      product *= factor;
  }
  if (over || product > kMaxRuns) {
    std::string sizes = fmt::format("{} scene(s) x {} configuration(s)", e.scenes.size(), configs.size());
    for (const auto& a : axes) sizes += fmt::format(" x {} ({} values)", text_excerpt(a.first), a.second.size());
    problems.push_back(fmt::format("{}: more than {} runs ({}): split the experiment", path, kMaxRuns, sizes));
    axes.clear();  // never expanded
  }

  // What "curves" and "answer" may name: a swept key, or one a configuration sets.
  auto swept = [&](const nlohmann::json& key) {
    return key.is_string() &&
           std::any_of(axes.begin(), axes.end(), [&](const auto& a) { return a.first == key.get<std::string>(); });
  };
  auto swept_or_set = [&](const nlohmann::json& key) {
    return swept(key) || (key.is_string() && std::any_of(configs.begin(), configs.end(), [&](const auto& c) {
                            return c.set.contains(key.get<std::string>());
                          }));
  };

  // Rate-quality curves: "vary" names keys that are swept or set by configurations; the anchor is
  // a family.
  if (j.contains("curves")) {
    const auto& cv = j.at("curves");
    Reader r{cv, path + ".curves", problems};
    if (!cv.is_object())
      problems.push_back(fmt::format("{}.curves: must be an object {{\"vary\": [keys], \"anchor\": family}}", path));
    r.keys({"vary", "anchor", "replicates"});
    // Replicates: swept keys whose values are independent draws (seeds, camera paths); the report
    // gives each BD figure's mean and interval over them.
    if (r.has("replicates")) {
      const auto& rep = cv.at("replicates");
      if (!rep.is_array() || rep.empty()) {
        problems.push_back(
            fmt::format("{}.curves.replicates: must be a non-empty list of swept keys (e.g. [\"seed\"])", path));
      } else {
        for (const auto& k : rep) {
          if (!swept(k))
            problems.push_back(
                fmt::format("{}.curves.replicates: {} is not a key of \"sweep\"", path, json_excerpt(k)));
        }
      }
    }
    if (!r.has("vary") || !cv.at("vary").is_array() || cv.at("vary").empty()) {
      problems.push_back(
          fmt::format("{}.curves.vary: must be a non-empty list of the dotted keys that move along a curve", path));
    } else {
      for (const auto& k : cv.at("vary")) {
        if (!swept_or_set(k))
          problems.push_back(fmt::format("{}.curves.vary: {} is not a key of \"sweep\" or of a configuration's \"set\"",
                                         path, json_excerpt(k)));
      }
      // A key that only some configurations set and that is not in "vary" makes the runs that set
      // it a condition of their own: the report would never compare their curves with the others'
      // (the regime map would find no pair and the answer fall back to the Pareto fronts).
      std::map<std::string, size_t> set_by;
      for (const auto& c : configs)
        for (const auto& [k, v] : c.set.items()) ++set_by[k];
      const auto& vary = cv.at("vary");
      for (const auto& [k, n] : set_by)
        if (k != "network" && n < configs.size() && std::find(vary.begin(), vary.end(), k) == vary.end())
          problems.push_back(fmt::format(
              "{}.curves.vary: '{}' is set by {} of the {} configurations but not in \"vary\": the runs that set it "
              "would form a condition of their own, their curves compared with no other; add it to \"vary\" (or set "
              "it in every configuration)",
              path, text_excerpt(k), n, configs.size()));
    }
    if (r.has("anchor")) {
      // One family, or a list of families (the report tabulates BD-rate against each).
      std::vector<std::string> anchors;
      const auto& a = cv.at("anchor");
      if (a.is_string()) {
        anchors.push_back(a.get<std::string>());
      } else if (a.is_array() && !a.empty() &&
                 std::all_of(a.begin(), a.end(), [](const auto& x) { return x.is_string(); })) {
        for (const auto& x : a) anchors.push_back(x.get<std::string>());
      } else {
        problems.push_back(fmt::format("{}.curves.anchor: {} must be a family's name or a non-empty list of them", path,
                                       json_excerpt(a)));
      }
      std::vector<std::string> families;
      for (const auto& c : configs)
        if (std::find(families.begin(), families.end(), c.family) == families.end()) families.push_back(c.family);
      for (const std::string& anchor : anchors)
        if (!anchor.empty() && std::find(families.begin(), families.end(), anchor) == families.end())
          problems.push_back(fmt::format("{}.curves.anchor: '{}' is not a family of the configurations (families: {})",
                                         path, text_excerpt(anchor),
                                         text_excerpt(fmt::format("{}", fmt::join(families, ", ")), 200)));
    }
  }

  // The report's answer (experiments/report.py, "The answer"): its question, the cost the
  // Pareto front is drawn against, or a key whose values the answer compares along another.
  if (j.contains("answer")) {
    const auto& an = j.at("answer");
    Reader r{an, path + ".answer", problems};
    r.keys({"question", "cost", "group", "along", "terms"});
    std::string text;
    r.string("question", text);
    if (r.has("question") && (text.empty() || text.size() > 400))
      problems.push_back(fmt::format("{}.answer.question: must be 1-400 characters", path));
    r.string("cost", text, {"bandwidth", "server_time"});
    for (const char* k : {"group", "along"}) {
      std::string key;
      r.string(k, key);
      if (key.empty() || (std::string(k) == "group" && key == "configuration")) continue;  // by configuration
      if (!swept_or_set(key))
        problems.push_back(fmt::format("{}.answer.{}: '{}' is not a key of \"sweep\" or of a configuration's \"set\"",
                                       path, k, text_excerpt(key)));
    }
    // An error budget: each term is the difference between a configuration with the effect and
    // one without it, on every scene (without "without": the first configuration's own figure).
    if (r.has("terms")) {
      const auto& terms = an.at("terms");
      const std::string want =
          "a non-empty list of {\"name\": text, \"with\": configuration, \"without\": configuration (optional)}";
      if (!terms.is_array() || terms.empty() || terms.size() > 32) {
        problems.push_back(fmt::format("{}.answer.terms: must be {} (at most 32)", path, want));
      } else {
        for (size_t i = 0; i < terms.size(); ++i) {
          const std::string where = fmt::format("{}.answer.terms[{}]", path, i);
          Reader t{terms[i], where, problems};
          t.keys({"name", "with", "without"});
          if (!terms[i].is_object()) continue;
          for (const char* k : {"name", "with", "without"}) {
            if (std::string(k) == "without" && !terms[i].contains(k)) continue;  // the term is "with" itself
            if (!terms[i].contains(k) || !terms[i].at(k).is_string()) {
              problems.push_back(fmt::format("{}.{}: missing or not text ({})", where, k, want));
              continue;
            }
            if (std::string(k) == "name") continue;
            const std::string config = terms[i].at(k).get<std::string>();
            bool known = false;
            for (const auto& c : configs) known = known || c.name == config;
            if (!known)
              problems.push_back(
                  fmt::format("{}.{}: '{}' is not a configuration's name", where, k, text_excerpt(config)));
          }
        }
      }
    }
    if (r.has("group") && !r.has("along"))
      problems.push_back(
          fmt::format("{}.answer: \"group\" needs \"along\" (the key whose values each group is compared over)", path));
  }

  // Problems of the expanded run settings, grouped: message -> the runs it concerns.
  std::map<std::string, std::vector<std::string>> per_run;
  if (problems.empty()) {
    int index = 0;
    for (const auto& scene : e.scenes) {
      for (const auto& [config_name, family, set, only] : configs) {
        if (!only.empty() && std::find(only.begin(), only.end(), scene) == only.end()) continue;
        std::vector<size_t> pos(axes.size(), 0);
        for (;;) {
          nlohmann::json settings = set;
          for (size_t a = 0; a < axes.size(); ++a) settings[axes[a].first] = axes[a].second[pos[a]];
          nlohmann::json run = base;
          std::string label = config_name;
          for (const auto& [k, v] : settings.items()) {
            if (k == "network") {
              const std::string name = v.is_string() ? v.get<std::string>() : json_excerpt(v);
              if (!networks.is_object() || !networks.contains(name)) {
                problems.push_back(
                    fmt::format("{}: network '{}' is not defined in \"networks\"", path, text_excerpt(name)));
                continue;
              }
              const auto& net = networks.at(name);
              if (!net.is_object()) {
                problems.push_back(fmt::format("{}.networks.{}: must be an object with uplink and/or downlink", path,
                                               text_excerpt(name)));
                continue;
              }
              for (const auto& [nk, nv] : net.items()) {
                if (nk != "uplink" && nk != "downlink")
                  problems.push_back(fmt::format("{}.networks.{}.{}: unknown key (valid: uplink, downlink)", path,
                                                 text_excerpt(name), text_excerpt(nk)));
                else
                  run[nk] = nv;
              }
            } else {
              try {
                set_dotted(run, k, v);
              } catch (const Error& err) {
                problems.push_back(fmt::format("{}: {}", path, err.what()));
              }
            }
            if (!axes.empty() || config_name.empty())
              label +=
                  fmt::format("{}{}={}", label.empty() ? "" : ", ", k, v.is_string() ? v.get<std::string>() : v.dump());
          }
          RunSpec spec;
          spec.id = fmt::format("r{:03d}", index++);
          spec.scene = scene;
          spec.label = label.empty() ? "default" : label;
          spec.configuration = config_name;
          spec.family = family;
          spec.settings = settings;
          std::vector<std::string> run_problems;
          spec.config = sim_config_from_json(run, path + ": run", run_problems, version);
          for (auto& p : run_problems)
            per_run[p].push_back(fmt::format("{} on {}", text_excerpt(spec.label, 120), text_excerpt(scene)));
          for (LinkConfig* link : {&spec.config.uplink, &spec.config.downlink}) {
            link->trace_file = resolve_data_path(link->trace_file, path);
            link->capacity_trace_file = resolve_data_path(link->capacity_trace_file, path);
          }
          e.runs.push_back(std::move(spec));
          // Next combination.
          size_t a = 0;
          while (a < axes.size() && ++pos[a] == axes[a].second.size()) pos[a++] = 0;
          if (a == axes.size()) break;
        }
      }
    }
  }
  for (const auto& [message, labels] : per_run) {
    if (labels.size() == e.runs.size()) {
      problems.push_back(message + " (every run)");
    } else {
      std::string which;
      // At most 10 runs named: a sweep can hold thousands.
      for (size_t i = 0; i < std::min<size_t>(labels.size(), 10); ++i) which += (which.empty() ? "" : "; ") + labels[i];
      if (labels.size() > 10) which += fmt::format("; and {} more", labels.size() - 10);
      problems.push_back(fmt::format("{} (in: {})", message, which));
    }
  }
  if (!problems.empty()) {
    // Configurations repeat the same problem per scene: report each once.
    std::vector<std::string> unique;
    std::set<std::string> seen;
    for (auto& p : problems)
      if (seen.insert(p).second) unique.push_back(p);
    std::string msg = fmt::format("{} problem(s) in the experiment:", unique.size());
    for (const auto& p : unique) msg += "\n  " + p;
    throw Error(msg);
  }
  return e;
}

}  // namespace dhr
