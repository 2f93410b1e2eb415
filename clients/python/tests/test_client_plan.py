"""Resection edits with base versions, undo/redo, stale versions, volumes, plans, exports and
slices and label slices, against the real server."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import resecta_client as rc

from .conftest import ROLES, read_ply

END = (-30.0, 0.0, 0.0)


def test_every_edit_and_undo_redo(ready: rc.Session) -> None:
    s = ready
    v0 = s.plan_version
    r = s.init_from_end_point("r1", END)
    assert r.plan_version == v0 + 1 == s.plan_version
    res = r["r1"].resection
    assert res.grid == (4, 4) and res.control_points.shape == (4, 4, 3) and res.margin_mm > 0
    assert r["r1"].verdict.min_margin_mm is not None and r["r1"].verdict.inside_area_mm2 > 0
    cps = res.control_points.copy()

    moved = s.set_control_point("r1", 1, 2, cps[1, 2] + [2.0, 3.0, 0.0])["r1"].resection.control_points
    assert np.allclose(moved[1, 2], cps[1, 2] + [2, 3, 0]) and np.allclose(
        np.delete(moved.reshape(-1, 3), 6, 0), np.delete(cps.reshape(-1, 3), 6, 0)
    )
    assert np.allclose(s.set_control_points("r1", cps)["r1"].resection.control_points, cps)
    inner = s.move_group("r1", (1.0, 0.0, 0.0), group="inner")["r1"].resection.control_points
    assert np.allclose(inner[1:3, 1:3], cps[1:3, 1:3] + [1, 0, 0]) and np.allclose(inner[0], cps[0])
    ring = s.move_group("r1", (0.0, 1.0, 0.0), ring=0)["r1"].resection.control_points
    assert np.allclose(ring[0], inner[0] + [0, 1, 0]) and np.allclose(ring[1:3, 1:3], inner[1:3, 1:3])
    with pytest.raises(ValueError):
        s.move_group("r1", (0, 0, 0))
    shifted = s.translate("r1", (0.0, 0.0, 2.0))["r1"].resection.control_points
    assert np.allclose(shifted, ring + [0, 0, 2])
    centre = shifted.reshape(-1, 3).mean(0)
    turned = s.rotate("r1", (0, 0, 1), 90.0, centre=centre)["r1"].resection.control_points
    rel = shifted - centre
    assert np.allclose(turned - centre, np.stack([-rel[..., 1], rel[..., 0], rel[..., 2]], -1), atol=1e-9)
    s.rotate("r1", (0, 0, 1), -90.0)  # about the centroid by default
    r = s.set_margin("r1", 12.5)
    assert r["r1"].resection.margin_mm == 12.5
    assert s.set_band("r1", 3.0)["r1"].resection.band_mm == 3.0
    assert s.set_resolution("r1", 30, 20)["r1"].resection.resolution == (30, 20)
    assert s.set_target("r1", [2])["r1"].resection.target == rc.Target(labels=(2,))
    version = s.plan_version

    # Undo walks back one edit at a time, redo forward again.
    undone = s.undo()
    assert undone.plan_version == version + 1 and undone["r1"].resection.target == rc.Target()
    assert s.redo()["r1"].resection.target == rc.Target(labels=(2,))
    with pytest.raises(rc.FailedPrecondition) as e:
        s.redo()
    assert e.value.code == "NOTHING_TO_REDO"
    gone = s.delete_resection("r1")
    assert gone.removed == ("r1",) and gone.resections == ()
    assert s.undo()["r1"].resection.resolution == (30, 20)

    # Bad input is refused with the field named; unknown names are NotFound.
    with pytest.raises(rc.InvalidArgument) as e2:
        s.set_control_point("r1", 0, 0, (float("nan"), 0.0, 0.0))
    assert e2.value.code == "INVALID_ARGUMENT" and "point" in e2.value.field
    with pytest.raises(rc.NotFound) as e3:
        s.set_margin("nope", 5.0)
    assert e3.value.code == "RESECTION_NOT_FOUND" and not isinstance(e3.value, rc.SessionNotFound)


def test_stale_version(ready: rc.Session) -> None:
    s = ready
    other = s.client.session(s.id)  # a second handle: another client of the same session
    s.init_from_end_point("r1", END)
    with pytest.raises(rc.StaleVersion) as e:
        other.set_margin("r1", 8.0)
    assert e.value.current_version == s.plan_version and e.value.code == "STALE_VERSION"
    assert other.plan_version < s.plan_version  # the handle waits for its owner to re-read
    assert other.set_margin("r1", 8.0, base_version=0).plan_version == s.plan_version + 1  # no check
    with pytest.raises(rc.StaleVersion):
        s.set_margin("r1", 9.0)
    s.info()  # re-read
    assert s.set_margin("r1", 9.0).plan_version == other.plan_version + 1
    with pytest.raises(rc.StaleVersion):
        s.import_plan(s.export_plan(), base_version=1)


def test_volumes_plan_round_trip_export_and_slices(ready: rc.Session) -> None:
    s = ready
    s.init_from_end_point("r1", END)
    vol = s.volumes(timeout=120)
    assert vol.plan_version == s.plan_version and vol.complete
    assert vol.remnant_ml is not None and vol.resected_ml is not None
    assert vol.remnant_ml + vol.resected_ml == pytest.approx(vol.total_ml, rel=1e-6)
    (rv,) = vol.resections
    assert rv.name == "r1" and rv.complete_cut and rv.resected_ml == pytest.approx(vol.resected_ml)
    # With vessels (the portal label) the warning is on the functional remnant.
    pct = vol.risk.functional_remnant_pct if vol.risk else vol.remnant_pct
    assert vol.flr_warning == (pct < vol.flr_threshold_pct)

    text = s.export_plan()
    plan = json.loads(text)
    assert plan["format"] == "resecta-plan/1" and [r["name"] for r in plan["resections"]] == ["r1"]
    s.delete_resection("r1")
    assert json.loads(s.export_plan())["resections"] == []
    version = s.import_plan(text)
    assert version == s.plan_version and json.loads(s.export_plan()) == plan
    assert s.import_plan(plan) == version + 1  # a dict is fine too
    with pytest.raises(rc.InvalidArgument) as e:
        s.import_plan("{not json")
    assert e.value.code == "BAD_PLAN"

    ply = read_ply(s.export_model("r1", "ply", resection=True))
    assert len(ply["x"]) == 40 * 40 and "margin_mm" in ply
    assert s.export_model("parenchyma", rc.ModelFormat.VTP).startswith(b"<?xml")
    assert s.export_model("tumor_1", "stl")[80:84] != b""
    with pytest.raises(rc.NotFound) as e2:
        s.export_model("nope", "ply")
    assert e2.value.code == "MODEL_NOT_FOUND"

    z = float(np.mean(ply["z"]))
    sl = s.slices("r1", axial=z, sagittal=float(np.mean(ply["x"])), resection=True)
    assert sl.axial and sl.sagittal and not sl.coronal
    assert all(np.allclose(p.points[:, 2], z, atol=1e-3) for p in sl.axial)


def test_label_slice(client: rc.Client, phantom: Path) -> None:
    s = client.create_session("label-slice")
    with pytest.raises(rc.FailedPrecondition) as e:
        s.label_slice("axial", 0.0)
    assert e.value.code == "NO_LABEL_MAP"
    s.upload_label_map_file(phantom, ROLES)
    # The small phantom's tumour: a ball of 8 mm about (10, 5, 0).
    sl = s.label_slice("axial", 0.0, pixel_mm=0.5)
    assert sl.pixel_mm == 0.5 and sl.column_axis == (1, 0, 0) and sl.row_axis == (0, 1, 0)
    assert sl.min_position_mm < 0.0 < sl.max_position_mm
    rows, cols = np.nonzero(sl.labels == 2)
    area = rows.size * 0.25
    assert area == pytest.approx(np.pi * 8**2, rel=0.15)
    centre = sl.point(rows.mean(), cols.mean())
    assert np.allclose(centre, (10.0, 5.0, 0.0), atol=1.0)
    assert {1, 2} <= set(np.unique(sl.labels).tolist())
    sag = s.label_slice(rc.SliceAxis.SAGITTAL, 10.0)
    assert sag.column_axis == (0, 1, 0) and sag.row_axis == (0, 0, 1) and (sag.labels == 2).any()
    with pytest.raises(rc.InvalidArgument) as e:
        s.label_slice("coronal", sl.max_position_mm + 1.0)
    assert "position_mm" in str(e.value)
    with pytest.raises(rc.InvalidArgument):
        s.label_slice("axial", 0.0, pixel_mm=0.0)
