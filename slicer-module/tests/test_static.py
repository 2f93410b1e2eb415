"""Checks that need neither Slicer nor a server: the module's files are well formed and agree
with each other (Python compiles, the .ui is Qt Designer XML holding every widget the Widget
uses, the parameter node's fields are bound in the .ui, icons are present, dependencies are
imported lazily). The CMake lists, the catalog entry and the installed layout: test_packaging.py."""

import ast
import py_compile
import re
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

EXT = Path(__file__).resolve().parent.parent
MODULE = EXT / "Resecta"
UI = MODULE / "Resources" / "UI" / "Resecta.ui"
LIB = MODULE / "ResectaLib"
PY_FILES = sorted(p for p in EXT.rglob("*.py") if "__pycache__" not in p.parts)


@pytest.mark.parametrize("path", PY_FILES, ids=lambda p: str(p.relative_to(EXT)))
def test_python_compiles(path, tmp_path):
    ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    py_compile.compile(str(path), cfile=str(tmp_path / "out.pyc"), doraise=True)


def _ui_widgets():
    root = ET.parse(UI).getroot()
    assert root.tag == "ui" and root.get("version") == "4.0"
    widgets = {w.get("name"): w for w in root.iter("widget")}
    return root, widgets


def _module_ast():
    return ast.parse((MODULE / "Resecta.py").read_text(encoding="utf-8"))


def test_ui_is_designer_xml_with_custom_widgets_declared():
    root, widgets = _ui_widgets()
    assert root.find("class").text == "Resecta"
    top = root.find("widget")
    assert top.get("class") == "qMRMLWidget" and top.get("name") == "Resecta"
    declared = {c.find("class").text for c in root.iter("customwidget")}
    used = {w.get("class") for w in widgets.values()}
    qt = {c for c in used if c.startswith("Q")}
    assert used - qt <= declared, f"custom widgets not declared: {used - qt - declared}"
    names = [w.get("name") for w in root.iter("widget")] + [w.get("name") for w in root.iter("layout")]
    assert len(names) == len(set(names)), "duplicate widget or layout names"


def test_every_widget_the_module_uses_is_in_the_ui():
    _root, widgets = _ui_widgets()
    text = (MODULE / "Resecta.py").read_text(encoding="utf-8")
    used = set(re.findall(r"self\.ui\.([A-Za-z_][A-Za-z0-9_]*)", text))
    assert used, "the Widget uses no UI element?"
    missing = sorted(used - set(widgets))
    assert not missing, f"Resecta.py uses widgets missing from Resecta.ui: {missing}"


def test_parameter_node_fields_are_bound_in_the_ui():
    _root, widgets = _ui_widgets()
    bound = {}
    for name, w in widgets.items():
        for p in w.findall("property"):
            if p.get("name") == "SlicerParameterName":
                bound[p.find("string").text] = name
    cls = next(n for n in _module_ast().body
               if isinstance(n, ast.ClassDef) and n.name == "ResectaParameterNode")
    fields = {s.target.id for s in cls.body if isinstance(s, ast.AnnAssign)}
    assert set(bound) <= fields, f"the .ui binds unknown parameters {set(bound) - fields}"
    assert "sessionId" not in bound
    assert not any("token" in f.lower() for f in fields), "the token must not be in the scene"


def test_module_follows_the_scripted_module_template():
    tree = _module_ast()
    classes = {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}
    bases = {name: [ast.unparse(b) for b in c.bases] for name, c in classes.items()}
    assert bases["Resecta"] == ["ScriptedLoadableModule"]
    assert "ScriptedLoadableModuleWidget" in bases["ResectaWidget"]
    assert bases["ResectaLogic"][0] == "ScriptedLoadableModuleLogic"
    assert bases["ResectaTest"] == ["ScriptedLoadableModuleTest"]
    decorators = [ast.unparse(d) for d in classes["ResectaParameterNode"].decorator_list]
    assert decorators == ["parameterNodeWrapper"]
    methods = {n.name for n in classes["ResectaTest"].body if isinstance(n, ast.FunctionDef)}
    assert {"setUp", "runTest"} <= methods
    widget_src = ast.unparse(classes["ResectaWidget"])
    assert 'loadUI(self.resourcePath("UI/Resecta.ui"))' in widget_src.replace("'", '"')
    assert "pip_install" not in widget_src, "installing belongs in ResectaLib.deps"
    logic_src = ast.unparse(classes["ResectaLogic"])
    for gui in ("QMessageBox", "confirmOkCancelDisplay", "errorDisplay", "QFileDialog"):
        assert gui not in logic_src, f"the Logic opens a dialog ({gui})"


