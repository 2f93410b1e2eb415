"""The browser client's planning interaction (#20) end to end: in Debian's Chromium (software
WebGL through SwiftShader), driven by Playwright, a real mouse drag on a control point of the
demo resection edits the plan on `resecta serve --demo`; Ctrl+Z and Ctrl+Y undo and redo it;
a drag elsewhere rotates the camera and edits nothing."""
import json
import math
import sys
import threading

import pytest
import requests

from browser_harness import browser, demo, open_page  # noqa: F401 (fixtures)
from conftest import ROOT
from server_harness import wait_for


class PythonWatcher:
    """A `resecta_client` (gRPC) watching the session in a thread: the plan versions and the
    resections each delta changed, as the Slicer module would see them."""

    def __init__(self, server, sid):
        sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))
        from resecta_client import Client

        self.client = Client(server.grpc_addr)
        self.watch = self.client.session(sid).watch()
        self.deltas = []  # (plan_version, changed names)
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        for u in self.watch:
            if u.kind == "delta":
                self.deltas.append((u.plan_version, set(u.changed)))

    def close(self):
        self.watch.stop()
        self.thread.join(timeout=10)
        self.client.close()


def state(page):
    return page.evaluate("window.resecta.state()")


def version(page):
    return int(state(page)["planVersion"])


def wait_version_above(page, v):
    page.wait_for_function(f"() => Number(window.resecta.state().planVersion) > {v}",
                           timeout=15_000)


def exported(server, sid):
    """The server's plan export: its version and its resections by name."""
    r = requests.get(f"{server.http_url}/v1/sessions/{sid}/plan", timeout=30)
    assert r.status_code == 200, r.text
    body = r.json()
    plan = json.loads(body["planJson"])
    return int(body["planVersion"]), {x["name"]: x for x in plan["resections"]}


def test_a_mouse_drag_moves_a_control_point_and_undo_redo_follow(demo, browser):
    server, sid = demo
    page, errors = open_page(browser, server)
    page.wait_for_function("() => window.resecta.screenPosition('r1', 1, 2) !== null",
                           timeout=60_000)
    page.wait_for_timeout(300)  # the first frame framed the camera
    before = state(page)
    v0 = int(before["planVersion"])
    grid = before["resections"]["r1"]["controlPoints"]
    assert len(grid) == 16
    watcher = PythonWatcher(server, sid)

    # A drag away from the grid rotates the camera: the point is drawn elsewhere, no edit.
    at0 = page.evaluate("window.resecta.screenPosition('r1', 1, 2)")
    page.mouse.move(60, 640)
    page.mouse.down()
    page.mouse.move(140, 600, steps=6)
    page.mouse.up()
    page.wait_for_timeout(200)
    at = page.evaluate("window.resecta.screenPosition('r1', 1, 2)")
    assert math.hypot(at["x"] - at0["x"], at["y"] - at0["y"]) > 5, "the camera did not rotate"
    assert version(page) == v0

    # Drag P_12 with the mouse: 40 px right, 30 px up, in steps (coalesced edits).
    page.mouse.move(at["x"], at["y"])
    page.mouse.down()
    for k in range(1, 11):
        page.mouse.move(at["x"] + 4 * k, at["y"] - 3 * k)
    page.mouse.up()
    wait_version_above(page, v0)
    # The last position wins: once the edits are all answered, the page, the server's plan
    # and the pointer agree.
    target = page.evaluate("window.resecta.state().resections.r1.controlPoints[6]")
    wait_for(lambda: exported(server, sid)[1]["r1"]["control_points"][6] == pytest.approx(
        [target["x"], target["y"], target["z"]], abs=1e-6), timeout=15)
    v1, plan = exported(server, sid)
    assert v1 > v0
    moved = plan["r1"]["control_points"][6]
    old = grid[6]
    assert math.dist(moved, [old["x"], old["y"], old["z"]]) > 1.0, "the point did not move"
    # Only P_12 moved.
    for k, p in enumerate(plan["r1"]["control_points"]):
        if k != 6:
            assert p == pytest.approx([grid[k]["x"], grid[k]["y"], grid[k]["z"]], abs=1e-9)
    # The point is drawn under the pointer where the drag ended.
    page.wait_for_function(f"() => Number(window.resecta.state().planVersion) >= {v1}",
                           timeout=15_000)
    end = page.evaluate("window.resecta.screenPosition('r1', 1, 2)")
    assert math.hypot(end["x"] - (at["x"] + 40), end["y"] - (at["y"] - 30)) < 2.0
    # A Python client watching the session saw the drag's edits, the last one included.
    wait_for(lambda: any(v >= v1 and "r1" in changed for v, changed in watcher.deltas), timeout=15)
    watcher.close()

    # Ctrl+Z undoes the last edit, Ctrl+Y redoes it: each moves the plan version on.
    page.keyboard.press("Control+z")
    wait_version_above(page, v1)
    v2 = version(page)
    assert exported(server, sid)[0] == v2
    page.keyboard.press("Control+y")
    wait_version_above(page, v2)
    v3, plan = exported(server, sid)
    assert v3 > v2
    assert plan["r1"]["control_points"][6] == pytest.approx(moved, abs=1e-9)
    assert not errors, errors
    page.close()


def test_a_shift_drag_moves_the_grabbed_points_group(demo, browser):
    """Shift+drag on an inner point moves the four inner points by one displacement, as one
    edit per coalesced position; the border ring stays."""
    server, sid = demo
    page, errors = open_page(browser, server)
    page.wait_for_function("() => window.resecta.screenPosition('r1', 2, 1) !== null",
                           timeout=60_000)
    page.wait_for_timeout(300)
    v0, plan = exported(server, sid)
    grid = plan["r1"]["control_points"]
    at = page.evaluate("window.resecta.screenPosition('r1', 2, 1)")
    page.keyboard.down("Shift")
    page.mouse.move(at["x"], at["y"])
    page.mouse.down()
    for k in range(1, 9):
        page.mouse.move(at["x"] - 3 * k, at["y"] + 4 * k)
    page.mouse.up()
    page.keyboard.up("Shift")
    wait_version_above(page, v0)
    shown = page.evaluate("window.resecta.state().resections.r1.controlPoints[9]")
    wait_for(lambda: exported(server, sid)[1]["r1"]["control_points"][9] == pytest.approx(
        [shown["x"], shown["y"], shown["z"]], abs=1e-6), timeout=15)
    _, plan = exported(server, sid)
    after = plan["r1"]["control_points"]
    d = [a - b for a, b in zip(after[9], grid[9])]
    assert math.hypot(*d) > 1.0, "the group did not move"
    inner = {5, 6, 9, 10}
    for k in range(16):
        want = [g + (dk if k in inner else 0.0) for g, dk in zip(grid[k], d)]
        assert after[k] == pytest.approx(want, abs=1e-6), k
    assert not errors, errors
    page.close()
