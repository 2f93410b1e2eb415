"""Watch: a snapshot, then deltas applied into numpy arrays, equal to what the server exports;
resuming with since_seq; stopping from another thread; bad deltas; vtkPolyData."""

from __future__ import annotations

import struct
import threading
import time

import numpy as np
import pytest

import resecta_client as rc
from resecta_client import wire
from resecta_client._gen import planning_service_pb2 as pb
from resecta_client._gen import watch_pb2

from .conftest import Proxy, read_ply

END = (-30.0, 0.0, 0.0)


def until_version(w: rc.Watch, version: int, kind: str = "delta") -> list[rc.SceneUpdate]:
    seen = []
    for u in w:
        seen.append(u)
        if u.kind == kind and u.plan_version >= version:
            return seen
    raise AssertionError(f"the watch ended before plan version {version}: {seen}")


def assert_matches_export(session: rc.Session, surface: rc.SurfaceState, resection: bool) -> None:
    ply = read_ply(session.export_model(surface.name, "ply", resection=resection))
    positions = np.stack([ply["x"], ply["y"], ply["z"]], axis=1)
    assert np.array_equal(surface.positions, positions), surface.name  # exact f32: not quantised
    assert np.array_equal(surface.triangles, ply["triangles"])
    if "nx" in ply:
        assert np.allclose(surface.normals, np.stack([ply["nx"], ply["ny"], ply["nz"]], axis=1), atol=1e-6)
    if resection:
        assert np.allclose(surface.margins, ply["margin_mm"], rtol=1e-6, atol=1e-5)
        assert np.array_equal(surface.classes, ply["margin_class"].astype(np.uint8))


def test_snapshot_and_deltas_equal_the_export(ready: rc.Session) -> None:
    s = ready
    with s.watch() as w:
        first = next(w)
        assert first.kind == "snapshot" and first.changed == first.rebuilt == set(w.scene.surfaces)
        assert set(w.scene.models) == {"parenchyma", "tumor_1", "portal_1"} and not w.scene.resections
        assert w.scene.session is not None and w.scene.session.id == s.id
        assert w.scene.surfaces["tumor_1"].kind is rc.SurfaceKind.TUMOR
        assert_matches_export(s, w.scene.surfaces["parenchyma"], resection=False)

        init = s.init_from_end_point("r1", END)
        added = until_version(w, init.plan_version)[-1]
        assert added.changed == added.rebuilt == {"r1"}
        r1 = w.scene.surfaces["r1"]
        positions = r1.positions
        cps = init["r1"].resection.control_points
        s.set_control_point("r1", 1, 2, cps[1, 2] + [1.5, 2.0, 1.0])
        s.move_group("r1", (0.0, 0.0, 1.0), group="outer")
        last = s.set_margin("r1", 14.0)
        updates = until_version(w, last.plan_version)
        deltas = [u for u in updates if u.kind == "delta"]
        assert all(u.changed == {"r1"} and not u.rebuilt for u in deltas), deltas
        assert w.scene.surfaces["r1"] is r1 and r1.positions is positions  # rows updated in place
        assert r1.revision == 3 and r1.resection is not None and r1.resection.margin_mm == 14.0
        assert np.allclose(r1.resection.control_points, last["r1"].resection.control_points)
        assert r1.verdict == last["r1"].verdict
        assert (r1.classes == rc.MarginClass.VIOLATION).any() == last["r1"].verdict.violation
        assert_matches_export(s, r1, resection=True)
        assert s.plan_version == w.scene.plan_version == last.plan_version

        # Volumes follow the deltas they belong to.
        vols = next(u for u in w if u.kind == "volumes" and u.plan_version == last.plan_version)
        assert vols.volumes_changed and w.scene.volumes is not None
        assert w.scene.volumes.total_ml == pytest.approx(s.volumes().total_ml)

        gone = s.delete_resection("r1")
        assert until_version(w, gone.plan_version)[-1].removed == {"r1"} and "r1" not in w.scene.surfaces


def test_resume_with_since_seq_and_stop_from_another_thread(ready: rc.Session) -> None:
    s = ready
    v = s.init_from_end_point("r1", END).plan_version
    w = s.watch()
    assert next(w).kind == "snapshot"
    seen: list[rc.SceneUpdate] = []
    ended = threading.Event()

    def follow() -> None:
        for u in w:
            seen.append(u)
        ended.set()

    t = threading.Thread(target=follow)
    t.start()
    v = s.translate("r1", (0.0, 0.0, 1.0)).plan_version
    deadline = time.monotonic() + 30
    while not any(u.plan_version == v and u.kind == "delta" for u in seen):
        assert time.monotonic() < deadline, seen
        time.sleep(0.02)
    w.stop()  # from this thread, while the other one waits in next()
    assert ended.wait(5), "stop() did not end the iteration"
    t.join()
    w.stop()  # twice is fine
    scene, seq = w.scene, w.last_seq
    assert seq is not None

    # Edits while nobody watches, then a resume: deltas after seq, applied to the same scene.
    s.translate("r1", (0.0, 1.0, 0.0))
    v = s.set_band("r1", 2.0).plan_version
    with s.watch(since_seq=seq, scene=scene) as resumed:
        updates = until_version(resumed, v)
    assert updates[0].kind == "delta" and updates[0].seq > seq, updates[0]
    with s.watch() as fresh:
        next(fresh)
        ref = fresh.scene.surfaces["r1"]
    got = scene.surfaces["r1"]
    for a, b in (
        (got.positions, ref.positions),
        (got.normals, ref.normals),
        (got.margins, ref.margins),
        (got.classes, ref.classes),
    ):
        assert np.array_equal(a, b)
    assert got.resection is not None and got.resection.band_mm == 2.0


