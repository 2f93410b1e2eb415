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
from slicer import vtkMRMLMarkupsFiducialNode, vtkMRMLSegmentationNode
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

from ResectaLib import deps, margin, segmentation, volumetry

SETTINGS_ADDRESS = "Resecta/ServerAddress"
SETTINGS_TOKEN = "Resecta/Token"
SETTINGS_TLS = "Resecta/UseTls"
SETTINGS_CA_FILE = "Resecta/CaFile"
DEFAULT_ADDRESS = "127.0.0.1:50051"


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
            "Plan liver resections with a deformable Bézier surface and live safety margins, "
            "computed by a resecta planning server (after R. Palomar, NTNU 2018). "
            "See the module's README for the workflow.")
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
    sessionId: str = ""


#
# ResectaWidget
#


class ResectaWidget(ScriptedLoadableModuleWidget, VTKObservationMixin):
    """Wires the UI of Resources/UI/Resecta.ui to the Logic; holds no planning state."""

    def __init__(self, parent=None) -> None:
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self._parameterNode = None
        self._parameterNodeGuiTag = None
        self._shortcuts = []
        self._pollTimer = None
        self._editTimer = None

    def setup(self) -> None:
        ScriptedLoadableModuleWidget.setup(self)
        uiWidget = slicer.util.loadUI(self.resourcePath("UI/Resecta.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        uiWidget.setMRMLScene(slicer.mrmlScene)

        self.logic = ResectaLogic()
        self.logic.setCallbacks(
            status=self._showStatus, error=self._showError, progress=self._showProgress,
            models=self._refreshTumours, resections=self._refreshResections,
            volumes=self._showVolumes, margin=self._showMargin)

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
        self.ui.tokenLineEdit.text = settings.value(SETTINGS_TOKEN, "")
        self.ui.tlsCheckBox.checked = str(settings.value(SETTINGS_TLS, "false")).lower() == "true"
        self.ui.caFilePathLineEdit.currentPath = settings.value(SETTINGS_CA_FILE, "")

        if self.ui.methodComboBox.count == 0:
            self.ui.methodComboBox.addItems(["psr", "mcsd"])
        for label in (_("Inner points"), _("Outer ring"), _("All points")):
            self.ui.groupComboBox.addItem(label)
        for label in ("R", "A", "S", _("Surface normal")):
            self.ui.rotateAxisComboBox.addItem(label)
        for fmt in ("vtp", "vtk", "stl", "ply", "obj"):
            self.ui.exportFormatComboBox.addItem(fmt)
        self.ui.roleTable.horizontalHeader().setStretchLastSection(True)
        self.ui.volumeTable.horizontalHeader().setStretchLastSection(True)

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
        self.ui.marginSpinBox.connect("valueChanged(double)", lambda _v: self._editTimer.start())
        self.ui.bandSpinBox.connect("valueChanged(double)", lambda _v: self._editTimer.start())
        self.ui.marginIndicatorButton.connect("clicked(bool)", self.onJumpToWorst)
        self.ui.moveGroupButton.connect("clicked(bool)", self.onMoveGroup)
        self.ui.translateButton.connect("clicked(bool)", self.onTranslate)
        self.ui.rotateButton.connect("clicked(bool)", self.onRotate)
        self.ui.undoButton.connect("clicked(bool)", self.onUndo)
        self.ui.redoButton.connect("clicked(bool)", self.onRedo)
        self.ui.deleteResectionButton.connect("clicked(bool)", self.onDeleteResection)
        self.ui.savePlanButton.connect("clicked(bool)", self.onSavePlan)
        self.ui.loadPlanButton.connect("clicked(bool)", self.onLoadPlan)
        self.ui.exportModelsButton.connect("clicked(bool)", self.onExportModels)

        self.initializeParameterNode()
        self._updateButtons()

    def cleanup(self) -> None:
        self.removeObservers()
        if self._pollTimer:
            self._pollTimer.stop()
        if self.logic:
            self.logic.close()

    def enter(self) -> None:
        self.initializeParameterNode()
        # While the panel is shown, Ctrl+Z / Ctrl+Y undo and redo plan edits. Slicer's own
        # actions with the same keys (scene undo) lend them to us until exit(), otherwise Qt
        # would find the shortcut ambiguous and fire neither.
        mainWindow = slicer.util.mainWindow()
        self._lentShortcuts = []
        for keys, slot in (("Ctrl+Z", self.onUndo), ("Ctrl+Y", self.onRedo)):
            sequence = qt.QKeySequence(keys)
            for action in mainWindow.findChildren(qt.QAction) if mainWindow else []:
                if action.shortcut == sequence:
                    self._lentShortcuts.append((action, action.shortcut))
                    action.shortcut = qt.QKeySequence()
            shortcut = qt.QShortcut(sequence, mainWindow)
            shortcut.connect("activated()", slot)
            self._shortcuts.append(shortcut)

    def exit(self) -> None:
        for shortcut in self._shortcuts:
            shortcut.disconnect("activated()")
            shortcut.setParent(None)
        self._shortcuts = []
        for action, sequence in getattr(self, "_lentShortcuts", []):
            action.shortcut = sequence
        self._lentShortcuts = []
        if self._parameterNode:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
            self._parameterNodeGuiTag = None

    def onSceneStartClose(self, caller, event) -> None:
        self.setParameterNode(None)
        self.logic.close()

    def onSceneEndClose(self, caller, event) -> None:
        if self.parent.isEntered:
            self.initializeParameterNode()

    def initializeParameterNode(self) -> None:
        self.setParameterNode(self.logic.getParameterNode())
        if not self._parameterNode.segmentation:
            node = slicer.mrmlScene.GetFirstNodeByClass("vtkMRMLSegmentationNode")
            if node:
                self._parameterNode.segmentation = node

    def setParameterNode(self, inputParameterNode: Optional[ResectaParameterNode]) -> None:
        if self._parameterNode:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
        self._parameterNode = inputParameterNode
        if self._parameterNode:
            self._parameterNodeGuiTag = self._parameterNode.connectGui(self.ui)
            self.onSegmentationChanged(self._parameterNode.segmentation)

    # --- connection ---------------------------------------------------------------------------

    def onConnect(self) -> None:
        if not deps.ensure_installed(self._confirmInstall):
            self._showStatus(_("The Python packages resecta needs are not installed."))
            return
        address = self.ui.serverAddressLineEdit.text.strip() or DEFAULT_ADDRESS
        token = self.ui.tokenLineEdit.text.strip()
        tls = self.ui.tlsCheckBox.checked
        caFile = self.ui.caFilePathLineEdit.currentPath
        settings = qt.QSettings()
        settings.setValue(SETTINGS_ADDRESS, address)
        settings.setValue(SETTINGS_TOKEN, token)
        settings.setValue(SETTINGS_TLS, "true" if tls else "false")
        settings.setValue(SETTINGS_CA_FILE, caFile)
        with slicer.util.tryWithErrorDisplay(_("Could not connect."), waitCursor=True):
            self.logic.connect(address, token or None, tls, caFile or None,
                               onDone=lambda info: self._connected(info))

    def _confirmInstall(self, packages) -> bool:
        return slicer.util.confirmOkCancelDisplay(
            _("Resecta needs these Python packages, which will be installed now with pip:\n\n")
            + "\n".join(packages), windowTitle=_("Resecta: install dependencies"))

    def _connected(self, info) -> None:
        self.ui.connectionStatusLabel.text = _("Connected: resecta {version}").format(
            version=info.server_version)
        # A scene saved with a plan remembers its server session: follow it again.
        sessionId = self._parameterNode.sessionId if self._parameterNode else ""
        if sessionId:
            self.logic.openSession(sessionId, onDone=lambda _s: self._updateButtons())
        self._updateButtons()

    # --- patient ------------------------------------------------------------------------------

    def onSegmentationChanged(self, node) -> None:
        table = self.ui.roleTable
        table.setRowCount(0)
        if node is None:
            return
        roles = self.logic.roleTable(node)
        table.setRowCount(len(roles))
        for row, (segmentId, name, role) in enumerate(roles):
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
            self.ui.buildProgressBar.value = 0
            self.ui.cancelBuildButton.enabled = True
            self.ui.buildModelsButton.enabled = False
            self.logic.buildModels(p.segmentation, self._roleTableFromUi(), p.method,
                                   onDone=self._buildDone)

    def _buildDone(self, _models) -> None:
        self._parameterNode.sessionId = self.logic.sessionId or ""
        self._buildFinished()

    def _buildFinished(self, _result=None) -> None:
        self.ui.cancelBuildButton.enabled = False
        self.ui.buildModelsButton.enabled = True
        self._updateButtons()

    def onCancelBuild(self) -> None:
        self.logic.cancelBuild()
        self._buildFinished()

    def onOpacity(self, value) -> None:
        self.logic.setOpacity(("parenchyma",), value)

    def onResectionOpacity(self, value) -> None:
        self.logic.setOpacity(("resection",), value)

    # --- resection ----------------------------------------------------------------------------

    def onPlaceEndPoint(self, checked) -> None:
        if not checked:
            slicer.app.applicationLogic().GetInteractionNode().SwitchToViewTransformMode()
            return
        node = self._parameterNode.endPoint
        if node is None:
            node = slicer.mrmlScene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", _("Resecta end point"))
            node.SetMaximumNumberOfControlPoints(1)
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
        if node is None or node.GetNumberOfDefinedControlPoints() < 1:
            return None
        p = [0.0, 0.0, 0.0]
        node.GetNthControlPointPositionWorld(0, p)
        return p

    def onPreview(self, *args) -> None:
        endPoint = self._endPoint()
        if endPoint is not None:
            self.ui.placeEndPointButton.checked = False
        tumour = self.ui.tumorComboBox.currentText
        self.logic.preview(tumour, endPoint)
        self._updateButtons()

    def onNewResection(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Could not create the resection."), waitCursor=True):
            endPoint = self._endPoint()
            if endPoint is None:
                raise ValueError(_("Place the end point first."))
            name = self.ui.resectionNameLineEdit.text.strip() or "r1"
            self.logic.newResection(name, self.ui.tumorComboBox.currentText, endPoint,
                                    marginMm=self._parameterNode.marginMm,
                                    bandMm=self._parameterNode.bandMm)
            self.logic.preview(None, None)

    def _currentResection(self) -> str:
        return self.ui.resectionComboBox.currentText

    def onResectionSelected(self, _index=None) -> None:
        params = self.logic.resectionParameters(self._currentResection())
        if params is not None and self._parameterNode:
            self._parameterNode.marginMm = params.margin_mm
            self._parameterNode.bandMm = params.band_mm
            self._editTimer.stop()  # the values came from the server: nothing to send
        self._updateButtons()

    def onMarginBandSettled(self) -> None:
        name = self._currentResection()
        if not name:
            return
        with slicer.util.tryWithErrorDisplay(_("Could not change the margin.")):
            self.logic.setMarginAndBand(name, self._parameterNode.marginMm, self._parameterNode.bandMm)

    def _delta(self):
        return [float(x) for x in self.ui.deltaCoordinates.coordinates.split(",")]

    def onMoveGroup(self) -> None:
        group = ("inner", "outer", "all")[self.ui.groupComboBox.currentIndex]
        with slicer.util.tryWithErrorDisplay(_("Could not move the group.")):
            self.logic.moveGroup(self._currentResection(), group, self._delta())

    def onTranslate(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Could not translate.")):
            self.logic.translate(self._currentResection(), self._delta())

    def onRotate(self) -> None:
        axis = ("R", "A", "S", "normal")[self.ui.rotateAxisComboBox.currentIndex]
        with slicer.util.tryWithErrorDisplay(_("Could not rotate.")):
            self.logic.rotate(self._currentResection(), axis, self.ui.rotateAngleSpinBox.value)

    def onUndo(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Nothing to undo.")):
            self.logic.undo()

    def onRedo(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Nothing to redo.")):
            self.logic.redo()

    def onDeleteResection(self) -> None:
        name = self._currentResection()
        if name and slicer.util.confirmYesNoDisplay(_("Delete resection {name}?").format(name=name)):
            self.logic.deleteResection(name)

    def onJumpToWorst(self) -> None:
        self.logic.jumpToWorstPoint()

    # --- plan ---------------------------------------------------------------------------------

    def onSavePlan(self) -> None:
        path = qt.QFileDialog.getSaveFileName(None, _("Save plan"), "plan.json", _("Plan (*.json)"))
        if path:
            with slicer.util.tryWithErrorDisplay(_("Could not save the plan.")):
                self.logic.savePlan(path)

    def onLoadPlan(self) -> None:
        path = qt.QFileDialog.getOpenFileName(None, _("Load plan"), "", _("Plan (*.json)"))
        if path:
            with slicer.util.tryWithErrorDisplay(_("Could not load the plan.")):
                self.logic.loadPlan(path)

    def onExportModels(self) -> None:
        folder = qt.QFileDialog.getExistingDirectory(None, _("Export resection models to"))
        if folder:
            with slicer.util.tryWithErrorDisplay(_("Could not export the models.")):
                self.logic.exportResections(folder, self.ui.exportFormatComboBox.currentText)

    # --- what the Logic reports ---------------------------------------------------------------

    def _showStatus(self, text: str) -> None:
        self.ui.statusLabel.text = text

    def _showError(self, exc: Exception) -> None:
        logging.error("Resecta: %s", exc)
        self.ui.statusLabel.text = _("Error: {error}").format(error=exc)
        self._buildFinished()

    def _showProgress(self, fraction: float, stage: str) -> None:
        self.ui.buildProgressBar.value = int(round(100 * fraction))
        self.ui.buildProgressBar.format = f"{stage} %p%"

    def _refreshTumours(self) -> None:
        current = self.ui.tumorComboBox.currentText
        self.ui.tumorComboBox.clear()
        for name in self.logic.tumours():
            self.ui.tumorComboBox.addItem(name)
        index = self.ui.tumorComboBox.findText(current)
        if index >= 0:
            self.ui.tumorComboBox.setCurrentIndex(index)
        self._updateButtons()

    def _refreshResections(self) -> None:
        current = self._currentResection()
        combo = self.ui.resectionComboBox
        wasBlocked = combo.blockSignals(True)
        combo.clear()
        for name in self.logic.resectionNames():
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

    def _showMargin(self, state: margin.MarginIndicator) -> None:
        button = self.ui.marginIndicatorButton
        button.text = state.text
        button.enabled = state.can_jump
        button.setStyleSheet(f"QPushButton {{ background-color: {state.color}; color: white; "
                             "font-weight: bold; padding: 4px; }}")

    def _updateButtons(self) -> None:
        connected = self.logic.connected
        ready = self.logic.modelsReady
        hasResection = bool(self._currentResection())
        self.ui.buildModelsButton.enabled = connected and self.ui.segmentationSelector.currentNode() is not None
        self.ui.newResectionButton.enabled = ready and self.ui.tumorComboBox.count > 0
        for button in (self.ui.moveGroupButton, self.ui.translateButton, self.ui.rotateButton,
                       self.ui.deleteResectionButton, self.ui.exportModelsButton):
            button.enabled = hasResection
        for button in (self.ui.undoButton, self.ui.redoButton, self.ui.savePlanButton,
                       self.ui.loadPlanButton):
            button.enabled = ready


#
# ResectaLogic
#


class ResectaLogic(ScriptedLoadableModuleLogic):
    """The module's Logic: no dialogs, runs without a GUI. Planning work is delegated to
    `ResectaLib.session.PlanningSession` (server calls on worker threads, scene updates on the
    main thread by `poll()`)."""

    def __init__(self) -> None:
        ScriptedLoadableModuleLogic.__init__(self)
        self._session = None
        self._callbacks = {}

    def getParameterNode(self):
        return ResectaParameterNode(super().getParameterNode())

    def setCallbacks(self, **callbacks) -> None:
        self._callbacks = callbacks
        if self._session is not None:
            self._session.set_callbacks(**callbacks)

    @property
    def session(self):
        if self._session is None:
            from ResectaLib.dispatch import ThreadDispatcher
            from ResectaLib.session import PlanningSession

            self._session = PlanningSession(slicer.mrmlScene, ThreadDispatcher())
            self._session.set_callbacks(**self._callbacks)
        return self._session

    @property
    def connected(self) -> bool:
        return self._session is not None and self._session.connected

    @property
    def modelsReady(self) -> bool:
        return self._session is not None and self._session.models_ready

    def poll(self) -> None:
        if self._session is not None:
            self._session.poll()

    def close(self) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None

    def connect(self, address, token=None, tls=False, caFile=None, onDone=None):
        self.session.connect(address, token=token, tls=tls, ca_file=caFile, on_done=onDone)

    @property
    def sessionId(self):
        return self._session.session_id if self._session is not None else None

    def openSession(self, sessionId, onDone=None):
        self.session.open_session(sessionId, on_done=onDone)

    def roleTable(self, segmentationNode):
        guesses = segmentation.default_role_table(segmentationNode)
        return [(sid, name, guesses[sid]) for sid, name in segmentation.segments_of(segmentationNode)]

    def buildModels(self, segmentationNode, roleTable, method="psr", onDone=None):
        if segmentationNode is None:
            raise ValueError(_("Select a segmentation first."))
        self.session.upload_and_build(segmentationNode, roleTable, method=method, on_done=onDone)

    def cancelBuild(self) -> None:
        if self._session is not None:
            self._session.cancel_build()

    def setOpacity(self, kinds, value) -> None:
        if self._session is not None:
            self._session.set_opacity(kinds, value)

    def tumours(self):
        return self.session.tumours()

    def resectionNames(self):
        return self.session.resection_names()

    def resectionParameters(self, name):
        return self.session.resection(name) if name and self._session is not None else None

    def preview(self, tumour, endPoint):
        if self._session is not None:
            self._session.preview(tumour, endPoint)

    def newResection(self, name, tumour, endPoint, marginMm=None, bandMm=None):
        self.session.new_resection(name, tumour, endPoint, margin_mm=marginMm, band_mm=bandMm)

    def setMarginAndBand(self, name, marginMm, bandMm):
        self.session.set_margin_and_band(name, marginMm, bandMm)

    def moveGroup(self, name, group, delta):
        self.session.move_group(name, group, delta)

    def translate(self, name, delta):
        self.session.translate(name, delta)

    def rotate(self, name, axis, angleDeg):
        self.session.rotate(name, axis, angleDeg)

    def undo(self):
        self.session.undo()

    def redo(self):
        self.session.redo()

    def deleteResection(self, name):
        self.session.delete_resection(name)

    def savePlan(self, path):
        self.session.save_plan(path)

    def loadPlan(self, path):
        self.session.load_plan(path)

    def exportResections(self, folder, fmt="vtp"):
        self.session.export_resections(folder, fmt)

    def jumpToWorstPoint(self) -> None:
        state = self.session.margin_state
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
    against the server whose address is in the module's settings (`resecta serve` on
    127.0.0.1:50051 by default)."""

    def setUp(self):
        slicer.mrmlScene.Clear()

    def runTest(self):
        self.setUp()
        self.test_Scenario()

    def test_Scenario(self):
        self.delayDisplay("Starting the Resecta scenario")
        if not deps.ensure_installed(lambda packages: slicer.util.confirmOkCancelDisplay(
                _("The self-test needs: ") + ", ".join(packages))):
            self.delayDisplay("Dependencies not installed: test skipped")
            return
        from ResectaLib import phantom, selftest
        from ResectaLib.dispatch import ThreadDispatcher

        settings = qt.QSettings()
        address = settings.value(SETTINGS_ADDRESS, DEFAULT_ADDRESS)
        token = settings.value(SETTINGS_TOKEN, "") or None
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
        report = selftest.run(slicer.mrmlScene, segNode, truth, dispatcher, wait,
                              address=address, token=token, log=self.delayDisplay)
        self.delayDisplay("Resecta scenario passed: " + report)
