#!/usr/bin/env python3
"""Builds DIR/report.md and its plots, and DIR/report.html (experiments/report_html.py), from what 'dhrbench run' wrote in DIR (results.json,
frames.csv, images/). Run by 'dhrbench run' and 'dhrbench report DIR' with Debian's
/usr/bin/python3 and python3-matplotlib; nothing here runs the benchmark again.

Plots (DIR/plots/): quality against bandwidth and against server time, with the Pareto front
marked (higher SSIM, lower cost); SSIM per frame; stage wall times. Image grids (DIR/grids/):
per scene, the ground truth, the local reference, and for each run what the client showed
and its error map, all error maps on one fixed colour scale with its colour bar.
"""
import math
import os
import sys
from typing import NamedTuple

import dhrbench_results as dr
from dhrbench_results import BadResults

# matplotlib is imported once results.json and frames.csv have been checked (load_matplotlib):
# a damaged file is reported without the second it takes to import.
EXIT_NO_MATPLOTLIB = 3


class Plot(NamedTuple):
    """matplotlib's pyplot and image modules, loaded by load_matplotlib() and passed to whatever draws."""
    plt: object
    mpimg: object


def load_matplotlib():
    """Plot(pyplot, image) with the Agg backend; exit 3 with a message where matplotlib is missing."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.image as mpimg
        import matplotlib.pyplot as plt
        return Plot(plt, mpimg)
    except ImportError:
        print("dhrbench report: error: the report needs matplotlib for Debian's python3: apt-get install "
              "python3-matplotlib (or run scripts/setup.sh)", file=sys.stderr)
        sys.exit(EXIT_NO_MATPLOTLIB)

ERROR_SCALE_LEVELS = 32  # the runner writes |luma difference| 0..32 levels as 0..255 grey
MAX_RUNS_PER_GRID = 8
UNIT_NAMES = {"db": "dB"}  # how a declared unit is written in a table heading
EXIT_BAD_INPUT = 2


def frame_intervals(frames, metrics):
    """{(run, frames.csv column): (half-width, block length)}: the 95 % interval
    (experiments/intervals.py, mean_interval) of each run's mean of each declared image metric over its scored
    frames, in frame order. +inf (PSNR of identical frames) counts as 100 dB, as in the means."""
    import intervals
    series = {}
    cols = [(im["columns"][ref], im.get("unit") == "db") for im in metrics for ref in ("local", "ground_truth")]
    for row in sorted(frames, key=lambda f: (f["run"], int(f["frame"]))):
        for col, db in cols:
            v = row.get(col)
            if not v:
                continue
            try:
                x = float(v)
            except ValueError:
                continue
            if math.isinf(x) and db and x > 0:
                x = 100.0
            if math.isfinite(x):
                series.setdefault((row["run"], col), []).append(x)
    out = {}
    for key, xs in series.items():
        ci = intervals.mean_interval(xs)
        if ci is not None:
            out[key] = ci
    return out


def read_image(plot, path):
    try:
        return plot.mpimg.imread(path)
    except Exception as e:  # PIL and matplotlib raise several kinds for a damaged file
        raise BadResults(f"{path}: not a readable PNG image: {str(e)[:120]}")


def fmt(v, digits=4):
    if v is None:
        return "–"
    if isinstance(v, float):
        if math.isnan(v):
            return "–"
        return f"{v:.{digits}f}"
    return str(v)


def pareto(points):
    """Indices of points (cost, quality) not dominated by another (lower cost, higher quality)."""
    front = []
    for i, (c, q) in enumerate(points):
        dominated = any((c2 <= c and q2 >= q) and (c2 < c or q2 > q) for j, (c2, q2) in enumerate(points) if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def server_ms(run):
    stages = run["metrics"]["stages_wall"]
    return sum(stages[s]["median_ms"] for s in
               ("server_rasterize", "trace_shadows", "trace_ao", "denoise", "encode", "server_composite") if s in stages)


def metric_value(run, im):
    """An image metric's mean against the ground truth where scored, else the local reference."""
    m = run["metrics"]
    q = m.get(im["aggregates"]["ground_truth"]["mean"])
    return q if q is not None else m.get(im["aggregates"]["local"]["mean"])


def rate_quality_section(plot, d, exp, ok, metrics):
    """Rate-quality curves and BD-rate tables, when the experiment declares "curves" (the lines)."""
    spec = exp.get("curves")
    out = []
    if not isinstance(spec, dict) or not ok:
        return out
    import rate_quality as rq
    vary = [k for k in spec.get("vary", []) if isinstance(k, str)]
    sweep_keys = sorted({k for r in ok for k in r.get("settings", {}) if k not in vary})
    anchor = spec.get("anchor")
    anchors = [anchor] if isinstance(anchor, str) else [a for a in (anchor or []) if isinstance(a, str)]
    out.append("## Rate-quality curves\n")
    out.append(f"One curve per family, scene and setting of {', '.join(f'`{k}`' for k in sweep_keys) or 'the run'}; "
               f"along a curve {', '.join(f'`{k}`' for k in vary)} varies. Bitrate: every packet on the wire (Mb/s). "
               "Quality: each metric's mean against the ground truth where the run scored it, else against the local "
               "reference.\n")
    rate = lambda r: r["metrics"]["bandwidth_mbps"] or None  # noqa: E731
    for im in metrics:
        cm = rq.curves(ok, sweep_keys, vary, rate, lambda r, im=im: metric_value(r, im))
        if not cm:
            continue
        groups = sorted({(s, c) for s, c, _ in cm})
        scenes = sorted({s for s, _ in groups})
        conds = sorted({c for _, c in groups})
        fig, axes = plot.plt.subplots(len(scenes), len(conds), figsize=(4.6 * len(conds), 3.6 * len(scenes)),
                                      squeeze=False)
        for i, scene in enumerate(scenes):
            for j, cond in enumerate(conds):
                ax = axes[i, j]
                for (s, c, fam), pts in sorted(cm.items()):
                    if s == scene and c == cond:
                        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3, lw=1.2,
                                label=fam + (" (anchor)" if fam in anchors else ""))
                ax.set_xscale("log")
                ax.set_title(f"{scene}; " + (", ".join(f"{k.split('.')[-1]}={v}" for k, v in cond) or "all runs"),
                             fontsize=8)
                ax.set_xlabel("Mb/s on the wire (log)")
                ax.set_ylabel(im["name"].upper())
                ax.grid(alpha=0.3, which="both")
                ax.legend(fontsize=6)
        fig.tight_layout()
        name = f"rate_quality_{im['name']}.png"
        fig.savefig(os.path.join(d, "plots", name), dpi=100)
        plot.plt.close(fig)
        out.append(f"![rate against {im['name'].upper()}](plots/{name})\n")
        replicates = [k for k in spec.get("replicates", []) if isinstance(k, str)]
        for anchor in anchors:
            out += bd_section(rq, cm, anchor, im)
            if replicates:
                out += replicate_section(rq, cm, anchor, im, replicates)
        for anchor in anchors:
            out += bd_section(rq, cm, anchor, im, equal_bandwidth=True)
            if replicates:
                out += replicate_section(rq, cm, anchor, im, replicates, equal_bandwidth=True)
        out += crossover_section(rq, cm, ok, sweep_keys, im)
    return out


def network_rtt_ms(runs):
    """{network value: round-trip time in ms} for the networks whose two links have a constant
    latency (the same in every run of that network); other networks (traces, random latency) are
    left out."""
    rtts = {}
    for r in runs:
        cfg = r.get("config", {})
        name = r.get("settings", {}).get("network")
        up, down = cfg.get("uplink", {}), cfg.get("downlink", {})
        if name is None:
            continue
        rtt = None
        if up.get("latency") == "constant" and down.get("latency") == "constant":
            rtt = float(up.get("latency_ms", 0.0)) + float(down.get("latency_ms", 0.0))
        if rtts.setdefault(str(name), rtt) != rtt:
            rtts[str(name)] = None
    return rtts


