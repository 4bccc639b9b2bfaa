// dhrbench list: every registered backend with its parameters, defaults and ranges, and an
// example of each in the syntax experiment files and --set accept (experiments/cli/list_examples.h).
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "experiments/cli/commands.h"
#include "experiments/cli/list_examples.h"

#include <fmt/format.h>

#include <memory>

namespace dhr::cli {

namespace {

template <class Interface>
void print_kind(const Registry<Interface>& reg, const std::string& title) {
  std::string keys;
  for (const auto& k : run_keys(reg.kind())) keys += (keys.empty() ? "" : ", ") + k;
  fmt::print("{} ({}), set at run keys {}:\n", title, reg.entries().size(), keys);
  const std::vector<BackendExample> examples = backend_examples(reg);
  for (size_t i = 0; i < reg.entries().size(); ++i) {
    const auto& e = reg.entries()[i];
    fmt::print("  {:<18} {}\n", e.name, e.description);
    for (const auto& p : e.params) {
      fmt::print("      {:<22} default {:<10} {}; {}\n", p.name, p.default_value.dump(), p.range_text(), p.description);
    }
    fmt::print("      example: {}\n", examples[i].file_text());
  }
}

}  // namespace

Runner add_list_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("list",
                                 "List every registered backend (codecs, denoisers, predictors) "
                                 "with its parameters, defaults and valid ranges");
  auto kind = std::make_shared<std::string>("all");
  cmd->add_option("kind", *kind, "Only this kind")->check(CLI::IsMember({"all", "codec", "denoiser", "predictor"}));
  return [kind] {
    const Registries& r = registries();
    if (*kind == "all" || *kind == "codec") print_kind(r.codecs, "codecs");
    if (*kind == "all" || *kind == "denoiser") print_kind(r.denoisers, "denoisers");
    if (*kind == "all" || *kind == "predictor") print_kind(r.predictors, "predictors");
    // The closing example: the first codec example with a parameter (zstd's level, today).
    const std::vector<BackendExample> codecs = backend_examples(r.codecs);
    const BackendExample* shown = nullptr;
    for (const auto& e : codecs)
      if (!shown && e.value.contains("params")) shown = &e;
    fmt::print(
        "\nA backend is {{\"name\": ..., \"params\": {{...}}}} (\"params\" may be left out for the defaults),\n"
        "set at one of the run keys above: in an experiment file's \"run\" (or a --config file)\n");
    if (shown) {
      const std::string assignment = shown->set_assignment();
      const size_t eq = assignment.find('=');
      fmt::print(
          "  {}\n"
          "or on the command line (dhrbench run/validate; serve and client drop the \"run.\"):\n"
          "  --set {}='{}'    or one parameter: --set run.{}.params.{}=...\n",
          shown->file_text(), assignment.substr(0, eq), assignment.substr(eq + 1), shown->run_key,
          shown->value["params"].begin().key());
    }
    return 0;
  };
}

}  // namespace dhr::cli
