// Typed backend parameters read from a JSON object (after pbrt-v4's parameter dictionaries):
// every key must be declared, every value must have the declared type and lie in its range,
// and every problem is reported at once. The effective parameters (defaults filled in) are
// kept so that results can record exactly what ran.
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace dhr {

enum class ParamType { Int, Float, Bool, String };

struct ParamSpec {
  std::string name;  // with units where there are any: latency_ms, radius_m
  ParamType type = ParamType::Int;
  nlohmann::json default_value;
  double min = 0.0;  // Int and Float: inclusive range
  double max = 0.0;
  std::vector<std::string> choices;  // String: the valid values (empty: any string)
  std::string description;

  static ParamSpec integer(std::string name, int def, int min, int max, std::string description);
  static ParamSpec real(std::string name, double def, double min, double max, std::string description);
  static ParamSpec boolean(std::string name, bool def, std::string description);
  static ParamSpec choice(std::string name, std::string def, std::vector<std::string> choices, std::string description);
  std::string range_text() const;  // "1..255", "one of: fast, hc", "true or false"
};

class Params {
 public:
  Params() = default;
  // Validates `given` against `specs` for the backend called `owner` (used in messages).
  // Throws dhr::Error listing every unknown key (with the valid keys), wrong type and
  // out-of-range value.
  Params(const std::string& owner, const std::vector<ParamSpec>& specs, const nlohmann::json& given);

  int get_int(const std::string& name) const;
  double get_float(const std::string& name) const;
  bool get_bool(const std::string& name) const;
  std::string get_string(const std::string& name) const;
  const nlohmann::json& effective() const { return values_; }  // defaults filled in

 private:
  const nlohmann::json& at(const std::string& name) const;
  std::string owner_;
  nlohmann::json values_ = nlohmann::json::object();
};

}  // namespace dhr
