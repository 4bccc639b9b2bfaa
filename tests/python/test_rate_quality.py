"""BD-rate on cases with a known answer (experiments/rate_quality.py); run by CTest with Debian's
python3 (numpy comes with python3-matplotlib). SciPy (python3-scipy, which python3-skimage
brings) is an independent implementation of PCHIP and Akima for the cross-checks; they are
skipped where it is missing."""
import math
import os
import sys
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "experiments"))
import rate_quality as rq  # noqa: E402

try:
    import numpy as np
    from scipy.interpolate import Akima1DInterpolator, PchipInterpolator
except ImportError:  # the cross-checks against SciPy are skipped
    PchipInterpolator = Akima1DInterpolator = None

ANCHOR = [(1.0, 30.0), (2.0, 33.5), (4.0, 36.0), (8.0, 38.0)]


class BdRate(unittest.TestCase):
    def test_same_curve_is_zero(self):
        self.assertAlmostEqual(rq.bd_rate(ANCHOR, ANCHOR), 0.0, places=9)

    def test_every_rate_times_0_8_is_minus_20_percent(self):
        test = [(r * 0.8, q) for r, q in ANCHOR]
        self.assertAlmostEqual(rq.bd_rate(ANCHOR, test), -20.0, places=9)
        self.assertAlmostEqual(rq.bd_rate(test, ANCHOR), 25.0, places=9)

    def test_ssim_scale_and_few_points(self):
        # SSIM-like qualities near 1 (badly conditioned without normalisation), 3 and 2 points.
        a = [(0.5, 0.91), (1.0, 0.95), (3.0, 0.985)]
        self.assertAlmostEqual(rq.bd_rate(a, [(r * 1.5, q) for r, q in a]), 50.0, places=8)
        b = [(1.0, 0.90), (4.0, 0.98)]
        self.assertAlmostEqual(rq.bd_rate(b, [(r * 0.5, q) for r, q in b]), -50.0, places=8)

    def test_partial_overlap_uses_the_shared_range(self):
        # Test curve: the anchor halved in rate, but only over the upper half of its quality range.
        test = [(r * 0.5, q) for r, q in ANCHOR[1:]]
        self.assertAlmostEqual(rq.bd_rate(ANCHOR, test), -50.0, delta=2.0)

    def test_a_better_curve_has_negative_bd_rate(self):
        # Same rates, 1 dB more quality everywhere: less rate at equal quality.
        better = [(r, q + 1.0) for r, q in ANCHOR]
        self.assertLess(rq.bd_rate(ANCHOR, better), 0.0)

    def test_disjoint_ranges_are_an_error(self):
        with self.assertRaises(rq.NoOverlap):
            rq.bd_rate(ANCHOR, [(1.0, 40.0), (2.0, 42.0)])

    def test_bad_curves_are_errors(self):
        for bad in ([(1.0, 30.0)], [(0.0, 30.0), (1.0, 31.0)], [(1.0, 30.0), (2.0, 30.0)],
                    [(1.0, math.nan), (2.0, 31.0)]):
            with self.assertRaises(ValueError, msg=str(bad)):
                rq.bd_rate(ANCHOR, bad)


