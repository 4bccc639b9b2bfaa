"""Reads what 'dhrbench run' wrote in a results folder: results.json and frames.csv (or the
frames.csv.gz a published report keeps), checked field by field the way experiments/report.py
needs them; every problem is one BadResults naming the file and the field, never a traceback.
Also the other results the reports read: the convergence checks of 'dhrbench converge'
(reports/converge/*.json) and the three files of a live run (reports/live).

    import dhrbench_results as dr
    res = dr.load("reports/quick")          # checked: res.results, res.declared, res.frames (rows)
    runs = dr.runs_frame(res)               # pandas: one row per run, units in runs.attrs["units"]
    frames = dr.frames_frame(res)           # pandas: one row per displayed frame
    checks = dr.load_convergence_checks("reports/converge")  # [(file name, check)]
    live = dr.load_live("reports/live")     # client, server session and relay records

    python3 -m dhrbench_results DIR         # a short summary table (PYTHONPATH=experiments)

The module lives beside report.py in experiments/ (report.py, which 'dhrbench run' starts by
its path, finds it there without a path of its own; scripts/check_figures.py and the tests put
experiments/ on sys.path as they do for rate_quality). Loading and checking need only the
standard library; runs_frame and frames_frame need pandas (python3-pandas, scripts/setup.sh).
"""
import csv
import gzip
import io
import json
import math
import os
import zlib
from typing import NamedTuple

MAX_JSON_DEPTH = 64  # core/base/json_io.h kMaxJsonDepth: the limit for every JSON dhrbench reads


# The image metrics of results written before results.json declared them ("declared", from
# core/results/results.cpp): SSIM and PSNR, with the same names.
DECLARED_BEFORE_RECORD = {"image_metrics": [
    {"name": "ssim", "unit": "", "higher_is_better": True,
     "columns": {"local": "ssim_local", "ground_truth": "ssim_ground_truth"},
     "aggregates": {"local": {"mean": "ssim_local_mean"}, "ground_truth": {"mean": "ssim_ground_truth_mean"}}},
    {"name": "psnr", "unit": "db", "higher_is_better": True,
     "columns": {"local": "psnr_local_db", "ground_truth": "psnr_ground_truth_db"},
     "aggregates": {"local": {"mean": "psnr_local_mean_db"}, "ground_truth": {"mean": "psnr_ground_truth_mean_db"}}}]}


class BadResults(ValueError):
    """Damaged input: the message names the file and what is wrong (report.py prints it, exit 2)."""


def excerpt(v, limit=60):
    try:
        s = json.dumps(v, ensure_ascii=False)
    except (TypeError, ValueError, RecursionError):
        s = repr(v)
    return s if len(s) <= limit else s[:limit] + "..."


def _no_constant(name):
    raise ValueError(f"{name} is not a JSON number")


def _finite_float(text):
    v = float(text)
    if math.isinf(v):
        raise ValueError(f"number out of range: {text[:40]}")
    return v


def load_json(path):
    """results.json as dhrbench reads JSON: strict (no NaN/Infinity, no 1e400), depth-bounded."""
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        raise BadResults(f"{path}: cannot read the file: {e.strerror}")
    except UnicodeDecodeError as e:
        raise BadResults(f"{path}: not UTF-8 text (byte {e.start})")
    try:
        value = json.loads(text, parse_constant=_no_constant, parse_float=_finite_float)
    except RecursionError:
        raise BadResults(f"{path}: JSON nested deeper than {MAX_JSON_DEPTH} levels of arrays and objects "
                         "(the limit for every JSON dhrbench reads)")
    except ValueError as e:  # json.JSONDecodeError too
        raise BadResults(f"{path}: not valid JSON: {str(e)[:240]}")
    # The depth of what was parsed, without recursion.
    stack = [(value, 0)]
    while stack:
        v, depth = stack.pop()
        if isinstance(v, (list, dict)):
            depth += 1
            if depth > MAX_JSON_DEPTH:
                raise BadResults(f"{path}: JSON nested deeper than {MAX_JSON_DEPTH} levels of arrays and objects "
                                 "(the limit for every JSON dhrbench reads)")
            stack.extend((c, depth) for c in (v.values() if isinstance(v, dict) else v))
    return value


