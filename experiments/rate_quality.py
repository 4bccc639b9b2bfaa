"""Rate-quality curves and Bjontegaard deltas (BD-rate, BD-quality), for experiments/report.py.

A curve is the runs of one family (a configuration's "family", else its name) on one scene under
the same other settings, ordered by bitrate: the experiment's "curves": {"vary": [keys]} names
the settings that move along a curve (a codec's quality knob); every other swept setting (the
latency, the network) tells curves apart (docs/architecture.md, "Rate-quality curves").

BD-rate (Bjontegaard, "Calculation of average PSNR differences between RD-curves", VCEG-M33,
2001): interpolate log10(bitrate) of each curve as a function of the quality, integrate both over
the quality range the curves share, and report 10^(mean difference) - 1 in percent: the bitrate
the test family needs at equal quality, relative to the anchor (negative: it needs less).
BD-quality (the same paper's BD-PSNR, on any metric) is the comparison at equal bandwidth: the
mean quality difference over the log-bitrate range both curves share, quality interpolated as a
function of log10(bitrate). Curves whose ranges do not overlap have no delta: an error
(NoOverlap), not a number.

How the points are joined (`method=`):
  - "pchip" (the default): piecewise cubic Hermite interpolation with Fritsch-Carlson monotone
    slopes (the weighted harmonic mean of the neighbouring secants inside, zero at a local
    extremum; the three-point shape-preserving formula at the ends, as MATLAB's pchip and
    scipy.interpolate.PchipInterpolator), integrated exactly. This is the JCT-VC/JVET common test
    conditions' spreadsheet method (JCTVC-L1100, JVET-T2010) and the `bjontegaard` package's
    default 'pchip'. It never overshoots the points, so a monotone curve stays monotone.
  - "akima": Akima's (1970) slopes (the end slopes from two extrapolated secants, as
    scipy.interpolate.Akima1DInterpolator), integrated exactly; Herglotz et al. (ICIP 2022,
    arXiv:2202.12565) found it closest to intermediate points.
  - "polynomial": VCEG-M33's single fit, degree 3 (lower with fewer than 4 points): with 4 points
    it passes through them exactly and may swing between them. The abscissa is normalised to the
    union of both ranges before fitting (a cubic in SSIM values near 1 is otherwise badly
    conditioned); the result does not depend on that scale.
With two points every method is the straight line through them.

bd_checked() is what the report uses: the value of one method plus flags that say how far to
trust it (a curve that is not monotonic has no number; the methods disagreeing, or fewer than 4
points per curve, keep the number but are flagged).
"""
import math
from typing import NamedTuple

import numpy as np

METHODS = ("pchip", "akima", "polynomial")
METHOD_NAMES = {"pchip": "PCHIP", "akima": "Akima", "polynomial": "polynomial"}
CTC_POINTS = 4          # VCEG-M33 and the common test conditions use 4 points per curve
RATE_TOLERANCE_PP = 5.0  # BD-rate: the methods may differ by this many percentage points
QUALITY_TOLERANCE = 0.05  # BD-quality: ... by this share of the quality span of both curves


class NoOverlap(ValueError):
    """The two curves share no quality (BD-rate) or bitrate (BD-quality) range."""


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


# --- Piecewise cubic Hermite interpolation, integrated exactly --------------------------------

def _sorted_xy(pts, what):
    """x and y arrays sorted by x; two points at the same x are an error (no function of x)."""
    pts = sorted(pts)
    x = np.array([p[0] for p in pts], dtype=float)
    y = np.array([p[1] for p in pts], dtype=float)
    if np.any(np.diff(x) <= 0):
        i = int(np.argmax(np.diff(x) <= 0))
        raise ValueError(f"two points share the {what} {x[i]:.6g}: the curve is no function of it")
    return x, y


def pchip_slopes(x, y):
    """Fritsch-Carlson monotone slopes at the points (x increasing): inside, 0 where the secants
    on either side differ in sign or one is 0, else their weighted harmonic mean (weights 2h_k +
    h_{k-1} and h_k + 2h_{k-1}, Fritsch and Butland 1984, as MATLAB's pchip); at each end the
    three-point formula, set to 0 where its sign differs from the end secant and limited to 3
    times that secant where the first two secants differ in sign. Two points: the secant."""
    h = np.diff(x)
    m = np.diff(y) / h
    n = len(x)
    if n == 2:
        return np.array([m[0], m[0]])
    d = np.zeros(n)
    for k in range(1, n - 1):
        if m[k - 1] * m[k] > 0:
            w1, w2 = 2 * h[k] + h[k - 1], h[k] + 2 * h[k - 1]
            d[k] = (w1 + w2) / (w1 / m[k - 1] + w2 / m[k])

    def end(h0, h1, m0, m1):
        e = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
        if np.sign(e) != np.sign(m0):
            return 0.0
        if np.sign(m0) != np.sign(m1) and abs(e) > 3 * abs(m0):
            return 3 * m0
        return e

    d[0] = end(h[0], h[1], m[0], m[1])
    d[-1] = end(h[-1], h[-2], m[-1], m[-2])
    return d


