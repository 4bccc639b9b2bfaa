#!/usr/bin/env python3
"""Writes the capacity traces in experiments/traces/ (LinkConfig::capacity_trace_file, Mb/s per
sample; core/net/network.h), deterministically:

  capacity_step.txt    10 Mb/s for 1 s, 2 Mb/s for 1 s, 10 Mb/s for 1 s (a step down and back)
  capacity_ramp.txt    10 Mb/s falling linearly to 1 Mb/s over 2 s, then rising back over 2 s
  capacity_mobile.txt  a synthetic mobile link, 60 s at 100 ms per sample: a log-normal AR(1)
                       process (log-capacity mean-reverting with lag-1 autocorrelation 0.9 per
                       100 ms), mean 8 Mb/s, coefficient of variation 0.6, clamped to 0.2..40
                       Mb/s, seed 1. Synthetic: its statistics are chosen, not fitted to a
                       measured dataset (the script prints what it wrote).

    python3 scripts/make_capacity_traces.py     (standard library only)
"""
import math
import os
import random

OUT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "experiments", "traces")


def write(name, header, interval_ms, samples):
    with open(os.path.join(OUT, name), "w") as f:
        f.write("".join(f"# {line}\n" for line in header))
        f.write(f"interval_ms: {interval_ms:g}\n")
        f.writelines(f"{v:.3f}\n" for v in samples)
    mean = sum(samples) / len(samples)
    print(f"{name}: {len(samples)} samples of {interval_ms:g} ms, mean {mean:.3f} Mb/s, "
          f"min {min(samples):.3f}, max {max(samples):.3f}")


def main():
    write("capacity_step.txt", ["Capacity in Mb/s: 10 for 1 s, 2 for 1 s, 10 for 1 s (scripts/make_capacity_traces.py)"],
          100, [10.0] * 10 + [2.0] * 10 + [10.0] * 10)
    down = [10.0 - 9.0 * i / 20 for i in range(20)]
    write("capacity_ramp.txt", ["Capacity in Mb/s: 10 falling to 1 over 2 s, then back (scripts/make_capacity_traces.py)"],
          100, down + [1.0] + down[::-1][:-1])
    rng = random.Random(1)
    mean, cv, rho = 8.0, 0.6, 0.9
    sigma = math.sqrt(math.log(1 + cv * cv))  # of log-capacity, for the chosen CoV
    mu = math.log(mean) - sigma * sigma / 2    # so that the mean is `mean`
    x, samples = mu, []
    for _ in range(600):
        x = mu + rho * (x - mu) + sigma * math.sqrt(1 - rho * rho) * rng.gauss(0.0, 1.0)
        samples.append(min(40.0, max(0.2, math.exp(x))))
    write("capacity_mobile.txt",
          ["Synthetic mobile capacity in Mb/s (scripts/make_capacity_traces.py): log-normal AR(1), lag-1",
           "autocorrelation 0.9 per 100 ms, mean 8 Mb/s, CoV 0.6, clamped to 0.2..40, seed 1; chosen, not fitted"],
          100, samples)


if __name__ == "__main__":
    main()
