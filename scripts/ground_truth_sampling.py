#!/usr/bin/env python3
"""Random against lattice samples for the ground truth, scored against one reference.

For each scene, `dhrbench converge` renders the ground truth of a few frames three ways into one
cache folder: with independent uniforms at N AO rays and S rays per area light, with the lattice
(ground_truth_sampling "lattice") at N / 2 and S / 2, and the reference, independent uniforms
at 8 N and 8 S with another seed. Both candidates are scored against that same reference, so
its own noise adds the same amount to both. Prints each candidate's mean squared error per
8-bit channel (from PSNR: what the reference's noise adds is the same for both), SSIM and
FLIP, per scene, and writes every figure to OUT/ground_truth_sampling.json.

    scripts/ground_truth_sampling.py --width 320 --height 180 --ao-rays 128 --samples-per-light 32 \\
        --start 2.2 --duration 0.9 --out out/sampling room temple street living-room
(docs/architecture.md, "The references")
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "experiments"))
import dhrbench_results as dr  # noqa: E402


def converge(dhrbench, scene, args, sampling, ao_rays, spl, factor, out, cache):
    cmd = [dhrbench, "converge", "--scene", scene, "--width", str(args.width), "--height", str(args.height),
           "--start", str(args.start), "--duration", str(args.duration), "--frames", str(args.frames),
           "--ao-rays", str(ao_rays), "--samples-per-light", str(spl), "--factor", str(factor),
           "--sampling", sampling, "--large-sampling", "random", "--out", out]
    env = dict(os.environ, DHR_CACHE_DIR=cache)
    r = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        sys.exit(f"ground_truth_sampling: {' '.join(cmd)} failed:\n{r.stdout}")
    try:
        return dr.load_convergence_check(os.path.join(out, "convergence.json"))["scenes"][0]["summary"]
    except dr.BadResults as e:
        sys.exit(f"ground_truth_sampling: {e}")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenes", nargs="+")
    p.add_argument("--dhrbench", default="build/experiments/dhrbench")
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=180)
    p.add_argument("--ao-rays", type=int, default=128, help="N: the random candidate's AO rays (the lattice's: N / 2)")
    p.add_argument("--samples-per-light", type=int, default=32, help="S: the random candidate's rays per area light")
    p.add_argument("--start", type=float, default=1.0)
    p.add_argument("--duration", type=float, default=1.0)
    p.add_argument("--frames", type=int, default=3)
    p.add_argument("--out", required=True)
    args = p.parse_args()
    if args.ao_rays % 2 or args.samples_per_light % 2:
        sys.exit("ground_truth_sampling: --ao-rays and --samples-per-light must be even (the lattice takes half)")
    os.makedirs(args.out, exist_ok=True)
    n, s = args.ao_rays, args.samples_per_light
    rows = []
    print(f"{args.width}x{args.height}, {args.frames} frames from t = {args.start} s over {args.duration} s; "
          f"reference: random {8 * n} AO rays, {8 * s} per light")
    print(f"{'scene':<18} {'candidate':<22} {'MSE':>8} {'SSIM':>8} {'FLIP':>8}")
    for scene in args.scenes:
        with tempfile.TemporaryDirectory(prefix="dhr-sampling-") as cache:
            name = os.path.splitext(os.path.basename(scene))[0]
            for label, sampling, ao, spl, factor in (("random", "random", n, s, 8),
                                                     ("lattice", "lattice", n // 2, s // 2, 16)):
                out = os.path.join(args.out, f"{name}_{label}")
                summary = converge(args.dhrbench, scene, args, sampling, ao, spl, factor, out, cache)
                mse = 255.0 ** 2 * 10 ** (-summary["psnr_mean"] / 10)
                row = {"scene": scene, "sampling": sampling, "ao_rays": ao, "samples_per_light": spl,
                       "reference": {"sampling": "random", "ao_rays": 8 * n, "samples_per_light": 8 * s},
                       "mse": mse, **summary}
                rows.append(row)
                print(f"{name:<18} {f'{sampling} {ao}/{spl}':<22} {mse:8.4f} {summary['ssim_mean']:8.5f} "
                      f"{summary['flip_mean']:8.5f}", flush=True)
    with open(os.path.join(args.out, "ground_truth_sampling.json"), "w") as f:
        json.dump({"width": args.width, "height": args.height, "frames": args.frames, "start_s": args.start,
                   "duration_s": args.duration, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
