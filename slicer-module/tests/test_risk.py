"""The vascular risk analysis in the scene, against a real `resecta serve` on the demo phantom
(the plane from end point (0, 30, 0) cuts the portal vein): the volume rows, the cut-vessel
markups, the risk and territory segmentations, the resectogram following the plan, and both
drawn through Slicer's displayable managers (`offscreen.py`)."""

import threading
import types

import numpy as np
import pytest
from vtk.util import numpy_support

import offscreen
from conftest import DEMO_ROLES
from ResectaLib import models, risk, volumetry

END = (0.0, 30.0, 0.0)


@pytest.fixture(scope="module")
def planned(planning_server, demo_phantom):
    """A PlanningLogic following a session of the demo phantom with resection r1."""
    import slicer
    from resecta_client import Client

    from ResectaLib.dispatch import ThreadDispatcher
    from ResectaLib.logic import PlanningLogic

    offscreen.register_segmentation_converters()  # as Slicer's Segmentations module does
    scene = slicer.vtkMRMLScene()
    dispatcher = ThreadDispatcher()
    client = Client(planning_server.grpc_addr)
    session = client.create_session("risk")
    session.upload_label_map_file(demo_phantom, DEMO_ROLES)
    session.init_from_end_point("r1", END)
    logic = PlanningLogic(scene, dispatcher)
    logic.connect(planning_server.grpc_addr)
    dispatcher.wait_until(lambda: logic.connected, 30)
    logic.open_session(session.id)
    dispatcher.wait_until(lambda: logic.volume_table.plan_version == session.plan_version
                          and "r1" in logic.surfaces(), 60)
    yield types.SimpleNamespace(scene=scene, dispatcher=dispatcher, logic=logic, session=session)
    logic.close()
    client.close()


def _nodes(scene, cls, name):
    return [n for n in risk._nodes(scene, cls) if n.GetName() == name]


def _points(node):
    out = []
    for i in range(node.GetNumberOfControlPoints()):
        p = [0.0, 0.0, 0.0]
        node.GetNthControlPointPosition(i, p)
        out.append(p)
    return np.array(out)


def test_volume_rows_and_cut_vessels(planned):
    v = planned.session.volumes()
    table = planned.logic.volume_table
    k = v.risk
    assert table.row("Functional remnant").cells()[1:] == \
        (f"{k.functional_remnant_ml:.1f}", f"{k.functional_remnant_pct:.1f}")
    assert table.row("Devascularised").ml == pytest.approx(k.devascularised_ml)
    assert table.row("Congested").ml == 0.0
    assert table.flr_warning is False and table.messages == ()
    assert [r.cells() for r in table.cut_vessels] == \
        [("portal", f"{c.radius_mm:.1f} mm", "r1") for c in k.cut_vessels]
    [node] = _nodes(planned.scene, "vtkMRMLMarkupsFiducialNode", risk.CUT_VESSELS_NODE)
    assert np.allclose(_points(node), [c.point for c in k.cut_vessels], atol=1e-4)
    assert node.GetNthControlPointLabel(0) == f"portal {k.cut_vessels[0].radius_mm:.1f} mm"


def test_flr_warning_names_the_functional_remnant():
    risk_ = types.SimpleNamespace(functional_remnant_ml=200.0, functional_remnant_pct=20.0,
                                  devascularised_ml=150.0, congested_ml=50.0, cut_vessels=())
    vol = types.SimpleNamespace(total_ml=1000.0, remnant_ml=400.0, remnant_pct=40.0,
                                resected_ml=600.0, flr_threshold_pct=30.0, flr_warning=True,
                                resections=(), risk=risk_, risk_unavailable="")
    t = volumetry.table(vol)
    assert t.messages == ("FLR warning: functional remnant 20.0 % < 30 % of the liver",)
    assert t.row("Functional remnant").warning and not t.row("Remnant (FLR)").warning
    vol.risk, vol.flr_warning, vol.risk_unavailable = None, False, "a cut is incomplete"
    t = volumetry.table(vol)
    assert t.messages == ("No risk analysis: a cut is incomplete",)
    with pytest.raises(KeyError):
        t.row("Functional remnant")