class EveryMethod(unittest.TestCase):
    """Known answers that hold for every way of joining the points."""

    CURVES = [ANCHOR, [(0.5, 0.91), (1.0, 0.95), (3.0, 0.985)], [(1.0, 0.90), (4.0, 0.98)],
              [(0.3, 20.0), (0.7, 26.0), (1.1, 28.5), (2.9, 33.0), (7.5, 36.2), (20.0, 38.0)]]

    def test_a_constant_rate_factor_is_exactly_that_factor(self):
        for method in rq.METHODS:
            for curve in self.CURVES:
                for k in (0.5, 0.8, 1.0, 1.25, 3.0):
                    scaled = [(r * k, q) for r, q in curve]
                    self.assertAlmostEqual(rq.bd_rate(curve, scaled, method), (k - 1) * 100, places=8,
                                           msg=f"{method} {curve} k={k}")

    def test_identical_curves_are_zero(self):
        for method in rq.METHODS:
            for curve in self.CURVES:
                self.assertAlmostEqual(rq.bd_rate(curve, curve, method), 0.0, places=10)
                self.assertAlmostEqual(rq.bd_quality(curve, curve, method), 0.0, places=10)

    def test_linear_in_log_curves(self):
        # q = a + b log10(r) at uneven rates: every method reproduces the line, so BD-rate between
        # two parallel lines is 10^(-(a_test - a_anchor) / b) - 1 and BD-quality the offset.
        anchor = [(r, 30.0 + 10.0 * math.log10(r)) for r in (1.0, 1.7, 4.0, 9.0, 11.0)]
        test = [(r, 32.0 + 10.0 * math.log10(r)) for r in (0.8, 2.5, 3.0, 7.0)]
        for method in rq.METHODS:
            self.assertAlmostEqual(rq.bd_rate(anchor, test, method), (10 ** -0.2 - 1) * 100, places=8, msg=method)
            self.assertAlmostEqual(rq.bd_quality(anchor, test, method), 2.0, places=9, msg=method)

    def test_unknown_method_is_an_error(self):
        with self.assertRaises(ValueError):
            rq.bd_rate(ANCHOR, ANCHOR, "spline")

    def test_points_at_one_quality_are_no_function_for_the_splines(self):
        bent = [(1.0, 30.0), (2.0, 33.0), (3.0, 33.0), (8.0, 38.0)]
        for method in ("pchip", "akima"):
            with self.assertRaises(ValueError):
                rq.bd_rate(ANCHOR, bent, method)


def _scipy_bd(cls, anchor, test, rate=True):
    """BD-rate (percent) or BD-quality through a SciPy interpolator and its exact integral: the
    `bjontegaard` package's 'pchip' method is scipy.interpolate.PchipInterpolator integrated this
    way (FAU-LMS/bjontegaard, bjontegaard/bd_piecewise_cubic.py)."""
    def xy(c):
        x = np.array([q if rate else math.log10(r) for r, q in c])
        y = np.array([math.log10(r) if rate else q for r, q in c])
        o = np.argsort(x)
        return x[o], y[o]
    (xa, ya), (xt, yt) = xy(anchor), xy(test)
    lo, hi = max(xa[0], xt[0]), min(xa[-1], xt[-1])
    gap = (cls(xt, yt).integrate(lo, hi) - cls(xa, ya).integrate(lo, hi)) / (hi - lo)
    return (10 ** gap - 1) * 100 if rate else gap


