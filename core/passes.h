// The passes of a run as a list. A planned pass is {name, meaning, desc}: the byte layout in
// `desc` (a bitmask, 8-bit planes, RGB) is what codecs and predictors see; the meaning
// (visibility, ao, colour) is what the denoise stage and the composite use. The server traces,
// denoises, encodes and sends each pass of the list; the client receives, decodes and predicts
// each, and the composite takes the list. docs/architecture.md shows how to add a pass.
#pragma once

#include "core/pass_buffer.h"
#include "core/trace.h"

#include <string>
#include <vector>

namespace dhr {

enum class PassMeaning : uint8_t { Visibility, Ao, Colour };
enum class PassLayout : uint8_t { Bitmask, Planes8, Rgb8 };

const char* pass_meaning_name(PassMeaning meaning);
// Every meaning, in order, and their names: the pass column groups of frames.csv.
inline constexpr PassMeaning kAllPassMeanings[] = {PassMeaning::Visibility, PassMeaning::Ao, PassMeaning::Colour};
std::vector<std::string> all_pass_names();
PassLayout pass_layout(PassKind kind);
PassMeaning pass_meaning(PassKind kind);

struct PlannedPass {
  std::string name;  // the key of its settings and of its results: "visibility", "ao", "colour"
  PassMeaning meaning = PassMeaning::Ao;
  PassDesc desc;     // layout, size, channels and full scale as traced (before denoising)
  PassLayout layout() const { return pass_layout(desc.kind); }
};

// What the server traces for `plan` at width x height, in order: visibility (when the scene's
// lights need one), then AO (when the scene asks for it).
std::vector<PlannedPass> traced_passes(const PassPlan& plan, int width, int height);

// What the server sends: hybrid mode sends the traced passes; remote mode composites them and
// sends one colour pass.
std::vector<PlannedPass> sent_passes(const PassPlan& plan, bool remote, int width, int height);

// The index in `passes` of the pass with `meaning`, or -1.
int find_pass(const std::vector<PlannedPass>& passes, PassMeaning meaning);

}  // namespace dhr
