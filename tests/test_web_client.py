"""The browser client (#20) end to end: `resecta serve --demo` serves the page at `/`; Debian's
Chromium (software WebGL through SwiftShader), driven by Playwright, opens it, shows the demo
patient in 3D and follows edits made by another client."""
import requests

from browser_harness import browser, demo, open_page  # noqa: F401 (fixtures)


def state(page):
    return page.evaluate("window.resecta && window.resecta.state()")


def test_the_page_opens_the_demo_patient_and_follows_other_clients(demo, browser, tmp_path):
    server, sid = demo
    # The server holds one session: the page opens it and shows its resection.
    page, errors = open_page(browser, server)
    shown = state(page)
    assert shown["sessionId"] == sid
    version = int(shown["planVersion"])
    (name, resection), = shown["resections"].items()
    assert isinstance(resection["minMarginMm"], (int, float))
    # The 3D view is drawn: a screenshot of the canvas holds many colours, not a blank clear.
    shot = tmp_path / "page.png"
    page.locator("canvas").first.screenshot(path=str(shot))
    colours = distinct_colours(shot)
    assert colours > 50, f"{colours} colours: the scene is not drawn"
    # The demo resection comes closer to its tumour than its margin: its violating vertices
    # are drawn in the violation colour (red, seen through the translucent surface).
    assert resection["violation"] is True
    red = reddish_pixels(shot)
    assert red > 500, f"{red} violation-coloured pixels"
    # Another client moves the resection: the page shows the new plan version within seconds.
    move = {"baseVersion": str(version),
            "translate": {"name": name, "delta": {"x": 2.0, "y": 0.0, "z": 0.0}}}
    r = requests.post(f"{server.http_url}/v1/sessions/{sid}/edits", json=move, timeout=60)
    assert r.status_code == 200, r.text
    after = int(r.json()["planVersion"])
    # The bound: the page shows it within 1 s of the answer (typically tens of ms).
    page.wait_for_function(f"() => Number(window.resecta.state().planVersion) >= {after}",
                           timeout=1_000)
    # ... and draws it: the resection moved 2 mm, so the picture changed.
    page.wait_for_timeout(100)  # the frame after the delta
    moved = tmp_path / "moved.png"
    page.locator("canvas").first.screenshot(path=str(moved))
    assert changed_pixels(shot, moved) > 200, "the 3D view did not change"
    assert not errors, errors
    page.close()


def reddish_pixels(png):
    """Pixels whose red exceeds green and blue by more than 60 (the violation colour blended
    with the liver; the liver itself, the vessels and the tumours stay below)."""
    from PIL import Image

    with Image.open(png) as im:
        counts = im.convert("RGB").getcolors(maxcolors=1 << 24)
    return sum(n for n, (r, g, b) in counts if r > 110 and r - g > 60 and r - b > 60)


def changed_pixels(a, b):
    from PIL import Image, ImageChops

    with Image.open(a) as x, Image.open(b) as y:
        diff = ImageChops.difference(x.convert("RGB"), y.convert("RGB")).convert("L")
        return sum(diff.point(lambda v: 255 if v > 24 else 0).histogram()[255:])


def distinct_colours(png):
    from PIL import Image

    with Image.open(png) as im:
        return len(im.convert("RGB").getcolors(maxcolors=1 << 24))


def test_the_page_is_served_with_a_same_origin_policy(demo):
    server, _ = demo
    r = requests.get(server.bound["page"], timeout=30)
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/html")
    assert "default-src 'self'" in r.headers["content-security-policy"]
    again = requests.get(server.bound["page"], headers={"if-none-match": r.headers["etag"]},
                         timeout=30)
    assert again.status_code == 304


def test_all_sessions_lists_the_only_session_and_offers_a_new_one(demo, browser):
    server, sid = demo
    page, errors = open_page(browser, server)
    page.get_by_role("link", name="All sessions").click()
    page.wait_for_url("**/?sessions")
    page.get_by_role("button", name="demo patient (phantom)").wait_for()
    page.get_by_label("Display name").wait_for()
    # Picking it opens it again.
    page.get_by_role("button", name="demo patient (phantom)").click()
    page.wait_for_function(f"() => window.resecta.state() && window.resecta.state().sessionId === '{sid}'",
                           timeout=60_000)
    assert not errors, errors
    page.close()
