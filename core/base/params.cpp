#include "core/base/params.h"

#include "core/base/error.h"
#include "core/base/json_io.h"

#include <cmath>

namespace dhr {

ParamSpec ParamSpec::integer(std::string name, int def, int min, int max, std::string description) {
  ParamSpec s;
  s.name = std::move(name);
  s.type = ParamType::Int;
  s.default_value = def;
  s.min = min;
  s.max = max;
  s.description = std::move(description);
  return s;
}

ParamSpec ParamSpec::real(std::string name, double def, double min, double max, std::string description) {
  ParamSpec s;
  s.name = std::move(name);
  s.type = ParamType::Float;
  s.default_value = def;
  s.min = min;
  s.max = max;
  s.description = std::move(description);
  return s;
}

ParamSpec ParamSpec::boolean(std::string name, bool def, std::string description) {
  ParamSpec s;
  s.name = std::move(name);
  s.type = ParamType::Bool;
  s.default_value = def;
  s.description = std::move(description);
  return s;
}

ParamSpec ParamSpec::choice(std::string name, std::string def, std::vector<std::string> choices,
                            std::string description) {
  ParamSpec s;
  s.name = std::move(name);
  s.type = ParamType::String;
  s.default_value = std::move(def);
  s.choices = std::move(choices);
  s.description = std::move(description);
  return s;
}

std::string ParamSpec::range_text() const {
  switch (type) {
    case ParamType::Int: return fmt::format("integer {}..{}", int64_t(min), int64_t(max));
    case ParamType::Float: return fmt::format("number {}..{}", min, max);
    case ParamType::Bool: return "true or false";
    case ParamType::String: {
      if (choices.empty()) return "any string";
      std::string s = "one of:";
      for (const auto& c : choices) s += " " + c;
      return s;
    }
  }
  return "";
}

namespace {

// Returns an empty string when `v` is valid for `spec`, else what is wrong.
std::string check_value(const ParamSpec& spec, const nlohmann::json& v) {
  switch (spec.type) {
    case ParamType::Int: {
      if (!v.is_number_integer()) return "must be an integer";
      const double x = double(v.get<int64_t>());
      if (x < spec.min || x > spec.max) return "is out of range";
      return {};
    }
    case ParamType::Float: {
      if (!v.is_number()) return "must be a number";
      const double x = v.get<double>();
      if (!std::isfinite(x) || x < spec.min || x > spec.max) return "is out of range";
      return {};
    }
    case ParamType::Bool: return v.is_boolean() ? std::string{} : std::string("must be true or false");
    case ParamType::String: {
      if (!v.is_string()) return "must be a string";
      if (spec.choices.empty()) return {};
      for (const auto& c : spec.choices)
        if (c == v.get<std::string>()) return {};
      return "is not a valid choice";
    }
  }
  return "has an unknown type";
}

}  // namespace

Params::Params(const std::string& owner, const std::vector<ParamSpec>& specs, const nlohmann::json& given)
    : owner_(owner) {
  std::vector<std::string> problems;
  if (!given.is_null() && !given.is_object()) {
    fail("{}: parameters must be a JSON object, got {}", owner, json_excerpt(given));
  }
  std::string valid_keys;
  for (const auto& s : specs) valid_keys += (valid_keys.empty() ? "" : ", ") + s.name;
  if (valid_keys.empty()) valid_keys = "(none: this backend takes no parameters)";
  if (given.is_object()) {
    for (const auto& [key, value] : given.items()) {
      const ParamSpec* spec = nullptr;
      for (const auto& s : specs)
        if (s.name == key) spec = &s;
      if (!spec) {
        problems.push_back(fmt::format("unknown parameter '{}' (valid: {})", key, valid_keys));
        continue;
      }
      const std::string why = check_value(*spec, value);
      if (!why.empty()) {
        problems.push_back(
            fmt::format("parameter '{}' = {} {} (valid: {})", key, json_excerpt(value), why, spec->range_text()));
      }
    }
  }
  if (!problems.empty()) {
    std::string msg = owner + ": " + problems.front();
    for (size_t i = 1; i < problems.size(); ++i) msg += "\n" + owner + ": " + problems[i];
    throw Error(msg);
  }
  for (const auto& s : specs) {
    values_[s.name] = (given.is_object() && given.contains(s.name)) ? given.at(s.name) : s.default_value;
  }
}

const nlohmann::json& Params::at(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end()) fail("{}: internal error: parameter '{}' was never declared", owner_, name);
  return *it;
}

int Params::get_int(const std::string& name) const { return at(name).get<int>(); }
double Params::get_float(const std::string& name) const { return at(name).get<double>(); }
bool Params::get_bool(const std::string& name) const { return at(name).get<bool>(); }
std::string Params::get_string(const std::string& name) const { return at(name).get<std::string>(); }

}  // namespace dhr
