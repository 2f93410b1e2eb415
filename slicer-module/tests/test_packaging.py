"""The extension as the Slicer extensions index builds it and the Extension Manager installs it:
the CMake lists (one truth for what is installed), the catalog entry against Slicer's schema,
the checks the index runs on the repository, the stated Slicer range, and the installed file
layout imported without the repository around it."""

import json
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

from ResectaLib import deps

EXT = Path(__file__).resolve().parent.parent
REPO = EXT.parent
MODULE = EXT / "Resecta"
CLIENT_SRC = REPO / "clients" / "python" / "src"
ROOT_CMAKE = REPO / "CMakeLists.txt"
CATALOG = EXT / "Resecta.json"
sys.path.insert(0, str(EXT / "scripts"))
import install_layout  # noqa: E402

SETS = install_layout.cmake_sets(Resecta_SOURCE_DIR=str(REPO))


def _py_files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*.py") if "__pycache__" not in p.parts}


# --- the CMake lists ----------------------------------------------------------------------------

def test_cmake_lists_every_module_file_and_only_existing_ones():
    listed = set(SETS["MODULE_PYTHON_SCRIPTS"]) | set(SETS["MODULE_PYTHON_RESOURCES"])
    present = {"Resecta.py"} | {f"ResectaLib/{p}" for p in _py_files(MODULE / "ResectaLib")}
    present |= {str(p.relative_to(MODULE)) for p in (MODULE / "Resources").rglob("*") if p.is_file()}
    assert present - listed == set(), "add these to slicer-module/Resecta/CMakeLists.txt"
    assert listed - present == set(), "slicer-module/Resecta/CMakeLists.txt lists missing files"


def test_cmake_ships_every_python_file_of_the_client():
    assert Path(*SETS["RESECTA_CLIENT_SOURCE_DIR"]) == CLIENT_SRC
    assert set(SETS["RESECTA_CLIENT_FILES"]) == _py_files(CLIENT_SRC) - {
        p for p in _py_files(CLIENT_SRC) if not p.startswith("resecta_client/")}
    assert {"resecta_client/__init__.py", "resecta_client/_gen/planning_service_pb2_grpc.py"} <= set(
        SETS["RESECTA_CLIENT_FILES"])


def test_deps_imports_the_client_from_where_cmake_puts_it():
    (subdir,) = SETS["RESECTA_CLIENT_SUBDIR"]
    assert deps.BUNDLED_CLIENT == MODULE / subdir
    cmake = (MODULE / "CMakeLists.txt").read_text(encoding="utf-8")
    # The build tree and the install tree get the same place beside the module's scripts.
    assert "${CMAKE_BINARY_DIR}/${Slicer_QTSCRIPTEDMODULES_LIB_DIR}/${RESECTA_CLIENT_SUBDIR}/${file}" in cmake
    assert "DESTINATION ${Slicer_INSTALL_QTSCRIPTEDMODULES_LIB_DIR}/${RESECTA_CLIENT_SUBDIR}/${subdir}" in cmake
    assert "slicerMacroBuildScriptedModule" in cmake and "WITH_GENERIC_TESTS" in cmake


# --- what the extensions index reads ------------------------------------------------------------

# Slicer's catalog-entry schema v1.0.1 ($id https://raw.githubusercontent.com/Slicer/Slicer/main/
# Schemas/slicer-extension-catalog-entry-schema-v1.0.1.json#, draft-07), which the ExtensionsIndex
# validates each `<Extension>.json` against since Slicer 5.8. Its constraints are restated here
# rather than the file copied (Slicer's licence asks redistributed files to carry its notice).
SCHEMA_ID = ("https://raw.githubusercontent.com/Slicer/Slicer/main/Schemas/"
             "slicer-extension-catalog-entry-schema-v1.0.1.json#")
