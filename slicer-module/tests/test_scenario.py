"""The module's scenario (ResectaLib.selftest, also the Slicer self-test) against a real
`resecta serve`, on real MRML nodes from `slicer-core`."""

import json

import numpy as np
import pytest

from conftest import load_phantom_segmentation


def _engine_check(resecta, labelmap_file, tmp_path):
    """Compares the volumes the module shows with the engine's `resecta plan` on the same plan
    and the original label-map file (the server got the segmentation, cropped and re-numbered)."""
    seen = {}

    def check(plan_json, volumes):
        path = tmp_path / "plan.json"
        path.write_text(plan_json)
        report = resecta("plan", labelmap_file, path, "--json").json()
        assert report["total_ml"] == pytest.approx(volumes.total_ml, rel=1e-6, abs=1e-6)
        assert report["remnant_ml"] == pytest.approx(volumes.remnant_ml, rel=1e-6, abs=1e-6)
        resected = [r["resected_ml"] for r in report["resections"]]
        assert resected == pytest.approx([r.resected_ml for r in volumes.resections], rel=1e-6)
        seen.update(report)

    return check, seen


def test_scenario_on_the_resecta_phantom(scene, dispatcher, planning_server, phantom,
                                         phantom_truth, resecta, tmp_path):
    from ResectaLib import selftest

    _labelmap, seg = load_phantom_segmentation(scene, phantom)
    ids = [seg.GetSegmentation().GetNthSegmentID(i) for i in range(3)]
    roles = dict(zip(ids, ["parenchyma", "tumor", "portal"]))
    check, seen = _engine_check(resecta, phantom, tmp_path)
    log = []
    report = selftest.run(scene, seg, phantom_truth, dispatcher, dispatcher.wait_until,
                          address=planning_server.grpc_addr, role_table=roles,
                          engine_check=check, log=log.append)
    assert seen, "the engine check did not run"
    assert log[-1].startswith("done")
    print(report)


def test_scenario_on_the_self_test_phantom(scene, dispatcher, planning_server):
    """The scenario exactly as `ResectaTest.runTest` runs it in Slicer (numpy phantom, segment
    names guessed into roles, PSR models)."""
    from ResectaLib import phantom, segmentation, selftest

    labels, ijk_to_ras, names, truth = phantom.make()
    seg = segmentation.segmentation_from_labelmap_array(scene, labels, ijk_to_ras, names)
    guessed = sorted(segmentation.default_role_table(seg).values())
    assert guessed == ["parenchyma", "portal", "tumor"]
    report = selftest.run(scene, seg, truth, dispatcher, dispatcher.wait_until,
                          address=planning_server.grpc_addr, log=lambda _m: None)
    print(report)


def test_build_progress_and_cancel(scene, dispatcher, planning_server, phantom):
    """Progress reaches the callback on the main thread; cancelling a build reports Cancelled
    and keeps the session usable."""
    import threading

    from ResectaLib.logic import PlanningLogic

    _lm, seg = load_phantom_segmentation(scene, phantom)
    ids = [seg.GetSegmentation().GetNthSegmentID(i) for i in range(3)]
    roles = dict(zip(ids, ["parenchyma", "tumor", "portal"]))
    main = threading.get_ident()
    progress = []
    s = PlanningLogic(scene, dispatcher)
    s.set_callbacks(progress=lambda f, stage: progress.append((f, stage, threading.get_ident())))
    try:
        s.connect(planning_server.grpc_addr)
        dispatcher.wait_until(lambda: s.connected, 30)
        s.upload_and_build(seg, roles, method="psr", on_done=lambda _i: None)
        s.cancel_build()
        dispatcher.wait_until(lambda: not s.building, 120)
        from resecta_client import Cancelled
        if s.errors:  # the cancel arrived in time
            assert isinstance(s.errors[-1], Cancelled)
        s.errors.clear()
        done = []
        s.upload_and_build(seg, roles, method="psr", on_done=done.append)
        dispatcher.wait_until(lambda: done and s.models_ready, 120)
        assert not s.errors
        assert progress and all(t == main for _f, _s, t in progress)
        fractions = [f for f, _s, _t in progress]
        assert fractions[-1] == 1.0
    finally:
        s.close()


def test_wrong_token_is_reported(scene, dispatcher, tmp_path):
    from resecta_client import AuthError
    from conftest import Server

    from ResectaLib.logic import PlanningLogic

    server = Server("--token", "correct-horse-battery-staple")
    try:
        s = PlanningLogic(scene, dispatcher)
        errors = []
        s.set_callbacks(error=errors.append)
        s.connect(server.grpc_addr, "wrong")
        dispatcher.wait_until(lambda: errors, 30)
        assert isinstance(errors[0], AuthError) and not s.connected
        s.connect(server.grpc_addr, "correct-horse-battery-staple")
        dispatcher.wait_until(lambda: s.connected, 30)
        s.close()
    finally:
        server.stop()


