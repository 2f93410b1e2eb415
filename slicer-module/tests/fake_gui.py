"""A small fake of the Qt / CTK / Slicer-application surface that `Resecta.py` uses, so that the
Widget's lifecycle (setup, enter, exit, scene close, reload, cleanup) runs under pytest on real
MRML (`slicer-core`) and a real server.

The fake widgets are made from `Resources/UI/Resecta.ui` itself (names, classes, initial
properties and `SlicerParameterName` bindings), so a widget the code uses and the .ui lacks fails
here as in Slicer. `Gui` records what a leak would leave behind: running timers, shortcuts on the
main window, Slicer's own Ctrl+Z/Ctrl+Y actions still lent, parameter-node GUI connections, and
the dialogs that popped up. `install(scene)` puts the fake modules in place and returns the `Gui`.
"""

from __future__ import annotations

import contextlib
import sys
import types
import xml.etree.ElementTree as ET
from pathlib import Path

import slicer

MODULE_DIR = Path(__file__).resolve().parent.parent / "Resecta"


# --- signals and widgets ---------------------------------------------------------------------


def _arity(slot, available: int) -> int:
    """How many of a signal's arguments `slot` takes (PythonQt drops the rest, as Qt does)."""
    import inspect

    try:
        params = inspect.signature(slot).parameters.values()
    except (TypeError, ValueError):
        return available
    if any(p.kind is p.VAR_POSITIONAL for p in params):
        return available
    return min(available, sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params))


class _Object:
    """Qt-style signals: `connect("name(args)", slot)`, `disconnect("name(args)")`."""

    def __init__(self):
        self._slots: dict[str, list] = {}
        self._blocked = False

    def connect(self, signal: str, slot) -> None:
        self._slots.setdefault(signal.split("(")[0], []).append(slot)

    def disconnect(self, signal: str, slot=None) -> None:
        name = signal.split("(")[0]
        if slot is None:
            self._slots.pop(name, None)
        elif slot in self._slots.get(name, []):
            self._slots[name].remove(slot)

    def emit(self, signal: str, *args) -> None:
        if self._blocked:
            return
        for slot in list(self._slots.get(signal, [])):
            slot(*args[:_arity(slot, len(args))])

    def blockSignals(self, block: bool) -> bool:
        was, self._blocked = self._blocked, bool(block)
        return was


class Widget(_Object):
    def __init__(self, name="", cls="QWidget", props=None):
        super().__init__()
        self.name, self.cls = name, cls
        self.props = dict(props or {})
        self.enabled = self.props.pop("enabled", "true") != "false"
        self.text = self.props.pop("text", "") or ""
        self.checked = False
        self.children: list[Widget] = []
        self.style = ""

    def __setattr__(self, key, value):
        old = self.__dict__.get(key)
        super().__setattr__(key, value)
        if key == "checked" and "_slots" in self.__dict__ and bool(old) != bool(value):
            self.emit("toggled", bool(value))

    def setStyleSheet(self, style):
        self.style = style

    def setMRMLScene(self, scene):
        for child in self.children:
            child.setMRMLScene(scene)


class ComboBox(Widget):
    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.items: list[str] = []
        self._index = -1

    @property
    def count(self):
        return len(self.items)

    def addItem(self, text):
        self.items.append(text)
        if self._index < 0:
            self.setCurrentIndex(0)

    def addItems(self, texts):
        for t in texts:
            self.addItem(t)

    def clear(self):
        self.items = []
        self.setCurrentIndex(-1)

    def findText(self, text):
        return self.items.index(text) if text in self.items else -1

    @property
    def currentIndex(self):
        return self._index

    def setCurrentIndex(self, index):
        changed = index != self._index
        self._index = index
        if changed:
            self.emit("currentIndexChanged", index)

    @property
    def currentText(self):
        return self.items[self._index] if 0 <= self._index < len(self.items) else ""

    @currentText.setter
    def currentText(self, text):
        if text in self.items:
            self.setCurrentIndex(self.items.index(text))