class Checker:
    """Checks the fields of results.json that the report reads; every problem names its JSON path."""

    def __init__(self, path):
        self.path = path

    def fail(self, where, what, v):
        raise BadResults(f"{self.path}: {where}: must be {what}, got {excerpt(v)}")

    def obj(self, v, where):
        if not isinstance(v, dict):
            self.fail(where, "a JSON object", v)
        return v

    def lst(self, v, where):
        if not isinstance(v, list):
            self.fail(where, "a list", v)
        return v

    def num(self, v, where, none_ok=False):
        if v is None and none_ok:
            return
        ok = isinstance(v, (int, float)) and not isinstance(v, bool)
        if ok:
            try:
                ok = math.isfinite(float(v))
            except OverflowError:
                ok = False
        if not ok:
            self.fail(where, "a finite number" + (" or null" if none_ok else ""), v)

    def name(self, v, where, filename=False):
        """A string; a name that becomes part of a file name has no path separator or NUL."""
        if not isinstance(v, str) or not v or "\0" in v or (filename and ("/" in v or "\\" in v or v in (".", ".."))):
            self.fail(where, "a non-empty string" + (" without / (it names image files)" if filename else ""), v)

    def results(self, res):
        self.obj(res, "(top level)")
        for key in ("context", "experiment", "runs"):
            if key not in res:
                raise BadResults(f"{self.path}: \"{key}\" is missing (is this a results.json written by 'dhrbench run'?)")
        ctx = self.obj(res["context"], "context")
        if "libraries" in ctx:
            self.obj(ctx["libraries"], "context.libraries")
        exp = self.obj(res["experiment"], "experiment")
        for key in ("name", "description"):
            if key in exp and not isinstance(exp[key], str):
                self.fail(f"experiment.{key}", "a string", exp[key])
        notes = exp.get("notes")
        if notes is not None and not isinstance(notes, str) and not (
                isinstance(notes, list) and all(isinstance(n, str) for n in notes)):
            self.fail("experiment.notes", "a string or a list of strings", notes)
        if "experiment_path" in res and not isinstance(res["experiment_path"], str):
            self.fail("experiment_path", "a string", res["experiment_path"])
        if "wall_s" in res:
            self.num(res["wall_s"], "wall_s")
        self.declared = self.declaration(res.get("declared", DECLARED_BEFORE_RECORD))
        for i, r in enumerate(self.lst(res["runs"], "runs")):
            self.run(r, f"runs[{i}]")

    def declaration(self, d):
        """The "declared" record: every image metric with its columns and aggregate keys."""
        self.obj(d, "declared")
        if "image_metrics" not in d:
            raise BadResults(f"{self.path}: declared.image_metrics is missing")
        for j, m in enumerate(self.lst(d["image_metrics"], "declared.image_metrics")):
            w = f"declared.image_metrics[{j}]"
            self.obj(m, w)
            for key in ("name", "unit"):
                if not isinstance(m.get(key), str):
                    self.fail(f"{w}.{key}", "a string", m.get(key))
            if not isinstance(m.get("higher_is_better"), bool):
                self.fail(f"{w}.higher_is_better", "true or false", m.get("higher_is_better"))
            for ref in ("local", "ground_truth"):
                self.name(self.obj(m.get("columns"), f"{w}.columns").get(ref), f"{w}.columns.{ref}")
                self.name(self.obj(self.obj(m.get("aggregates"), f"{w}.aggregates").get(ref), f"{w}.aggregates.{ref}")
                          .get("mean"), f"{w}.aggregates.{ref}.mean")
        if not d["image_metrics"]:
            raise BadResults(f"{self.path}: declared.image_metrics is empty (the report needs one metric)")
        return d

    def run(self, r, where):
        self.obj(r, where)
        for key in ("id", "scene", "label"):
            if key not in r:
                raise BadResults(f"{self.path}: {where}.{key} is missing")
        self.name(r["id"], f"{where}.id", filename=True)
        self.name(r["scene"], f"{where}.scene")
        if not isinstance(r["label"], str):
            self.fail(f"{where}.label", "a string", r["label"])
        if "error" in r and not isinstance(r["error"], str):
            self.fail(f"{where}.error", "a string", r["error"])
        for key in ("config", "images"):
            if key in r:
                self.obj(r[key], f"{where}.{key}")
        if "metrics" not in r:
            if "error" not in r:
                raise BadResults(f"{self.path}: {where} ({r['id']}) has neither \"metrics\" nor \"error\": the record "
                                 "is incomplete (a run always records one of them)")
            return
        m = self.obj(r["metrics"], f"{where}.metrics")
        if "frames_displayed" in m and (not isinstance(m["frames_displayed"], int) or isinstance(
                m["frames_displayed"], bool) or m["frames_displayed"] < 0):
            self.fail(f"{where}.metrics.frames_displayed", "a whole number >= 0", m["frames_displayed"])
        w = f"{where}.metrics"
        for key in ("bandwidth_mbps", "server_fps_virtual", "client_fps_wall"):
            if key not in m:
                raise BadResults(f"{self.path}: {w}.{key} is missing")
            self.num(m[key], f"{w}.{key}")
        for im in self.declared["image_metrics"]:
            for ref in ("local", "ground_truth"):
                key = im["aggregates"][ref]["mean"]
                if key in m:
                    self.num(m[key], f"{w}.{key}", none_ok=True)
        for key in ("passes", "stages_wall"):
            if key not in m:
                raise BadResults(f"{self.path}: {w}.{key} is missing")
        for j, p in enumerate(self.lst(m["passes"], f"{w}.passes")):
            pw = f"{w}.passes[{j}]"
            self.obj(p, pw)
            for key in ("pass", "bytes_per_frame", "server_frames", "frames_lost"):
                if key not in p:
                    raise BadResults(f"{self.path}: {pw}.{key} is missing")
            for key in ("bytes_per_frame", "server_frames", "frames_lost"):
                self.num(p[key], f"{pw}.{key}")
            if "delivered_fps" in p:
                self.num(p["delivered_fps"], f"{pw}.delivered_fps")
        for stage, st in self.obj(m["stages_wall"], f"{w}.stages_wall").items():
            sw = f"{w}.stages_wall.{stage}"
            self.obj(st, sw)
            for key in ("median_ms", "p95_ms"):
                if key not in st:
                    raise BadResults(f"{self.path}: {sw}.{key} is missing")
                self.num(st[key], f"{sw}.{key}")
        for key, v in m.items():
            if key.startswith("buffer_age_ms_"):
                self.obj(v, f"{w}.{key}")
                if "median" not in v:
                    raise BadResults(f"{self.path}: {w}.{key}.median is missing")
                self.num(v["median"], f"{w}.{key}.median")


