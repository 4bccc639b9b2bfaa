#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the default experiment
# (experiments/quick.json: the built-in room scene, five configurations, about a minute on
# 2 cores), writing results and a report to out/quick/.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash scripts/setup.sh
bash scripts/build.sh build -DCMAKE_BUILD_TYPE=Release
./build/experiments/dhrbench run experiments/quick.json --out out/quick
echo "main: report written to $root/out/quick/report.md"
