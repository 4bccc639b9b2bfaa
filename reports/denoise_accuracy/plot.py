#!/usr/bin/python3
"""Plot and Pareto front of the denoiser accuracy-versus-time table.

Input: the CSV written by `bench_denoise --accuracy --csv=PATH` (one row per scene, AO rays,
denoiser, frame of history: SSIM and MAE against converged AO, trace / denoise / total ms).
Output: accuracy.png beside the CSV (SSIM against total ms per scene, log x, one line per
denoiser; solid = frame 8 of a static camera, dashed = frame 1, no history), and on stdout the
Pareto front per scene and frame of history: the (rays, denoiser) points that no other point
beats in both time (lower total_ms) and SSIM (higher), fastest first, as a Markdown list.

Usage: /usr/bin/python3 reports/denoise_accuracy/plot.py [reports/denoise_accuracy/accuracy.csv]
"""
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

DENOISERS = ["none", "single_iteration", "atrous", "svgf_ao"]
COLOURS = {"none": "tab:gray", "single_iteration": "tab:blue", "atrous": "tab:orange", "svgf_ao": "tab:green"}


def read_rows(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for k in ("rays", "frame_of_history", "width", "height", "reference_rays", "threads"):
            r[k] = int(r[k])
        for k in ("ssim", "mae_levels", "trace_ms", "denoise_ms", "total_ms"):
            r[k] = float(r[k])
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


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    path = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "accuracy.csv")
    rows = read_rows(path)
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    cols = min(4, len(scenes))
    nrows = math.ceil(len(scenes) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.6 * nrows), squeeze=False)
    for k, scene in enumerate(scenes):
        ax = axes[k // cols][k % cols]
        for d in DENOISERS:
            for frame, style in ((8, "-"), (1, "--")):
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
                if frame == 8:
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
    fig.suptitle("AO accuracy against time: rays {1..64} x denoiser (numbers: rays; solid: frame 8 of a "
                 "static camera, dashed: frame 1)", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 0.97))
    out = os.path.join(os.path.dirname(os.path.abspath(path)), "accuracy.png")
    fig.savefig(out, dpi=110)
    print(f"wrote {out}", file=sys.stderr)

    for frame in (1, 8):
        print(f"\n### Pareto front, frame {frame} ({'no history' if frame == 1 else 'static camera, 8 frames of history'})\n")
        for scene in scenes:
            pts = [r for r in rows if r["scene"] == scene and r["frame_of_history"] == frame]
            front = pareto(pts)
            items = ", ".join(f"{p['rays']} {p['denoiser']} ({p['total_ms']:.0f} ms, {p['ssim']:.3f})" for p in front)
            print(f"- **{scene}**: {items}")


if __name__ == "__main__":
    main()
