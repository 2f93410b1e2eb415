"""The browser client's DS and CP resections (thesis Paper II, Sec. 2.5) end to end in Chromium:
a DS resection drawn as traces on the slice view (held by the page until there are 3, then one
more added, one deleted, one redrawn), a CP resection from points clicked on the liver with one
deformation dragged on its surface and taken back; the server's plan holds them and the panel
shows each one's kind and the Sec. 7.4 metrics."""
import json

import pytest
import requests

from browser_harness import browser, demo, open_page  # noqa: F401 (fixtures)


def state(page):
    return page.evaluate("window.resecta.state()")


def plan_resections(server, sid):
    plan = requests.get(f"{server.http_url}/v1/sessions/{sid}/plan", timeout=30).json()
    return {r["name"]: r for r in json.loads(plan["planJson"])["resections"]}


def wait_for_resection(page, name, test, timeout=60_000):
    page.wait_for_function(
        f"() => {{ const r = window.resecta.state().resections[{json.dumps(name)}]; return r && ({test}); }}",
        timeout=timeout)
    return state(page)["resections"][name]


@pytest.fixture(scope="module")
def page(demo, browser):
    server, _ = demo
    p, errors = open_page(browser, server)
    p.wait_for_function("() => window.resecta.slice() !== null", timeout=30_000)
    yield p
    assert not errors, errors
    p.close()


def new_resection(page, name, method):
    page.get_by_text("New resection").click()
    page.get_by_label("Name").fill(name)
    page.get_by_label("Resection kind").select_option(method)
    page.get_by_role("button", name="Draw on slices" if method == "ds" else "Draw on the liver").click()
    page.wait_for_function(f"() => window.resecta.drawing()?.name === {json.dumps(name)}")


def go_to_slice(page, mm):
    """Moves the axial slice view to `mm` (the slider snaps to its step); waits for its raster."""
    page.get_by_label("Slice position").fill(str(mm))
    page.wait_for_function(
        "() => { const s = window.resecta.slice();"
        " return s && Math.abs(s.positionMm - Number(document.querySelector('.slice-bar input').value)) < 1e-9; }")
    return page.evaluate("window.resecta.slice().positionMm")


def draw_stroke(page, bend=0.0):
    """Drags across the middle of the slice view, left to right, a little bent."""
    box = page.locator(".slice-canvas").bounding_box()
    y = box["y"] + box["height"] * 0.5
    steps = 30
    page.mouse.move(box["x"] + box["width"] * 0.1, y)
    page.mouse.down()
    for k in range(1, steps + 1):
        t = k / steps
        page.mouse.move(box["x"] + box["width"] * (0.1 + 0.8 * t), y + box["height"] * bend * t * (1 - t))
    page.mouse.up()


def test_a_ds_resection_is_drawn_on_slices(page, demo):
    server, sid = demo
    page.get_by_role("button", name="Axial", exact=True).click()
    new_resection(page, "ds1", "ds")
    slices = []
    for k, mm in enumerate((-20, 0, 20)):
        slices.append(go_to_slice(page, mm))
        version = state(page)["planVersion"]
        draw_stroke(page, bend=0.2)
        if k < 2:  # held by the page, drawn dashed on the slice view
            page.wait_for_function(f"() => window.resecta.drawing().traces.length === {k + 1}")
            assert page.evaluate("window.resecta.slice().traces") == 1
            assert state(page)["planVersion"] == version
    ds = wait_for_resection(page, "ds1", "r.traces.length === 3")
    assert ds["kind"] == "RESECTION_KIND_DS"
    # Watchers see the resection once computed, its edit is acknowledged once stored: the page
    # drops its drawing on the acknowledgement, which may come a moment later.
    page.wait_for_function("() => window.resecta.drawing() === null", timeout=10_000)
    for trace, z in zip(sorted(ds["traces"], key=lambda t: t[0]["z"]), slices):
        assert len(trace) >= 3 and all(abs(p["z"] - z) < 1e-6 for p in trace)
    # A fourth trace (addTrace), then the one on the first slice deleted (removeTrace) after
    # selecting it in the panel's list.
    go_to_slice(page, 35)
    draw_stroke(page, bend=-0.2)
    wait_for_resection(page, "ds1", "r.traces.length === 4")
    page.get_by_role("button", name=f"axial {slices[0]:.1f} mm", exact=True).click()
    page.wait_for_function(f"() => Math.abs(window.resecta.slice().positionMm - {slices[0]}) < 1e-6")
    page.get_by_role("button", name=f"Delete the trace on axial {slices[0]:.1f} mm").click()
    wait_for_resection(page, "ds1", f"r.traces.length === 3 && r.traces.every(t => Math.abs(t[0].z - {slices[0]}) > 0.01)")
    # Redrawn on its own slice (setTrace): still 3 traces, that one changed.
    go_to_slice(page, slices[1])
    before = next(t for t in state(page)["resections"]["ds1"]["traces"] if abs(t[0]["z"] - slices[1]) < 0.01)
    draw_stroke(page, bend=-0.3)
    ds = wait_for_resection(
        page, "ds1", f"r.traces.length === 3 && JSON.stringify(r.traces.find(t => Math.abs(t[0].z - {slices[1]}) < 0.01))"
        f" !== {json.dumps(json.dumps(before, separators=(',', ':')))}")
    held = plan_resections(server, sid)["ds1"]
    assert held["kind"] == "ds" and len(held["traces"]) == 3
    # The panel: its kind, and the metrics row once the volumes come.
    page.wait_for_function(
        "() => [...document.querySelectorAll('#panel tr')].some(r => r.textContent.startsWith('ds1') && r.textContent.includes('DS'))")
    metrics_row(page, "ds1")
    # Its surface spans 0 … 35 mm only: the volumes say it ends inside the liver.
    page.wait_for_function(
        "() => [...document.querySelectorAll('.incomplete')].some(e => e.textContent.startsWith('ds1') && e.textContent.includes('ends inside the liver'))",
        timeout=60_000)