def test_edits_from_another_client_reach_the_scene(scene, dispatcher, planning_server, phantom):
    """A second client (a script, another Slicer) edits the session the module watches: the
    resection, its model and its control-grid markups appear and follow; reopening the session
    in a new PlanningLogic finds the same model nodes again (updated, not duplicated)."""
    from resecta_client import Client

    from ResectaLib import controlgrid, models
    from ResectaLib.logic import PlanningLogic

    _lm, seg = load_phantom_segmentation(scene, phantom)
    ids = [seg.GetSegmentation().GetNthSegmentID(i) for i in range(3)]
    s = PlanningLogic(scene, dispatcher)
    try:
        s.connect(planning_server.grpc_addr)
        dispatcher.wait_until(lambda: s.connected, 30)
        built = []
        s.upload_and_build(seg, dict(zip(ids, ["parenchyma", "tumor", "portal"])), on_done=built.append)
        dispatcher.wait_until(lambda: built and s.models_ready, 120)
        with Client(planning_server.grpc_addr) as other:
            remote = other.session(s.session_id)
            remote.init_from_plane("scripted", (-12.0, 0.0, 0.0), (-1.0, 0.0, 0.0))
            dispatcher.wait_until(lambda: "scripted" in s.grids and s.model_node("scripted"), 30)
            grid = s.grids["scripted"]
            remote.translate("scripted", (0.0, 0.0, 3.0))
            want = remote.export_plan()
            cps = np.array(json.loads(want)["resections"][0]["control_points"])
            dispatcher.wait_until(
                lambda: np.allclose(controlgrid.grid_points(grid), cps, atol=1e-6), 30)
        assert not s.errors
    except BaseException:
        s.close()
        raise
    node_ids = sorted(n.GetID() for n in models.model_nodes(scene))
    markups = scene.GetNumberOfNodesByClass("vtkMRMLMarkupsFiducialNode")
    sid = s.session_id
    s.close()
    again = PlanningLogic(scene, dispatcher.__class__())
    try:
        again.connect(planning_server.grpc_addr)
        again.dispatcher.wait_until(lambda: again.connected, 30)
        opened = []
        again.open_session(sid, on_done=opened.append)
        again.dispatcher.wait_until(lambda: opened and again.applier is not None and again.applier.flushes > 0, 30)
        assert sorted(n.GetID() for n in models.model_nodes(scene)) == node_ids
        assert scene.GetNumberOfNodesByClass("vtkMRMLMarkupsFiducialNode") == markups
        assert again.grids["scripted"] is grid
        assert not again.errors
    finally:
        again.close()


def test_models_one_per_segment_and_left_out_fragments_are_reported(scene, dispatcher,
                                                                    planning_server):
    """A vessel segment in two pieces gives one model; a one-voxel fragment of it is left out
    and the status line says so."""
    from ResectaLib import phantom, segmentation
    from ResectaLib.logic import PlanningLogic

    labels, ijk_to_ras, names, _truth = phantom.make()
    vessel = np.argwhere(labels == 3)
    mid = int(np.median(vessel[:, 2]))
    cut = vessel[np.abs(vessel[:, 2] - mid) <= 1]
    labels[tuple(cut.T)] = 1  # the portal vessel (along i) cut in two: still one segment
    inner = np.argwhere(labels == 1)
    deep = next(v for v in inner[len(inner) // 2:]
                if (labels[tuple(slice(c - 1, c + 2) for c in v)] == 1).all())
    labels[tuple(deep)] = 3  # and a one-voxel fragment of it, alone inside the liver
    seg = segmentation.segmentation_from_labelmap_array(scene, labels, ijk_to_ras, names)
    s = PlanningLogic(scene, dispatcher)
    statuses = []
    s.set_callbacks(status=statuses.append)
    try:
        s.connect(planning_server.grpc_addr)
        dispatcher.wait_until(lambda: s.connected, 30)
        built = []
        # A voxel here is 2×2×3 = 12 mm³: above the server's default speck size (10 mm³).
        s.upload_and_build(seg, segmentation.default_role_table(seg), on_done=built.append,
                           min_component_mm3=20.0)
        dispatcher.wait_until(lambda: built and s.models_ready, 120)
        assert not s.errors
        assert sorted(info.name for info in built[0]) == ["parenchyma", "portal_1", "tumor_1"]
        assert "1 fragment(s) under" in statuses[-1], statuses[-1]
    finally:
        s.close()
