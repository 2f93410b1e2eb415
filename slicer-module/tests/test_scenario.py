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

    from ResectaLib.session import PlanningSession

    _lm, seg = load_phantom_segmentation(scene, phantom)
    ids = [seg.GetSegmentation().GetNthSegmentID(i) for i in range(3)]
    roles = dict(zip(ids, ["parenchyma", "tumor", "portal"]))
    main = threading.get_ident()
    progress = []
    s = PlanningSession(scene, dispatcher)
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

    from ResectaLib.session import PlanningSession

    server = Server("--token", "correct-horse-battery-staple")
    try:
        s = PlanningSession(scene, dispatcher)
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
