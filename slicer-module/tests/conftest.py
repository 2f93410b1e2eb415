"""Fixtures of the Slicer-module suite: real MRML from PyPI's `slicer-core`, a real `resecta serve`.

The end-to-end helpers of the repository's `tests/` are reused, not copied: `server_harness`
(`Server` on free ports, the `phantom` fixture made by `resecta phantom`) and `conftest`
(`resecta_bin`, the `resecta` CLI fixture). `ResectaLib` is imported from `slicer-module/Resecta`
and `resecta_client` from `clients/python/src` unless it is installed.
"""

import importlib.util
import json
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
MODULE_DIR = HERE.parent / "Resecta"
REPO = HERE.parent.parent
E2E = REPO / "tests"

sys.path.insert(0, str(MODULE_DIR))
sys.path.insert(0, str(E2E))
if importlib.util.find_spec("resecta_client") is None:
    sys.path.insert(0, str(REPO / "clients" / "python" / "src"))

_spec = importlib.util.spec_from_file_location("resecta_e2e_conftest", E2E / "conftest.py")
_e2e = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_e2e)
# server_harness does `from conftest import ROOT, resecta_bin`: whichever conftest module is
# current, these two are the repository's.
ROOT = _e2e.ROOT
resecta_bin = _e2e.resecta_bin
resecta = _e2e.resecta

from server_harness import Server, phantom  # noqa: E402,F401  (fixture re-exported)


@pytest.fixture
def scene():
    import slicer

    return slicer.vtkMRMLScene()


@pytest.fixture(scope="module")
def planning_server(tmp_path_factory):
    """One in-memory `resecta serve` for a test module."""
    s = Server()
    yield s
    s.stop()


@pytest.fixture(scope="module")
def phantom_truth(phantom):
    from ResectaLib import phantom as ph

    return ph.truth_from_phantom_json(json.loads((phantom.parent / "truth.json").read_text()))


#: The roles of the demo phantom (`resecta phantom` without a preset: liver, tumours, a portal
#: and a hepatic vessel on an oblique 0.8×0.8×2.5 mm grid).
DEMO_ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3], "hepatic": [4]}


@pytest.fixture(scope="session")
def demo_phantom(tmp_path_factory):
    import subprocess

    out = tmp_path_factory.mktemp("demo")
    subprocess.run([resecta_bin(), "phantom", "--out", str(out), "--json"], check=True,
                   capture_output=True)
    return out / "phantom.nii.gz"


@pytest.fixture
def dispatcher():
    from ResectaLib.dispatch import ThreadDispatcher

    d = ThreadDispatcher()
    yield d
    d.shutdown()


def load_phantom_segmentation(scene, path):
    """A segmentation node from a label-map file, as a user gets it in Slicer: the volume read
    by Slicer's own reader (ITK), then imported into a segmentation (one segment per label)."""
    import slicer

    labelmap = scene.AddNewNodeByClass("vtkMRMLLabelMapVolumeNode", "phantom")
    storage = slicer.vtkMRMLVolumeArchetypeStorageNode()
    scene.AddNode(storage)
    storage.SetFileName(str(path))
    assert storage.ReadData(labelmap), f"could not read {path}"
    seg = scene.AddNewNodeByClass("vtkMRMLSegmentationNode", "phantom segmentation")
    assert slicer.vtkSlicerSegmentationsModuleLogic.ImportLabelmapToSegmentationNode(labelmap, seg)
    return labelmap, seg
