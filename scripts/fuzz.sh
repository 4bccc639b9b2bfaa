#!/usr/bin/env bash
# Builds the libFuzzer targets with clang (AddressSanitizer + UndefinedBehaviorSanitizer) in
# build-fuzz, replays every seed corpus, then fuzzes each target for a while. Exits non-zero
# on any crash, leak, sanitizer report or failed check; the input that caused it is left in
# build-fuzz/artifacts/<target>/ (replay it with: build-fuzz/tests/fuzz/<target> FILE).
# Two modes:
#   default        a reproducible run: libFuzzer with a fixed seed for DHR_FUZZ_RUNS inputs per
#                  target, starting from the seed corpus only, so the same commit explores the
#                  same inputs on every machine (this is what scripts/test.sh and CI run)
#   DHR_FUZZ_SECONDS=N  exploratory: N seconds per target with a random seed, growing the work
#                  corpus in build-fuzz/corpus/ across runs; use it to look for new bugs, then
#                  add the input that found one to tests/fuzz/corpus/<target>/ with the fix
#   DHR_FUZZ_RUNS      inputs per target in the default mode (default 50000 for the packet
#                      header and the assembler, 4000 for the slower decoders and for the
#                      scene and experiment readers (~20 s each on 2 cores); 0 only replays)
#   DHR_FUZZ_SEED      libFuzzer seed in the default mode (default 1)
#   DHR_FUZZ_TARGETS   targets to run (default: fuzz_packet_header fuzz_assembler fuzz_decoders
#                      fuzz_scene_load fuzz_experiment fuzz_live_control fuzz_results fuzz_image)
#   DHR_FUZZ_JOBS      build parallelism (default: nproc)
#   DHR_FUZZ_WERROR    ON (default): clang's warnings are errors, as gcc's are in the main build
# New inputs found while fuzzing go to build-fuzz/corpus/<target>/, never into the repository.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
seconds=${DHR_FUZZ_SECONDS:-0}
seed=${DHR_FUZZ_SEED:-1}
targets=${DHR_FUZZ_TARGETS:-"fuzz_packet_header fuzz_assembler fuzz_decoders fuzz_scene_load fuzz_experiment fuzz_live_control fuzz_results fuzz_image"}
jobs=${DHR_FUZZ_JOBS:-$(nproc 2>/dev/null || echo 2)}
werror=${DHR_FUZZ_WERROR:-ON}
build=$root/build-fuzz

for tool in clang clang++; do
  command -v "$tool" >/dev/null || { echo "fuzz: $tool not found: run scripts/setup.sh" >&2; exit 1; }
done

echo "== configure and build the fuzz targets (clang, libFuzzer, ASan+UBSan)"
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DDHR_BUILD_TESTS=OFF -DDHR_BUILD_BENCHMARKS=OFF -DDHR_FUZZ=ON -DDHR_WERROR="$werror" \
  -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_C_COMPILER=clang >/dev/null
# shellcheck disable=SC2086
cmake --build "$build" -j "$jobs" --target $targets

export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:symbolize=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
status=0
for t in $targets; do
  exe=$build/tests/fuzz/$t
  seeds=$root/tests/fuzz/corpus/$t
  work=$build/corpus/$t
  artifacts=$build/artifacts/$t
  mkdir -p "$work" "$artifacts"
  echo "== $t: replay $(find "$seeds" -type f | wc -l) seeds"
  if ! "$exe" -runs=0 -artifact_prefix="$artifacts/" "$seeds" >"$build/$t.replay.log" 2>&1; then
    echo "fuzz: $t crashed on its seed corpus; see $build/$t.replay.log" >&2
    tail -n 40 "$build/$t.replay.log" >&2
    status=1
    continue
  fi
  # -rss_limit_mb bounds memory (the assembler and the decoders must not allocate from
  # untrusted sizes); -timeout catches hangs; the work corpus is listed first so that new
  # inputs go there and the seeds stay read-only.
  # The scene and experiment readers build scenes and expand sweeps per input (a few hundred
  # inputs a second): 4000 keep each near 20 s on 2 cores; live control messages carry JSON
  # bodies: 6000 are about 25 s.
  case $t in
    fuzz_decoders | fuzz_scene_load | fuzz_experiment | fuzz_image) runs=${DHR_FUZZ_RUNS:-4000} ;;
    fuzz_results) runs=${DHR_FUZZ_RUNS:-20000} ;;
    fuzz_live_control) runs=${DHR_FUZZ_RUNS:-6000} ;;
    *) runs=${DHR_FUZZ_RUNS:-50000} ;;
  esac
  if [ "$seconds" -gt 0 ]; then
    echo "== $t: fuzz for $seconds s (random seed, work corpus $work)"
    mode=(-max_total_time="$seconds")
  elif [ "$runs" -gt 0 ]; then
    echo "== $t: fuzz $runs inputs with seed $seed (reproducible)"
    rm -rf "$work" && mkdir -p "$work"
    mode=(-runs="$runs" -seed="$seed")
  else
    continue
  fi
  if ! "$exe" "${mode[@]}" -timeout=10 -rss_limit_mb=2048 -max_len=8192 \
      -print_final_stats=1 -artifact_prefix="$artifacts/" "$work" "$seeds" >"$build/$t.fuzz.log" 2>&1; then
    echo "fuzz: $t failed; see $build/$t.fuzz.log and $artifacts/" >&2
    tail -n 60 "$build/$t.fuzz.log" >&2
    status=1
    continue
  fi
  done_runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$build/$t.fuzz.log" | grep -o '[0-9]*$' || true)
  speed=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$build/$t.fuzz.log" | grep -o '[0-9]*$' || true)
  echo "   $t: ${done_runs:-?} runs, ${speed:-?} exec/s, no crash"
done
if [ "$status" -ne 0 ]; then
  echo "== fuzzing found problems" >&2
  exit 1
fi
echo "== fuzzing: no crash"
