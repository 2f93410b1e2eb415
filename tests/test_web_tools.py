"""The browser client's planning tools (#20) end to end, driven by the keyboard and the mouse in
Chromium: margin and band, moves and rotations of the selected resection, a new resection from a
tumour and an end point picked on the liver, the closest point, opacity, plan save / load, mesh
export; and a wrong token answered with a clear message."""
import json
import math

import pytest
import requests

from browser_harness import browser, demo, open_page  # noqa: F401 (fixtures)
from server_harness import Server, wait_for


def state(page):
    return page.evaluate("window.resecta.state()")


def wait_version(page, above):
    page.wait_for_function(f"() => window.resecta.state().planVersion > {above}", timeout=30_000)
    return state(page)


def press(page, name):
    """Presses button `name` from the keyboard: focus, then Enter."""
    page.get_by_role("button", name=name, exact=True).focus()
    page.keyboard.press("Enter")


@pytest.fixture(scope="module")
def page(demo, browser):
    server, _ = demo
    p, errors = open_page(browser, server)
    yield p
    assert not errors, errors
    p.close()


def test_moves_rotations_margin_and_band_edit_the_selected_resection(page):
    before = state(page)
    (name, r), = before["resections"].items()
    points = r["controlPoints"]
    # The whole surface 5 mm anterior (+y), from the keyboard.
    press(page, "A")
    after = wait_version(page, before["planVersion"])
    moved = after["resections"][name]["controlPoints"]
    for p, q in zip(points, moved):
        assert q["y"] - p["y"] == pytest.approx(5.0, abs=1e-9)
        assert q["x"] == pytest.approx(p["x"], abs=1e-9) and q["z"] == pytest.approx(p["z"], abs=1e-9)
    # One control point, P(1,2), 3 mm superior: it alone moves.
    page.get_by_label("Which control points move").select_option("point")
    page.get_by_label("row i").fill("1")
    page.get_by_label("column j").fill("2")
    page.get_by_label("Move by (mm)").fill("3")
    press(page, "S")
    one = wait_version(page, after["planVersion"])
    changed = [k for k, (p, q) in enumerate(zip(moved, one["resections"][name]["controlPoints"]))
               if p != q]
    assert changed == [1 * 4 + 2]
    assert one["resections"][name]["controlPoints"][6]["z"] - moved[6]["z"] == pytest.approx(3.0)
    # A rotation about the S–I axis keeps the centroid.
    page.get_by_label("Rotation axis").select_option("z")
    press(page, "⟲")
    turned = wait_version(page, one["planVersion"])
    c0 = centroid(one["resections"][name]["controlPoints"])
    c1 = centroid(turned["resections"][name]["controlPoints"])
    assert all(abs(a - b) < 1e-6 for a, b in zip(c0, c1))
    # Margin and band: typed and set with Enter.
    page.get_by_label("Margin (mm)").fill("12.5")
    page.get_by_label("Band (mm)").fill("3")
    page.get_by_label("Band (mm)").press("Enter")
    page.wait_for_function(
        f"() => {{ const r = window.resecta.state().resections[{json.dumps(name)}];"
        " return r.marginMm === 12.5 && r.bandMm === 3; }", timeout=30_000)
    # A number out of range is refused in the page, naming the field; the plan is unchanged.
    version = state(page)["planVersion"]
    page.get_by_label("Margin (mm)").fill("0")
    page.get_by_label("Margin (mm)").press("Enter")
    page.wait_for_function("() => document.querySelector('.status').textContent.includes('Margin')")
    assert state(page)["planVersion"] == version


def test_an_edit_against_a_stale_version_is_refused_with_a_clear_message(page):
    """The page sends its edits against the newest version it knows; when another client got
    there first the server refuses (409) and the page says what happened. The race is made
    here by rewriting the edit's base version on its way out."""
    def stale(route):
        body = json.loads(route.request.post_data)
        body["baseVersion"] = "1"
        route.continue_(post_data=json.dumps(body))

    before = state(page)["planVersion"]
    page.route("**/edits", stale)
    press(page, "P")
    page.wait_for_function("() => document.querySelector('.status').textContent"
                           ".includes('The plan changed meanwhile')")
    page.unroute("**/edits")
    assert state(page)["planVersion"] == before


def centroid(points):
    return [sum(p[c] for p in points) / len(points) for c in "xyz"]