def crossover_section(rq, cm, runs, sweep_keys, im):
    """Per scene, the round-trip time from which on hybrid wins on image metric `im`: the
    smallest measured RTT from which on, at every larger one too, a hybrid family beats every
    remote family (less bitrate at equal quality where the curves meet, a better quality range
    where they do not). Returns the lines (none without a network sweep of both sides)."""
    if "network" not in sweep_keys:
        return []
    rtts = network_rtt_ms(runs)
    remote = {rq.family_of(r) for r in runs if r.get("config", {}).get("mode") == "remote"}
    if not remote or not any(v is not None for v in rtts.values()):
        return []
    higher = im.get("higher_is_better", True)
    table = rq.crossover(cm, lambda f: f in remote, lambda v: rtts.get(v), "network", higher)
    if not table:
        return []
    name = im["name"].upper()
    out = []
    out.append(f"Where hybrid starts to win on {name}: the smallest round-trip time from which on, at every larger "
               "RTT measured, a hybrid family beats every remote family (less bitrate at equal quality where the "
               "curves meet, BD-rate < 0; where they do not, a better quality range at a bitrate remote also "
               "spends); the families that win from there; and, per RTT, how many hybrid families beat every "
               "remote one (of those measured):\n")
    rtt_cols = sorted({t for row in table.values() for t in row["rtts"]})
    out.append("| scene | conditions | hybrid wins from RTT | families | "
               + " | ".join(f"{t:g} ms" for t in rtt_cols) + " |")
    out.append("|---|---|---|---|" + "---|" * len(rtt_cols))
    for (scene, rest), row in sorted(table.items()):
        starts = [t for t in row["families"].values() if t is not None]
        best = min(starts) if starts else None
        fams = sorted(f for f, t in row["families"].items() if t is not None and t == best)
        per_rtt = []
        for t in rtt_cols:
            if t not in row["rtts"]:
                per_rtt.append("–")
                continue
            n = sum(1 for f in row["wins"] if row["wins"][f].get(t) is True)
            per_rtt.append(f"{n} of {len(row['wins'])}")
        out.append(f"| {scene} | {', '.join(f'{k}={v}' for k, v in rest) or '–'} | "
                   f"{f'{best:g} ms' if best is not None else 'not at the largest RTT'} | "
                   f"{', '.join(fams) or '–'} | " + " | ".join(per_rtt) + " |")
    out.append("")
    return out


def regime_tables(exp, ok, metrics, budget_points=12):
    """Per scene, which side -- hybrid or remote -- gives the better FLIP against the ground truth
    (SSIM where FLIP is not declared) at each bitrate budget and round-trip time
    (rate_quality.regime_map: each side's best family at that budget, each family's curve joined
    by PCHIP in log-rate within its measured range), when the runs hold both sides and a network
    sweep of constant latencies. Returns (the metric's declaration, {(scene, rest): map}) or None."""
    import rate_quality as rq
    by_name = {im["name"]: im for im in metrics}
    im = by_name.get("flip") or by_name.get("ssim")
    remote = {rq.family_of(r) for r in ok if r.get("config", {}).get("mode") == "remote"
              or rq.family_of(r).startswith("remote")}
    hybrid = {rq.family_of(r) for r in ok} - remote
    rtts = network_rtt_ms(ok)
    if im is None or not remote or not hybrid or not any(v is not None for v in rtts.values()):
        return None
    spec = exp.get("curves") if isinstance(exp.get("curves"), dict) else {}
    sweep_keys = sorted({k for r in ok for k in r.get("settings", {})})
    vary = [k for k in spec.get("vary", []) if isinstance(k, str)] or [k for k in sweep_keys if k != "network"]
    key = im["aggregates"]["ground_truth"]["mean"]
    higher = im.get("higher_is_better", True)
    rate = lambda r: r["metrics"]["bandwidth_mbps"] or None  # noqa: E731
    cm = rq.curves(ok, [k for k in sweep_keys if k not in vary], vary, rate, lambda r: r["metrics"].get(key))
    rates = [x for pts in cm.values() for x, *_ in pts]
    if not rates:
        return None
    lo, hi = math.log10(min(rates)), math.log10(max(rates))
    budgets = [10 ** (lo + (hi - lo) * i / (budget_points - 1)) for i in range(budget_points)] if hi > lo else [min(rates)]
    table = rq.regime_map(cm, lambda f: f in remote, lambda v: rtts.get(v), budgets, "network", higher)
    # Only scenes where both sides were measured at a constant latency (a remote run over a
    # trace has no RTT: a map of one side says nothing).
    table = {k: m for k, m in table.items()
             if all(any(c[side] for c in m["cells"].values()) for side in ("hybrid", "remote"))}
    return (im, table) if table else None


def regime_file(title):
    return "regime_map_" + "".join(c if c.isalnum() or c in "-_" else "_" for c in title).strip("_") + ".png"


def scene_name(scene):
    """A scene as a reader names it: room, classroom (not scenes/real/classroom.json)."""
    base = scene.replace("\\", "/").rsplit("/", 1)[-1]
    return base[:-5] if base.endswith(".json") else base


def lead_metric(metrics):
    """The metric an answer is given in: FLIP where the results declare it (it sees the AO and
    shadow passes that SSIM barely moves for), else the first declared (SSIM)."""
    by_name = {im["name"]: im for im in metrics}
    return by_name.get("flip") or metrics[0]


def scale_line(ok, checks):
    """Resolution, scenes, frames and runs the answer rests on; `checks`: the committed
    convergence checks (dr.load_convergence_checks)."""
    first = ok[0]["config"] if ok and "config" in ok[0] else {}
    scenes = sorted({r["scene"] for r in ok})
    frames = sorted({r["metrics"].get("frames_displayed") for r in ok if r["metrics"].get("frames_displayed")})
    truth_frames = sorted({r["metrics"].get("frames_scored_ground_truth") for r in ok
                           if r["metrics"].get("frames_scored_ground_truth")})
    seeds = sorted({r.get("config", {}).get("seed") for r in ok if r.get("config", {}).get("seed") is not None})
    speeds = {r.get("config", {}).get("camera_speed", 1.0) for r in ok}  # one path per speed
    truth = (f", {'/'.join(str(f) for f in truth_frames)} scored against the ground truth" if truth_frames
             else ", none scored against a ground truth")
    found = convergence_checks(ok, checks)
    scored = {r["scene"] for r in ok if r.get("config", {}).get("ground_truth_every")}
    converged = ""
    if scored and scored <= set(found) and all("flip_mean" in found[s][2]["summary"] for s in scored):
        worst = max(scored, key=lambda s: found[s][2]["summary"]["flip_mean"])
        converged = (f"; the ground truth is within FLIP {found[worst][2]['summary']['flip_mean']:.3g} of "
                     f"{found[worst][1]['factor']}x its samples ({scene_name(worst)}, the farthest; "
                     "\"Ground truth convergence\")")
    return (f"Scale: {first.get('width')}x{first.get('height')}, {len(scenes)} scene(s), "
            f"{'/'.join(str(f) for f in frames)} displayed frames per run{truth}, "
            f"{len(seeds)} seed(s), {len(speeds)} camera path(s), {len(ok)} runs{converged}.")


CONVERGE_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "reports", "converge")


def converge_command(c):
    """The command that gives a convergence file (reports/converge/), from what it records."""
    scenes = " ".join(f"--scene {s['scene']}" for s in c["scenes"])
    frames = max(len(s["frames"]) for s in c["scenes"])
    return (f"dhrbench converge {scenes} --width {c['width']} --height {c['height']} --frames {frames} "
            f"--ao-rays {c['ao_rays']} --samples-per-light {c['samples_per_light']} --sampling {c['sampling']} "
            f"--factor {c['factor']}")


