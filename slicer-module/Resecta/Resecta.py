"""Resecta: liver resection planning in 3D Slicer, thin over the resecta planning server.

Module (metadata) → parameter node → Widget (wires the Qt Designer UI, nothing else) → Logic
(delegates to `ResectaLib.session.PlanningSession`, which also runs without Slicer's GUI under
pytest) → Test (the self-test scenario of `ResectaLib.selftest`, the same one the pytest suite
runs).
"""

import logging
import os
from typing import Annotated, Optional

import qt
import vtk

import slicer
from slicer import vtkMRMLMarkupsFiducialNode, vtkMRMLSegmentationNode, vtkSegmentation
from slicer.i18n import tr as _
from slicer.i18n import translate
from slicer.parameterNodeWrapper import Choice, WithinRange, parameterNodeWrapper
from slicer.ScriptedLoadableModule import (
    ScriptedLoadableModule,
    ScriptedLoadableModuleLogic,
    ScriptedLoadableModuleTest,
    ScriptedLoadableModuleWidget,
)
from slicer.util import VTKObservationMixin

from ResectaLib import deps, margin, segmentation, traces, volumetry
from ResectaLib.edits import GROUPS
from ResectaLib.logic import PlanningLogic

SETTINGS_ADDRESS = "Resecta/ServerAddress"
SETTINGS_TOKEN = "Resecta/Token"
SETTINGS_TLS = "Resecta/UseTls"
SETTINGS_CA_FILE = "Resecta/CaFile"
SETTINGS_REPLICAS = "Resecta/Replicas"
DEFAULT_ADDRESS = "127.0.0.1:50051"
#: Markups lists made by "Place" carry it; the end-point selector lists only them.
END_POINT_ATTRIBUTE = "Resecta.EndPoint"
SEGMENT_EVENTS = (vtkSegmentation.SegmentAdded, vtkSegmentation.SegmentRemoved,
                  vtkSegmentation.SegmentModified)


#
# Resecta
#


class Resecta(ScriptedLoadableModule):
    """Module metadata."""

    def __init__(self, parent):
        ScriptedLoadableModule.__init__(self, parent)
        self.parent.title = _("Resecta")
        self.parent.categories = [translate("qSlicerAbstractCoreModule", "Surgical Planning")]
        self.parent.dependencies = ["Segmentations", "Markups", "Models"]
        self.parent.contributors = ["resecta project"]
        self.parent.helpText = _(
            "Plan liver resections with a deformable Bézier surface, curves drawn on slices "
            "(DS) or a deformable cutting plane (CP), and live safety margins, "
            "computed by a resecta planning server (after R. Palomar, NTNU 2018). Requires 3D "
            "Slicer 5.10 or newer. The first Connect asks to install grpcio, protobuf and numpy "
            "(version ranges; packages other extensions share are never downgraded); the resecta "
            "client ships with the extension. See the module's README for the workflow.")
        self.parent.acknowledgementText = _(
            "The method follows R. Palomar's thesis (NTNU 2018, Papers I–III); the colours of "
            "the margin display follow the thesis and the Slicer-Liver extension.")


#
# ResectaParameterNode
#


@parameterNodeWrapper
class ResectaParameterNode:
    """What the panel holds in the scene. The server token is never here (Slicer settings)."""

    segmentation: vtkMRMLSegmentationNode
    method: Annotated[str, Choice(["psr", "mcsd"])] = "psr"
    opacity: Annotated[float, WithinRange(0.0, 1.0)] = 0.35
    resectionOpacity: Annotated[float, WithinRange(0.0, 1.0)] = 1.0
    endPoint: vtkMRMLMarkupsFiducialNode
    marginMm: Annotated[float, WithinRange(0.5, 100.0)] = 10.0
    bandMm: Annotated[float, WithinRange(0.0, 100.0)] = 5.0
    deformationRadiusMm: Annotated[float, WithinRange(1.0, 200.0)] = 20.0
    sessionId: str = ""


#
# ResectaWidget
#