def test_a_new_resection_from_a_tumour_and_an_end_point_picked_on_the_liver(page):
    before = state(page)
    page.get_by_text("New resection").click()
    page.get_by_role("button", name="Pick on a view").click()
    # The liver fills the middle of the 3D view: a click there picks a point on its surface.
    box = page.locator("#view canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.32, box["y"] + box["height"] * 0.5)
    ends = [page.get_by_label(f"end point {c}").input_value() for c in "RAS"]
    assert all(e != "" for e in ends), ends
    assert page.get_by_label("Name").input_value() == "r2"
    page.get_by_role("button", name="Create").click()
    page.wait_for_function("() => 'r2' in window.resecta.state().resections", timeout=60_000)
    after = state(page)
    assert after["planVersion"] > before["planVersion"]
    assert len(after["resections"]["r2"]["controlPoints"]) == 16
    # The new resection is selected: the tools name it.
    page.wait_for_function(
        "() => [...document.querySelectorAll('h2')].some(e => e.textContent === 'Resection r2')")


def test_show_closest_point_turns_the_view_to_it(page):
    page.get_by_role("button", name="r1", exact=True).click()
    press(page, "Show closest point")
    page.wait_for_function("() => document.querySelector('.status').textContent.includes('closest')")
    want = state(page)["resections"]["r1"]["closestPoint"]
    got = page.evaluate("window.resecta.focalPoint()")
    assert math.dist([got[c] for c in "xyz"], [want[c] for c in "xyz"]) < 1e-6


def test_opacity_and_visibility_per_structure(page, tmp_path):
    page.get_by_text("Structures").click()
    page.get_by_label("opacity of parenchyma").fill("0")
    assert page.evaluate("window.resecta.look('parenchyma')")["opacity"] == 0
    page.get_by_label("parenchyma", exact=True).check()  # already shown: stays shown
    page.get_by_label("tumor_1", exact=True).uncheck()
    assert page.evaluate("window.resecta.look('tumor_1')")["visible"] is False
    page.get_by_label("tumor_1", exact=True).check()
    page.get_by_label("opacity of parenchyma").fill("35")
    assert page.evaluate("window.resecta.look('parenchyma')")["opacity"] == pytest.approx(0.35)


def test_plan_save_and_load_and_mesh_export(page, demo, tmp_path):
    server, sid = demo
    page.get_by_text("Files").click()
    with page.expect_download() as d:
        page.get_by_role("button", name="Save plan").click()
    saved = tmp_path / "plan.json"
    d.value.save_as(saved)
    doc = json.loads(saved.read_text())
    assert doc["format"] == "resecta-plan/1"
    kept = state(page)["resections"]
    # Another client deletes r2; loading the saved file brings the saved plan back.
    v = state(page)["planVersion"]
    r = requests.post(f"{server.http_url}/v1/sessions/{sid}/edits",
                      json={"baseVersion": str(v), "deleteResection": {"name": "r2"}}, timeout=60)
    assert r.status_code == 200, r.text
    page.wait_for_function("() => !('r2' in window.resecta.state().resections)", timeout=30_000)
    page.locator("input[type=file][accept^='.json']").set_input_files(str(saved))
    page.wait_for_function("() => 'r2' in window.resecta.state().resections", timeout=60_000)
    page.wait_for_function("() => document.querySelector('.status').textContent.startsWith('Plan loaded')")
    back = state(page)["resections"]
    assert all(math.dist([p[c] for c in "xyz"], [q[c] for c in "xyz"]) < 1e-9
               for p, q in zip(back["r2"]["controlPoints"], kept["r2"]["controlPoints"], strict=True))
    # The resection's mesh as binary STL: 84 bytes of header and count, 50 per triangle.
    page.get_by_label("Surface").select_option("r1")
    page.get_by_label("File format").select_option("MODEL_FORMAT_STL")
    with page.expect_download() as d:
        page.get_by_role("button", name="Download").click()
    assert d.value.suggested_filename == "r1.stl"
    stl = tmp_path / "r1.stl"
    d.value.save_as(stl)
    data = stl.read_bytes()
    triangles = int.from_bytes(data[80:84], "little")
    assert triangles > 100 and len(data) == 84 + 50 * triangles


def test_a_wrong_token_is_answered_clearly_and_the_right_one_opens_the_page(browser, tmp_path):
    token = "correct-horse-battery-staple-42"
    server = Server("--demo", env={"RESECTA_TOKEN": token})
    try:
        auth = {"authorization": f"Bearer {token}"}
        wait_for(lambda: requests.get(f"{server.http_url}/v1/sessions", headers=auth, timeout=30)
                 .json().get("sessions"), timeout=120)
        page = browser.new_page()
        page.goto(server.bound["page"])
        page.get_by_text("This server needs a token").wait_for()
        page.locator("input[type=password]").fill("not-the-token-at-all")
        page.keyboard.press("Enter")
        page.get_by_text("The server refused the token").wait_for()
        page.locator("input[type=password]").fill(token)
        page.keyboard.press("Enter")
        page.wait_for_function("() => { const s = window.resecta.state();"
                               " return s && Object.keys(s.resections).length > 0; }", timeout=120_000)
        # The token is kept for the tab, never in the address.
        assert token not in page.url
        page.close()
    finally:
        server.stop()