@unittest.skipIf(PchipInterpolator is None, "scipy is not installed")
class AgainstScipy(unittest.TestCase):
    # The example curves of the `bjontegaard` package's README and example_usage.py (FAU-LMS,
    # https://github.com/FAU-LMS/bjontegaard; x265 at four presets, kb/s and PSNR dB). Neither
    # the README nor the examples print their results, and no published value of them was found:
    # the reference here is SciPy, an independent implementation of the same interpolants.
    FAU_LOW = ([9487.76, 4593.60, 2486.44, 1358.24], [40.037, 38.615, 36.845, 34.851],
               [9787.80, 4469.00, 2451.52, 1356.24], [40.121, 38.651, 36.970, 34.987])
    FAU_HIGH = ([82472.76, 26875.24, 9487.76, 4593.6], [43.825, 41.404, 40.037, 38.615],
                [99896.96, 33952.04, 9787.8, 4469.0], [44.731, 41.875, 40.121, 38.651])

    def cases(self):
        out = []
        for ra, qa, rt, qt in (self.FAU_LOW, self.FAU_HIGH):
            out.append((list(zip(ra, qa)), list(zip(rt, qt))))
        rng = np.random.default_rng(7)
        for _ in range(40):
            n, m = rng.integers(2, 8, size=2)
            a = sorted(zip(np.exp(rng.uniform(-1, 3, n)), 0.8 + 0.2 * rng.uniform(0, 1, n)))
            t = sorted(zip(np.exp(rng.uniform(-1, 3, m)), 0.8 + 0.2 * rng.uniform(0, 1, m)))
            # Monotone curves (rate and quality sorted together), as measured ones are.
            a = list(zip(sorted(r for r, _ in a), sorted(q for _, q in a)))
            t = list(zip(sorted(r for r, _ in t), sorted(q for _, q in t)))
            out.append((a, t))
        return out

    def test_pchip_and_akima_equal_scipy(self):
        checked = 0
        for a, t in self.cases():
            for method, cls in (("pchip", PchipInterpolator), ("akima", Akima1DInterpolator)):
                if method == "akima" and min(len(a), len(t)) < 3:
                    continue  # two points: ours is the line; SciPy 1.10's Akima extrapolates garbage slopes
                for rate in (True, False):
                    fn = rq.bd_rate if rate else rq.bd_quality
                    try:
                        ours = fn(a, t, method)
                    except rq.NoOverlap:
                        continue
                    self.assertAlmostEqual(ours, _scipy_bd(cls, a, t, rate), places=8, msg=f"{method} {a} {t}")
                    checked += 1
        self.assertGreater(checked, 60)

    def test_slopes_and_values_equal_scipy(self):
        x = np.array([0.1, 0.4, 0.5, 1.3, 2.0, 2.2, 4.0])
        for y in (np.array([1.0, 2.0, 2.1, 2.1, 3.5, 3.0, 5.0]), np.array([0.0, 1.0, 1.5, 1.8, 2.5, 2.6, 3.0])):
            np.testing.assert_allclose(rq.pchip_slopes(x, y), PchipInterpolator(x, y).derivative()(x), atol=1e-12)
            np.testing.assert_allclose(rq.akima_slopes(x, y), Akima1DInterpolator(x, y).derivative()(x), atol=1e-12)
            pts = list(zip(x, y))
            for t in np.linspace(0.1, 4.0, 37):
                self.assertAlmostEqual(rq.interpolate(pts, t, "pchip"), float(PchipInterpolator(x, y)(t)), places=12)
                self.assertAlmostEqual(rq.interpolate(pts, t, "akima"), float(Akima1DInterpolator(x, y)(t)), places=12)
        with self.assertRaises(ValueError):  # no extrapolation
            rq.interpolate(list(zip(x, x)), 4.5)


