"""DS and CP resections drawn as markups curves, and the CP deformation handle.

A **trace** is a markups curve node tagged with the resection it belongs to
(`Resecta.Trace` = name, `Resecta.TraceKind` = ``ds`` or ``cp``). Its interpolated curve points
(what the view draws) are the trace sent to the server, RAS mm.

- DS (drawn on slices): each curve lies on one axial, coronal or sagittal slice (the coordinate
  of that axis constant within `SLICE_TOLERANCE_MM`; it is set to the median exactly). The
  curves of a DS resection not yet on the server are held until there are `DS_MIN_TRACES`, then
  the resection is created with all of them (`add_ds`); later curves are appended (`add_trace`).
- CP (deformable cutting plane): one curve (typically a closed ring drawn on the liver model in
  the 3D view) creates the resection (`add_cp`); more curves are appended.
- A curve the user edits (its points moved, added or removed; sent when the interaction ends)
  redraws its trace (`set_trace`); a curve removed from the scene removes its trace
  (`remove_trace`). The index sent is the position of the curve's last sent points among the
  resection's traces as the server last answered, so the server's order is never guessed.
- Deformation: a one-point markups node (`Resecta.Deformation` = name) the user drags. The
  offset sent is the handle's height above the surface along the plane normal: the surface
  vertex nearest the handle in the plane (CP surfaces are sampled at their grid vertices) is
  moved onto the handle's level, so the surface follows the handle.

The plane normal N is the smallest PCA axis of the trace points (as the server computes it); its
sign is the server's: the surface's vertex normals (∂S/∂u × ∂S/∂v, u along the short axis)
point against N, so N is oriented against their mean.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import vtk
from vtk.util import numpy_support

TRACE_ATTRIBUTE = "Resecta.Trace"
TRACE_KIND_ATTRIBUTE = "Resecta.TraceKind"
DEFORMATION_ATTRIBUTE = "Resecta.Deformation"
SESSION_ATTRIBUTE = "Resecta.SessionId"
KINDS = ("ds", "cp")
DS_MIN_TRACES = 3
SLICE_TOLERANCE_MM = 0.01
MAX_OFFSET_MM = 100.0
#: the axis a slice orientation keeps constant (RAS index)
SLICE_AXES = {"sagittal": 0, "coronal": 1, "axial": 2}
TRACE_COLOR = (0.15, 0.75, 0.95)
HANDLE_COLOR = (0.95, 0.35, 0.85)


def curve_points(node) -> np.ndarray:
    """The curve's interpolated points in world RAS, (n, 3); its control points when the curve
    has not been interpolated."""
    pts = node.GetCurvePointsWorld()
    if pts is not None and pts.GetNumberOfPoints() >= 2:
        return numpy_support.vtk_to_numpy(pts.GetData()).astype(np.float64).copy()
    out = np.zeros((node.GetNumberOfControlPoints(), 3))
    for k in range(len(out)):
        node.GetNthControlPointPositionWorld(k, out[k])
    return out


def slice_orientation(points: np.ndarray, tol: float = SLICE_TOLERANCE_MM) -> str | None:
    """The orientation ("axial", "coronal", "sagittal") of the slice all `points` lie on, or
    None. A trace on two at once (a straight line along an axis) counts as the first of axial,
    coronal, sagittal."""
    spread = np.ptp(np.asarray(points, float), axis=0)
    for name in ("axial", "coronal", "sagittal"):
        if spread[SLICE_AXES[name]] <= tol:
            return name
    return None


def ds_trace(points, label: str = "the curve") -> np.ndarray:
    """`points` as a DS trace: ≥ 3 points on one axis-aligned slice, that coordinate set to
    their median (ValueError naming `label` otherwise)."""
    pts = np.array(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 3:
        raise ValueError(f"{label} needs at least 3 points, has {len(pts)}")
    orientation = slice_orientation(pts)
    if orientation is None:
        raise ValueError(f"{label} is not on one axial, coronal or sagittal slice: draw it in a "
                         "slice view with the slice's default orientation")
    axis = SLICE_AXES[orientation]
    pts[:, axis] = np.median(pts[:, axis])
    return pts


def cp_trace(points, label: str = "the curve") -> np.ndarray:
    pts = np.array(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 3:
        raise ValueError(f"{label} needs at least 3 points, has {len(pts)}")
    return pts


def to_trace(kind: str, points, label: str = "the curve") -> np.ndarray:
    return ds_trace(points, label) if kind == "ds" else cp_trace(points, label)


def trace_index(traces, sent: np.ndarray) -> int | None:
    """Index of the trace equal to `sent` (within 1 µm) among `traces`, or None."""
    for k, t in enumerate(traces):
        t = np.asarray(t)
        if t.shape == sent.shape and np.allclose(t, sent, atol=1e-3):
            return k
    return None


def plane_normal(traces, vertex_normals) -> np.ndarray:
    """The CP plane's unit normal as the server orients it (module docstring)."""
    pts = np.concatenate([np.asarray(t, float).reshape(-1, 3) for t in traces])
    centred = pts - pts.mean(axis=0)
    _u, _s, vt = np.linalg.svd(centred, full_matrices=False)
    n = vt[-1] / np.linalg.norm(vt[-1])
    mean = np.asarray(vertex_normals, float).mean(axis=0)
    return -n if float(np.dot(n, mean)) > 0 else n


