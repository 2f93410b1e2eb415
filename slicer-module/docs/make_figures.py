"""Draws the figures of slicer-module/README.md (PNG, with matplotlib):

- `panel.png`: the module panel, drawn from `Resecta/Resources/UI/Resecta.ui` itself (sections,
  labels, widgets in their order), with example contents;
- `workflow.png`: the planning workflow (after the thesis' Fig. 7.4) and where each step runs.

Run: python slicer-module/docs/make_figures.py  (needs matplotlib)
"""

import xml.etree.ElementTree as ET
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyBboxPatch, Rectangle  # noqa: E402

HERE = Path(__file__).resolve().parent
UI = HERE.parent / "Resecta" / "Resources" / "UI" / "Resecta.ui"

#: example contents shown in the drawing, by widget name
EXAMPLE = {
    "serverAddressLineEdit": "planning.hospital.local:50051",
    "tokenLineEdit": "••••••••••••••••",
    "connectionStatusLabel": "Connected: resecta 0.1.0",
    "segmentationSelector": "Patient 12 segmentation",
    "methodComboBox": "psr",
    "tumorComboBox": "tumor_1",
    "endPointSelector": "Resecta end point",
    "resectionNameLineEdit": "r1",
    "resectionComboBox": "r1",
    "marginSpinBox": "10.0 mm",
    "bandSpinBox": "5.0 mm",
    "groupComboBox": "Inner points",
    "deltaCoordinates": "0.0   0.0   5.0",
    "rotateAxisComboBox": "S",
    "rotateAngleSpinBox": "5.0°",
    "exportFormatComboBox": "vtp",
    "drawnKindComboBox": "DS: drawn on slices",
    "drawnNameLineEdit": "ds1",
    "deformationRadiusSpinBox": "20.0 mm",
    "caFilePathLineEdit": "",
    "flrLabel": "",
    "statusLabel": "Exported 1 resection(s) to /data/plans",
}
ROLE_ROWS = [("Liver", "parenchyma"), ("Tumour", "tumor"), ("Portal vein", "portal"),
             ("Hepatic veins", "hepatic")]
VOLUME_ROWS = [("Total liver", "1523.4", "100.0"), ("Resected by r1", "412.8", "27.1"),
               ("Remnant (FLR)", "1110.6", "72.9"), ("Functional remnant", "1071.3", "70.3"),
               ("Devascularised", "39.3", "2.6"), ("Congested", "0.0", "0.0")]
METRIC_ROWS = [("r1", "Bézier", "+1.4 mm", "0.0031 mm⁻¹")]
VESSEL_ROWS = [("portal", "5.1 mm", "r1")]
TABLES = {"roleTable": (("Segment", "Role"), ROLE_ROWS), "volumeTable": (("", "ml", "%"), VOLUME_ROWS),
          "metricsTable": (("", "kind", "margin dev.", "median |H|"), METRIC_ROWS),
          "cutVesselTable": (("cut vessel", "radius", "resection"), VESSEL_ROWS)}


def _text(w, prop):
    for p in w.findall("property"):
        if p.get("name") == prop:
            s = p.find("string")
            return s.text if s is not None else None
    return None


def _rows(layout):
    """(label text or None, [widget elements]) per form row, in order."""
    rows = {}
    for item in layout.findall("item"):
        r = int(item.get("row", 0))
        c = int(item.get("column", 0))
        w = item.find("widget")
        sub = item.find("layout")
        entry = rows.setdefault(r, [None, []])
        if w is not None and c == 0 and w.get("class") == "QLabel" and item.get("colspan") is None:
            entry[0] = _text(w, "text")
        elif w is not None:
            entry[1].append(w)
        elif sub is not None:
            entry[1] += [i.find("widget") for i in sub.findall("item") if i.find("widget") is not None]
    return [rows[k] for k in sorted(rows)]