class Checked(unittest.TestCase):
    def test_a_good_curve_has_no_flags(self):
        res = rq.bd_checked(ANCHOR, [(r * 0.8, q) for r, q in ANCHOR])
        self.assertAlmostEqual(res.value, -20.0, places=9)
        self.assertEqual(res.flags, {})
        self.assertEqual(set(res.by_method), set(rq.METHODS))

    def test_a_curve_that_is_not_monotonic_has_no_number(self):
        dip = [(1.0, 30.0), (2.0, 34.0), (4.0, 33.0), (8.0, 38.0)]
        res = rq.bd_checked(ANCHOR, dip)
        self.assertIsNone(res.value)
        self.assertIn("the test curve is not monotonic", res.reason)
        self.assertIn("34 at 2 Mb/s to 33 at 4 Mb/s", res.reason)
        res = rq.bd_checked(dip, ANCHOR, "quality")
        self.assertIsNone(res.value)
        self.assertIn("the anchor curve is not monotonic", res.reason)
        # Flat: no BD-rate (quality is its abscissa); BD-quality has one.
        flat = [(1.0, 30.0), (2.0, 34.0), (4.0, 34.0), (8.0, 38.0)]
        self.assertIsNone(rq.bd_checked(ANCHOR, flat).value)
        self.assertIn("stays", rq.bd_checked(ANCHOR, flat).reason)
        self.assertIsNotNone(rq.bd_checked(ANCHOR, flat, "quality").value)

    def test_lower_is_better(self):
        flip = [(1.0, 0.30), (2.0, 0.20), (4.0, 0.10)]
        better = [(1.0, 0.25), (2.0, 0.15), (4.0, 0.08)]
        self.assertLess(rq.bd_checked(flip, better, higher_is_better=False).value, 0.0)
        self.assertIsNone(rq.bd_checked(flip, better).value)  # read as higher-is-better: falls
        res = rq.bd_checked(flip, [(1.0, 0.25), (2.0, 0.15), (4.0, 0.16)], higher_is_better=False)
        self.assertIn("rises from 0.15 at 2 Mb/s to 0.16 at 4 Mb/s (it must fall", res.reason)

    def test_methods_that_disagree_are_flagged(self):
        a = [(1, 0.80), (2, 0.90), (3, 0.905), (8, 0.99)]
        t = [(1, 0.85), (1.5, 0.86), (4, 0.97), (6, 0.98)]
        res = rq.bd_checked(a, t)
        self.assertAlmostEqual(res.value, res.by_method["pchip"])
        self.assertIn("methods_disagree", res.flags)
        self.assertIn("polynomial", res.flags["methods_disagree"])
        self.assertNotIn("few_points", res.flags)
        self.assertEqual(rq.bd_checked(a, t, method="akima").value, res.by_method["akima"])

    def test_fewer_than_4_points_are_flagged(self):
        a = [(0.5, 0.91), (1.0, 0.95), (3.0, 0.985)]
        res = rq.bd_checked(a, [(r * 1.5, q) for r, q in a])
        self.assertAlmostEqual(res.value, 50.0, places=8)
        self.assertIn("few_points", res.flags)
        self.assertIn("the anchor curve has 3 points", res.flags["few_points"])

    def test_disjoint_curves_have_a_reason(self):
        res = rq.bd_checked(ANCHOR, [(1.0, 40.0), (2.0, 42.0)])
        self.assertIsNone(res.value)
        self.assertTrue(res.no_overlap)
        self.assertIn("do not overlap", res.reason)


class BdQuality(unittest.TestCase):
    def test_same_curve_is_zero(self):
        self.assertAlmostEqual(rq.bd_quality(ANCHOR, ANCHOR), 0.0, places=9)

    def test_a_constant_quality_offset_is_that_offset(self):
        self.assertAlmostEqual(rq.bd_quality(ANCHOR, [(r, q + 0.75) for r, q in ANCHOR]), 0.75, places=9)
        a = [(0.5, 0.91), (1.0, 0.95), (3.0, 0.985)]
        self.assertAlmostEqual(rq.bd_quality(a, [(r, q - 0.02) for r, q in a]), -0.02, places=9)

    def test_half_the_rate_on_a_log_linear_curve(self):
        # q = 30 + 10 log10(r): at half the bitrate for the same quality, the test family gives
        # 10 log10(2) more at equal bitrate.
        anchor = [(r, 30.0 + 10.0 * math.log10(r)) for r in (1.0, 2.0, 4.0, 8.0)]
        test = [(r * 0.5, q) for r, q in anchor]
        self.assertAlmostEqual(rq.bd_quality(anchor, test), 10.0 * math.log10(2.0), places=9)

    def test_disjoint_rate_ranges_are_an_error(self):
        with self.assertRaises(rq.NoOverlap):
            rq.bd_quality(ANCHOR, [(20.0, 40.0), (40.0, 42.0)])

    def test_bad_curves_are_errors(self):
        for bad in ([(1.0, 30.0)], [(0.0, 30.0), (1.0, 31.0)], [(2.0, 30.0), (2.0, 31.0)],
                    [(1.0, math.inf), (2.0, 31.0)]):
            with self.assertRaises(ValueError, msg=str(bad)):
                rq.bd_quality(ANCHOR, bad)

    def test_table_with_bd_quality(self):
        runs = [{"id": f"r{i}", "scene": "room", "family": fam, "settings": {"crf": crf}, "mbps": mbps, "ssim": ssim}
                for i, (fam, crf, mbps, ssim) in enumerate([("a", 18, 4.0, 0.95), ("a", 28, 1.0, 0.90),
                                                            ("b", 18, 4.0, 0.97), ("b", 28, 1.0, 0.92)])]
        cm = rq.curves(runs, ["crf"], ["crf"], lambda r: r["mbps"], lambda r: r["ssim"])
        table = rq.bd_table(cm, "a", rq.bd_quality)
        self.assertAlmostEqual(table[("room", ())]["b"].value, 0.02, places=9)


