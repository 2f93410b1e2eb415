"""Edit → repainted frame in the browser client (issue #20), measured in headless Chromium.

Starts `resecta serve --demo` (RESECTA_BIN), opens its page, sets the demo resection r1 to each
resolution under test, then makes K `setControlPoint` edits over HTTP from here (an inner control
point moved back and forth by a small step), each once the previous one is painted. Per edit:

- the edit's HTTP round trip (request sent → answer read, here);
- in the page (`window.resecta.timings()`, web/src/timings.ts): the delta's watch event received →
  applied (decoded, plan and scene meshes) → `scene.render()` done → the next animation frame
  (the frame that shows it): the client-side part alone;
- request sent here → the page's paint, across the two clocks: the page's times are
  `performance.timeOrigin + t` corrected by the page's own offset to `Date.now()` (the wall
  clock Python's `time.time()` reads), so both sides are on the one system clock.

Prints one JSON object. Usage (from the repository root):

    RESECTA_BIN=target/release/resecta .venv/bin/python web/bench/repaint.py [--edits 40]
    # the page from web/dist through `node web/dev.mjs --dist` rather than the one the binary embeds:
    ... web/bench/repaint.py --dev-dist
"""
import argparse
import gzip
import hashlib
import json
import os
import platform
import select
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import requests
from playwright.sync_api import sync_playwright

WEB = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
        "--disable-background-networking", "--disable-component-update", "--no-first-run"]
VIEWPORT = {"width": 1024, "height": 700}


def wait_for(predicate, timeout, every=0.1):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    raise TimeoutError("condition not met in time")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stats(xs):
    xs = sorted(xs)
    if not xs:
        return None
    p95 = xs[min(len(xs) - 1, round(0.95 * (len(xs) - 1)))]
    return {"median": round(statistics.median(xs), 2), "p95": round(p95, 2),
            "min": round(xs[0], 2), "max": round(xs[-1], 2)}


class Demo:
    """`resecta serve --demo` on free loopback ports, its session ready."""

    def __init__(self, binary):
        self.proc = subprocess.Popen(
            [binary, "serve", "--demo", "--http", "127.0.0.1:0", "--grpc", "127.0.0.1:0"],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
            env={**os.environ, "RUST_LOG": "warn"})
        ready, _, _ = select.select([self.proc.stdout], [], [], 120)
        line = self.proc.stdout.readline() if ready else ""
        if not line:
            self.stop()
            raise RuntimeError("the server did not start")
        self.bound = json.loads(line)
        self.url = f"{'https' if self.bound.get('tls') else 'http'}://{self.bound['http']}"

        def ready():
            s = requests.get(f"{self.url}/v1/sessions", timeout=30).json().get("sessions", [])
            return s and s[0].get("state") == "SESSION_STATE_READY" and s[0]["id"]

        self.sid = wait_for(ready, 300)

    def edit(self, body):
        r = requests.post(f"{self.url}/v1/sessions/{self.sid}/edits", json=body, timeout=300)
        r.raise_for_status()
        return r.json()

    def get(self, what):
        r = requests.get(f"{self.url}/v1/sessions/{self.sid}/{what}", timeout=60)
        r.raise_for_status()
        return r.json()

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=30)


def page_clock(page):
    """The page's `performance.timeOrigin + now()` minus `Date.now()` (ms): what to subtract from
    a page time to get the wall clock."""
    return page.evaluate("() => performance.timeOrigin + performance.now() - Date.now()")


def wait_painted(page, version, timeout_ms=300_000):
    """The page's timing entry of the delta of plan version `version`, once painted."""
    i = page.wait_for_function(
        "v => { const t = window.resecta.timings(); const i = t.planVersion.lastIndexOf(v);"
        " return i >= 0 ? i + 1 : 0; }", arg=version, timeout=timeout_ms).json_value() - 1
    t = page.evaluate("() => window.resecta.timings()")
    return {k: v[i] for k, v in t.items()}


