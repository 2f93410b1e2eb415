"""Resecta.py itself outside Slicer: its Logic and its self-test run on real MRML (slicer-core)
against a real server, with `fake_gui`'s stand-ins for what only the Slicer application has (Qt,
the ScriptedLoadableModule base classes, the parameter-node wrapper, `slicer.app`). The Widget's
lifecycle is `test_widget.py`'s."""

import importlib
import sys
import types

import numpy as np
import pytest

import fake_gui
from conftest import load_phantom_segmentation, resecta_bin


@pytest.fixture
def Resecta(scene, monkeypatch):
    gui = fake_gui.install(monkeypatch, scene)
    sys.modules.pop("Resecta", None)
    module = importlib.import_module("Resecta")
    module._markups = gui.markups
    module._gui = gui
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
    assert not logic.connected and not logic.models_ready

    def wait(predicate, timeout=60):
        return logic.dispatcher.wait_until(predicate, timeout)

    try:
        assert logic.session_id is None
        infos = []
        logic.connect(planning_server.grpc_addr, on_done=infos.append)
        wait(lambda: infos)
        assert logic.connected and infos[0].api_version == "resecta.v1"
        _lm, seg = load_phantom_segmentation(scene, phantom)
        rows = logic.role_table(seg)
        assert [r[2] for r in rows] == ["ignore"] * 3  # "Label_1"...: nothing to guess from
        roles = {sid: role for (sid, _n, _g), role in zip(rows, ["parenchyma", "tumor", "portal"])}
        assert [r[2] for r in logic.role_table(seg, keep=roles)] == ["parenchyma", "tumor", "portal"]
        built, seen = [], []
        logic.set_callbacks(model_built=seen.append)
        logic.upload_and_build(seg, roles, "psr", on_done=built.append)
        wait(lambda: built and logic.models_ready and logic.tumours(), 120)
        assert logic.session_id
        assert sorted(i.name for i in seen) == sorted(i.name for i in built[0])
        tumour = logic.tumours()[0]
        end = logic.tumour_centroid(tumour) + [-40.0, 0, 0]
        logic.preview(tumour, end)
        logic.new_resection("r1", tumour, end, margin_mm=8.0, band_mm=3.0)
        wait(lambda: logic.resection_names() == ["r1"] and logic.resection("r1").margin_mm == 8.0
             and logic.resection("r1").band_mm == 3.0)
        with pytest.raises(ValueError, match="exists already"):
            logic.new_resection("r1", tumour, end)
        logic.edits.set_margin_and_band("r1", 9.0, 3.0)
        wait(lambda: logic.resection("r1").margin_mm == 9.0)
        cp = logic.resection("r1").control_points.copy()
        logic.edits.move_group("r1", "outer", (0, 0, 1.0))
        wait(lambda: not np.allclose(logic.resection("r1").control_points, cp)
             and not np.allclose(logic.edits.last["r1"].resection.control_points, cp))
        edits = logic.edits.acknowledged
        logic.edits.translate("r1", (1.0, 0, 0))
        logic.edits.rotate("r1", "normal", 3.0)
        wait(lambda: logic.edits.acknowledged == edits + 2)
        rotated = logic.edits.last["r1"].resection.control_points.copy()
        logic.edits.undo()
        logic.edits.redo()
        wait(lambda: logic.edits.acknowledged == edits + 4 and not logic.errors)
        wait(lambda: np.allclose(logic.resection("r1").control_points, rotated))
        logic.jump_to_worst_point()
        assert len(Resecta._markups.jumps) == 1
        assert np.allclose(Resecta._markups.jumps[0], logic.margin_state.point)
        logic.save_plan(tmp_path / "plan.json")
        wait(lambda: (tmp_path / "plan.json").is_file())
        logic.export_resections(tmp_path, "stl")
        wait(lambda: (tmp_path / "r1.stl").is_file())
        logic.edits.delete("r1")
        wait(lambda: logic.resection_names() == [])
        logic.load_plan(tmp_path / "plan.json")
        wait(lambda: logic.resection_names() == ["r1"])
        logic.set_opacity(("parenchyma",), 0.5)
        assert not logic.errors
    finally:
        logic.close()
    assert not logic.connected


def test_self_test_starts_its_own_server(Resecta, monkeypatch):
    """`ResectaTest.runTest()` exactly as Slicer runs it: it starts `resecta serve` itself."""
    monkeypatch.setenv("RESECTA_BIN", resecta_bin())
    test = Resecta.ResectaTest()
    test.runTest()
    assert test.messages[-1].startswith("Resecta scenario passed"), test.messages


def test_self_test_without_a_server_program_skips(Resecta, monkeypatch):
    """On a dashboard without `resecta`: a visible skip, never a false failure."""
    monkeypatch.delenv("RESECTA_BIN", raising=False)
    monkeypatch.setenv("PATH", "/nonexistent")
    test = Resecta.ResectaTest()
    test.runTest()
    assert test.messages[-1].startswith("Resecta self-test skipped: no resecta server program")


def test_old_slicer_is_refused_with_a_clear_message(Resecta, scene):
    Resecta._gui.slicer_version = "5.8.1"
    import slicer

    slicer.app.applicationVersion = "5.8.1"
    w = Resecta.ResectaWidget(types.SimpleNamespace(isEntered=False))
    w.setup()
    try:
        assert "5.10 or newer" in w.ui.connectionStatusLabel.text
        assert not w.ui.connectButton.enabled
    finally:
        w.cleanup()