class Curves(unittest.TestCase):
    def test_grouping_by_scene_conditions_and_family(self):
        runs = []
        for i, (fam, lat, crf, mbps, ssim) in enumerate([
                ("remote", 0, 18, 4.0, 0.95), ("remote", 0, 28, 1.0, 0.90), ("remote", 50, 18, 4.0, 0.90),
                ("remote", 50, 28, 1.0, 0.85), ("hybrid", 0, 18, 2.0, 0.96), ("hybrid", 0, 28, 0.5, 0.91)]):
            runs.append({"id": f"r{i}", "scene": "room", "family": fam,
                         "settings": {"downlink.latency_ms": lat, "crf": crf}, "mbps": mbps, "ssim": ssim})
        cm = rq.curves(runs, ["downlink.latency_ms", "crf"], ["crf"], lambda r: r["mbps"], lambda r: r["ssim"])
        self.assertEqual(len(cm), 3)
        key = ("room", (("downlink.latency_ms", "0"),), "remote")
        self.assertEqual([p[0] for p in cm[key]], [1.0, 4.0])
        table = rq.bd_table(cm, "remote")
        self.assertEqual(set(table), {("room", (("downlink.latency_ms", "0"),)), ("room", (("downlink.latency_ms", "50"),))})
        self.assertLess(table[("room", (("downlink.latency_ms", "0"),))]["hybrid"].value, 0.0)


class Crossover(unittest.TestCase):
    REMOTE = [(1.0, 0.80), (2.0, 0.85), (4.0, 0.88)]

    def test_beats(self):
        r = self.REMOTE
        self.assertTrue(rq.beats([(x * 0.5, q) for x, q in r], r))      # half the rate at equal quality
        self.assertFalse(rq.beats([(x * 2.0, q) for x, q in r], r))     # twice
        self.assertTrue(rq.beats([(1.0, 0.95), (2.0, 0.97)], r))       # above every remote point, no dearer
        self.assertFalse(rq.beats([(1.0, 0.60), (2.0, 0.70)], r))      # below
        self.assertIsNone(rq.beats([(8.0, 0.95), (16.0, 0.97)], r))    # above, but only at a higher rate
        self.assertIsNone(rq.beats([(1.0, 0.9)], r))                   # one point: no curve
        # Lower is better (FLIP): the test's errors all below the other's.
        flip_r = [(1.0, 0.20), (2.0, 0.15), (4.0, 0.12)]
        self.assertTrue(rq.beats([(1.0, 0.05), (2.0, 0.04)], flip_r, higher_is_better=False))
        self.assertFalse(rq.beats([(1.0, 0.05), (2.0, 0.04)], flip_r, higher_is_better=True))

    def test_crossover_is_where_hybrid_wins_from_on(self):
        # Remote loses quality with latency, hybrid keeps it: hybrid loses at 0 ms, wins from 50 on.
        rows = []
        for rtt, drop in ((0, 0.0), (50, 0.08), (200, 0.2)):
            rows += [("remote", rtt, x, q - drop) for x, q in self.REMOTE]
            rows += [("hybrid", rtt, x * 2.0, q - drop / 8) for x, q in self.REMOTE]
            rows += [("hybrid cheap", rtt, x * 0.25, 0.5) for x in (1.0, 2.0)]  # below every remote point
        runs = [{"id": f"r{i}", "scene": "room", "family": f, "settings": {"network": f"rtt{rtt}", "crf": i},
                 "mbps": x, "ssim": q} for i, (f, rtt, x, q) in enumerate(rows)]
        cm = rq.curves(runs, ["network", "crf"], ["crf"], lambda r: r["mbps"], lambda r: r["ssim"])
        out = rq.crossover(cm, lambda f: f.startswith("remote"), lambda v: float(v[3:]))
        c = out[("room", ())]
        self.assertEqual(c["rtts"], [0.0, 50.0, 200.0])
        self.assertEqual(c["families"]["hybrid"], 50.0)
        self.assertIsNone(c["families"]["hybrid cheap"])
        self.assertFalse(c["wins"]["hybrid"][0.0])
        # A trace network (no RTT) is left out.
        out = rq.crossover(cm, lambda f: f.startswith("remote"), lambda v: None if v == "rtt50" else float(v[3:]))
        self.assertEqual(out[("room", ())]["rtts"], [0.0, 200.0])