def run_resolution(server, page, n, edits, warmup, gap):
    r = server.edit({"setResolution": {"name": "r1", "ru": n, "rv": n}})
    wait_painted(page, int(r["planVersion"]))
    plan = json.loads(server.get("plan")["planJson"])
    res = next(x for x in plan["resections"] if x["name"] == "r1")
    m, nn = res["grid"]
    i, j = m // 2, nn // 2  # an inner control point
    p0 = dict(zip("xyz", res["control_points"][i * nn + j]))
    step = 0.5  # mm: a small move, away and back
    skew = page_clock(page)
    rows = []
    for k in range(warmup + edits):
        to = {**p0, "x": p0["x"] + (step if k % 2 == 0 else 0.0)}
        sent = time.time()
        t0 = time.perf_counter()
        r = server.edit({"setControlPoint": {"name": "r1", "i": i, "j": j, "point": to}})
        rtt = (time.perf_counter() - t0) * 1000
        e = wait_painted(page, int(r["planVersion"]))
        to_wall = page_clock(page)
        skew_now = (skew + to_wall) / 2
        origin = page.evaluate("() => performance.timeOrigin")
        if k >= warmup:
            rows.append({
                "edit_rtt_ms": rtt,
                "send_to_arrival_ms": origin + e["arrivalAt"] - skew_now - sent * 1000,
                "send_to_paint_ms": origin + e["paintAt"] - skew_now - sent * 1000,
                "arrival_to_apply_ms": e["arrivalToApplyMs"],
                "arrival_to_render_ms": e["arrivalToRenderMs"],
                "arrival_to_paint_ms": e["arrivalToPaintMs"],
            })
        skew = to_wall
        time.sleep(gap)
    out = {"ru": n, "rv": n, "grid": [m, nn], "point": [i, j], "edits": len(rows), "warmup": warmup}
    for key in rows[0]:
        out[key] = stats([row[key] for row in rows])
    out["samples"] = {key: [round(row[key], 2) for row in rows] for key in rows[0]}
    out["page_clock_skew_ms"] = round(skew, 3)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolutions", default="40,200", help="ru = rv values (comma-separated)")
    ap.add_argument("--edits", type=int, default=40, help="measured edits per resolution")
    ap.add_argument("--warmup", type=int, default=3, help="edits first, not measured")
    ap.add_argument("--gap", type=float, default=0.25, help="seconds idle after each painted edit")
    ap.add_argument("--dev-dist", action="store_true",
                    help="open web/dist through `node web/dev.mjs --dist`, not the embedded page")
    a = ap.parse_args()
    binary = os.environ.get("RESECTA_BIN") or shutil.which("resecta")
    if not binary:
        sys.exit("RESECTA_BIN: the resecta binary")

    server = Demo(binary)
    dev = None
    try:
        if not a.dev_dist:
            page_url = server.bound["page"]
        else:
            port = free_port()
            dev = subprocess.Popen(["node", "dev.mjs", "--dist", "--server", server.url, "--port", str(port)],
                                   cwd=WEB, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            dev.stdout.readline()
            page_url = f"http://127.0.0.1:{port}/?session={server.sid}"
        base = page_url.split("?")[0].rstrip("/")
        app = requests.get(f"{base}/app.js", timeout=30).content
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page(viewport=VIEWPORT)
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(page_url)
            page.wait_for_function(
                "() => { const s = window.resecta && window.resecta.state();"
                " return s && Object.keys(s.resections).length > 0 && window.resecta.timings; }",
                timeout=120_000)
            renderer = page.evaluate(
                "() => { const g = document.createElement('canvas').getContext('webgl2');"
                " const d = g && g.getExtension('WEBGL_debug_renderer_info');"
                " return d ? g.getParameter(d.UNMASKED_RENDERER_WEBGL) : null; }")
            results = [run_resolution(server, page, int(n), a.edits, a.warmup, a.gap)
                       for n in a.resolutions.split(",")]
            version = browser.version
            browser.close()
        dist = (WEB / "dist" / "app.js").read_bytes()
        print(json.dumps({
            "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "server": {"binary": binary, "page": "web/dist via dev.mjs --dist" if a.dev_dist else "embedded"},
            "browser": {"chromium": version, "args": ARGS, "viewport": VIEWPORT, "webgl_renderer": renderer},
            "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                        "loadavg_at_end": [round(x, 2) for x in os.getloadavg()]},
            "gap_s": a.gap,
            "bundle": {"app_js_bytes": len(app), "app_js_gzip9_bytes": len(gzip.compress(app, 9)),
                       "sha256": hashlib.sha256(app).hexdigest(),
                       "same_as_web_dist": app == dist},
            "page_errors": errors,
            "resolutions": results,
        }, indent=1))
    finally:
        if dev is not None:
            dev.terminate()
            dev.wait(timeout=10)
        server.stop()


if __name__ == "__main__":
    main()
