"""ResectaLib on real MRML (slicer-core), without a server."""

import json
import threading

import numpy as np
import pytest
import vtk

import slicer
from conftest import load_phantom_segmentation
from ResectaLib import (coalesce, controlgrid, dispatch, margin, models, phantom, planfile, preview,
                        segmentation, volumetry)


# --- segmentation → label map ----------------------------------------------------------------


def test_segmentation_to_labelmap_keeps_the_oblique_grid(scene, phantom):
    nib = pytest.importorskip("nibabel")
    _lm, seg = load_phantom_segmentation(scene, phantom)
    ids = [sid for sid, _ in segmentation.segments_of(seg)]
    lm = segmentation.labelmap_from_segmentation(seg, dict(zip(ids, ["parenchyma", "tumor", "portal"])))
    assert lm.roles == {"parenchyma": [1], "tumor": [2], "portal": [3]}
    img = nib.load(phantom)
    truth = np.asarray(img.dataobj).transpose(2, 1, 0)  # [k, j, i]
    # Same spacing and direction as the file (NIfTI stores float32: 1e-5 relative).
    assert np.allclose(lm.ijk_to_ras[:3, :3], img.affine[:3, :3], rtol=1e-5, atol=1e-5)
    assert np.allclose(lm.spacing, (2, 2, 3), atol=1e-5)
    # Every voxel of the merged map lies on a voxel of the file with the same label.
    kji = np.argwhere(np.ones_like(lm.labels, dtype=bool))
    ras = lm.ijk_to_ras @ np.c_[kji[:, ::-1], np.ones(len(kji))].T
    ijk = np.linalg.solve(img.affine, ras).T[:, :3]
    assert np.abs(ijk - np.round(ijk)).max() < 1e-3
    ijk = np.round(ijk).astype(int)
    inside = np.all((ijk >= 0) & (ijk < truth.shape[::-1]), axis=1)
    got = lm.labels.reshape(-1)[inside]
    want = truth[ijk[inside, 2], ijk[inside, 1], ijk[inside, 0]]
    assert np.array_equal(got, want)
    assert (lm.labels > 0).sum() == (truth > 0).sum()  # nothing cropped away
    for role, label in (("parenchyma", 1), ("tumor", 2), ("portal", 3)):
        assert lm.role_volume_ml(role) == pytest.approx((truth == label).sum() * 0.012, rel=1e-5)


def test_labels_follow_the_role_table_and_ignore(scene):
    labels, ijk, names, _truth = phantom.make()
    seg = segmentation.segmentation_from_labelmap_array(scene, labels, ijk, names)
    table = segmentation.default_role_table(seg)
    by_name = {name: sid for sid, name in segmentation.segments_of(seg)}
    assert table[by_name["liver"]] == "parenchyma" and table[by_name["tumour"]] == "tumor"
    table[by_name["portal vein"]] = segmentation.IGNORE
    lm = segmentation.labelmap_from_segmentation(seg, table)
    assert sorted(lm.roles) == ["parenchyma", "tumor"]
    assert set(np.unique(lm.labels)) == {0, 1, 2}
    # the input's own grid comes back (oblique, anisotropic)
    assert np.allclose(lm.ijk_to_ras[:3, :3], ijk[:3, :3], atol=1e-9)
    assert (lm.labels == 2).sum() == (labels == 2).sum()


def test_segmentation_under_a_transform_is_uploaded_in_world_coordinates(scene):
    labels, ijk, names, _truth = phantom.make()
    seg = segmentation.segmentation_from_labelmap_array(scene, labels, ijk, names)
    transform = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode")
    m = vtk.vtkMatrix4x4()
    m.SetElement(0, 3, 12.5)
    transform.SetMatrixTransformToParent(m)
    seg.SetAndObserveTransformNodeID(transform.GetID())
    lm = segmentation.labelmap_from_segmentation(seg, segmentation.default_role_table(seg))
    assert np.allclose(lm.ijk_to_ras[:3, :3], ijk[:3, :3], atol=1e-9)
    origin_shift = lm.ijk_to_ras[:3, 3] - (ijk[:3, :3] @ np.zeros(3) + ijk[:3, 3])
    # the merged map is padded/cropped by whole voxels; modulo that the shift is +12.5 in R
    steps = np.linalg.solve(ijk[:3, :3], origin_shift - [12.5, 0, 0])
    assert np.allclose(steps, np.round(steps), atol=1e-6)


