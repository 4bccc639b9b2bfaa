// dhrbench render: placeholder until the scene loader and rasterizer land.
#include "experiments/commands.h"

#include <cstdio>

namespace dhr::cli {

Runner add_render_command(CLI::App& app) {
  app.add_subcommand("render", "Render a scene's frame to images (G-buffer, passes)");
  return [] {
    std::fprintf(stderr, "render: not built yet\n");
    return 2;
  };
}

}  // namespace dhr::cli
