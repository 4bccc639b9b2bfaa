#!/usr/bin/env python3
"""Groups a perf profile of `dhrbench run` by pipeline stage: the time budget of docs/performance.md.

Usage:
  perf record -F 499 -g -o perf.data -- build/experiments/dhrbench run EXP --out OUT [--set ...]
  perf report -i perf.data --stdio --no-children --sort dso,symbol -g none --percent-limit 0.01 > perf.txt
  scripts/perf_budget.py perf.txt [--cpu-s SECONDS]

Each sampled symbol (self time, children not included) is put in the first stage whose pattern
matches "library symbol" (STAGES, in order; "other" takes the rest). Embree's library is stripped
on Debian, so all its time (traversal and BVH builds) is one line. With --cpu-s (the run's CPU time, user + sys)
the shares are also given in seconds. The groups are by function name, so they are approximate
where a function serves two stages (a memcpy, a TBB scheduler loop): those land in "runtime".
"""
import argparse
import re
import sys

# (stage, regular expression on the symbol). First match wins.
STAGES = [
    ("trace: Embree (traversal, BVH builds)", r"^libembree"),
    ("trace: shadow pass (surfaces, lights, packets)", r"visibility_rows|sphere_light|distant_light|trace_pairs|surfaces_x|soft_pair_rays|update_triangle|triangle_world|light_infos|visibility_impl|pack_visibility|visibility_to_planes|uniforms_pixels"),
    ("trace: AO pass (ray generation)", r"ao_rays_|ao_rows|ao_impl|trace_ao"),
    ("denoise (svgf_ao: temporal, moments, a-trous)", r"denoise::|atrous|svgf|Svgf|moment|accumulate_row|guide_"),
    ("metrics: FLIP", r"flip|Flip|filter_column|filter_row|weighted_rows|lab_f_row|horizontal_pass|vertical_row|RowScratch|magnitude_row|colour_row|lab_row|__powf|powf|pow_row|hyab_rows|error_terms"),
    ("metrics: SSIM, PSNR, temporal", r"ssim|Ssim|psnr|temporal_scores|step_terms|dhr::luma|luma_pixels|difference_sums"),
    ("rasterize (client and server)", r"dhr::rasterize|resolve|cover|setup_triangles|sample_bilinear|Texture|raster|pixel_bounds|alpha_cutout"),
    ("composite and tone mapping", r"composite|shade_lambert|shade_row|gbuffer_row|tonemap|srgb8"),
    ("predict (reprojection, colour warps)", r"Reprojection|reproject|plan_x16|write_x16|Predictor|[Ww]arp"),
    ("codecs", r"^liblz4|^libzstd|^libx26|^libav|^libsw|^libaom|^libdav1d|LZ4|ZSTD|Codec"),
    ("packets, network, assembler", r"packet|Packet|assembl|Assembl|crc32|update_hardware|Link::|network"),
    ("report (report.py, plots) and image files", r"^python|^_multiarray|^_imaging|^_image|^_backend|^libz\.|^libpng|^libjpeg|^libOpenImageIO|write_png|downscale|png"),
    ("scene loading", r"^libassimp|scene_load|mesh_import"),
    ("kernel (page faults, zeroing fresh memory)", r"^\[kernel"),
    ("runtime (TBB, allocation, copies)", r"^libtbb|^libc\.|^libstdc|^ld-linux|tbb::|memcpy|memset|memmove|malloc|operator new|Hasher::"),
]

LINE = re.compile(r"^\s*([0-9.]+)%\s+(.*\S)\s*$")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("report", help="output of perf report --stdio --no-children --sort symbol")
    ap.add_argument("--cpu-s", type=float, default=0.0, help="the run's CPU time (user + sys), to state shares in CPU seconds")
    a = ap.parse_args()
    totals = {name: 0.0 for name, _ in STAGES}
    totals["other"] = 0.0
    compiled = [(name, re.compile(rx)) for name, rx in STAGES]
    seen = 0.0
    with open(a.report) as f:
        for line in f:
            if line.startswith("#"):
                continue
            m = LINE.match(line)
            if not m:
                continue
            pct = float(m.group(1))
            sym = re.sub(r"\s\[[.kHg]\]\s", " ", m.group(2))
            for name, rx in compiled:
                if rx.search(sym):
                    totals[name] += pct
                    break
            else:
                totals["other"] += pct
            seen += pct
    if seen <= 0:
        sys.exit(f"perf_budget: no samples found in {a.report} (was it written with --stdio --sort symbol?)")
    print(f"| stage | share of samples |{' CPU seconds |' if a.cpu_s else ''}")
    print(f"|---|---:|{'---:|' if a.cpu_s else ''}")
    for name, pct in sorted(totals.items(), key=lambda kv: -kv[1]):
        share = pct / seen
        sec = f" {share * a.cpu_s:.0f} |" if a.cpu_s else ""
        print(f"| {name} | {100 * share:.1f} % |{sec}")
    print(f"\n(samples covered: {seen:.1f} % of the profile)")


if __name__ == "__main__":
    main()