@pytest.mark.parametrize("table,message", [
    ({}, "no segment is mapped"),
    ("tumour-only", "parenchyma"),
    ("bad-role", "unknown role"),
])
def test_bad_role_tables_are_refused(scene, table, message):
    labels, ijk, names, _truth = phantom.make()
    seg = segmentation.segmentation_from_labelmap_array(scene, labels, ijk, names)
    ids = {name: sid for sid, name in segmentation.segments_of(seg)}
    if table == "tumour-only":
        table = {ids["tumour"]: "tumor"}
    elif table == "bad-role":
        table = {ids["liver"]: "spleen"}
    with pytest.raises(ValueError, match=message):
        segmentation.labelmap_from_segmentation(seg, table)


def test_role_guesses():
    g = segmentation.guess_role
    assert [g("Liver"), g("tumor 1"), g("Lesion"), g("Portal vein"), g("Hepatic veins"),
            g("IVC"), g("vessels"), g("spleen")] == [
        "parenchyma", "tumor", "tumor", "portal", "hepatic", "hepatic", "vessel", "ignore"]


# --- model nodes ------------------------------------------------------------------------------


def _grid_mesh(n=5, z=0.0):
    u, v = np.meshgrid(np.arange(n, dtype=np.float32), np.arange(n, dtype=np.float32), indexing="ij")
    pos = np.stack([u.ravel(), v.ravel(), np.full(n * n, z, np.float32)], axis=1)
    tri = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            tri += [(a, a + n, a + 1), (a + 1, a + n, a + n + 1)]
    return pos, np.array(tri, dtype=np.uint32)


def _surface(name, kind, pos, tri, normals=None, margins=None, classes=None):
    from resecta_client import SurfaceState

    return SurfaceState(name, kind, 0, None, pos, normals, tri, margins, classes)


def test_models_are_updated_in_place_and_rebuilt_on_new_topology(scene):
    up = models.ModelUpdater(scene, "s1")
    pos, tri = _grid_mesh()
    normals = np.tile([0, 0, 1], (len(pos), 1)).astype(np.float32)
    marg = np.linspace(0, 20, len(pos)).astype(np.float32)
    cls = np.ones(len(pos), np.uint8)
    node = up.upsert(_surface("r1", "resection", pos, tri, normals, marg, cls))
    poly = node.GetPolyData()
    margins_array = poly.GetPointData().GetArray(models.MARGIN_ARRAY)
    points_array = poly.GetPoints().GetData()
    # Rows only (not in the update's `rebuilt`): the same arrays, new values.
    node2 = up.upsert(_surface("r1", "resection", pos + 1, tri, normals, marg + 1, cls * 3),
                      rebuild=False)
    assert node2 is node and node.GetPolyData() is poly
    assert poly.GetPointData().GetArray(models.MARGIN_ARRAY) is margins_array
    assert poly.GetPoints().GetData() is points_array
    got = models.polydata_arrays(node)
    assert np.allclose(got["positions"], pos + 1) and np.allclose(got[models.MARGIN_ARRAY], marg + 1)
    assert (got[models.CLASS_ARRAY] == 3).all()
    assert up.rebuilds["r1"] == 1 and up.updates["r1"] == 1
    pos3, tri3 = _grid_mesh(6)
    # A new mesh: rebuilt in the same polydata object, even when asked for rows only.
    node3 = up.upsert(_surface("r1", "resection", pos3, tri3), rebuild=False)
    assert node3 is node and node.GetPolyData() is poly and up.rebuilds["r1"] == 2
    assert poly.GetNumberOfPoints() == len(pos3) and poly.GetNumberOfPolys() == len(tri3)
    assert len(models.model_nodes(scene)) == 1
    display = node.GetDisplayNode()
    assert display.GetActiveScalarName() == models.CLASS_ARRAY and display.GetScalarVisibility()
    table = scene.GetNodeByID(display.GetColorNodeID())
    assert table.GetName() == models.MARGIN_COLOR_TABLE_NAME and table.GetNumberOfColors() == 4
    rgba = [0.0] * 4
    table.GetColor(3, rgba)
    assert rgba[0] > 0.8 and rgba[1] < 0.2  # violation is red
    table.GetColor(2, rgba)
    assert rgba[0] > 0.9 and rgba[1] > 0.8 and rgba[2] < 0.1  # warning is yellow
    up.upsert(_surface("r2", "resection", pos, tri))
    assert scene.GetNumberOfNodesByClass("vtkMRMLColorTableNode") >= 1
    names = [scene.GetNthNodeByClass(i, "vtkMRMLColorTableNode").GetName()
             for i in range(scene.GetNumberOfNodesByClass("vtkMRMLColorTableNode"))]
    assert names.count(models.MARGIN_COLOR_TABLE_NAME) == 1
    assert up.remove("r2") and not up.remove("r2")


