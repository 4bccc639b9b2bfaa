#!/usr/bin/python3
"""SSIM by scikit-image, the reference tests/core/metrics/test_metrics.cpp compares dhrbench's SSIM with.

Usage: ssim_reference.py FILE...   Each FILE holds one image pair: a header of three
little-endian int32 (width, height, channels) followed by both images' bytes (8-bit,
row-major, channels interleaved). Prints one line per file: the mean SSIM of
skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=255), with channel_axis=2 for 3 channels.
Exits non-zero (and says why) when scikit-image cannot be imported: the test then fails.
"""
import sys

import numpy as np

try:
    from skimage.metrics import structural_similarity
except ImportError as e:  # the test must fail, not skip: scripts/setup.sh installs python3-skimage
    sys.exit("ssim_reference.py: scikit-image is missing (%s); install python3-skimage (scripts/setup.sh)" % e)

for path in sys.argv[1:]:
    data = np.fromfile(path, dtype=np.uint8)
    w, h, c = np.frombuffer(data[:12].tobytes(), dtype="<i4")
    n = int(w) * int(h) * int(c)
    a = data[12:12 + n].reshape(h, w, c)
    b = data[12 + n:12 + 2 * n].reshape(h, w, c)
    if c == 1:
        a, b, axis = a[:, :, 0], b[:, :, 0], None
    else:
        axis = 2
    s = structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                              data_range=255, channel_axis=axis)
    print("%.12f" % s)