def deformation_offset(handle, positions, normal) -> tuple[float, np.ndarray]:
    """(offset along `normal` that brings the surface vertex nearest `handle` in the plane to
    the handle's level, clamped to ±MAX_OFFSET_MM; that vertex)."""
    p = np.asarray(handle, float)
    d = np.asarray(positions, float) - p
    in_plane = d - np.outer(d @ normal, normal)
    k = int(np.argmin(np.einsum("ij,ij->i", in_plane, in_plane)))
    vertex = np.asarray(positions[k], float)
    offset = float(np.clip(np.dot(p - vertex, normal), -MAX_OFFSET_MM, MAX_OFFSET_MM))
    return offset, vertex


def is_trace(node) -> bool:
    return node is not None and node.GetAttribute(TRACE_ATTRIBUTE) is not None


def make_curve_node(scene, resection: str, kind: str, session_id: str | None = None,
                    closed: bool | None = None):
    """A new curve node for a trace of `resection` (closed for CP unless told)."""
    if kind not in KINDS:
        raise ValueError(f"unknown trace kind {kind!r} (one of {', '.join(KINDS)})")
    closed = kind == "cp" if closed is None else closed
    cls = "vtkMRMLMarkupsClosedCurveNode" if closed else "vtkMRMLMarkupsCurveNode"
    node = scene.AddNewNodeByClass(cls, scene.GenerateUniqueName(f"Resecta {resection} trace"))
    node.SetAttribute(TRACE_ATTRIBUTE, resection)
    node.SetAttribute(TRACE_KIND_ATTRIBUTE, kind)
    if session_id:
        node.SetAttribute(SESSION_ATTRIBUTE, session_id)
    node.CreateDefaultDisplayNodes()
    display = node.GetDisplayNode()
    display.SetSelectedColor(*TRACE_COLOR)
    display.SetColor(*TRACE_COLOR)
    return node


def make_handle_node(scene, resection: str, point=None):
    """The deformation handle of `resection`: a one-point markups list."""
    node = scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode",
                                   scene.GenerateUniqueName(f"Resecta {resection} deformation"))
    node.SetAttribute(DEFORMATION_ATTRIBUTE, resection)
    node.SetMaximumNumberOfControlPoints(1)
    node.CreateDefaultDisplayNodes()
    node.GetDisplayNode().SetSelectedColor(*HANDLE_COLOR)
    if point is not None:
        node.AddControlPointWorld(vtk.vtkVector3d(*(float(x) for x in point)), "D")
    return node