def open_frames(path):
    """The text of frames.csv, or of frames.csv.gz beside it when only that exists (a published
    report larger than 4 MB keeps it compressed: scripts/regenerate_reports.sh); `path` may name
    either."""
    if not os.path.exists(path) and not path.endswith(".gz") and os.path.exists(path + ".gz"):
        path = path + ".gz"
    opener = gzip.open if path.endswith(".gz") else open
    return opener(path, "rt", encoding="utf-8", newline=""), path


def read_csv_rows(path):
    """frames.csv (or .gz, open_frames) as a list of {column: text}; a file that is cut inside a
    row, not UTF-8 or no CSV is a BadResults naming it. The fields are not checked (load_frames)."""
    try:
        f, path = open_frames(path)
        with f:
            text = f.read()
        if text and not text.endswith("\n"):
            raise BadResults(f"{path}: the file ends inside its last row (cut short): a complete row ends with a newline")
        return list(csv.DictReader(io.StringIO(text, newline="")))
    except OSError as e:
        raise BadResults(f"{path}: cannot read the file: {e.strerror or e}")
    except (UnicodeDecodeError, csv.Error, EOFError, zlib.error) as e:
        raise BadResults(f"{path}: not a CSV file as 'dhrbench run' writes it: {str(e)[:120]}")


