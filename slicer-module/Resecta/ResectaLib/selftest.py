"""The module's scenario, run by the pytest suite (against `resecta serve`) and by the module's
self-test inside Slicer (`ResectaTest.runTest`), on real MRML nodes.

A segmentation of a phantom goes up; the models come back as model nodes where the phantom's
analytic shapes are; a resection made from the tumour and an end point brings a 4×4 control-grid
markups node; dragging a control point (a burst of positions, coalesced) updates the resection
model in place with new margin scalars; the volumetry table agrees with the server (and, given
`engine_check`, with the engine's own `resecta plan`); margin and band, translate, group moves
and rotation reach the plan; undo restores the earlier surface; the plan survives a save → delete
→ load round trip; resections export as mesh files.

`wait(predicate, timeout)` must keep delivering the dispatcher's results while it waits
(`ThreadDispatcher.wait_until`, or Slicer's event loop plus `dispatcher.poll()`). Every check
raises AssertionError with what was expected.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from . import controlgrid, models, phantom, segmentation
from .edits import grid_normal
from .logic import PlanningLogic

#: Tolerances of the geometric checks, mm. Models are reconstructed from 2×2×3 mm voxels: the
#: bounding box of a voxelised ellipsoid differs from the analytic one by up to about one voxel
#: (3 mm along the coarse axis); centroids average that out.
BOUNDS_TOL_MM = 3.5
CENTROID_TOL_MM = 1.0
TUMOUR_CENTROID_TOL_MM = 1.0


def _check(cond: bool, what: str) -> None:
    if not cond:
        raise AssertionError(what)


def _bounds(node) -> np.ndarray:
    b = [0.0] * 6
    node.GetPolyData().GetBounds(b)
    return np.array(b).reshape(3, 2)


def check_models(logic: PlanningLogic, truth: dict) -> dict:
    """Parenchyma and tumour model nodes are where the analytic shapes are."""
    from .preview import mesh_centroid

    out = {}
    liver = next((n for n in models.model_nodes(logic.scene, logic.session_id)
                  if n.GetAttribute(models.KIND_ATTRIBUTE) == "parenchyma"), None)
    _check(liver is not None, "no parenchyma model node")
    half = phantom.ellipsoid_half_extent(truth["liver"]["radii"], truth["liver"]["rotation"])
    c = truth["liver"]["center"]
    expected = np.stack([c - half, c + half], axis=1)
    got = _bounds(liver)
    err = np.abs(got - expected).max()
    _check(err <= BOUNDS_TOL_MM,
           f"liver model bounds {got.round(2).tolist()} vs analytic {expected.round(2).tolist()}: "
           f"{err:.2f} mm > {BOUNDS_TOL_MM} mm")
    out["liver_bounds_err_mm"] = float(err)
    centroid = mesh_centroid(liver.GetPolyData())
    cerr = float(np.linalg.norm(centroid - c))
    _check(cerr <= CENTROID_TOL_MM, f"liver centroid {centroid.round(2)} vs {c}: {cerr:.2f} mm")
    out["liver_centroid_err_mm"] = cerr
    tumours = logic.tumours()
    _check(len(tumours) == 1, f"expected one tumour model, got {tumours}")
    t = logic.tumour_centroid(tumours[0])
    terr = float(np.linalg.norm(t - truth["tumour"]["center"]))
    _check(terr <= TUMOUR_CENTROID_TOL_MM,
           f"tumour centroid {t.round(2)} vs {truth['tumour']['center']}: {terr:.2f} mm")
    out["tumour_centroid_err_mm"] = terr
    tb = _bounds(logic.model_node(tumours[0]))
    radius = (tb[:, 1] - tb[:, 0]).mean() / 2
    _check(abs(radius - truth["tumour"]["radius"]) <= BOUNDS_TOL_MM / 2 + 0.5,
           f"tumour model half-size {radius:.2f} mm vs radius {truth['tumour']['radius']}")
    for node in models.model_nodes(logic.scene, logic.session_id):
        kind = node.GetAttribute(models.KIND_ATTRIBUTE)
        display = node.GetDisplayNode()
        _check(display is not None and display.GetVisibility2D(),
               f"model {node.GetName()} has no slice intersection display")
        _check(np.allclose(display.GetColor(), models.PALETTE[kind][0], atol=1e-3),
               f"model {node.GetName()} colour {display.GetColor()}")
    return out


def run(scene, segmentation_node, truth: dict, dispatcher, wait: Callable[..., Any], *,
        address: str, token: str | None = None, tls: bool = False, ca_file: str | None = None,
        role_table: dict[str, str] | None = None, method: str = "psr",
        engine_check: Callable[[str, Any], None] | None = None,
        log: Callable[[str], None] = print, logic: PlanningLogic | None = None) -> str:
    """Runs the scenario; returns a one-line report. Leaves `logic` open when given one."""
    own = logic is None
    s = logic or PlanningLogic(scene, dispatcher)
    try:
        return _run(s, segmentation_node, truth, wait, address, token, tls, ca_file, role_table,
                    method, engine_check, log)
    finally:
        if own:
            s.close()


def _run(s: PlanningLogic, seg_node, truth, wait, address, token, tls, ca_file, role_table,
         method, engine_check, log) -> str:
    results: dict[str, Any] = {}

    def finished(key):
        return lambda value=None: results.__setitem__(key, value)

    def no_errors():
        if s.errors:
            raise AssertionError(f"the session reported an error: {s.errors[-1]!r}")
        return True

    log("connecting")
    s.connect(address, token, tls=tls, ca_file=ca_file, on_done=finished("info"))
    wait(lambda: no_errors() and "info" in results, 30)

    log("uploading the segmentation and building the models")
    table = role_table or segmentation.default_role_table(seg_node)
    s.upload_and_build(seg_node, table, method=method, on_done=finished("built"))
    wait(lambda: no_errors() and "built" in results and s.models_ready and s.tumours(), 300)
    report = check_models(s, truth)

    log("new resection from the tumour and an end point")
    tumour = s.tumours()[0]
    centre = s.tumour_centroid(tumour)
    end_point = centre + np.array([-40.0, 0.0, 0.0])
    s.preview(tumour, end_point)
    contour = s.scene.GetFirstNodeByName("Resecta preview contour")
    _check(contour is not None and contour.GetPolyData().GetNumberOfPoints() > 10,
           "no preview contour of the liver on the initial plane")
    s.new_resection("r1", tumour, end_point, margin_mm=10.0, band_mm=5.0, on_done=finished("init"))
    wait(lambda: no_errors() and "init" in results and "r1" in s.grids
         and s.model_node("r1") is not None, 60)
    grid = s.grids["r1"]
    _check(grid.GetNumberOfControlPoints() == 16, "the control grid is not 4×4")
    r1 = s.resection("r1")
    _check(np.allclose(controlgrid.grid_points(grid), r1.control_points.reshape(-1, 3), atol=1e-6),
           "the markups do not hold the resection's control points in row-major order")
    node = s.model_node("r1")
    poly = node.GetPolyData()
    points = poly.GetPoints().GetData()
    before = models.polydata_arrays(node)
    _check(models.MARGIN_ARRAY in before and models.CLASS_ARRAY in before,
           "the resection model has no margin scalars")
    _check(node.GetDisplayNode().GetActiveScalarName() == models.CLASS_ARRAY,
           "the resection is not coloured by its margin class")
    margin_before = s.margin_state.min_margin_mm
    _check(margin_before is not None, "no margin verdict for r1")

    log("dragging a control point (a burst of positions)")
    k = controlgrid.index(1, 1, 4)
    start = controlgrid.control_point(grid, k)
    toward = -grid_normal(s.resection("r1"))  # the surface normal faces the remnant, away from the tumour
    version_before = s.session.plan_version
    positions = [start + toward * d for d in np.linspace(1.0, 9.0, 9)]
    pushed_before, sent_before = s.edits.coalescer.pushed, s.edits.coalescer.sent
    for p in positions:
        grid.SetNthControlPointPosition(k, *p)
    target = positions[-1]

    def dragged():
        r = s.resection("r1")
        return (not s.edits.coalescer.busy and r is not None
                and np.allclose(r.control_points[1, 1], target, atol=1e-6)
                and not np.array_equal(models.polydata_arrays(node)[models.MARGIN_ARRAY],
                                       before[models.MARGIN_ARRAY]))

    wait(lambda: no_errors() and dragged(), 60)
    pushed = s.edits.coalescer.pushed - pushed_before
    sent = s.edits.coalescer.sent - sent_before
    _check(pushed == len(positions), f"{pushed} positions pushed, expected {len(positions)}")
    _check(1 <= sent <= pushed, f"{sent} edits sent for {pushed} positions")
    _check(s.model_node("r1") is node and node.GetPolyData() is poly
           and poly.GetPoints().GetData() is points,
           "the resection model was rebuilt for a drag: its arrays should be updated in place")
    after = models.polydata_arrays(node)
    _check(after["positions"].shape == before["positions"].shape, "vertex count changed")
    _check(not np.allclose(after["positions"], before["positions"]), "the surface did not move")
    _check(np.allclose(controlgrid.control_point(grid, k), target, atol=1e-6),
           "the dragged markups point was moved back")
    report["edits_sent_for_drag"] = f"{sent}/{pushed}"
    wait(lambda: s.margin_state.min_margin_mm is not None
         and s.margin_state.min_margin_mm < margin_before - 1e-6, 30)
    report["min_margin_mm"] = (round(margin_before, 2), round(s.margin_state.min_margin_mm, 2))

    log("volumes")
    server_volumes = {}
    s.call(s.session.volumes, finished("volumes"))
    wait(lambda: no_errors() and "volumes" in results
         and results["volumes"].plan_version >= s.session.plan_version
         and s.volume_table.plan_version >= results["volumes"].plan_version, 60)
    v = results["volumes"]
    if s.volume_table.plan_version != v.plan_version:  # the watch brought a newer report: re-ask
        results.pop("volumes")
        s.call(s.session.volumes, finished("volumes"))
        wait(lambda: no_errors() and "volumes" in results, 60)
        v = results["volumes"]
    row_total = s.volume_table.row("Total liver")
    _check(abs(row_total.ml - v.total_ml) < 1e-9, f"table total {row_total.ml} vs server {v.total_ml}")
    remnant = s.volume_table.row("Remnant (FLR)")
    _check(v.remnant_ml is not None and abs(remnant.ml - v.remnant_ml) < 1e-9,
           f"table remnant {remnant.ml} vs server {v.remnant_ml}")
    _check(abs(v.total_ml - truth["liver_ml"]) / truth["liver_ml"] < 0.03,
           f"total liver {v.total_ml:.2f} ml vs analytic {truth['liver_ml']:.2f} ml")
    server_volumes.update(total=v.total_ml, remnant=v.remnant_ml, resected=v.resected_ml)
    report["volumes_ml"] = {k2: round(x, 3) for k2, x in server_volumes.items() if x is not None}
    if engine_check is not None:
        results.pop("plan", None)
        s.call(s.session.export_plan, finished("plan"))
        wait(lambda: no_errors() and "plan" in results, 30)
        engine_check(results["plan"], v)

    log("margin and band, translate, group move, rotate")
    s.edits.set_margin_and_band("r1", 12.0, 4.0, on_done=finished("margin"))
    wait(lambda: no_errors() and "margin" in results and s.resection("r1").margin_mm == 12.0
         and s.resection("r1").band_mm == 4.0, 30)
    cp0 = s.resection("r1").control_points.copy()
    s.edits.translate("r1", (0.0, 0.0, 2.0), on_done=finished("translate"))
    wait(lambda: no_errors() and "translate" in results
         and np.allclose(s.resection("r1").control_points, cp0 + [0, 0, 2.0], atol=1e-6), 30)
    _check(np.allclose(controlgrid.grid_points(grid), (cp0 + [0, 0, 2.0]).reshape(-1, 3), atol=1e-6),
           "the markups did not follow the translation")
    cp1 = s.resection("r1").control_points.copy()
    s.edits.move_group("r1", "inner", (1.0, 0.0, 0.0), on_done=finished("group"))
    wait(lambda: no_errors() and "group" in results
         and not np.allclose(s.resection("r1").control_points, cp1), 30)
    moved = np.abs(s.resection("r1").control_points - cp1).sum(axis=2) > 1e-9
    _check(moved[1:3, 1:3].all() and moved.sum() == 4, "the inner group did not move alone")
    cp2 = s.resection("r1").control_points.copy()
    s.edits.rotate("r1", "S", 5.0, on_done=finished("rotate"))
    wait(lambda: no_errors() and "rotate" in results
         and not np.allclose(s.resection("r1").control_points, cp2), 30)
    c2 = cp2.reshape(-1, 3).mean(axis=0)
    c3 = s.resection("r1").control_points.reshape(-1, 3).mean(axis=0)
    _check(np.allclose(c2, c3, atol=1e-6), "rotation about the centroid moved the centroid")

    log("undo")
    s.edits.undo(on_done=finished("undo"))
    wait(lambda: no_errors() and "undo" in results
         and np.allclose(s.resection("r1").control_points, cp2, atol=1e-9)
         and np.allclose(controlgrid.grid_points(grid), cp2.reshape(-1, 3), atol=1e-6), 30)
    s.edits.redo(on_done=finished("redo"))
    wait(lambda: no_errors() and "redo" in results
         and not np.allclose(s.resection("r1").control_points, cp2), 30)
    rotated = s.resection("r1").control_points.copy()

    log("plan save → delete → load")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "plan.json"
        s.save_plan(path, on_done=finished("saved"))
        wait(lambda: no_errors() and "saved" in results and path.is_file(), 30)
        s.edits.delete("r1", on_done=finished("deleted"))
        wait(lambda: no_errors() and "deleted" in results and s.model_node("r1") is None
             and "r1" not in s.grids, 30)
        s.load_plan(path, on_done=finished("loaded"))
        wait(lambda: no_errors() and "loaded" in results and s.model_node("r1") is not None
             and "r1" in s.grids and s.resection("r1") is not None
             and np.allclose(s.resection("r1").control_points, rotated, atol=1e-9), 30)
        _check(s.resection("r1").margin_mm == 12.0, "the loaded plan lost the margin")

        log("export")
        s.export_resections(tmp, "vtp", on_done=finished("exported"))
        wait(lambda: no_errors() and "exported" in results, 60)
        files = results["exported"]
        _check(len(files) == 1 and files[0].stat().st_size > 1000, f"exported {files}")

    text = ", ".join(f"{k2}={v2}" for k2, v2 in report.items())
    log("done: " + text)
    return text
