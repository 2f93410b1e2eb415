#!/usr/bin/env python3
"""Anchor for the EDT benchmark: scipy.ndimage.distance_transform_edt on the same mask as
`server/crates/geometry/resecta-geom/benches/edt.rs` (512×512×300 at 0.8×0.8×2.5 mm).

Usage: python docs/bench/edt_scipy.py   (needs numpy and scipy; prints one JSON object)
"""
import json
import time

import numpy as np
from scipy import ndimage


def mask():
    dims, spacing = (512, 512, 300), np.array([0.8, 0.8, 2.5])
    origin = np.array([-204.4, -204.4, -373.75])
    # Arrays indexed [i, j, k] like the Rust grid (i fastest there; layout does not change the EDT).
    i, j, k = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in dims), indexing="ij", sparse=True)
    x, y, z = origin[0] + spacing[0] * i, origin[1] + spacing[1] * j, origin[2] + spacing[2] * k
    m = (x / 110.0) ** 2 + (y / 90.0) ** 2 + (z / 120.0) ** 2 <= 1.0
    for (cx, cy, cz), r in [((-40.0, 10.0, 0.0), 25.0), ((50.0, -20.0, 30.0), 15.0), ((10.0, 40.0, -60.0), 20.0)]:
        m &= (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2 > r * r
    return m, spacing


def main():
    m, spacing = mask()
    # Distance of every voxel to the nearest feature (mask) voxel = EDT of the complement.
    runs = []
    for _ in range(3):
        t = time.perf_counter()
        d = ndimage.distance_transform_edt(~m, sampling=spacing)
        runs.append(time.perf_counter() - t)
    best = min(runs)
    print(json.dumps({"tool": "scipy.ndimage.distance_transform_edt", "scipy": __import__("scipy").__version__,
                      "voxels": int(m.size), "best_s": best, "voxels_per_s": m.size / best,
                      "max_mm": float(d.max())}))


if __name__ == "__main__":
    main()