def _module_level_imports(path: Path) -> set[str]:
    out = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("path", [MODULE / "Resecta.py", *sorted(LIB.glob("*.py"))],
                         ids=lambda p: p.name)
def test_dependencies_are_not_imported_at_module_import(path):
    lazy = {"grpc", "google", "resecta_client", "zstandard"}
    found = _module_level_imports(path) & lazy
    assert not found, f"{path.name} imports {found} at import time (installed on first use)"


@pytest.mark.parametrize("path", sorted(LIB.glob("*.py")), ids=lambda p: p.name)
def test_lib_has_no_qt_nor_slicer_gui(path):
    text = path.read_text(encoding="utf-8")
    tree = ast.parse(text)
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    assert not names & {"qt", "ctk", "PythonQt", "slicer.util", "slicer.ScriptedLoadableModule"}
    if path.name != "deps.py":  # deps calls slicer.util.pip_install, inside Slicer only
        assert "slicer.util" not in text and "slicer.app" not in text


@pytest.mark.parametrize("path", [EXT / "Resecta.png", MODULE / "Resources" / "Icons" / "Resecta.png"],
                         ids=lambda p: str(p.relative_to(EXT)))
def test_icons_are_128px_png(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (128, 128)


def test_readme_pictures_exist():
    text = (EXT / "README.md").read_text(encoding="utf-8")
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert len(pictures) >= 2
    for p in pictures:
        assert (EXT / p).is_file(), f"README shows {p}, which is missing"


def _attribute_uses(cls: ast.ClassDef, owner: str) -> set[str]:
    """Names `x` of every `self.<owner>.x` in the class."""
    out = set()
    for node in ast.walk(cls):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute)
                and node.value.attr == owner and isinstance(node.value.value, ast.Name)
                and node.value.value.id == "self"):
            out.add(node.attr)
    return out


def _instance_attributes(cls) -> set[str]:
    """Members of `cls` and the attributes its `__init__` sets on `self`."""
    import inspect

    tree = ast.parse(inspect.getsource(cls.__init__).strip().replace("\n    ", "\n"))
    assigned = {t.attr for node in ast.walk(tree) if isinstance(node, (ast.Assign, ast.AnnAssign))
                for t in getattr(node, "targets", [getattr(node, "target", None)])
                if isinstance(t, ast.Attribute)}
    return set(dir(cls)) | assigned


def test_widget_calls_only_what_the_logic_has():
    """The Widget's `self.logic.x` and `self.logic.edits.y` exist (the Logic is ResectaLib's
    PlanningLogic plus the methods ResectaLogic adds)."""
    import sys

    sys.path.insert(0, str(MODULE))
    from ResectaLib.edits import EditCommands
    from ResectaLib.logic import PlanningLogic

    classes = {n.name: n for n in _module_ast().body if isinstance(n, ast.ClassDef)}
    logic = classes["ResectaLogic"]
    assert [ast.unparse(b) for b in logic.bases] == ["ScriptedLoadableModuleLogic", "PlanningLogic"]
    members = {n.name for n in logic.body if isinstance(n, ast.FunctionDef)}
    members |= _instance_attributes(PlanningLogic)
    widget = classes["ResectaWidget"]
    missing = _attribute_uses(widget, "logic") - members
    assert not missing, f"the Widget calls Logic members that do not exist: {sorted(missing)}"
    edit_uses = {node.attr for node in ast.walk(widget)
                 if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute)
                 and node.value.attr == "edits"}
    assert edit_uses, "the Widget sends no edit through the Logic?"
    missing = edit_uses - _instance_attributes(EditCommands)
    assert not missing, f"the Widget calls edit commands that do not exist: {sorted(missing)}"


@pytest.mark.parametrize("path", [MODULE / "Resecta.py", *sorted(LIB.glob("*.py"))],
                         ids=lambda p: p.name)
def test_module_parses_on_the_python_of_old_slicers(path):
    """Slicer 5.4–5.8 (Python 3.9) must load the module far enough to say it is not supported."""
    ast.parse(path.read_text(encoding="utf-8"), filename=str(path), feature_version=(3, 9))
