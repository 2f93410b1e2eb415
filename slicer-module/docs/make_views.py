"""Renders the README's pictures of the views as Slicer draws them (PNG, offscreen):

- `view3d.png`: the demo patient's models and its resection (as the demo makes it: too close to
  the tumour) in a 3D view, margin colours on the resection surface, the margin indicator drawn
  over the view (top left) as the panel's button shows it;
- `slice_axial.png`: the axial slice view through the tumour, the models' intersections;
- `view3d_kept.png`: the same 3D view after the resection was moved 8 mm away from the tumour
  (the margin is kept; the warning band remains).

It starts `resecta serve --demo` (on free loopback ports, sessions in memory), follows the demo
session with the Python client (`resecta_client`), applies its updates to an MRML scene with the
module's own `WatchApplier` (model nodes by `ResectaLib.models.ModelUpdater`, the control grid as
a markups node), and renders them through Slicer's displayable managers from
PyPI's `slicer-core` (`tests/offscreen.py`, the set-up the rendering tests use).

Run from the repository root: python slicer-module/docs/make_views.py
(the server binary: $RESECTA_BIN, else target/debug/resecta, else `resecta` on PATH).
"""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import vtk

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
sys.path[:0] = [str(HERE.parent / "Resecta"), str(HERE.parent / "tests"),
                str(REPO / "clients" / "python" / "src")]

import slicer  # noqa: E402
from resecta_client import Client  # noqa: E402

import offscreen  # noqa: E402
from ResectaLib import margin, models  # noqa: E402
from ResectaLib.gridsync import GridSync  # noqa: E402
from ResectaLib.sceneupdate import WatchApplier  # noqa: E402

DEMO_SESSION = "demo patient (phantom)"
TUMOUR_CENTRE = (40.0, -10.0, 5.0)  # the demo's large tumour (resecta-server/src/demo.rs)
SIZE_3D, SIZE_SLICE = (560, 400), (480, 360)


def server_binary() -> str:
    for candidate in (os.environ.get("RESECTA_BIN"), REPO / "target" / "debug" / "resecta",
                      shutil.which("resecta")):
        if candidate and Path(candidate).is_file():
            return str(candidate)
    sys.exit("no resecta binary: build it (cargo build) or set RESECTA_BIN")


def start_demo_server() -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([server_binary(), "serve", "--demo", "--grpc", "127.0.0.1:0",
                             "--http", "127.0.0.1:0"], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "RUST_LOG": "warn"})
    line = proc.stdout.readline()
    if not line:
        proc.kill()
        sys.exit("resecta serve --demo did not start")
    return proc, json.loads(line)["grpc"]


def demo_session_id(client, timeout=120.0) -> str:
    """The demo session's id, once its models and resection are made (the server seeds it in
    the background after start-up)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for info in client.list_sessions():
            if info.display_name == DEMO_SESSION and info.plan_version >= 1:
                return info.id
        time.sleep(0.5)
    sys.exit("the demo session did not appear")


def follow(watch, applier, until):
    """Applies Watch updates to the scene as the module does, until `until(update)`."""
    for update in watch:
        applier.enqueue(update)
        applier.flush(watch.scene)
        if until(update):
            return


def indicator_overlay(view, watch_scene):
    """The margin indicator (the panel's button: text on its colour) drawn top left."""
    state = margin.indicator({n: (s.resection.margin_mm, s.verdict)
                              for n, s in watch_scene.resections.items()})
    text = vtk.vtkTextActor()
    text.SetInput(f" {state.text} ")
    prop = text.GetTextProperty()
    prop.SetFontSize(17)
    prop.SetColor(1, 1, 1)
    prop.SetBackgroundColor(*(int(state.color[i:i + 2], 16) / 255 for i in (1, 3, 5)))
    prop.SetBackgroundOpacity(1.0)
    prop.SetFrameColor(1, 1, 1)
    prop.SetVerticalJustificationToTop()
    text.SetDisplayPosition(10, view.size[1] - 10)
    view.renderer.AddViewProp(text)
    return text, state


def render_3d(view, watch_scene, path: Path) -> str:
    overlay, state = indicator_overlay(view, watch_scene)
    view.save_png(path)
    view.renderer.RemoveViewProp(overlay)
    return state.text


def render_slice(scene, path: Path) -> None:
    view = offscreen.SliceView(scene, "Axial", size=SIZE_SLICE)
    try:
        bounds = [0.0] * 6
        models.find_model(scene, "parenchyma").GetRASBounds(bounds)
        centre = ((bounds[0] + bounds[1]) / 2, (bounds[2] + bounds[3]) / 2, TUMOUR_CENTRE[2])
        view.show(centre, 1.1 * (bounds[1] - bounds[0]))
        view.save_png(path)
    finally:
        view.close()


def main() -> None:
    proc, address = start_demo_server()
    scene = slicer.vtkMRMLScene()
    view = offscreen.ThreeDView(scene, SIZE_3D, markups=True)
    try:
        with Client(address) as client:
            session = client.session(demo_session_id(client))
            grids = GridSync(scene, session.id, on_drag=lambda *a: None, busy=lambda n: False,
                             on_released=lambda: None)
            applier = WatchApplier(models.ModelUpdater(scene, session.id), grids)
            with session.watch() as watch:
                follow(watch, applier,  # every model, the resection with its verdict
                       until=lambda u: any(r.verdict for r in watch.scene.resections.values()))
                names = sorted(watch.scene.surfaces)
                print("surfaces:", ", ".join(names))
                view.fit(azimuth=-50, elevation=15, zoom=1.3)
                print("view3d.png:", render_3d(view, watch.scene, HERE / "view3d.png"))
                render_slice(scene, HERE / "slice_axial.png")
                name = next(iter(watch.scene.resections))
                away = np.subtract(watch.scene.resections[name].positions.mean(0), TUMOUR_CENTRE)
                away[2] = 0.0
                result = session.translate(name, tuple(8.0 * away / np.linalg.norm(away)))
                follow(watch, applier,
                       until=lambda u: u.plan_version >= result.plan_version and name in u.changed)
                print("view3d_kept.png:", render_3d(view, watch.scene, HERE / "view3d_kept.png"))
    finally:
        view.close()
        proc.terminate()
        proc.wait(30)
    for p in ("view3d.png", "slice_axial.png", "view3d_kept.png"):
        print(f"{p}: {(HERE / p).stat().st_size // 1024} KiB")


if __name__ == "__main__":
    main()
