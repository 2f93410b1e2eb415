"""`PlanningLogic`: the Logic of the Resecta module, without Qt (`ResectaLogic` in Resecta.py
is this plus Slicer's Logic base class).

It owns the connection to a resecta server and one server session, and keeps the scene in step
with it. Every server call runs on a worker (the dispatcher's pool, one call at a time so that
edits reach the server in the order they were made); the watch stream runs on its own thread;
their results come back to the main thread through the dispatcher's queue (`poll()`), where the
scene changes. The work is split into parts with one job each:

- `sceneupdate.WatchApplier`: watch updates → model nodes, by the server's `changed`/`rebuilt`/
  `removed` lists;
- `gridsync.GridSync`: control grids ↔ markups nodes (drags go to `edits.drag`);
- `edits.EditCommands`: the edit commands (and the coalescing of drags);
- `traces.TraceSync`: markups curves ↔ the traces of DS and CP resections.

Callbacks (all optional, all on the main thread): `status(text)`, `error(exception)`,
`progress(fraction, stage)`, `model_built(info)`, `models()` (model nodes added or removed),
`resections()` (resections added or removed), `volumes(VolumeTable)`, `metrics(rows)` (each
resection's kind and Sec. 7.4 metrics, `volumetry.MetricRow`s), `margin(MarginIndicator)`,
`session()` (the server session was opened or forgotten), `resectogram(Resectogram)` (the
resectogram shown was refreshed), `session_moved(session_id, address)` (a replicated server's
session is now served by the replica at `address`; the client follows it by itself).

The vascular risk (`risk.py`): cut vessels follow every volume report; `show_risk` fetches the
risk map once; `follow_resectogram` shows a resection's resectogram and refetches it after each
plan change (at most one request in flight, the latest plan wins).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import vtk

from . import margin, models, planfile, preview, risk, segmentation, traces, volumetry
from .dispatch import ThreadDispatcher
from .edits import EditCommands
from .gridsync import GridSync
from .sceneupdate import WatchApplier

PREVIEW_NODE_NAME = "Resecta preview contour"


def parse_addresses(text: str | Sequence[str]) -> list[str]:
    """The addresses in `text` (comma-, space- or newline-separated, or already a list), in
    order, without blanks or repeats: ``"a:1, b:2"`` → ``["a:1", "b:2"]``."""
    items = text.replace(",", " ").split() if isinstance(text, str) else [str(a).strip() for a in text]
    return list(dict.fromkeys(a for a in items if a))


class PlanningLogic:
    def __init__(self, scene, dispatcher=None, client_factory: Callable[..., Any] | None = None):
        self.scene = scene
        self.dispatcher = dispatcher if dispatcher is not None else ThreadDispatcher(workers=1)
        self._client_factory = client_factory
        self.client = None
        self.server_info = None
        self.session = None  # resecta_client.Session
        self.watch = None  # resecta_client.Watch
        self.grids: GridSync | None = None
        self.traces: traces.TraceSync | None = None
        self.applier: WatchApplier | None = None
        self.edits = EditCommands(self.call, self._need_session, self.resection,
                                  self._edit_done, self._resync_grids)
        self.margin_state = margin.NONE
        self.volume_table = volumetry.EMPTY
        self.metrics_table: tuple[volumetry.MetricRow, ...] = ()
        self.verdicts: dict[str, tuple[float, Any]] = {}
        self.model_infos: dict[str, Any] = {}
        self.label_map_summary = None
        self.errors: list[BaseException] = []
        self.moves: list[tuple[str, str]] = []  # (session id, replica address), as reported
        self._callbacks: dict[str, Callable] = {}
        self._cancel = threading.Event()
        self._building = False
        self._centroids: dict[str, np.ndarray] = {}
        self._threads: list[threading.Thread] = []
        self.resectogram_resection: str | None = None
        self._resectogram_busy = False
        self._resectogram_version = -1

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
        self.errors.append(exc)
        self._emit("error", exc)

    def call(self, fn: Callable[[], Any], on_done: Callable[[Any], None] | None = None,
             user_done: Callable[[Any], None] | None = None,
             on_error: Callable[[BaseException], None] | None = None) -> None:
        """Runs `fn` on the worker; `on_done(result)` then `user_done(result)` on the main
        thread, or `on_error(exc)` and the `error` callback."""

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
    def has_session(self) -> bool:
        return self.session is not None

    @property
    def models_ready(self) -> bool:
        return self.session is not None and any(
            n.GetAttribute(models.KIND_ATTRIBUTE) == "parenchyma"
            for n in models.model_nodes(self.scene, self.session_id))

    @property
    def threads_alive(self) -> list[threading.Thread]:
        """The watch and reconstruction threads still running (tests: none after close)."""
        self._threads = [t for t in self._threads if t.is_alive()]
        return list(self._threads)

    def _need_session(self):
        if self.session is None:
            raise ValueError("no server session: connect and build the models first")
        return self.session

    def _require_client(self):
        if self.client is None:
            raise ValueError("not connected to a resecta server")
        return self.client

    # --- connection and session ---------------------------------------------------------------

    def connect(self, address: str, token: str | None = None, tls: bool = False,
                ca_file: str | None = None, on_done: Callable | None = None,
                replicas: str | Sequence[str] = ()) -> None:
        """Connects (on the worker) and checks the server; `on_done(server_info)`.

        `replicas`: the other gRPC addresses of a replicated server (a list, or one text with
        them comma-separated, `parse_addresses`), tried when the current one cannot be reached.
        The client follows a session to the replica holding it by itself, retrying on the
        worker and the watch thread (never on the main thread); each move is reported by the
        `status` callback ("Session moved to replica …") and `session_moved(id, address)`."""
        factory = self._client_factory
        if factory is None:
            from resecta_client import Client as factory  # installed on first use in Slicer
        others = [a for a in parse_addresses(replicas) if a != address]

        def moved(session_id: str, at: str) -> None:  # on a worker or the watch thread
            self.dispatcher.call_soon(lambda: self._session_moved(session_id, at))

        def work():
            client = factory(address, token, tls=tls, ca_cert=ca_file or None, replicas=others,
                             on_session_moved=moved)
            try:
                info = client.server_info()
            except BaseException:
                client.close()
                raise
            return client, info

        def done(result):
            self.disconnect()
            self.client, self.server_info = result
            self._status(f"Connected to resecta {self.server_info.server_version} at {address}")

        self.call(work, done, lambda r: on_done(r[1]) if on_done else None)

    def _session_moved(self, session_id: str, address: str) -> None:
        self.moves.append((session_id, address))
        if session_id == self.session_id or self.session is None:
            self._status(f"Session moved to replica {address}")
        self._emit("session_moved", session_id, address)

    def open_session(self, session_id: str, on_done: Callable | None = None) -> None:
        """Follows an existing server session (e.g. after a scene reload)."""
        client = self._require_client()

        def done(sess):
            self._use_session(sess)
            self.start_watch()

        self.call(lambda: client.session(session_id), done, on_done)

    def _use_session(self, sess) -> None:
        if self.session is not None and self.session.id == sess.id:
            self.session = sess
            return
        self._drop_session()
        self.session = sess
        updater = models.ModelUpdater(self.scene, sess.id)
        self.grids = GridSync(self.scene, sess.id, self.edits.drag, self.edits.busy,
                              self._resync_grids)
        self.applier = WatchApplier(updater, self.grids)
        self.traces = traces.TraceSync(
            self.scene, lambda _name, work, on_error: self.edits.send(work, on_error=on_error),
            self.resection)
        self.traces.on_error = self._error
        self.edits.on_answer = self.traces.answer
        self._emit("session")

    def _drop_session(self) -> bool:
        """Stops following the session; True when there was one."""
        self.stop_watch()
        self.edits.coalescer.clear()
        if self.grids is not None:
            self.grids.close()
        if self.traces is not None:
            self.traces.close()
        self.edits.on_answer = None
        had = self.session is not None
        self.session = self.grids = self.applier = self.traces = None
        self.verdicts.clear()
        self._centroids.clear()
        self.model_infos = {}
        self.margin_state = margin.NONE
        self.volume_table = volumetry.EMPTY
        self.metrics_table = ()
        self.resectogram_resection = None
        return had

    def forget_session(self) -> None:
        """Stops following the server session and cancels a running reconstruction (the scene
        was closed); the connection stays and the server keeps the session."""
        self._cancel.set()
        if self._drop_session():
            self._emit("session")
            self._emit("margin", self.margin_state)
            self._emit("volumes", self.volume_table)

    def disconnect(self) -> None:
        """Forgets the session and closes the connection."""
        self.forget_session()
        if self.client is not None:
            self.client.close()
        self.client = self.server_info = None

    def close(self) -> None:
        """Everything ends: session, connection, worker threads (the server keeps the session)."""
        self.disconnect()
        self.dispatcher.shutdown()

    # --- upload and models --------------------------------------------------------------------

    def upload_and_build(self, segmentation_node, role_table: dict[str, str], method: str = "psr",
                         display_name: str = "Slicer", on_done: Callable | None = None,
                         **reconstruct_options) -> None:
        """Merges the segmentation (main thread), then on the worker: creates a session if there
        is none, uploads, reconstructs with progress (`progress`, `model_built` callbacks);
        the watch's snapshot brings the models into the scene. `cancel_build()` cancels."""
        client = self._require_client()
        if self._building:
            raise ValueError("a reconstruction is already running")
        labelmap = segmentation.labelmap_from_segmentation(segmentation_node, role_table)
        self._building = True
        self._cancel.clear()
        existing = self.session
        cancel = self._cancel

        def progress(fraction, stage):
            self.dispatcher.call_soon(lambda: self._emit("progress", fraction, stage))

        def model_built(info):
            self.dispatcher.call_soon(lambda: self._model_built(info))

        def upload():
            sess = existing if existing is not None else client.create_session(display_name)
            summary = sess.upload_label_map(labelmap.labels, labelmap.ijk_to_ras, labelmap.roles)
            return sess, summary

        def uploaded(result):
            sess, summary = result
            if cancel.is_set():
                self._building = False
                return
            self._use_session(sess)
            self.label_map_summary = summary
            self.model_infos = {}
            self._status(f"Label map uploaded ({summary.liver_volume_ml:.1f} ml of liver); "
                         "building models…")
            self.start_watch()
            self._start_thread(lambda: build(sess), "resecta-reconstruct")

        def build(sess):
            try:
                infos = sess.reconstruct(method, progress=progress, cancel=cancel,
                                         on_model=model_built, **reconstruct_options)
            except BaseException as exc:  # noqa: BLE001 - reported on the main thread
                self.dispatcher.call_soon(lambda exc=exc: self._build_failed(exc))
                return
            self.dispatcher.call_soon(lambda: self._build_done(infos, on_done))

        def upload_failed(_exc):
            self._building = False

        self.call(upload, uploaded, on_error=upload_failed)

    def _model_built(self, info) -> None:
        self.model_infos[info.name] = info
        self._emit("model_built", info)

    def _build_done(self, result, on_done) -> None:
        """`result` is the client's `Reconstruction`: the models and the specks left out."""
        self._building = False
        self.model_infos = {i.name: i for i in result}
        text = f"{len(result)} models built"
        specks = sum(d.count for d in result.dropped)
        if specks:
            ml = sum(d.volume_ml for d in result.dropped)
            text += (f"; {specks} fragment(s) under {result.min_component_mm3:g} mm³ left out "
                     f"({ml:.3f} ml)")
        self._status(text)
        if on_done is not None:
            on_done(result)

    def _build_failed(self, exc) -> None:
        self._building = False
        self._error(exc)

    def cancel_build(self) -> None:
        self._cancel.set()

    @property
    def building(self) -> bool:
        return self._building

    # --- watch --------------------------------------------------------------------------------

    def _start_thread(self, target: Callable[[], None], name: str) -> None:
        self._threads.append(self.dispatcher.start_thread(target, name))

    def start_watch(self) -> None:
        """Follows the session on a thread; updates reach the scene on `poll()`."""
        sess = self._need_session()
        if self.watch is not None and self.watch.session.id == sess.id:
            return
        self.stop_watch()
        watch = sess.watch()
        self.watch = watch
        applier = self.applier

        def loop():
            try:
                for update in watch:
                    if applier.enqueue(update):
                        self.dispatcher.call_soon(lambda: self._flush(watch, applier))
            except BaseException as exc:  # noqa: BLE001 - reported on the main thread
                if self.watch is watch:
                    self.dispatcher.call_soon(lambda exc=exc: self._error(exc))

        self._start_thread(loop, "resecta-watch")

    def stop_watch(self) -> None:
        watch, self.watch = self.watch, None
        if watch is not None:
            watch.stop()

    def _flush(self, watch, applier) -> None:
        if self.watch is not watch or self.applier is not applier:
            return  # the session was forgotten meanwhile
        applied = applier.flush(watch.scene)
        for name in applied.remeshed | applied.removed:
            self._centroids.pop(name, None)
        for name in applied.removed:
            self.verdicts.pop(name, None)
        self.verdicts.update(applied.verdicts)
        if applied.models_added_or_removed:
            self._emit("models")
        if applied.resections_added_or_removed or applied.snapshot:
            self._emit("resections")
        self._update_margin()
        if applied.volumes is not None:
            self._set_volumes(applied.volumes)
        self._refresh_resectogram()

    def _set_volumes(self, volumes) -> None:
        self.volume_table = volumetry.table(volumes)
        self._emit("volumes", self.volume_table)
        self.metrics_table = volumetry.metric_rows(volumes, self.resection_kinds())
        self._emit("metrics", self.metrics_table)
        risk.update_cut_vessels(self.scene, getattr(volumes, "risk", None))

    def _update_margin(self) -> None:
        state = margin.indicator(self.verdicts)
        if state != self.margin_state:
            self.margin_state = state
            self._emit("margin", state)

    def _resync_grids(self) -> None:
        if self.watch is not None and self.applier is not None:
            self.applier.resync_grids(self.watch.scene)

    def _edit_done(self, result) -> None:
        for status in result.resections:
            self.verdicts[status.resection.name] = (status.resection.margin_mm, status.verdict)
        for name in result.removed:
            self.verdicts.pop(name, None)
        self._update_margin()

    # --- queries --------------------------------------------------------------------------------

    def surfaces(self) -> dict:
        if self.watch is None:
            return {}
        with self.watch.scene.lock:
            return dict(self.watch.scene.surfaces)

    def tumours(self) -> list[str]:
        return sorted(n for n, s in self.surfaces().items() if models.kind_name(s.kind) == "tumor")

    def resection_names(self) -> list[str]:
        return sorted(n for n, s in self.surfaces().items() if s.is_resection)

    def resection_kinds(self) -> dict[str, str]:
        """Resection name → kind ("bezier", "ds", "cp")."""
        return {n: str(getattr(s.resection, "kind", "bezier")) for n, s in self.surfaces().items()
                if s.is_resection and s.resection is not None}

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
        if self.applier is not None:
            self.applier.updater.set_opacity(tuple(kinds), value)

    # --- resections -----------------------------------------------------------------------------

    def new_resection(self, name: str, tumour: str, end_point, margin_mm: float | None = None,
                      band_mm: float | None = None, grid=(4, 4), on_done: Callable | None = None):
        """Adds resection `name` targeting the tumour model `tumour`, from the end point; its
        control grid appears as a markups node when the watch brings it."""
        from resecta_client import Target

        if name in self.surfaces():
            raise ValueError(f"a surface named {name!r} exists already: choose another name")
        s = self.surfaces().get(tumour)
        if s is None or models.kind_name(s.kind) != "tumor":
            raise ValueError(f"{tumour!r} is not a tumour model")
        centroid = self.tumour_centroid(tumour)
        target = Target(labels=(s.label,) if s.label else (),
                        points=(tuple(float(x) for x in centroid),))
        self.edits.new_resection(name, end_point, target, margin_mm, band_mm, grid, on_done)

    # --- DS and CP resections -------------------------------------------------------------------

    def _target(self, tumour: str | None):
        """The `Target` of tumour model `tumour` (None: every tumour)."""
        if not tumour:
            return None
        from resecta_client import Target

        s = self.surfaces().get(tumour)
        if s is None or models.kind_name(s.kind) != "tumor":
            raise ValueError(f"{tumour!r} is not a tumour model")
        centroid = self.tumour_centroid(tumour)
        return Target(labels=(s.label,) if s.label else (),
                      points=(tuple(float(x) for x in centroid),))

    def new_trace_curve(self, name: str, kind: str):
        """A new markups curve for a trace of resection `name` ("ds": an open curve to draw on
        a slice view; "cp": a closed curve, the ring on the liver model)."""
        self._need_session()
        if not name:
            raise ValueError("the resection needs a name")
        existing = self.resection(name)
        if existing is not None and str(existing.kind) != kind:
            raise ValueError(f"{name!r} is a {volumetry.KIND_LABELS[str(existing.kind)]} "
                             "resection: choose another name")
        return traces.make_curve_node(self.scene, name, kind, self.session_id)

    def use_curve(self, node, tumour: str | None = None, margin_mm: float | None = None,
                  band_mm: float | None = None) -> str:
        """A finished curve becomes a trace (`traces.TraceSync.use_curve`): "added", "held"
        (a DS resection waits for 3 curves) or "created"."""
        self._need_session()
        outcome = self.traces.use_curve(node, margin_mm, band_mm, self._target(tumour))
        name = node.GetAttribute(traces.TRACE_ATTRIBUTE)
        if outcome == "held":
            held = len(self.traces.held(name))
            self._status(f"{name}: {held} of {traces.DS_MIN_TRACES} traces drawn")
        return outcome

    def deformation_handle(self, name: str, point=None):
        """The deformation handle (one-point markups) of CP resection `name`, made when missing
        (at `point`, or the surface's centre)."""
        cls = "vtkMRMLMarkupsFiducialNode"
        for i in range(self.scene.GetNumberOfNodesByClass(cls)):
            node = self.scene.GetNthNodeByClass(i, cls)
            if node.GetAttribute(traces.DEFORMATION_ATTRIBUTE) == name:
                return node
        s = self.surfaces().get(name)
        if point is None and s is not None:
            point = np.asarray(s.positions, float).mean(axis=0)
        return traces.make_handle_node(self.scene, name, point)

    def deform(self, name: str, radius_mm: float, handle=None,
               on_done: Callable | None = None) -> float:
        """Deforms CP resection `name` so that its surface reaches the handle's point, along the
        plane normal, with `radius_mm` of influence; returns the offset sent (mm)."""
        s = self.surfaces().get(name)
        if s is None or s.resection is None or str(s.resection.kind) != "cp":
            raise ValueError(f"{name!r} is not a CP resection")
        handle = handle if handle is not None else self.deformation_handle(name)
        point = traces.handle_point(handle)
        if point is None:
            raise ValueError("place the deformation handle first")
        with self.watch.scene.lock:
            positions = np.array(s.positions, dtype=float)
            normals = np.array(s.normals, dtype=float)
        normal = traces.plane_normal(s.resection.traces, normals)
        offset, _vertex = traces.deformation_offset(point, positions, normal)
        self.edits.add_deformation(name, point, offset, radius_mm, on_done)
        return offset

    def undo_deformation(self, name: str, on_done: Callable | None = None) -> None:
        self.edits.undo_deformation(name, on_done)

    # --- preview ------------------------------------------------------------------------------

    def preview(self, tumour: str | None, end_point) -> Any:
        """Draws (or with None hides) the parenchyma's contour on Algorithm 1's plane."""
        node = self.scene.GetFirstNodeByName(PREVIEW_NODE_NAME)
        parenchyma = next((m for m in models.model_nodes(self.scene, self.session_id)
                           if m.GetAttribute(models.KIND_ATTRIBUTE) == "parenchyma"), None)
        if not tumour or end_point is None or parenchyma is None or self.session is None:
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

    # --- vascular risk ------------------------------------------------------------------------

    def show_risk(self, on_done: Callable | None = None) -> None:
        """Fetches the risk map (worker) and fills the segmentations "Resecta risk" and
        "Resecta territories"; `on_done(RiskMap)`."""
        sess = self._need_session()

        def done(risk_map):
            risk.update_risk(self.scene, risk_map)
            self._status(f"Risk map of plan version {risk_map.plan_version} shown")

        self.call(sess.risk_map, done, on_done)

    def follow_resectogram(self, name: str | None) -> None:
        """Shows resection `name`'s resectogram and keeps it current after plan changes
        (None: stops following; the nodes stay)."""
        self.resectogram_resection = name or None
        self._resectogram_version = -1
        if self.resectogram_resection:
            self._need_session()
            self._refresh_resectogram()

    def _refresh_resectogram(self) -> None:
        """Fetches the followed resectogram when the plan changed since the last request,
        unless one is on its way (its answer asks again)."""
        name, sess, watch = self.resectogram_resection, self.session, self.watch
        if not name or sess is None or watch is None or self._resectogram_busy \
                or watch.scene.plan_version == self._resectogram_version \
                or name not in self.surfaces():
            return
        self._resectogram_busy = True
        self._resectogram_version = watch.scene.plan_version

        def done(gram):
            self._resectogram_busy = False
            if self.session is sess and self.resectogram_resection == gram.resection:
                risk.update_resectogram(self.scene, gram)
                self._emit("resectogram", gram)
            self._refresh_resectogram()

        def failed(_exc):
            self._resectogram_busy = False

        self.call(lambda: sess.resectogram(name), done, on_error=failed)

    def show_resectogram_in(self, layout: str = "Red") -> None:
        """Puts the resectogram into slice view `layout` (MRML: its composite and slice node)."""
        risk.show_resectogram_in(self.scene, layout)

    # --- volumes, plans, exports ----------------------------------------------------------------

    def refresh_volumes(self, on_done: Callable | None = None) -> None:
        sess = self._need_session()

        self.call(sess.volumes, self._set_volumes, on_done)

    def save_plan(self, path, on_done: Callable | None = None) -> None:
        sess = self._need_session()

        def done(text):
            planfile.save(path, text)
            self._status(f"Plan saved to {path}")

        self.call(sess.export_plan, done, on_done)

    def load_plan(self, path, on_done: Callable | None = None) -> None:
        text = planfile.load(path)

        def loaded(version):
            self._status(f"Plan loaded from {path} (version {version})")
            if on_done is not None:
                on_done(version)

        self.edits.import_plan(text, loaded)

    def export_resections(self, folder, fmt: str = "vtp", on_done: Callable | None = None) -> None:
        """Writes every resection's mesh as `<folder>/<name>.<fmt>` (RAS; VTP with margins)."""
        sess = self._need_session()
        names = self.resection_names()
        folder = Path(folder)

        def work():
            out = []
            for name in names:
                path = folder / f"{name}.{fmt}"
                path.write_bytes(sess.export_model(name, fmt, resection=True))
                out.append(path)
            return out

        self.call(work, lambda paths: self._status(
            f"Exported {len(paths)} resection(s) to {folder}"), on_done)