def load_frames(path, column):
    """frames.csv rows; the columns the report reads are checked (frame an integer, `column` -- the first
    declared image metric against the local reference, ssim_local -- a number)."""
    rows = read_csv_rows(path)
    for n, row in enumerate(rows, start=2):
        extra, missing = len(row.get(None) or []), sum(v is None for k, v in row.items() if k is not None)
        if extra or missing:
            header = len(row) - (None in row)
            raise BadResults(f"{path}: line {n}: {header + extra - missing} fields where the header has {header} "
                             "(a row cut short, or a damaged file)")
        for key in ("run", "frame", column):
            if row.get(key) is None:
                raise BadResults(f"{path}: line {n}: the column \"{key}\" is missing")
        try:
            int(row["frame"])
            if row[column] != "":
                if not math.isfinite(float(row[column])):
                    raise ValueError
        except ValueError:
            raise BadResults(f"{path}: line {n}: frame must be an integer and {column} a number or empty, got "
                             f"{excerpt(row['frame'])} and {excerpt(row[column])}")
    return rows


def check_frames_against_runs(frames, runs, path):
    """Every row of a run of results.json, and per run as many rows as it displayed frames."""
    count = {}
    for row in frames:
        count[row["run"]] = count.get(row["run"], 0) + 1
    ids = {r["id"] for r in runs}
    for run_id in count:
        if run_id not in ids:
            raise BadResults(f"{path}: rows of run {excerpt(run_id)}, which results.json does not hold")
    for r in runs:
        want = r["metrics"].get("frames_displayed") if "metrics" in r else 0
        if want is None:
            continue  # results written before frames_displayed was recorded
        if count.get(r["id"], 0) != want:
            raise BadResults(f"{path}: run {r['id']} has {count.get(r['id'], 0)} row(s), but results.json says it "
                             f"displayed {want} frame(s)")


class Results(NamedTuple):
    """A checked results folder: `results` (results.json as parsed), `declared` (its "declared"
    record, or the one of results written before it), `frames` (frames.csv rows, {column: text}),
    and the paths read."""
    results: dict
    declared: dict
    frames: list
    results_path: str
    frames_path: str

    @property
    def headline(self):
        """The headline image metric: the first declared (SSIM)."""
        return self.declared["image_metrics"][0]


def frames_path(d):
    """DIR/frames.csv, else DIR/frames.csv.gz; BadResults when neither exists."""
    for name in ("frames.csv", "frames.csv.gz"):
        if os.path.exists(os.path.join(d, name)):
            return os.path.join(d, name)
    raise BadResults(f"{os.path.join(d, 'frames.csv')}: missing: the report needs the frames of every run")


def load(d):
    """Reads and checks DIR/results.json and DIR/frames.csv(.gz) (Results); BadResults names the
    file and the field of the first problem."""
    results_path = os.path.join(d, "results.json")
    res = load_json(results_path)
    checker = Checker(results_path)
    checker.results(res)
    path = frames_path(d)
    frames = load_frames(path, checker.declared["image_metrics"][0]["columns"]["local"])
    check_frames_against_runs(frames, res["runs"], os.path.join(d, "frames.csv"))
    return Results(res, checker.declared, frames, results_path, path)


def wall_clock_fields(results):
    """(run metric keys, frames.csv columns) that a parsed results.json declares measured on the
    wall clock; empty sets for results written before the "declared" record."""
    declared = results.get("declared", {}) if isinstance(results, dict) else {}
    keys = {m["key"] for m in declared.get("run_metrics", []) if m.get("wall_clock")}
    return keys, set(declared.get("frames_csv_wall_clock_columns", []))


def pass_names(results):
    """{run id: the names of the passes it sent (metrics.passes[].pass)} of a parsed results.json;
    {} where it holds no list of runs with ids."""
    try:
        return {r["id"]: [p["pass"] for p in r.get("metrics", {}).get("passes", [])] for r in results["runs"]}
    except (KeyError, TypeError):
        return {}


