"""The risk bench (docs/bench/plan/risk-*.txt, criterion's medians) against #23's targets, each
beside its anchor of the same run: PNG and SVG.

Usage: python plot_risk.py risk-2026-11-26.txt OUT_STEM   (writes OUT_STEM.png and .svg)
"""
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

UNIT = {"ns": 1e-6, "µs": 1e-3, "ms": 1.0, "s": 1e3}


def medians(path: str) -> dict[str, float]:
    out, name = {}, None
    for line in open(path, encoding="utf-8"):
        line = line.strip()
        if re.fullmatch(r"[a-z0-9_]+/[a-z0-9_]+", line):
            name = line
        m = re.search(r"time:\s+\[\S+ \S+ (\S+) (\S+)", line)
        if m and name:
            out[name] = float(m.group(1)) * UNIT[m.group(2)]
    return out


def main(path: str, stem: str) -> None:
    t = medians(path)
    panels = [
        ("territories, 512×512×300 (ms)", [("tree + territories", t["risk_512x512x300/territories_portal_order_2"])], 2000),
        ("volumes per pause (ms)", [("without risk", t["risk_pause_512x512x300/volumes_without_risk"]),
                                    ("with risk", t["risk_pause_512x512x300/volumes_with_risk"])], None),
        ("per edit, 200×200 (ms)", [("edit", t["resectogram_200x200/edit"]),
                                    ("edit + resectogram", t["resectogram_200x200/edit_then_resectogram"]),
                                    ("resectogram", t["resectogram_200x200/resectogram_alone"])], None),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for ax, (title, bars, target) in zip(axes, panels):
        names = [b[0] for b in bars]
        values = [b[1] for b in bars]
        ax.barh(names, values, color=["#9e9e9e"] + ["#1e88e5"] * (len(bars) - 1) if len(bars) > 1 else ["#1e88e5"])
        for y, v in enumerate(values):
            ax.text(v, y, f" {v:.3g}", va="center")
        ax.set_title(title)
        ax.set_xlim(0, max(values + ([target] if target else [])) * 1.3)
        if target:
            ax.axvline(target, color="#e53935", ls="--")
            ax.text(target, -0.45, " target", color="#e53935", va="bottom")
    risk = t["risk_pause_512x512x300/volumes_with_risk"] - t["risk_pause_512x512x300/volumes_without_risk"]
    rg = t["resectogram_200x200/edit_then_resectogram"] - t["resectogram_200x200/edit"]
    fig.suptitle(f"EPYC-2 (2-core AMD EPYC): risk analysis +{risk:.1f} ms per pause (target ≤ 100), "
                 f"resectogram +{rg:.2f} ms per edit (target ≤ 2)")
    fig.tight_layout()
    fig.savefig(stem + ".png", dpi=90)
    fig.savefig(stem + ".svg")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