def rsms(positions: np.ndarray, triangles: np.ndarray) -> bytes:
    """A minimal uncompressed snapshot (positions only) in the wire format."""
    payload = triangles.astype("<u4").tobytes() + positions.astype("<f4").tobytes()
    return (
        struct.pack("<4sHHIII", b"RSMS", wire.VERSION, wire.POSITIONS, len(positions), len(triangles), len(payload))
        + payload
    )


def rsdl(n: int, changed: list[int], rows: np.ndarray) -> bytes:
    payload = np.asarray(changed, "<u4").tobytes() + rows.astype("<f4").tobytes()
    flags = wire.POSITIONS | wire.INDEX_LIST
    return struct.pack("<4sHHIII", b"RSDL", wire.VERSION, flags, n, len(changed), len(payload)) + payload


def test_scene_snapshot_parts_and_bad_deltas() -> None:
    tri = np.array([[0, 1, 2]])
    pts = np.eye(3, dtype=np.float32)
    part1 = watch_pb2.Snapshot(
        models=[rc.types.surface_pb2.Surface(name="a", kind=2, label=2, mesh=rsms(pts, tri))]
    )
    part2 = watch_pb2.Snapshot(
        resections=[watch_pb2.ResectionSurface(name="r", full_mesh=rsms(pts + 1, tri))], complete=True
    )
    scene = rc.LiveScene()
    assert scene.apply(pb.WatchResponse(seq=4, plan_version=2, snapshot=part1)) is None
    assert scene.surfaces == {}  # a snapshot takes effect with its last part
    u = scene.apply(pb.WatchResponse(seq=4, plan_version=2, snapshot=part2))
    assert u is not None and u.changed == {"a", "r"} and scene.seq == 4
    assert scene.models["a"].label == 2 and scene.resections["r"].positions[0].tolist() == [2, 1, 1]
    good = rsdl(3, [1], np.array([[9.0, 9.0, 9.0]]))
    for name, data in (("missing", good), ("r", rsdl(4, [1], np.zeros((1, 3)))), ("r", good[:-4])):
        msg = pb.WatchResponse(
            seq=5,
            plan_version=3,
            delta=watch_pb2.Delta(resections=[watch_pb2.ResectionSurface(name=name, mesh_delta=data)]),
        )
        with pytest.raises(wire.WireError):
            scene.apply(msg)
        assert scene.seq == 4 and scene.resections["r"].positions[1].tolist() == [1, 2, 1]
    msg = pb.WatchResponse(
        seq=5,
        plan_version=3,
        delta=watch_pb2.Delta(resections=[watch_pb2.ResectionSurface(name="r", mesh_delta=good)]),
    )
    assert scene.apply(msg).changed == {"r"} and scene.resections["r"].positions[1].tolist() == [9, 9, 9]


def test_vtk_polydata(ready: rc.Session) -> None:
    if not rc.vtk_available():
        print("SKIP: vtk is not installed (pip install 'resecta-client[vtk]'): no vtkPolyData test")
        pytest.skip("vtk is not installed")
    s = ready
    v = s.init_from_end_point("r1", END).plan_version
    with s.watch() as w:
        next(w)
        r1 = w.scene.surfaces["r1"]
        pd = rc.to_vtk_polydata(r1)
        assert (pd.GetNumberOfPoints(), pd.GetNumberOfPolys()) == (len(r1.positions), len(r1.triangles))
        data = pd.GetPointData()
        assert data.GetNormals() is not None and data.GetScalars().GetName() == "margin_mm"
        assert data.GetArray("margin_class").GetNumberOfTuples() == len(r1.positions)
        v = s.translate("r1", (0.0, 0.0, 3.0)).plan_version
        until_version(w, v)
        same = rc.to_vtk_polydata(r1, pd)
        assert same is pd and pd.GetPoint(0) == pytest.approx(tuple(r1.positions[0].tolist()))
        # Rows only (a delta that did not rebuild the surface): the same VTK arrays, new values.
        points, classes = pd.GetPoints().GetData(), data.GetArray("margin_class")
        v = s.translate("r1", (0.0, 0.0, -2.0)).plan_version
        update = until_version(w, v)[-1]
        assert "r1" in update.changed and "r1" not in update.rebuilt
        assert rc.to_vtk_polydata(r1, pd, rebuild=False) is pd
        assert pd.GetPoints().GetData() is points and data.GetArray("margin_class") is classes
        assert pd.GetPoint(0) == pytest.approx(tuple(r1.positions[0].tolist()))
        # A shape that does not fit is rebuilt even when asked for rows only.
        empty = rc.to_vtk_polydata(r1)
        empty.GetPointData().RemoveArray("margin_class")
        assert rc.to_vtk_polydata(r1, empty, rebuild=False).GetPointData().GetArray("margin_class")
        liver = w.scene.to_vtk_polydata("parenchyma")
        assert liver.GetPointData().GetScalars() is None and liver.GetNumberOfPolys() > 0


