"""The Widget's lifecycle in a fake of the Qt/CTK surface (`fake_gui.py`) on real MRML and a real
server: what `setup`/`enter` take (timers, observers, shortcuts, GUI connections, threads) is
given back by `exit`/`cleanup` (a reload), the status is truthful, and the panel's controls
follow the scene."""

import importlib
import sys
import threading
import types

import numpy as np
import pytest

import fake_gui
from conftest import load_phantom_segmentation


@pytest.fixture
def app(scene, monkeypatch):
    gui = fake_gui.install(monkeypatch, scene)
    sys.modules.pop("Resecta", None)
    gui.Resecta = importlib.import_module("Resecta")
    yield gui
    sys.modules.pop("Resecta", None)


def _widget(app):
    w = app.Resecta.ResectaWidget(types.SimpleNamespace(isEntered=True))
    w.setup()
    return w


def _connect(app, w, server):
    w.ui.serverAddressLineEdit.text = server.grpc_addr
    w.ui.connectButton.emit("clicked", True)
    app.wait(lambda: w.ui.connectionStatusLabel.text.startswith("Connected"), 30)


def _pick_phantom(app, w, phantom):
    _lm, seg = load_phantom_segmentation(app.scene, phantom)
    w.ui.segmentationSelector.setCurrentNode(seg)
    for row, role in enumerate(["parenchyma", "tumor", "portal"]):
        w.ui.roleTable.cellWidget(row, 1).currentText = role
    return seg


def _alive(prefix="resecta"):
    return [t for t in threading.enumerate() if t.name.startswith(prefix) and t.is_alive()]


def test_enter_exit_and_reload_give_back_what_they_took(app, planning_server, phantom):
    w = _widget(app)
    assert [t.interval for t in app.running_timers] == [20]  # the poll timer
    undo, redo = app.main_window.actions[:2]
    w.enter()
    w.enter()  # Slicer may enter twice: still one shortcut per key
    keys = sorted(s.sequence.keys for s in app.main_window.shortcuts)
    assert keys == ["Ctrl+Y", "Ctrl+Z"]
    assert undo.shortcut.keys == "" and redo.shortcut.keys == ""  # lent to the panel
    w.exit()
    assert app.main_window.shortcuts == [] and not app.gui_connections
    assert (undo.shortcut.keys, redo.shortcut.keys) == ("Ctrl+Z", "Ctrl+Y")

    w.enter()
    _connect(app, w, planning_server)
    _pick_phantom(app, w, phantom)
    w.ui.buildModelsButton.emit("clicked", True)
    app.wait(lambda: app.errors or (w.logic.models_ready and w.ui.tumorComboBox.count > 0), 120)
    assert not app.errors and _alive("resecta-watch")
    # Reload: Slicer calls cleanup() on the old widget (no exit() first) and makes a new one.
    w.cleanup()
    assert app.main_window.shortcuts == [], "the shortcuts leaked"
    assert (undo.shortcut.keys, redo.shortcut.keys) == ("Ctrl+Z", "Ctrl+Y")
    assert app.running_timers == [] and not app.gui_connections
    assert w.Observations == [], f"observers left: {w.Observations}"
    app.wait(lambda: not w.logic.threads_alive, 10)
    assert not w.logic.connected
    again = _widget(app)
    again.enter()
    assert len(app.main_window.shortcuts) == 2 and len(app.running_timers) == 1
    again.cleanup()
    assert app.main_window.shortcuts == [] and app.running_timers == []
    assert not app.dialogs, app.dialogs


