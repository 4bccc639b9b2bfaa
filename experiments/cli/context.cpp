// The context block of results.json: what a reviewer needs to know to trust and reproduce a
// result (after Google Benchmark's context): the code, the build, the machine, the libraries.
#include "experiments/cli/context.h"

#include "core/base/process.h"
#include "core/trace/rt_scene.h"

#include <OpenImageIO/imageio.h>
#include <lz4.h>
#include <opencv2/core/version.hpp>
#include <opencv2/core/utility.hpp>
#include <sys/utsname.h>
#include <tbb/version.h>
#include <zstd.h>
extern "C" {
#include <libavcodec/avcodec.h>
#include <libavutil/avutil.h>
#include <x264.h>
}

#include <dlfcn.h>

#include <cstdio>
#include <fstream>
#include <thread>
#include <vector>

namespace dhr::cli {

namespace {

// A command's standard output without its trailing newlines; empty when it fails. Run from an
// argument vector (core/base/process.h), never a shell: the source folder may hold any character.
std::string run_command(const std::vector<std::string>& argv) {
  ProcessResult r = run_process(argv, {.capture_out = true, .err = ProcessOptions::Err::Discard, .max_out = 1 << 16});
  if (!r.ok()) return "";
  std::string out = std::move(r.out);
  while (!out.empty() && (out.back() == '\n' || out.back() == '\r')) out.pop_back();
  return out;
}

std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown";
}

std::string av_version(unsigned v) { return fmt::format("{}.{}.{}", v >> 16, (v >> 8) & 255, v & 255); }

// The version string of a library that libavcodec loads (x265, libaom, dav1d: their headers
// are not installed, so they are not linked directly), from the library's own version call or
// variable found in the running process; "not loaded" when the symbol is absent.
std::string wrapped_version(const char* symbol, bool is_function) {
  void* sym = dlsym(RTLD_DEFAULT, symbol);
  if (!sym) return "not loaded";
  const char* v = is_function ? reinterpret_cast<const char* (*)()>(sym)() : *static_cast<const char* const*>(sym);
  return v ? v : "unknown";
}

}  // namespace

nlohmann::json run_context(const std::string& build_type) {
  nlohmann::json c;
  c["schema_version"] = kResultsSchemaVersion;
  c["dhrbench_version"] = "0.1.0";
  const std::string src = DHR_SOURCE_DIR;
  const std::string commit = run_command({"git", "-C", src, "rev-parse", "HEAD"});
  c["git_commit"] = commit.empty() ? nlohmann::json(nullptr) : nlohmann::json(commit);
  c["git_dirty"] =
      commit.empty()
          ? nlohmann::json(nullptr)
          : nlohmann::json(!run_command({"git", "-C", src, "status", "--porcelain", "--untracked-files=no"}).empty());
  c["compiler"] = fmt::format("{} {}",
                              __GNUC__ ? (
#ifdef __clang__
                                             "clang"
#else
                                             "gcc"
#endif
                                             )
                                       : "unknown",
                              __VERSION__);
  c["build_type"] = build_type;
#ifdef __SANITIZE_ADDRESS__
  c["sanitizers"] = true;
#else
  c["sanitizers"] = false;
#endif
  c["cpu_model"] = cpu_model();
  // Embree's kernels: results differ between ISAs on rays that graze an edge (core/trace/rt_scene.h).
  c["embree_isa"] = embree_isa();
  c["hardware_threads"] = std::thread::hardware_concurrency();
  utsname u{};
  if (uname(&u) == 0) c["kernel"] = fmt::format("{} {} {}", u.sysname, u.release, u.machine);
  // Library versions, read at run time where the library offers it.
  c["libraries"] = {
      {"embree", embree_version()},
      {"lz4", LZ4_versionString()},
      {"zstd", ZSTD_versionString()},
      {"libavcodec", av_version(avcodec_version())},
      {"libavutil", av_version(avutil_version())},
      {"x264", fmt::format("build {} (compile time: x264 has no run-time version call)", X264_BUILD)},
      {"x265", wrapped_version("x265_version_str", false)},
      {"libaom", wrapped_version("aom_codec_version_str", true)},
      {"dav1d", wrapped_version("dav1d_version", true)},
      {"opencv", cv::getVersionString()},
      {"openimageio", fmt::format("{}.{}.{}", OIIO::openimageio_version() / 10000,
                                  OIIO::openimageio_version() / 100 % 100, OIIO::openimageio_version() % 100)},
      {"tbb", TBB_runtime_version()},
  };
  return c;
}

}  // namespace dhr::cli
