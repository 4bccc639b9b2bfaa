#!/usr/bin/env bash
# Configures and builds one build folder. Usage: scripts/build.sh DIR [cmake options...]
set -euo pipefail
dir=${1:?usage: scripts/build.sh DIR [cmake options]}
shift
root=$(cd "$(dirname "$0")/.." && pwd)
jobs=$(nproc 2>/dev/null || echo 2)
cmake -S "$root" -B "$root/$dir" -G Ninja -DDHR_WERROR=ON "$@" >/dev/null
cmake --build "$root/$dir" -j "$jobs"
