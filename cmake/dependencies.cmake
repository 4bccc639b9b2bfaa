# Every dependency comes from a Debian 12 package. A missing one stops configuration with
# the name of the package to install (scripts/setup.sh installs all of them).
find_package(PkgConfig QUIET)
if(NOT PKG_CONFIG_FOUND)
  message(FATAL_ERROR "pkg-config not found: apt-get install pkg-config (or run scripts/setup.sh)")
endif()

macro(dhr_find_config name debian_pkg)
  find_package(${name} ${ARGN} QUIET)
  if(NOT ${name}_FOUND)
    message(FATAL_ERROR "dhrbench needs ${name}: apt-get install ${debian_pkg} (or run scripts/setup.sh)")
  endif()
endmacro()

macro(dhr_find_pkgconfig prefix module debian_pkg)
  pkg_check_modules(${prefix} QUIET IMPORTED_TARGET ${module})
  if(NOT ${prefix}_FOUND)
    message(FATAL_ERROR "dhrbench needs ${module} (pkg-config): apt-get install ${debian_pkg} (or run scripts/setup.sh)")
  endif()
endmacro()

dhr_find_config(embree libembree-dev 3 CONFIG)
dhr_find_config(OpenCV "libopencv-dev libopencv-contrib-dev" COMPONENTS core imgproc quality)
dhr_find_config(nlohmann_json nlohmann-json3-dev CONFIG)
dhr_find_config(glm libglm-dev CONFIG)
dhr_find_config(assimp libassimp-dev CONFIG)
dhr_find_config(CLI11 libcli11-dev CONFIG)
dhr_find_config(TBB libtbb-dev CONFIG)
dhr_find_config(fmt libfmt-dev CONFIG)
# OpenImageIO through pkg-config: Debian's CMake config also demands the command-line tools
# and the Python bindings of Imath.
dhr_find_pkgconfig(OIIO OpenImageIO libopenimageio-dev)
dhr_find_pkgconfig(LZ4 liblz4 liblz4-dev)
dhr_find_pkgconfig(ZSTD libzstd libzstd-dev)
dhr_find_pkgconfig(AVCODEC libavcodec libavcodec-dev)
dhr_find_pkgconfig(AVUTIL libavutil libavutil-dev)
dhr_find_pkgconfig(SWSCALE libswscale libswscale-dev)
dhr_find_pkgconfig(X264 x264 libx264-dev)
# Reed-Solomon erasure codes for the packets' forward error correction (core/net/fec.h).
dhr_find_pkgconfig(ISAL libisal libisal-dev)
# HMAC-SHA256 for live mode's optional datagram authentication (--key-file, core/live/live_protocol.h).
dhr_find_pkgconfig(CRYPTO libcrypto libssl-dev)
if(DHR_BUILD_TESTS)
  dhr_find_config(GTest "libgtest-dev libgmock-dev" CONFIG)
endif()
if(DHR_BUILD_BENCHMARKS)
  dhr_find_config(benchmark libbenchmark-dev CONFIG)
endif()