def test_scene_close_and_reopen(app, planning_server, phantom):
    w = _widget(app)
    w.enter()
    try:
        assert w.ui.connectionStatusLabel.text == "Not connected"
        assert not w.ui.buildModelsButton.enabled
        _connect(app, w, planning_server)
        assert not w.ui.buildModelsButton.enabled  # no segmentation yet
        # The segmentation picked after connecting enables Build.
        _pick_phantom(app, w, phantom)
        assert w.ui.buildModelsButton.enabled and w.ui.roleTable.rowCount == 3
        w.ui.buildModelsButton.emit("clicked", True)
        assert not w.ui.buildModelsButton.enabled and w.ui.cancelBuildButton.enabled
        app.wait(lambda: w.logic.models_ready and w.ui.tumorComboBox.count > 0
                 and not w.logic.building, 120)
        assert w.ui.buildModelsButton.enabled and not w.ui.cancelBuildButton.enabled
        assert "models so far" in w.ui.statusLabel.text or "models built" in w.ui.statusLabel.text
        assert w.ui.buildProgressBar.value == 100
        sid = w.logic.session_id
        assert w._parameterNode.sessionId == sid

        app.scene.Clear(0)
        assert w.ui.tumorComboBox.count == 0 and w.ui.resectionComboBox.count == 0
        assert w.ui.roleTable.rowCount == 0
        assert w.ui.marginIndicatorButton.text == "No resection"
        assert not w.logic.has_session and not w._parameterNode.sessionId
        # The connection is the application's, not the scene's: still open, and said so.
        assert w.logic.connected and w.ui.connectionStatusLabel.text.startswith("Connected")
        assert not w.ui.undoButton.enabled and not w.ui.newResectionButton.enabled
        assert app.gui_connections, "the panel is shown: the new scene's parameter node is bound"

        # Reopen: a scene saved with the plan remembers its session; Connect follows it again.
        w._parameterNode.sessionId = sid
        w.ui.connectButton.emit("clicked", True)
        app.wait(lambda: w.logic.session_id == sid and w.ui.tumorComboBox.count > 0, 30)
        assert w.logic.models_ready and w.ui.undoButton.enabled
        assert not app.dialogs, app.dialogs
    finally:
        w.cleanup()


def _add_segment(node, segment_id, name):
    import slicer
    import vtk

    segment = slicer.vtkSegment()
    segment.SetName(name)
    mask = slicer.vtkOrientedImageData()
    mask.SetDimensions(2, 2, 2)
    mask.AllocateScalars(vtk.VTK_UNSIGNED_CHAR, 1)
    segment.AddRepresentation(
        slicer.vtkSegmentationConverter.GetSegmentationBinaryLabelmapRepresentationName(), mask)
    node.GetSegmentation().AddSegment(segment, segment_id)


def test_role_table_follows_the_segments(app, scene):
    w = _widget(app)
    try:
        seg = scene.AddNewNodeByClass("vtkMRMLSegmentationNode", "seg")
        _add_segment(seg, "liver", "Liver")
        w.ui.segmentationSelector.setCurrentNode(seg)
        assert w.ui.roleTable.rowCount == 1
        assert w.ui.roleTable.cellWidget(0, 1).currentText == "parenchyma"
        w.ui.roleTable.cellWidget(0, 1).currentText = "ignore"  # the user's choice is kept
        _add_segment(seg, "tumour", "Tumour")
        assert w.ui.roleTable.rowCount == 2
        assert [w.ui.roleTable.cellWidget(r, 1).currentText for r in range(2)] == ["ignore", "tumor"]
        seg.GetSegmentation().GetSegment("tumour").SetName("Lesion 2")
        seg.GetSegmentation().Modified()
        w.onSegmentsChanged()  # SegmentModified is sent by Slicer's editor; renaming here is silent
        assert w.ui.roleTable.item(1, 0).text() == "Lesion 2"
        seg.GetSegmentation().RemoveSegment("liver")
        assert w.ui.roleTable.rowCount == 1
        assert w.ui.roleTable.item(0, 0).data(256) == "tumour"
    finally:
        w.cleanup()