def test_model_palette_and_opacity(scene):
    up = models.ModelUpdater(scene, "s1")
    pos, tri = _grid_mesh()
    liver = up.upsert(_surface("parenchyma", "parenchyma", pos, tri))
    tumour = up.upsert(_surface("tumor_1", 2, pos, tri))
    assert tumour.GetAttribute(models.KIND_ATTRIBUTE) == "tumor"
    assert np.allclose(liver.GetDisplayNode().GetColor(), models.PALETTE["parenchyma"][0])
    assert liver.GetDisplayNode().GetVisibility2D()
    up.set_opacity(("parenchyma",), 0.2)
    assert liver.GetDisplayNode().GetOpacity() == pytest.approx(0.2)
    assert tumour.GetDisplayNode().GetOpacity() == pytest.approx(1.0)
    # another session's nodes are not touched
    other = models.ModelUpdater(scene, "s2")
    assert models.find_model(scene, "parenchyma", "s2") is None
    assert other.upsert(_surface("parenchyma", "parenchyma", pos, tri)) is not liver


# --- control grid -----------------------------------------------------------------------------


def test_control_grid_is_row_major_in_u_then_v(scene):
    m, n = 3, 5
    cps = np.array([[(10 * i, j, 0.0) for j in range(n)] for i in range(m)])  # P_ij = (10i, j, 0)
    node = controlgrid.make_grid_node(scene, "r1", cps.reshape(-1, 3), m, n)
    assert node.GetNumberOfControlPoints() == m * n
    for i in range(m):
        for j in range(n):
            k = controlgrid.index(i, j, n)
            assert node.GetNthControlPointLabel(k) == f"P{i},{j}"
            assert np.allclose(controlgrid.control_point(node, k), (10 * i, j, 0))
            assert controlgrid.ij(k, n) == (i, j)
    assert np.allclose(controlgrid.grid_points(node), cps.reshape(-1, 3))
    controlgrid.set_grid(node, cps[:2].reshape(-1, 3), 2, n)  # shrinks in place
    assert controlgrid.grid_shape(node) == (2, n) and node.GetNumberOfControlPoints() == 2 * n
    assert [controlgrid.ring_of(k, 4, 4) for k in range(16)] == [
        0, 0, 0, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 0, 0, 0]
    poly = controlgrid.net_polydata(cps, m, n)
    assert poly.GetNumberOfLines() == m * (n - 1) + n * (m - 1)


