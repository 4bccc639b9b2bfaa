// dhrbench list: every registered backend with its parameters, defaults and ranges.
#include "core/backend.h"
#include "experiments/commands.h"

#include <fmt/format.h>

#include <memory>

namespace dhr::cli {

namespace {

template <class Interface>
void print_kind(const Registry<Interface>& reg, const std::string& title) {
  fmt::print("{} ({}):\n", title, reg.entries().size());
  for (const auto& e : reg.entries()) {
    fmt::print("  {:<18} {}\n", e.name, e.description);
    for (const auto& p : e.params) {
      fmt::print("      {:<22} default {:<10} {}; {}\n", p.name, p.default_value.dump(), p.range_text(),
                 p.description);
    }
  }
}

}  // namespace

Runner add_list_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("list", "List every registered backend (codecs, denoisers, predictors) "
                                         "with its parameters, defaults and valid ranges");
  auto kind = std::make_shared<std::string>("all");
  cmd->add_option("kind", *kind, "Only this kind")->check(CLI::IsMember({"all", "codec", "denoiser", "predictor"}));
  return [kind] {
    const Registries& r = registries();
    if (*kind == "all" || *kind == "codec") print_kind(r.codecs, "codecs");
    if (*kind == "all" || *kind == "denoiser") print_kind(r.denoisers, "denoisers");
    if (*kind == "all" || *kind == "predictor") print_kind(r.predictors, "predictors");
    fmt::print("\nParameters are given as a JSON object, e.g. {{\"codec\": \"zstd\", \"level\": 3}}.\n");
    return 0;
  };
}

}  // namespace dhr::cli
