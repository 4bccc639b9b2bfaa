"""Rate-quality curves and Bjontegaard delta rate, for experiments/report.py.

A curve is the runs of one family (a configuration's "family", else its name) on one scene under
the same other settings, ordered by bitrate: the experiment's "curves": {"vary": [keys]} names
the settings that move along a curve (a codec's quality knob); every other swept setting (the
latency, the network) tells curves apart (docs/architecture.md, "Rate-quality curves").

BD-rate (Bjontegaard, "Calculation of average PSNR differences between RD-curves", VCEG-M33,
2001): fit log10(bitrate) of each curve as a polynomial in the quality (degree 3, lower when a
curve has fewer than 4 points), integrate both over the quality range the curves share, and
report 10^(mean difference) - 1 in percent: the bitrate the test family needs at equal quality,
relative to the anchor (negative: it needs less). Quality is normalised to the shared range
before fitting (a cubic in SSIM values near 1 is otherwise badly conditioned); the result does
not depend on that scale. Curves whose quality ranges do not overlap have no BD-rate: an error,
not a number.

BD-quality (the same paper's BD-PSNR, on any metric) is the comparison at equal bandwidth: the
mean quality difference over the bitrate range both curves share.
"""
import math

import numpy as np


class NoOverlap(ValueError):
    """The two curves share no quality range."""


def _fit(quality, log_rate, lo, hi, degree):
    x = (np.asarray(quality, dtype=float) - lo) / (hi - lo)
    return np.polyfit(x, np.asarray(log_rate, dtype=float), degree)


def bd_rate(anchor, test):
    """Bjontegaard delta rate of `test` against `anchor`, in percent. Each curve is a list of
    (bitrate, quality) pairs, bitrate > 0, at least 2 points with distinct qualities."""
    curves = []
    for name, curve in (("anchor", anchor), ("test", test)):
        pts = [(float(r), float(q)) for r, q in curve]
        if len(pts) < 2:
            raise ValueError(f"the {name} curve has {len(pts)} point(s); BD-rate needs at least 2")
        if any(not (r > 0 and math.isfinite(r)) or not math.isfinite(q) for r, q in pts):
            raise ValueError(f"the {name} curve has a bitrate <= 0 or a value that is not finite: {pts}")
        if len({q for _, q in pts}) < 2:
            raise ValueError(f"the {name} curve's points all have the same quality {pts[0][1]}")
        curves.append(pts)
    lo = max(min(q for _, q in c) for c in curves)
    hi = min(max(q for _, q in c) for c in curves)
    if not hi > lo:
        raise NoOverlap(f"the quality ranges do not overlap (anchor {min(q for _, q in curves[0]):.4g}.."
                        f"{max(q for _, q in curves[0]):.4g}, test {min(q for _, q in curves[1]):.4g}.."
                        f"{max(q for _, q in curves[1]):.4g})")
    # Normalise on the union of both ranges, so that both fits use the same scale.
    ulo = min(min(q for _, q in c) for c in curves)
    uhi = max(max(q for _, q in c) for c in curves)
    integrals = []
    for pts in curves:
        degree = min(3, len({q for _, q in pts}) - 1)
        p = _fit([q for _, q in pts], [math.log10(r) for r, _ in pts], ulo, uhi, degree)
        P = np.polyint(p)
        a, b = (lo - ulo) / (uhi - ulo), (hi - ulo) / (uhi - ulo)
        integrals.append((np.polyval(P, b) - np.polyval(P, a)) / (b - a))
    return (10.0 ** (integrals[1] - integrals[0]) - 1.0) * 100.0


def bd_quality(anchor, test):
    """Bjontegaard delta quality of `test` against `anchor` (VCEG-M33's BD-PSNR, on any quality
    metric): fit each curve's quality as a polynomial in log10(bitrate), integrate both over the
    log-bitrate range the curves share, and report the mean difference, test - anchor, in the
    metric's own units: the quality the test family gives at equal bandwidth (positive: more).
    Curves as in bd_rate; curves whose bitrate ranges do not overlap are an error (NoOverlap)."""
    curves = []
    for name, curve in (("anchor", anchor), ("test", test)):
        pts = [(float(r), float(q)) for r, q in curve]
        if len(pts) < 2:
            raise ValueError(f"the {name} curve has {len(pts)} point(s); BD-quality needs at least 2")
        if any(not (r > 0 and math.isfinite(r)) or not math.isfinite(q) for r, q in pts):
            raise ValueError(f"the {name} curve has a bitrate <= 0 or a value that is not finite: {pts}")
        if len({r for r, _ in pts}) < 2:
            raise ValueError(f"the {name} curve's points all have the same bitrate {pts[0][0]}")
        curves.append([(math.log10(r), q) for r, q in pts])
    lo = max(min(x for x, _ in c) for c in curves)
    hi = min(max(x for x, _ in c) for c in curves)
    if not hi > lo:
        raise NoOverlap(f"the bitrate ranges do not overlap (anchor {10 ** min(x for x, _ in curves[0]):.4g}.."
                        f"{10 ** max(x for x, _ in curves[0]):.4g}, test {10 ** min(x for x, _ in curves[1]):.4g}.."
                        f"{10 ** max(x for x, _ in curves[1]):.4g} Mb/s)")
    ulo = min(min(x for x, _ in c) for c in curves)
    uhi = max(max(x for x, _ in c) for c in curves)
    means = []
    for pts in curves:
        degree = min(3, len({x for x, _ in pts}) - 1)
        p = _fit([x for x, _ in pts], [q for _, q in pts], ulo, uhi, degree)
        P = np.polyint(p)
        a, b = (lo - ulo) / (uhi - ulo), (hi - ulo) / (uhi - ulo)
        means.append((np.polyval(P, b) - np.polyval(P, a)) / (b - a))
    return float(means[1] - means[0])


def family_of(run):
    return run.get("family") or run.get("configuration") or run.get("label", "")


def curves(runs, sweep_keys, vary, rate, quality):
    """Groups runs into curves: {(scene, conditions, family): [(rate, quality, run), ...] sorted by
    rate}. `conditions` is a tuple of (key, value) of the swept settings not in `vary`; `rate` and
    `quality` are functions of a run (None: the run has no such figure and is left out)."""
    out = {}
    for r in runs:
        settings = r.get("settings", {})
        cond = tuple((k, str(settings[k])) for k in sweep_keys if k in settings and k not in vary)
        x, y = rate(r), quality(r)
        if x is None or y is None:
            continue
        out.setdefault((r["scene"], cond, family_of(r)), []).append((x, y, r))
    for pts in out.values():
        pts.sort(key=lambda p: p[0])
    return out


def bd_table(curve_map, anchor, measure=bd_rate):
    """Per (scene, conditions), `measure` (bd_rate: percent; bd_quality: quality units) of every
    other family against `anchor`: {(scene, conditions): {family: value or the reason there is none}}."""
    table = {}
    groups = sorted({(s, c) for s, c, _ in curve_map})
    for scene, cond in groups:
        fams = {f: pts for (s, c, f), pts in curve_map.items() if s == scene and c == cond}
        if anchor not in fams:
            continue
        row = {}
        for fam, pts in sorted(fams.items()):
            if fam == anchor:
                continue
            try:
                row[fam] = measure([(x, y) for x, y, _ in fams[anchor]], [(x, y) for x, y, _ in pts])
            except ValueError as e:
                row[fam] = str(e)
        table[(scene, cond)] = row
    return table
