#!/usr/bin/env bash
# The main job: installs what is missing, builds, and renders a built-in scene.
# (Until the experiment runner lands, the main job renders the G-buffer of a few frames of
# the built-in room scene into out/main/.)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash scripts/setup.sh
bash scripts/build.sh build -DCMAKE_BUILD_TYPE=Release
for frame in 0 120 300; do
  ./build/experiments/dhrbench render --scene scenes/room.json --frame "$frame" --out out/main
done
echo "main: images written to $root/out/main"