def akima_slopes(x, y):
    """Akima's slopes: at point i the average of the secants m_{i-1} and m_i weighted by
    |m_{i+1} - m_i| and |m_{i-1} - m_{i-2}| (their plain mean where both weights are 0), with two
    secants extrapolated linearly beyond each end (m_{-1} = 2 m_0 - m_1, m_{-2} = 3 m_0 - 2 m_1).
    Two points: the secant."""
    m = np.diff(y) / np.diff(x)
    if len(x) == 2:
        return np.array([m[0], m[0]])
    ext = np.concatenate([[3 * m[0] - 2 * m[1], 2 * m[0] - m[1]], m, [2 * m[-1] - m[-2], 3 * m[-1] - 2 * m[-2]]])
    dm = np.abs(np.diff(ext))
    f1, f2 = dm[2:], dm[:-2]   # |m_{i+1} - m_i|, |m_{i-1} - m_{i-2}|
    left, right = ext[1:-2], ext[2:-1]  # m_{i-1}, m_i
    den = f1 + f2
    scale = max(float(np.max(np.abs(ext))), 1e-300)
    flat = den <= 1e-9 * scale
    return np.where(flat, 0.5 * (left + right), (f1 * left + f2 * right) / np.where(flat, 1.0, den))


def _hermite_antiderivative(x, y, d, t):
    """The integral from x[0] to t (x[0] <= t <= x[-1]) of the cubic Hermite interpolant through
    (x, y) with slopes d."""
    k = min(max(int(np.searchsorted(x, t, side="right")) - 1, 0), len(x) - 2)
    h = np.diff(x)
    # Whole segments before k: h (y_k + y_k+1) / 2 + h^2 (d_k - d_k+1) / 12.
    whole = float(np.sum(h[:k] * (y[:k] + y[1:k + 1]) / 2 + h[:k] ** 2 * (d[:k] - d[1:k + 1]) / 12))
    s = (t - x[k]) / h[k]
    # Integrals from 0 to s of the Hermite basis h00, h10, h01, h11.
    i00 = s ** 4 / 2 - s ** 3 + s
    i10 = s ** 4 / 4 - 2 * s ** 3 / 3 + s ** 2 / 2
    i01 = -s ** 4 / 2 + s ** 3
    i11 = s ** 4 / 4 - s ** 3 / 3
    part = h[k] * (y[k] * i00 + h[k] * d[k] * i10 + y[k + 1] * i01 + h[k] * d[k + 1] * i11)
    return whole + float(part)


def _mean_over(pts, lo, hi, method, ulo, uhi, what):
    """The mean of the curve (list of (x, y)) joined by `method` over [lo, hi], inside its range."""
    if method == "polynomial":
        degree = min(3, len({x for x, _ in pts}) - 1)
        x = (np.asarray([x for x, _ in pts], dtype=float) - ulo) / (uhi - ulo)
        P = np.polyint(np.polyfit(x, np.asarray([y for _, y in pts], dtype=float), degree))
        a, b = (lo - ulo) / (uhi - ulo), (hi - ulo) / (uhi - ulo)
        return float((np.polyval(P, b) - np.polyval(P, a)) / (b - a))
    x, y = _sorted_xy(pts, what)
    d = pchip_slopes(x, y) if method == "pchip" else akima_slopes(x, y)
    return (_hermite_antiderivative(x, y, d, hi) - _hermite_antiderivative(x, y, d, lo)) / (hi - lo)


