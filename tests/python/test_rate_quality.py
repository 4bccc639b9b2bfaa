"""BD-rate on cases with a known answer (experiments/rate_quality.py); run by CTest with Debian's
python3 (numpy comes with python3-matplotlib)."""
import math
import os
import sys
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "experiments"))
import rate_quality as rq  # noqa: E402

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
        self.assertAlmostEqual(table[("room", ())]["b"], 0.02, places=9)


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
        self.assertLess(table[("room", (("downlink.latency_ms", "0"),))]["hybrid"], 0.0)


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


if __name__ == "__main__":
    unittest.main()
