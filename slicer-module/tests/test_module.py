"""Resecta.py itself outside Slicer: its Logic and its self-test run on real MRML (slicer-core)
against a real server, with small stand-ins for what only the Slicer application has (Qt, the
ScriptedLoadableModule base classes, the parameter-node wrapper, `slicer.app`). The Widget needs
Qt and is covered by the static checks (every widget it uses exists in the .ui)."""

import importlib
import sys
import types

import numpy as np
import pytest

import slicer
from conftest import MODULE_DIR, load_phantom_segmentation


class _Settings:
    values: dict = {}

    def value(self, key, default=None):
        return self.values.get(key, default)

    def setValue(self, key, value):
        self.values[key] = value


class _MarkupsLogic:
    def __init__(self):
        self.jumps = []

    def JumpSlicesToLocation(self, x, y, z, centered, *rest):
        self.jumps.append((x, y, z))


def _stand_ins(scene):
    qt = types.ModuleType("qt")
    qt.QSettings = _Settings
    slm = types.ModuleType("slicer.ScriptedLoadableModule")

    class ScriptedLoadableModule:
        def __init__(self, parent):
            self.parent = parent

    class ScriptedLoadableModuleWidget:
        def __init__(self, parent=None):
            self.parent = parent

    class ScriptedLoadableModuleLogic:
        def __init__(self, parent=None):
            pass

        def getParameterNode(self):
            node = scene.AddNewNodeByClass("vtkMRMLScriptedModuleNode")
            node.SetAttribute("ModuleName", "Resecta")
            return node

    class ScriptedLoadableModuleTest:
        def __init__(self):
            self.messages = []

        def delayDisplay(self, message, msec=None):
            self.messages.append(message)

    for cls in (ScriptedLoadableModule, ScriptedLoadableModuleWidget, ScriptedLoadableModuleLogic,
                ScriptedLoadableModuleTest):
        setattr(slm, cls.__name__, cls)
    pnw = types.ModuleType("slicer.parameterNodeWrapper")

    def parameterNodeWrapper(cls):
        defaults = {k: getattr(cls, k, None) for k in cls.__annotations__}

        def init(self, node):
            self.parameterNode = node
            for k, v in defaults.items():
                setattr(self, k, v)

        cls.__init__ = init
        return cls

    pnw.parameterNodeWrapper = parameterNodeWrapper
    pnw.Choice = lambda values: ("choice", tuple(values))
    pnw.WithinRange = lambda lo, hi: ("range", lo, hi)
    i18n = types.ModuleType("slicer.i18n")
    i18n.tr = lambda text: text
    i18n.translate = lambda context, text: text
    app = types.SimpleNamespace(processEvents=lambda: None)
    markups = _MarkupsLogic()
    modules = types.SimpleNamespace(markups=types.SimpleNamespace(logic=lambda: markups))
    return {"qt": qt, "slicer.ScriptedLoadableModule": slm, "slicer.parameterNodeWrapper": pnw,
            "slicer.i18n": i18n}, {"mrmlScene": scene, "app": app, "modules": modules}, markups


@pytest.fixture
def Resecta(scene, monkeypatch):
    mods, attrs, markups = _stand_ins(scene)
    for name, module in mods.items():
        monkeypatch.setitem(sys.modules, name, module)
    for name, value in attrs.items():
        monkeypatch.setattr(slicer, name, value, raising=False)
    monkeypatch.syspath_prepend(str(MODULE_DIR))
    sys.modules.pop("Resecta", None)
    module = importlib.import_module("Resecta")
    module._markups = markups
    yield module
    sys.modules.pop("Resecta", None)


def test_module_metadata(Resecta):
    parent = types.SimpleNamespace()
    Resecta.Resecta(parent)
    assert parent.title == "Resecta" and parent.categories == ["Surgical Planning"]
    node = Resecta.ResectaParameterNode(None)
    assert node.method == "psr" and node.marginMm == 10.0 and node.bandMm == 5.0


def test_logic_drives_a_plan(Resecta, scene, planning_server, phantom, tmp_path):
    logic = Resecta.ResectaLogic()
    assert not logic.connected and not logic.modelsReady

    def wait(predicate, timeout=60):
        return logic.session.dispatcher.wait_until(predicate, timeout)

    try:
        assert logic.sessionId is None
        infos = []
        logic.connect(planning_server.grpc_addr, onDone=infos.append)
        wait(lambda: infos)
        assert logic.connected and infos[0].api_version == "resecta.v1"
        _lm, seg = load_phantom_segmentation(scene, phantom)
        rows = logic.roleTable(seg)
        assert [r[2] for r in rows] == ["ignore"] * 3  # "Label_1"...: nothing to guess from
        roles = {sid: role for (sid, _n, _g), role in zip(rows, ["parenchyma", "tumor", "portal"])}
        built = []
        logic.buildModels(seg, roles, "psr", onDone=built.append)
        wait(lambda: built and logic.modelsReady and logic.tumours(), 120)
        assert logic.sessionId
        tumour = logic.tumours()[0]
        end = logic.session.tumour_centroid(tumour) + [-40.0, 0, 0]
        logic.preview(tumour, end)
        logic.newResection("r1", tumour, end, marginMm=8.0, bandMm=3.0)
        wait(lambda: logic.resectionNames() == ["r1"] and logic.resectionParameters("r1").margin_mm == 8.0
             and logic.resectionParameters("r1").band_mm == 3.0)
        logic.setMarginAndBand("r1", 9.0, 3.0)
        wait(lambda: logic.resectionParameters("r1").margin_mm == 9.0)
        cp = logic.resectionParameters("r1").control_points.copy()
        logic.moveGroup("r1", "outer", (0, 0, 1.0))
        wait(lambda: not np.allclose(logic.resectionParameters("r1").control_points, cp)
             and not np.allclose(logic.session.last_edit["r1"].resection.control_points, cp))
        edits = logic.session.acknowledged_edits
        logic.translate("r1", (1.0, 0, 0))
        logic.rotate("r1", "normal", 3.0)
        wait(lambda: logic.session.acknowledged_edits == edits + 2)
        rotated = logic.session.last_edit["r1"].resection.control_points.copy()
        logic.undo()
        logic.redo()
        wait(lambda: logic.session.acknowledged_edits == edits + 4 and not logic.session.errors)
        wait(lambda: np.allclose(logic.resectionParameters("r1").control_points, rotated))
        logic.jumpToWorstPoint()
        assert len(Resecta._markups.jumps) == 1
        assert np.allclose(Resecta._markups.jumps[0], logic.session.margin_state.point)
        logic.savePlan(tmp_path / "plan.json")
        wait(lambda: (tmp_path / "plan.json").is_file())
        logic.exportResections(tmp_path, "stl")
        wait(lambda: (tmp_path / "r1.stl").is_file())
        logic.deleteResection("r1")
        wait(lambda: logic.resectionNames() == [])
        logic.loadPlan(tmp_path / "plan.json")
        wait(lambda: logic.resectionNames() == ["r1"])
        logic.setOpacity(("parenchyma",), 0.5)
        assert not logic.session.errors
    finally:
        logic.close()
    assert not logic.connected


def test_self_test_runs_as_in_slicer(Resecta, planning_server):
    """`ResectaTest.runTest()` exactly as Slicer runs it, with the server from the settings."""
    _Settings.values = {Resecta.SETTINGS_ADDRESS: planning_server.grpc_addr}
    test = Resecta.ResectaTest()
    test.runTest()
    assert test.messages[-1].startswith("Resecta scenario passed")