def convergence_checks(ok, checks):
    """Per scene of the runs, the committed check (`checks`: [(file name, check)] of
    reports/converge/*.json, `dhrbench converge`) of the ground truth the runs were scored against:
    {scene: (file name, the check, its scene entry)}, for the scenes a check with the same size,
    samples and sampling covers."""
    found = {}
    for r in ok:
        c = r.get("config", {})
        if r["scene"] in found or not c.get("ground_truth_every"):
            continue
        want = (c.get("width"), c.get("height"), c.get("ground_truth_ao_rays"), c.get("ground_truth_samples_per_light"),
                c.get("ground_truth_sampling"))
        for n, chk in checks:
            if not isinstance(chk, dict):
                continue
            have = (chk.get("width"), chk.get("height"), chk.get("ao_rays"), chk.get("samples_per_light"), chk.get("sampling"))
            entry = next((s for s in chk.get("scenes", []) if isinstance(s, dict)
                          and s.get("scene") == scene_name(r["scene"])), None)
            if have == want and entry is not None:
                found[r["scene"]] = (n, chk, entry)
                break
    return found


def convergence_section(ok, checks):
    """The ground truth shown converged: per scene, the committed check against factor x its
    samples, or how to make one."""
    scored = [r for r in ok if r.get("config", {}).get("ground_truth_every")]
    if not scored:
        return []
    found = convergence_checks(scored, checks)
    out = ["## Ground truth convergence\n",
           "Each figure scores the ground truth these runs were scored against (same size, samples and sampling; "
           "an independent seed) against one with factor x its samples (`dhrbench converge`): the difference bounds "
           "the ground truth's own error from above, so a run's difference from the ground truth smaller than this "
           "is within the ground truth's noise.\n",
           "| scene | check | factor | frames | FLIP mean (worst) | SSIM mean (worst) | PSNR dB mean |",
           "|---|---|---:|---:|---:|---:|---:|"]
    for scene in sorted({r["scene"] for r in scored}):
        if scene in found:
            n, chk, e = found[scene]
            sm = e.get("summary", {})
            out.append(f"| {scene_name(scene)} | `reports/converge/{n}` | {chk.get('factor')} | "
                       f"{len(e.get('frames', []))} | {fmt(sm.get('flip_mean'))} ({fmt(sm.get('flip_worst'))}) | "
                       f"{fmt(sm.get('ssim_mean'))} ({fmt(sm.get('ssim_worst'))}) | {fmt(sm.get('psnr_mean'), 2)} |")
        else:
            c = next(r["config"] for r in scored if r["scene"] == scene)
            out.append(f"| {scene_name(scene)} | none committed: `dhrbench converge --scene {scene_name(scene)} --width "
                       f"{c.get('width')} --height {c.get('height')} --ao-rays {c.get('ground_truth_ao_rays')} "
                       f"--samples-per-light {c.get('ground_truth_samples_per_light')} --sampling "
                       f"{c.get('ground_truth_sampling')}` | | | | | |")
    commands = sorted({converge_command(chk) for n, chk, e in found.values()})
    if commands:
        out.append("\nCommands: " + "; ".join(f"`{c}`" for c in commands) + ".\n")
    else:
        out.append("")
    return out


def answer_lines(question, rows, ok, checks, figure=None):
    """The answer block's lines: the question, one row per scene (joined into one line past six
    scenes, so that the block stays within ten lines), the scale, and the figure if any."""
    out = ["## The answer\n", f"Question: {question}\n"]
    out += rows if len(rows) <= 6 else ["- " + "; ".join(r[2:].rstrip(".") for r in rows) + "."]
    out.append("\n" + scale_line(ok, checks) + "\n")
    if figure:
        out.append(figure)
    return out


def against_words(refs):
    """The references the answer's figures are against, as words."""
    return " and ".join(REFERENCE_WORDS[r] for r in sorted(refs))


class Answer(NamedTuple):
    """The answer first: report.md's opening lines and the one sentence reports/README.md quotes."""
    lines: list
    sentence: str


def regime_answer(ok, regimes, checks, replicates=()):
    """The answer of a report that holds both sides at constant latencies: the question, one
    sentence per scene from the regime map (how many of the cells where both sides have a run
    each side wins, over which budgets, and where only one side exists), the scale, and the
    figure that shows it. The maps of replicates (curves.replicates: seeds, camera paths) of
    one scene and condition are pooled: their cells counted together."""
    im, table = regimes
    name = im["name"].upper()
    pooled = {}
    for (scene, rest), m in sorted(table.items()):
        key = (scene, tuple((k, v) for k, v in rest if k not in replicates))
        pooled.setdefault(key, []).append(m)
    short, rows = [], []
    for (scene, rest), maps in sorted(pooled.items()):
        cells = [c for m in maps for c in m["cells"].items()]
        both = [(k, c) for k, c in cells if c["winner"] in ("hybrid", "remote", "tie") and not c["only"]]
        hw = [k for k, c in both if c["winner"] == "hybrid"]
        rw = [k for k, c in both if c["winner"] == "remote"]
        only = {side: sorted(b for (_, b), c in cells if c["only"] == side) for side in ("hybrid", "remote")}
        parts = [f"hybrid better in {len(hw)} and remote in {len(rw)} of {len(both)} cells where both have a run"]
        span = lambda bs: f"{bs[0]:.3g}" if f"{bs[0]:.3g}" == f"{bs[-1]:.3g}" else f"{bs[0]:.3g}-{bs[-1]:.3g}"  # noqa: E731
        for side, won in (("hybrid", hw), ("remote", rw)):
            if won:
                parts.append(f"{side} wins at {span(sorted(b for _, b in won))} Mb/s")
        for side in ("remote", "hybrid"):
            if only[side]:
                parts.append(f"only {side} reaches {span(only[side])} Mb/s")
        rtt_list = ", ".join(f"{t:g}" for t in sorted({t for m in maps for t in m["rtts"]}))
        title = scene + (f" ({', '.join(f'{k}={v}' for k, v in rest)})" if rest else "")
        over = f", {len(maps)} replicates pooled" if len(maps) > 1 else ""
        rows.append(f"- **{title}** (RTT {rtt_list} ms{over}): " + "; ".join(parts) + ".")
        short.append(f"{scene_name(scene)} {len(hw)}:{len(rw)}" + (f", only remote under {only['remote'][-1]:.3g} Mb/s"
                                                                  if only["remote"] else ""))
    (scene, rest), _ = sorted(table.items())[0]
    title = scene + (f" ({', '.join(f'{k}={v}' for k, v in rest)})" if rest else "")
    out = answer_lines(f"at a given bitrate budget and round-trip time, does hybrid rendering or remote rendering "
                       f"give the better image ({name} against the ground truth)?", rows, ok, checks,
                       f"![regime map {title}](plots/{regime_file(title)})\n")
    sentence = (f"At matched bitrate and RTT, cells where hybrid : remote gives the better {name} against the ground "
                f"truth: " + "; ".join(short) + ".")
    return Answer(out, sentence)


def scene_values(ok, scene, im):
    """(run, value) of an image metric's run means on one scene, against the ground truth where
    every run of the scene scored it, else against the local reference; and which reference."""
    rs = [r for r in ok if r["scene"] == scene]
    truth = [r["metrics"].get(im["aggregates"]["ground_truth"]["mean"]) for r in rs]
    ref = "ground_truth" if rs and all(v is not None for v in truth) else "local"
    vals = [(r, r["metrics"].get(im["aggregates"][ref]["mean"])) for r in rs]
    return [(r, v) for r, v in vals if isinstance(v, (int, float)) and math.isfinite(v)], ref


REFERENCE_WORDS = {"ground_truth": "the ground truth", "local": "the local reference"}


