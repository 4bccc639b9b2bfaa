#include "core/passes.h"

namespace dhr {

const char* pass_meaning_name(PassMeaning meaning) {
  switch (meaning) {
    case PassMeaning::Visibility: return "visibility";
    case PassMeaning::Ao: return "ao";
    case PassMeaning::Colour: return "colour";
  }
  return "?";
}

std::vector<std::string> all_pass_names() {
  std::vector<std::string> names;
  for (PassMeaning m : kAllPassMeanings) names.push_back(pass_meaning_name(m));
  return names;
}

PassLayout pass_layout(PassKind kind) {
  switch (kind) {
    case PassKind::Visibility: return PassLayout::Bitmask;
    case PassKind::Colour: return PassLayout::Rgb8;
    case PassKind::SoftVisibility:
    case PassKind::Ao: break;
  }
  return PassLayout::Planes8;
}

PassMeaning pass_meaning(PassKind kind) {
  switch (kind) {
    case PassKind::Visibility:
    case PassKind::SoftVisibility: return PassMeaning::Visibility;
    case PassKind::Colour: return PassMeaning::Colour;
    case PassKind::Ao: break;
  }
  return PassMeaning::Ao;
}

std::vector<PlannedPass> traced_passes(const PassPlan& plan, int width, int height) {
  std::vector<PlannedPass> passes;
  if (plan.visibility()) passes.push_back({"visibility", PassMeaning::Visibility, plan.visibility_desc(width, height)});
  if (plan.ao) passes.push_back({"ao", PassMeaning::Ao, plan.ao_desc(width, height)});
  return passes;
}

std::vector<PlannedPass> sent_passes(const PassPlan& plan, bool remote, int width, int height) {
  if (remote) return {{"colour", PassMeaning::Colour, {PassKind::Colour, width, height, 3, 255}}};
  return traced_passes(plan, width, height);
}

int find_pass(const std::vector<PlannedPass>& passes, PassMeaning meaning) {
  for (size_t i = 0; i < passes.size(); ++i)
    if (passes[i].meaning == meaning) return int(i);
  return -1;
}

}  // namespace dhr