def metrics_row(page, name):
    """The metrics table's row of `name` once it shows the margin deviation and median |H|."""
    page.wait_for_function(
        "name => [...document.querySelectorAll('table.metrics tr')].some(r => r.cells[0].textContent === name"
        " && r.cells[1].textContent.endsWith(' mm') && r.cells[2].textContent.endsWith('mm⁻¹'))",
        arg=name, timeout=60_000)


def test_a_cp_resection_from_points_on_the_liver_with_a_deformation(page, demo):
    server, sid = demo
    new_resection(page, "cp1", "cp")
    # Points clicked down the liver's front, as seen from anterior.
    box = page.locator("#view canvas").bounding_box()
    x0 = box["x"] + box["width"] * 0.42
    clicks = [(x0 + box["width"] * 0.02 * (k % 2), box["y"] + box["height"] * (0.3 + 0.05 * k)) for k in range(9)]
    for x, y in clicks:
        page.mouse.click(x, y)
    ring = page.evaluate("window.resecta.drawing().traces[0]")
    assert len(ring) >= 5, ring
    page.get_by_role("button", name="Finish").click()
    cp = wait_for_resection(page, "cp1", "r.traces.length === 1")
    assert cp["kind"] == "RESECTION_KIND_CP" and len(cp["traces"][0]) == len(ring)
    assert cp["deformations"] == []
    # The plane is about sagittal, seen edge-on from the front: turn the camera 45° about the
    # vertical with a drag on the background (vtk.js: about 0.5° per pixel of a 400 px view).
    page.mouse.move(box["x"] + 10, box["y"] + 60)
    page.mouse.down()
    for k in range(1, 10):
        page.mouse.move(box["x"] + 10 + 10 * k, box["y"] + 60)
    page.mouse.up()
    # A deformation: drag on the surface, 25 mm radius.
    page.get_by_label("Deformation radius (mm)").fill("25")
    y = clicks[4][1]
    hits = [(x, page.evaluate("([x, y]) => window.resecta.probe('cp1', x, y)", [x, y]))
            for x in range(int(box["x"] + box["width"] * 0.2), int(box["x"] + box["width"] * 0.7), 10)]
    x, probe = next((x, p) for x, p in hits if p)
    start = page.evaluate("k => window.resecta.vertexScreen('cp1', k)", probe["vertex"])
    page.mouse.move(x, y)
    page.mouse.down()
    for k in range(1, 11):
        page.mouse.move(x + 8 * k, y)
    page.mouse.up()
    cp = wait_for_resection(page, "cp1", "r.deformations.length === 1")
    d = cp["deformations"][0]
    assert d["radiusMm"] == 25 and d["offsetMm"] != 0
    # The vertex under the pointer moved the way the mouse did.
    page.wait_for_function(
        "([k, x]) => window.resecta.vertexScreen('cp1', k).x > x + 2", arg=[probe["vertex"], start["x"]], timeout=30_000)
    held = plan_resections(server, sid)["cp1"]
    assert held["kind"] == "cp" and len(held["deformations"]) == 1
    page.wait_for_function(
        "() => [...document.querySelectorAll('#panel tr')].some(r => r.textContent.startsWith('cp1') && r.textContent.includes('CP'))")
    metrics_row(page, "cp1")
    # Undo deformation takes it back.
    page.get_by_role("button", name="Undo deformation").click()
    wait_for_resection(page, "cp1", "r.deformations.length === 0")
    assert plan_resections(server, sid)["cp1"].get("deformations", []) == []