def front_answer(ok, metrics, spec, checks):
    """The answer of a report without both sides at constant latencies: per scene, the best run on
    the lead metric, the cheapest run (bandwidth, or the server's time where the experiment's
    answer.cost says so), and how many runs lie on the front of quality against that cost."""
    im = lead_metric(metrics)
    name = im["name"].upper()
    higher = im.get("higher_is_better", True)
    key = lambda v: v if higher else -v  # noqa: E731  larger is better
    by_time = spec.get("cost") == "server_time"
    cost = server_ms if by_time else (lambda r: r["metrics"].get("bandwidth_mbps") or None)  # noqa: E731
    unit = "ms of server time per frame" if by_time else "Mb/s"
    rows, short, refs = [], [], set()
    for scene in sorted({r["scene"] for r in ok}):
        vals, ref = scene_values(ok, scene, im)
        vals = [(r, v) for r, v in vals if cost(r)]
        if not vals:
            continue
        refs.add(ref)
        best_r, best_v = max(vals, key=lambda rv: key(rv[1]))
        cheap_r, cheap_v = min(vals, key=lambda rv: cost(rv[0]))
        front = pareto([(cost(r), key(v)) for r, v in vals])
        rows.append(f"- **{scene_name(scene)}**: best {name} {best_v:.4g} ({best_r['label']}, {cost(best_r):.3g} {unit}); "
                    f"cheapest {cost(cheap_r):.3g} {unit} ({cheap_r['label']}, {name} {cheap_v:.4g}); "
                    f"{len(front)} of {len(vals)} runs on the front.")
        short.append(f"{scene_name(scene)} {best_v:.4g} ({best_r['label']}, {cost(best_r):.3g} {unit})")
    if not rows:
        return Answer([], "")
    against = against_words(refs)
    what = "server time" if by_time else "bandwidth"
    question = spec.get("question") or f"which configuration gives the best image for the {what} it costs?"
    plot = "quality_vs_server_time" if by_time else "quality_vs_bandwidth"
    out = answer_lines(f"{question} ({name} against {against}; {'higher' if higher else 'lower'} is better; the front: "
                       f"the runs no other run of the scene beats on both quality and {what}.)", rows, ok, checks,
                       f"![quality against {what}](plots/{plot}.png)\n")
    return Answer(out, f"Best {name} against {against} per scene: " + "; ".join(short) + ".")


def group_and_condition(run, group, along):
    """The run's value of answer.group (a setting or "configuration") and of answer.along, as
    strings; None when the run has either not."""
    st = dict(run.get("settings", {}), configuration=run.get("configuration"))
    if st.get(group) is None or along not in st:
        return None
    return str(st[group]), str(st[along])


def range_answer(ok, metrics, spec, checks):
    """The answer of a report that compares groups (answer.group, e.g. the predictor) along a
    condition (answer.along, e.g. the network): per scene and group, the lead metric at the best and
    the worst value of the condition."""
    im = lead_metric(metrics)
    name = im["name"].upper()
    higher = im.get("higher_is_better", True)
    key = lambda v: v if higher else -v  # noqa: E731
    group, along = spec["group"], spec["along"]
    rows, short, refs = [], [], set()
    for scene in sorted({r["scene"] for r in ok}):
        vals, ref = scene_values(ok, scene, im)
        groups = {}
        for r, v in vals:
            if ga := group_and_condition(r, group, along):
                groups.setdefault(ga[0], []).append((ga[1], v))
        if not groups:
            continue
        refs.add(ref)
        parts = []
        for g, pts in sorted(groups.items()):
            best = max(pts, key=lambda p: key(p[1]))
            worst = min(pts, key=lambda p: key(p[1]))
            parts.append(f"{g}: {best[1]:.4g} ({best[0]}) to {worst[1]:.4g} ({worst[0]})")
        rows.append(f"- **{scene_name(scene)}**, {name} by {group}: " + "; ".join(parts) + ".")
        short.append(f"{scene_name(scene)}: " + "; ".join(parts))
    if not rows:
        return Answer([], "")
    against = against_words(refs)
    question = spec.get("question") or f"how does the image change with {along}, for each {group}?"
    out = answer_lines(f"{question} ({name} against {against}, {'higher' if higher else 'lower'} is better: each "
                       f"{group}'s best and worst run over the values of {along}.)", rows, ok, checks)
    return Answer(out, f"{name} against {against}, best to worst over {along}: " + " | ".join(short) + ".")


def budget_answer(ok, metrics, spec, checks):
    """The answer of an error budget (answer.terms): per scene, each term's share of the lead
    metric, the run of the configuration with the effect minus the run without it."""
    im = lead_metric(metrics)
    name = im["name"].upper()
    sign = 1 if not im.get("higher_is_better", True) else -1  # positive: the effect costs quality
    terms = [t for t in spec["terms"] if isinstance(t, dict)]
    rows, short, refs = [], [], set()
    for scene in sorted({r["scene"] for r in ok}):
        vals, ref = scene_values(ok, scene, im)
        by_config = {r.get("configuration"): v for r, v in vals}
        parts = []
        for t in terms:
            a, b = by_config.get(t.get("with")), by_config.get(t.get("without"))
            if a is None or (b is None and "without" in t):
                parts.append(f"{t.get('name')} – (a run is missing)")
            elif "without" in t:
                parts.append(f"{t.get('name')} {sign * (a - b):+.4f}")
            else:
                parts.append(f"{t.get('name')} {a:.4f}")
        if not vals:
            continue
        refs.add(ref)
        rows.append(f"- **{scene_name(scene)}**: " + "; ".join(parts) + ".")
        short.append(f"{scene_name(scene)}: " + ", ".join(parts))
    if not rows:
        return Answer([], "")
    against = against_words(refs)
    question = spec.get("question") or "how much does each effect cost the image?"
    out = answer_lines(f"{question} (each term: {name} against {against} of the configuration with the effect "
                       f"minus the one without it, signed so that a positive term is error the effect adds; a term "
                       f"without a configuration to subtract is that configuration's own {name}.)", rows, ok, checks)
    return Answer(out, f"{name} added by each effect: " + " | ".join(short) + ".")


def answer(exp, ok, metrics, regimes, checks):
    """The answer first (at most ten lines): the error budget or the comparison along a condition
    that the experiment's "answer" declares; else the regime map where the report holds both
    sides at constant latencies; else the Pareto fronts. `checks`: the committed convergence
    checks its scale line cites."""
    if not ok or not metrics:
        return Answer([], "")
    spec = exp.get("answer") if isinstance(exp.get("answer"), dict) else {}
    if isinstance(spec.get("terms"), list):
        return budget_answer(ok, metrics, spec, checks)
    if isinstance(spec.get("group"), str) and isinstance(spec.get("along"), str):
        return range_answer(ok, metrics, spec, checks)
    if regimes:
        curves = exp.get("curves") if isinstance(exp.get("curves"), dict) else {}
        replicates = [k for k in curves.get("replicates", []) if isinstance(k, str)]
        return regime_answer(ok, regimes, checks, replicates)
    return front_answer(ok, metrics, spec, checks)


def regime_section(plot, d, regimes):
    """The regime maps (regime_tables): a markdown table and a heatmap (plots/regime_map_SCENE.png)
    per scene."""
    if not regimes:
        return []
    im, table = regimes
    higher = im.get("higher_is_better", True)
    name = im["name"].upper()
    out = ["## Regime map: hybrid or remote\n",
           f"Which side gives the better {name} against the ground truth (run means; {'higher' if higher else 'lower'} "
           "is better) at each bitrate budget (Mb/s on the wire, log-spaced over every run's bitrate) and round-trip "
           "time (the network's two constant latencies added): per side its best family at that budget, each "
           f"family's {name} interpolated in log-bitrate by PCHIP within its measured range (a budget above a "
           "family's dearest point takes that point; none is extrapolated). Cell: **H** hybrid better, R remote "
           f"better, by the {name} difference shown; *H only* / *R only*: only that side has a run at or under the "
           "budget; – neither.\n"]
    for (scene, rest), m in sorted(table.items()):
        title = scene + (f" ({', '.join(f'{k}={v}' for k, v in rest)})" if rest else "")
        fname = regime_file(title)
        out.append(f"{title}:\n")
        out.append("| RTT \\ Mb/s | " + " | ".join(f"{b:.3g}" for b in m["budgets"]) + " |")
        out.append("|---|" + "---|" * len(m["budgets"]))
        for rtt in m["rtts"]:
            cells = []
            for b in m["budgets"]:
                c = m["cells"][(rtt, b)]
                if c["winner"] is None:
                    cells.append("–")
                elif c["only"]:
                    cells.append(f"*{c['only'][0].upper()} only*")
                elif c["winner"] == "tie":
                    cells.append("tie")
                else:
                    side = "**H**" if c["winner"] == "hybrid" else "R"
                    cells.append(f"{side} {abs(c['margin']):.4f}")
            out.append(f"| {rtt:g} ms | " + " | ".join(cells) + " |")
        out.append("")
        winners = sorted({c[c["winner"]][0] for c in m["cells"].values() if c["winner"] in ("hybrid", "remote")})
        if winners:
            out.append("Best families where a side wins: " + ", ".join(winners) + ".\n")
        regime_heatmap(plot, m, title, name, os.path.join(d, "plots", fname))
        out.append(f"![regime map {title}](plots/{fname})\n")
    return out