def _segment_volumes_ml(node):
    """Segment name → label-map voxels of the segment × voxel volume (ml)."""
    seg = node.GetSegmentation()
    out = {}
    for n in range(seg.GetNumberOfSegments()):
        segment = seg.GetSegment(seg.GetNthSegmentID(n))
        image = segment.GetRepresentation("Binary labelmap")
        values = numpy_support.vtk_to_numpy(image.GetPointData().GetScalars())
        voxel_mm3 = abs(np.prod(image.GetSpacing()))  # the directions are orthonormal
        out[segment.GetName()] = np.count_nonzero(values == segment.GetLabelValue()) \
            * voxel_mm3 / 1000.0
    return out


def test_risk_and_territory_segmentations(planned):
    maps = []
    planned.logic.show_risk(on_done=maps.append)
    planned.dispatcher.wait_until(lambda: maps or planned.logic.errors, 60)
    assert not planned.logic.errors
    m = maps[0]
    [node] = _nodes(planned.scene, "vtkMRMLSegmentationNode", risk.RISK_NODE)
    got = _segment_volumes_ml(node)
    want = {risk.RISK_SEGMENTS[c][0]: m.volume_ml(c) for c in np.unique(m.classes) if c}
    assert set(got) == set(want) == {"Functional remnant", "Resected", "Devascularised"}
    for name in want:
        assert got[name] == pytest.approx(want[name], rel=1e-6), name
    display = node.GetDisplayNode()
    seg = node.GetSegmentation()
    red = seg.GetSegment(seg.GetSegmentIdBySegmentName("Devascularised"))
    assert red.GetColor() == risk.RISK_SEGMENTS[3][1]
    assert display.GetSegmentOpacity3D(seg.GetSegmentIdBySegmentName("Devascularised")) == 1.0
    assert display.GetSegmentOpacity3D(seg.GetSegmentIdBySegmentName("Functional remnant")) < 0.5
    [territories] = _nodes(planned.scene, "vtkMRMLSegmentationNode", risk.TERRITORIES_NODE)
    ids = set(np.unique(m.territories)) - {0}
    assert territories.GetSegmentation().GetNumberOfSegments() == len(ids) >= 1
    # Again: the same nodes refilled, no label-map volumes left behind.
    maps.clear()
    planned.logic.show_risk(on_done=maps.append)
    planned.dispatcher.wait_until(lambda: maps, 60)
    assert planned.scene.GetNumberOfNodesByClass("vtkMRMLSegmentationNode") == 2
    assert not [n for n in risk._nodes(planned.scene, "vtkMRMLLabelMapVolumeNode")
                if n.GetName().startswith((risk.RISK_NODE, risk.TERRITORIES_NODE))]
    assert _segment_volumes_ml(node) == got


def _image(node):
    data = node.GetImageData()
    w, h, d = data.GetDimensions()
    return numpy_support.vtk_to_numpy(data.GetPointData().GetScalars()).reshape(d, h, w)[0]


