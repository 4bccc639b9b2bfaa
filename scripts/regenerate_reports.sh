#!/usr/bin/env bash
# Regenerates every published report (reports/README.md) from one clean commit, with a fresh
# disk cache, and says how long each took. Refuses to run on a tree with uncommitted changes
# (a report records the commit it came from, and "dirty" would make it unreproducible).
#   bash scripts/regenerate_reports.sh [NAME ...]     default: every experiments/NAME.json with a
#                                                     reports/NAME/, then the live report
# A report of a committed experiment at other settings (reports/paper_1080p, about an hour) has no
# experiment file of its own: it is regenerated only when named, with the experiment and --set
# overrides its results.json records (scripts/check_figures.py --print-run-args NAME).
# Needs a Release build of this commit in ./build (bash scripts/build.sh build).
# Environment: DHR_CACHE_DIR (default: a fresh folder under /tmp, removed first); DHR_JOBS (runs
# side by side, `dhrbench run --jobs`; default 1: the same figures either way, the wall time differs).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
exe=./build/experiments/dhrbench
[ -x "$exe" ] || { echo "regenerate_reports: $exe not found: bash scripts/build.sh build" >&2; exit 1; }
if [ -n "$(git status --porcelain --untracked-files=no)" ]; then
  echo "regenerate_reports: the tree has uncommitted changes; commit them first (reports name their commit)" >&2
  exit 1
fi
export DHR_CACHE_DIR=${DHR_CACHE_DIR:-/tmp/dhr-regenerate-cache}
rm -rf "$DHR_CACHE_DIR"
names=("$@")
if [ ${#names[@]} -eq 0 ]; then
  for d in reports/*/; do
    n=$(basename "$d")
    [ -f "experiments/$n.json" ] && names+=("$n")
  done
  names+=(live)
fi
scratch=$(mktemp -d /tmp/dhr-regenerate.XXXXXX)
echo "regenerate_reports: commit $(git rev-parse --short HEAD), cache $DHR_CACHE_DIR (cold), scratch $scratch"
for n in "${names[@]}"; do
  start=$(date +%s)
  # Each run writes to a scratch folder first: overwriting reports/ while it runs would make the
  # next report's context record a dirty tree.
  tmp=$scratch/$n
  if [ "$n" = live ]; then
    DHR_LIVE_CLIENT_ARGS="--save-every 300" DHR_LIVE_FRAMES=600 bash scripts/live_loopback.sh "$tmp" >/dev/null
  else
    mapfile -t run_args < <(python3 scripts/check_figures.py --print-run-args "$n")
    [ ${#run_args[@]} -gt 0 ] || { echo "regenerate_reports: no run arguments for $n" >&2; exit 1; }
    "$exe" run "${run_args[@]}" --jobs "${DHR_JOBS:-1}" --out "$tmp" >/dev/null
  fi
  echo "regenerate_reports: $n took $(( $(date +%s) - start )) s"
done
# Every run done: replace the published folders (live's report.md is written from its files by
# experiments/report_live.py).
for n in "${names[@]}"; do
  if [ "$n" = live ]; then
    rm -rf reports/live/client reports/live/server reports/live/*.log reports/live/relay.json
    cp -r "$scratch/live/." reports/live/
    /usr/bin/python3 experiments/report_live.py reports/live
  else
    rm -rf "reports/$n"
    cp -r "$scratch/$n" "reports/$n"
    # The full-size frames (images/) stay out of the repository: the report is written again
    # without them (report.md keeps its downscaled grids; report.html then has no image viewer).
    if [ -d "reports/$n/images" ]; then
      rm -rf "reports/$n/images"
      "$exe" report "reports/$n" >/dev/null
    fi
    # The repository keeps files under 4 MB: a larger frames.csv is committed gzip-compressed
    # (report.py and check_figures.py read either form).
    f="reports/$n/frames.csv"
    if [ -f "$f" ] && [ "$(stat -c %s "$f")" -gt 4000000 ]; then gzip -9n "$f"; fi
    # A larger results.json is written again without indentation: the same values (every reader
    # parses it), a quarter fewer bytes.
    f="reports/$n/results.json"
    if [ "$(stat -c %s "$f")" -gt 4000000 ]; then
      /usr/bin/python3 -c 'import json, sys; d = json.load(open(sys.argv[1])); json.dump(d, open(sys.argv[1], "w"), separators=(",", ":"), ensure_ascii=False)' "$f"
    fi
  fi
done
# The index (reports/README.md) is written from the reports it lists.
/usr/bin/python3 experiments/report_index.py
echo "regenerate_reports: reports/ and reports/README.md updated from $scratch"