def regime_heatmap(plot, m, title, name, path):
    """One scene's regime map as a heatmap: the margin (> 0: hybrid better) on a diverging scale
    symmetric about 0; cells with one side only marked by text, empty cells grey."""
    import numpy as np
    plt = plot.plt
    rtts, budgets = m["rtts"], m["budgets"]
    grid = np.full((len(rtts), len(budgets)), np.nan)
    for i, rtt in enumerate(rtts):
        for j, b in enumerate(budgets):
            c = m["cells"][(rtt, b)]
            if c["margin"] is not None:
                grid[i, j] = c["margin"]
    span = float(np.nanmax(np.abs(grid))) if np.isfinite(grid).any() else 1.0
    fig, ax = plt.subplots(figsize=(1.0 + 0.62 * len(budgets), 1.4 + 0.55 * len(rtts)))
    cmap = plt.get_cmap("RdBu_r").copy()
    cmap.set_bad("#dddddd")
    im = ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=-(span or 1.0), vmax=span or 1.0, aspect="auto",
                   origin="lower")
    for i, rtt in enumerate(rtts):
        for j, b in enumerate(budgets):
            c = m["cells"][(rtt, b)]
            text = ("H only" if c["only"] == "hybrid" else "R only") if c["only"] else ("H" if c["winner"] == "hybrid" else
                                                                                        "R" if c["winner"] == "remote" else "")
            if text:
                ax.text(j, i, text, ha="center", va="center", fontsize=6)
    ax.set_xticks(range(len(budgets)))
    ax.set_xticklabels([f"{b:.3g}" for b in budgets], rotation=45, fontsize=7)
    ax.set_yticks(range(len(rtts)))
    ax.set_yticklabels([f"{t:g}" for t in rtts], fontsize=7)
    ax.set_xlabel("bitrate budget (Mb/s, log-spaced)")
    ax.set_ylabel("round-trip time (ms)")
    ax.set_title(f"{title}: hybrid (red) or remote (blue), {name} margin", fontsize=8)
    fig.colorbar(im, ax=ax, label=f"{name} advantage of hybrid")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def size_line(runs):
    """The image size and frames every figure below comes from, from the runs' effective settings
    (each distinct combination with its number of runs when they differ)."""
    shapes = {}
    for r in runs:
        c = r.get("config", {})
        key = (c.get("width"), c.get("height"), c.get("frames"), c.get("warmup_frames"), c.get("display_hz"))
        shapes[key] = shapes.get(key, 0) + 1
    parts = [f"{w}x{h}, {f} displayed frames after {wu} warm-up at {hz:g} Hz" + ("" if len(shapes) == 1 else f" ({n} runs)")
             for (w, h, f, wu, hz), n in sorted(shapes.items(), key=lambda kv: -kv[1])
             if None not in (w, h, f, wu, hz)]
    return ("Size: " + "; ".join(parts) + " per run.\n") if parts else ""


def bd_section(rq, cm, anchor, im, equal_bandwidth=False):
    """The BD-rate table (equal quality) or, with `equal_bandwidth`, the BD-quality table of every
    family against `anchor` on image metric `im` (rate_quality.bd_checked: PCHIP, its flags marked
    in the cells and explained below the table): the lines."""
    higher = im.get("higher_is_better", True)
    table = rq.bd_table(cm, anchor, "quality" if equal_bandwidth else "rate", "pchip", higher)
    if not table:
        return []
    out = []
    fams = sorted({f for row in table.values() for f in row})
    name = im["name"].upper()
    results = [((scene, cond), f, row[f]) for (scene, cond), row in sorted(table.items()) for f in fams if f in row]
    valued = [res for _, _, res in results if res.value is not None]
    # Fewer than 4 points: marked per cell unless every number has it (then said once).
    few_everywhere = bool(valued) and all("few_points" in res.flags for res in valued)
    marks = {"methods_disagree": "†", "few_points": "" if few_everywhere else "‡"}
    if equal_bandwidth:
        better = "higher" if higher else "lower"
        out.append(f"At equal bandwidth: BD-{name} against **{anchor}** (VCEG-M33's BD-PSNR on {name}: the mean "
                   f"{name} difference, family minus anchor, over the bitrate range both curves share, {name} "
                   f"interpolated by PCHIP in log-bitrate as the JCT-VC common test conditions do; {better} is "
                   "better; – : no number, the reasons below):\n")
    else:
        out.append(f"BD-rate against **{anchor}** on {name} (VCEG-M33 with PCHIP interpolation of log-bitrate in "
                   f"{name}, as the JCT-VC common test conditions; negative: the family needs that much less "
                   "bitrate at equal quality; – : no number, the reasons below):\n")
    out.append("| scene | conditions | " + " | ".join(fams) + " |")
    out.append("|---|---|" + "---|" * len(fams))
    for (scene, cond), row in sorted(table.items()):
        cells = []
        for f in fams:
            res = row.get(f)
            if res is None or res.value is None:
                cells.append("–")
                continue
            text = f"{res.value:+.4f}" if equal_bandwidth else f"{res.value:+.1f} %"
            cells.append(text + "".join(marks[k] for k in ("methods_disagree", "few_points") if k in res.flags))
        out.append(f"| {scene} | {', '.join(f'{k}={v}' for k, v in cond) or '–'} | " + " | ".join(cells) + " |")
    out.append("")
    where = lambda key, f: f"{key[0]}, {', '.join(f'{k}={v}' for k, v in key[1]) or 'all runs'}, {f}"  # noqa: E731
    disagree = [f"- {where(key, f)}: {res.flags['methods_disagree']}"
                for key, f, res in results if "methods_disagree" in res.flags]
    if disagree:
        out.append("† The PCHIP, Akima and polynomial (VCEG-M33's cubic) fits disagree in sign or by more than "
                   + ("5 % of the curves' quality span" if equal_bandwidth else "5 percentage points")
                   + ": the number depends on how the points are joined:\n")
        out.extend(disagree)
        out.append("")
    if few_everywhere:
        out.append("Every number above comes from curves of fewer than 4 points (VCEG-M33 and the common test "
                   "conditions use 4): read them as indications.\n")
    elif any("few_points" in res.flags for res in valued):
        out.append("‡ A curve of fewer than 4 points (VCEG-M33 and the common test conditions use 4).\n")
    reasons = [f"- {where(key, f)}: {res.reason}" for key, f, res in results if res.value is None]
    if reasons:
        out.append(f"Why a cell has no {'BD-' + name if equal_bandwidth else 'BD-rate'}:\n")
        out.extend(reasons)
        out.append("")
    return out


