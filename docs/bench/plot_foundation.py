#!/usr/bin/env python3
"""Draws docs/bench/foundation-*.json as PNG and SVG bar charts (needs matplotlib)."""
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main(path: str) -> None:
    src = Path(path)
    r = json.loads(src.read_text())
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))

    edt = r["edt_512x512x300"]["seconds"]
    names = list(edt)
    colors = ["#2a7" if n.startswith("resecta") else "#999" for n in names]
    a.barh(names, [edt[n] for n in names], color=colors)
    for y, n in enumerate(names):
        a.text(edt[n], y, f" {edt[n]:.2f} s", va="center", fontsize=8)
    a.set_xlabel("seconds (lower is better)")
    a.set_title("Exact EDT, 512×512×300 voxels, 0.8×0.8×2.5 mm")
    a.invert_yaxis()
    a.set_xlim(0, max(edt.values()) * 1.25)

    q = r["bvh_closest_point"]["queries_per_s"]
    kinds = ["brute force", "bvh", "signed distance", "bvh rayon 2 threads", "bvh near surface"]
    width = 0.38
    for i, (mesh, color) in enumerate([("20480", "#2a7"), ("327680", "#27a")]):
        vals = [q[mesh].get(k, 0) for k in kinds]
        xs = [x + (i - 0.5) * width for x in range(len(kinds))]
        b.bar(xs, vals, width, label=f"{int(mesh):,} triangles", color=color)
    b.set_yscale("log")
    b.set_xticks(range(len(kinds)), kinds, rotation=15, fontsize=8)
    b.set_ylabel("closest-point queries per second (log)")
    b.set_title("BVH closest point on icospheres")
    b.legend(fontsize=8)
    fig.suptitle(r["machine"], fontsize=8)
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(src.with_suffix(f".{ext}"), dpi=110)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/bench/foundation-2026-11-26.json")