def test_end_point_selector_never_offers_a_control_grid(app, scene):
    import numpy as np

    from ResectaLib import controlgrid

    w = _widget(app)
    w.enter()
    try:
        grid = controlgrid.make_grid_node(scene, "r1", np.zeros((16, 3)), 4, 4)
        w.ui.placeEndPointButton.checked = True
        end = w._parameterNode.endPoint
        assert end is not None and end is not grid and app.markups.active is end
        assert w.ui.endPointSelector.nodes() == [end]
        # A grid forced into the selector (an old scene) is not used as the end point.
        w._parameterNode.endPoint = grid
        w.ui.placeEndPointButton.checked = False
        w.ui.placeEndPointButton.checked = True
        assert w._parameterNode.endPoint is not grid
        assert grid.GetNumberOfControlPoints() == 16, "Place wiped the control grid"
        assert w.logic.end_point(grid) is None
    finally:
        w.cleanup()


def test_undo_without_a_plan_and_install_failures_stay_in_the_panel(app, monkeypatch):
    w = _widget(app)
    w.enter()
    try:
        ctrl_z = next(s for s in app.main_window.shortcuts if s.sequence.keys == "Ctrl+Z")
        ctrl_z.emit("activated")
        assert not app.dialogs and "Nothing to undo" in w.ui.statusLabel.text

        def broken(confirm):
            raise RuntimeError("pip failed: no network")

        monkeypatch.setattr(app.Resecta.deps, "ensure_installed", broken)
        w.ui.connectButton.emit("clicked", True)
        assert [str(e) for e in app.errors] == ["pip failed: no network"]
        assert w.ui.connectionStatusLabel.text == "Not connected"
    finally:
        w.cleanup()


def test_a_failed_connection_says_not_connected(app):
    w = _widget(app)
    try:
        w.ui.serverAddressLineEdit.text = "127.0.0.1:9"  # nothing listens there
        w.ui.connectButton.emit("clicked", True)
        app.wait(lambda: w.logic.errors, 30)
        assert w.ui.connectionStatusLabel.text == "Not connected"
        assert w.ui.statusLabel.text.startswith("Error")
    finally:
        w.cleanup()


def test_panel_draws_ds_and_cp_resections(app, planning_server, phantom):
    """The *Drawn resections* section: three curves drawn with *Draw trace* make a DS
    resection, a ring a CP one; the kind and metrics table fills; grid edits are off for them
    and the deformation buttons only for CP; the handle released deforms, *Undo deformation*
    takes it back."""
    import vtk

    w = _widget(app)
    w.enter()
    _connect(app, w, planning_server)
    _pick_phantom(app, w, phantom)
    w.ui.buildModelsButton.emit("clicked", True)
    app.wait(lambda: app.errors or (w.logic.models_ready and w.ui.tumorComboBox.count > 0), 120)
    assert w.ui.drawTraceButton.enabled

    def draw(points):
        placing = app.markups.placing
        w.ui.drawTraceButton.checked = True  # toggled(True)
        curve = app.markups.active
        assert app.markups.placing == placing + 1 and curve is w._drawingCurve
        for p in points:
            curve.AddControlPointWorld(vtk.vtkVector3d(*p))
        w.ui.drawTraceButton.checked = False  # toggled(False): the curve is used
        return curve

    w.ui.drawnNameLineEdit.text = "ds1"
    for z in (-30.0, 0.0, 30.0):
        draw([(-10.0 + 0.02 * y, y, z) for y in (-50.0, 0.0, 50.0)])
    app.wait(lambda: app.errors or w.ui.resectionComboBox.findText("ds1") >= 0, 30)
    app.wait(lambda: w.ui.metricsTable.rowCount == 1, 30)
    cells = [w.ui.metricsTable.item(0, c).text() for c in range(4)]
    assert cells[:2] == ["ds1", "DS"] and cells[2].endswith("mm") and "mm⁻¹" in cells[3]
    w.ui.resectionComboBox.setCurrentIndex(w.ui.resectionComboBox.findText("ds1"))
    assert not w.ui.rotateButton.enabled and not w.ui.deformButton.enabled
    assert w.ui.deleteResectionButton.enabled

    w.ui.drawnKindComboBox.setCurrentIndex(1)
    w.ui.drawnNameLineEdit.text = "cp1"
    draw([(-10.0, 30.0 * np.cos(t), 22.0 * np.sin(t)) for t in np.linspace(0, 6.0, 10)])
    app.wait(lambda: app.errors or w.ui.resectionComboBox.findText("cp1") >= 0, 30)
    w.ui.resectionComboBox.setCurrentIndex(w.ui.resectionComboBox.findText("cp1"))
    assert w.ui.deformButton.enabled and not w.ui.translateButton.enabled
    w.ui.placeHandleButton.emit("clicked", True)
    handle = w._handle
    assert handle is not None and handle.GetNumberOfControlPoints() == 1
    p = [0.0, 0.0, 0.0]
    handle.GetNthControlPointPositionWorld(0, p)
    handle.SetNthControlPointPositionWorld(0, p[0] - 4.0, p[1], p[2])
    handle.InvokeEvent(handle.PointEndInteractionEvent)  # the user lets go
    app.wait(lambda: app.errors or w.logic.resection("cp1").deformations, 30)
    assert w.logic.resection("cp1").deformations[0].radius_mm == 20.0
    w.ui.undoDeformationButton.emit("clicked", True)
    app.wait(lambda: app.errors or not w.logic.resection("cp1").deformations, 30)
    assert not app.errors and not app.dialogs
    w.cleanup()
    assert w.Observations == [], f"observers left: {w.Observations}"


