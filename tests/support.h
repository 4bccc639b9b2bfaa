// Helpers shared by the tests: where the repository and the real scenes are.
#pragma once

#include "core/metrics/temporal.h"
#include "core/scene/scene.h"

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <functional>
#include <optional>
#include <string>

namespace dhr::test {

// The repository root (tests run from the build tree).
std::string source_dir();
// ../shared/scenes beside the checkout, or $DHR_SCENE_PATH's first entry when set.
std::string shared_scenes_dir();

// A static scene object with id `id`: `mesh` moved by `offset` (world space), with `material`.
Object make_object(uint32_t id, Mesh mesh, glm::vec3 offset, uint32_t material = 0);

// A sphere light at `p` (radius 0: a point light) and a distant light shining along `dir`
// (angular radius 0: hard), as the trace tests build them.
Light sphere_light(glm::vec3 p, float radius_m, float intensity);
Light distant_light(glm::vec3 dir, float angular_radius_deg = 0.0f);

// Calls fn(name, scene) for every built-in and real scene (core/scene/scene_load.h) that loads; name is
// the file's stem. One that does not load (a real scene whose assets are not here) is skipped and
// said so on stdout.
void for_each_scene(const std::function<void(const std::string& name, const Scene& scene)>& fn);

// FNV-1a (64 bit) over bytes: the pinned-hash tests (test_trace_bits, test_raster_bits) fold
// buffers and values into it.
struct Fnv1a {
  uint64_t h = 1469598103934665603ull;
  void bytes(const void* p, size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    for (size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ull;
  }
  template <class T>
  void value(const T& v) {
    bytes(&v, sizeof v);
  }
  template <class I>
  void plane(const I& image) {
    bytes(image.data(), image.size() * sizeof(image[0]));
  }
};

// temporal_scores (core/metrics/temporal.h) as one sequential loop over the pixels, the way
// core/metrics/temporal.cpp computed them before its per-pixel terms ran in vectorized chunks: the
// definition of the bits it keeps (tests/core/metrics/test_temporal.cpp) and the "before" of bench_metrics.
TemporalScores temporal_scores_one_loop(const ImageRGB8& reference_prev, const ImageRGB8& reference,
                                        const ImageRGB8& test_prev, const ImageRGB8& test, double static_threshold);

// The message of the dhr::Error that `f` throws; "" when it throws none.
std::string error_of(const std::function<void()>& f);

// Runs `program` with `args` from an argument vector (no shell: any character in an argument
// reaches it as written); its standard output and error together in `log`. Returns the exit
// code (-1 when it did not exit normally).
int run_program(const std::string& program, const std::vector<std::string>& args, std::string& log);

// Sets an environment variable for a scope (setenv), then restores its earlier value or
// absence. Tests run one at a time in their process.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    ::setenv(name, value, 1);
  }
  ~ScopedEnv() {
    if (old_)
      ::setenv(name_.c_str(), old_->c_str(), 1);
    else
      ::unsetenv(name_.c_str());
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  std::string name_;
  std::optional<std::string> old_;
};

}  // namespace dhr::test
