#!/usr/bin/python3
"""Figure, Pareto fronts and report.md of the denoiser accuracy-versus-time tables.

Input: the CSV written by `bench_denoise --accuracy --csv=PATH` (one row per scene, AO rays,
denoiser, frame of history: SSIM and MAE against converged AO, trace / denoise / total ms), and
beside it, when present, svgf_variants_room.csv, light_history_frame8.csv and
light_history_frame40.csv (the same columns, from the runs that report.md names).
Output, beside the CSV:
  accuracy.png  SSIM against total ms per scene (log x, one line per denoiser; solid = the
                frame with history of a static camera, dashed = frame 1, no history);
  report.md     written from the CSVs alone (every figure in it is computed here, so it cannot
                go stale; tests/python/test_denoise_accuracy_report.py checks the committed one);
and on stdout the Pareto front per scene and frame of history: the (rays, denoiser) points that
no other point beats in both time (lower total_ms) and SSIM (higher), fastest first.

Usage: /usr/bin/python3 reports/denoise_accuracy/plot.py [--report-only] [PATH/accuracy.csv]
  --report-only  write report.md only (no figure, no matplotlib; report.md is byte-stable,
                 the PNG is not)
A damaged CSV (a missing field, a value that is not a number) is one line on stderr naming the
file and line, and exit status 2.
"""
import csv
import math
import os
import sys

DENOISERS = ["none", "single_iteration", "atrous", "svgf_ao"]
COLOURS = {"none": "tab:gray", "single_iteration": "tab:blue", "atrous": "tab:orange", "svgf_ao": "tab:green"}
INT_FIELDS = ("rays", "frame_of_history", "width", "height", "reference_rays", "threads")
FLOAT_FIELDS = ("ssim", "mae_levels", "trace_ms", "denoise_ms", "total_ms")
FIELDS = ("scene", "denoiser") + INT_FIELDS + FLOAT_FIELDS
SSIM_GOAL = 0.9  # the answer's quality bar: the cheapest point reaching it
VARIANTS_CSV = "svgf_variants_room.csv"
LIGHT_CSVS = ("light_history_frame8.csv", "light_history_frame40.csv")
DASH = "\u2013"  # en dash of ranges


class BadCsv(Exception):
    """A CSV that cannot be read: the message names the file and line."""


