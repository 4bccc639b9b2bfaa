// dhrbench render: one frame of a scene to images -- the client's G-buffer, the server's
// passes, the composite and the references -- with each stage's wall time.
#include "core/base/error.h"
#include "core/base/json_io.h"
#include "core/buffers/image_io.h"
#include "core/buffers/visualize.h"
#include "core/pass/composite.h"
#include "core/pass/passes.h"
#include "core/pass/reference.h"
#include "core/raster/raster.h"
#include "core/scene/scene_load.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"
#include "experiments/cli/commands.h"

#include <fmt/format.h>
#include <tbb/global_control.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <set>

namespace dhr::cli {

namespace {

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// A plane rescaled from 0..full_scale to 0..255 for viewing.
ImageU8 viewable_plane(const PassBuffer& b, int index) {
  ImageU8 img = pass_plane(b, index);
  const int scale = std::max(1, b.desc.full_scale);
  for (auto& v : img.pixels()) v = uint8_t((v * 255 + scale / 2) / scale);
  return img;
}

// One light's bit of an interleaved bitmask, as black/white.
ImageU8 bit_plane(const PassBuffer& b, int light) {
  ImageU8 img(b.desc.width, b.desc.height);
  const int bytes_per_pixel = (b.desc.channels + 7) / 8;
  for (size_t i = 0; i < img.size(); ++i)
    img[i] = (b.bytes[i * size_t(bytes_per_pixel) + size_t(light / 8)] >> (light % 8)) & 1 ? 255 : 0;
  return img;
}

}  // namespace

Runner add_render_command(CLI::App& app) {
  struct Options {
    std::string scene, out = "out/render";
    std::vector<std::string> scene_path, passes{"gbuffer"};
    int frame = 0, width = 1280, height = 720, threads = 0, ao_rays = 0, samples_per_light = 1;
    int reference_ao_rays = 512, reference_samples = 256;
    std::string reference_sampling = sampling_name(ReferenceRays{}.lattice);
    double fps = 60.0, ao_radius_m = 0.0;
    uint64_t seed = 1;
    bool hard = false;
  };
  auto o = std::make_shared<Options>();
  auto* cmd = app.add_subcommand(
      "render",
      "Render one frame of a scene to images and print each stage's wall time.\n"
      "Passes: gbuffer (depth, normals, albedo, object ids, motion), visibility (per light and combined),\n"
      "ao (the unoccluded fraction), composite (the client's shading with those passes), reference\n"
      "(the ground truth: converged visibility and AO, cached on disk), all.\n"
      "Examples:\n"
      "  dhrbench render --scene room --frame 120 --out out/room\n"
      "  dhrbench render --scene scenes/real/living-room.json --pass all --width 640 --height 360\n"
      "  dhrbench render --scene /usr/share/assimp/models/glTF2/BoxTextured-glTF/BoxTextured.gltf");
  cmd->add_option("--scene", o->scene,
                  "Scene file (.json), a built-in scene's name (room, temple, street, living-room, ...) or a model "
                  "file (OBJ, glTF, GLB) framed with a default camera and light")
      ->required();
  cmd->add_option("--frame", o->frame, "Frame index on the scene's camera path")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--fps", o->fps, "Frames per second of the path (time = frame / fps)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->add_option("--width", o->width, "Image width")->check(CLI::Range(8, 7680))->capture_default_str();
  cmd->add_option("--height", o->height, "Image height")->check(CLI::Range(8, 4320))->capture_default_str();
  cmd->add_option("--out", o->out, "Output folder")->capture_default_str();
  cmd->add_option("--pass", o->passes, "What to write (repeatable)")
      ->check(CLI::IsMember({"gbuffer", "visibility", "ao", "composite", "reference", "all"}))
      ->capture_default_str();
  cmd->add_option("--scene-path", o->scene_path,
                  "Folder to look for scene assets in (repeatable; then $DHR_SCENE_PATH, then ../shared/scenes)");
  cmd->add_option("--threads", o->threads, "Threads (0 = all cores)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "Random seed")->capture_default_str();
  cmd->add_option("--ao-rays", o->ao_rays, "AO rays per pixel (0 = the scene's ao block)")
      ->check(CLI::Range(0, 255))
      ->capture_default_str();
  cmd->add_option("--ao-radius", o->ao_radius_m, "AO radius in metres (0 = the scene's)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_flag("--hard", o->hard, "Hard shadows even for area lights (one ray to each light's centre)");
  cmd->add_option("--samples-per-light", o->samples_per_light,
                  "Soft shadows: rays per area light (1 = the paper's one-bit jittered ray; more = 8-bit fraction)")
      ->check(CLI::Range(1, 1024))
      ->capture_default_str();
  cmd->add_option("--reference-ao-rays", o->reference_ao_rays, "Ground truth: AO rays per pixel")
      ->check(CLI::Range(1, 65535))
      ->capture_default_str();
  cmd->add_option("--reference-samples", o->reference_samples, "Ground truth: rays per area light")
      ->check(CLI::Range(1, 65535))
      ->capture_default_str();
  cmd->add_option("--reference-sampling", o->reference_sampling,
                  "Ground truth: samples of a pixel, random (independent uniforms) or lattice (a shifted R2 lattice)")
      ->check(CLI::IsMember(sampling_names()))
      ->capture_default_str();

  return [o] {
    std::unique_ptr<tbb::global_control> limit;
    if (o->threads > 0)
      limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, size_t(o->threads));
    std::set<std::string> want(o->passes.begin(), o->passes.end());
    auto wants = [&](const char* p) { return want.count(p) || want.count("all"); };
    namespace fs = std::filesystem;
    make_output_dir(o->out, "--out");
    const std::string prefix = (fs::path(o->out) / fmt::format("f{:05d}_", o->frame)).string();

    auto t0 = std::chrono::steady_clock::now();
    const Scene scene = load_scene_or_model(o->scene, SceneSearchPath::standard(o->scene_path));
    fmt::print("scene     {} ({} objects, {} triangles, {} lights{}) loaded in {:.1f} ms\n", scene.name,
               scene.objects.size(), scene.triangle_count(), scene.lights.size(),
               scene.ao ? fmt::format(", ao {} rays r={} m", scene.ao->rays, scene.ao->radius_m) : ", no ao block",
               ms_since(t0));
    const double t = double(o->frame) / o->fps;
    const Camera cam = scene.camera.at(t, o->width, o->height);
    const Camera prev = o->frame > 0 ? scene.camera.at(double(o->frame - 1) / o->fps, o->width, o->height) : cam;

    GBuffer gbuf;
    const RasterStats rs = rasterize({&scene, cam, t, prev, o->frame > 0 ? double(o->frame - 1) / o->fps : t}, gbuf);
    fmt::print("rasterize {:8.2f} ms  {}x{}, {} triangles in, {} clipped, {} culled, {} fragments\n", rs.ms, o->width,
               o->height, rs.triangles_in, rs.triangles_clipped, rs.triangles_culled, rs.fragments);
    if (wants("gbuffer")) {
      write_png(prefix + "depth.png", visualize_depth(gbuf.depth));
      write_exr(prefix + "depth.exr", gbuf.depth);
      write_png(prefix + "normal.png", visualize_normals(gbuf.normal, gbuf.object_id));
      write_png(prefix + "albedo.png", visualize_albedo(gbuf.albedo));
      write_png(prefix + "id.png", visualize_ids(gbuf.object_id));
      write_png(prefix + "motion.png", visualize_motion(gbuf.motion));
    }
    const bool need_trace = wants("visibility") || wants("ao") || wants("composite") || wants("reference");
    if (need_trace) {
      t0 = std::chrono::steady_clock::now();
      RtScene rt(scene);
      fmt::print("bvh       {:8.2f} ms  ({} triangles built, {} skipped)\n", ms_since(t0),
                 rt.build_stats().triangles_built, rt.build_stats().skipped());
      TraceSettings ts;
      ts.seed = o->seed;
      ts.frame = uint32_t(o->frame);
      ts.ao_rays = o->ao_rays;
      ts.ao_radius_m = float(o->ao_radius_m);
      ts.soft_shadows = !o->hard;
      ts.samples_per_light = o->samples_per_light;
      const TraceResult tr = trace_passes(rt, gbuf, ts);
      fmt::print("passes    {}\n", tr.plan.describe());
      for (const TracedPass& p : tr.passes) {
        const bool shadows = p.meaning == PassMeaning::Visibility;
        const uint64_t rays = shadows ? tr.stats.shadow_rays : tr.stats.ao_rays;
        fmt::print("{:<9} {:8.2f} ms  {} rays ({:.1f} Mrays/s)", p.name, p.ms, rays,
                   double(rays) / std::max(p.ms, 1e-9) / 1e3);
        if (shadows)
          fmt::print(", {} skipped facing away, {} beyond range", tr.stats.shadow_skipped_facing,
                     tr.stats.shadow_skipped_range);
        fmt::print("\n");
      }
      if (tr.stats.invalid_rays)
        fmt::print("warning   {} invalid rays were counted and not traced\n", tr.stats.invalid_rays);
      if (wants("visibility") && tr.find("visibility")) {
        const PassBuffer& v = *tr.find("visibility");
        ImageU8 combined(v.desc.width, v.desc.height, 0);
        for (int l = 0; l < v.desc.channels; ++l) {
          const ImageU8 p = v.desc.layout() == PassLayout::Bitmask ? bit_plane(v, l) : viewable_plane(v, l);
          write_png(prefix + fmt::format("visibility_light{:02d}.png", l), p);
          for (size_t i = 0; i < p.size(); ++i)
            combined[i] = uint8_t(std::min(255, combined[i] + p[i] / v.desc.channels));
        }
        write_png(prefix + "visibility.png", combined);
      }
      if (wants("ao") && tr.find("ao")) write_png(prefix + "ao.png", viewable_plane(*tr.find("ao"), 0));
      if (wants("composite")) {
        t0 = std::chrono::steady_clock::now();
        const ImageRGB8 img = composite(gbuf, scene, composite_inputs(tr));
        fmt::print("composite {:8.2f} ms\n", ms_since(t0));
        write_png(prefix + "composite.png", img);
      }
      if (wants("reference")) {
        ReferenceSettings ref;
        ref.ao_rays = o->reference_ao_rays;
        ref.samples_per_light = o->reference_samples;
        ref.lattice = is_lattice(o->reference_sampling);
        t0 = std::chrono::steady_clock::now();
        const ReferenceResult r = ground_truth(rt, gbuf, ref);
        fmt::print("reference {:8.2f} ms  ({}; {} AO rays, {} samples per area light)\n", ms_since(t0),
                   r.from_cache ? "from the cache " + r.path
                                : fmt::format("{} rays traced", r.stats.ao_rays + r.stats.shadow_rays),
                   ref.ao_rays, ref.samples_per_light);
        write_png(prefix + "reference.png", r.image);
      }
    }
    fmt::print("images    {}*.png\n", prefix);
    return 0;
  };
}

}  // namespace dhr::cli
