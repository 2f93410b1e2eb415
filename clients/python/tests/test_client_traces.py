"""DS (drawn on slices) and CP (deformable cutting plane) resections through the client against
the real server: creation, trace and deformation edits, undo/redo, the typed errors of bad
input, and the volumes' Sec. 7.4 metrics (in replies and in the watch)."""

from __future__ import annotations

import numpy as np
import pytest

import resecta_client as rc

# The small phantom: ellipsoid liver (radii 40, 30, 25 mm) at the origin, tumour (r 8 mm) at
# (10, 5, 0). The cuts lie on the plane x = X, 12 mm from the tumour.
X = -10.0


def axial(z: float, x: float = X) -> np.ndarray:
    """A straight trace across the liver on the axial slice z, through (x, 0, z), tilted 1 mm
    in 50 (a trace of constant x would lie on a sagittal slice too)."""
    return np.array([(x + 0.02 * y, y, z) for y in np.linspace(-50.0, 50.0, 5)])


def ring(x: float = X, points: int = 40) -> np.ndarray:
    """A ring in the plane x = `x` around the liver's section."""
    t = np.linspace(0.0, 2.0 * np.pi, points, endpoint=False)
    return np.stack([np.full_like(t, x), 30.0 * np.cos(t), 22.0 * np.sin(t)], axis=1)


def test_ds_create_edit_undo_redo(ready: rc.Session) -> None:
    s = ready
    traces = [axial(z) for z in (-30.0, -10.0, 10.0, 30.0)]
    r = s.add_ds("d", traces, margin_mm=10.0, band_mm=4.0)
    d = r["d"].resection
    assert d.kind is rc.ResectionKind.DS and d.grid == (0, 0) and d.control_points.shape == (0, 0, 3)
    assert len(d.traces) == 4 and all(np.allclose(a, b) for a, b in zip(d.traces, traces))
    assert (d.margin_mm, d.band_mm, d.resolution, d.deformations) == (10.0, 4.0, (40, 40), ())
    # The plane keeps about 12 mm from the tumour (measured to its voxels).
    assert r["d"].verdict.min_margin_mm == pytest.approx(12.0, abs=1.5) and not r["d"].verdict.violation

    v = s.volumes()
    (vol,) = v.resections
    assert vol.complete_cut and vol.metrics is not None
    assert vol.metrics.margin_deviation_mm == pytest.approx(r["d"].verdict.min_margin_mm - 10.0)
    assert vol.metrics.median_abs_mean_curvature_per_mm == pytest.approx(0.0, abs=1e-9)  # a plane
    assert vol.metrics.volume_deviation_pct is None  # a session has no reference plan

    # Redraw a trace 3 mm nearer the tumour, add one, remove one; undo and redo each.
    bent = axial(10.0, X + 3.0)
    r = s.set_trace("d", 2, bent)
    assert np.allclose(r["d"].resection.traces[2], bent)
    assert r["d"].verdict.min_margin_mm < 12.0
    r = s.add_trace("d", axial(0.0))
    assert len(r["d"].resection.traces) == 5
    r = s.remove_trace("d", 0)
    assert len(r["d"].resection.traces) == 4 and np.allclose(r["d"].resection.traces[0], traces[1])
    assert len(s.undo()["d"].resection.traces) == 5
    assert len(s.undo()["d"].resection.traces) == 4
    back = s.undo()["d"].resection
    assert np.allclose(back.traces[2], traces[2])
    assert np.allclose(s.redo()["d"].resection.traces[2], bent)

    # The surface spans the first to the last trace's slice: cut short of the liver's top, the
    # cut is incomplete.
    s.add_ds("short", [axial(z) for z in (-10.0, 0.0, 10.0)])
    short = next(x for x in s.volumes().resections if x.name == "short")
    assert not short.complete_cut and "inside the liver" in short.incomplete_reason


