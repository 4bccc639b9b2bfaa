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


def _points(name, curve, measure, distinct_index, distinct_name):
    """The curve's (bitrate, quality) pairs, checked: at least 2, bitrates > 0, all finite, and at
    least two distinct values at `distinct_index` (what the fit is a function of)."""
    pts = [(float(r), float(q)) for r, q in curve]
    if len(pts) < 2:
        raise ValueError(f"the {name} curve has {len(pts)} point(s); {measure} needs at least 2")
    if any(not (r > 0 and math.isfinite(r)) or not math.isfinite(q) for r, q in pts):
        raise ValueError(f"the {name} curve has a bitrate <= 0 or a value that is not finite: {pts}")
    if len({p[distinct_index] for p in pts}) < 2:
        raise ValueError(f"the {name} curve's points all have the same {distinct_name} {pts[0][distinct_index]}")
    return pts


def _mean_gap(anchor, test, what, show=lambda x: x, unit=""):
    """Fits y as a polynomial in x for each curve (lists of (x, y); degree 3, lower with fewer
    distinct x), and returns the test curve's mean y minus the anchor's over the x range both
    share. x is normalised to the union of both ranges first (the result does not depend on it).
    NoOverlap names `what` and the ranges (x shown through `show`, then `unit`)."""
    curves = [anchor, test]
    lo = max(min(x for x, _ in c) for c in curves)
    hi = min(max(x for x, _ in c) for c in curves)
    if not hi > lo:
        span = [f"{show(min(x for x, _ in c)):.4g}..{show(max(x for x, _ in c)):.4g}" for c in curves]
        raise NoOverlap(f"the {what} ranges do not overlap (anchor {span[0]}, test {span[1]}{unit})")
    ulo = min(min(x for x, _ in c) for c in curves)
    uhi = max(max(x for x, _ in c) for c in curves)
    means = []
    for pts in curves:
        degree = min(3, len({x for x, _ in pts}) - 1)
        x = (np.asarray([x for x, _ in pts], dtype=float) - ulo) / (uhi - ulo)
        P = np.polyint(np.polyfit(x, np.asarray([y for _, y in pts], dtype=float), degree))
        a, b = (lo - ulo) / (uhi - ulo), (hi - ulo) / (uhi - ulo)
        means.append((np.polyval(P, b) - np.polyval(P, a)) / (b - a))
    return float(means[1] - means[0])


def bd_rate(anchor, test):
    """Bjontegaard delta rate of `test` against `anchor`, in percent. Each curve is a list of
    (bitrate, quality) pairs, bitrate > 0, at least 2 points with distinct qualities."""
    a, t = (_points(n, c, "BD-rate", 1, "quality") for n, c in (("anchor", anchor), ("test", test)))
    gap = _mean_gap([(q, math.log10(r)) for r, q in a], [(q, math.log10(r)) for r, q in t], "quality")
    return (10.0 ** gap - 1.0) * 100.0


def bd_quality(anchor, test):
    """Bjontegaard delta quality of `test` against `anchor` (VCEG-M33's BD-PSNR, on any quality
    metric): fit each curve's quality as a polynomial in log10(bitrate), integrate both over the
    log-bitrate range the curves share, and report the mean difference, test - anchor, in the
    metric's own units: the quality the test family gives at equal bandwidth (positive: more).
    Curves as in bd_rate but with distinct bitrates; curves whose bitrate ranges do not overlap
    are an error (NoOverlap)."""
    a, t = (_points(n, c, "BD-quality", 0, "bitrate") for n, c in (("anchor", anchor), ("test", test)))
    return _mean_gap([(math.log10(r), q) for r, q in a], [(math.log10(r), q) for r, q in t], "bitrate",
                     lambda x: 10.0 ** x, " Mb/s")


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


def beats(test, other, higher_is_better=True):
    """Does the `test` curve beat the `other` one (lists of (bitrate, quality))? Where their
    quality ranges overlap: it needs less bitrate at equal quality (BD-rate < 0). Where they do
    not: its whole quality range lies on the better side and its cheapest point costs no more than
    the other's dearest (better quality at a bitrate the other also spends). None when that cannot
    be told (a curve too short to fit, or better quality only at a higher bitrate than any of the
    other's)."""
    try:
        return bd_rate(other, test) < 0.0
    except NoOverlap:
        tq, oq = [q for _, q in test], [q for _, q in other]
        above = min(tq) > max(oq) if higher_is_better else max(tq) < min(oq)
        below = max(tq) < min(oq) if higher_is_better else min(tq) > max(oq)
        if below:
            return False
        if above and min(r for r, _ in test) <= max(r for r, _ in other):
            return True
        return None
    except ValueError:
        return None


def crossover(curve_map, is_remote, rtt_of, latency_key="network", higher_is_better=True):
    """Where hybrid starts to win, per scene (and other conditions than `latency_key`): for every
    hybrid family, the smallest round-trip time from which on, at every measured RTT, it beats
    (beats()) every remote family measured there. `is_remote(family)` tells the sides apart;
    `rtt_of(value)` gives the RTT in ms of a `latency_key` value, or None (a trace: left out).
    Returns {(scene, other conditions): {"rtts": [...], "families": {family: RTT or None (it does
    not win at the largest RTT)}, "wins": {family: {rtt: True/False/None}}}}."""
    groups = {}
    for (scene, cond, fam), pts in curve_map.items():
        lat = dict(cond).get(latency_key)
        rtt = rtt_of(lat) if lat is not None else None
        if rtt is None:
            continue
        rest = tuple((k, v) for k, v in cond if k != latency_key)
        groups.setdefault((scene, rest), {}).setdefault(rtt, {})[fam] = [(x, y) for x, y, *_ in pts]
    out = {}
    for key, by_rtt in sorted(groups.items()):
        rtts = sorted(by_rtt)
        hybrids = sorted({f for fams in by_rtt.values() for f in fams if not is_remote(f)})
        wins = {}
        for h in hybrids:
            wins[h] = {}
            for rtt in rtts:
                fams = by_rtt[rtt]
                remotes = [f for f in fams if is_remote(f)]
                if h not in fams or not remotes:
                    wins[h][rtt] = None
                    continue
                results = [beats(fams[h], fams[r], higher_is_better) for r in remotes]
                wins[h][rtt] = False if False in results else (None if None in results else True)
        families = {}
        for h in hybrids:
            start = None
            for rtt in reversed(rtts):
                if wins[h][rtt] is True:
                    start = rtt
                else:
                    break
            families[h] = start
        out[key] = {"rtts": rtts, "families": families, "wins": wins}
    return out
