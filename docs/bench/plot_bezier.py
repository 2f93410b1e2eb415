#!/usr/bin/env python3
"""Plots `resecta bench bezier --json` output in the shape of the thesis' Figs. 8.5–8.7.

Usage: python docs/bench/plot_bezier.py RESULTS.json   (writes RESULTS.png and RESULTS.svg)
"""
import json
import sys
from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLORS = {"brf": "#c44", "mat": "#d92", "mle": "#2a7", "wgpu": "#27a", "ceiling": "#444"}


def main(path: str) -> None:
    src = Path(path)
    rep = json.loads(src.read_text())
    rows = rep["results"]
    grids = sorted({r["grid"][0] for r in rows})
    res = sorted({r["resolution"][0] for r in rows})
    threads = sorted({r["threads"] for r in rows if r["threads"] is not None})
    fig, axes = plt.subplots(2, len(grids), figsize=(4.6 * len(grids), 8), squeeze=False)
    for col, g in enumerate(grids):
        for row, prec in enumerate(["f64", "f32"]):
            ax = axes[row][col]
            for method in ["brf", "mat", "mle"]:
                for t in threads:
                    pts = [(r["resolution"][0], r["evals_per_s"]) for r in rows
                           if r["method"] == method and r["grid"][0] == g and r["precision"] == prec
                           and r["threads"] == t and r["backend"] == "cpu"]
                    if pts:
                        ax.plot(*zip(*sorted(pts)), marker="o", color=COLORS[method],
                                linestyle="-" if t == 1 else "--", label=f"{method.upper()} {t}t")
            gpu = [(r["resolution"][0], r["evals_per_s"]) for r in rows
                   if r["backend"] == "wgpu" and r["grid"][0] == g and r["precision"] == prec]
            if gpu:
                ax.plot(*zip(*sorted(gpu)), marker="s", color=COLORS["wgpu"], label="MLE wgpu")
            ceil = [(c["resolution"][0], c["write_ceiling_evals_per_s"]) for c in rep["write_ceilings"]
                    if c["precision"] == prec and c["threads"] == max(threads)]
            if ceil:
                ax.plot(*zip(*sorted(ceil)), color=COLORS["ceiling"], linestyle=":",
                        label=f"write ceiling {max(threads)}t")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xticks(res, [f"{r}²" for r in res])
            ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
            ax.set_title(f"{g}×{g} control points, {prec}")
            ax.set_xlabel("resolution")
            ax.set_ylabel("evaluations / s")
            ax.grid(True, which="both", alpha=0.3)
            if row == 0 and col == 0:
                ax.legend(fontsize=7)
    dev = rep.get("wgpu") or {}
    fig.suptitle(f"{rep['machine']['cpu']}, {rep['machine']['logical_cores']} cores"
                 + (f"; wgpu: {dev.get('name')} ({dev.get('backend')})" if dev else ""), fontsize=9)
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(src.with_suffix(f".{ext}"), dpi=100)


if __name__ == "__main__":
    main(sys.argv[1])