def load_convergence_check(path):
    """One convergence.json of 'dhrbench converge', checked: "scenes" a list of {scene, frames,
    summary of numbers}; BadResults naming the file otherwise."""
    chk = load_json(path)
    scenes = chk.get("scenes") if isinstance(chk, dict) else None
    if not isinstance(scenes, list) or not all(
            isinstance(s, dict) and isinstance(s.get("frames"), list) and isinstance(s.get("summary"), dict)
            and all(isinstance(v, (int, float)) for v in s["summary"].values()) for s in scenes):
        raise BadResults(f"{path}: not the convergence.json of `dhrbench converge` (scenes: a list of "
                         "{scene, frames, summary of numbers})")
    return chk


def load_convergence_checks(folder):
    """[(file name, check)] of FOLDER/*.json in name order, each checked (load_convergence_check):
    a damaged check is an error naming the file, never skipped. [] when the folder cannot be
    listed."""
    try:
        names = sorted(n for n in os.listdir(folder) if n.endswith(".json"))
    except OSError:
        return []
    return [(n, load_convergence_check(os.path.join(folder, n))) for n in names]


def field(d, path, where):
    """d[a][b]... for path "a.b...", a BadResults naming `where` and the field when it is missing."""
    v = d
    for k in path.split("."):
        if not isinstance(v, dict) or k not in v:
            raise BadResults(f"{where}: {path}: missing")
        v = v[k]
    return v


def number(d, path, where):
    """field() that must be a number (not a boolean)."""
    v = field(d, path, where)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise BadResults(f"{where}: {path}: must be a number, got {excerpt(v)}")
    return v


class LiveResults(NamedTuple):
    """A live run's folder (scripts/live_loopback.sh DIR): the client's summary (client/live.json),
    the server's one session (server/server.json sessions[0]), the relay's record (relay.json),
    the paths they were read from, and the names of the client's saved frames (client/frames/*.png,
    sorted)."""
    client: dict
    session: dict
    relay: dict
    client_path: str
    server_path: str
    relay_path: str
    saved_frames: list


def load_live(d):
    """Reads DIR/client/live.json, DIR/server/server.json and DIR/relay.json (LiveResults); the
    server must hold exactly one session. The fields are checked where they are read (field,
    number)."""
    cpath, spath, rpath = (os.path.join(d, p) for p in ("client/live.json", "server/server.json", "relay.json"))
    c, s, r = load_json(cpath), load_json(spath), load_json(rpath)
    sessions = field(s, "sessions", spath)
    if not isinstance(sessions, list) or len(sessions) != 1:
        raise BadResults(f"{spath}: sessions: must hold the one session of the run, got {excerpt(sessions)}")
    frames = os.path.join(d, "client", "frames")
    saved = sorted(f for f in os.listdir(frames) if f.endswith(".png")) if os.path.isdir(frames) else []
    return LiveResults(c, sessions[0], r, cpath, spath, rpath, saved)


def _pandas():
    try:
        import pandas
    except ImportError:
        raise ImportError("dhrbench_results needs pandas for tables: apt-get install python3-pandas "
                          "(or run scripts/setup.sh)") from None
    return pandas


def _flatten(value, prefix, out):
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(v, f"{prefix}.{k}" if prefix else k, out)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            key = v.get("pass") if isinstance(v, dict) and "pass" in v else str(i)
            _flatten({k: x for k, x in v.items() if k != "pass"} if isinstance(v, dict) else v, f"{prefix}.{key}", out)
    else:
        out[prefix] = value


def metric_units(declared):
    """{metrics key: unit} from the "declared" record: the run metrics, every image metric's
    aggregates (the metric's unit; "" for a number without one) and the per-pass metrics
    (passes.PASS.key)."""
    units = {}
    for m in declared.get("run_metrics", []):
        if isinstance(m, dict) and isinstance(m.get("key"), str):
            units[m["key"]] = m.get("unit", "")
    for im in declared.get("image_metrics", []):
        for ref in ("local", "ground_truth"):
            for key in im.get("aggregates", {}).get(ref, {}).values():
                units[key] = im.get("unit", "")
    return units