def draw_panel(out: Path):
    root = ET.parse(UI).getroot().find("widget")
    sections = []
    for item in root.find("layout").findall("item"):
        w = item.find("widget")
        if w is not None and w.get("class") == "ctkCollapsibleButton":
            sections.append((_text(w, "text"), _rows(w.find("layout"))))
    W = 460
    y = 0
    fig_h = 1180
    fig, ax = plt.subplots(figsize=(W / 100, fig_h / 100), dpi=130)
    ax.set_xlim(0, W)
    ax.set_ylim(fig_h, 0)
    ax.axis("off")
    ax.add_patch(Rectangle((0, 0), W, fig_h, color="#f3f3f3"))
    ax.text(12, 22, "Resecta", fontsize=13, weight="bold")
    y = 40
    for title, rows in sections:
        ax.add_patch(Rectangle((6, y), W - 12, 22, color="#dcdcdc"))
        ax.text(14, y + 15, "▼ " + title, fontsize=9, weight="bold")
        y += 30
        for label, widgets in rows:
            x0 = 14
            if label:
                ax.text(x0, y + 13, label, fontsize=7.5)
                x0 = 150
            span = (W - 14 - x0) / max(1, len(widgets))
            h = 20
            for w in widgets:
                cls, name = w.get("class"), w.get("name")
                if cls == "QTableWidget":
                    h = _table(ax, x0, y, W - 14 - x0, name)
                    continue
                _widget(ax, cls, name, w, x0 + 2, y, span - 6)
                x0 += span
            y += h + 6
        y += 6
    status = EXAMPLE["statusLabel"]
    ax.text(14, y + 12, status, fontsize=7, color="#444")
    ax.set_ylim(y + 24, 0)
    fig.set_size_inches(W / 100, (y + 24) / 100)
    fig.savefig(out, bbox_inches="tight", pad_inches=0.05)
    plt.close(fig)


def _widget(ax, cls, name, w, x, y, width):
    text = EXAMPLE.get(name, _text(w, "text") or "")
    if cls == "QPushButton" and name == "marginIndicatorButton":
        ax.add_patch(FancyBboxPatch((x, y), width, 20, boxstyle="round,pad=0,rounding_size=3",
                                    color="#2e9e44"))
        ax.text(x + width / 2, y + 14, "r1: min. margin 11.4 mm ≥ 10 mm", ha="center",
                fontsize=8, color="white", weight="bold")
        return
    if cls == "QPushButton":
        ax.add_patch(FancyBboxPatch((x, y), width, 20, boxstyle="round,pad=0,rounding_size=3",
                                    facecolor="#fafafa", edgecolor="#888"))
        ax.text(x + width / 2, y + 14, text, ha="center", fontsize=7.5)
    elif cls == "QProgressBar":
        ax.add_patch(Rectangle((x, y + 4), width, 12, facecolor="white", edgecolor="#888"))
        ax.add_patch(Rectangle((x, y + 4), width * 1.0, 12, color="#4a90d9"))
        ax.text(x + width / 2, y + 14, "done 100%", ha="center", fontsize=7, color="white")
    elif cls == "QCheckBox":
        ax.add_patch(Rectangle((x, y + 5), 10, 10, facecolor="white", edgecolor="#666"))
        ax.text(x + 16, y + 14, text, fontsize=7.5)
    elif cls == "ctkSliderWidget":
        ax.plot([x, x + width - 40], [y + 10, y + 10], color="#888", lw=2)
        value = 0.35 if name == "opacitySlider" else 1.0
        ax.add_patch(Rectangle((x + (width - 40) * value - 3, y + 4), 6, 12, color="#4a90d9"))
        ax.text(x + width - 34, y + 14, f"{value:.2f}", fontsize=7.5)
    elif cls == "QLabel":
        ax.text(x, y + 14, text, fontsize=7.5, color="#2e7d32" if "Connected" in text else "#222")
    else:  # line edits, combo boxes, spin boxes, node selectors, coordinates
        ax.add_patch(Rectangle((x, y), width, 20, facecolor="white", edgecolor="#999"))
        ax.text(x + 5, y + 14, text, fontsize=7.5)
        if cls in ("QComboBox", "qMRMLNodeComboBox"):
            ax.text(x + width - 12, y + 14, "▾", fontsize=8)


def _table(ax, x, y, width, name):
    header, rows = TABLES[name]
    cols = len(header)
    first = 0.5 if cols <= 3 else 0.16
    cw = [width * first] + [width * (1 - first) / (cols - 1)] * (cols - 1)
    h = 16 * (len(rows) + 1)
    ax.add_patch(Rectangle((x, y), width, h, facecolor="white", edgecolor="#999"))
    for r, cells in enumerate([header, *rows]):
        cx = x
        for c, cell in enumerate(cells):
            ax.text(cx + 4, y + 12 + 16 * r, cell, fontsize=7.2, weight="bold" if r == 0 else None,
                    color="#222")
            cx += cw[c]
        if r:
            ax.plot([x, x + width], [y + 16 * r, y + 16 * r], color="#e0e0e0", lw=0.6)
    return h


