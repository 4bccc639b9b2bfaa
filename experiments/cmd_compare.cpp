// dhrbench compare A.png B.png [--map OUT.png]: the benchmark's frame metrics between any two
// images, so that a user can score any pair exactly the way the benchmark does.
#include "core/error.h"
#include "core/image_io.h"
#include "core/metrics.h"
#include "experiments/commands.h"

#include <fmt/format.h>

#include <cmath>
#include <memory>

namespace dhr::cli {

Runner add_compare_command(CLI::App& app) {
  struct Options {
    std::string a, b, map, channel = "luma";
    float map_max = 32.0f;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "compare",
      "Score image B against image A with the benchmark's metrics: SSIM (Wang et al. 2004: Gaussian\n"
      "11x11, sigma 1.5, K1 0.01, K2 0.03, on BT.601 luma of the 8-bit sRGB values unless --channel\n"
      "rgb), PSNR over RGB, and mean absolute error. Example:\n"
      "  dhrbench compare out/reference.png out/hybrid.png --map out/error.png");
  cmd->add_option("A", o->a, "Reference image (PNG, or anything OpenImageIO reads)")->required();
  cmd->add_option("B", o->b, "Image to score")->required();
  cmd->add_option("--map", o->map, "Write an error map (|luma difference|, fixed scale, colour bar) to this PNG");
  cmd->add_option("--map-max", o->map_max, "Luma difference (8-bit levels) at the top of the map's scale")
      ->check(CLI::PositiveNumber)->capture_default_str();
  cmd->add_option("--channel", o->channel, "SSIM on luma, or the mean of R, G and B")
      ->check(CLI::IsMember({"luma", "rgb"}))->capture_default_str();
  return [o] {
    const ImageRGB8 a = read_rgb8(o->a);
    const ImageRGB8 b = read_rgb8(o->b);
    if (!a.same_size(b))
      fail("{} is {}x{} but {} is {}x{}: images must have the same size", o->a, a.width(), a.height(), o->b,
           b.width(), b.height());
    const QualityScores q = compare_images(a, b, o->channel == "rgb" ? SsimChannel::RgbMean : SsimChannel::Luma);
    fmt::print("ssim {:.6f}   ({}; Gaussian 11x11 sigma 1.5)\n", q.ssim, o->channel == "rgb" ? "mean of R,G,B" : "luma");
    if (std::isinf(q.psnr_db))
      fmt::print("psnr inf dB  (identical)\n");
    else
      fmt::print("psnr {:.3f} dB\n", q.psnr_db);
    fmt::print("mae  {:.4f}   (mean |difference| in 8-bit levels)\n", q.mean_abs_error);
    if (!o->map.empty()) {
      write_png(o->map, error_map(abs_luma_difference(a, b), o->map_max));
      fmt::print("error map: {} (0 .. {} levels of luma difference, colour bar at the bottom)\n", o->map, o->map_max);
    }
    return 0;
  };
}

}  // namespace dhr::cli
