#!/usr/bin/env python3
"""Builds DIR/report.md and its plots from what 'dhrbench run' wrote in DIR (results.json,
frames.csv, images/). Run by 'dhrbench run' and 'dhrbench report DIR' with Debian's
/usr/bin/python3 and python3-matplotlib; nothing here runs the benchmark again.

Plots (DIR/plots/): quality against bandwidth and against server time, with the Pareto front
marked (higher SSIM, lower cost); SSIM per frame; stage wall times. Image grids (DIR/grids/):
per scene, the ground truth, the local reference, and for each run what the client showed
and its error map, all error maps on one fixed colour scale with its colour bar.
"""
import csv
import json
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402

ERROR_SCALE_LEVELS = 32  # the runner writes |luma difference| 0..32 levels as 0..255 grey
MAX_RUNS_PER_GRID = 8


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


def quality(run):
    m = run["metrics"]
    q = m.get("ssim_ground_truth_mean")
    return q if q is not None else m.get("ssim_local_mean")


def scatter_with_front(runs, xkey, xlabel, title, path, logx=False):
    scenes = sorted({r["scene"] for r in runs})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4.2), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        rs = [r for r in runs if r["scene"] == scene and quality(r) is not None]
        pts = [(xkey(r), quality(r)) for r in rs]
        if not pts:
            continue
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=18, color="tab:blue", zorder=2)
        front = pareto(pts)
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], color="tab:red", lw=1.2, zorder=1,
                label="Pareto front")
        for i in front:
            ax.annotate(rs[i]["id"], pts[i], fontsize=7, xytext=(3, 3), textcoords="offset points")
        if logx and all(p[0] > 0 for p in pts):
            ax.set_xscale("log")
        ax.set_title(scene)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("SSIM (vs ground truth where scored, else local reference)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(d):
    with open(os.path.join(d, "results.json")) as f:
        res = json.load(f)
    frames = []
    if os.path.exists(os.path.join(d, "frames.csv")):
        with open(os.path.join(d, "frames.csv")) as f:
            frames = list(csv.DictReader(f))
    os.makedirs(os.path.join(d, "plots"), exist_ok=True)
    os.makedirs(os.path.join(d, "grids"), exist_ok=True)
    ctx = res["context"]
    exp = res["experiment"]
    runs = res["runs"]
    ok = [r for r in runs if "metrics" in r]
    failed = [r for r in runs if "error" in r]

    out = []
    out.append(f"# {exp.get('name', 'experiment')}\n")
    if exp.get("description"):
        out.append(exp["description"] + "\n")
    out.append(f"Regenerate: `{ctx.get('command', 'dhrbench run ' + res.get('experiment_path', ''))}` "
               f"(wall time of this run: {res.get('wall_s', float('nan')):.0f} s).\n")
    out.append("Virtual time (ms) drives the display, the network and the server schedule; wall time measures "
               "what each stage costs on this machine. Bandwidth counts every packet on the wire: payload, the "
               "44-byte dhrbench header and 28 bytes of IP/UDP. SSIM follows Wang et al. 2004 (Gaussian 11x11, "
               "sigma 1.5, K1 0.01, K2 0.03) on BT.601 luma of the 8-bit sRGB frames.\n")
    out.append("## Context\n")
    out.append("| | |\n|---|---|")
    out.append(f"| git commit | `{ctx.get('git_commit')}`{' (dirty)' if ctx.get('git_dirty') else ''} |")
    out.append(f"| build | {ctx.get('build_type')}, {ctx.get('compiler')} |")
    out.append(f"| CPU | {ctx.get('cpu_model')} ({ctx.get('hardware_threads')} hardware threads; "
               f"threads option {ctx.get('threads') or 'all'}) |")
    out.append(f"| kernel | {ctx.get('kernel')} |")
    libs = ", ".join(f"{k} {v}" for k, v in ctx.get("libraries", {}).items())
    out.append(f"| libraries | {libs} |\n")

    out.append("## Results\n")
    out.append("| run | scene | configuration | SSIM local | SSIM truth | PSNR local dB | Mb/s | bytes/frame per pass "
               "| server fps (virtual) | client fps (wall) | buffer age ms (median) | frames lost |")
    out.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in ok:
        m = r["metrics"]
        per_pass = ", ".join(f"{p['pass']} {p['bytes_per_frame']:.0f}" for p in m["passes"] if p["server_frames"])
        ages = [v["median"] for k, v in m.items() if k.startswith("buffer_age_ms_")]
        lost = sum(p["frames_lost"] for p in m["passes"])
        out.append(f"| {r['id']} | {r['scene']} | {r['label']} | {fmt(m.get('ssim_local_mean'))} | "
                   f"{fmt(m.get('ssim_ground_truth_mean'))} | {fmt(m.get('psnr_local_mean_db'), 2)} | "
                   f"{m['bandwidth_mbps']:.2f} | {per_pass or '–'} | {m['server_fps_virtual']:.1f} | "
                   f"{m['client_fps_wall']:.1f} | {', '.join(f'{a:.1f}' for a in ages) or '–'} | {lost} |")
    out.append("")
    if failed:
        out.append("### Failed configurations\n")
        for r in failed:
            out.append(f"- {r['id']} ({r['label']} on {r['scene']}): `{r['error']}`")
        out.append("")

    # Stage times.
    out.append("## Stage wall times (median / p95 ms)\n")
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

    if ok:
        scatter_with_front(ok, lambda r: r["metrics"]["bandwidth_mbps"], "bandwidth on the wire (Mb/s)",
                           "Quality against bandwidth", os.path.join(d, "plots", "quality_vs_bandwidth.png"), logx=True)
        scatter_with_front(ok, server_ms, "server wall time per frame (ms, sum of stage medians)",
                           "Quality against server time", os.path.join(d, "plots", "quality_vs_server_time.png"))
        # Frame size against delivered frame rate (the paper's Fig. 10): per run, the bytes of one
        # server frame (all passes) against the frames per second that arrived complete (the
        # slowest pass). Under a bandwidth cap, larger frames arrive less often.
        have_fps = any("delivered_fps" in p for r in ok for p in r["metrics"]["passes"])
        fig, ax = plt.subplots(figsize=(7, 4.2))
        for mode, colour in (("hybrid", "tab:blue"), ("remote", "tab:orange")) if have_fps else ():
            rs = [r for r in ok if r["config"].get("mode", "hybrid") == mode]
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
        fig.savefig(os.path.join(d, "plots", "frame_size_vs_fps.png"), dpi=110)
        plt.close(fig)
        out.append("## Plots\n")
        out.append("Red: the Pareto front (no other run of the scene is both cheaper and better).\n")
        out.append("![quality against bandwidth](plots/quality_vs_bandwidth.png)\n")
        out.append("![quality against server time](plots/quality_vs_server_time.png)\n")
        if have_fps:
            out.append("![frame size against delivered frame rate](plots/frame_size_vs_fps.png)\n")
        # SSIM per frame.
        if frames:
            scenes = sorted({r["scene"] for r in ok})
            fig, axes = plt.subplots(len(scenes), 1, figsize=(9, 3.2 * len(scenes)), squeeze=False)
            for ax, scene in zip(axes[:, 0], scenes):
                for r in [r for r in ok if r["scene"] == scene][:12]:
                    rows = [f for f in frames if f["run"] == r["id"] and f["ssim_local"] != ""]
                    ax.plot([int(f["frame"]) for f in rows], [float(f["ssim_local"]) for f in rows],
                            lw=1, label=f"{r['id']} {r['label']}"[:48])
                ax.set_title(f"{scene}: SSIM against the local reference, per displayed frame")
                ax.set_xlabel("frame")
                ax.set_ylabel("SSIM")
                ax.grid(alpha=0.3)
                ax.legend(fontsize=6, loc="lower left")
            fig.tight_layout()
            fig.savefig(os.path.join(d, "plots", "ssim_per_frame.png"), dpi=110)
            plt.close(fig)
            out.append("![SSIM per frame](plots/ssim_per_frame.png)\n")

    # Image grids.
    img_dir = os.path.join(d, "images")
    grids = []
    for scene in sorted({r["scene"] for r in ok}):
        rs = [r for r in ok if r["scene"] == scene and os.path.exists(os.path.join(img_dir, r["id"] + "_shown.png"))]
        for part in range(0, len(rs), MAX_RUNS_PER_GRID):
            chunk = rs[part:part + MAX_RUNS_PER_GRID]
            refs = []
            first = chunk[0]["id"]
            if os.path.exists(os.path.join(img_dir, first + "_truth.png")):
                refs.append(("ground truth", first + "_truth.png"))
            refs.append((f"local reference ({first})", first + "_local.png"))
            cols = max(len(chunk), len(refs))
            fig, axes = plt.subplots(3, cols, figsize=(3.2 * cols, 6.6), squeeze=False)
            for ax in axes.flat:
                ax.axis("off")
            for c, (title, name) in enumerate(refs):
                axes[0, c].imshow(mpimg.imread(os.path.join(img_dir, name)))
                axes[0, c].set_title(title, fontsize=8)
            im = None
            for c, r in enumerate(chunk):
                axes[1, c].imshow(mpimg.imread(os.path.join(img_dir, r["id"] + "_shown.png")))
                axes[1, c].set_title(f"{r['id']}: {r['label']}"[:44], fontsize=7)
                err = mpimg.imread(os.path.join(img_dir, r["id"] + "_error.png"))
                if err.ndim == 3:
                    err = err[..., 0]
                im = axes[2, c].imshow(err * ERROR_SCALE_LEVELS, cmap="viridis", vmin=0, vmax=ERROR_SCALE_LEVELS)
                axes[2, c].set_title(f"error vs {r.get('images', {}).get('error_against', 'reference')}", fontsize=7)
            if im is not None:
                fig.colorbar(im, ax=list(axes[2, :]), orientation="horizontal", fraction=0.05, pad=0.02,
                             label="|luma difference| (8-bit levels), one scale for every map")
            fig.suptitle(f"{scene}: last scored frame", fontsize=10)
            name = f"grid_{scene.replace('/', '_').replace('.json', '')}_{part // MAX_RUNS_PER_GRID}.png"
            fig.savefig(os.path.join(d, "grids", name), dpi=100)
            plt.close(fig)
            grids.append(name)
    if grids:
        out.append("## Image grids\n")
        out.append("Top: references. Middle: what the client displayed. Bottom: the error of each against the "
                   "ground truth where it was scored on that frame, else against the local reference, on one fixed "
                   f"colour scale (0..{ERROR_SCALE_LEVELS} levels of luma difference).\n")
        for g in grids:
            out.append(f"![{g}](grids/{g})\n")

    notes = exp.get("notes")
    if notes:
        out.append("## Notes\n")
        out.append(notes if isinstance(notes, str) else "\n".join(notes))
        out.append("")
    with open(os.path.join(d, "report.md"), "w") as f:
        f.write("\n".join(out) + "\n")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: report.py RESULTS_DIR")
    main(sys.argv[1])