STEPS = [
    ("1  Connect", "address, token, TLS\n(Slicer settings)", "client"),
    ("2  Map segments", "segments → parenchyma,\ntumour, portal, hepatic", "client"),
    ("3  Build models", "upload label map, PSR,\nprogress, cancel", "server"),
    ("4  Tumour, end point", "live preview of the\nslicing contour", "client"),
    ("5  New resection", "Alg. 1–2: plane,\n4×4 control grid", "server"),
    ("6  Shape surface", "drag points, groups,\ntranslate, rotate", "client"),
    ("7  Margins live", "grey / yellow / red,\nglobal indicator", "server"),
    ("8  Volumetry", "resected, remnant,\nFLR warning", "server"),
    ("9  Save / export", "plan JSON,\nresection meshes", "client"),
]


def draw_workflow(out: Path):
    fig, ax = plt.subplots(figsize=(10.5, 4.0), dpi=130)
    ax.set_xlim(0, 10.5)
    ax.set_ylim(-0.2, 3.9)
    ax.axis("off")
    colors = {"client": "#e3f0fb", "server": "#fdf0e0"}
    edges = {"client": "#4a90d9", "server": "#d9822b"}
    pos = []
    for k, (title, body, where) in enumerate(STEPS):
        row, col = divmod(k, 5)
        x = 0.25 + col * 2.05 if row == 0 else 0.25 + (4 - col) * 2.05 - 0 * 1.0
        if row == 1:
            x = 0.25 + (3 - col) * 2.05 + 1.02
        y = 2.55 if row == 0 else 0.75
        pos.append((x, y))
        ax.add_patch(FancyBboxPatch((x, y), 1.75, 1.0, boxstyle="round,pad=0.02,rounding_size=0.08",
                                    facecolor=colors[where], edgecolor=edges[where], lw=1.4))
        ax.text(x + 0.08, y + 0.78, title, fontsize=8.5, weight="bold")
        ax.text(x + 0.08, y + 0.22, body, fontsize=7.5)
    for (x0, y0), (x1, y1) in zip(pos, pos[1:]):
        if y0 == y1:
            if x1 > x0:
                ax.annotate("", (x1, y1 + 0.5), (x0 + 1.75, y0 + 0.5),
                            arrowprops=dict(arrowstyle="->", lw=1.2))
            else:
                ax.annotate("", (x1 + 1.75, y1 + 0.5), (x0, y0 + 0.5),
                            arrowprops=dict(arrowstyle="->", lw=1.2))
        else:
            ax.annotate("", (x1 + 0.9, y1 + 1.0), (x0 + 0.9, y0),
                        arrowprops=dict(arrowstyle="->", lw=1.2, connectionstyle="arc3,rad=-0.3"))
    # the editing loop 6 → 7 → 8 → 6
    x6, y6 = pos[5]
    x8, y8 = pos[7]
    ax.annotate("", (x6 + 0.9, y6), (x8 + 0.9, y8),
                arrowprops=dict(arrowstyle="->", lw=1.0, ls="--", color="#666",
                                connectionstyle="arc3,rad=0.35"))
    ax.text((x6 + x8) / 2 + 0.9, -0.12, "repeat until no yellow/red and the FLR is enough",
            ha="center", fontsize=7.5, color="#444")
    ax.add_patch(Rectangle((0.25, 3.65), 0.25, 0.15, facecolor=colors["client"], edgecolor=edges["client"]))
    ax.text(0.55, 3.67, "in Slicer (module)", fontsize=7.5)
    ax.add_patch(Rectangle((2.1, 3.65), 0.25, 0.15, facecolor=colors["server"], edgecolor=edges["server"]))
    ax.text(2.4, 3.67, "on the resecta server (results stream back)", fontsize=7.5)
    fig.savefig(out, bbox_inches="tight", pad_inches=0.05)
    plt.close(fig)


if __name__ == "__main__":
    draw_panel(HERE / "panel.png")
    draw_workflow(HERE / "workflow.png")
    print("wrote", HERE / "panel.png", HERE / "workflow.png")