def runs_frame(res):
    """pandas DataFrame, one row per run of a Results (load()): id, scene, label, configuration,
    family, mode, error; every setting as "settings.KEY" (a JSON object as its JSON text); every
    metric flattened ("bandwidth_mbps", "passes.ao.bytes_per_frame", "stages_wall.encode.median_ms",
    "buffer_age_ms_ao.median"). attrs["units"]: {column: unit} for the metrics results.json
    declares (the unit of passes.PASS.KEY is that of the pass metric KEY)."""
    pd = _pandas()
    units = metric_units(res.declared)
    pass_units = {m["key"]: m.get("unit", "") for m in res.declared.get("pass_metrics", [])
                  if isinstance(m, dict) and isinstance(m.get("key"), str)}
    rows = []
    for r in res.results["runs"]:
        row = {"id": r["id"], "scene": r["scene"], "label": r["label"],
               "configuration": r.get("configuration"), "family": r.get("family") or r.get("configuration") or r["label"],
               "mode": r.get("config", {}).get("mode"), "error": r.get("error")}
        for k, v in (r.get("settings") or {}).items():
            row[f"settings.{k}"] = json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else v
        metrics = {}
        _flatten(r.get("metrics", {}), "", metrics)
        row.update(metrics)
        rows.append(row)
    df = pd.DataFrame(rows)
    col_units = {}
    for c in df.columns:
        if c in units:
            col_units[c] = units[c]
        elif c.startswith("passes.") and c.rsplit(".", 1)[-1] in pass_units:
            col_units[c] = pass_units[c.rsplit(".", 1)[-1]]
        elif c.startswith("stages_wall."):
            col_units[c] = "ms"
        elif c.startswith("buffer_age_ms_"):
            col_units[c] = "ms"
    df.attrs["units"] = col_units
    return df


def frames_frame(res):
    """pandas DataFrame, one row per displayed frame (frames.csv): run, scene and label as text,
    every other column a number (empty: NaN). attrs["units"]: the declared image metrics'
    columns with their units."""
    pd = _pandas()
    df = pd.DataFrame(res.frames)
    for c in df.columns:
        if c not in ("run", "scene", "label"):
            df[c] = pd.to_numeric(df[c].replace("", None), errors="coerce")
    units = {}
    for im in res.declared["image_metrics"]:
        for ref in ("local", "ground_truth"):
            units[im["columns"][ref]] = im.get("unit", "")
    df.attrs["units"] = {c: u for c, u in units.items() if c in df.columns}
    return df


def summary(res):
    """A short text table: per scene and family, its runs, their bitrate range and the mean of
    the headline metric's run means against the local reference and the ground truth."""
    df = runs_frame(res)
    h = res.headline
    local, truth = h["aggregates"]["local"]["mean"], h["aggregates"]["ground_truth"]["mean"]
    agg = {"runs": ("id", "count")}
    if "bandwidth_mbps" in df.columns:
        agg["Mb/s min"] = ("bandwidth_mbps", "min")
        agg["Mb/s max"] = ("bandwidth_mbps", "max")
    for col, name in ((local, f"{h['name']} local"), (truth, f"{h['name']} truth")):
        if col in df.columns:
            agg[name] = (col, "mean")
    if "error" in df.columns and df["error"].notna().any():
        agg["failed"] = ("error", "count")
    table = df.groupby(["scene", "family"], sort=True).agg(**agg).reset_index()
    ok = sum("metrics" in r for r in res.results["runs"])
    head = (f"{res.results_path}: {len(df)} runs ({ok} with metrics), {len(res.frames)} frames "
            f"({os.path.basename(res.frames_path)}); experiment {res.results['experiment'].get('name', '?')}; "
            "image metrics: " + ", ".join(im["name"] for im in res.declared["image_metrics"]))
    return head + "\n" + table.to_string(index=False, float_format=lambda v: f"{v:.4f}")