def read_rows(path):
    """The rows of one bench_denoise CSV, numbers parsed; BadCsv naming the file and line of the
    first bad row (a missing or extra field, an empty field, a value that is not a number)."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if header is None:
                raise BadCsv(f"{path}:1: empty file (expected the header {','.join(FIELDS)})")
            lacking = [k for k in FIELDS if k not in header]
            if lacking:
                raise BadCsv(f"{path}:1: the header lacks the column(s) {', '.join(lacking)}")
            rows, seen = [], {}
            for rec in reader:
                line = reader.line_num
                if not rec:
                    continue
                if len(rec) < len(header):
                    raise BadCsv(f"{path}:{line}: {len(rec)} fields where the header has {len(header)}: "
                                 "a field is missing")
                if len(rec) > len(header):
                    raise BadCsv(f"{path}:{line}: {len(rec)} fields where the header has {len(header)}: "
                                 f"{len(rec) - len(header)} too many")
                r = dict(zip(header, rec))
                for k in FIELDS:
                    v = r[k].strip()
                    if not v:
                        raise BadCsv(f"{path}:{line}: field {k} is empty")
                    if k in INT_FIELDS:
                        try:
                            r[k] = int(v)
                        except ValueError:
                            raise BadCsv(f"{path}:{line}: field {k} = {v!r} is not an integer") from None
                    elif k in FLOAT_FIELDS:
                        try:
                            r[k] = float(v)
                        except ValueError:
                            raise BadCsv(f"{path}:{line}: field {k} = {v!r} is not a number") from None
                        if not math.isfinite(r[k]):
                            raise BadCsv(f"{path}:{line}: field {k} = {v!r} is not a finite number")
                key = (r["scene"], r["rays"], r["denoiser"], r["frame_of_history"])
                if key in seen:
                    raise BadCsv(f"{path}:{line}: a second row for scene {key[0]}, {key[1]} rays, {key[2]}, "
                                 f"frame {key[3]} (the first is on line {seen[key]})")
                seen[key] = line
                rows.append(r)
    except OSError as e:
        raise BadCsv(f"{path}: cannot read it ({e.strerror})") from None
    except (csv.Error, UnicodeDecodeError) as e:
        raise BadCsv(f"{path}: not a readable CSV ({e})") from None
    if not rows:
        raise BadCsv(f"{path}:2: no data rows")
    return rows


def pareto(points):
    """Points not dominated in (total_ms lower, ssim higher); fastest first."""
    front = []
    for p in points:
        dominated = any(
            q is not p
            and q["total_ms"] <= p["total_ms"]
            and q["ssim"] >= p["ssim"]
            and (q["total_ms"] < p["total_ms"] or q["ssim"] > p["ssim"])
            for q in points
        )
        if not dominated:
            front.append(p)
    return sorted(front, key=lambda p: p["total_ms"])


def front_items(front):
    return ", ".join(f"{p['rays']} {p['denoiser']} ({p['total_ms']:.0f} ms, {p['ssim']:.3f})" for p in front)


def unique(values):
    return list(dict.fromkeys(values))


def draw(rows, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = unique(r["scene"] for r in rows)
    hist = max(r["frame_of_history"] for r in rows)
    cols = min(4, len(scenes))
    nrows = math.ceil(len(scenes) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.6 * nrows), squeeze=False)
    for k, scene in enumerate(scenes):
        ax = axes[k // cols][k % cols]
        for d in DENOISERS:
            for frame, style in ((hist, "-"), (1, "--")):
                pts = sorted(
                    (r for r in rows if r["scene"] == scene and r["denoiser"] == d and r["frame_of_history"] == frame),
                    key=lambda r: r["rays"],
                )
                if not pts:
                    continue
                ax.plot(
                    [p["total_ms"] for p in pts],
                    [p["ssim"] for p in pts],
                    style,
                    marker="o",
                    markersize=3,
                    color=COLOURS[d],
                    label=f"{d} (frame {frame})",
                )
                if frame == hist:
                    for p in pts:
                        ax.annotate(str(p["rays"]), (p["total_ms"], p["ssim"]), fontsize=6, color=COLOURS[d],
                                    xytext=(2, -7), textcoords="offset points")
        r0 = next(r for r in rows if r["scene"] == scene)
        ax.set_xscale("log")
        ax.set_title(f"{scene} ({r0['width']}x{r0['height']}, ref {r0['reference_rays']} rays)", fontsize=9)
        ax.set_xlabel("trace + denoise ms (log)", fontsize=8)
        ax.set_ylabel("SSIM vs converged AO", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", alpha=0.3)
    for k in range(len(scenes), nrows * cols):
        axes[k // cols][k % cols].axis("off")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8)
    rays = sorted({r["rays"] for r in rows})
    fig.suptitle(f"AO accuracy against time: rays {{{rays[0]}..{rays[-1]}}} x denoiser (numbers: rays; solid: "
                 f"frame {hist} of a static camera, dashed: frame 1)", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 0.97))
    fig.savefig(out, dpi=110)
    print(f"wrote {out}", file=sys.stderr)


# ---- report.md: every figure below is computed from the CSVs.


def rng(values, fmt="{:.0f}", sep=DASH):
    """'lo–hi' of the formatted extremes, or one value when they print the same."""
    lo, hi = fmt.format(min(values)), fmt.format(max(values))
    return lo if lo == hi else f"{lo}{sep}{hi}"


def listing(items):
    items = list(items)
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def variant_label(name):
    """'svgf_ao{"kernel_radius":1;"iterations":3}' -> 'svgf_ao kernel_radius=1, iterations=3'."""
    if "{" not in name:
        return name
    base, params = name.split("{", 1)
    parts = [p.replace('"', "").replace(":", "=") for p in params.rstrip("}").split(";") if p]
    return f"{base} {', '.join(parts)}"


def params(name):
    """The {"key":value;...} parameters of a denoiser label, as a dict of strings."""
    if "{" not in name:
        return {}
    out = {}
    for p in name.split("{", 1)[1].rstrip("}").split(";"):
        if ":" in p:
            k, v = p.split(":", 1)
            out[k.strip('"')] = v.strip('"')
    return out


class Table:
    """One CSV indexed by (scene, rays, denoiser, frame)."""

    def __init__(self, rows):
        self.rows = rows
        self.at = {(r["scene"], r["rays"], r["denoiser"], r["frame_of_history"]): r for r in rows}
        self.scenes = unique(r["scene"] for r in rows)
        self.denoisers = unique(r["denoiser"] for r in rows)
        self.rays = sorted({r["rays"] for r in rows})
        self.frames = sorted({r["frame_of_history"] for r in rows})

    def get(self, scene, rays, denoiser, frame):
        return self.at.get((scene, rays, denoiser, frame))

    def points(self, scene, frame):
        return [r for r in self.rows if r["scene"] == scene and r["frame_of_history"] == frame]

    def trace_1ray(self, scene):
        return min(r["trace_ms"] for r in self.rows if r["scene"] == scene and r["rays"] == self.rays[0])

    def denoise_ms(self, scene, denoiser, frame):
        """denoise_ms of a (scene, denoiser, frame): one value per ray count in the CSV (the work
        does not depend on it); the minimum over the ray counts should they differ."""
        v = [r["denoise_ms"] for r in self.rows
             if r["scene"] == scene and r["denoiser"] == denoiser and r["frame_of_history"] == frame]
        return min(v) if v else None


def frame_phrase(frame, hist):
    return "no history" if frame == 1 else f"still camera, {hist} frames of history"


def cheapest_at_goal(t, scene, frame):
    ok = [p for p in t.points(scene, frame) if p["ssim"] >= SSIM_GOAL]
    return min(ok, key=lambda p: p["total_ms"]) if ok else None


def answer_section(t, hist):
    r0 = t.rows[0]
    counts = {}
    for frame in (hist, 1):
        c = {d: 0 for d in t.denoisers}
        for s in t.scenes:
            for p in pareto(t.points(s, frame)):
                c[p["denoiser"]] += 1
        counts[frame] = c

    def count_text(frame):
        c = counts[frame]
        order = sorted(t.denoisers, key=lambda d: -c[d])
        return f"frame {frame}: " + ", ".join(f"{d} {c[d]}" for d in order) + f" (of {sum(c.values())})"

    def goal_text(frame):
        items = []
        for s in t.scenes:
            p = cheapest_at_goal(t, s, frame)
            items.append(f"{s} {p['rays']} {p['denoiser']} ({p['total_ms']:.0f})" if p else f"{s} none reaches it")
        return f"frame {frame}: " + ", ".join(items)

    lead = {f: max(t.denoisers, key=lambda d: counts[f][d]) for f in (hist, 1)}

    def verdict(frame, twin=""):
        goal = [p for p in (cheapest_at_goal(t, s, frame) for s in t.scenes) if p]
        text = f"{lead[frame]}{twin}, which holds the most Pareto-front points"
        if goal:
            n = len(t.scenes)
            text += (f"; SSIM >= {SSIM_GOAL:g} costs {rng([p['rays'] for p in goal])} rays "
                     f"({rng([p['total_ms'] for p in goal])} ms) in "
                     + (f"all {n} scenes" if len(goal) == n else f"{len(goal)} of {n} scenes"))
        return text

    twin = ""
    if lead[1] in ("atrous", "svgf_ao") and first_frame_twins(t) == "all":
        twin = " (or svgf_ao: the same first-frame image)" if lead[1] == "atrous" else " (or atrous: the same image)"
    return [
        "# Denoisers: AO accuracy against time",
        "",
        "**Question:** which AO denoiser and ray count gives the best AO for the time it costs?\\",
        f"**Answer:** with history (frame {hist}, still camera), {verdict(hist)}. Without history (frame 1), "
        f"{verdict(1, twin)}.",
        f"- Pareto-front points over all {len(t.scenes)} scenes (points no other point of the scene beats in both "
        f"trace + denoise ms and SSIM): {count_text(hist)}; {count_text(1)}.",
        f"- Cheapest point with SSIM >= {SSIM_GOAL:g} (rays, denoiser, trace + denoise ms), {goal_text(hist)}.",
        f"- The same, {goal_text(1)}.",
        f"- Scale: {r0['width']}x{r0['height']}, {len(t.scenes)} scenes ({', '.join(t.scenes)}), "
        f"{', '.join(map(str, t.rays))} AO rays per pixel x {len(t.denoisers)} denoisers "
        f"({', '.join(t.denoisers)}) x frames {' and '.join(map(str, t.frames))} of history "
        f"({len(t.rows)} rows); reference {rng([r['reference_rays'] for r in t.rows])}-ray AO; "
        f"{rng([r['threads'] for r in t.rows])} threads.",
        "",
        f"![SSIM against trace + denoise ms per scene; solid: frame {hist}, dashed: frame 1](accuracy.png)",
    ]


def first_frame_twins(t):
    """'all' when atrous and svgf_ao have the same SSIM and MAE in every frame-1 row, else
    '<same> of <pairs>' (or '' when the CSV lacks one of them)."""
    pairs = [(r, t.get(r["scene"], r["rays"], "svgf_ao", 1)) for r in t.rows
             if r["denoiser"] == "atrous" and r["frame_of_history"] == 1]
    pairs = [(a, b) for a, b in pairs if b]
    if not pairs:
        return ""
    same = sum(1 for a, b in pairs if a["ssim"] == b["ssim"] and a["mae_levels"] == b["mae_levels"])
    return "all" if same == len(pairs) else f"{same} of {len(pairs)}"


def how_section(t, hist):
    refs = sorted({r["reference_rays"] for r in t.rows})
    se = 0.5 / math.sqrt(refs[0])
    return [
        "",
        "## How it was made",
        "",
        "This file is written by `plot.py` from the CSV files beside it; change `plot.py`, not this file.",
        "",
        "```",
        "cmake -S . -B build-denoise -G Ninja -DCMAKE_BUILD_TYPE=Release -DDHR_WERROR=ON",
        "cmake --build build-denoise -j2 --target bench_denoise",
        "build-denoise/tests/bench_denoise --accuracy --csv=reports/denoise_accuracy/accuracy.csv",
        "/usr/bin/python3 reports/denoise_accuracy/plot.py   # accuracy.png, report.md; the fronts on stdout",
        "/usr/bin/python3 reports/denoise_accuracy/plot.py --report-only   # report.md alone",
        "```",
        "",
        "`--scenes=room,temple` limits the scenes and `--reference_rays=N` changes the reference. If",
        "`../shared/scenes` is missing, the real scenes are skipped with a message on stderr. The",
        "machine was a shared cloud VM with other jobs compiling beside the run, so every time is the",
        "fastest of several runs (below).",
        "",
        "- **Setup:** the rasterizer builds the G-buffer with the camera held still on each scene's",
        "  path; the noisy AO comes from `trace_ao`, a new noise realisation each frame; the reference",
        "  comes from `trace_ao_counts` with an independent seed, rounded to 8 bits. It is not exact:",
        f"  the standard error of a {refs[0]}-ray estimate is at most 0.5/sqrt({refs[0]}) = {se:.4f}, or "
        f"{se * 255:.1f} levels",
        "  at AO = 0.5. The header of `tests/bench_denoise.cpp` gives the exact time, seed and frames.",
        "- **Quality:** `ssim_u8` (the project's metric) over the whole image. Background pixels count",
        "  too, and they agree exactly, so scenes with much sky score higher. MAE is mean |out - ref|",
        "  in 8-bit levels.",
        f"- **Frame 1 against frame {hist}:** each denoiser keeps its history across the frames. Frame 1",
        f"  is the no-history case (a camera cut), frame {hist} the best case of the temporal denoisers",
        "  (still camera, full history); a moving camera falls between. `none` and `atrous` keep no",
        f"  history, so their frame-{hist} row is just another noise realisation.",
        "- **Time (fastest of N runs):** `trace_ms` of a ray count is the fastest of its traced frames",
        "  and of extra interleaved timing rounds. `denoise_ms` is per denoiser (its work does not",
        "  depend on the ray count): for frame 1 the fastest first-frame path (`history_valid = false`)",
        f"  of the timing rounds, for frame {hist} the fastest steady frame (long history everywhere) of",
        "  the late frames and the rounds. `total_ms = trace_ms + denoise_ms`.",
        "",
    ] + timing_table(t, hist)


def timing_table(t, hist):
    r0 = t.rows[0]
    ones = [t.trace_1ray(s) for s in t.scenes]
    out = [
        f"Denoise ms per frame at {r0['width']}x{r0['height']} (frame {hist} / frame 1; atrous keeps no history, so",
        f"its column is its frame-1 row). For comparison, one AO ray (`trace_ms` at {t.rays[0]} ray) costs "
        f"{rng(ones)} ms.",
        "",
        f"| scene | {t.rays[0]} ray trace | single_iteration | atrous | svgf_ao |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]

    def both(s, d):
        a, b = t.denoise_ms(s, d, hist), t.denoise_ms(s, d, 1)
        return "-" if a is None or b is None else f"{a:.1f} / {b:.1f}"

    for s in t.scenes:
        at = t.denoise_ms(s, "atrous", 1)
        out.append(f"| {s} | {t.trace_1ray(s):.1f} | {both(s, 'single_iteration')} | "
                   f"{'-' if at is None else f'{at:.1f}'} | {both(s, 'svgf_ao')} |")
    return out


def pareto_section(t, hist):
    fronts = {(s, f): pareto(t.points(s, f)) for s in t.scenes for f in (hist, 1)}
    n = len(t.scenes)
    out = [
        "",
        "## Where the Pareto front lies",
        "",
        "A point is on the front when no other (rays, denoiser) point of the same scene and frame is both",
        "faster (lower `total_ms`) and better (higher SSIM). Entries are rays, denoiser, total ms and",
        "SSIM, fastest first.",
        "",
        f"**Frame {hist} ({frame_phrase(hist, hist)}).**",
    ]
    fh = {s: fronts[(s, hist)] for s in t.scenes}
    sv = {s: [p for p in fh[s] if p["denoiser"] == "svgf_ao"] for s in t.scenes}
    with_sv = [s for s in t.scenes if sv[s]]
    if with_sv:
        not_sv = [s for s in t.scenes if not sv[s]]
        out.append(f"- svgf_ao is on it in {len(with_sv)} of {n} scenes"
                   + (f" (not {listing(not_sv)})" if not_sv else "")
                   + "; its highest ray count on the front: "
                   + ", ".join(f"{s} {max(p['rays'] for p in sv[s])}" for s in with_sv) + ".")
    nn = [p for s in t.scenes for p in fh[s] if p["denoiser"] == "none"]
    if nn:
        out.append(f"- none is on it only at {rng([p['rays'] for p in nn])} rays, where it is the fastest but poor "
                   f"(SSIM {rng([p['ssim'] for p in nn], '{:.2f}')}).")
    top = t.rays[-1]
    diffs = [(s, t.get(s, top, "single_iteration", hist), t.get(s, top, "svgf_ao", hist)) for s in t.scenes]
    diffs = [(s, a, b) for s, a, b in diffs if a and b]
    if diffs:
        d_ssim = [a["ssim"] - b["ssim"] for _, a, b in diffs]
        d_mae = [b["mae_levels"] - a["mae_levels"] for _, a, b in diffs]
        worse = sum(1 for x in d_ssim if x > 0)
        why = (": with a long history svgf_ao's wide spatial filter blurs detail that the history already resolves"
               if worse == len(diffs) and min(d_mae) > 0 else "")
        out.append(f"- At {top} rays single_iteration's SSIM minus svgf_ao's is {rng(d_ssim, '{:+.3f}', ' to ')} "
                   f"(positive in {worse} of {len(diffs)} scenes) and svgf_ao's MAE minus single_iteration's "
                   f"{rng(d_mae, '{:+.2f}', ' to ')} levels{why}.")
    best_rays = []
    for r in t.rays:
        wins = []
        for s in t.scenes:
            pts = [p for p in t.points(s, hist) if p["rays"] == r]
            if pts and max(pts, key=lambda p: p["ssim"])["denoiser"] == "svgf_ao":
                wins.append(s)
        if len(wins) == n:
            best_rays.append(r)
    pair = ("svgf_ao", "single_iteration")
    if best_rays and all(t.denoise_ms(s, d, hist) is not None for s in t.scenes for d in pair):
        extra = [t.denoise_ms(s, "svgf_ao", hist) - t.denoise_ms(s, "single_iteration", hist) for s in t.scenes]
        out.append(f"- At {listing([str(r) for r in best_rays])} rays svgf_ao has the best SSIM of all denoisers "
                   f"in every scene; it costs {rng(extra)} ms more than single_iteration to denoise.")
    out.append("- Per scene:")
    out += [f"  - {s}: {front_items(fh[s])}" for s in t.scenes]

    out += ["", f"**Frame 1 ({frame_phrase(1, hist)}).**"]
    f1 = {s: fronts[(s, 1)] for s in t.scenes}
    full = ("atrous", "svgf_ao")
    cheap = {s: f1[s][:next((i for i, p in enumerate(f1[s]) if p["denoiser"] in full), len(f1[s]))]
             for s in t.scenes}
    cheap = {s: v for s, v in cheap.items() if v}
    if cheap:
        pts = [p for v in cheap.values() for p in v]
        out.append(f"- The cheap end of the front is {listing(unique(p['denoiser'] for p in pts))} at "
                   f"{rng([p['rays'] for p in pts])} rays, up to "
                   f"{rng([max(p['total_ms'] for p in v) for v in cheap.values()])} ms depending on the scene: "
                   f"cheap but poor, SSIM {rng([p['ssim'] for p in pts], '{:.2f}')}.")
    twins = first_frame_twins(t)
    if twins:
        sv_scenes = [s for s in t.scenes if any(p["denoiser"] == "svgf_ao" for p in f1[s])]
        same = "every" if twins == "all" else twins
        out.append(f"- Above it the front is atrous / svgf_ao. On a first frame they give the same SSIM and MAE in "
                   f"{same} row{'' if same == 'every' else 's'} "
                   "(`Denoisers.ResetAndInvalidHistoryGiveTheSpatialOnlyPath` in tests/test_denoisers.cpp checks "
                   "the images bit for bit), so which of the two is listed is "
                   "timing noise. svgf_ao is listed " + (f"in {listing(sv_scenes)}." if sv_scenes else "in no scene."))
    rejoin = {}
    for s in t.scenes:
        first_full = next((i for i, p in enumerate(f1[s]) if p["denoiser"] in full), None)
        if first_full is not None:
            late = [p["rays"] for p in f1[s][first_full:] if p["denoiser"] == "single_iteration"]
            if late:
                rejoin[s] = late
    if rejoin:
        out.append(f"- single_iteration rejoins the front at "
                   f"{rng([r for v in rejoin.values() for r in v])} rays in {len(rejoin)} of {n} scenes "
                   f"({listing(list(rejoin))}): there the full filter's blur costs more SSIM than the "
                   "remaining noise.")
    match = []
    for s in t.scenes:
        bar = t.get(s, top, "none", 1)
        if not bar:
            continue
        hit = next((p for p in sorted((p for p in t.points(s, 1) if p["denoiser"] == "atrous"),
                                      key=lambda p: p["rays"]) if p["ssim"] >= bar["ssim"]), None)
        if hit:
            match.append((s, hit, bar))
    if match:
        out.append(f"- Even without history, atrous reaches the SSIM of {top} unfiltered rays with far fewer rays "
                   "(rays, atrous ms against unfiltered ms): "
                   + ", ".join(f"{s} {h['rays']} ({h['total_ms']:.0f} against {b['total_ms']:.0f})"
                               for s, h, b in match)
                   + f"; {rng([b['total_ms'] / h['total_ms'] for _, h, b in match], '{:.1f}')}x faster.")
    out.append("- Per scene:")
    out += [f"  - {s}: {front_items(f1[s])}" for s in t.scenes]
    return out


def ssim_rows(t, rows_of, label_of, frame_of):
    """Markdown rows: one per (scene, frame, denoiser): SSIM per ray count, then denoise ms."""
    out = []
    for s, f, d in rows_of:
        cells = []
        for r in t.rays:
            p = t.get(s, r, d, f)
            cells.append(f"{p['ssim']:.3f}" if p else "-")
        dm = t.denoise_ms(s, d, f)
        out.append(f"| {s} | {frame_of(f)} | {label_of(d)} | " + " | ".join(cells) + f" | {dm:.1f} |")
    return out


def table_head(t):
    return [f"| scene | frame | denoiser | {t.rays[0]} ray | " + " | ".join(str(r) for r in t.rays[1:])
            + " | denoise ms |",
            "| --- | ---: | --- | " + "---: | " * len(t.rays) + "---: |"]


def better_rays(t, scene, a, b, frame):
    """Ray counts where denoiser a's SSIM is at least b's (both at 3 decimals, as printed)."""
    out = []
    for r in t.rays:
        pa, pb = t.get(scene, r, a, frame), t.get(scene, r, b, frame)
        if pa and pb and round(pa["ssim"], 3) >= round(pb["ssim"], 3):
            out.append(r)
    return out


def ray_set(rays, all_rays):
    if not rays:
        return "none"
    if rays == all_rays:
        return "all"
    if rays == all_rays[all_rays.index(rays[0]):]:
        return f"{rays[0]} and up"
    return ", ".join(map(str, rays))


def variants_section(t):
    default = "svgf_ao"
    hist = max(t.frames)
    sc = listing(t.scenes)
    out = [
        "",
        f"## svgf_ao's kernel and iterations ({sc})",
        "",
        "```",
        "build/tests/bench_denoise --accuracy --scenes=room --denoisers='single_iteration svgf_ao "
        "svgf_ao{\"kernel_radius\":1} svgf_ao{\"kernel_radius\":1,\"iterations\":3} svgf_ao{\"iterations\":1}' "
        "--csv=reports/denoise_accuracy/svgf_variants_room.csv",
        "```",
        "",
        f"`{VARIANTS_CSV}`, run on a quiet machine: SSIM against {rng([r['reference_rays'] for r in t.rows])}-ray "
        f"AO at {t.rows[0]['width']}x{t.rows[0]['height']} and denoise ms per frame; one AO ray costs "
        + ", ".join(f"{t.trace_1ray(s):.1f} ms" + (f" ({s})" if len(t.scenes) > 1 else "") for s in t.scenes)
        + " to trace here. `svgf_ao` is its default"
        + "".join(f"; `kernel_radius={k}` is a {2 * int(k) + 1}x{2 * int(k) + 1} kernel"
                  for k in unique(params(d).get("kernel_radius") for d in t.denoisers) if k and k.isdigit())
        + ".",
        "",
    ] + table_head(t)
    order = [(s, f, d) for s in t.scenes for f in sorted(t.frames, reverse=True) for d in t.denoisers
             if t.denoise_ms(s, d, f) is not None]
    out += ssim_rows(t, order, lambda d: variant_label(d) + (" (default)" if d == default else ""), str)
    others = [d for d in t.denoisers if d.startswith(default + "{")]
    if others and default in t.denoisers:
        out += ["",
                f"Each variant against the default: its denoise time as a share of the default's at frame {hist}, "
                "and the ray counts where its SSIM is at least the default's (at three decimals).",
                "",
                f"| scene | variant | denoise time, frame {hist} | SSIM >= default, frame {hist} | "
                "SSIM >= default, frame 1 |",
                "| --- | --- | ---: | --- | --- |"]
        cheaper_with_history = True
        for s in t.scenes:
            if not t.denoise_ms(s, default, hist):
                continue
            for d in others:
                if t.denoise_ms(s, d, hist) is None:
                    continue
                share = t.denoise_ms(s, d, hist) / t.denoise_ms(s, default, hist)
                with_h, without = better_rays(t, s, d, default, hist), better_rays(t, s, d, default, 1)
                out.append(f"| {s} | {variant_label(d)} | {100 * share:.0f} % | {ray_set(with_h, t.rays)} | "
                           f"{ray_set(without, t.rays)} |")
                # "match from fewer rays with history than without": every variant, every scene
                if share >= 1 or not with_h or (without and without[0] <= with_h[0]):
                    cheaper_with_history = False
        out.append("")
        if cheaper_with_history:
            out += ["Every variant is cheaper than the default and matches it from fewer rays with history than",
                    "without: the default's wider blur pays mainly where history is missing."]
            out.append("")
        out += ["The cost at a larger resolution against one traced AO ray is what",
                "`build/tests/bench_denoise --rounds=9 --benchmark_filter='^$'` prints (not in these files)."]
    return out


def light_section(tables):
    rows = [r for t in tables for r in t.rows]
    t = Table(rows)
    frames = t.frames
    steady = max(frames)
    short = [f for f in frames if f not in (1, steady)]
    lvars = [d for d in t.denoisers if "light_history" in params(d)]
    lval = {d: int(params(d)["light_history"]) for d in lvars}
    out = [
        "",
        f"## svgf_ao's lightweight path for long history (`light_history`, {listing(t.scenes)})",
        "",
        "The DHR-S paper ends its AO section by proposing \"a more lightweight denoiser for ambient occlusion",
        "due to many of the pixels having a high number of temporal samples ... just one iteration of filter",
        "and also using a smaller kernel size\". svgf_ao's `light_history` = L does that per pixel: a pixel",
        "whose history is at least L frames long gets a single small-kernel a-trous iteration, the others",
        "the full filter (off by default).",
        "",
        "```",
        "D='svgf_ao svgf_ao{\"light_history\":4} svgf_ao{\"light_history\":8} svgf_ao{\"light_history\":16} "
        "single_iteration'",
        "build/tests/bench_denoise --accuracy --scenes=room,temple,sponza-dabrovic --denoisers=\"$D\" \\",
        "    --csv=reports/denoise_accuracy/light_history_frame8.csv",
        "build/tests/bench_denoise --accuracy --frames=40 --scenes=room,temple,sponza-dabrovic --denoisers=\"$D\" \\",
        "    --csv=reports/denoise_accuracy/light_history_frame40.csv",
        "```",
        "",
        f"`{'`, `'.join(LIGHT_CSVS)}`, run on a quiet machine: SSIM against "
        f"{rng([r['reference_rays'] for r in rows])}-ray AO at {rows[0]['width']}x{rows[0]['height']}, still camera, "
        f"and denoise ms per frame (the fastest steady frame). Frame {steady} is past "
        f"the history cap, the steady state.",
        "",
    ] + table_head(t)
    order = [(s, f, d) for s in t.scenes for f in frames if f != 1 for d in t.denoisers
             if t.denoise_ms(s, d, f) is not None]
    out += ssim_rows(t, order, lambda d: f"L={lval[d]}" if d in lval else d, str)
    out.append("")
    notes = []
    base = "svgf_ao"

    def same(a, b):
        return a is not None and b is not None and a["ssim"] == b["ssim"] and a["mae_levels"] == b["mae_levels"]

    for f in short:
        later = [d for d in lvars if lval[d] > f]
        if later and all(same(t.get(s, r, d, f), t.get(s, r, base, f)) for s in t.scenes for r in t.rays
                         for d in later):
            notes.append(f"At frame {f} the history is {f} frames long: "
                         f"{listing([f'L={lval[d]}' for d in later])} has not switched yet and gives the default's "
                         "SSIM and MAE in every row.")
    first = [r for r in rows if r["frame_of_history"] == 1]
    if first and lvars and all(same(r, t.get(r["scene"], r["rays"], base, 1)) for r in first if r["denoiser"] in lvars):
        notes.append("On a first frame (no history) every L gives the default's SSIM and MAE.")
    si = "single_iteration"
    grid = lvars + [si, base]
    complete = lvars and all(t.get(s, r, d, steady) for s in t.scenes for r in t.rays for d in grid) \
        and all(t.denoise_ms(s, d, steady) for s in t.scenes for d in grid)
    if complete:
        dss = [abs(t.get(s, r, d, steady)["ssim"] - t.get(s, r, si, steady)["ssim"])
               for s in t.scenes for r in t.rays for d in lvars]
        dmae = [abs(t.get(s, r, d, steady)["mae_levels"] - t.get(s, r, si, steady)["mae_levels"])
                for s in t.scenes for r in t.rays for d in lvars]
        ratio = [t.denoise_ms(s, base, steady) / t.denoise_ms(s, d, steady) for s in t.scenes for d in lvars]
        notes.append(f"In the steady state (frame {steady}) every L gives single_iteration's image (one small "
                     f"iteration on the temporal average): SSIM within {max(dss):.6f} and MAE within "
                     f"{max(dmae):.4f} levels of it in every row, at {rng(ratio, '{:.1f}')}x less denoise time than "
                     "the full filter.")
        groups = []
        for r in t.rays:
            win = [s for s in t.scenes
                   if round(t.get(s, r, base, steady)["ssim"], 3) > max(round(t.get(s, r, d, steady)["ssim"], 3)
                                                                        for d in lvars)]
            key = ("all" if len(win) == len(t.scenes) else "none" if not win else listing(win))
            if groups and groups[-1][0] == key:
                groups[-1][1].append(r)
            else:
                groups.append((key, [r]))
        parts = []
        for key, rs in groups:
            rays_txt = f"{listing([str(r) for r in rs])} ray{'s' if rs != [1] else ''}"
            if key == "all":
                parts.append(f"at {rays_txt} in every scene")
            elif key == "none":
                parts.append(f"at {rays_txt} in no scene")
            else:
                parts.append(f"at {rays_txt} only in {key}")
        ex = t.get(t.scenes[0], t.rays[0], base, steady)
        exl = t.get(t.scenes[0], t.rays[0], si, steady)
        notes.append(f"The price depends on the ray count ({t.scenes[0]}, {t.rays[0]} ray: full filter "
                     f"{ex['ssim']:.3f}, light path {exl['ssim']:.3f}). The full filter has the higher steady-state "
                     f"SSIM (at three decimals, against every L) {'; '.join(parts)}. Where it loses, its repeated "
                     "wide iterations over-blur.")
    notes.append("With a still camera the error of the light path also stops falling at the switch "
                 "(tests/test_denoisers.cpp, `LightHistory.StaticCameraSwitchesToTheSingleIterationLevel` records "
                 "it). So the default stays off.")
    out += [f"- {n}" for n in notes]
    return out


def caveats_section(t):
    return [
        "",
        "## Caveats",
        "",
        "- **Timing noise.** The main table ran on a loaded, shared machine. The fastest-of-N and the",
        "  interleaved rounds damp the noise but cannot remove it: small ms differences are not",
        "  meaningful, and neither is the atrous / svgf_ao choice at frame 1.",
        "- **Imperfect reference.** The reference is a finite-ray estimate rounded to 8 bits (its",
        "  standard error is above); near the top of each front the ranking is limited by it.",
        "- **Static camera only.** A moving camera loses history where it disoccludes; the frame-loop",
        "  experiments measure that. Frame 1 is the bound.",
        "- **Default parameters** in the main table; svgf_ao's are varied on a few scenes in the",
        "  sections above (where their CSVs are present).",
        "- **Resolution and tracer.** The times are for this resolution and for the tracer of the run;",
        "  a faster tracer moves every `trace_ms` down (not SSIM or MAE) and favours denoising fewer rays.",
    ]


def report_text(acc_rows, variants_rows=None, light_rows=None):
    t = Table(acc_rows)
    hist = max(t.frames)
    lines = answer_section(t, hist) + how_section(t, hist) + pareto_section(t, hist)
    if variants_rows:
        lines += variants_section(Table(variants_rows))
    if light_rows:
        lines += light_section([Table(r) for r in light_rows])
    lines += caveats_section(t)
    return "\n".join(lines) + "\n"


def write_report(acc_path, acc_rows):
    folder = os.path.dirname(os.path.abspath(acc_path))
    extra = {}
    for name in (VARIANTS_CSV,) + LIGHT_CSVS:
        p = os.path.join(folder, name)
        if os.path.exists(p):
            extra[name] = read_rows(p)
        else:
            print(f"plot.py: {p} is missing; report.md leaves out its section", file=sys.stderr)
    light = [extra[n] for n in LIGHT_CSVS if n in extra]
    text = report_text(acc_rows, extra.get(VARIANTS_CSV), light or None)
    out = os.path.join(folder, "report.md")
    with open(out, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    print(f"wrote {out}", file=sys.stderr)


def main(argv):
    args = argv[1:]
    report_only = "--report-only" in args
    args = [a for a in args if a != "--report-only"]
    if len(args) > 1 or any(a.startswith("-") for a in args):
        print("usage: plot.py [--report-only] [PATH/accuracy.csv]", file=sys.stderr)
        return 2
    here = os.path.dirname(os.path.abspath(__file__))
    path = args[0] if args else os.path.join(here, "accuracy.csv")
    try:
        rows = read_rows(path)
        write_report(path, rows)
    except BadCsv as e:
        print(f"plot.py: {e}", file=sys.stderr)
        return 2
    if report_only:
        return 0
    draw(rows, os.path.join(os.path.dirname(os.path.abspath(path)), "accuracy.png"))
    t = Table(rows)
    for frame in t.frames:
        print(f"\n### Pareto front, frame {frame} ({frame_phrase(frame, max(t.frames))})\n")
        for scene in t.scenes:
            print(f"- **{scene}**: {front_items(pareto(t.points(scene, frame)))}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