class NodeComboBox(Widget):
    """qMRMLNodeComboBox: lists the scene's nodes of `nodeTypes`, filtered by `addAttribute`."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.scene = None
        self.node = None
        self.nodeTypes = list(self.props.get("nodeTypes") or [])
        self.attributes: dict[str, tuple[str, str]] = {}

    def setMRMLScene(self, scene):
        self.scene = scene

    def addAttribute(self, nodeType, name, value=None):
        self.attributes[nodeType] = (name, value)

    def nodes(self):
        out = []
        for cls in self.nodeTypes:
            for i in range(self.scene.GetNumberOfNodesByClass(cls)):
                node = self.scene.GetNthNodeByClass(i, cls)
                name, value = self.attributes.get(node.GetClassName(), (None, None))
                if name is None or node.GetAttribute(name) == value:
                    out.append(node)
        return out

    def currentNode(self):
        if self.node is not None and self.scene is not None \
                and self.scene.GetNodeByID(self.node.GetID()) is not self.node:
            self.node = None
        return self.node

    def setCurrentNode(self, node):
        if node is not self.node:
            self.node = node
            self.emit("currentNodeChanged", node)


class TableWidget(Widget):
    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.rowCount = 0
        self.items: dict = {}
        self.cells: dict = {}
        self.header = types.SimpleNamespace(setStretchLastSection=lambda _on: None)

    def horizontalHeader(self):
        return self.header

    def setRowCount(self, n):
        self.rowCount = n
        self.items = {k: v for k, v in self.items.items() if k[0] < n}
        self.cells = {k: v for k, v in self.cells.items() if k[0] < n}

    def setItem(self, row, col, item):
        self.items[(row, col)] = item

    def item(self, row, col):
        return self.items.get((row, col))

    def setCellWidget(self, row, col, widget):
        self.cells[(row, col)] = widget

    def cellWidget(self, row, col):
        return self.cells.get((row, col))


class ValueWidget(Widget):
    """Spin boxes and sliders: `value` emits valueChanged."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.__dict__["_value"] = float(self.props.get("value", 0) or 0)
        self.format = "%p%"

    @property
    def value(self):
        return self._value

    @value.setter
    def value(self, v):
        changed = v != self._value
        self.__dict__["_value"] = v
        if changed:
            self.emit("valueChanged", v)


class CoordinatesWidget(Widget):
    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.coordinates = self.props.get("coordinates", "0,0,0")


class PathLineEdit(Widget):
    currentPath = ""


_CLASSES = {"QComboBox": ComboBox, "qMRMLNodeComboBox": NodeComboBox, "QTableWidget": TableWidget,
            "QDoubleSpinBox": ValueWidget, "ctkSliderWidget": ValueWidget,
            "QProgressBar": ValueWidget, "ctkCoordinatesWidget": CoordinatesWidget,
            "ctkPathLineEdit": PathLineEdit}


def _property(p):
    value = list(p)[0] if len(p) else None
    if value is None:
        return None
    if value.tag == "stringlist":
        return [s.text for s in value]
    return value.text


def load_ui(path) -> Widget:
    """The widget tree of a Qt Designer file, made of the fakes above."""

    def make(element):
        props = {p.get("name"): _property(p) for p in element.findall("property")}
        cls = element.get("class")
        w = _CLASSES.get(cls, Widget)(element.get("name"), cls, props)
        for child in element.iter("widget"):
            if child is not element and child not in seen:
                seen.add(child)
                w.children.append(make(child))
        return w

    seen: set = set()
    root = ET.parse(path).getroot().find("widget")
    seen.add(root)
    return make(root)


def child_widgets(root: Widget) -> types.SimpleNamespace:
    out = {}

    def walk(w):
        for c in w.children:
            out[c.name] = c
            walk(c)

    walk(root)
    return types.SimpleNamespace(**out)


# --- Qt classes ------------------------------------------------------------------------------


class Gui:
    """What the fake application holds, for assertions."""

    def __init__(self, scene):
        self.scene = scene
        self.timers: list = []
        self.main_window = MainWindow()
        self.gui_connections: dict = {}
        self.dialogs: list[str] = []
        self.errors: list[BaseException] = []
        self.confirm = True
        self.file_answer = ""
        self.markups = types.SimpleNamespace(active=None, placing=0, jumps=[])
        self.slicer_version = "5.10.0"

    @property
    def running_timers(self):
        return [t for t in self.timers if t.active]

    def process(self) -> None:
        """One turn of the event loop: every running timer fires."""
        for timer in self.running_timers:
            timer.fire()

    def wait(self, predicate, timeout=60.0):
        import time

        end = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > end:
                raise TimeoutError("condition not met in time")
            self.process()
            time.sleep(0.005)


class KeySequence:
    def __init__(self, keys=""):
        self.keys = keys

    def __eq__(self, other):
        return isinstance(other, KeySequence) and other.keys == self.keys

    def __hash__(self):
        return hash(self.keys)


class Action:
    def __init__(self, keys):
        self.shortcut = KeySequence(keys)