def interpolate(pts, t, method="pchip"):
    """The curve (list of (x, y)) joined by `method` ("pchip" or "akima") evaluated at t, which
    must lie within the curve's x range (no extrapolation: ValueError)."""
    x, y = _sorted_xy(pts, "abscissa")
    if not x[0] <= t <= x[-1]:
        raise ValueError(f"{t} lies outside the curve's range {x[0]}..{x[-1]}")
    d = pchip_slopes(x, y) if method == "pchip" else akima_slopes(x, y)
    k = min(max(int(np.searchsorted(x, t, side="right")) - 1, 0), len(x) - 2)
    h = x[k + 1] - x[k]
    s = (t - x[k]) / h
    return float(y[k] * (2 * s ** 3 - 3 * s ** 2 + 1) + h * d[k] * (s ** 3 - 2 * s ** 2 + s)
                 + y[k + 1] * (-2 * s ** 3 + 3 * s ** 2) + h * d[k + 1] * (s ** 3 - s ** 2))


def _mean_gap(anchor, test, what, show=lambda x: x, unit="", method="pchip"):
    """The test curve's mean y minus the anchor's over the x range both share (curves: lists of
    (x, y)). NoOverlap names `what` and the ranges (x shown through `show`, then `unit`)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    curves = [anchor, test]
    lo = max(min(x for x, _ in c) for c in curves)
    hi = min(max(x for x, _ in c) for c in curves)
    if not hi > lo:
        span = [f"{show(min(x for x, _ in c)):.4g}..{show(max(x for x, _ in c)):.4g}" for c in curves]
        raise NoOverlap(f"the {what} ranges do not overlap (anchor {span[0]}, test {span[1]}{unit})")
    ulo = min(min(x for x, _ in c) for c in curves)
    uhi = max(max(x for x, _ in c) for c in curves)
    means = [_mean_over(pts, lo, hi, method, ulo, uhi, what) for pts in curves]
    return float(means[1] - means[0])


def bd_rate(anchor, test, method="pchip"):
    """Bjontegaard delta rate of `test` against `anchor`, in percent. Each curve is a list of
    (bitrate, quality) pairs, bitrate > 0, at least 2 points with distinct qualities (for "pchip"
    and "akima" no two points may share a quality). No check of monotonicity: bd_checked."""
    a, t = (_points(n, c, "BD-rate", 1, "quality") for n, c in (("anchor", anchor), ("test", test)))
    gap = _mean_gap([(q, math.log10(r)) for r, q in a], [(q, math.log10(r)) for r, q in t], "quality",
                    method=method)
    return (10.0 ** gap - 1.0) * 100.0


def bd_quality(anchor, test, method="pchip"):
    """Bjontegaard delta quality of `test` against `anchor` (VCEG-M33's BD-PSNR, on any quality
    metric): each curve's quality as a function of log10(bitrate), integrated over the
    log-bitrate range the curves share; the mean difference, test - anchor, in the metric's own
    units: the quality the test family gives at equal bandwidth (positive: more). Curves as in
    bd_rate but with distinct bitrates; curves whose bitrate ranges do not overlap are an error
    (NoOverlap)."""
    a, t = (_points(n, c, "BD-quality", 0, "bitrate") for n, c in (("anchor", anchor), ("test", test)))
    return _mean_gap([(math.log10(r), q) for r, q in a], [(math.log10(r), q) for r, q in t], "bitrate",
                     lambda x: 10.0 ** x, " Mb/s", method=method)


# --- The checked entry point -------------------------------------------------------------------

class BdResult(NamedTuple):
    """What bd_checked found. `value`: the delta by `method` (None: no number, `reason` says
    why); `flags`: {flag: sentence} for a number to read with care ("methods_disagree",
    "few_points"); `by_method`: every method's value (where it has one); `no_overlap`: the
    curves share no range (the reason then says which ranges)."""
    value: object
    reason: object = None
    flags: dict = {}
    by_method: dict = {}
    no_overlap: bool = False


def monotonic_problem(name, curve, higher_is_better=True, strict=True, unit=" Mb/s"):
    """None when the curve (list of (bitrate, quality)) rises in quality with bitrate (falls,
    for a metric where lower is better): strictly with `strict`, else never the wrong way and no
    two points at one bitrate. Else a sentence naming the curve and the first place it does not."""
    pts = sorted((float(r), float(q)) for r, q in curve)
    for (r0, q0), (r1, q1) in zip(pts, pts[1:]):
        step = (q1 - q0) if higher_is_better else (q0 - q1)
        if r1 == r0 or step < 0 or (strict and step == 0):
            word = "rises" if higher_is_better else "falls"
            change = ("stays" if step == 0 else ("falls" if higher_is_better else "rises"))
            return (f"the {name} curve is not monotonic: quality {change} from {q0:.6g} at {r0:.4g}{unit} to "
                    f"{q1:.6g} at {r1:.4g}{unit} (it must {word.rstrip('s')} with bitrate)")
    return None


def bd_checked(anchor, test, measure="rate", method="pchip", higher_is_better=True):
    """BD-rate (`measure` "rate", percent) or BD-quality ("quality", the metric's units) of `test`
    against `anchor` with how far to trust it (BdResult):
      - a curve that is not monotonic (quality must rise with rate; fall, for a metric where
        lower is better; strictly for BD-rate, whose abscissa is the quality): no number, and the
        reason names the curve and where;
      - the PCHIP, Akima and polynomial values differ in sign, or by more than 5 percentage points
        (BD-rate) or 5 % of the quality span of both curves (BD-quality): flag "methods_disagree";
      - fewer than 4 points in a curve (VCEG-M33 and the common test conditions use 4): flag
        "few_points".
    Curves that share no range, or are too short or damaged for `measure`, have no number either
    (reason; no_overlap set for the former)."""
    if measure not in ("rate", "quality"):
        raise ValueError(f"unknown measure {measure!r} (rate or quality)")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    fn = bd_rate if measure == "rate" else bd_quality
    for name, c in (("anchor", anchor), ("test", test)):
        problem = monotonic_problem(name, c, higher_is_better, strict=(measure == "rate"))
        if problem:
            return BdResult(None, problem)
    by_method = {}
    for m in METHODS:
        try:
            by_method[m] = fn(anchor, test, m)
        except NoOverlap as e:
            return BdResult(None, str(e), no_overlap=True)
        except ValueError as e:
            if m == method:
                return BdResult(None, str(e))
    value = by_method[method]
    flags = {}
    vals = list(by_method.values())
    if measure == "rate":
        tol, tol_text = RATE_TOLERANCE_PP, f"{RATE_TOLERANCE_PP:g} percentage points"
        show = lambda v: f"{v:+.1f} %"  # noqa: E731
    else:
        qs = [float(q) for _, q in list(anchor) + list(test)]
        tol = QUALITY_TOLERANCE * (max(qs) - min(qs))
        tol_text = f"{QUALITY_TOLERANCE * 100:g} % of both curves' quality span ({tol:.3g})"
        show = lambda v: f"{v:+.4g}"  # noqa: E731
    opposite = any(v > 0 for v in vals) and any(v < 0 for v in vals)
    spread = max(vals) - min(vals)
    if opposite or spread > tol:
        listed = ", ".join(f"{METHOD_NAMES[m]} {show(v)}" for m, v in by_method.items())
        why = "differ in sign" if opposite else f"differ by more than {tol_text}"
        flags["methods_disagree"] = f"the fits {why}: {listed}"
    few = {name: len(c) for name, c in (("anchor", anchor), ("test", test)) if len(c) < CTC_POINTS}
    if few:
        flags["few_points"] = (", ".join(f"the {n} curve has {k} points" for n, k in few.items())
                               + f" (VCEG-M33 and the common test conditions use {CTC_POINTS})")
    return BdResult(value, None, flags, by_method)


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


def bd_table(curve_map, anchor, measure="rate", method="pchip", higher_is_better=True):
    """Per (scene, conditions), bd_checked() of every other family against `anchor`: `measure`
    "rate" (BD-rate, percent) or "quality" (BD-quality, quality units; bd_rate and bd_quality
    name them too). Returns {(scene, conditions): {family: BdResult}}."""
    measure = {bd_rate: "rate", bd_quality: "quality"}.get(measure, measure)
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
            row[fam] = bd_checked([(x, y) for x, y, *_ in fams[anchor]], [(x, y) for x, y, *_ in pts],
                                  measure, method, higher_is_better)
        table[(scene, cond)] = row
    return table


def beats(test, other, higher_is_better=True, method="pchip"):
    """Does the `test` curve beat the `other` one (lists of (bitrate, quality))? Where their
    quality ranges overlap: it needs less bitrate at equal quality (BD-rate < 0, bd_checked; its
    flags do not change the answer). Where they do not: its whole quality range lies on the
    better side and its cheapest point costs no more than the other's dearest (better quality at
    a bitrate the other also spends). None when that cannot be told (a curve that is not
    monotonic or too short, or better quality only at a higher bitrate than any of the other's)."""
    res = bd_checked(other, test, "rate", method, higher_is_better)
    if res.value is not None:
        return res.value < 0.0
    if not res.no_overlap:
        return None
    tq, oq = [q for _, q in test], [q for _, q in other]
    above = min(tq) > max(oq) if higher_is_better else max(tq) < min(oq)
    below = max(tq) < min(oq) if higher_is_better else min(tq) > max(oq)
    if below:
        return False
    if above and min(r for r, _ in test) <= max(r for r, _ in other):
        return True
    return None


def latency_groups(curve_map, rtt_of, latency_key):
    """The curves by (scene, conditions other than `latency_key`), then by round-trip time:
    {(scene, rest): {rtt: {family: [(rate, quality), ...]}}}; curves whose `latency_key` value has
    no RTT (rtt_of gives None: a trace) are left out."""
    groups = {}
    for (scene, cond, fam), pts in curve_map.items():
        lat = dict(cond).get(latency_key)
        rtt = rtt_of(lat) if lat is not None else None
        if rtt is None:
            continue
        rest = tuple((k, v) for k, v in cond if k != latency_key)
        groups.setdefault((scene, rest), {}).setdefault(rtt, {})[fam] = [(x, y) for x, y, *_ in pts]
    return groups


def crossover(curve_map, is_remote, rtt_of, latency_key="network", higher_is_better=True):
    """Where hybrid starts to win, per scene (and other conditions than `latency_key`): for every
    hybrid family, the smallest round-trip time from which on, at every measured RTT, it beats
    (beats()) every remote family measured there. `is_remote(family)` tells the sides apart;
    `rtt_of(value)` gives the RTT in ms of a `latency_key` value, or None (a trace: left out).
    Returns {(scene, other conditions): {"rtts": [...], "families": {family: RTT or None (it does
    not win at the largest RTT)}, "wins": {family: {rtt: True/False/None}}}}."""
    groups = latency_groups(curve_map, rtt_of, latency_key)
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


def best_under_budget(pts, budget, higher_is_better=True, method="pchip"):
    """The best quality a curve (list of (bitrate, quality)) reaches at a bitrate at or under
    `budget`: its measured points at or under it, and where the budget lies within the curve's
    measured bitrate range, the curve joined by `method` (PCHIP: quality against log10(bitrate))
    at the budget; never extrapolated. None where no point is at or under the budget."""
    pts = [(float(r), float(q)) for r, q in pts]
    cands = [q for r, q in pts if r <= budget]
    if not cands:
        return None
    rates = [r for r, _ in pts]
    if min(rates) <= budget <= max(rates) and len(set(rates)) >= 2:
        try:
            cands.append(interpolate([(math.log10(r), q) for r, q in pts], math.log10(budget), method))
        except ValueError:
            pass  # two points at one bitrate: no function of it; the measured points stand
    return max(cands) if higher_is_better else min(cands)


def regime_map(curve_map, is_remote, rtt_of, budgets, latency_key="network", higher_is_better=True, method="pchip"):
    """Which side wins at each bitrate budget and round-trip time, per scene (and other
    conditions than `latency_key`): for every budget, the best family of each side (hybrid: not
    is_remote) by best_under_budget(), the side whose best is better, and by how much. Returns
    {(scene, rest): {"rtts": [...], "budgets": [...], "cells": {(rtt, budget): {"hybrid": (family,
    quality) or None, "remote": ..., "winner": "hybrid", "remote", "tie" or None (neither has a
    point at or under the budget), "only": the side that alone has one (else None), "margin":
    hybrid's quality minus remote's, signed so that > 0 favours hybrid (None unless both)}}}}."""
    groups = latency_groups(curve_map, rtt_of, latency_key)
    out = {}
    for key, by_rtt in sorted(groups.items()):
        cells = {}
        for rtt, fams in by_rtt.items():
            for b in budgets:
                best = {"hybrid": None, "remote": None}
                for fam, pts in sorted(fams.items()):
                    q = best_under_budget(pts, b, higher_is_better, method)
                    if q is None:
                        continue
                    side = "remote" if is_remote(fam) else "hybrid"
                    cur = best[side]
                    if cur is None or (q > cur[1] if higher_is_better else q < cur[1]):
                        best[side] = (fam, q)
                cell = dict(best, winner=None, only=None, margin=None)
                if best["hybrid"] and best["remote"]:
                    d = best["hybrid"][1] - best["remote"][1]
                    cell["margin"] = d if higher_is_better else -d
                    cell["winner"] = "hybrid" if cell["margin"] > 0 else ("remote" if cell["margin"] < 0 else "tie")
                elif best["hybrid"] or best["remote"]:
                    cell["only"] = cell["winner"] = "hybrid" if best["hybrid"] else "remote"
                cells[(rtt, b)] = cell
        out[key] = {"rtts": sorted(by_rtt), "budgets": list(budgets), "cells": cells}
    return out
