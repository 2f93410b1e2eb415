"""The browser client's vascular risk analysis and resectogram end to end: in Debian's Chromium
driven by Playwright, the page on `resecta serve --demo` shows the demo patient's functional
remnant and its cut portal vessel in the panel, draws the resectogram in the margin class
colours, and draws it again after an edit made by another client."""
import requests

from browser_harness import browser, demo, open_page  # noqa: F401 (fixtures)
from server_harness import wait_for

# web/src/resectogram.ts: the margin class colours (scene.ts), the boundary, the cut portal
# vessel and the worst point, as bytes.
OUTSIDE = (219, 219, 219)
SAFE = (158, 158, 158)
WARNING = (255, 217, 0)
VIOLATION = (230, 13, 13)
BOUNDARY = (0, 0, 0)
PORTAL = (26, 89, 255)
WORST = (255, 0, 255)
COLOURS = {"outside": OUTSIDE, "safe": SAFE, "warning": WARNING, "violation": VIOLATION,
           "boundary": BOUNDARY, "portal": PORTAL, "worst": WORST}

# The resectogram canvas read back: pixels per colour above, and a digest of all its bytes.
READ_CANVAS = """(colours) => {
  const c = document.querySelector("canvas.resectogram-canvas");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  const counts = Object.fromEntries(Object.keys(colours).map((k) => [k, 0]));
  let digest = 2166136261;
  for (let i = 0; i < d.length; i += 4) {
    for (const [k, [r, g, b]] of Object.entries(colours)) {
      if (d[i] === r && d[i + 1] === g && d[i + 2] === b && d[i + 3] === 255) counts[k]++;
    }
    for (let j = i; j < i + 4; j++) digest = Math.imul(digest ^ d[j], 16777619) >>> 0;
  }
  return { width: c.width, height: c.height, counts, digest };
}"""


def read_canvas(page):
    return page.evaluate(READ_CANVAS, {k: list(v) for k, v in COLOURS.items()})


def test_the_panel_shows_the_risk_and_the_resectogram_follows_edits(demo, browser):
    server, sid = demo
    page, errors = open_page(browser, server)
    report = requests.get(f"{server.http_url}/v1/sessions/{sid}/volumes", timeout=30).json()
    risk = report["volumes"]["risk"]

    # The volumes name the functional remnant, in ml and percent, and what is at risk.
    table = page.locator("table.risk")
    table.wait_for(timeout=60_000)
    rows = {r[0]: r[1:] for r in (line.split("\t") for line in table.inner_text().splitlines())}
    assert rows["functional remnant"] == [f"{risk['functionalRemnantMl']:.0f} ml",
                                          f"{risk['functionalRemnantPct']:.1f} %"]
    assert rows["devascularised"][0] == f"{risk['devascularisedMl']:.0f} ml"
    assert rows["congested"][0] == "0 ml"  # left out of the JSON: 0
    assert rows["at risk"][0] == f"{risk['atRiskMl']:.0f} ml"
    # The demo resection cuts a portal vessel (5 mm radius).
    assert page.locator(".cut-count").inner_text() == f"{len(risk['cutVessels'])} cut vessel"
    vessels = page.locator("table.cut-vessels tbody tr").all_inner_texts()
    assert vessels[0].split("\t") == ["portal", "5.0 mm", "r1"]
    assert not page.locator(".risk-unavailable").count()

    # The resectogram of r1: its canvas holds the raster, in the class colours, the liver's
    # boundary, the cut vessel's disc and the worst point's cross.
    page.get_by_role("heading", name="Resectogram — u →, v ↓").wait_for()
    page.wait_for_function("() => window.resecta.resectogram() !== null", timeout=30_000)
    before = read_canvas(page)
    assert (before["width"], before["height"]) == (200, 200)
    counts = before["counts"]
    assert counts["outside"] > 2000, counts
    assert counts["safe"] > 2000, counts
    assert counts["warning"] > 300, counts
    assert counts["violation"] > 300, counts
    assert counts["boundary"] > 100, counts
    assert counts["portal"] > 20, counts
    assert counts["worst"] >= 15, counts
    for name in ("safe", "warning", "violation", "outside the liver", "cut portal vessel"):
        assert page.locator("ul.legend li", has_text=name).count() == 1, name

    # Another client moves r1 by 8 mm: the page draws its new resectogram within seconds.
    shown = page.evaluate("window.resecta.state()")
    move = {"baseVersion": str(shown["planVersion"]),
            "translate": {"name": "r1", "delta": {"x": 8.0, "y": 0.0, "z": 0.0}}}
    r = requests.post(f"{server.http_url}/v1/sessions/{sid}/edits", json=move, timeout=60)
    assert r.status_code == 200, r.text
    version = int(r.json()["planVersion"])
    page.wait_for_function(f"() => window.resecta.resectogram().planVersion >= {version}",
                           timeout=10_000)
    after = wait_for(lambda: (c := read_canvas(page))["digest"] != before["digest"] and c,
                     timeout=10)
    assert after["counts"]["safe"] > 2000, after["counts"]
    assert errors == [], errors
    page.close()