def test_control_grid_matches_the_client_resection_layout():
    client = pytest.importorskip("resecta_client")
    from resecta_client._gen import common_pb2, resection_pb2

    pts = [common_pb2.Vec3(x=i, y=j, z=0) for i in range(3) for j in range(4)]
    r = client.Resection.from_pb(resection_pb2.Resection(name="r", grid_m=3, grid_n=4, control_points=pts))
    flat = r.control_points.reshape(-1, 3)
    for k in range(12):
        i, j = controlgrid.ij(k, 4)
        assert tuple(flat[k][:2]) == (i, j) == tuple(r.control_points[i, j][:2])


# --- coalescer, dispatch ----------------------------------------------------------------------


def test_coalescer_keeps_one_edit_in_flight_and_the_latest_position_per_point():
    sent = []
    c = coalesce.EditCoalescer(lambda key, value: sent.append((key, value)))
    c.push("a", 1)
    assert sent == [("a", 1)] and c.busy
    for v in (2, 3, 4):
        c.push("a", v)
    c.push("b", 10)
    c.push("a", 5)
    assert sent == [("a", 1)] and c.pending == {"a": 5, "b": 10}
    c.done()
    assert sent[-1] == ("a", 5)  # oldest key first, newest value
    c.done()
    assert sent[-1] == ("b", 10)
    c.done()
    assert not c.busy and c.pushed == 6 and c.sent == 3 and c.dropped == 3
    c.push("a", 6)
    c.push("a", 7)
    c.clear()
    c.done()
    assert sent[-1] == ("a", 6) and not c.busy


def test_thread_dispatcher_delivers_on_the_polling_thread():
    d = dispatch.ThreadDispatcher()
    main = threading.get_ident()
    seen = []
    d.submit(lambda: threading.get_ident(), lambda worker: seen.append((worker, threading.get_ident())))
    d.submit(lambda: 1 / 0, None, lambda exc: seen.append(type(exc)))
    d.wait_until(lambda: len(seen) == 2, 10)
    assert seen[0][0] != main and seen[0][1] == main and seen[1] is ZeroDivisionError
    d.submit(lambda: 1 / 0)  # no error callback: kept
    d.wait_until(lambda: d.errors, 10)
    with pytest.raises(TimeoutError):
        d.wait_until(lambda: False, 0.05)
    d.shutdown()
    s = dispatch.SyncDispatcher()
    out = []
    s.submit(lambda: 2, out.append)
    s.submit(lambda: 1 / 0, None, lambda e: out.append("err"))
    assert out == [2, "err"]


# --- margin indicator, volumetry, plans, preview -----------------------------------------------


class V:
    def __init__(self, d, violation=None, point=(1, 2, 3), uncertainty=None):
        self.min_margin_mm, self.point = d, None if d is None else np.array(point, float)
        self.margin_uncertainty_mm = uncertainty
        self.violation = violation if violation is not None else (d is not None and d < 10)


def test_margin_indicator():
    assert margin.indicator({}) == margin.NONE and not margin.NONE.can_jump
    assert margin.indicator({"r1": (10.0, V(None))}).state == "none"
    ok = margin.indicator({"r1": (10.0, V(12.3)), "r2": (5.0, V(6.0, violation=False))})
    assert ok.state == "ok" and ok.color == margin.GREEN and ok.resection == "r2"
    assert "6.0 mm" in ok.text and ok.can_jump and ok.point == (1.0, 2.0, 3.0)
    bad = margin.indicator({"r1": (10.0, V(12.3)), "r2": (10.0, V(9.5, point=(4, 5, 6)))})
    assert bad.state == "violation" and bad.color == margin.RED and bad.resection == "r2"
    assert bad.point == (4.0, 5.0, 6.0) and "9.5 mm < 10 mm" in bad.text
    # The distance to the voxels as cubes, and how much farther the nearest voxel centre may be.
    sure = margin.indicator({"r1": (10.0, V(11.04, uncertainty=0.58))})
    assert sure.text == "r1: min. margin 11.0 (+0.6) mm ≥ 10 mm" and sure.uncertainty_mm == 0.58


class RV:
    def __init__(self, name, ml, complete=True, reason=""):
        self.name, self.resected_ml, self.complete_cut, self.incomplete_reason = name, ml, complete, reason
        self.resected_pct = None


