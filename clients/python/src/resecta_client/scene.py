"""The live state of a watched session: every surface as numpy arrays, the resections' parameters
and verdicts, and the volumes, kept up to date by applying the Watch stream's snapshots and
deltas (`LiveScene.apply`)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Literal

from . import wire
from ._gen import planning_service_pb2 as pb
from ._gen import surface_pb2, watch_pb2
from .types import F32, Resection, SessionInfo, SurfaceKind, Verdict, Volumes


@dataclass
class SurfaceState:
    """One surface as the client holds it. Arrays are float32 RAS mm (positions (n, 3), unit
    normals (n, 3)), uint32 triangles (m, 3); resections also have per-vertex `margins` (n,) in
    mm (distance to the nearest target tumour) and `classes` (n,) uint8 `MarginClass` codes
    (0 outside the liver, 1 safe, 2 warning, 3 violation), and their `resection` parameters and
    `verdict`. Deltas overwrite the rows of these arrays in place (the array objects stay the
    same until a new full mesh replaces them); `revision` counts the changes."""

    name: str
    kind: SurfaceKind
    label: int
    color: tuple[float, float, float, float] | None
    positions: F32
    normals: F32 | None
    triangles: wire.U32
    margins: F32 | None = None
    classes: wire.U8 | None = None
    resection: Resection | None = None
    verdict: Verdict | None = None
    revision: int = 0

    @property
    def is_resection(self) -> bool:
        return self.kind is SurfaceKind.RESECTION

    def _mesh(self) -> wire.Mesh:
        """A `wire.Mesh` view of this surface's arrays (the same objects)."""
        return wire.Mesh(
            version=wire.VERSION,
            flags=0,
            vertex_count=len(self.positions),
            triangle_count=len(self.triangles),
            payload_bytes=0,
            positions=self.positions,
            normals=self.normals,
            triangles=self.triangles,
            margin=self.margins,
            classes=self.classes,
        )

    def _set_mesh(self, m: wire.Mesh) -> None:
        self.positions, self.normals, self.triangles = m["positions"], m["normals"], m["triangles"]
        self.margins, self.classes = m["margin"], m["classes"]


@dataclass(frozen=True)
class SceneUpdate:
    """What one applied Watch event changed.

    `kind` is ``"snapshot"`` (everything was replaced), ``"delta"`` (a plan change) or
    ``"volumes"``. `changed` names the surfaces whose mesh, parameters or verdict changed (every
    surface after a snapshot); of those, `rebuilt` got a whole new mesh (new arrays, possibly new
    triangles: rebuild any polydata), the others had rows updated in place. `removed` names the
    surfaces that are gone. `volumes_changed` is true when `LiveScene.volumes` was replaced."""

    seq: int
    plan_version: int
    kind: Literal["snapshot", "delta", "volumes"]
    changed: frozenset[str] = frozenset()
    rebuilt: frozenset[str] = frozenset()
    removed: frozenset[str] = frozenset()
    volumes_changed: bool = False


def _color(m: surface_pb2.Surface) -> tuple[float, float, float, float] | None:
    c = m.color
    return (c.r, c.g, c.b, c.a) if m.HasField("color") else None


def _from_mesh(
    name: str, kind: SurfaceKind, label: int, color: tuple[float, float, float, float] | None, data: bytes
) -> SurfaceState:
    m = wire.decode_mesh(data)
    s = SurfaceState(name, kind, label, color, m["positions"], m["normals"], m["triangles"])
    s._set_mesh(m)
    return s


