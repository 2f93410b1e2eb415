"""`PlanningSession`: the Logic of the Resecta module, without Qt.

One object per connected server session. Every server call runs on a worker (the dispatcher's
pool, one call at a time so that edits reach the server in the order they were made); the watch
stream runs on its own thread; their results come back to the main thread through the
dispatcher's queue (`poll()`), where the scene is changed: model nodes made or updated in place,
the control-grid markups kept in step with the plan, the margin indicator and the volumetry table
recomputed, and the caller told through callbacks (`set_callbacks`).

Callbacks (all optional, all on the main thread): `status(text)`, `error(exception)`,
`progress(fraction, stage)`, `models()` (the set of model nodes changed), `resections()` (the set
of resections changed), `volumes(VolumeTable)`, `margin(MarginIndicator)`.

Dragging a control point of a grid markups node sends `set_control_point` edits through an
`EditCoalescer` (one edit in flight; while it is, only the latest position per point waits), with
`base_version = 0` (a dragged point's position is absolute: the last one wins). While a grid has
edits in flight or waiting, or a point is being dragged, echoes of the plan from the watch stream
do not move its markups (they would pull the point back under the mouse); the grid is brought in
line with the server when the coalescer is idle again.
"""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path
from typing import Any, Callable

import numpy as np
import vtk

from . import controlgrid, margin, models, planfile, preview, segmentation, volumetry
from .coalesce import EditCoalescer
from .dispatch import ThreadDispatcher

PREVIEW_NODE_NAME = "Resecta preview contour"
AXES = {"R": (1.0, 0.0, 0.0), "A": (0.0, 1.0, 0.0), "S": (0.0, 0.0, 1.0)}


@dataclasses.dataclass
class _Pending:
    """Watch updates merged until the main thread applies them."""

    changed: set = dataclasses.field(default_factory=set)
    rebuilt: set = dataclasses.field(default_factory=set)
    removed: set = dataclasses.field(default_factory=set)
    snapshot: bool = False
    volumes: bool = False