def test_cp_create_deform_undo_redo(ready: rc.Session) -> None:
    s = ready
    r = s.add_cp("c", [ring()])
    c = r["c"].resection
    assert c.kind is rc.ResectionKind.CP and len(c.traces) == 1 and c.deformations == ()
    flat = r["c"].verdict.min_margin_mm
    assert flat == pytest.approx(12.0, abs=1.5)

    # +5 mm along the plane normal near the tumour: the surface moves away or towards it,
    # and undo_deformation takes exactly that back.
    bump = rc.Deformation((X, 5.0, 0.0), 5.0, 20.0)
    r = s.add_deformation("c", bump.point, bump.offset_mm, bump.radius_mm)
    assert r["c"].resection.deformations == (bump,)
    bumped = r["c"].verdict.min_margin_mm
    assert abs(bumped - flat) > 1.0
    r = s.undo_deformation("c")
    assert r["c"].resection.deformations == () and r["c"].verdict.min_margin_mm == pytest.approx(flat)
    assert s.undo()["c"].resection.deformations == (bump,)  # undo of the undo_deformation
    assert s.redo()["c"].resection.deformations == ()

    # A second stroke (a trace) redraws the plane; created with deformations at once.
    r = s.set_trace("c", 0, ring(X - 2.0))
    assert r["c"].verdict.min_margin_mm == pytest.approx(flat + 2.0, abs=1.0)
    r = s.add_cp("c2", [ring()[:20], ring()[20:]], [bump])
    assert len(r["c2"].resection.traces) == 2 and r["c2"].resection.deformations == (bump,)
    assert r["c2"].verdict.min_margin_mm == pytest.approx(bumped, abs=0.5)

    metrics = {x.name: x.metrics for x in s.volumes().resections}
    assert set(metrics) == {"c", "c2"}
    assert metrics["c2"].median_abs_mean_curvature_per_mm is not None
    assert metrics["c2"].margin_deviation_mm == pytest.approx(bumped - 10.0)

    # add_resection round-trips what an answer holds, of any kind.
    copy = rc.Resection(**{**vars(r["c2"].resection), "name": "c3"})
    assert s.add_resection(copy)["c3"].resection.deformations == (bump,)


def test_bad_traces_are_typed_errors(ready: rc.Session) -> None:
    s = ready
    with pytest.raises(rc.InvalidArgument) as e:
        s.add_ds("d", [axial(0.0), axial(10.0)])  # 2 traces
    assert e.value.code == "INVALID_ARGUMENT" and "3" in e.value.message
    coronal = np.array([(x, 0.0, z) for x, z in ((-30.0, 0.0), (0.0, 1.0), (30.0, 2.0))])
    with pytest.raises(rc.InvalidArgument) as e:
        s.add_ds("d", [axial(-10.0), axial(0.0), coronal])  # mixed orientations
    assert "orientation" in e.value.message
    with pytest.raises(rc.InvalidArgument):
        s.add_ds("d", [axial(-10.0), axial(0.0), axial(0.0, X + 5.0)])  # two on one slice
    with pytest.raises(ValueError):
        s.add_ds("d", [[(0.0, 0.0)]])  # not (n, 3): refused before sending
    with pytest.raises(rc.InvalidArgument):
        s.add_cp("c", [[(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0)]])  # collinear

    s.add_ds("d", [axial(z) for z in (-30.0, 0.0, 30.0)])
    with pytest.raises(rc.InvalidArgument) as e:
        s.remove_trace("d", 0)  # a DS keeps 3
    with pytest.raises(rc.InvalidArgument) as e:
        s.add_deformation("d", (X, 0.0, 0.0), 2.0, 10.0)  # DS has no deformations
    assert "DS" in e.value.message
    s.add_cp("c", [ring()])
    with pytest.raises(rc.InvalidArgument):
        s.add_deformation("c", (X, 0.0, 0.0), 2.0, 0.0)  # radius must be > 0
    with pytest.raises(rc.InvalidArgument):
        s.set_trace("c", 4, ring())
    with pytest.raises(rc.InvalidArgument):
        s.set_control_point("c", 0, 0, (0.0, 0.0, 0.0))  # a CP has no control grid
    with pytest.raises(rc.NotFound):
        s.add_trace("nope", ring())


def test_watch_carries_kinds_and_metrics(ready: rc.Session) -> None:
    s = ready
    s.add_ds("d", [axial(z) for z in (-30.0, 0.0, 30.0)])
    with s.watch() as w:
        for update in w:
            if w.scene.volumes is not None and w.scene.volumes.resections:
                break
        d = w.scene.surfaces["d"]
        assert d.is_resection and d.resection.kind is rc.ResectionKind.DS
        assert len(d.resection.traces) == 3 and d.positions.shape == (40 * 40, 3)
        s.add_cp("c", [ring()])
        for update in w:
            if "c" in update.changed:
                break
        c = w.scene.surfaces["c"]
        assert c.resection.kind is rc.ResectionKind.CP
        before, normal = c.positions.astype(float), c.normals.mean(axis=0)
        # A positive offset moves the surface against its vertex normals (README).
        s.add_deformation("c", (X, 5.0, 0.0), 4.0, 10.0)
        for update in w:
            if "c" in update.changed:
                break
        moved = w.scene.surfaces["c"].positions - before
        k = int(np.argmax(np.linalg.norm(moved, axis=1)))
        assert np.allclose(moved[k], -4.0 * normal / np.linalg.norm(normal), atol=1e-3)
        for update in w:
            if update.volumes_changed and update.plan_version == s.plan_version:
                break
        assert all(r.metrics.margin_deviation_mm is not None for r in w.scene.volumes.resections)
