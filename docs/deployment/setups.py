"""Draws docs/deployment/setups.svg (and setups.png with cairosvg when it is installed): the three
set-ups of docs/deployment.md side by side.

    python docs/deployment/setups.py            # SVG, and PNG if cairosvg imports
"""

from pathlib import Path
from xml.sax.saxutils import escape

HERE = Path(__file__).resolve().parent
W, H = 1280, 600
PANEL_W = 400
GAP = 20
FONT = "DejaVu Sans, Helvetica, Arial, sans-serif"

# Colours: clients, server processes, storage, network boundaries.
CLIENT = "#e8f0fe"
SERVER = "#fff4d6"
STORE = "#e6f4ea"
EDGE = "#5f6368"
ACCENT = "#c5221f"

out = []


def rect(x, y, w, h, fill, stroke=EDGE, dash=None, rx=8, width=1.5):
    d = f' stroke-dasharray="{dash}"' if dash else ""
    out.append(
        f'<rect x="{x}" y="{y}" width="{w}" height="{h}" rx="{rx}" fill="{fill}" '
        f'stroke="{stroke}" stroke-width="{width}"{d}/>'
    )


def text(x, y, s, size=13, weight="normal", anchor="middle", fill="#202124", style="normal"):
    out.append(
        f'<text x="{x}" y="{y}" font-family="{FONT}" font-size="{size}" font-weight="{weight}" '
        f'font-style="{style}" text-anchor="{anchor}" fill="{fill}">{escape(s)}</text>'
    )


def label(x, y, s, size=11, anchor="middle", fill="#5f6368", style="normal"):
    """Text on a white patch, readable where a line crosses it."""
    w = len(s) * size * 0.56 + 6
    left = {"middle": x - w / 2, "start": x - 3, "end": x - w + 3}[anchor]
    out.append(f'<rect x="{left:.1f}" y="{y - size:.1f}" width="{w:.1f}" height="{size + 5}" fill="#ffffff"/>')
    text(x, y, s, size=size, anchor=anchor, fill=fill, style=style)


def lines(x, y, rows, size=12, **kw):
    for i, s in enumerate(rows):
        text(x, y + i * (size + 4), s, size=size, **kw)


def arrow(x1, y1, x2, y2, colour=EDGE, dash=None, both=False):
    d = f' stroke-dasharray="{dash}"' if dash else ""
    start = ' marker-start="url(#head-start)"' if both else ""
    marker = "head-red" if colour == ACCENT else "head"
    out.append(
        f'<line x1="{x1}" y1="{y1}" x2="{x2}" y2="{y2}" stroke="{colour}" stroke-width="1.6"{d} '
        f'marker-end="url(#{marker})"{start}/>'
    )


def cylinder(cx, y, w, h, label, sub):
    rx, ry = w / 2, 9
    out.append(
        f'<path d="M{cx - rx},{y + ry} v{h - 2 * ry} a{rx},{ry} 0 0,0 {w},0 v{-(h - 2 * ry)}" '
        f'fill="{STORE}" stroke="{EDGE}" stroke-width="1.5"/>'
    )
    out.append(
        f'<ellipse cx="{cx}" cy="{y + ry}" rx="{rx}" ry="{ry}" fill="{STORE}" stroke="{EDGE}" stroke-width="1.5"/>'
    )
    text(cx, y + h / 2 + 6, label, size=13, weight="bold")
    lines(cx, y + h / 2 + 22, sub, size=11)


def panel(i, title, subtitle, promises):
    x = GAP + i * (PANEL_W + GAP)
    rect(x, 20, PANEL_W, H - 40, "#ffffff", stroke="#9aa0a6", rx=12)
    text(x + PANEL_W / 2, 50, title, size=18, weight="bold")
    text(x + PANEL_W / 2, 70, subtitle, size=12, fill="#5f6368")
    rect(x + 12, H - 130, PANEL_W - 24, 98, "#f8f9fa", stroke="#dadce0", rx=6)
    lines(x + 24, H - 110, promises, size=11.5, anchor="start")
    return x


def workstation():
    x = panel(0, "Single workstation", "one user, loopback only", [
        "In memory: sessions end with the process",
        "SQLite: an acknowledged edit survives a crash",
        "Process dies: restart it; stored sessions return",
        "Operator provides: the machine, nothing else",
    ])
    rect(x + 30, 95, PANEL_W - 60, 330, "#fafafa", stroke=EDGE, dash="6 4")
    text(x + 45, 115, "workstation (127.0.0.1)", size=12, anchor="start", fill="#5f6368")
    rect(x + 70, 135, PANEL_W - 140, 60, CLIENT)
    lines(x + PANEL_W / 2, 160, ["3D Slicer + Resecta module", "or the browser, Python"], size=12)
    arrow(x + PANEL_W / 2, 195, x + PANEL_W / 2, 240, both=True)
    text(x + PANEL_W / 2 + 8, 222, "gRPC / HTTP, no token", size=11, anchor="start", fill="#5f6368")
    rect(x + 70, 240, PANEL_W - 140, 60, SERVER)
    lines(x + PANEL_W / 2, 265, ["resecta serve", "127.0.0.1:50051 / :8080"], size=12)
    arrow(x + PANEL_W / 2, 300, x + PANEL_W / 2, 330)
    cylinder(x + PANEL_W / 2, 330, 200, 80, "memory or SQLite", ["--data-dir (optional)"])