def replicate_section(rq, cm, anchor, im, replicates, equal_bandwidth=False):
    """BD-rate (or BD-quality) of every family against `anchor` over the replicates (the swept
    keys in curves.replicates, e.g. seed and camera_speed): per scene, remaining conditions and
    family, the mean of its per-replicate BD figures with Student's t 95 % interval (the
    replicates taken as independent draws), their range and how many replicates gave a number.
    Returns the lines."""
    import intervals
    higher = im.get("higher_is_better", True)
    table = rq.bd_table(cm, anchor, "quality" if equal_bandwidth else "rate", "pchip", higher)
    groups = {}
    for (scene, cond), row in table.items():
        rest = tuple((k, v) for k, v in cond if k not in replicates)
        reps = tuple((k, v) for k, v in cond if k in replicates)
        for fam, res in row.items():
            groups.setdefault((scene, rest, fam), []).append((reps, res.value))
    if not groups:
        return []
    name = im["name"].upper()
    what = f"BD-{name}" if equal_bandwidth else f"BD-rate on {name}"
    out = []
    out.append(f"{what} against **{anchor}** over the replicates ({', '.join(f'`{k}`' for k in replicates)}): the mean "
               "of the per-replicate figures (PCHIP, as above) with Student's t 95 % interval, the replicates taken as "
               "independent draws of the scene's noise and motion; n: replicates with a number (of those run).\n")
    out.append("| scene | conditions | family | n | mean | 95 % interval | range |")
    out.append("|---|---|---|---:|---:|---:|---:|")
    unit = "" if equal_bandwidth else " %"
    digits = 4 if equal_bandwidth else 1
    for (scene, rest, fam), vals in sorted(groups.items()):
        xs = [v for _, v in vals if v is not None]
        if not xs:
            out.append(f"| {scene} | {', '.join(f'{k}={v}' for k, v in rest) or '–'} | {fam} | 0 of {len(vals)} | – | – | – |")
            continue
        mean = sum(xs) / len(xs)
        if len(xs) >= 2:
            sd = math.sqrt(sum((x - mean) ** 2 for x in xs) / (len(xs) - 1))
            half = intervals.t975(len(xs) - 1) * sd / math.sqrt(len(xs))
            ci = f"{mean - half:+.{digits}f} .. {mean + half:+.{digits}f}{unit}"
        else:
            ci = "– (one replicate)"
        out.append(f"| {scene} | {', '.join(f'{k}={v}' for k, v in rest) or '–'} | {fam} | {len(xs)} of {len(vals)} | "
                   f"{mean:+.{digits}f}{unit} | {ci} | {min(xs):+.{digits}f} .. {max(xs):+.{digits}f}{unit} |")
    out.append("")
    return out