class RegimeMap(unittest.TestCase):
    def test_best_under_budget(self):
        flip = [(1.0, 0.30), (2.0, 0.20), (4.0, 0.10)]
        self.assertIsNone(rq.best_under_budget(flip, 0.5, higher_is_better=False))
        self.assertEqual(rq.best_under_budget(flip, 1.0, higher_is_better=False), 0.30)
        self.assertEqual(rq.best_under_budget(flip, 9.0, higher_is_better=False), 0.10)  # its best point, not beyond
        # Within the range: PCHIP in log-rate; the points lie on a line in log2, so midway in log.
        self.assertAlmostEqual(rq.best_under_budget(flip, math.sqrt(2), higher_is_better=False), 0.25, places=9)

    def test_map(self):
        # FLIP (lower is better). Remote gets worse with latency, hybrid does not; hybrid needs
        # at least 2 Mb/s.
        rows = []
        for rtt, drop in ((0, 0.0), (200, 0.2)):
            rows += [("remote h264", rtt, x, q) for x, q in ((0.5, 0.20 + drop), (1.0, 0.10 + drop), (4.0, 0.05 + drop))]
            rows += [("hybrid", rtt, x, q) for x, q in ((2.0, 0.12), (8.0, 0.08))]
        runs = [{"id": f"r{i}", "scene": "room", "family": f, "settings": {"network": f"rtt{rtt}", "crf": i},
                 "mbps": x, "flip": q} for i, (f, rtt, x, q) in enumerate(rows)]
        cm = rq.curves(runs, ["network", "crf"], ["crf"], lambda r: r["mbps"], lambda r: r["flip"])
        out = rq.regime_map(cm, lambda f: f.startswith("remote"), lambda v: float(v[3:]), [0.25, 0.7, 2.0, 8.0],
                            higher_is_better=False)
        m = out[("room", ())]
        self.assertEqual(m["rtts"], [0.0, 200.0])
        c = m["cells"]
        self.assertIsNone(c[(0.0, 0.25)]["winner"])                # no side has a point that cheap
        self.assertEqual(c[(0.0, 0.7)]["only"], "remote")           # hybrid starts at 2 Mb/s
        self.assertEqual(c[(0.0, 2.0)]["winner"], "remote")
        self.assertAlmostEqual(c[(0.0, 2.0)]["margin"], -(0.12 - rq.best_under_budget(
            [(0.5, 0.20), (1.0, 0.10), (4.0, 0.05)], 2.0, False)), places=12)
        self.assertEqual(c[(200.0, 2.0)]["winner"], "hybrid")
        self.assertAlmostEqual(c[(200.0, 8.0)]["margin"], 0.25 - 0.08, places=12)
        self.assertEqual(c[(200.0, 8.0)]["hybrid"], ("hybrid", 0.08))


if __name__ == "__main__":
    unittest.main()
