// Live mode: the session offer both sides compare (core/live/live.h).
#include "core/live/live.h"
#include "core/base/json_io.h"
#include "core/config/run_plan.h"
#include "core/live/live_detail.h"

namespace dhr {

using namespace live_detail;

// ---- the offer ---------------------------------------------------------------------------

nlohmann::json session_offer(const SimConfig& c, const Registries& r, const std::string& scene_name,
                             const std::string& scene_key) {
  nlohmann::json offer{{"protocol", kLiveProtocolVersion}, {"scene", scene_name}, {"scene_hash", scene_key}};
  // The settings flagged kInLiveOffer (core/config/run_config.cpp), backends with their effective
  // parameters. A backend goes under its version-1 key ("ao_codec"): the offer's wire format
  // (parse_offer_json) is unchanged by the per-pass keys of experiment files.
  for (const RunSetting& s : run_settings()) {
    if (!s.has(kInLiveOffer)) continue;
    nlohmann::json value = s.get(c);
    if (s.type == SettingType::Backend) value = effective_backend(s, value, r);
    const std::string key = s.v1_key.empty() ? s.key : s.v1_key;
    nlohmann::json* node = &offer;
    size_t start = 0;
    for (size_t dot; (dot = key.find('.', start)) != std::string::npos; start = dot + 1)
      node = &(*node)[key.substr(start, dot - start)];
    (*node)[key.substr(start)] = std::move(value);
  }
  return offer;
}

std::vector<std::string> offer_mismatches(const nlohmann::json& client, const nlohmann::json& server) {
  std::vector<std::string> out;
  auto walk = [&](auto& self, const nlohmann::json& a, const nlohmann::json& b, const std::string& path) -> void {
    if (a.is_object() && b.is_object()) {
      std::set<std::string> keys;
      for (auto it = a.begin(); it != a.end(); ++it) keys.insert(it.key());
      for (auto it = b.begin(); it != b.end(); ++it) keys.insert(it.key());
      for (const std::string& k : keys) {
        if (path.empty() && k == "scene") continue;  // the name may differ; the hash may not
        const std::string p = path.empty() ? k : path + "." + k;
        self(self, a.contains(k) ? a[k] : nlohmann::json(), b.contains(k) ? b[k] : nlohmann::json(), p);
      }
      return;
    }
    if (a != b)
      out.push_back(fmt::format("{}: client {}, server {}", path, json_excerpt(a, 200), json_excerpt(b, 200)));
  };
  walk(walk, client, server, "");
  // Never throws, whatever the shapes: a field that is absent or not a string reads as "?".
  auto text = [](const nlohmann::json& o, const char* key) {
    if (!o.is_object()) return std::string("?");
    const auto it = o.find(key);
    return it != o.end() && it->is_string() ? json_excerpt(*it, 200) : std::string("?");
  };
  if (!out.empty() && text(client, "scene_hash") != text(server, "scene_hash"))
    out.insert(out.begin(), fmt::format("scene: client {}, server {} (different content)", text(client, "scene"),
                                        text(server, "scene")));
  return out;
}

std::vector<std::string> live_ignored_fields(const SimConfig& c) {
  const SimConfig d;
  std::vector<std::string> out;
  // The settings with a live_ignored reason (core/config/run_config.cpp), set to other than their defaults.
  for (const RunSetting& s : run_settings())
    if (!s.live_ignored.empty() && s.get(c) != s.get(d)) out.push_back(fmt::format("{} ({})", s.key, s.live_ignored));
  return out;
}

}  // namespace dhr
