#!/usr/bin/env python3
"""Writes experiments/traces/5g_paper_shape.txt: a synthetic one-way latency trace shaped like
the 5G edge measurement in the DHR+S paper (section 4.2, Fig. 8: mean 12 ms, 99th percentile
48.3 ms). The paper publishes only those two figures, not its samples, so this is a model,
not a measurement:

  latency = floor + exp(x),  x an AR(1) process in log space (stationary normal N(mu, s^2),
  lag-1 correlation rho per 10 ms sample, so bursts of high latency last a few samples),

with floor = 5 ms and (mu, s) solved so that the distribution's mean is 12 ms and its 99th
percentile 48.3 ms exactly: exp(mu + s^2/2) = 7 and exp(mu + 2.3263 s) = 43.3. The finite
trace is then rescaled affinely above the floor so that its own sample mean and p99 hit the
targets to 0.1 ms. Standard library only; seeded, so the file is reproducible:

  python3 scripts/make_5g_trace.py > experiments/traces/5g_paper_shape.txt
"""
import math
import random

FLOOR, MEAN, P99, Z99 = 5.0, 12.0, 48.3, 2.3263478740
N, INTERVAL_MS, RHO, SEED = 60000, 10, 0.6, 20240607

a, b = math.log(MEAN - FLOOR), math.log(P99 - FLOOR)
# s^2/2 - Z99 s + (b - a) = 0, smaller root
s = Z99 - math.sqrt(Z99 * Z99 - 2 * (b - a))
mu = a - s * s / 2

rng = random.Random(SEED)
x, raw = rng.gauss(0, 1), []
for _ in range(N):
    x = RHO * x + math.sqrt(1 - RHO * RHO) * rng.gauss(0, 1)
    raw.append(math.exp(mu + s * x))

def stats(v):
    srt = sorted(v)
    return sum(v) / len(v), srt[int(0.99 * (len(v) - 1))]

# Affine correction of the excess over the floor: excess' = c0 + c1 * excess, so that the
# sample mean and p99 hit the targets (c0 small, c1 near 1).
m, p = stats(raw)
c1 = ((P99 - FLOOR) - (MEAN - FLOOR)) / (p - m)
c0 = (MEAN - FLOOR) - c1 * m
lat = [FLOOR + max(0.0, c0 + c1 * e) for e in raw]
m, p = stats(lat)

print("# Synthetic 5G edge latency trace shaped like DHR+S Fig. 8 (mean 12 ms, p99 48.3 ms).")
print("# Made by scripts/make_5g_trace.py (a model, not a measurement: see that script).")
print(f"# samples {N}, every {INTERVAL_MS} ms ({N * INTERVAL_MS / 1000:.0f} s, repeating); floor {FLOOR} ms;")
print(f"# lognormal excess mu {mu:.4f} s {s:.4f}, AR(1) rho {RHO}, seed {SEED}")
print(f"# sample mean {m:.2f} ms, sample p99 {p:.2f} ms, min {min(lat):.2f} ms, max {max(lat):.2f} ms")
print(f"interval_ms: {INTERVAL_MS}")
for v in lat:
    print(f"{v:.2f}")
