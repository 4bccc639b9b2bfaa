// dhrbench compare A.png B.png [--map OUT.png]: the benchmark's frame metrics between any two
// images, so that a user can score any pair exactly the way the benchmark does.
#include "core/base/error.h"
#include "core/buffers/image_io.h"
#include "core/metrics/flip.h"
#include "core/metrics/metrics.h"
#include "core/results/results.h"
#include "experiments/cli/commands.h"

#include <fmt/format.h>

#include <cmath>
#include <memory>

namespace dhr::cli {

Runner add_compare_command(CLI::App& app) {
  struct Options {
    std::string a, b, map, flip_map, channel = "luma", border = "valid";
    float map_max = 32.0f;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "compare",
      "Score image B against image A with the benchmark's image metrics, exactly as runs score frames\n"
      "(`dhrbench metrics` lists them: SSIM over the valid interior, PSNR, FLIP), then SSIM with the\n"
      "options below and the mean absolute error. Example:\n"
      "  dhrbench compare out/reference.png out/hybrid.png --map out/error.png --flip-map out/flip.png");
  cmd->add_option("A", o->a, "Reference image (PNG, or anything OpenImageIO reads)")->required();
  cmd->add_option("B", o->b, "Image to score")->required();
  cmd->add_option("--map", o->map, "Write an error map (|luma difference|, fixed scale, colour bar) to this PNG");
  cmd->add_option("--map-max", o->map_max, "Luma difference (8-bit levels) at the top of the map's scale")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->add_option("--flip-map", o->flip_map, "Write FLIP's error map (67 ppd) on FLIP's colour map to this PNG");
  cmd->add_option("--channel", o->channel, "The optional SSIM: on luma, or the mean of R, G and B")
      ->check(CLI::IsMember({"luma", "rgb"}))
      ->capture_default_str();
  cmd->add_option("--border", o->border,
                  "The optional SSIM's mean: valid (interior, Wang et al., scikit-image; as runs score) or mirrored "
                  "(every pixel, reflect-101 borders, OpenCV's convention)")
      ->check(CLI::IsMember({"valid", "mirrored"}))
      ->capture_default_str();
  return [o] {
    const ImageRGB8 a = read_rgb8(o->a);
    const ImageRGB8 b = read_rgb8(o->b);
    if (!a.same_size(b))
      fail("{} is {}x{} but {} is {}x{}: images must have the same size", o->a, a.width(), a.height(), o->b, b.width(),
           b.height());
    // The declared metrics, as a run scores a frame (the step metrics need a sequence: skipped).
    const std::vector<double> scores = score_frame(a, b);
    for (size_t i = 0; i < scores.size(); ++i) {
      const ImageMetric& m = image_metrics()[i];
      if (!m.score) continue;
      fmt::print("{:<6} {}{}\n", m.name, std::isinf(scores[i]) ? std::string("inf") : fmt::format("{:.6f}", scores[i]),
                 m.unit.empty() ? "" : " " + m.unit);
    }
    const QualityScores q = compare_images(a, b, o->channel == "rgb" ? SsimChannel::RgbMean : SsimChannel::Luma,
                                           nullptr, o->border == "valid" ? SsimBorder::Valid : SsimBorder::Mirrored);
    fmt::print("ssim   {:.6f} ({}, {} mean; --channel, --border)\n", q.ssim,
               o->channel == "rgb" ? "mean of R,G,B" : "luma", o->border);
    fmt::print("mae    {:.4f} (mean |difference| in 8-bit levels)\n", q.mean_abs_error);
    if (!o->flip_map.empty()) {
      write_png(o->flip_map, flip_colour_map(flip(a, b).map));
      fmt::print("FLIP map: {} (FLIP's colour map, 0 black .. 1 light yellow)\n", o->flip_map);
    }
    if (!o->map.empty()) {
      write_png(o->map, error_map(abs_luma_difference(a, b), o->map_max));
      fmt::print("error map: {} (0 .. {} levels of luma difference, colour bar at the bottom)\n", o->map, o->map_max);
    }
    return 0;
  };
}

}  // namespace dhr::cli
