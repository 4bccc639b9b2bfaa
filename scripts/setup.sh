#!/usr/bin/env bash
# Installs every Debian 12 package dhrbench needs to build, test and write reports.
# Idempotent: when everything is installed already it changes nothing and needs no network.
set -euo pipefail

PACKAGES=(
  # toolchain
  g++ cmake ninja-build pkg-config git
  # libraries (cmake/dependencies.cmake names the same packages)
  libembree-dev libopenimageio-dev liblz4-dev libzstd-dev
  libavcodec-dev libavutil-dev libswscale-dev libx264-dev
  # the ffmpeg command-line tool: tests decode the streams of --dump-streams with it
  ffmpeg
  libopencv-dev libopencv-contrib-dev
  libbenchmark-dev nlohmann-json3-dev libglm-dev libassimp-dev libcli11-dev libtbb-dev libfmt-dev
  libgtest-dev libgmock-dev
  # live mode's datagram authentication (HMAC-SHA256, --key-file)
  libssl-dev
  # Reed-Solomon forward error correction of the packets (core/net/fec.h)
  libisal-dev
  # tests: the broken models that the loader must reject
  assimp-testmodels
  # fuzz targets (libFuzzer) and sanitizer runtimes for clang
  clang libclang-rt-14-dev
  # tests: the sources as .clang-format writes them (tests/format_check.sh)
  clang-format
  # report plots; results as tables (experiments/dhrbench_results: runs_frame, frames_frame)
  python3 python3-matplotlib python3-numpy python3-pandas
  # tests: report.html opened in headless Chromium (tests/python/test_report_html.py)
  chromium
  # tests: scikit-image is the reference SSIM (tests/ssim_reference.py)
  python3-skimage
  # the one-node Slurm cluster of tests/slurm/run_slurm_test.sh (scripts/slurm/)
  munge slurmctld slurmd slurm-client
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} packages are installed"
  exit 0
fi

echo "setup: installing ${#missing[@]} missing packages: ${missing[*]}"
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then
    SUDO=sudo
  else
    echo "setup: not root and no sudo. Run as root:  su -c 'bash scripts/setup.sh'" >&2
    echo "       or install by hand: apt-get install ${missing[*]}" >&2
    exit 1
  fi
else
  SUDO=
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
echo "setup: done"