def handle_point(node) -> np.ndarray | None:
    if node is None or node.GetNumberOfDefinedControlPoints() < 1:
        return None
    p = np.zeros(3)
    node.GetNthControlPointPositionWorld(0, p)
    return p


class TraceSync:
    """Curves ↔ the traces of DS and CP resections.

    `send(name, fn, on_error)` runs a server call `fn(session) -> EditResult` for resection
    `name` (the Logic's edit path; `on_error(exc)` when it fails); `resection(name)` is the
    resection as last watched (None when the server has none). The sync holds, per curve node
    id: the resection, the kind, the points last sent and whether it is held.
    """

    def __init__(self, scene, send: Callable[[str, Callable, Callable | None], None],
                 resection: Callable[[str], object]):
        self.scene = scene
        self._send = send
        self._resection = resection
        self.curves: dict[str, dict] = {}  # node id → {"name", "kind", "sent", "node", "pending"}
        #: resection name → its traces as the last edit answered (worker thread, `answer`)
        self._answered: dict[str, tuple] = {}
        self._options: dict[str, dict] = {}  # resection name → margin_mm, band_mm, target
        self._creating: set[str] = set()  # names whose creation was sent
        self._observers: list[tuple[object, int]] = []
        self._scene_tag = scene.AddObserver(scene.NodeAboutToBeRemovedEvent, self._node_removed)

    # --- queries -----------------------------------------------------------------------------

    def held(self, name: str) -> list[str]:
        """Ids of the curves of `name` not yet on the server (a DS waiting for 3)."""
        return [i for i, c in self.curves.items() if c["name"] == name and c["pending"]]

    def curve_ids(self, name: str) -> list[str]:
        return [i for i, c in self.curves.items() if c["name"] == name]

    @property
    def observer_count(self) -> int:
        return len(self._observers)

    # --- curves ------------------------------------------------------------------------------

    def use_curve(self, node, margin_mm: float | None = None, band_mm: float | None = None,
                  target=None) -> str:
        """Turns a finished curve into a trace of its resection: appended when the resection is
        on the server, else held, and the resection created once enough are held. Returns
        "added", "held" or "created"."""
        name = node.GetAttribute(TRACE_ATTRIBUTE)
        kind = node.GetAttribute(TRACE_KIND_ATTRIBUTE)
        if not name or kind not in KINDS:
            raise ValueError(f"{node.GetName()!r} is not a Resecta trace curve")
        if node.GetID() in self.curves:
            self.redraw(node)
            return "added"
        trace = to_trace(kind, curve_points(node), f"the curve {node.GetName()!r}")
        exists = (self._resection(name) is not None or name in self._answered
                  or name in self._creating)
        entry = {"name": name, "kind": kind, "sent": trace, "node": node, "pending": not exists}
        self.curves[node.GetID()] = entry
        self._observe(node)
        if exists:
            self._edit(name, lambda s: s.add_trace(name, trace))
            return "added"
        self._options[name] = {k: v for k, v in (("margin_mm", margin_mm), ("band_mm", band_mm),
                                                 ("target", target)) if v is not None}
        return self._create_if_ready(name, kind)

    def _create_if_ready(self, name: str, kind: str) -> str:
        """Creates `name` from its held curves once there are enough ("created"), else "held".
        Should the server refuse them, they are held again (redraw one to try again)."""
        held = [self.curves[i] for i in self.held(name)]
        if kind == "ds" and len(held) < DS_MIN_TRACES:
            return "held"
        traces = [c["sent"] for c in held]
        for c in held:
            c["pending"] = False
        options = self._options.get(name, {})

        self._creating.add(name)

        def refused(_exc):
            self._creating.discard(name)
            for c in held:
                c["pending"] = True

        if kind == "ds":
            self._edit(name, lambda s: s.add_ds(name, traces, **options), refused)
        else:
            self._edit(name, lambda s: s.add_cp(name, traces, **options), refused)
        return "created"

    def redraw(self, node) -> bool:
        """Sends the curve's points again (`set_trace`) when they changed; True when sent."""
        entry = self.curves.get(node.GetID())
        if entry is None:
            return False
        trace = to_trace(entry["kind"], curve_points(node), f"the curve {node.GetName()!r}")
        old = entry["sent"]
        if old.shape == trace.shape and np.allclose(old, trace, atol=1e-6):
            return False
        entry["sent"] = trace
        if entry["pending"]:
            self._create_if_ready(entry["name"], entry["kind"])
            return True
        name = entry["name"]
        self._edit(name, lambda s: s.set_trace(name, self._index(name, old), trace))
        return True

    def remove(self, node_id: str) -> None:
        """The curve is gone: its trace is removed (a held one is just forgotten)."""
        entry = self.curves.pop(node_id, None)
        if entry is None:
            return
        self._unobserve(entry["node"])
        if entry["pending"]:
            return
        name, old = entry["name"], entry["sent"]
        self._edit(name, lambda s: s.remove_trace(name, self._index(name, old)))

    def _edit(self, name: str, fn: Callable, on_error: Callable | None = None) -> None:
        self._send(name, fn, on_error)

    def answer(self, result) -> None:
        """Worker thread, every edit's answer in the server's order (`EditCommands.on_answer`):
        the traces it holds (the next edit may run before the watch brings them); None
        (a plan import) forgets them all."""
        if result is None:
            self._answered.clear()
            return
        for status in result.resections:
            self._answered[status.resection.name] = status.resection.traces
        for gone in result.removed:
            self._answered.pop(gone, None)

    def _index(self, name: str, sent: np.ndarray) -> int:
        """Where `sent` is among the traces of `name`: in the last answer, else as watched."""
        k = trace_index(self._answered.get(name, ()), sent)
        if k is None:
            resection = self._resection(name)
            k = trace_index(resection.traces if resection is not None else (), sent)
        if k is None:
            raise ValueError(f"the trace drawn for {name!r} is not among its traces on the server")
        return k

    def forget(self, name: str | None = None) -> None:
        """Stops following the curves of `name` (all with None); the nodes stay."""
        for node_id in [i for i, c in self.curves.items() if name is None or c["name"] == name]:
            self._unobserve(self.curves.pop(node_id)["node"])

    def close(self) -> None:
        self.forget()
        if self._scene_tag is not None:
            self.scene.RemoveObserver(self._scene_tag)
            self._scene_tag = None

    # --- observers ---------------------------------------------------------------------------

    def _observe(self, node) -> None:
        import slicer

        Markups = slicer.vtkMRMLMarkupsNode

        def ended(caller, event):
            self._safe(lambda: self.redraw(caller))

        def changed(caller, event):
            # Points added or removed outside an interaction (scripts, the Markups module).
            self._safe(lambda: self.redraw(caller))

        for event, fn in ((Markups.PointEndInteractionEvent, ended),
                          (Markups.PointRemovedEvent, changed),
                          (Markups.PointPositionDefinedEvent, changed)):
            self._observers.append((node, node.AddObserver(event, fn)))

    def _unobserve(self, node) -> None:
        keep = []
        for obj, tag in self._observers:
            if obj is node:
                obj.RemoveObserver(tag)
            else:
                keep.append((obj, tag))
        self._observers = keep

    def _safe(self, fn) -> None:
        try:
            fn()
        except ValueError as exc:  # a curve not on a slice: reported, the old trace stays
            self.on_error(exc)

    #: set by the Logic: how a curve that cannot be sent is reported
    on_error: Callable[[BaseException], None] = staticmethod(lambda exc: None)

    @vtk.calldata_type(vtk.VTK_OBJECT)
    def _node_removed(self, caller, event, node=None):
        if node is not None and node.GetID() in self.curves:
            self.remove(node.GetID())