class Vol:
    def __init__(self, total, remnant, resections, flr=False, threshold=30.0):
        self.total_ml, self.remnant_ml, self.resections = total, remnant, resections
        self.remnant_pct = None if remnant is None else 100 * remnant / total
        self.resected_ml = None if remnant is None else total - remnant
        self.flr_warning, self.flr_threshold_pct, self.plan_version = flr, threshold, 7


def test_volume_table():
    t = volumetry.table(Vol(1000.0, 250.0, [RV("r1", 750.0)], flr=True))
    assert [r.label for r in t.rows] == ["Total liver", "Resected by r1", "Remnant (FLR)"]
    assert t.row("Remnant (FLR)").cells() == ("Remnant (FLR)", "250.0", "25.0")
    assert t.row("Resected by r1").cells()[2] == "75.0"
    assert t.flr_warning and t.row("Remnant (FLR)").warning and "FLR warning" in t.messages[0]
    assert t.plan_version == 7
    t = volumetry.table(Vol(1000.0, None, [RV("r1", None, False, "the surface ends inside"),
                                           RV("r2", 100.0)]))
    assert t.row("Remnant (FLR)").cells()[1:] == ("—", "—")
    assert t.row("Resected (all)").ml is None and "r1: incomplete cut" in t.messages[0]
    assert not t.flr_warning


def test_plan_files(tmp_path):
    text = json.dumps({"format": "resecta-plan/1", "roles": {"parenchyma": [1]}, "resections": []})
    path = planfile.save(tmp_path / "p.json", text)
    assert planfile.load(path) and planfile.resection_names(text) == []
    for bad in ("not json", json.dumps({"format": "other"}), json.dumps([1])):
        with pytest.raises(ValueError):
            planfile.check(bad)


def test_preview_contour_of_a_sphere():
    src = vtk.vtkSphereSource()
    src.SetRadius(20.0)
    src.SetThetaResolution(64)
    src.SetPhiResolution(64)
    src.Update()
    sphere = src.GetOutput()
    tri = vtk.vtkTriangleFilter()
    tri.SetInputData(sphere)
    tri.Update()
    assert np.allclose(preview.mesh_centroid(tri.GetOutput()), 0, atol=1e-6)
    point, normal = preview.initial_plane((0, 0, 0), (0, 0, 20))  # plane z = 10
    assert np.allclose(point, (0, 0, 10)) and np.allclose(normal, (0, 0, 1))
    c = preview.contour(sphere, point, normal)
    from vtk.util import numpy_support
    pts = numpy_support.vtk_to_numpy(c.GetPoints().GetData())
    assert c.GetNumberOfLines() >= 1
    assert np.allclose(pts[:, 2], 10, atol=1e-6)
    assert np.allclose(np.linalg.norm(pts[:, :2], axis=1), np.sqrt(400 - 100), atol=0.3)
    with pytest.raises(ValueError):
        preview.initial_plane((0, 0, 0), (0, 0, 0.5))


def test_phantom_truth_matches_its_voxels():
    labels, ijk, _names, truth = phantom.make()
    voxel_ml = abs(np.linalg.det(ijk[:3, :3])) / 1000
    assert (labels > 0).sum() * voxel_ml == pytest.approx(truth["liver_ml"], rel=0.03)
    assert (labels == 2).sum() * voxel_ml == pytest.approx(4 / 3 * np.pi * 8 ** 3 / 1000, rel=0.1)


# --- DS / CP traces (ResectaLib.traces), metrics rows ----------------------------------------