class PlanningSession:
    def __init__(self, scene, dispatcher=None, client_factory: Callable[..., Any] | None = None):
        self.scene = scene
        self.dispatcher = dispatcher if dispatcher is not None else ThreadDispatcher(workers=1)
        self._client_factory = client_factory
        self.client = None
        self.server_info = None
        self.session = None  # resecta_client.Session
        self.watch = None  # resecta_client.Watch
        self._watch_thread = None
        self.models: models.ModelUpdater | None = None
        self.grids: dict[str, Any] = {}  # resection name → markups node
        self._grid_observers: dict[str, list[tuple[Any, int]]] = {}
        self._syncing = False
        self._interacting: set[str] = set()
        self.coalescer = EditCoalescer(self._send_control_point)
        self.margin_state = margin.NONE
        self.volume_table = volumetry.EMPTY
        self.verdicts: dict[str, tuple[float, Any]] = {}
        self.last_error: BaseException | None = None
        self.errors: list[BaseException] = []
        self._callbacks: dict[str, Callable] = {}
        self._pending = _Pending()
        self._pending_lock = threading.Lock()
        self._flush_scheduled = False
        self._cancel = threading.Event()
        self._building = False
        self._centroids: dict[str, np.ndarray] = {}
        #: counters (tests, status line): watch updates applied, edits acknowledged
        self.applied_updates = 0
        self.acknowledged_edits = 0
        self.last_edit = None  # resecta_client.EditResult

    # --- plumbing -----------------------------------------------------------------------------

    def set_callbacks(self, **callbacks: Callable) -> None:
        self._callbacks = {k: v for k, v in callbacks.items() if v is not None}

    def _emit(self, name: str, *args) -> None:
        cb = self._callbacks.get(name)
        if cb is not None:
            cb(*args)

    def _status(self, text: str) -> None:
        self._emit("status", text)

    def _error(self, exc: BaseException) -> None:
        self.last_error = exc
        self.errors.append(exc)
        self._emit("error", exc)

    def _call(self, fn: Callable[[], Any], on_done: Callable[[Any], None] | None = None,
              user_done: Callable[[Any], None] | None = None,
              on_error: Callable[[BaseException], None] | None = None) -> None:
        """Runs `fn` on a worker; `on_done(result)` then `user_done(result)` on the main thread."""

        def done(result):
            if on_done is not None:
                on_done(result)
            if user_done is not None:
                user_done(result)

        def failed(exc):
            if on_error is not None:
                on_error(exc)
            self._error(exc)

        self.dispatcher.submit(fn, done, failed)

    def poll(self) -> int:
        """Delivers worker results on the calling (main) thread; Slicer calls it from a timer."""
        return self.dispatcher.poll()

    @property
    def connected(self) -> bool:
        return self.client is not None

    @property
    def session_id(self) -> str | None:
        return self.session.id if self.session is not None else None

    @property
    def models_ready(self) -> bool:
        return self.models is not None and any(
            n.GetAttribute(models.KIND_ATTRIBUTE) == "parenchyma"
            for n in models.model_nodes(self.scene, self.session_id))

    def _need_session(self):
        if self.session is None:
            raise ValueError("no server session: connect and build the models first")
        return self.session

    # --- connection and session ---------------------------------------------------------------

    def connect(self, address: str, token: str | None = None, tls: bool = False,
                ca_file: str | None = None, on_done: Callable | None = None) -> None:
        """Connects (on a worker) and checks the server (`server_info`)."""
        factory = self._client_factory
        if factory is None:
            from resecta_client import Client as factory  # installed on first use in Slicer

        def work():
            client = factory(address, token, tls=tls, ca_cert=ca_file or None)
            try:
                info = client.server_info()
            except BaseException:
                client.close()
                raise
            return client, info

        def done(result):
            self.close_client()
            self.client, self.server_info = result
            self._status(f"Connected to resecta {self.server_info.server_version} at {address}")

        self._call(work, done, lambda r: on_done(r[1]) if on_done else None)

    def open_session(self, session_id: str, on_done: Callable | None = None) -> None:
        """Uses an existing server session (e.g. after a scene reload) and starts watching it."""
        client = self._require_client()

        def done(sess):
            self._use_session(sess)
            self.start_watch()

        self._call(lambda: client.session(session_id), done, on_done)

    def _require_client(self):
        if self.client is None:
            raise ValueError("not connected to a resecta server")
        return self.client

    def _use_session(self, sess) -> None:
        self.session = sess
        self.models = models.ModelUpdater(self.scene, sess.id)

    # --- upload and models --------------------------------------------------------------------

    def upload_and_build(self, segmentation_node, role_table: dict[str, str], method: str = "psr",
                         display_name: str = "Slicer", on_done: Callable | None = None,
                         **reconstruct_options) -> None:
        """Merges the segmentation (main thread), then on a worker: creates a session if there is
        none, uploads, reconstructs with progress; starts the watch, whose snapshot brings the
        models into the scene. `cancel_build()` cancels the reconstruction."""
        client = self._require_client()
        labelmap = segmentation.labelmap_from_segmentation(segmentation_node, role_table)
        if self._building:
            raise ValueError("a reconstruction is already running")
        self._building = True
        self._cancel.clear()
        existing = self.session

        def progress(fraction, stage):
            self.dispatcher.call_soon(lambda: self._emit("progress", fraction, stage))

        def upload():
            sess = existing if existing is not None else client.create_session(display_name)
            summary = sess.upload_label_map(labelmap.labels, labelmap.ijk_to_ras, labelmap.roles)
            return sess, summary

        def uploaded(result):
            sess, summary = result
            if self.session is None or self.session.id != sess.id:
                self._use_session(sess)
            self.label_map_summary = summary
            self._status(f"Label map uploaded ({summary.liver_volume_ml:.1f} ml of liver); "
                         "building models…")
            self.start_watch()
            self.dispatcher.start_thread(build, "resecta-reconstruct")

        def build():
            try:
                infos = self.session.reconstruct(method, progress=progress, cancel=self._cancel,
                                                 **reconstruct_options)
            except BaseException as exc:  # noqa: BLE001 - reported on the main thread
                self.dispatcher.call_soon(lambda exc=exc: self._build_failed(exc))
                return
            self.dispatcher.call_soon(lambda: self._build_done(infos, on_done))

        def upload_failed(_exc):
            self._building = False

        self._call(upload, uploaded, on_error=upload_failed)

    def _build_done(self, infos, on_done) -> None:
        self._building = False
        self.model_infos = {i.name: i for i in infos}
        self._status(f"{len(infos)} models built")
        if on_done is not None:
            on_done(infos)

    def _build_failed(self, exc) -> None:
        self._building = False
        self._error(exc)

    def cancel_build(self) -> None:
        self._cancel.set()

    @property
    def building(self) -> bool:
        return self._building

    # --- watch --------------------------------------------------------------------------------

    def start_watch(self) -> None:
        """Follows the session on a thread; updates reach the scene on `poll()`."""
        sess = self._need_session()
        if self.watch is not None and self.watch.session.id == sess.id:
            return
        self.stop_watch()
        watch = sess.watch()
        self.watch = watch

        def loop():
            try:
                for update in watch:
                    self._enqueue(update)
            except BaseException as exc:  # noqa: BLE001 - reported on the main thread
                if self.watch is watch:
                    self.dispatcher.call_soon(lambda exc=exc: self._error(exc))

        self._watch_thread = self.dispatcher.start_thread(loop, "resecta-watch")

    def stop_watch(self) -> None:
        watch, self.watch = self.watch, None
        if watch is not None:
            watch.stop()

    def _enqueue(self, update) -> None:
        """Watch thread: merges the update and schedules one main-thread flush."""
        with self._pending_lock:
            p = self._pending
            if update.kind == "snapshot":
                p.snapshot = True
                p.changed |= set(update.changed)
                p.rebuilt |= set(update.rebuilt)
                p.removed |= set(update.removed)
            else:
                p.changed |= set(update.changed)
                p.rebuilt |= set(update.rebuilt)
                p.removed |= set(update.removed)
                p.changed -= set(update.removed)
            p.volumes |= bool(update.volumes_changed)
            if self._flush_scheduled:
                return
            self._flush_scheduled = True
        self.dispatcher.call_soon(self._flush)

    def _flush(self) -> None:
        """Main thread: applies the merged watch updates to the scene."""
        with self._pending_lock:
            p, self._pending = self._pending, _Pending()
            self._flush_scheduled = False
        if self.watch is None or self.models is None:
            return
        live = self.watch.scene
        models_changed = resections_changed = False
        with live.lock:
            surfaces = dict(live.surfaces)
            if p.snapshot:
                for node in models.model_nodes(self.scene, self.session_id):
                    name = node.GetAttribute(models.NAME_ATTRIBUTE)
                    if name not in surfaces:
                        p.removed.add(name)
            for name in sorted(p.changed):
                s = surfaces.get(name)
                if s is None:
                    continue
                kind = s.kind.value if hasattr(s.kind, "value") else s.kind
                is_new = models.find_model(self.scene, name, self.session_id) is None
                self.models.upsert(name, kind, s.positions, s.triangles, normals=s.normals,
                                   margins=s.margins, classes=s.classes, color=s.color)
                if s.is_resection:
                    resections_changed |= is_new
                    if s.resection is not None:
                        self.verdicts[name] = (s.resection.margin_mm, s.verdict)
                        self._sync_grid(name, s.resection)
                else:
                    models_changed |= is_new
                    self._centroids.pop(name, None)
            volumes = live.volumes
        for name in sorted(p.removed):
            if self.models.remove(name):
                resections_changed = True
                models_changed = True
            self.verdicts.pop(name, None)
            self._remove_grid(name)
        self.applied_updates += 1
        if models_changed:
            self._emit("models")
        if resections_changed or p.snapshot:
            self._emit("resections")
        self._update_margin()
        if (p.volumes or p.snapshot) and volumes is not None:
            self.volume_table = volumetry.table(volumes)
            self._emit("volumes", self.volume_table)

    def _update_margin(self) -> None:
        state = margin.indicator(self.verdicts)
        if state != self.margin_state:
            self.margin_state = state
            self._emit("margin", state)

    # --- queries --------------------------------------------------------------------------------

    def surfaces(self) -> dict:
        return dict(self.watch.scene.surfaces) if self.watch is not None else {}

    def tumours(self) -> list[str]:
        return sorted(n for n, s in self.surfaces().items()
                      if getattr(s.kind, "value", s.kind) == "tumor")

    def resection_names(self) -> list[str]:
        return sorted(n for n, s in self.surfaces().items() if s.is_resection)

    def resection(self, name: str):
        """The resection's parameters (`resecta_client.Resection`) as last seen."""
        s = self.surfaces().get(name)
        return s.resection if s is not None and s.is_resection else None

    def model_node(self, name: str):
        return models.find_model(self.scene, name, self.session_id)

    def tumour_centroid(self, name: str) -> np.ndarray:
        if name not in self._centroids:
            node = self.model_node(name)
            if node is None or node.GetPolyData() is None:
                raise ValueError(f"no tumour model {name!r}")
            self._centroids[name] = preview.mesh_centroid(node.GetPolyData())
        return self._centroids[name]

    def set_opacity(self, kinds, value: float) -> None:
        if self.models is not None:
            self.models.set_opacity(tuple(kinds), value)

    # --- preview ------------------------------------------------------------------------------

    def preview(self, tumour: str | None, end_point) -> Any:
        """Draws (or with None hides) the parenchyma's contour on Algorithm 1's plane."""
        node = None
        n = self.scene.GetNumberOfNodesByClass("vtkMRMLModelNode")
        for i in range(n):
            candidate = self.scene.GetNthNodeByClass(i, "vtkMRMLModelNode")
            if candidate.GetName() == PREVIEW_NODE_NAME:
                node = candidate
        parenchyma = None
        for m in models.model_nodes(self.scene, self.session_id):
            if m.GetAttribute(models.KIND_ATTRIBUTE) == "parenchyma":
                parenchyma = m
        if not tumour or end_point is None or parenchyma is None:
            if node is not None and node.GetDisplayNode():
                node.GetDisplayNode().SetVisibility(False)
            return None
        try:
            point, normal = preview.initial_plane(self.tumour_centroid(tumour), end_point)
        except ValueError as exc:
            self._status(str(exc))
            return None
        if node is None:
            node = self.scene.AddNewNodeByClass("vtkMRMLModelNode", PREVIEW_NODE_NAME)
            node.CreateDefaultDisplayNodes()
            display = node.GetDisplayNode()
            display.SetColor(1.0, 0.9, 0.1)
            display.SetLineWidth(3)
            display.SetVisibility2D(True)
            node.SetAndObservePolyData(vtk.vtkPolyData())
        preview.contour(parenchyma.GetPolyData(), point, normal, node.GetPolyData())
        node.GetPolyData().Modified()
        node.GetDisplayNode().SetVisibility(True)
        return node

    # --- resections -----------------------------------------------------------------------------

    def _edit(self, fn: Callable[[Any], Any], on_done: Callable | None = None) -> None:
        sess = self._need_session()

        def done(result):
            self._edit_done(result)

        self._call(lambda: fn(sess), done, on_done)

    def _edit_done(self, result) -> None:
        self.acknowledged_edits += 1
        self.last_edit = result
        for status in result.resections:
            self.verdicts[status.resection.name] = (status.resection.margin_mm, status.verdict)
        for name in result.removed:
            self.verdicts.pop(name, None)
        self._update_margin()

    def new_resection(self, name: str, tumour: str, end_point, margin_mm: float | None = None,
                      band_mm: float | None = None, grid=(4, 4), on_done: Callable | None = None):
        """Adds resection `name` from tumour model `tumour` and the end point (Algorithms 1–2),
        then sets its margin and band when given. Its control grid appears as a markups node
        when the watch brings the resection."""
        from resecta_client import Target

        s = self.surfaces().get(tumour)
        if s is None or getattr(s.kind, "value", s.kind) != "tumor":
            raise ValueError(f"{tumour!r} is not a tumour model")
        centroid = self.tumour_centroid(tumour)
        target = Target(labels=(s.label,) if s.label else (),
                        points=(tuple(float(x) for x in centroid),))
        end = tuple(float(x) for x in end_point)

        def work(sess):
            result = sess.init_from_end_point(name, end, target=target, grid=tuple(grid))
            if margin_mm is not None and abs(result[name].resection.margin_mm - margin_mm) > 1e-9:
                result = sess.set_margin(name, margin_mm)
            if band_mm is not None and abs(result[name].resection.band_mm - band_mm) > 1e-9:
                result = sess.set_band(name, band_mm)
            return result

        self._edit(work, on_done)

    def set_margin_and_band(self, name: str, margin_mm: float, band_mm: float,
                            on_done: Callable | None = None) -> None:
        current = self.resection(name)

        def work(sess):
            result = None
            if current is None or abs(current.margin_mm - margin_mm) > 1e-9:
                result = sess.set_margin(name, margin_mm)
            if current is None or abs(current.band_mm - band_mm) > 1e-9:
                result = sess.set_band(name, band_mm)
            return result

        def done(result):
            if result is not None:
                self._edit_done(result)

        self._call(lambda: work(self._need_session()), done, on_done)

    def move_group(self, name: str, group: str, delta, on_done: Callable | None = None) -> None:
        """Moves `group` ("inner", "outer", "all" or a ring number) of `name`'s grid by delta."""
        delta = tuple(float(x) for x in delta)
        if isinstance(group, int):
            self._edit(lambda s: s.move_group(name, delta, ring=group), on_done)
        else:
            self._edit(lambda s: s.move_group(name, delta, group=group), on_done)

    def translate(self, name: str, delta, on_done: Callable | None = None) -> None:
        delta = tuple(float(x) for x in delta)
        self._edit(lambda s: s.translate(name, delta), on_done)

    def rotate(self, name: str, axis, angle_deg: float, centre=None,
               on_done: Callable | None = None) -> None:
        """Rotates `name` about `axis` ("R", "A", "S", "normal" or a vector) through `centre`
        (default: the control points' centroid)."""
        if isinstance(axis, str):
            if axis == "normal":
                axis = self.grid_normal(name)
            else:
                axis = AXES[axis]
        axis = tuple(float(x) for x in axis)
        self._edit(lambda s: s.rotate(name, axis, float(angle_deg), centre=centre), on_done)

    def grid_normal(self, name: str) -> np.ndarray:
        r = self.resection(name)
        if r is None:
            raise ValueError(f"no resection {name!r}")
        cp = r.control_points
        du = cp[-1, :, :].mean(axis=0) - cp[0, :, :].mean(axis=0)
        dv = cp[:, -1, :].mean(axis=0) - cp[:, 0, :].mean(axis=0)
        n = np.cross(du, dv)
        return n / np.linalg.norm(n)

    def delete_resection(self, name: str, on_done: Callable | None = None) -> None:
        self.coalescer.clear()
        self._edit(lambda s: s.delete_resection(name), on_done)

    def undo(self, on_done: Callable | None = None) -> None:
        self.coalescer.clear()
        self._edit(lambda s: s.undo(), on_done)

    def redo(self, on_done: Callable | None = None) -> None:
        self.coalescer.clear()
        self._edit(lambda s: s.redo(), on_done)

    # --- control grid markups -------------------------------------------------------------------

    def _sync_grid(self, name: str, resection) -> None:
        """Makes (or updates) the markups of `name` from the server's control points, unless the
        user is dragging or edits of it are on their way."""
        cp = np.asarray(resection.control_points, dtype=float)
        m, n = cp.shape[0], cp.shape[1]
        node = self.grids.get(name)
        if node is None or self.scene.GetNodeByID(node.GetID()) is None:
            node = controlgrid.find_grid_node(self.scene, name, self.session_id)
            if node is None:
                node = controlgrid.make_grid_node(self.scene, name, cp.reshape(-1, 3), m, n,
                                                  session_id=self.session_id)
            self.grids[name] = node
            self._observe_grid(name, node)
        if self._grid_busy(name):
            return
        if node.GetNumberOfControlPoints() == m * n and controlgrid.grid_shape(node) == (m, n) \
                and np.allclose(controlgrid.grid_points(node), cp.reshape(-1, 3), atol=1e-6):
            return
        self._syncing = True
        try:
            controlgrid.set_grid(node, cp.reshape(-1, 3), m, n)
        finally:
            self._syncing = False

    def _grid_busy(self, name: str) -> bool:
        if name in self._interacting:
            return True
        if self.coalescer.busy and self.coalescer._in_flight is not None \
                and self.coalescer._in_flight[0] == name:
            return True
        return any(key[0] == name for key in self.coalescer.pending)

    def _observe_grid(self, name: str, node) -> None:
        import slicer

        Markups = slicer.vtkMRMLMarkupsNode

        @vtk.calldata_type(vtk.VTK_INT)
        def moved(caller, event, index=None):
            if self._syncing or index is None or index < 0:
                return
            self.on_control_point_moved(name, int(index))

        def started(caller, event):
            self._interacting.add(name)

        def ended(caller, event):
            self._interacting.discard(name)
            if not self.coalescer.busy:
                self._resync_grids()

        tags = [(node, node.AddObserver(Markups.PointModifiedEvent, moved)),
                (node, node.AddObserver(Markups.PointStartInteractionEvent, started)),
                (node, node.AddObserver(Markups.PointEndInteractionEvent, ended))]
        self._grid_observers[name] = tags

    def _remove_grid(self, name: str) -> None:
        for obj, tag in self._grid_observers.pop(name, []):
            obj.RemoveObserver(tag)
        node = self.grids.pop(name, None)
        if node is not None and self.scene.GetNodeByID(node.GetID()) is not None:
            self.scene.RemoveNode(node)

    def on_control_point_moved(self, name: str, k: int) -> None:
        """A markups control point moved (the user dragged it): send it, coalesced."""
        node = self.grids.get(name)
        if node is None:
            return
        m, n = controlgrid.grid_shape(node)
        if k >= m * n:
            return
        self.coalescer.push((name, k), controlgrid.control_point(node, k))

    def _send_control_point(self, key, point) -> None:
        name, k = key
        node = self.grids.get(name)
        if node is None or self.session is None:
            self.coalescer.done()
            return
        _m, n = controlgrid.grid_shape(node)
        i, j = controlgrid.ij(k, n)
        p = tuple(float(x) for x in point)
        sess = self.session

        def done(result):
            self._edit_done(result)
            self._coalescer_done()

        def failed(_exc):
            self._coalescer_done()

        self._call(lambda: sess.set_control_point(name, i, j, p, base_version=0), done,
                   on_error=failed)

    def _coalescer_done(self) -> None:
        self.coalescer.done()
        if not self.coalescer.busy:
            self._resync_grids()

    def _resync_grids(self) -> None:
        for name, s in self.surfaces().items():
            if s.is_resection and s.resection is not None:
                self._sync_grid(name, s.resection)

    # --- volumes, plans, exports ----------------------------------------------------------------

    def refresh_volumes(self, on_done: Callable | None = None) -> None:
        sess = self._need_session()

        def done(v):
            self.volume_table = volumetry.table(v)
            self._emit("volumes", self.volume_table)

        self._call(sess.volumes, done, on_done)

    def save_plan(self, path, on_done: Callable | None = None) -> None:
        sess = self._need_session()

        def done(text):
            planfile.save(path, text)
            self._status(f"Plan saved to {path}")

        self._call(sess.export_plan, done, on_done)

    def load_plan(self, path, on_done: Callable | None = None) -> None:
        sess = self._need_session()
        text = planfile.load(path)
        self.coalescer.clear()
        self._call(lambda: sess.import_plan(text),
                   lambda v: self._status(f"Plan loaded from {path} (version {v})"), on_done)

    def export_resections(self, folder, fmt: str = "vtp", on_done: Callable | None = None) -> None:
        """Writes every resection's mesh as `<folder>/<name>.<fmt>` (RAS; VTP with margins)."""
        sess = self._need_session()
        names = self.resection_names()
        folder = Path(folder)

        def work():
            out = []
            for name in names:
                data = sess.export_model(name, fmt, resection=True)
                path = folder / f"{name}.{fmt}"
                path.write_bytes(data)
                out.append(path)
            return out

        self._call(work, lambda paths: self._status(f"Exported {len(paths)} resection(s) to {folder}"),
                   on_done)

    # --- ending ---------------------------------------------------------------------------------

    def close_client(self) -> None:
        self.stop_watch()
        if self.client is not None:
            self.client.close()
        self.client = None

    def close(self) -> None:
        """Stops the watch and closes the connection (the server keeps the session)."""
        self._cancel.set()
        for name in list(self._grid_observers):
            for obj, tag in self._grid_observers.pop(name):
                obj.RemoveObserver(tag)
        self.close_client()
        self.dispatcher.shutdown()