def test_panel_shows_the_vascular_risk(app, planning_server, demo_phantom):
    """A session of the demo phantom followed by the panel: the volume table's risk rows and
    the cut vessels, *Show risk* makes the segmentations, *Resectogram* puts it in the Red
    view and follows the plan until the panel is left."""
    from resecta_client import Client

    from ResectaLib import risk
    from conftest import DEMO_ROLES

    scene = app.scene
    for cls in ("vtkMRMLSliceNode", "vtkMRMLSliceCompositeNode"):  # Slicer's Red view
        scene.AddNewNodeByClass(cls).SetLayoutName("Red")
    w = _widget(app)
    w.enter()
    with Client(planning_server.grpc_addr) as other:
        remote = other.create_session("risk")
        remote.upload_label_map_file(demo_phantom, DEMO_ROLES)
        remote.init_from_end_point("r1", (0.0, 30.0, 0.0))
        w._parameterNode.sessionId = remote.id
        _connect(app, w, planning_server)
        app.wait(lambda: w.ui.cutVesselTable.rowCount == 1, 30)
        labels = [w.ui.volumeTable.item(r, 0).text() for r in range(w.ui.volumeTable.rowCount)]
        assert labels[-3:] == ["Functional remnant", "Devascularised", "Congested"]
        assert w.ui.cutVesselTable.item(0, 0).text() == "portal"
        assert w.ui.cutVesselTable.item(0, 2).text() == "r1"
        assert w.ui.showRiskButton.enabled and w.ui.resectogramButton.enabled

        w.ui.showRiskButton.emit("clicked", True)
        app.wait(lambda: app.errors or scene.GetFirstNodeByName(risk.RISK_NODE), 60)
        w.ui.resectogramButton.checked = True
        app.wait(lambda: app.errors or scene.GetFirstNodeByName(risk.RESECTOGRAM_NODE), 30)
        composite = next(n for n in risk._nodes(scene, "vtkMRMLSliceCompositeNode")
                         if n.GetLayoutName() == "Red")
        assert composite.GetBackgroundVolumeID() == \
            scene.GetFirstNodeByName(risk.RESECTOGRAM_NODE).GetID()
        assert w.logic.resectogram_resection == "r1"
        w.exit()
        assert not w.ui.resectogramButton.checked and w.logic.resectogram_resection is None
    assert not app.errors and not app.dialogs
    w.cleanup()
