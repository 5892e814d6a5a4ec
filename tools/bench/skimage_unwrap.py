#!/usr/bin/python3
"""Times scikit-image's unwrap_phase (Herráez et al. 2002, Appl. Opt. 41(35):7437) for d3d-bench-unwrap.

Usage: skimage_unwrap.py DIR [REPS]
  reads  DIR/wrapped.npy  float32 H×W wrapped phase in [−π, π)
         DIR/mask.npy     uint8 H×W, nonzero = pixel to unwrap
  writes DIR/unwrapped.npy float32 H×W, NaN where masked
  prints one JSON line: {"ms": median time of unwrap_phase over REPS runs, "version": ...}
Only the unwrap_phase call is timed (no file I/O). Needs Debian's python3-skimage.
"""
import json
import sys
import time

import numpy as np
import skimage
from skimage.restoration import unwrap_phase


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    folder = sys.argv[1]
    reps = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    wrapped = np.load(folder + "/wrapped.npy").astype(np.float64)
    mask = np.load(folder + "/mask.npy") == 0  # numpy masked arrays: True = masked out
    image = np.ma.masked_array(wrapped, mask=mask)
    times = []
    out = None
    for _ in range(max(1, reps)):
        t0 = time.perf_counter()
        out = unwrap_phase(image)
        times.append((time.perf_counter() - t0) * 1e3)
    result = np.ma.filled(out.astype(np.float32), np.nan)
    np.save(folder + "/unwrapped.npy", result)
    print(json.dumps({"ms": float(np.median(times)), "version": skimage.__version__}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
