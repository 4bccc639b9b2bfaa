// dhrbench converge: is the ground truth converged? Renders the ground truth (core/pass/reference.h)
// of a few frames per scene with N samples (AO rays and rays per area light) and again with
// factor x N and an independent seed, and scores one against the other with every image metric
// (core/results/results.h). With independent estimates, the difference's variance is the N estimate's
// plus the larger one's (1 + 1/factor times the N estimate's own), so these figures bound the
// ground truth's own error from above (docs/architecture.md, "The references").
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/buffers/image_io.h"
#include "core/metrics/metrics.h"
#include "core/pass/reference.h"
#include "core/raster/raster.h"
#include "core/results/results.h"
#include "core/scene/scene_load.h"
#include "core/trace/rt_scene.h"
#include "experiments/cli/commands.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <tbb/global_control.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <memory>

namespace dhr::cli {

Runner add_converge_command(CLI::App& app) {
  struct Options {
    std::vector<std::string> scenes, scene_path;
    std::string out, sampling = sampling_name(ReferenceRays{}.lattice), large_sampling;
    int width = 320, height = 180, frames = 3, ao_rays = 128, samples_per_light = 32, factor = 4, threads = 0;
    double start_s = 1.0, duration_s = 1.0;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "converge",
      "Check that the ground truth is converged: render it for a few frames of each scene with N samples and\n"
      "with factor x N (independent seeds), and score one against the other with every image metric\n"
      "(`dhrbench metrics`). The difference bounds the N estimate's own error from above. Examples:\n"
      "  dhrbench converge --scene room --scene street\n"
      "  dhrbench converge --scene living-room --ao-rays 128 --samples-per-light 32 --factor 4 --out out/converge");
  cmd->add_option("--scene", o->scenes, "Scene (repeatable): a file, a built-in name or a real scene's name")
      ->required();
  cmd->add_option("--scene-path", o->scene_path, "Folder to look for scene assets in (repeatable)");
  cmd->add_option("--width", o->width, "Image width")->check(CLI::Range(8, 7680))->capture_default_str();
  cmd->add_option("--height", o->height, "Image height")->check(CLI::Range(8, 4320))->capture_default_str();
  cmd->add_option("--frames", o->frames, "Frames per scene, evenly spread over the duration")
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  cmd->add_option("--start", o->start_s, "Scene time of the first frame (s)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--duration", o->duration_s, "Scene time the frames span (s)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--ao-rays", o->ao_rays,
                  "N: the ground truth's AO rays per pixel (experiments: ground_truth_ao_rays)")
      ->check(CLI::Range(1, 16383))
      ->capture_default_str();
  cmd->add_option("--samples-per-light", o->samples_per_light,
                  "N: the ground truth's rays per area light (experiments: ground_truth_samples_per_light)")
      ->check(CLI::Range(1, 16383))
      ->capture_default_str();
  cmd->add_option(
         "--sampling", o->sampling,
         "The ground truth's samples of a pixel (the larger estimate's too, unless --large-sampling): lattice (a "
         "shifted R2 lattice per pixel and light) or random (independent uniforms); experiments: "
         "ground_truth_sampling")
      ->check(CLI::IsMember(sampling_names()))
      ->capture_default_str();
  cmd->add_option("--large-sampling", o->large_sampling,
                  "The factor x N estimate's samples (default: --sampling's). Two candidates scored against one "
                  "estimate: e.g. lattice N against random 8N, then random 2N against random 8N (factor 4)")
      ->check(CLI::IsMember(sampling_names()));
  cmd->add_option("--factor", o->factor, "The larger estimate's samples: factor x N")
      ->check(CLI::Range(2, 64))
      ->capture_default_str();
  cmd->add_option("--out", o->out, "Write convergence.json here (and the larger estimates' images)");
  cmd->add_option("--threads", o->threads, "Threads (0 = all cores)")->check(CLI::NonNegativeNumber);
  return [o] {
    std::unique_ptr<tbb::global_control> limit;
    if (o->threads > 0)
      limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, size_t(o->threads));
    if (int64_t(o->ao_rays) * o->factor > 65535 || int64_t(o->samples_per_light) * o->factor > 65535)
      fail("converge: factor {} x N (AO rays {}, rays per light {}) exceeds 65535, the ground truth's limit", o->factor,
           o->ao_rays, o->samples_per_light);
    namespace fs = std::filesystem;
    const std::string large_sampling = o->large_sampling.empty() ? o->sampling : o->large_sampling;
    nlohmann::json out = {{"width", o->width},
                          {"height", o->height},
                          {"ao_rays", o->ao_rays},
                          {"samples_per_light", o->samples_per_light},
                          {"factor", o->factor},
                          {"sampling", o->sampling},
                          {"large_sampling", large_sampling},
                          {"note",
                           "each figure scores the N-sample ground truth against the factor x N one (independent "
                           "seeds); the difference bounds the N estimate's own error from above"},
                          {"scenes", nlohmann::json::array()}};
    const auto& metrics = image_metrics();
    fmt::print("ground truth at N = {} AO rays, {} rays per light ({} samples) against {} x N ({}); {}x{}\n",
               o->ao_rays, o->samples_per_light, o->sampling, o->factor, large_sampling, o->width, o->height);
    fmt::print("{:<24} {:>7}", "scene", "time s");
    for (const ImageMetric& m : metrics)
      if (m.score) fmt::print(" {:>10}", m.name + (m.unit.empty() ? "" : " " + m.unit));
    fmt::print(" {:>14}\n", "max |dY| levels");
    for (const std::string& name : o->scenes) {
      const Scene scene = load_scene_or_model(name, SceneSearchPath::standard(o->scene_path));
      RtScene rt(scene);
      nlohmann::json rows = nlohmann::json::array();
      std::vector<std::vector<double>> per_metric(metrics.size());
      for (int i = 0; i < o->frames; ++i) {
        const double t = o->start_s + (o->frames > 1 ? o->duration_s * double(i) / double(o->frames - 1) : 0.0);
        const Camera cam = scene.camera.at(t, o->width, o->height);
        GBuffer g;
        rasterize({&scene, cam, t, cam, t}, g);
        ReferenceSettings small, large;
        small.ao_rays = o->ao_rays;
        small.samples_per_light = o->samples_per_light;
        large.ao_rays = o->ao_rays * o->factor;
        large.samples_per_light = o->samples_per_light * o->factor;
        large.seed = small.seed ^ 0x9e3779b97f4a7c15ull;  // independent of the N estimate's samples
        small.lattice = is_lattice(o->sampling);
        large.lattice = is_lattice(large_sampling);
        const ImageRGB8 a = ground_truth(rt, g, small).image;
        const ImageRGB8 b = ground_truth(rt, g, large).image;
        const std::vector<double> s = score_frame(b, a);
        const ImageF d = abs_luma_difference(a, b);
        const float max_d = d.empty() ? 0.0f : *std::max_element(d.pixels().begin(), d.pixels().end());
        nlohmann::json row = {{"time_s", t}, {"max_abs_luma_difference", max_d}};
        fmt::print("{:<24} {:>7.3f}", name.substr(0, 24), t);
        for (size_t k = 0; k < metrics.size(); ++k) {
          if (!metrics[k].score) continue;  // a step metric: needs a sequence
          row[metrics[k].name] = std::isfinite(s[k]) ? nlohmann::json(s[k]) : nlohmann::json("inf");
          per_metric[k].push_back(metrics[k].for_mean ? metrics[k].for_mean(s[k]) : s[k]);
          fmt::print(" {:>10.5f}", s[k]);
        }
        fmt::print(" {:>14.1f}\n", max_d);
        rows.push_back(row);
        if (!o->out.empty()) {
          make_output_dir(o->out, "--out");
          write_png((fs::path(o->out) / fmt::format("{}_t{:.3f}_x{}.png", fs::path(name).stem().string(), t, o->factor))
                        .string(),
                    b);
        }
      }
      nlohmann::json summary = nlohmann::json::object();
      for (size_t k = 0; k < metrics.size(); ++k) {
        if (!metrics[k].score) continue;
        for (const ImageStatistic& st : image_statistics())  // as results.json summarises a run
          if (st.name == "mean" || st.name == "worst")
            summary[metrics[k].name + "_" + st.name] = st.of(per_metric[k], metrics[k].higher_is_better);
      }
      out["scenes"].push_back({{"scene", name}, {"frames", rows}, {"summary", summary}});
    }
    if (!o->out.empty()) {
      std::ofstream(fs::path(o->out) / "convergence.json") << out.dump(1) << '\n';
      fmt::print("written: {}/convergence.json\n", o->out);
    }
    return 0;
  };
}

}  // namespace dhr::cli