class MainWindow:
    def __init__(self):
        self.actions = [Action("Ctrl+Z"), Action("Ctrl+Y"), Action("Ctrl+S")]
        self.shortcuts: list = []

    def findChildren(self, cls):
        return list(self.actions) if cls is Action else []


def _qt_module(gui: Gui) -> types.ModuleType:
    qt = types.ModuleType("qt")

    class QTimer(_Object):
        def __init__(self):
            super().__init__()
            self.active = False
            self.single = False
            self.interval = 0
            gui.timers.append(self)

        def setInterval(self, ms):
            self.interval = ms

        def setSingleShot(self, single):
            self.single = single

        def start(self):
            self.active = True

        def stop(self):
            self.active = False

        def fire(self):
            if self.single:
                self.active = False
            self.emit("timeout")

    class QShortcut(_Object):
        def __init__(self, sequence, parent):
            super().__init__()
            self.sequence = sequence
            self.parent = None
            self.setParent(parent)

        def setParent(self, parent):
            if self.parent is not None:
                self.parent.shortcuts.remove(self)
            self.parent = parent
            if parent is not None:
                parent.shortcuts.append(self)

    class QSettings:
        values: dict = {}

        def value(self, key, default=None):
            return self.values.get(key, default)

        def setValue(self, key, value):
            self.values[key] = value

    class QTableWidgetItem:
        def __init__(self, text=""):
            self._text, self._data = text, {}

        def text(self):
            return self._text

        def setData(self, role, value):
            self._data[role] = value

        def data(self, role):
            return self._data.get(role)

        def setFlags(self, flags):
            self.flags = flags

        def setForeground(self, brush):
            self.brush = brush

    class QFileDialog:
        getSaveFileName = getOpenFileName = getExistingDirectory = \
            staticmethod(lambda *a, **k: gui.file_answer)

    qt.QTimer, qt.QShortcut, qt.QSettings = QTimer, QShortcut, QSettings
    qt.QKeySequence, qt.QAction = KeySequence, Action
    qt.QTableWidgetItem, qt.QFileDialog = QTableWidgetItem, QFileDialog
    qt.QComboBox = lambda: ComboBox("", "QComboBox")
    qt.QBrush = qt.QColor = lambda *a: a
    qt.Qt = types.SimpleNamespace(UserRole=256, ItemIsEnabled=32)
    return qt


# --- Slicer's scripted-module classes and parameter-node wrapper ------------------------------


def _slm_module(gui: Gui) -> types.ModuleType:
    slm = types.ModuleType("slicer.ScriptedLoadableModule")

    class ScriptedLoadableModule:
        def __init__(self, parent):
            self.parent = parent

    class ScriptedLoadableModuleWidget:
        def __init__(self, parent=None):
            self.parent = parent or types.SimpleNamespace(isEntered=False)
            self.layout = types.SimpleNamespace(addWidget=lambda _w: None)

        def setup(self):
            pass

        def resourcePath(self, relative):
            return str(MODULE_DIR / "Resources" / relative)

    class ScriptedLoadableModuleLogic:
        def __init__(self, parent=None):
            pass

        def getParameterNode(self):
            node = gui.scene.GetSingletonNode("Resecta", "vtkMRMLScriptedModuleNode")
            if node is None:
                node = slicer.vtkMRMLScriptedModuleNode()
                node.SetSingletonTag("Resecta")
                node.SetAttribute("ModuleName", "Resecta")
                gui.scene.AddNode(node)
            return node

    class ScriptedLoadableModuleTest:
        def __init__(self):
            self.messages = []

        def delayDisplay(self, message, msec=None):
            self.messages.append(message)

    for cls in (ScriptedLoadableModule, ScriptedLoadableModuleWidget, ScriptedLoadableModuleLogic,
                ScriptedLoadableModuleTest):
        setattr(slm, cls.__name__, cls)
    return slm