class ResectaWidget(ScriptedLoadableModuleWidget, VTKObservationMixin):
    """Wires the UI of Resources/UI/Resecta.ui to the Logic; holds no planning state. What it
    takes on `setup` or `enter` (timers, scene observers, shortcuts, the parameter node's GUI
    connection) it gives back on `exit` and `cleanup` (a reload calls `cleanup`)."""

    def __init__(self, parent=None) -> None:
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self._parameterNode = None
        self._parameterNodeGuiTag = None
        self._shortcuts = []
        self._lentShortcuts = []
        self._pollTimer = None
        self._editTimer = None
        self._observedSegmentation = None
        self._unsupported = None
        self._drawingCurve = None
        self._handle = None
        self._resectogramInView = False

    def setup(self) -> None:
        ScriptedLoadableModuleWidget.setup(self)
        uiWidget = slicer.util.loadUI(self.resourcePath("UI/Resecta.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        uiWidget.setMRMLScene(slicer.mrmlScene)
        try:
            deps.check_slicer_version(slicer.app.applicationVersion)
            self._unsupported = None
        except deps.UnsupportedSlicer as exc:
            self._unsupported = str(exc)

        self.logic = ResectaLogic()
        self.logic.set_callbacks(
            status=self._showStatus, error=self._showError, progress=self._showProgress,
            model_built=self._showModelBuilt, models=self._refreshTumours,
            resections=self._refreshResections, volumes=self._showVolumes,
            metrics=self._showMetrics, resectogram=self._showResectogram,
            margin=self._showMargin, session=self._sessionChanged)

        # Main-thread delivery of worker results (network calls never run on this thread).
        self._pollTimer = qt.QTimer()
        self._pollTimer.setInterval(20)
        self._pollTimer.connect("timeout()", self.logic.poll)
        self._pollTimer.start()
        # Margin / band spin boxes send one edit after the value settles.
        self._editTimer = qt.QTimer()
        self._editTimer.setSingleShot(True)
        self._editTimer.setInterval(300)
        self._editTimer.connect("timeout()", self.onMarginBandSettled)

        settings = qt.QSettings()
        self.ui.serverAddressLineEdit.text = settings.value(SETTINGS_ADDRESS, DEFAULT_ADDRESS)
        self.ui.serverReplicasLineEdit.text = settings.value(SETTINGS_REPLICAS, "")
        self.ui.tokenLineEdit.text = settings.value(SETTINGS_TOKEN, "")
        self.ui.tlsCheckBox.checked = str(settings.value(SETTINGS_TLS, "false")).lower() == "true"
        self.ui.caFilePathLineEdit.currentPath = settings.value(SETTINGS_CA_FILE, "")

        if self.ui.methodComboBox.count == 0:
            self.ui.methodComboBox.addItems(["psr", "mcsd"])
        for label in (_("Inner points"), _("Outer ring"), _("All points")):
            self.ui.groupComboBox.addItem(label)
        for label in ("R", "A", "S", _("Surface normal")):
            self.ui.rotateAxisComboBox.addItem(label)
        for label in (_("DS: drawn on slices"), _("CP: cutting plane")):
            self.ui.drawnKindComboBox.addItem(label)
        for fmt in ("vtp", "vtk", "stl", "ply", "obj"):
            self.ui.exportFormatComboBox.addItem(fmt)
        self.ui.roleTable.horizontalHeader().setStretchLastSection(True)
        self.ui.volumeTable.horizontalHeader().setStretchLastSection(True)
        self.ui.metricsTable.horizontalHeader().setStretchLastSection(True)
        self.ui.cutVesselTable.horizontalHeader().setStretchLastSection(True)
        # Only this module's end-point lists, never the control grids (also markups lists).
        self.ui.endPointSelector.addAttribute("vtkMRMLMarkupsFiducialNode", END_POINT_ATTRIBUTE, "1")

        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.StartCloseEvent, self.onSceneStartClose)
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.EndCloseEvent, self.onSceneEndClose)

        self.ui.connectButton.connect("clicked(bool)", self.onConnect)
        self.ui.segmentationSelector.connect("currentNodeChanged(vtkMRMLNode*)", self.onSegmentationChanged)
        self.ui.buildModelsButton.connect("clicked(bool)", self.onBuildModels)
        self.ui.cancelBuildButton.connect("clicked(bool)", self.onCancelBuild)
        self.ui.opacitySlider.connect("valueChanged(double)", self.onOpacity)
        self.ui.resectionOpacitySlider.connect("valueChanged(double)", self.onResectionOpacity)
        self.ui.placeEndPointButton.connect("toggled(bool)", self.onPlaceEndPoint)
        self.ui.endPointSelector.connect("currentNodeChanged(vtkMRMLNode*)", self.onEndPointNodeChanged)
        self.ui.tumorComboBox.connect("currentIndexChanged(int)", self.onPreview)
        self.ui.newResectionButton.connect("clicked(bool)", self.onNewResection)
        self.ui.resectionComboBox.connect("currentIndexChanged(int)", self.onResectionSelected)
        self.ui.marginSpinBox.connect("valueChanged(double)", self.onMarginBandChanged)
        self.ui.bandSpinBox.connect("valueChanged(double)", self.onMarginBandChanged)
        self.ui.marginIndicatorButton.connect("clicked(bool)", self.onJumpToWorst)
        self.ui.moveGroupButton.connect("clicked(bool)", self.onMoveGroup)
        self.ui.translateButton.connect("clicked(bool)", self.onTranslate)
        self.ui.rotateButton.connect("clicked(bool)", self.onRotate)
        self.ui.undoButton.connect("clicked(bool)", self.onUndo)
        self.ui.redoButton.connect("clicked(bool)", self.onRedo)
        self.ui.deleteResectionButton.connect("clicked(bool)", self.onDeleteResection)
        self.ui.drawTraceButton.connect("toggled(bool)", self.onDrawTrace)
        self.ui.placeHandleButton.connect("clicked(bool)", self.onPlaceHandle)
        self.ui.deformButton.connect("clicked(bool)", self.onDeform)
        self.ui.undoDeformationButton.connect("clicked(bool)", self.onUndoDeformation)
        self.ui.savePlanButton.connect("clicked(bool)", self.onSavePlan)
        self.ui.loadPlanButton.connect("clicked(bool)", self.onLoadPlan)
        self.ui.exportModelsButton.connect("clicked(bool)", self.onExportModels)
        self.ui.showRiskButton.connect("clicked(bool)", self.onShowRisk)
        self.ui.resectogramButton.connect("toggled(bool)", self.onResectogram)

        self.initializeParameterNode()
        self._updateButtons()

    def cleanup(self) -> None:
        """The panel goes away (application exit or module reload): give everything back."""
        self.ui.resectogramButton.checked = False
        self._releaseShortcuts()
        self.removeObservers()
        self._observedSegmentation = self._handle = self._drawingCurve = None
        for timer in (self._pollTimer, self._editTimer):
            if timer is not None:
                timer.stop()
                timer.disconnect("timeout()")
        self._pollTimer = self._editTimer = None
        self.setParameterNode(None)
        if self.logic:
            self.logic.close()

    def enter(self) -> None:
        self.initializeParameterNode()
        self._takeShortcuts()

    def exit(self) -> None:
        self.ui.resectogramButton.checked = False  # it follows the plan while the panel shows
        self._releaseShortcuts()
        self.setParameterNode(None)

    def _takeShortcuts(self) -> None:
        """While the panel is shown, Ctrl+Z / Ctrl+Y undo and redo plan edits. Slicer's own
        actions with the same keys (scene undo) lend them to us until `exit`/`cleanup`,
        otherwise Qt would find the shortcut ambiguous and fire neither."""
        self._releaseShortcuts()
        mainWindow = slicer.util.mainWindow()
        if mainWindow is None:
            return
        for keys, slot in (("Ctrl+Z", self.onUndo), ("Ctrl+Y", self.onRedo)):
            sequence = qt.QKeySequence(keys)
            for action in mainWindow.findChildren(qt.QAction):
                if action.shortcut == sequence:
                    self._lentShortcuts.append((action, action.shortcut))
                    action.shortcut = qt.QKeySequence()
            shortcut = qt.QShortcut(sequence, mainWindow)
            shortcut.connect("activated()", slot)
            self._shortcuts.append(shortcut)

    def _releaseShortcuts(self) -> None:
        for shortcut in self._shortcuts:
            shortcut.disconnect("activated()")
            shortcut.setParent(None)
        self._shortcuts = []
        for action, sequence in self._lentShortcuts:
            action.shortcut = sequence
        self._lentShortcuts = []

    def onSceneStartClose(self, caller, event) -> None:
        self.ui.resectogramButton.checked = False
        self._drawingCurve = None
        self._observeHandle(None)
        self.setParameterNode(None)
        self._observeSegmentation(None)
        self.logic.forget_session()

    def onSceneEndClose(self, caller, event) -> None:
        if self.parent.isEntered:
            self.initializeParameterNode()
        self._updateButtons()

    def initializeParameterNode(self) -> None:
        self.setParameterNode(self.logic.getParameterNode())
        if not self._parameterNode.segmentation:
            node = slicer.mrmlScene.GetFirstNodeByClass("vtkMRMLSegmentationNode")
            if node:
                self._parameterNode.segmentation = node

    def setParameterNode(self, inputParameterNode: Optional[ResectaParameterNode]) -> None:
        if self._parameterNode and self._parameterNodeGuiTag is not None:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
        self._parameterNodeGuiTag = None
        self._parameterNode = inputParameterNode
        if self._parameterNode:
            self._parameterNodeGuiTag = self._parameterNode.connectGui(self.ui)
            self.onSegmentationChanged(self._parameterNode.segmentation)

    # --- connection ---------------------------------------------------------------------------

    def onConnect(self) -> None:
        address = self.ui.serverAddressLineEdit.text.strip() or DEFAULT_ADDRESS
        replicas = self.ui.serverReplicasLineEdit.text.strip()
        token = self.ui.tokenLineEdit.text.strip()
        tls = self.ui.tlsCheckBox.checked
        caFile = self.ui.caFilePathLineEdit.currentPath
        with slicer.util.tryWithErrorDisplay(_("Could not connect."), waitCursor=True):
            deps.check_slicer_version(slicer.app.applicationVersion)
            if not deps.ensure_installed(self._confirmInstall):
                self._showStatus(_("The Python packages resecta needs are not installed."))
                return
            settings = qt.QSettings()
            settings.setValue(SETTINGS_ADDRESS, address)
            settings.setValue(SETTINGS_REPLICAS, replicas)
            settings.setValue(SETTINGS_TOKEN, token)
            settings.setValue(SETTINGS_TLS, "true" if tls else "false")
            settings.setValue(SETTINGS_CA_FILE, caFile)
            self.ui.connectionStatusLabel.text = _("Connecting to {address}…").format(address=address)
            # Retries and fail-overs run on the Logic's worker and watch threads, never here.
            self.logic.connect(address, token or None, tls, caFile or None, on_done=self._connected,
                               replicas=replicas)

    def _confirmInstall(self, packages) -> bool:
        return slicer.util.confirmOkCancelDisplay(
            _("Resecta needs these Python packages, which will be installed or upgraded with "
              "pip:\n\n")
            + "\n".join(packages), windowTitle=_("Resecta: install dependencies"))

    def _connected(self, info) -> None:
        self.ui.connectionStatusLabel.text = _("Connected: resecta {version}").format(
            version=info.server_version)
        # A scene saved with a plan remembers its server session: follow it again.
        sessionId = self._parameterNode.sessionId if self._parameterNode else ""
        if sessionId:
            self.logic.open_session(sessionId)
        self._updateButtons()

    def _sessionChanged(self) -> None:
        if self._parameterNode and self.logic.session_id:
            self._parameterNode.sessionId = self.logic.session_id
        self._refreshTumours()
        self._refreshResections()
        self._updateButtons()

    # --- patient ------------------------------------------------------------------------------

    def _observeSegmentation(self, node) -> None:
        if self._observedSegmentation is not None:
            for event in SEGMENT_EVENTS:
                self.removeObserver(self._observedSegmentation, event, self.onSegmentsChanged)
        self._observedSegmentation = node
        if node is not None:
            for event in SEGMENT_EVENTS:
                self.addObserver(node, event, self.onSegmentsChanged)

    def onSegmentationChanged(self, node) -> None:
        if node is not self._observedSegmentation:
            self._observeSegmentation(node)
        self._fillRoleTable(node)
        self._updateButtons()

    def onSegmentsChanged(self, caller=None, event=None) -> None:
        """A segment was added, removed or renamed: the table follows, keeping chosen roles."""
        self._fillRoleTable(self._observedSegmentation, keep=self._roleTableFromUi())

    def _fillRoleTable(self, node, keep=None) -> None:
        table = self.ui.roleTable
        table.setRowCount(0)
        if node is None:
            return
        rows = self.logic.role_table(node, keep or {})
        table.setRowCount(len(rows))
        for row, (segmentId, name, role) in enumerate(rows):
            item = qt.QTableWidgetItem(name)
            item.setData(qt.Qt.UserRole, segmentId)
            item.setFlags(qt.Qt.ItemIsEnabled)
            table.setItem(row, 0, item)
            combo = qt.QComboBox()
            combo.addItems(list(segmentation.ROLES) + [segmentation.IGNORE])
            combo.currentText = role
            table.setCellWidget(row, 1, combo)

    def _roleTableFromUi(self) -> dict:
        table = self.ui.roleTable
        return {table.item(row, 0).data(qt.Qt.UserRole): table.cellWidget(row, 1).currentText
                for row in range(table.rowCount)}

    def onBuildModels(self) -> None:
        p = self._parameterNode
        with slicer.util.tryWithErrorDisplay(_("Could not build the models."), waitCursor=True):
            self.logic.upload_and_build(p.segmentation, self._roleTableFromUi(), p.method,
                                        on_done=self._buildFinished)
            self.ui.buildProgressBar.value = 0
            self.ui.buildProgressBar.format = _("uploading %p%")
            self._updateButtons()

    def _buildFinished(self, _result=None) -> None:
        self._updateButtons()

    def onCancelBuild(self) -> None:
        self.logic.cancel_build()
        self._showStatus(_("Cancelling the reconstruction…"))

    def onOpacity(self, value) -> None:
        self.logic.set_opacity(("parenchyma",), value)

    def onResectionOpacity(self, value) -> None:
        self.logic.set_opacity(("resection",), value)

    # --- resection ----------------------------------------------------------------------------

    def onPlaceEndPoint(self, checked) -> None:
        if not checked:
            slicer.app.applicationLogic().GetInteractionNode().SwitchToViewTransformMode()
            return
        node = self.logic.end_point_node(self._parameterNode.endPoint, _("Resecta end point"))
        self._parameterNode.endPoint = node
        node.RemoveAllControlPoints()
        slicer.modules.markups.logic().SetActiveList(node)
        slicer.modules.markups.logic().StartPlaceMode(False)

    def onEndPointNodeChanged(self, node) -> None:
        self.removeObservers(self.onPreview)
        if node is not None:
            self.addObserver(node, slicer.vtkMRMLMarkupsNode.PointPositionDefinedEvent, self.onPreview)
            self.addObserver(node, slicer.vtkMRMLMarkupsNode.PointModifiedEvent, self.onPreview)
        self.onPreview()

    def _endPoint(self):
        node = self._parameterNode.endPoint if self._parameterNode else None
        return self.logic.end_point(node)

    def onPreview(self, *args) -> None:
        endPoint = self._endPoint()
        if endPoint is not None:
            self.ui.placeEndPointButton.checked = False
        self.logic.preview(self.ui.tumorComboBox.currentText, endPoint)
        self._updateButtons()

    def onNewResection(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Could not create the resection."), waitCursor=True):
            endPoint = self._endPoint()
            if endPoint is None:
                raise ValueError(_("Place the end point first."))
            name = self.ui.resectionNameLineEdit.text.strip() or "r1"
            self.logic.new_resection(name, self.ui.tumorComboBox.currentText, endPoint,
                                     margin_mm=self._parameterNode.marginMm,
                                     band_mm=self._parameterNode.bandMm)
            self.logic.preview(None, None)

    def _currentResection(self) -> str:
        return self.ui.resectionComboBox.currentText

    def onResectionSelected(self, _index=None) -> None:
        params = self.logic.resection(self._currentResection())
        if params is not None and self._parameterNode:
            self._parameterNode.marginMm = params.margin_mm
            self._parameterNode.bandMm = params.band_mm
            self._editTimer.stop()  # the values came from the server: nothing to send
        if self.ui.resectogramButton.checked:
            self.onResectogram(True)
        self._updateButtons()

    def onMarginBandChanged(self, _value=None) -> None:
        self._editTimer.start()

    def onMarginBandSettled(self) -> None:
        name = self._currentResection()
        if not name or not self.logic.has_session:
            return
        with slicer.util.tryWithErrorDisplay(_("Could not change the margin.")):
            self.logic.edits.set_margin_and_band(name, self._parameterNode.marginMm,
                                                 self._parameterNode.bandMm)

    def _delta(self):
        return [float(x) for x in self.ui.deltaCoordinates.coordinates.split(",")]

    def onMoveGroup(self) -> None:
        group = GROUPS[self.ui.groupComboBox.currentIndex]
        with slicer.util.tryWithErrorDisplay(_("Could not move the group.")):
            self.logic.edits.move_group(self._currentResection(), group, self._delta())

    def onTranslate(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Could not translate.")):
            self.logic.edits.translate(self._currentResection(), self._delta())

    def onRotate(self) -> None:
        axis = ("R", "A", "S", "normal")[self.ui.rotateAxisComboBox.currentIndex]
        with slicer.util.tryWithErrorDisplay(_("Could not rotate.")):
            self.logic.edits.rotate(self._currentResection(), axis, self.ui.rotateAngleSpinBox.value)

    def onUndo(self) -> None:
        # Also reached by Ctrl+Z: without a plan there is nothing to undo, and nothing to say
        # in a dialog.
        if not self.logic.has_session:
            self._showStatus(_("Nothing to undo: no plan yet."))
            return
        with slicer.util.tryWithErrorDisplay(_("Could not undo.")):
            self.logic.edits.undo()

    def onRedo(self) -> None:
        if not self.logic.has_session:
            self._showStatus(_("Nothing to redo: no plan yet."))
            return
        with slicer.util.tryWithErrorDisplay(_("Could not redo.")):
            self.logic.edits.redo()

    def onDeleteResection(self) -> None:
        name = self._currentResection()
        if name and slicer.util.confirmYesNoDisplay(_("Delete resection {name}?").format(name=name)):
            with slicer.util.tryWithErrorDisplay(_("Could not delete the resection.")):
                self.logic.edits.delete(name)

    # --- DS and CP resections -------------------------------------------------------------------

    def _drawnKind(self) -> str:
        return ("ds", "cp")[max(0, self.ui.drawnKindComboBox.currentIndex)]

    def onDrawTrace(self, checked) -> None:
        """Pressed: a new curve to click in a view; pressed again: the curve becomes a trace."""
        markupsLogic = slicer.modules.markups.logic()
        if checked:
            with slicer.util.tryWithErrorDisplay(_("Could not start a trace.")):
                name = self.ui.drawnNameLineEdit.text.strip()
                self._drawingCurve = self.logic.new_trace_curve(name, self._drawnKind())
                markupsLogic.SetActiveList(self._drawingCurve)
                markupsLogic.StartPlaceMode(True)
            if self._drawingCurve is None:
                self.ui.drawTraceButton.checked = False
            return
        slicer.app.applicationLogic().GetInteractionNode().SwitchToViewTransformMode()
        node, self._drawingCurve = self._drawingCurve, None
        if node is None:
            return
        p = self._parameterNode
        with slicer.util.tryWithErrorDisplay(_("Could not use the curve.")):
            self.logic.use_curve(node, self.ui.tumorComboBox.currentText or None,
                                 margin_mm=p.marginMm, band_mm=p.bandMm)
        self._updateButtons()

    def _observeHandle(self, node) -> None:
        if self._handle is not None:
            self.removeObserver(self._handle, slicer.vtkMRMLMarkupsNode.PointEndInteractionEvent,
                                self.onHandleReleased)
        self._handle = node
        if node is not None:
            self.addObserver(node, slicer.vtkMRMLMarkupsNode.PointEndInteractionEvent,
                             self.onHandleReleased)

    def onPlaceHandle(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Could not show the deformation handle.")):
            self._observeHandle(self.logic.deformation_handle(self._currentResection()))

    def onHandleReleased(self, caller=None, event=None) -> None:
        self.onDeform()

    def onDeform(self) -> None:
        name = self._currentResection()
        with slicer.util.tryWithErrorDisplay(_("Could not deform the resection.")):
            if self._handle is None or self._handle.GetAttribute(traces.DEFORMATION_ATTRIBUTE) != name:
                self._observeHandle(self.logic.deformation_handle(name))
            self.logic.deform(name, self._parameterNode.deformationRadiusMm, self._handle)

    def onUndoDeformation(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Could not undo the deformation.")):
            self.logic.undo_deformation(self._currentResection())

    # --- vascular risk --------------------------------------------------------------------------

    def onShowRisk(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Could not show the risk map.")):
            self.logic.show_risk()

    def onResectogram(self, checked) -> None:
        """Pressed: the current resection's resectogram in the Red view, following the plan."""
        self._resectogramInView = False
        name = self._currentResection() if checked else None
        with slicer.util.tryWithErrorDisplay(_("Could not show the resectogram.")):
            self.logic.follow_resectogram(name)

    def _showResectogram(self, gram) -> None:
        if not self._resectogramInView:  # once: later refreshes keep the user's pan and zoom
            self._resectogramInView = True
            with slicer.util.tryWithErrorDisplay(_("Could not show the resectogram.")):
                self.logic.show_resectogram_in("Red")

    def onJumpToWorst(self) -> None:
        self.logic.jump_to_worst_point()

    # --- plan ---------------------------------------------------------------------------------

    def onSavePlan(self) -> None:
        path = qt.QFileDialog.getSaveFileName(None, _("Save plan"), "plan.json", _("Plan (*.json)"))
        if path:
            with slicer.util.tryWithErrorDisplay(_("Could not save the plan.")):
                self.logic.save_plan(path)

    def onLoadPlan(self) -> None:
        path = qt.QFileDialog.getOpenFileName(None, _("Load plan"), "", _("Plan (*.json)"))
        if path:
            with slicer.util.tryWithErrorDisplay(_("Could not load the plan.")):
                self.logic.load_plan(path)

    def onExportModels(self) -> None:
        folder = qt.QFileDialog.getExistingDirectory(None, _("Export resection models to"))
        if folder:
            with slicer.util.tryWithErrorDisplay(_("Could not export the models.")):
                self.logic.export_resections(folder, self.ui.exportFormatComboBox.currentText)

    # --- what the Logic reports ---------------------------------------------------------------

    def _showStatus(self, text: str) -> None:
        self.ui.statusLabel.text = text

    def _showError(self, exc: Exception) -> None:
        logging.error("Resecta: %s", exc)
        self.ui.statusLabel.text = _("Error: {error}").format(error=exc)
        if not self.logic.connected:
            self.ui.connectionStatusLabel.text = _("Not connected")
        self._updateButtons()

    def _showProgress(self, fraction: float, stage: str) -> None:
        self.ui.buildProgressBar.value = int(round(100 * fraction))
        self.ui.buildProgressBar.format = f"{stage} %p%"

    def _showModelBuilt(self, info) -> None:
        self._showStatus(_("Built {name} ({count} models so far)").format(
            name=info.name, count=len(self.logic.model_infos)))

    def _refreshTumours(self) -> None:
        combo = self.ui.tumorComboBox
        current = combo.currentText
        combo.clear()
        for name in self.logic.tumours():
            combo.addItem(name)
        index = combo.findText(current)
        if index >= 0:
            combo.setCurrentIndex(index)
        self._updateButtons()

    def _refreshResections(self) -> None:
        current = self._currentResection()
        combo = self.ui.resectionComboBox
        wasBlocked = combo.blockSignals(True)
        combo.clear()
        for name in self.logic.resection_names():
            combo.addItem(name)
        index = combo.findText(current)
        combo.setCurrentIndex(index if index >= 0 else combo.count - 1)
        combo.blockSignals(wasBlocked)
        self.onResectionSelected()

    def _showVolumes(self, table: volumetry.VolumeTable) -> None:
        widget = self.ui.volumeTable
        widget.setRowCount(len(table.rows))
        for row, r in enumerate(table.rows):
            for col, text in enumerate(r.cells()):
                item = qt.QTableWidgetItem(text)
                if r.warning:
                    item.setForeground(qt.QBrush(qt.QColor(margin.RED)))
                widget.setItem(row, col, item)
        self.ui.flrLabel.text = "\n".join(table.messages)
        vessels = self.ui.cutVesselTable
        vessels.setRowCount(len(table.cut_vessels))
        for row, v in enumerate(table.cut_vessels):
            for col, text in enumerate(v.cells()):
                vessels.setItem(row, col, qt.QTableWidgetItem(text))

    def _showMetrics(self, rows) -> None:
        widget = self.ui.metricsTable
        widget.setRowCount(len(rows))
        for row, r in enumerate(rows):
            for col, text in enumerate(r.cells()):
                widget.setItem(row, col, qt.QTableWidgetItem(text))

    def _showMargin(self, state: margin.MarginIndicator) -> None:
        button = self.ui.marginIndicatorButton
        button.text = state.text
        button.enabled = state.can_jump
        button.setStyleSheet(f"QPushButton {{ background-color: {state.color}; color: white; "
                             "font-weight: bold; padding: 4px; }}")

    def _updateButtons(self) -> None:
        connected = self.logic.connected
        building = self.logic.building
        ready = self.logic.models_ready
        hasSession = self.logic.has_session
        hasResection = bool(self._currentResection())
        kind = self.logic.resection_kinds().get(self._currentResection(), "bezier")
        if self._unsupported:
            self.ui.connectionStatusLabel.text = self._unsupported
        elif not connected:
            self.ui.connectionStatusLabel.text = _("Not connected")
        self.ui.connectButton.enabled = not self._unsupported
        self.ui.buildModelsButton.enabled = (connected and not building
                                             and self.ui.segmentationSelector.currentNode() is not None)
        self.ui.cancelBuildButton.enabled = building
        self.ui.newResectionButton.enabled = ready and self.ui.tumorComboBox.count > 0
        for button in (self.ui.deleteResectionButton, self.ui.exportModelsButton,
                       self.ui.showRiskButton, self.ui.resectogramButton):
            button.enabled = hasSession and hasResection
        for button in (self.ui.moveGroupButton, self.ui.translateButton, self.ui.rotateButton):
            button.enabled = hasSession and hasResection and kind == "bezier"
        for button in (self.ui.placeHandleButton, self.ui.deformButton,
                       self.ui.undoDeformationButton):
            button.enabled = hasSession and hasResection and kind == "cp"
        self.ui.drawTraceButton.enabled = ready
        for button in (self.ui.undoButton, self.ui.redoButton, self.ui.savePlanButton,
                       self.ui.loadPlanButton):
            button.enabled = hasSession and ready


#
# ResectaLogic
#


class ResectaLogic(ScriptedLoadableModuleLogic, PlanningLogic):
    """The module's Logic: no dialogs, runs without a GUI. The work is `ResectaLib.logic.
    PlanningLogic`'s (server calls on a worker thread, scene updates on the main thread by
    `poll()`); this class adds Slicer's parameter node, the end-point markups and the jump to
    the closest point."""

    def __init__(self) -> None:
        ScriptedLoadableModuleLogic.__init__(self)
        from ResectaLib.dispatch import ThreadDispatcher

        PlanningLogic.__init__(self, slicer.mrmlScene, ThreadDispatcher())

    def getParameterNode(self):
        return ResectaParameterNode(super().getParameterNode())

    def role_table(self, segmentationNode, keep=None):
        """(segment id, name, role) rows: `keep`'s role where given, else a guess by name."""
        guesses = segmentation.default_role_table(segmentationNode)
        keep = keep or {}
        return [(sid, name, keep.get(sid, guesses[sid]))
                for sid, name in segmentation.segments_of(segmentationNode)]

    def end_point_node(self, node, name):
        """`node` when it is an end-point list, else a new one (never a control grid)."""
        if node is None or node.GetAttribute(END_POINT_ATTRIBUTE) != "1":
            node = slicer.mrmlScene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", name)
            node.SetAttribute(END_POINT_ATTRIBUTE, "1")
            node.SetMaximumNumberOfControlPoints(1)
        return node

    @staticmethod
    def end_point(node):
        """The end point's RAS position, or None when `node` has no defined point."""
        if node is None or node.GetAttribute(END_POINT_ATTRIBUTE) != "1" \
                or node.GetNumberOfDefinedControlPoints() < 1:
            return None
        p = [0.0, 0.0, 0.0]
        node.GetNthControlPointPositionWorld(0, p)
        return p

    def jump_to_worst_point(self) -> None:
        state = self.margin_state
        if state.point is None:
            return
        x, y, z = state.point
        slicer.modules.markups.logic().JumpSlicesToLocation(x, y, z, True)
        for camera in slicer.util.getNodesByClass("vtkMRMLCameraNode"):
            camera.SetFocalPoint(x, y, z)


#
# ResectaTest
#


class ResectaTest(ScriptedLoadableModuleTest):
    """The self-test: the scenario of `ResectaLib.selftest` (also run by the pytest suite)
    against a `resecta serve` it starts on loopback (the program from the setting
    `Resecta/ServerBinary`, `$RESECTA_BIN` or PATH); without one it reports that it skipped."""

    def setUp(self):
        slicer.mrmlScene.Clear()

    def runTest(self):
        self.setUp()
        self.test_Scenario()

    def test_Scenario(self):
        from ResectaLib import localserver

        self.delayDisplay("Starting the Resecta scenario")
        binary = localserver.find_binary(qt.QSettings().value(localserver.SETTING_BINARY, ""))
        if binary is None:
            self.delayDisplay("Resecta self-test skipped: " + localserver.NOT_FOUND)
            return
        try:
            deps.check_slicer_version(slicer.app.applicationVersion)
        except deps.UnsupportedSlicer as exc:
            self.delayDisplay(f"Resecta self-test skipped: {exc}")
            return
        if not deps.ensure_installed(lambda packages: slicer.util.confirmOkCancelDisplay(
                _("The self-test needs: ") + ", ".join(packages))):
            self.delayDisplay("Resecta self-test skipped: dependencies not installed")
            return
        from ResectaLib import phantom, selftest
        from ResectaLib.dispatch import ThreadDispatcher

        dispatcher = ThreadDispatcher()

        def wait(predicate, timeout=120.0):
            # Keep Slicer's event loop turning while waiting (views redraw as models arrive).
            import time
            end = time.monotonic() + timeout
            while True:
                dispatcher.poll()
                slicer.app.processEvents()
                value = predicate()
                if value:
                    return value
                if time.monotonic() > end:
                    raise TimeoutError("condition not met in time")
                time.sleep(0.01)

        labels, ijkToRas, names, truth = phantom.make()
        segNode = segmentation.segmentation_from_labelmap_array(slicer.mrmlScene, labels, ijkToRas, names)
        with localserver.LocalServer(binary) as server:
            report = selftest.run(slicer.mrmlScene, segNode, truth, dispatcher, wait,
                                  address=server.grpc, log=self.delayDisplay)
        self.delayDisplay("Resecta scenario passed: " + report)