def hospital():
    x = panel(1, "Hospital server", "one server, many clients on the network", [
        "Acknowledged edit survives: process crash, power",
        "  loss (fsync); the disk's loss only with backups",
        "Process dies: systemd / compose restarts it (s)",
        "Operator: host, disk, TLS certificate, token",
    ])
    for j, name in enumerate(["Slicer", "browser", "Python"]):
        rect(x + 30 + j * 120, 95, 100, 40, CLIENT)
        text(x + 80 + j * 120, 120, name, size=12)
        arrow(x + 80 + j * 120, 135, x + PANEL_W / 2 + (j - 1) * 40, 215)
    label(x + PANEL_W / 2, 168, "hospital network", style="italic")
    label(x + PANEL_W / 2, 186, "TLS + bearer token", fill=ACCENT)
    rect(x + 30, 200, PANEL_W - 60, 225, "#fafafa", stroke=EDGE, dash="6 4")
    text(x + 45, 220, "server (systemd unit or compose)", size=12, anchor="start", fill="#5f6368")
    rect(x + 70, 230, PANEL_W - 140, 60, SERVER)
    lines(x + PANEL_W / 2, 255, ["resecta serve", "0.0.0.0:50051 / :8080"], size=12)
    arrow(x + PANEL_W / 2, 290, x + PANEL_W / 2, 330)
    cylinder(x + PANEL_W / 2, 330, 200, 80, "SQLite", ["--data-dir on a local disk"])


def cluster():
    x = panel(2, "Replicated cluster", "2+ replicas, Kubernetes", [
        "Acknowledged edit survives: a replica's or a",
        "  node's loss (the log is in PostgreSQL)",
        "Replica dies: its sessions move at the next",
        "  call, within the lease (3 s); SIGTERM: at once",
        "Operator: cluster, PostgreSQL (HA, backups)",
    ])
    rect(x + 130, 90, 140, 36, CLIENT)
    text(x + 200, 113, "client", size=12)
    arrow(x + 185, 126, x + 185, 158)
    text(x + 178, 146, "1 dial", size=11, anchor="end", fill="#5f6368")
    rect(x + 100, 158, 200, 30, "#f1f3f4")
    text(x + 200, 178, "Service resecta", size=12)
    arrow(x + 240, 188, x + 300, 228)
    # Replicas.
    rect(x + 40, 228, 140, 72, SERVER)
    lines(x + 110, 250, ["replica A", "holds session S", "(lease, token)"], size=11)
    rect(x + 220, 228, 140, 72, SERVER)
    lines(x + 290, 250, ["replica B", "S is elsewhere:", "UNAVAILABLE / 421"], size=11)
    # The redirect: B answers with A's address, the client reconnects there.
    out.append(
        f'<path d="M{x + 330},{228} C{x + 360},{150} {x + 330},{110} {x + 272},{108}" fill="none" '
        f'stroke="{ACCENT}" stroke-width="1.6" stroke-dasharray="5 3" marker-end="url(#head-red)"/>'
    )
    label(x + 392, 205, "2 A's address", anchor="end", fill=ACCENT)
    out.append(
        f'<path d="M{x + 140},{126} C{x + 110},{150} {x + 100},{190} {x + 100},{226}" fill="none" '
        f'stroke="{ACCENT}" stroke-width="1.6" marker-end="url(#head-red)"/>'
    )
    text(x + 40, 175, "3 direct to", size=11, anchor="start", fill=ACCENT)
    text(x + 40, 189, "A's pod IP", size=11, anchor="start", fill=ACCENT)
    arrow(x + 110, 300, x + 170, 335, both=True)
    arrow(x + 290, 300, x + 230, 335, both=True)
    cylinder(x + 200, 335, 230, 85, "PostgreSQL", ["leases + session logs", "(external, or overlays/trial)"])


out.append(
    f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}">'
)
out.append(
    "<defs>"
    f'<marker id="head" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" markerHeight="7" orient="auto">'
    f'<path d="M0,0 L10,5 L0,10 z" fill="{EDGE}"/></marker>'
    f'<marker id="head-start" viewBox="0 0 10 10" refX="1" refY="5" markerWidth="7" markerHeight="7" orient="auto-start-reverse">'
    f'<path d="M0,0 L10,5 L0,10 z" fill="{EDGE}"/></marker>'
    f'<marker id="head-red" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" markerHeight="7" orient="auto">'
    f'<path d="M0,0 L10,5 L0,10 z" fill="{ACCENT}"/></marker>'
    "</defs>"
)
out.append(f'<rect width="{W}" height="{H}" fill="#ffffff"/>')
workstation()
hospital()
cluster()
out.append("</svg>")

svg = "\n".join(out) + "\n"
(HERE / "setups.svg").write_text(svg)
try:
    import cairosvg
except ImportError:
    print("wrote setups.svg (pip install cairosvg for setups.png)")
else:
    cairosvg.svg2png(bytestring=svg.encode(), write_to=str(HERE / "setups.png"), output_width=W * 4 // 3)
    print("wrote setups.svg and setups.png")