def scatter_with_front(plot, headline, runs, xkey, xlabel, title, path, logx=False):
    """Per scene, an image metric (metric_value) against `xkey` with the Pareto front, its points
    labelled by configuration."""
    sign = 1 if headline.get("higher_is_better", True) else -1
    scenes = sorted({r["scene"] for r in runs})
    fig, axes = plot.plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4.2), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        rs = [r for r in runs if r["scene"] == scene and metric_value(r, headline) is not None]
        pts = [(xkey(r), metric_value(r, headline)) for r in rs]
        if not pts:
            continue
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=18, color="tab:blue", zorder=2)
        front = pareto([(x, sign * q) for x, q in pts])
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], color="tab:red", lw=1.2, zorder=1,
                label="Pareto front")
        for i in front:
            label = rs[i].get("label") or rs[i]["id"]
            ax.annotate(label if len(label) <= 32 else label[:31] + "…", pts[i], fontsize=6, xytext=(3, 3),
                        textcoords="offset points")
        if logx and all(p[0] > 0 for p in pts):
            ax.set_xscale("log")
        ax.set_title(scene)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(f"{headline['name'].upper()} (vs ground truth where scored, else local reference; "
                      f"{'higher' if sign > 0 else 'lower'} is better)", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plot.plt.close(fig)


def header_section(res):
    """Title, description, how to regenerate, image size and the measuring conventions."""
    ctx, exp = res["context"], res["experiment"]
    out = [f"# {exp.get('name', 'experiment')}\n"]
    if exp.get("description"):
        out.append(exp["description"] + "\n")
    out.append(f"Regenerate: `{ctx.get('command', 'dhrbench run ' + res.get('experiment_path', ''))}` "
               f"(wall time of this run: {res.get('wall_s', float('nan')):.0f} s).\n")
    out.append(size_line(res["runs"]))
    out.append("Virtual time (ms) drives the display, the network and the server schedule; wall time measures "
               "what each stage costs on this machine. Bandwidth counts every packet on the wire: payload, the "
               "44-byte dhrbench header and 28 bytes of IP/UDP. SSIM follows Wang et al. 2004 (Gaussian 11x11, "
               "sigma 1.5, K1 0.01, K2 0.03) on BT.601 luma of the 8-bit sRGB frames.\n")
    return out


def context_section(ctx):
    """The machine and build the results come from."""
    libs = ", ".join(f"{k} {v}" for k, v in ctx.get("libraries", {}).items())
    return ["## Context\n", "| | |\n|---|---|",
            f"| git commit | `{ctx.get('git_commit')}`{' (dirty)' if ctx.get('git_dirty') else ''} |",
            f"| build | {ctx.get('build_type')}, {ctx.get('compiler')} |",
            f"| CPU | {ctx.get('cpu_model')} ({ctx.get('hardware_threads')} hardware threads; "
            f"threads option {ctx.get('threads') or 'all'}) |",
            f"| kernel | {ctx.get('kernel')} |",
            f"| libraries | {libs} |\n"]


def results_section(ok, failed, metrics, frames):
    """One row per run: every declared image metric's means with their intervals, bitrate, frame
    sizes, frame rates, buffer ages and losses; then the failed runs."""
    out = ["## Results\n"]
    # One column per declared image metric and reference (means over the scored frames).
    quality_columns = [(f"{im['name'].upper()}{' ' + UNIT_NAMES.get(im['unit'], im['unit']) if im['unit'] else ''} "
                        f"{'local' if ref == 'local' else 'truth'}", im["aggregates"][ref]["mean"],
                        4 if not im["unit"] else 2, im["columns"][ref])
                       for im in metrics for ref in ("local", "ground_truth")]
    cis = frame_intervals(frames, metrics)
    blocks = sorted({ci[1] for ci in cis.values()})
    out.append("Quality: mean over the scored frames ± the half-width of its 95 % confidence interval; scored frames: "
               "against the local reference / the ground truth. Consecutive frames are correlated, so the "
               "half-width is Student's t quantile (n - 1 degrees of freedom) times the standard error of the mean "
               "by a circular block bootstrap (2000 resamples of blocks of consecutive scored frames, fixed seed; "
               "the block length from each series' lag-1 autocorrelation by Carlstein's AR(1) rule"
               + (f", here {blocks[0]}..{blocks[-1]} frames" if blocks else "") + "; experiments/intervals.py): "
               "Student's t interval where frames are independent, wider where they are not.\n")
    # Results written before the stall metrics have no stall column.
    stalls = any("stalls" in r["metrics"] for r in ok)
    out.append("| run | scene | configuration | scored frames | " + " | ".join(c[0] for c in quality_columns) +
               " | Mb/s | bytes/frame per pass | server fps (virtual) | client fps (wall) | buffer age ms (median) "
               "| frames lost" + (" (FEC rebuilt) | stalls (ms in all, longest) |" if stalls else " |"))
    out.append("|---|---|---|---|" + "---|" * len(quality_columns) + "---|---|---|---|---|---|" + ("---|" if stalls else ""))
    for r in ok:
        m = r["metrics"]
        per_pass = ", ".join(f"{p['pass']} {p['bytes_per_frame']:.0f}" for p in m["passes"] if p["server_frames"])
        ages = [v["median"] for k, v in m.items() if k.startswith("buffer_age_ms_")]
        lost = sum(p["frames_lost"] for p in m["passes"])
        cells = " | ".join(fmt(m.get(key), digits) + (f" ± {fmt(cis[(r['id'], col)][0], digits)}"
                                                      if m.get(key) is not None and (r["id"], col) in cis else "")
                           for _, key, digits, col in quality_columns)
        scored = f"{m.get('frames_scored', '–')} / {m.get('frames_scored_ground_truth', '–')}"
        out.append(f"| {r['id']} | {r['scene']} | {r['label']} | {scored} | {cells} | "
                   f"{m['bandwidth_mbps']:.2f} | {per_pass or '–'} | {m['server_fps_virtual']:.1f} | "
                   f"{m['client_fps_wall']:.1f} | {', '.join(f'{a:.1f}' for a in ages) or '–'} | {lost}"
                   + (f" ({sum(p.get('frames_recovered', 0) for p in m['passes'])}) | {m.get('stalls', '–')} "
                      f"({fmt(m.get('stall_ms_total'), 0)}, {fmt(m.get('stall_ms_longest'), 0)}) |" if stalls else " |"))
    out.append("")
    if failed:
        out.append("### Failed configurations\n")
        for r in failed:
            out.append(f"- {r['id']} ({r['label']} on {r['scene']}): `{r['error']}`")
        out.append("")
    return out


def stages_section(ok):
    """Median and p95 wall time of every stage, per run."""
    out = ["## Stage wall times (median / p95 ms)\n"]
    stage_names = []
    for r in ok:
        for s in r["metrics"]["stages_wall"]:
            if s not in stage_names:
                stage_names.append(s)
    out.append("| run | " + " | ".join(stage_names) + " |")
    out.append("|---|" + "---|" * len(stage_names))
    for r in ok:
        st = r["metrics"]["stages_wall"]
        cells = [f"{st[s]['median_ms']:.2f} / {st[s]['p95_ms']:.2f}" if s in st else "–" for s in stage_names]
        out.append(f"| {r['id']} | " + " | ".join(cells) + " |")
    out.append("")
    return out


def condition_table_section(exp, ok, metrics):
    """For an experiment that compares groups along a condition (answer.group, answer.along): the
    lead metric against the ground truth (else the local reference) and the stall time, one row
    per group and one column per value of the condition, each the mean over the scenes; the best
    cell of each column in bold."""
    spec = exp.get("answer") if isinstance(exp.get("answer"), dict) else {}
    group, along = spec.get("group"), spec.get("along")
    if not group or not along or not ok or not metrics:
        return []
    im = lead_metric(metrics)
    higher = im.get("higher_is_better", True)
    runs = [(r, ga) for r in ok if (ga := group_and_condition(r, group, along))]
    # Against the ground truth where every run has it, else the local reference.
    truth = all(r["metrics"].get(im["aggregates"]["ground_truth"]["mean"]) is not None for r, _ in runs)
    ref = "ground truth" if truth else "local reference"
    key = im["aggregates"]["ground_truth" if truth else "local"]["mean"]
    cells, cols, rows = {}, [], []
    for r, (g, a) in runs:
        rows += [g] if g not in rows else []
        cols += [a] if a not in cols else []
        cells.setdefault((g, a), []).append((r["metrics"].get(key), r["metrics"].get("stall_ms_total")))
    if not cells:
        return []
    out = [f"## {group.capitalize()} by {along}\n",
           f"{im['name'].upper()} against the {ref} ({'higher' if higher else 'lower'} is better) and the stall time in "
           f"ms (in brackets), each the mean over the scenes; the best {im['name'].upper()} of each column in bold.\n",
           f"| {group} | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    mean = lambda xs: sum(xs) / len(xs) if xs else None  # noqa: E731
    table = {k: (mean([x[0] for x in v if x[0] is not None]), mean([x[1] for x in v if x[1] is not None]))
             for k, v in cells.items()}
    best = {}
    for a in cols:
        vals = [table[(g, a)][0] for g in rows if (g, a) in table and table[(g, a)][0] is not None]
        best[a] = (max if higher else min)(vals) if vals else None
    for g in rows:
        out_cells = []
        for a in cols:
            v, stall = table.get((g, a), (None, None))
            text = "–" if v is None else f"{v:.4f}" + (f" ({stall:.0f})" if stall is not None else "")
            out_cells.append(f"**{text}**" if v is not None and v == best[a] else text)
        out.append(f"| {g} | " + " | ".join(out_cells) + " |")
    out.append("")
    return out


LATENCY_PARTS = [("uplink", "uplink"), ("server_wait", "server wait"), ("server", "server"),
                 ("downlink", "downlink (queue, FEC)"), ("display_wait", "display wait")]


def latency_section(ok):
    """Motion to photon: each displayed buffer's age as its stages (results' latency_breakdown_ms_PASS,
    each the median over a run's displayed frames), for the first pass sent (remote: colour), as the
    mean over the scenes per configuration and network. Empty for results written before it."""
    rows = {}
    for r in ok:
        m = r["metrics"]
        sent = [p["pass"] for p in m["passes"] if p["server_frames"]]
        parts = m.get(f"latency_breakdown_ms_{sent[0]}") if sent else None
        if not parts:
            continue
        key = (r.get("configuration", r["label"]), r.get("settings", {}).get("network", ""))
        rows.setdefault(key, []).append([parts[k] for k, _ in LATENCY_PARTS])
    if not rows:
        return []
    out = ["## Motion to photon (virtual ms)\n",
           "Each displayed buffer's age from the camera leaving the client to the display, as the stages it went "
           "through (the median over a run's displayed frames, then the mean over the scenes), for the first pass "
           "sent (hybrid: visibility; remote: colour). The stages add up to the buffer age; the client's own "
           "stages (rasterize, decode, predict, composite) are wall time, in the stage table.\n",
           "| configuration | network | " + " | ".join(label for _, label in LATENCY_PARTS) + " | total |",
           "|---|---|" + "---|" * (len(LATENCY_PARTS) + 1)]
    for (config, network), values in rows.items():
        means = [sum(v[k] for v in values) / len(values) for k in range(len(LATENCY_PARTS))]
        out.append(f"| {config} | {network or '–'} | " + " | ".join(f"{x:.1f}" for x in means) +
                   f" | {sum(means):.1f} |")
    out.append("")
    return out


def frame_size_plot(plot, ok, path):
    """Frame size against delivered frame rate (the paper's Fig. 10): per run, the bytes of one
    server frame (all passes) against the frames per second that arrived complete (the slowest
    pass). Under a bandwidth cap, larger frames arrive less often. Returns whether the runs
    recorded the delivered frame rate (else the plot is empty)."""
    plt = plot.plt
    have_fps = any("delivered_fps" in p for r in ok for p in r["metrics"]["passes"])
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for mode, colour in (("hybrid", "tab:blue"), ("remote", "tab:orange")) if have_fps else ():
        rs = [r for r in ok if r.get("config", {}).get("mode", "hybrid") == mode]
        xs, ys = [], []
        for r in rs:
            passes = [p for p in r["metrics"]["passes"] if p["server_frames"]]
            if not passes:
                continue
            xs.append(sum(p["bytes_per_frame"] for p in passes))
            ys.append(min(p.get("delivered_fps", 0.0) for p in passes))
        if xs:
            ax.scatter(xs, ys, s=16, color=colour, label=mode)
    ax.set_xscale("log")
    ax.set_xlabel("bytes per server frame (all passes, encoded)")
    ax.set_ylabel("frames delivered complete per second (slowest pass)")
    ax.set_title("Frame size against delivered frame rate")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return have_fps


def per_frame_plot(plot, ok, frames, headline, path):
    """The headline metric against the local reference per displayed frame, one panel per scene
    (at most 12 runs each)."""
    plt = plot.plt
    column = headline["columns"]["local"]
    scenes = sorted({r["scene"] for r in ok})
    fig, axes = plt.subplots(len(scenes), 1, figsize=(9, 3.2 * len(scenes)), squeeze=False)
    for ax, scene in zip(axes[:, 0], scenes):
        for r in [r for r in ok if r["scene"] == scene][:12]:
            rows = [f for f in frames if f["run"] == r["id"] and f[column] != ""]
            ax.plot([int(f["frame"]) for f in rows], [float(f[column]) for f in rows],
                    lw=1, label=f"{r['id']} {r['label']}"[:48])
        ax.set_title(f"{scene}: {headline['name'].upper()} against the local reference, per displayed frame")
        ax.set_xlabel("frame")
        ax.set_ylabel(headline["name"].upper())
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plots_section(plot, d, ok, frames, headline, lead):
    """Quality (the lead metric) against bandwidth and server time (Pareto fronts), frame size
    against frame rate, the headline metric per frame."""
    if not ok:
        return []
    plots = os.path.join(d, "plots")
    scatter_with_front(plot, lead, ok, lambda r: r["metrics"]["bandwidth_mbps"], "bandwidth on the wire (Mb/s)",
                       "Quality against bandwidth", os.path.join(plots, "quality_vs_bandwidth.png"), logx=True)
    scatter_with_front(plot, lead, ok, server_ms, "server wall time per frame (ms, sum of stage medians)",
                       "Quality against server time", os.path.join(plots, "quality_vs_server_time.png"))
    have_fps = frame_size_plot(plot, ok, os.path.join(plots, "frame_size_vs_fps.png"))
    out = ["## Plots\n", "Red: the Pareto front (no other run of the scene is both cheaper and better).\n",
           "![quality against bandwidth](plots/quality_vs_bandwidth.png)\n",
           "![quality against server time](plots/quality_vs_server_time.png)\n"]
    if have_fps:
        out.append("![frame size against delivered frame rate](plots/frame_size_vs_fps.png)\n")
    if frames:
        per_frame_plot(plot, ok, frames, headline, os.path.join(plots, "ssim_per_frame.png"))
        out.append("![SSIM per frame](plots/ssim_per_frame.png)\n")
    return out


def grid_figure(plot, img_dir, scene, chunk, path):
    """One image grid: the references, then per run what the client showed, its error map and
    (where written for every run of the chunk) FLIP's error map."""
    plt = plot.plt
    refs = []
    first = chunk[0]["id"]
    if os.path.exists(os.path.join(img_dir, first + "_truth.png")):
        refs.append(("ground truth", first + "_truth.png"))
    refs.append((f"local reference ({first})", first + "_local.png"))
    cols = max(len(chunk), len(refs))
    have_flip = all(os.path.exists(os.path.join(img_dir, r["id"] + "_flip.png")) for r in chunk)
    fig, axes = plt.subplots(4 if have_flip else 3, cols, figsize=(3.2 * cols, 8.8 if have_flip else 6.6),
                             squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for c, (title, name) in enumerate(refs):
        axes[0, c].imshow(read_image(plot, os.path.join(img_dir, name)))
        axes[0, c].set_title(title, fontsize=8)
    im = None
    for c, r in enumerate(chunk):
        axes[1, c].imshow(read_image(plot, os.path.join(img_dir, r["id"] + "_shown.png")))
        axes[1, c].set_title(f"{r['id']}: {r['label']}"[:44], fontsize=7)
        err = read_image(plot, os.path.join(img_dir, r["id"] + "_error.png"))
        if err.ndim == 3:
            err = err[..., 0]
        im = axes[2, c].imshow(err * ERROR_SCALE_LEVELS, cmap="viridis", vmin=0, vmax=ERROR_SCALE_LEVELS)
        axes[2, c].set_title(f"error vs {r.get('images', {}).get('error_against', 'reference')}", fontsize=7)
        if have_flip:
            axes[3, c].imshow(read_image(plot, os.path.join(img_dir, r["id"] + "_flip.png")))
            axes[3, c].set_title("FLIP error map (0 black .. 1 yellow)", fontsize=7)
    if im is not None:
        fig.colorbar(im, ax=list(axes[2, :]), orientation="vertical", fraction=0.02, pad=0.01,
                     label="|luma difference|\n(8-bit levels)")
    fig.suptitle(f"{scene}: last scored frame", fontsize=10)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def grids_section(plot, d, ok):
    """Per scene, grids of at most MAX_RUNS_PER_GRID runs (grid_figure); a published report
    without its per-run images lists the grids it keeps."""
    img_dir = os.path.join(d, "images")
    grids = []
    for scene in sorted({r["scene"] for r in ok}):
        rs = [r for r in ok if r["scene"] == scene and os.path.exists(os.path.join(img_dir, r["id"] + "_shown.png"))]
        stem = f"grid_{scene.replace('/', '_').replace('.json', '')}_"
        if not rs:
            # A published report keeps its grids but not the per-run images they were drawn from
            # (reports/README.md): rebuilding its report.md lists the grids it has.
            grids += sorted((g for g in os.listdir(os.path.join(d, "grids")) if g.startswith(stem) and g.endswith(".png")
                             and g[len(stem):-4].isdigit()), key=lambda g: int(g[len(stem):-4]))
        for part in range(0, len(rs), MAX_RUNS_PER_GRID):
            name = f"{stem}{part // MAX_RUNS_PER_GRID}.png"
            grid_figure(plot, img_dir, scene, rs[part:part + MAX_RUNS_PER_GRID], os.path.join(d, "grids", name))
            grids.append(name)
    if not grids:
        return []
    out = ["## Image grids\n",
           "Top: references. Then what the client displayed; the error of each against the ground truth where it "
           "was scored on that frame, else against the local reference, on one fixed colour scale "
           f"(0..{ERROR_SCALE_LEVELS} levels of luma difference); and, where written, FLIP's error map against the "
           "same reference on FLIP's own colour map (magma, 0..1).\n"]
    out += [f"![{g}](grids/{g})\n" for g in grids]
    return out


def notes_section(exp):
    notes = exp.get("notes")
    if not notes:
        return []
    return ["## Notes\n", notes if isinstance(notes, str) else "\n".join(notes), ""]


def write_report(d):
    """Reads DIR's results and writes DIR/report.md, its plots and grids, and DIR/report.html: each
    section from what it is given, in the order report.md shows them."""
    loaded = dr.load(d)  # checked: a damaged file is one BadResults, before matplotlib loads
    plot = load_matplotlib()
    for sub in ("plots", "grids"):
        os.makedirs(os.path.join(d, sub), exist_ok=True)
    res, metrics, headline = loaded.results, loaded.declared["image_metrics"], loaded.headline
    exp = res["experiment"]
    ok = [r for r in res["runs"] if "metrics" in r]
    failed = [r for r in res["runs"] if "error" in r]
    regimes = regime_tables(exp, ok, metrics)
    head = header_section(res)
    checks = dr.load_convergence_checks(CONVERGE_DIR)
    header = head[:1] + answer(exp, ok, metrics, regimes, checks).lines + head[1:]
    sections = [header,
                context_section(res["context"]),
                results_section(ok, failed, metrics, loaded.frames),
                condition_table_section(exp, ok, metrics),
                latency_section(ok),
                stages_section(ok),
                plots_section(plot, d, ok, loaded.frames, headline, lead_metric(metrics)),
                rate_quality_section(plot, d, exp, ok, metrics),
                regime_section(plot, d, regimes),
                convergence_section(ok, checks),
                grids_section(plot, d, ok),
                notes_section(exp)]
    with open(os.path.join(d, "report.md"), "w") as f:
        f.write("\n".join(line for lines in sections for line in lines) + "\n")
    import report_html
    report_html.write(d, header, res, ok, failed, metrics, metric_value)


def main(argv):
    """report.py RESULTS_DIR; damaged input exits 2 with one line naming the folder, never a traceback."""
    if len(argv) != 2:
        sys.exit("usage: report.py RESULTS_DIR")
    d = argv[1]
    try:
        write_report(d)
    except BadResults as e:
        print(f"dhrbench report: error: {e}", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError, RecursionError) as e:
        # Content the checks above let through: still one line naming the folder, never a traceback.
        tb = e.__traceback__
        while tb.tb_next:
            tb = tb.tb_next
        print(f"dhrbench report: error: {d}: results.json or frames.csv holds content the report cannot "
              f"use ({type(e).__name__}: {str(e)[:160]}; report.py line {tb.tb_lineno})", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)


if __name__ == "__main__":
    main(sys.argv)