CATALOG_SCHEMA = {
    "$schema": "http://json-schema.org/draft-07/schema",
    "$id": SCHEMA_ID,
    "type": "object",
    "required": ["$schema", "category", "scm_url"],
    "additionalProperties": False,
    "properties": {
        "$schema": {"type": "string"},
        "category": {"type": "string"},
        "scm_url": {"type": "string"},
        "scm_revision": {"type": "string"},
        "scm_type": {"type": "string", "enum": ["git", "local"]},
        "build_dependencies": {"type": "array", "items": {"type": "string"}},
        "build_subdirectory": {"type": "string"},
        "enabled": {"type": "boolean"},
        "tier": {"type": "integer", "minimum": 1, "maximum": 5},
    },
}


def _catalog():
    return json.loads(CATALOG.read_text(encoding="utf-8"))


def test_catalog_entry_validates_against_the_schema():
    import jsonschema

    entry = _catalog()
    jsonschema.Draft7Validator.check_schema(CATALOG_SCHEMA)
    jsonschema.validate(entry, CATALOG_SCHEMA)
    assert entry["$schema"] == SCHEMA_ID
    for wrong in ({**entry, "description": "x"}, {**entry, "tier": 0},
                  {k: v for k, v in entry.items() if k != "scm_url"}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(wrong, CATALOG_SCHEMA)


def _root_set(key: str) -> str:
    m = re.search(rf'set\s*\({key}\s*"([^"]+)"[ ]*\)', ROOT_CMAKE.read_text(encoding="utf-8"))
    assert m, f"{key} is not set (quoted) in the root CMakeLists.txt"
    return m[1]


def test_the_index_finds_the_extension_at_the_repository_root():
    # The index clones scm_url and reads <root>/CMakeLists.txt: project() must be the entry's
    # name, icon and screenshot URLs quoted (its scripts/check_description_files.py). The
    # entry's build_subdirectory is the *build* tree's inner folder of superbuild extensions,
    # not a source folder: "." here.
    entry = _catalog()
    assert entry["build_subdirectory"] == "." and entry["build_dependencies"] == []
    cmake = ROOT_CMAKE.read_text(encoding="utf-8")
    assert re.findall(r"project\s*\(\s*([^\s\)\n\r]+)", cmake, re.IGNORECASE)[0] == CATALOG.stem
    assert _root_set("EXTENSION_CATEGORY") == entry["category"]
    for key in ("EXTENSION_ICONURL", "EXTENSION_SCREENSHOTURLS", "EXTENSION_HOMEPAGE"):
        assert all(url.startswith("https://") for url in _root_set(key).split())
    assert not (EXT / "Resecta.s4ext").exists() and not (EXT / "CMakeLists.txt").exists()
    (sub,) = re.findall(r"add_subdirectory\(([^)]+)\)", cmake)
    assert (REPO / sub / "CMakeLists.txt").is_file() and REPO / sub == MODULE


def test_icon_and_screenshot_urls_name_files_of_this_repository():
    for key in ("EXTENSION_ICONURL", "EXTENSION_SCREENSHOTURLS"):
        for url in _root_set(key).split():
            path = url.split("/main/", 1)[1]
            assert (REPO / path).is_file(), f"{key} names {path}, which is not in the repository"


# --- the supported range, stated once and checked everywhere ------------------------------------

def test_the_supported_slicer_is_the_same_everywhere():
    major, minor = deps.MIN_SLICER
    cmake = ROOT_CMAKE.read_text(encoding="utf-8")
    assert re.search(rf"find_package\(Slicer {major}\.{minor} REQUIRED\)", cmake)
    assert deps.SUPPORTED in _root_set("EXTENSION_DESCRIPTION").replace("Needs 3D", "3D")
    readme = (EXT / "README.md").read_text(encoding="utf-8")
    assert deps.SUPPORTED in readme
    stated = {tuple(map(int, v)) for v in re.findall(r"Slicer (\d+)\.(\d+) or newer", readme)}
    assert stated == {deps.MIN_SLICER}, f"the README states other minimum versions: {stated}"
    top = (REPO / "README.md").read_text(encoding="utf-8")
    assert f"**3D Slicer** ({major}.{minor} or newer)" in top


def test_python_minimum_and_lower_bounds_follow_the_client():
    project = tomllib.loads((REPO / "clients" / "python" / "pyproject.toml").read_text())["project"]
    assert project["requires-python"] == ">={}.{}".format(*deps.MIN_PYTHON)
    client_lower = {}
    for line in project["dependencies"]:
        name, spec = re.match(r"([A-Za-z0-9_.-]+)(.*)", line).groups()
        client_lower[name] = {v for op, v in re.findall(r"(>=)([^,]+)", spec)}
    for req in deps.requirements():
        assert {v for op, v in req.bounds if op == ">="} == client_lower[req.name], req


# --- the installed layout, without the repository -----------------------------------------------

def _run_in_layout(qt_modules: Path, code: str) -> subprocess.CompletedProcess:
    """`code` in a fresh interpreter whose sys.path is the venv's plus `qt_modules` only (-I: no
    PYTHONPATH, no current folder), started outside the repository."""
    prelude = f"import sys; sys.path.insert(0, {str(qt_modules)!r})\n"
    return subprocess.run([sys.executable, "-I", "-c", prelude + textwrap.dedent(code)],
                          cwd=qt_modules, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def layout(tmp_path_factory):
    return install_layout.install(tmp_path_factory.mktemp("Extensions-1") / "Resecta")


def test_the_layout_holds_exactly_what_cmake_lists(layout):
    files = {str(p.relative_to(layout)) for p in layout.rglob("*") if p.is_file()}
    assert files == {rel for _src, rel in install_layout.module_files()}
    assert layout.parts[-3:] == ("lib", "Slicer-5.10", "qt-scripted-modules")
    assert (layout / "Resources" / "Python" / "resecta_client" / "_gen" / "watch_pb2.py").is_file()


def test_resectalib_and_the_shipped_client_import_from_the_layout(layout):
    modules = sorted(Path(p).stem for p in SETS["MODULE_PYTHON_SCRIPTS"] if p.startswith("ResectaLib/"))
    proc = _run_in_layout(layout, f"""
        import importlib
        from pathlib import Path
        from ResectaLib import deps
        here = Path(sys.path[0])
        assert deps.client_path() == here / "Resources" / "Python", deps.client_path()
        assert deps.ensure_installed(lambda lines: False), "the venv has every package"
        import resecta_client, resecta_client._gen.planning_service_pb2_grpc
        from resecta_client import Client
        for name in {modules!r}:
            importlib.import_module("ResectaLib." + name)
        repo = {str(REPO)!r}
        loaded = {{n: m.__file__ for n, m in sys.modules.items() if getattr(m, "__file__", None)}}
        for n in ("resecta_client", "ResectaLib", "ResectaLib.deps"):
            assert loaded[n].startswith(str(here)), (n, loaded[n])
        stray = [f for f in loaded.values()
                 if f.startswith(repo + "/slicer-module") or f.startswith(repo + "/clients")]
        assert not stray, stray
        print("OK", resecta_client.__file__)
    """)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"OK {layout}")


def test_the_module_itself_imports_from_the_layout_with_the_fake_gui(layout):
    fake_gui = EXT / "tests" / "fake_gui.py"
    if not fake_gui.is_file():
        pytest.skip("tests/fake_gui.py (the fake Qt/CTK/slicer GUI) is not there yet")
    proc = _run_in_layout(layout, f"""
        import pytest, slicer
        sys.path.append({str(fake_gui.parent)!r})
        import fake_gui
        fake_gui.install(pytest.MonkeyPatch(), slicer.vtkMRMLScene())
        layout = {str(layout)!r}
        sys.path[:] = [layout] + [p for p in sys.path if p not in (layout, str(fake_gui.MODULE_DIR))]
        import Resecta
        Resecta.deps.use_client()
        import resecta_client
        for m in (Resecta, Resecta.deps, resecta_client):
            assert m.__file__.startswith(layout), m.__file__
        print("OK")
    """)
    assert proc.returncode == 0, proc.stderr
