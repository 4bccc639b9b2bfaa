#!/usr/bin/env python3
"""The refactoring guard: reruns committed experiments and diffs every non-timing figure.

For each experiment NAME (default: every reports/NAME/ that has an experiments/NAME.json), runs
  dhrbench run experiments/NAME.json --out OUT/NAME
A report of a committed experiment at other settings (reports/paper_1080p: no experiment file of
its own) is rerun only when named, with the experiment and --set overrides its results.json
records (context.command).
then compares OUT/NAME against reports/NAME (or against --baseline DIR/NAME):
  - results.json: per run (matched by id), every value under "metrics" and "backends", except
    wall-clock figures (keys listed in TIMING_KEYS: measured on this machine, they vary run to run)
  - frames.csv: every column of every row (matched by run and frame), except the wall-clock ones
Runs are matched by what they are (scene, configuration, settings), not by position, so a
configuration inserted into an experiment still compares the runs it did not change; a run only in
the new results is a note, one only in the baseline a difference.
The wall-clock keys and columns are read from the new results' "declared" record (core/results/results.h),
joined with TIMING_KEYS / TIMING_COLUMNS for results older than that record.
Values must be equal bit for bit (floats as written); a figure only in the new results (a metric,
a backend setting or a frames.csv column added since the baseline) is listed as a note, one only
in the baseline is a difference. Exits 1 and lists the differences when
any figure changed; 0 when all are identical. A refactor that renames a key or column adds it to
ALIASES (new name -> old name) in the same commit, so the guard keeps comparing it.

Usage:
  scripts/check_figures.py [--dhrbench build/experiments/dhrbench] [--out /tmp/dhr-guard]
                           [--baseline reports] [--compare-only] [NAME ...]
  --compare-only: do not run, compare OUT/NAME that exists already.
  --cache DIR: the disk cache for the runs (default: OUT/cache, emptied first, so that no traced
               buffer or ground truth of an older build hides a change).
  --compare NEW OLD: compare two results folders (e.g. a merged sharded run against an unsharded
               one, tests/core/experiment/test_shard.cpp) and nothing else.
  --print-run-args NAME: print the arguments of `dhrbench run` that rerun report NAME and nothing else.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import shutil
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "experiments"))
import dhrbench_results as dr  # noqa: E402  (results.json and frames.csv(.gz) readers, errors naming the file)

# Metric keys measured on the wall clock: they depend on the machine and its load.
TIMING_KEYS = frozenset({"stages_wall", "client_frame_ms_median", "client_frame_ms_p95", "client_fps_wall", "wall_s"})
TIMING_COLUMNS = frozenset({"client_wall_ms"})
# Renamed keys and columns: new name -> the name in older results.
ALIASES = {
    # the backends record's keys are the run settings' keys (core/config/run_config.cpp); older results
    # have these names, with one "predictor" for the visibility and the AO pass.
    "passes.visibility.codec": "visibility_codec", "passes.ao.codec": "ao_codec",
    "passes.colour.codec": "colour_codec", "passes.visibility.denoiser": "visibility_denoiser",
    "passes.ao.denoiser": "ao_denoiser", "passes.visibility.predictor": "predictor",
    "passes.ao.predictor": "predictor", "passes.colour.predictor": "colour_predictor",
}


def load_results(path):
    """(results.json parsed, None), or (None, the BadResults that says why it cannot be read)."""
    try:
        return dr.load_json(path), None
    except dr.BadResults as e:
        return None, e


def old_frame_columns(row, passes):
    """frames.csv before pass-named columns: group 0 was visibility (remote: colour), group 1 ao,
    an absent pass written -1, 0, 0. Returns the row with PASS_source_frame... columns, every
    pass the run did not send left empty (as the new writer leaves it)."""
    if "source_frame_0" not in row:
        return row
    out = {k: v for k, v in row.items() if not k[-2:] in ("_0", "_1")}
    groups = {"visibility": "0", "colour": "0", "ao": "1"}
    for name, g in groups.items():
        for col in ("source_frame", "age_ms", "disoccluded"):
            out[f"{name}_{col}"] = row[f"{col}_{g}"] if name in passes else ""
    return out


def flatten(value, prefix, out, skip):
    """{path: value} of every leaf under `value`, keys in `skip` left out, renamed keys under
    their old names (ALIASES)."""
    if isinstance(value, dict):
        for k, v in value.items():
            if k in skip:
                continue
            flatten(v, f"{prefix}.{ALIASES.get(k, k)}" if prefix else ALIASES.get(k, k), out, skip)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            # lists of records with a "pass" name are matched by that name, not by position
            key = v.get("pass") if isinstance(v, dict) and "pass" in v else str(i)
            flatten(v, f"{prefix}[{key}]", out, skip)
    else:
        out[prefix] = value


def same(a, b):
    """Equal as written: numbers by value (an int may match a float), booleans only booleans, NaN NaN."""
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def run_identity(run):
    """What a run is, independent of its position in the sweep: scene, configuration and settings."""
    return (run.get("scene"), run.get("configuration", run.get("label")),
            json.dumps(run.get("settings", {}), sort_keys=True))


def match_runs(new_runs, old_runs):
    """new run id -> old run id. Runs are matched by identity (run_identity), so that a
    configuration inserted into an experiment, which shifts the ids after it, still compares run by
    run; where identities are missing or repeated, by id."""
    new_ids = {run_identity(r): r["id"] for r in new_runs}
    old_ids = {run_identity(r): r["id"] for r in old_runs}
    if len(new_ids) != len(new_runs) or len(old_ids) != len(old_runs):
        return {r["id"]: r["id"] for r in new_runs}
    return {new_ids[k]: old_ids.get(k) for k in new_ids}


def compare_results(new, old, problems, notes, run_map, skip):
    """Compares two parsed results.json run by run, the metrics in `skip` left out; fills
    `run_map` (new run id -> baseline run id) for compare_frames."""
    run_map.clear()
    run_map.update(match_runs(new["runs"], old["runs"]))
    old_runs = {r["id"]: r for r in old["runs"]}
    new_runs = {}
    for r in new["runs"]:
        old_id = run_map.get(r["id"])
        if old_id in old_runs:
            new_runs[old_id] = r
        else:
            notes.add(f"run {r['id']} ({r.get('configuration', r.get('label'))}, {r.get('scene')}): newer than the baseline")
    if set(old_runs) - set(new_runs):
        problems.append(f"runs only in the baseline: {sorted(set(old_runs) - set(new_runs))}")
    compared = 0
    for rid in sorted(set(new_runs) & set(old_runs)):  # the baseline's ids
        for part in ("metrics", "backends"):
            a, b = {}, {}
            flatten(new_runs[rid].get(part, {}), part, a, skip)
            flatten(old_runs[rid].get(part, {}), part, b, skip)
            for k in sorted(set(a) | set(b)):
                compared += 1
                if k not in b and part == "backends" and ".params." in k:
                    # a parameter added after the baseline was made: its default changes nothing
                    notes.add(f"{k.split('.', 1)[1]} = {a[k]!r} (a parameter newer than the baseline)")
                elif k not in b and part == "backends":
                    # a backend setting added after the baseline (a new pass's codec): it did
                    # not exist, so nothing it says changed
                    notes.add(f"{k.split('.', 1)[1]} (a setting newer than the baseline)")
                elif k not in b and part == "metrics":
                    # a figure added after the baseline was made: new, so nothing it says changed
                    notes.add(f"{k} (a figure newer than the baseline)")
                elif k not in a or k not in b:
                    problems.append(f"{rid} {k}: only in {'new' if k in a else 'old'}")
                elif not same(a[k], b[k]):
                    problems.append(f"{rid} {k}: new {a[k]!r}, old {b[k]!r}")
    return compared


def read_frames(path, passes_of_run, skip):
    """frames.csv, or frames.csv.gz beside it (how a published report larger than 4 MB keeps it:
    scripts/regenerate_reports.sh), keyed by (run, frame), the columns in `skip` left out."""
    rows = [old_frame_columns(r, passes_of_run.get(r["run"], [])) for r in dr.read_csv_rows(path)]
    return {(r["run"], r["frame"]): {ALIASES.get(k, k): v for k, v in r.items() if k not in skip}
            for r in rows}


def compare_frames(new_path, old_path, new_passes, old_passes, problems, run_map, notes, skip):
    """Compares two frames.csv row by row (dr.pass_names of each side's results for the older
    column names), the columns in `skip` left out."""
    try:
        old = read_frames(old_path, old_passes, skip)
        # The new rows under the baseline's run ids (run_map); rows of runs newer than the
        # baseline are left out (compare_results notes those runs).
        old_runs = {run for run, _ in old}
        new = {}
        for (run, frame), row in read_frames(new_path, new_passes, skip).items():
            old_id = run_map.get(run, run)
            if old_id in old_runs:
                new[(old_id, frame)] = dict(row, run=old_id)
    except (OSError, ValueError, KeyError) as e:  # dr.BadResults is a ValueError naming the file
        problems.append(f"cannot read frames.csv: {e}")
        return 0
    if set(new) != set(old):
        problems.append(f"frames.csv rows differ: {len(set(new) - set(old))} only new, {len(set(old) - set(new))} only old")
    compared = 0
    for key in sorted(set(new) & set(old)):
        a, b = new[key], old[key]
        for col in sorted(set(a) | set(b)):
            compared += 1
            if col not in b:
                # a column added after the baseline (a new pass's group): new, nothing changed
                notes.add(f"frames.csv column {col} (newer than the baseline)")
            elif a.get(col) != b.get(col):
                problems.append(f"frames.csv {key[0]} frame {key[1]} {col}: new {a.get(col)!r}, old {b.get(col)!r}")
    return compared


def compare(new, old):
    """(figures compared, differences, notes) of results folder NEW against OLD: results.json and
    frames.csv, without the wall-clock figures (TIMING_KEYS, TIMING_COLUMNS and those NEW's
    results declare)."""
    problems, notes = [], set()
    new_res, new_error = load_results(os.path.join(new, "results.json"))
    old_res, old_error = load_results(os.path.join(old, "results.json"))
    keys, columns = dr.wall_clock_fields(new_res)
    run_map = {}
    if new_error or old_error:
        problems.append(f"cannot read results: {new_error or old_error}")
        n = 0
    else:
        n = compare_results(new_res, old_res, problems, notes, run_map, TIMING_KEYS | keys)
    n += compare_frames(os.path.join(new, "frames.csv"), os.path.join(old, "frames.csv"), dr.pass_names(new_res),
                        dr.pass_names(old_res), problems, run_map, notes, TIMING_COLUMNS | columns)
    return n, problems, notes


def compare_folders(new, old):
    """--compare NEW OLD: prints the differences (at most 40) or that all figures are identical;
    1 when any differ."""
    n, problems, _ = compare(new, old)
    if problems:
        print(f"{new} against {old}: {len(problems)} of {n} figures differ")
        for p in problems[:40]:
            print("  " + p)
        return 1
    print(f"{new} against {old}: all {n} non-timing figures identical")
    return 0


def experiment_args(name, baseline):
    """What `dhrbench run` reruns for report NAME: experiments/NAME.json, or the experiment file and
    --set overrides recorded in BASELINE/NAME/results.json (context.command) for a report without
    an experiment file of its own."""
    own = os.path.join(ROOT, "experiments", name + ".json")
    if os.path.exists(own):
        return [own]
    path = os.path.join(baseline, name, "results.json")
    try:
        command = dr.load_json(path)["context"]["command"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SystemExit(f"{name}: no experiments/{name}.json, and no context.command in {path} ({e})")
    head, *sets = command.split(" --set ")
    if not head.startswith("dhrbench run ") or not all("=" in s for s in sets):
        raise SystemExit(f"{name}: {path}: context.command '{command}' is not "
                         "'dhrbench run EXPERIMENT [--set key=value ...]'")
    args = [os.path.join(ROOT, head[len("dhrbench run "):].strip())]
    for s in sets:
        args += ["--set", s.strip()]
    return args


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", help="experiments to check (default: every committed report with an experiment file)")
    ap.add_argument("--dhrbench", default=os.path.join(ROOT, "build/experiments/dhrbench"))
    ap.add_argument("--out", default="/tmp/dhr-guard")
    ap.add_argument("--baseline", default=os.path.join(ROOT, "reports"))
    ap.add_argument("--compare-only", action="store_true")
    ap.add_argument("--cache", help="disk cache folder, kept as it is (default: OUT/cache, emptied first)")
    ap.add_argument("--compare", nargs=2, metavar=("NEW", "OLD"), help="compare two results folders, run nothing")
    ap.add_argument("--print-run-args", metavar="NAME",
                    help="print what `dhrbench run` takes to rerun report NAME, one argument a line, run nothing "
                         "(scripts/regenerate_reports.sh)")
    args = ap.parse_args()
    if args.print_run_args:
        print("\n".join(os.path.relpath(a, ROOT) if a.startswith(ROOT) else a
                        for a in experiment_args(args.print_run_args, args.baseline)))
        return 0
    if args.compare:
        return compare_folders(*args.compare)
    env = dict(os.environ)
    if args.cache:
        env["DHR_CACHE_DIR"] = args.cache
    else:
        env["DHR_CACHE_DIR"] = os.path.join(args.out, "cache")
        if not args.compare_only:
            shutil.rmtree(env["DHR_CACHE_DIR"], ignore_errors=True)
    names = args.names or sorted(n for n in os.listdir(os.path.join(ROOT, "reports"))
                                 if os.path.exists(os.path.join(ROOT, "experiments", n + ".json"))
                                 and os.path.exists(os.path.join(ROOT, "reports", n, "results.json")))
    failed = False
    for name in names:
        out = os.path.join(args.out, name)
        if not args.compare_only:
            t0 = time.time()
            cmd = [args.dhrbench, "run", *experiment_args(name, args.baseline), "--out", out]
            r = subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            if r.returncode != 0:
                print(f"{name}: FAILED to run ({' '.join(cmd)}):\n{r.stderr[-2000:]}")
                failed = True
                continue
            print(f"{name}: ran in {time.time() - t0:.0f} s")
        n, problems, notes = compare(out, os.path.join(args.baseline, name))
        for note in sorted(notes):
            print(f"{name}: note: only in the new results: {note}")
        if problems:
            failed = True
            print(f"{name}: {len(problems)} of {n} figures differ")
            for p in problems[:40]:
                print("  " + p)
            if len(problems) > 40:
                print(f"  ... {len(problems) - 40} more")
        else:
            print(f"{name}: all {n} non-timing figures identical")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
