"""The browser client's slice view (#20) end to end: in Debian's Chromium driven by Playwright,
the page on `resecta serve --demo` paints a plane of the demo patient's label map in the
structures' colours with the resection's contour, switches axes, follows an edit made by another
client and reports the RAS point under a click."""
import io
import itertools

import numpy as np
import requests

from browser_harness import browser, demo, open_page  # noqa: F401 (fixtures)
from server_harness import wait_for

# The 3D view's palette (web/src/scene.ts) as bytes: what the slice view paints.
PARENCHYMA = (221, 130, 101)
TUMOUR = (78, 180, 78)
RESECTION = (191, 191, 191)


def pixels(page):
    """The slice canvas as an (h, w, 3) array of its screenshot."""
    from PIL import Image

    png = page.locator("canvas.slice-canvas").screenshot()
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"), dtype=np.int16)


def near(img, rgb, tol=6):
    return np.all(np.abs(img - np.array(rgb)) <= tol, axis=-1)


def slice_state(page):
    return page.evaluate("window.resecta.slice()")


def wait_contours(page, axis):
    page.wait_for_function(
        f"() => {{ const s = window.resecta.slice(); return s && s.axis === '{axis}' && s.contours > 0; }}",
        timeout=30_000)


def test_the_slice_view_paints_switches_follows_edits_and_picks(demo, browser):
    server, sid = demo
    page, errors = open_page(browser, server)
    wait_contours(page, "axial")
    axial = pixels(page)
    # The axial plane through the label map's centre cuts the liver and the larger tumour, and
    # the demo resection near it.
    assert near(axial, PARENCHYMA).sum() > 2000
    assert near(axial, TUMOUR).sum() > 300
    contour = near(axial, RESECTION)
    assert contour.sum() > 30

    # Another client moves the resection 10 mm to the patient's right (+x): the contour drawn
    # moves within seconds, to the screen's left (radiological).
    shown = page.evaluate("window.resecta.state()")
    (name, _), = shown["resections"].items()
    move = {"baseVersion": str(shown["planVersion"]),
            "translate": {"name": name, "delta": {"x": 10.0, "y": 0.0, "z": 0.0}}}
    r = requests.post(f"{server.http_url}/v1/sessions/{sid}/edits", json=move, timeout=60)
    assert r.status_code == 200, r.text

    def moved():
        now = near(pixels(page), RESECTION)
        return [now] if now.sum() > 30 and (now != contour).sum() > 30 else None

    (after,) = wait_for(moved, timeout=10)
    cols = lambda m: np.nonzero(m)[1].mean()  # noqa: E731
    assert cols(after) < cols(contour), "the contour moves to the screen's left"

    # Coronal and sagittal planes are other pictures, each with the liver.
    pictures = {"axial": near(axial, PARENCHYMA)}
    for axis in ("coronal", "sagittal"):
        page.get_by_role("button", name=axis.capitalize()).click()
        page.wait_for_function(f"() => window.resecta.slice()?.axis === '{axis}'", timeout=30_000)
        page.wait_for_timeout(300)  # the frame after the raster
        liver = near(pixels(page), PARENCHYMA)
        assert liver.sum() > 2000, axis
        pictures[axis] = liver
    for a, b in itertools.combinations(pictures.values(), 2):
        assert (a != b).sum() > 1000

    # The slider moves the plane (its keyboard steps are the browser's own), and shows it in mm.
    assert page.locator(".slice-mm").inner_text().endswith(" mm")
    s = slice_state(page)
    page.locator("#slice input[type=range]").focus()
    page.keyboard.press("PageUp")
    page.wait_for_function(
        f"() => window.resecta.slice().positionMm !== {s['positionMm']}", timeout=30_000)

    # A click gives the RAS point under the pointer, on the plane, inside the label map.
    box = page.locator("canvas.slice-canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.wait_for_function("() => window.resecta.slice().picked !== null", timeout=10_000)
    s = slice_state(page)
    p = s["picked"]
    assert abs(p["x"] - s["positionMm"]) < 1e-6  # sagittal: the plane x = position
    lo, hi = label_map_bounds(server, sid)
    assert all(lo[k] <= p[c] <= hi[k] for k, c in enumerate("xyz")), (p, lo, hi)
    assert not errors, errors
    page.close()


def label_map_bounds(server, sid):
    """RAS bounds of the demo label map's voxel cubes."""
    lm = requests.get(f"{server.http_url}/v1/sessions/{sid}", timeout=30).json()["session"]["labelMap"]
    d = np.array(lm["direction"]).reshape(3, 3) * np.array(lm["spacing"])
    corners = np.array(list(itertools.product(*[(-0.5, n - 0.5) for n in lm["dims"]])))
    ras = corners @ d.T + np.array(lm["origin"])
    return ras.min(0), ras.max(0)