def _pnw_module(gui: Gui) -> types.ModuleType:
    """`parameterNodeWrapper`: typed fields kept in the MRML parameter node (values as
    parameters, nodes as references, as Slicer keeps them); `connectGui` binds the widgets
    named by `SlicerParameterName` both ways until `disconnectGui`."""
    pnw = types.ModuleType("slicer.parameterNodeWrapper")

    def parameterNodeWrapper(cls):
        fields = dict(cls.__annotations__)
        defaults = {k: getattr(cls, k, None) for k in fields}

        def is_node(k):
            return isinstance(fields[k], type) and issubclass(fields[k], slicer.vtkMRMLNode)

        def init(self, node):
            object.__setattr__(self, "parameterNode", node)

        def getattr_(self, k):
            if k not in fields:
                raise AttributeError(k)
            node = self.parameterNode
            if is_node(k):
                return node.GetNodeReference(k) if node else None
            if node is None or not node.GetParameter(k):
                return defaults[k]
            return type(defaults[k])(node.GetParameter(k)) if defaults[k] is not None \
                else node.GetParameter(k)

        def setattr_(self, k, value):
            if k not in fields:
                raise AttributeError(f"{cls.__name__} has no parameter {k!r}")
            if is_node(k):
                self.parameterNode.SetNodeReferenceID(k, value.GetID() if value else None)
            else:
                self.parameterNode.SetParameter(k, str(value))

        def connectGui(self, ui):
            """Binds each widget with a `SlicerParameterName` both ways, as Slicer does."""
            tag = object()
            bindings = []
            for w in vars(ui).values():
                k = w.props.get("SlicerParameterName")
                if k not in fields:
                    continue
                if is_node(k):
                    w.setCurrentNode(getattr_(self, k))
                    signal, slot = "currentNodeChanged", (lambda node, k=k: setattr_(self, k, node))
                elif isinstance(w, ComboBox):
                    w.currentText = getattr_(self, k)
                    signal, slot = "currentIndexChanged", (
                        lambda _i, k=k, w=w: setattr_(self, k, w.currentText))
                elif isinstance(w, ValueWidget):
                    w.value = getattr_(self, k)
                    signal, slot = "valueChanged", (lambda v, k=k: setattr_(self, k, v))
                else:
                    continue
                w.connect(signal, slot)
                bindings.append((w, signal, slot))
            gui.gui_connections[tag] = bindings
            return tag

        def disconnectGui(self, tag):
            for w, signal, slot in gui.gui_connections.pop(tag, []):
                w.disconnect(signal, slot)

        cls.__init__ = init
        cls.__getattr__ = getattr_
        cls.__setattr__ = setattr_
        cls.connectGui, cls.disconnectGui = connectGui, disconnectGui
        for k in fields:
            if hasattr(cls, k):
                delattr(cls, k)
        return cls

    pnw.parameterNodeWrapper = parameterNodeWrapper
    pnw.Choice = lambda values: ("choice", tuple(values))
    pnw.WithinRange = lambda lo, hi: ("range", lo, hi)
    return pnw


def install(monkeypatch, scene) -> Gui:
    """Puts the fakes in place (undone by `monkeypatch`); returns the application's state."""
    gui = Gui(scene)
    i18n = types.ModuleType("slicer.i18n")
    i18n.tr = lambda text: text
    i18n.translate = lambda context, text: text
    for name, module in {"qt": _qt_module(gui), "slicer.ScriptedLoadableModule": _slm_module(gui),
                         "slicer.parameterNodeWrapper": _pnw_module(gui),
                         "slicer.i18n": i18n}.items():
        monkeypatch.setitem(sys.modules, name, module)

    @contextlib.contextmanager
    def try_with_error_display(message=None, show=True, waitCursor=False):
        try:
            yield
        except Exception as exc:  # noqa: BLE001 - what Slicer shows in a dialog
            gui.errors.append(exc)
            gui.dialogs.append(f"{message} {exc}")

    def confirm(text, **kwargs):
        gui.dialogs.append(text)
        return gui.confirm

    interaction = types.SimpleNamespace(SwitchToViewTransformMode=lambda: None)
    app = types.SimpleNamespace(
        applicationVersion=gui.slicer_version, processEvents=gui.process,
        applicationLogic=lambda: types.SimpleNamespace(GetInteractionNode=lambda: interaction))
    markups = gui.markups
    markups_logic = types.SimpleNamespace(
        SetActiveList=lambda node: setattr(markups, "active", node),
        StartPlaceMode=lambda persistent: setattr(markups, "placing", markups.placing + 1),
        JumpSlicesToLocation=lambda x, y, z, centred, *rest: markups.jumps.append((x, y, z)))
    for name, value in {"mrmlScene": scene, "app": app,
                        "modules": types.SimpleNamespace(
                            markups=types.SimpleNamespace(logic=lambda: markups_logic))}.items():
        monkeypatch.setattr(slicer, name, value, raising=False)
    for name, value in {"loadUI": load_ui, "childWidgetVariables": child_widgets,
                        "mainWindow": lambda: gui.main_window,
                        "tryWithErrorDisplay": try_with_error_display,
                        "confirmOkCancelDisplay": confirm, "confirmYesNoDisplay": confirm}.items():
        monkeypatch.setattr(slicer.util, name, value)
    monkeypatch.syspath_prepend(str(MODULE_DIR))
    return gui