def test_trace_slices_and_snapping():
    from ResectaLib import traces

    axial = [(0.0, 0.0, 5.0), (10.0, 3.0, 5.004), (20.0, -2.0, 4.998)]
    assert traces.slice_orientation(axial) == "axial"
    assert np.all(traces.ds_trace(axial)[:, 2] == 5.0)  # set to the median exactly
    assert traces.slice_orientation([(1.0, 0.0, 0.0), (1.0, 5.0, 3.0), (1.0, 9.0, -2.0)]) == "sagittal"
    assert traces.slice_orientation([(0.0, 7.0, 0.0), (5.0, 7.0, 3.0), (9.0, 7.0, -2.0)]) == "coronal"
    with pytest.raises(ValueError, match="not on one axial"):
        traces.ds_trace([(0.0, 0.0, 0.0), (1.0, 1.0, 0.02), (2.0, 0.0, 0.04)])
    with pytest.raises(ValueError, match="at least 3 points"):
        traces.to_trace("cp", [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0)])
    t = [np.zeros((3, 3)), np.ones((4, 3))]
    assert traces.trace_index(t, np.ones((4, 3))) == 1 and traces.trace_index(t, np.ones((3, 3))) is None


def test_plane_normal_against_the_vertex_normals_and_the_offset():
    from ResectaLib import traces

    ring = [(2.0, 10 * np.cos(a), 10 * np.sin(a)) for a in np.linspace(0, 6, 12)]
    for sign in (1.0, -1.0):
        n = traces.plane_normal([ring], np.tile((sign, 0.0, 0.0), (5, 1)))
        assert np.allclose(n, (-sign, 0.0, 0.0))
    grid = np.array([(2.0, y, z) for y in range(-10, 11) for z in range(-10, 11)], float)
    offset, vertex = traces.deformation_offset((7.0, 3.2, -4.1), grid, np.array((-1.0, 0.0, 0.0)))
    assert offset == pytest.approx(-5.0) and np.allclose(vertex, (2.0, 3.0, -4.0))
    offset, _ = traces.deformation_offset((500.0, 0.0, 0.0), grid, np.array((1.0, 0.0, 0.0)))
    assert offset == traces.MAX_OFFSET_MM


def test_curve_and_handle_nodes(scene):
    from ResectaLib import traces

    ds = traces.make_curve_node(scene, "d1", "ds", "s1")
    cp = traces.make_curve_node(scene, "c1", "cp")
    assert ds.IsA("vtkMRMLMarkupsCurveNode") and not ds.IsA("vtkMRMLMarkupsClosedCurveNode")
    assert cp.IsA("vtkMRMLMarkupsClosedCurveNode") and traces.is_trace(cp)
    assert (ds.GetAttribute(traces.TRACE_ATTRIBUTE), ds.GetAttribute(traces.TRACE_KIND_ATTRIBUTE),
            ds.GetAttribute(traces.SESSION_ATTRIBUTE)) == ("d1", "ds", "s1")
    for p in [(0.0, 0.0, 1.0), (10.0, 5.0, 1.0), (20.0, 0.0, 1.0)]:
        ds.AddControlPointWorld(vtk.vtkVector3d(*p))
    pts = traces.curve_points(ds)
    assert len(pts) > 3 and np.allclose(pts[:, 2], 1.0) and np.allclose(pts[[0, -1]], [(0, 0, 1), (20, 0, 1)])
    with pytest.raises(ValueError):
        traces.make_curve_node(scene, "x", "bezier")
    handle = traces.make_handle_node(scene, "c1", (1.0, 2.0, 3.0))
    assert np.allclose(traces.handle_point(handle), (1, 2, 3))
    assert traces.handle_point(traces.make_handle_node(scene, "c2")) is None


def test_metric_rows():
    from types import SimpleNamespace as NS

    metrics = NS(margin_deviation_mm=-1.25, volume_deviation_pct=None,
                 median_abs_mean_curvature_per_mm=0.00312)
    volumes = NS(resections=[NS(name="d", metrics=metrics), NS(name="r", metrics=None)])
    rows = volumetry.metric_rows(volumes, {"d": "ds"})
    assert rows[0].cells() == ("d", "DS", "-1.2 mm", "0.0031 mm⁻¹")
    assert rows[1].cells() == ("r", "Bézier", "—", "—")
    assert volumetry.metric_rows(None, {}) == ()