def test_resectogram_follows_the_plan(planned):
    logic, scene = planned.logic, planned.scene
    grams, active, most = [], [0], [0]
    sess = logic.session
    fetch = sess.resectogram
    lock = threading.Lock()

    def counted(*args, **kwargs):
        with lock:
            active[0] += 1
            most[0] = max(most[0], active[0])
        try:
            return fetch(*args, **kwargs)
        finally:
            with lock:
                active[0] -= 1

    sess.resectogram = counted
    logic.set_callbacks(resectogram=grams.append)
    try:
        logic.follow_resectogram("r1")
        planned.dispatcher.wait_until(lambda: grams or logic.errors, 30)
        gram = grams[-1]
        [node] = _nodes(scene, "vtkMRMLLabelMapVolumeNode", risk.RESECTOGRAM_NODE)
        assert np.array_equal(_image(node), gram.classes) and gram.classes.shape == (200, 200)
        assert np.array_equal(gram.classes, planned.session.resectogram("r1").classes)
        table = scene.GetNodeByID(node.GetDisplayNode().GetColorNodeID())
        assert table.GetNumberOfColors() == 4
        for i, (_name, rgba) in enumerate(risk.RESECTOGRAM_CLASSES):
            assert table.GetLookupTable().GetTableValue(i) == pytest.approx(rgba, abs=1 / 255)
        assert [n for n, _ in risk.RESECTOGRAM_CLASSES] == [n for n, _ in models.MARGIN_CLASSES]
        [markers] = _nodes(scene, "vtkMRMLMarkupsFiducialNode", risk.MARKERS_NODE)
        want = [risk.uv_to_ras(c.uv) for c in gram.cut_vessels] + [risk.uv_to_ras(gram.worst_uv)]
        assert np.allclose(_points(markers), want)
        # Plan changes made elsewhere: the resectogram follows, one request at a time.
        for _ in range(3):
            planned.session.translate("r1", (0.0, 0.0, 0.5))
        version = planned.session.plan_version
        planned.dispatcher.wait_until(lambda: grams[-1].plan_version == version, 30)
        assert most[0] == 1 and 2 <= len(grams) <= 4
        assert len(_nodes(scene, "vtkMRMLLabelMapVolumeNode", risk.RESECTOGRAM_NODE)) == 1
        assert np.array_equal(_image(node), grams[-1].classes)
        logic.follow_resectogram(None)
        planned.session.translate("r1", (0.0, 0.0, -1.5))
        version = planned.session.plan_version
        planned.dispatcher.wait_until(lambda: logic.volume_table.plan_version == version, 30)
        assert grams[-1].plan_version < version
        assert not logic.errors
    finally:
        del sess.resectogram
        logic.set_callbacks()


# --- as Slicer draws them --------------------------------------------------------------------


@pytest.fixture(scope="module")
def gl():
    problem = offscreen.offscreen_gl_problem()
    if problem:
        pytest.skip(f"no offscreen OpenGL: {problem}")


def _has(image, rgb, tol=6):
    return bool(np.any(np.all(np.abs(image.astype(int) - np.asarray(rgb)) <= tol, axis=-1)))


def test_risk_in_3d_and_the_resectogram_in_the_red_view(gl, planned):
    logic, scene = planned.logic, planned.scene
    done = []
    logic.show_risk(on_done=done.append)
    logic.follow_resectogram("r1")
    planned.dispatcher.wait_until(
        lambda: done and _nodes(scene, "vtkMRMLLabelMapVolumeNode", risk.RESECTOGRAM_NODE), 60)
    logic.follow_resectogram(None)
    for node in models.model_nodes(scene):  # the risk alone: no liver or resection surface
        node.GetDisplayNode().SetVisibility(False)
    _nodes(scene, "vtkMRMLSegmentationNode", risk.TERRITORIES_NODE)[0] \
        .GetDisplayNode().SetVisibility(False)
    view = offscreen.ThreeDView(scene, (300, 240), background=(0, 0, 0))
    try:
        view.render()
        view.fit()
        image = view.render().astype(int)
    finally:
        view.close()
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    assert np.count_nonzero((r > 120) & (g < 0.3 * r) & (b < 0.3 * r)) > 200  # devascularised
    assert np.count_nonzero((g > r + 15) & (g > b + 15)) > 200  # the faint green remnant

    red = offscreen.SliceView(scene, "Axial", layout="Red", size=(200, 200), volumes=True)
    try:
        logic.show_resectogram_in("Red")
        image = red.render()
    finally:
        red.close()
    for name, rgba in risk.RESECTOGRAM_CLASSES:
        assert _has(image, np.array(rgba[:3]) * 255), f"no {name} pixel in the Red view"