def test_compressed_and_quantised_payloads_decode_like_exact_ones(ready: rc.Session) -> None:
    # The server may send exact, uncompressed payloads anyway (today it does); the decoder's
    # handling of ZSTD / POSITIONS_U16 / NORMALS_OCT16 is checked on golden messages in
    # tests/test_mesh_wire.py.
    s = ready
    s.init_from_end_point("r1", END)
    v = s.set_control_point("r1", 2, 1, (-25.0, 4.0, 3.0)).plan_version
    scenes = []
    for zstd, quantised in ((False, False), (True, True)):
        with s.watch(allow_zstd=zstd, allow_quantized=quantised) as w:
            next(w)
            v2 = s.translate("r1", (0.5, 0.0, 0.0)).plan_version
            until_version(w, v2)
            scenes.append(w.scene)
        v = s.translate("r1", (-0.5, 0.0, 0.0)).plan_version
    exact, packed = (sc.surfaces["r1"] for sc in scenes)
    extent = float(np.ptp(exact.positions, axis=0).max())
    # Quantised positions are within half a step (extent / 65534) of the exact ones plus an ulp.
    assert np.abs(packed.positions - exact.positions).max() <= extent / 131068 + 1e-4
    assert np.array_equal(packed.triangles, exact.triangles) and np.array_equal(packed.classes, exact.classes)
    liver_exact, liver_packed = (sc.surfaces["parenchyma"].positions for sc in scenes)
    assert (
        np.abs(liver_packed - liver_exact).max() <= float(np.ptp(liver_exact, axis=0).max()) / 131068 + 1e-4
    )
    assert v > 0


def test_reconnects_after_a_dropped_connection(ready: rc.Session, server) -> None:  # type: ignore[no-untyped-def]
    proxy = Proxy(server.grpc_addr)
    try:
        with rc.Client(proxy.address, timeout=30) as c:
            s = c.session(ready.id)
            s.init_from_end_point("r1", END)
            with s.watch(reconnect=5) as w:
                assert next(w).kind == "snapshot"
                seq = w.last_seq
                proxy.drop()  # the stream breaks; edits go on meanwhile
                v = ready.translate("r1", (0.0, 0.0, 2.0), base_version=0).plan_version
                updates = until_version(w, v)
                assert w.reconnects >= 1
                assert updates[0].kind == "delta" and updates[0].seq > seq, "not resumed with since_seq"
                assert all(u.kind != "snapshot" for u in updates)
            with ready.watch() as fresh:
                next(fresh)
                assert np.array_equal(w.scene.surfaces["r1"].positions, fresh.scene.surfaces["r1"].positions)
    finally:
        proxy.close()


def test_an_unreadable_snapshot_raises_instead_of_reopening() -> None:
    """A snapshot the decoder cannot read (here: format version 1) ends the iteration with
    `WireError`; reopening would bring the same snapshot again, for ever."""
    bad = bytearray(rsms(np.zeros((3, 3), np.float32), np.array([[0, 1, 2]], np.uint32)))
    bad[4:6] = (1).to_bytes(2, "little")
    part = watch_pb2.Snapshot(complete=True)
    part.models.add(name="m", mesh=bytes(bad))
    opened = []

    class Call:
        def __init__(self) -> None:
            self.messages = iter([pb.WatchResponse(seq=1, plan_version=1, snapshot=part)])

        def __next__(self) -> pb.WatchResponse:
            return next(self.messages)

        def cancel(self) -> None:
            pass

    class Stub(rc.Watch):
        def _open(self) -> Call:
            opened.append(1)
            if len(opened) > 3:
                raise AssertionError("the watch reopened the stream after an unreadable snapshot")
            self._call = Call()
            return self._call

    session = rc.Session.__new__(rc.Session)
    w = Stub(session)
    with pytest.raises(wire.WireError, match="version 1"):
        next(w)
    assert len(opened) == 1
    with pytest.raises(StopIteration):
        next(w)
