"""Confidence intervals of a mean over frames that are correlated in time, for experiments/report.py.

Consecutive frames of a run are not independent: a codec artefact, a stale buffer or a
disocclusion lasts several frames. A Student's t interval that takes them as independent is then
too narrow by about sqrt((1 + rho) / (1 - rho)) for a first-order autoregressive series of lag-1
correlation rho (3x at rho 0.8). Here the interval is the percentile interval of a circular block
bootstrap (Politis and Romano 1992: blocks of consecutive values, wrapping round at the end, so
every value is equally likely to be drawn) of the mean, with the block length from the data: the
lag-1 autocorrelation rho (clipped to 0..0.95) in Carlstein's (1986) rule for an AR(1) series,
    l = ceil((2 rho / (1 - rho^2))^(2/3) n^(1/3)),
at least 1 (rho <= 0: the ordinary bootstrap) and at most n / 2. Resamples: 2000 by default, from
a generator seeded by the series length and block length only, so the same frames always give the
same interval.

A run's ground-truth series is short (10 frames in most reports, 3 in quick), where bootstrap
percentile intervals are far too narrow. So the report uses mean_interval(): Student's t quantile
with n - 1 degrees of freedom times the block bootstrap's standard error of the mean (its variance
scaled by n / (n - 1)): for independent frames that is Student's t interval, for correlated ones
it widens by the bootstrap's estimate of the variance inflation. block_bootstrap_ci() is the plain
percentile interval.
"""
import math

import numpy as np

RESAMPLES = 2000
SEED = 20010402  # fixed: the interval of a series does not depend on what else the report holds
_weights = {}


def lag1_autocorrelation(x):
    """The lag-1 sample autocorrelation of x (0 for fewer than 3 values or no variance)."""
    x = np.asarray(x, dtype=float)
    if len(x) < 3:
        return 0.0
    d = x - x.mean()
    den = float(np.dot(d, d))
    return float(np.dot(d[:-1], d[1:]) / den) if den > 0 else 0.0


def block_length(x):
    """Carlstein's AR(1) block length for a series x (see the module's docstring)."""
    n = len(x)
    rho = min(max(lag1_autocorrelation(x), 0.0), 0.95)
    if n < 2 or rho == 0.0:
        return 1
    l = math.ceil((2 * rho / (1 - rho * rho)) ** (2.0 / 3.0) * n ** (1.0 / 3.0))
    return int(min(max(l, 1), max(n // 2, 1)))


def _resample_weights(n, l, resamples):
    """(resamples, n): how often each of n values is drawn by each circular-block resample."""
    key = (n, l, resamples)
    if key not in _weights:
        rng = np.random.default_rng([SEED, n, l, resamples])
        blocks = -(-n // l)
        starts = rng.integers(0, n, size=(resamples, blocks))
        idx = ((starts[:, :, None] + np.arange(l)[None, None, :]) % n).reshape(resamples, -1)[:, :n]
        w = np.zeros((resamples, n))
        np.add.at(w, (np.repeat(np.arange(resamples), n), idx.ravel()), 1.0)
        _weights[key] = w
    return _weights[key]


def block_bootstrap_ci(x, level=0.95, resamples=RESAMPLES, block=None):
    """(low, high, block length) of the circular block bootstrap percentile interval of mean(x);
    None for fewer than 2 values."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    if n < 2:
        return None
    l = block_length(x) if block is None else int(block)
    means = _resample_weights(n, l, resamples) @ x / n
    a = (1 - level) / 2
    lo, hi = np.quantile(means, [a, 1 - a])
    return float(lo), float(hi), l


# Student's t 0.975 quantiles for 1..30 degrees of freedom; beyond, the Cornish-Fisher expansion
# (Abramowitz and Stegun 26.7.5), within 1e-5 there.
_T975 = [12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281, 2.2010, 2.1788,
         2.1604, 2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.0930, 2.0860, 2.0796, 2.0739, 2.0687, 2.0639,
         2.0595, 2.0555, 2.0518, 2.0484, 2.0452, 2.0423]


def t975(df):
    """Student's t 0.975 quantile with df >= 1 degrees of freedom."""
    if df <= len(_T975):
        return _T975[df - 1]
    z = 1.959963984540054
    return (z + (z ** 3 + z) / (4 * df) + (5 * z ** 5 + 16 * z ** 3 + 3 * z) / (96 * df ** 2)
            + (3 * z ** 7 + 19 * z ** 5 + 17 * z ** 3 - 15 * z) / (384 * df ** 3))


def mean_interval(x, resamples=RESAMPLES):
    """(half-width, block length) of the 95 % interval of mean(x) the report prints: t975(n - 1)
    times the circular block bootstrap's standard error of the mean, its variance scaled by
    n / (n - 1) (see the module's docstring); None for fewer than 2 values."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    if n < 2:
        return None
    l = block_length(x)
    means = _resample_weights(n, l, resamples) @ x / n
    return float(t975(n - 1) * means.std() * math.sqrt(n / (n - 1))), l


def t_interval(x, level=0.95):
    """(low, high) of Student's t interval of mean(x), the values taken as independent."""
    from scipy import stats  # tests only
    x = np.asarray(x, dtype=float)
    half = stats.t.ppf(0.5 + level / 2, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x))
    return float(x.mean() - half), float(x.mean() + half)
