#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: first an optimised build, then the
# same tests under AddressSanitizer and UndefinedBehaviorSanitizer. Warnings are errors.
# Then the fuzz targets replay their seed corpora and run a reproducible fuzz pass (fixed seed,
# DHR_FUZZ_RUNS inputs each; see scripts/fuzz.sh for exploratory fuzzing).
# Set DHR_SKIP_SANITIZERS=1 / DHR_SKIP_FUZZ=1 to skip those stages (not what CI does).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash scripts/setup.sh
jobs=$(nproc 2>/dev/null || echo 2)

echo "== build (Release) and test"
bash scripts/build.sh build -DCMAKE_BUILD_TYPE=Release
ctest --test-dir build --output-on-failure -j "$jobs"

if [ "${DHR_SKIP_SANITIZERS:-0}" != 1 ]; then
  echo "== build with AddressSanitizer + UndefinedBehaviorSanitizer and test"
  bash scripts/build.sh build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DDHR_SANITIZE=ON -DDHR_BUILD_BENCHMARKS=OFF
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=0 UBSAN_OPTIONS=print_stacktrace=1 \
    ctest --test-dir build-asan --output-on-failure -j "$jobs"
fi
if [ "${DHR_SKIP_FUZZ:-0}" != 1 ]; then
  echo "== fuzz targets (clang, libFuzzer): replay the seed corpora, then a fixed-seed fuzz pass"
  bash scripts/fuzz.sh
fi
echo "== all tests passed"
