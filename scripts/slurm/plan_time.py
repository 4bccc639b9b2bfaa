#!/usr/bin/env python3
"""Estimates what N machines give for a sweep, from the per-run wall times of an earlier run.

  scripts/slurm/plan_time.py RESULTS_JSON EXPERIMENT [--set KEY=VALUE ...] [--scale S] [--shards 1 2 4 ...]

For each N, takes the shard plan of `dhrbench validate EXPERIMENT --shards N` (runs sharing traces
or ground truths stay together, so a shard repeats no work of the unsharded run) and sums, per
shard, the wall_s that RESULTS_JSON records for its runs, times --scale (e.g. 36 for 320x180 ->
1920x1080, assuming cost in proportion to pixels). Prints the busiest shard (the sweep's time on
N machines like the one that measured RESULTS_JSON), the speed-up and the idle share. Start-up
and merge are not included (see README.md, "On a Slurm cluster").
"""
import argparse
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "experiments"))
import dhrbench_results as dr  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results")
    ap.add_argument("experiment")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--shards", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32])
    ap.add_argument("--dhrbench", default=os.path.join(ROOT, "build/experiments/dhrbench"))
    args = ap.parse_args()
    try:
        runs = {r["id"]: r for r in dr.load_json(args.results)["runs"]}
    except dr.BadResults as e:
        sys.exit(f"plan_time: {e}")
    total = None
    for n in args.shards:
        cmd = [args.dhrbench, "validate", args.experiment, "--shards", str(n)]
        for s in args.set:
            cmd += ["--set", s]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            sys.exit(f"{' '.join(cmd)} failed:\n{out.stderr}")
        shard_s, current = [], None
        for line in out.stdout.splitlines():
            if re.match(r"\s+shard \d+/\d+:", line):
                shard_s.append(0.0)
                current = True
            elif current and (m := re.match(r"\s+(r\d+)\s", line)):
                rid = m.group(1)
                if rid not in runs or "wall_s" not in runs[rid]:
                    sys.exit(f"{args.results}: no wall_s for run {rid}")
                shard_s[-1] += runs[rid]["wall_s"] * args.scale
            elif not line.startswith(" "):
                current = None
        busiest = max(shard_s)
        total = sum(shard_s)
        print(f"{n:5d} shard(s): busiest {busiest / 3600:7.2f} h, speed-up {total / busiest:5.2f}, "
              f"idle {100 * (1 - total / (n * busiest)):4.0f}% (sum {total / 3600:.2f} h)")


if __name__ == "__main__":
    main()
