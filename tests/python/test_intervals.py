"""The report's intervals of a mean over correlated frames (experiments/intervals.py): a circular
block bootstrap widens the interval where frames are correlated, by about sqrt((1+rho)/(1-rho))
for an AR(1) series, and leaves independent frames about where Student's t has them."""
import math
import os
import sys
import unittest

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "experiments"))
import intervals  # noqa: E402

try:
    import scipy  # noqa: F401
except ImportError:
    scipy = None


def ar1(rho, n, seed):
    rng = np.random.default_rng(seed)
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0] / math.sqrt(1 - rho * rho)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + e[i]
    return x


def width(ci):
    return ci[1] - ci[0]


@unittest.skipIf(scipy is None, "scipy is not installed (Student's t for the comparison)")
class Widths(unittest.TestCase):
    def test_ar1_rho_08_is_wider_by_the_variance_inflation(self):
        rho = 0.8
        want = math.sqrt((1 + rho) / (1 - rho))  # 3
        ratios = []
        for seed in (1, 2, 3):
            x = ar1(rho, 4000, seed)
            lo, hi, block = intervals.block_bootstrap_ci(x)
            self.assertGreater(block, 10)
            ratios.append(width((lo, hi)) / width(intervals.t_interval(x)))
        self.assertAlmostEqual(float(np.mean(ratios)), want, delta=0.2 * want, msg=str(ratios))

    def test_independent_frames_are_close_to_student_t(self):
        for seed in (4, 5, 6):
            x = np.random.default_rng(seed).standard_normal(500)
            lo, hi, block = intervals.block_bootstrap_ci(x)
            self.assertLessEqual(block, 3)
            self.assertAlmostEqual(width((lo, hi)) / width(intervals.t_interval(x)), 1.0, delta=0.12)


    def test_the_reports_interval(self):
        # mean_interval: Student's t for independent frames (here n = 10, as a run's ground-truth
        # series), wider by about the inflation for AR(1) ones.
        # (A short series may show some lag-1 correlation by chance: on average about t's width.)
        for n in (10, 60):
            ratios = []
            for seed in range(40):
                x = np.random.default_rng(seed).standard_normal(n)
                half, _ = intervals.mean_interval(x)
                ratios.append(2 * half / width(intervals.t_interval(x)))
            self.assertAlmostEqual(float(np.mean(ratios)), 1.0, delta=0.1, msg=n)
            self.assertGreater(min(ratios), 0.9, msg=n)
        x = ar1(0.8, 4000, 1)
        half, _ = intervals.mean_interval(x)
        self.assertAlmostEqual(2 * half / width(intervals.t_interval(x)), 3.0, delta=0.6)

    def test_t_quantiles(self):
        from scipy import stats
        for df in list(range(1, 40)) + [60, 100, 1000]:
            self.assertAlmostEqual(intervals.t975(df), stats.t.ppf(0.975, df), delta=2e-4, msg=df)


class Basics(unittest.TestCase):
    def test_deterministic(self):
        x = ar1(0.5, 60, 9)
        self.assertEqual(intervals.block_bootstrap_ci(x), intervals.block_bootstrap_ci(x.copy()))

    def test_block_length_rule(self):
        self.assertEqual(intervals.block_length(np.array([1.0, -1.0] * 20)), 1)  # negative rho
        x = ar1(0.8, 1000, 2)
        rho = intervals.lag1_autocorrelation(x)
        self.assertAlmostEqual(rho, 0.8, delta=0.05)
        self.assertEqual(intervals.block_length(x),
                         math.ceil((2 * rho / (1 - rho * rho)) ** (2 / 3) * 1000 ** (1 / 3)))
        self.assertLessEqual(intervals.block_length(np.arange(10.0)), 5)  # at most n / 2

    def test_edge_cases(self):
        self.assertIsNone(intervals.block_bootstrap_ci([0.5]))
        lo, hi, _ = intervals.block_bootstrap_ci([0.9] * 10)
        self.assertAlmostEqual(lo, 0.9, places=12)
        self.assertAlmostEqual(hi, 0.9, places=12)
        lo, hi, _ = intervals.block_bootstrap_ci(np.arange(20.0))
        self.assertLess(lo, 9.5)
        self.assertGreater(hi, 9.5)


if __name__ == "__main__":
    unittest.main()