@dataclass
class LiveScene:
    """Every surface of a watched session by name (`surfaces`; `models` and `resections` split
    them), the session's metadata from the last snapshot, the volumes, and the `seq` and
    `plan_version` of the last applied event.

    `Watch` applies events from its own thread of iteration; hold `lock` while reading arrays
    from another thread (applying an event holds it too)."""

    surfaces: dict[str, SurfaceState] = field(default_factory=dict)
    session: SessionInfo | None = None
    volumes: Volumes | None = None
    seq: int | None = None
    plan_version: int = 0
    lock: threading.RLock = field(default_factory=threading.RLock, repr=False, compare=False)
    _parts: list[watch_pb2.Snapshot] = field(default_factory=list, repr=False, compare=False)
    _parts_seq: int = field(default=-1, repr=False, compare=False)

    @property
    def models(self) -> dict[str, SurfaceState]:
        """The reconstructed models (parenchyma, tumours, vessels)."""
        return {n: s for n, s in self.surfaces.items() if not s.is_resection}

    @property
    def resections(self) -> dict[str, SurfaceState]:
        """The resection surfaces, with margins, classes, parameters and verdicts."""
        return {n: s for n, s in self.surfaces.items() if s.is_resection}

    def apply(self, msg: pb.WatchResponse) -> SceneUpdate | None:
        """Applies one Watch message; returns what changed, or None for a snapshot part that is
        not the last (a snapshot takes effect with its last part). Raises `wire.WireError` when a
        mesh or a delta does not decode or does not fit the held surface; the scene is then
        unchanged for that event, and needs a fresh snapshot."""
        event = msg.WhichOneof("event")
        with self.lock:
            if event == "snapshot":
                if self._parts_seq != msg.seq:
                    self._parts = []  # a new snapshot (an unfinished one was superseded)
                self._parts_seq = msg.seq
                self._parts.append(msg.snapshot)
                if not msg.snapshot.complete:
                    return None
                parts, self._parts, self._parts_seq = self._parts, [], -1
                return self._apply_snapshot(msg, parts)
            if event == "delta":
                return self._apply_delta(msg)
            if event == "volumes":
                self.volumes = Volumes.from_pb(msg.volumes, msg.plan_version)
                self._advance(msg)
                return SceneUpdate(msg.seq, msg.plan_version, "volumes", volumes_changed=True)
        return None

    def _advance(self, msg: pb.WatchResponse) -> None:
        self.seq, self.plan_version = msg.seq, msg.plan_version

    def _apply_snapshot(self, msg: pb.WatchResponse, parts: list[watch_pb2.Snapshot]) -> SceneUpdate:
        surfaces: dict[str, SurfaceState] = {}
        session, volumes = self.session, None
        for p in parts:
            if p.HasField("session"):
                session = SessionInfo.from_pb(p.session)
            if p.HasField("volumes"):
                volumes = Volumes.from_pb(p.volumes, msg.plan_version)
            for m in p.models:
                surfaces[m.name] = _from_mesh(m.name, SurfaceKind.from_pb(m.kind), m.label, _color(m), m.mesh)
            for r in p.resections:
                s = _from_mesh(r.name, SurfaceKind.RESECTION, 0, None, r.full_mesh)
                s.resection, s.verdict = Resection.from_pb(r.resection), Verdict.from_pb(r.verdict)
                surfaces[r.name] = s
        removed = frozenset(self.surfaces) - frozenset(surfaces)
        for name, s in surfaces.items():
            old = self.surfaces.get(name)
            s.revision = old.revision + 1 if old else 0
        self.surfaces, self.session, self.volumes = surfaces, session, volumes
        self._advance(msg)
        names = frozenset(surfaces)
        return SceneUpdate(msg.seq, msg.plan_version, "snapshot", names, names, removed, True)

    def _apply_delta(self, msg: pb.WatchResponse) -> SceneUpdate:
        # Decode everything first, so that a bad message leaves the scene as it was.
        staged: list[tuple[watch_pb2.ResectionSurface, wire.Mesh | None, wire.Delta | None]] = []
        for r in msg.delta.resections:
            which = r.WhichOneof("mesh")
            full = wire.decode_mesh(r.full_mesh) if which == "full_mesh" else None
            delta = wire.decode_delta(r.mesh_delta) if which == "mesh_delta" else None
            if delta is not None:
                held = self.surfaces.get(r.name)
                if held is None:
                    raise wire.WireError(f"a delta for surface {r.name!r}, which is not held")
                wire.check_delta(held._mesh(), delta)
            staged.append((r, full, delta))
        changed, rebuilt = set(), set()
        for r, full, delta in staged:
            s = self.surfaces.get(r.name)
            if full is not None:
                new = SurfaceState(
                    r.name, SurfaceKind.RESECTION, 0, None, full["positions"], None, full["triangles"]
                )
                new._set_mesh(full)
                new.revision = s.revision + 1 if s else 0
                self.surfaces[r.name] = s = new
                rebuilt.add(r.name)
            elif delta is not None:
                assert s is not None
                wire.write_delta(s._mesh(), delta)
                s.revision += 1
            elif s is None:
                continue  # parameters of a surface never sent: wait for its mesh
            else:
                s.revision += 1
            s.resection, s.verdict = Resection.from_pb(r.resection), Verdict.from_pb(r.verdict)
            changed.add(r.name)
        removed = frozenset(n for n in msg.delta.removed if self.surfaces.pop(n, None) is not None)
        self._advance(msg)
        return SceneUpdate(
            msg.seq, msg.plan_version, "delta", frozenset(changed), frozenset(rebuilt), removed
        )

    def to_vtk_polydata(self, name: str) -> object:
        """`resecta_client.vtk_adapter.to_vtk_polydata` of the surface `name` (needs `vtk`)."""
        from .vtk_adapter import to_vtk_polydata

        with self.lock:
            return to_vtk_polydata(self.surfaces[name])
