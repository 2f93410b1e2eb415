"""`Client` (a connection to a resecta server) and `Session` (one planning session: upload,
reconstruction, resection edits, volumes, plans, exports, slices, watch)."""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import grpc
import numpy as np

from . import wire
from ._gen import label_map_pb2, reconstruction_pb2, resection_pb2
from ._gen import planning_service_pb2 as pb
from ._gen import planning_service_pb2_grpc as pb_grpc
from .errors import Cancelled, ResectaError, ServerUnavailable, SessionElsewhere, from_rpc_error
from .geometry import Axes, decompose, label_bytes
from .scene import LiveScene, SceneUpdate
from .types import (
    ControlGroup,
    Deformation,
    EditResult,
    LabelMapSummary,
    LabelSlice,
    Method,
    ModelFormat,
    ModelInfo,
    Point,
    PointCloudSurface,
    Reconstruction,
    Resection,
    ResectionKind,
    Resectogram,
    RiskMap,
    ServerInfo,
    SessionInfo,
    SliceAxis,
    Slices,
    Target,
    Volumes,
    role_map,
    trace_pb,
    vec3,
)

API_VERSION = "v1"
"""The `resecta-api-version` this client speaks."""
CHUNK_BYTES = 4 << 20
"""Data per upload chunk (the server's `MAX_CHUNK_BYTES`)."""
DEFAULT_RECEIVE_BYTES = 4 << 20  # gRPC's default, raised to the server's max_message_bytes

ProgressCallback = Callable[[float, str], None]
"""Called with (fraction done in [0, 1], stage name) during a reconstruction."""
Trace = Any
"""An (n, 3) array-like of RAS mm points: one polyline drawn by the user."""
DEFAULT_MARGIN_MM = 10.0
DEFAULT_BAND_MM = 5.0
DEFAULT_RESOLUTION = (40, 40)
"""The server's defaults for a new resection (the thesis' 40×40 samples)."""
Roles = Mapping[str, "Iterable[int] | int"]
"""Role → label value(s), e.g. ``{"parenchyma": [1], "tumor": [2], "portal": [3]}``."""
TargetLike = Target | Iterable[int] | None
"""A `Target`, or tumour label values, or None for every tumour."""


def _target(t: TargetLike) -> resection_pb2.Target:
    if t is None:
        return resection_pb2.Target()
    return t.to_pb() if isinstance(t, Target) else resection_pb2.Target(labels=[int(x) for x in t])


def _read_pem(ca_cert: str | os.PathLike[str] | bytes | None) -> bytes | None:
    if ca_cert is None or isinstance(ca_cert, bytes):
        return ca_cert
    return Path(ca_cert).read_bytes()


_NOT_CONNECTED = ("failed to connect", "connection refused", "dns resolution failed", "no route to host")


def _not_connected(e: grpc.RpcError) -> bool:
    """Whether a failed call's connection could not be made: the server never saw the call."""
    if not isinstance(e, grpc.Call) or e.code() != grpc.StatusCode.UNAVAILABLE:
        return False
    text = (e.details() or "").lower()
    return any(s in text for s in _NOT_CONNECTED)


class _Tries:
    """The tries of one call (or one stream's reconnections) across the replicas: where to send
    the next one, and whether a failure may be repeated (`Client`'s rules)."""

    def __init__(self, client: Client, session: str | None) -> None:
        self.client, self.session = client, session
        self.address = client.route(session)
        self.start: float | None = None  # the first failure
        self.hops = 0
        self.step = 0
        self.down: set[str] = set()  # found unreachable in this round

    def succeeded(self) -> None:
        """The call was answered at `address`: the session (or the home) is there."""
        if self.client.route(self.session) != self.address:
            self.client._set_route(self.session, self.address)
        self.start, self.hops, self.step, self.down = None, 0, 0, set()

    def again(self, e: grpc.RpcError | None, err: ResectaError, *, read_only: bool) -> bool:
        """After a failed try: whether to try again (at `address`, after any backoff)."""
        if self.start is None:
            self.start = time.monotonic()
        if isinstance(err, SessionElsewhere):
            target = err.replica.grpc_address if err.replica is not None else ""
            if target and target != self.address and target not in self.down:
                self.hops += 1
                if self.session is not None:
                    self.client._set_route(self.session, target)
                if self.hops <= self.client.MAX_HOPS:
                    self.address = target
                    return True
                return self._wait(target)
            # No address (the session just moved: repeat), or a holder just found unreachable
            # (its lease runs on): wait and ask the replica that answered again.
            return self._wait(self.address)
        if err.status != grpc.StatusCode.UNAVAILABLE:
            return False
        if not (read_only or (e is not None and _not_connected(e))):
            return False  # cut mid-call: it may have been applied
        known = self.client._known()
        if len(known) < 2:
            return False  # nowhere else to go: fail fast, as a single server does
        self.down.add(self.address)
        others = [a for a in known if a not in self.down]
        if others:
            return self._go(others[0])
        self.down = set()  # every address failed: wait, then a new round from the route
        return self._wait(self.client.route(self.session))

    def _go(self, address: str) -> bool:
        if time.monotonic() - (self.start or 0.0) > self.client.failover_timeout:
            return False
        self.address = address
        return True

    def _wait(self, address: str) -> bool:
        delay = min(0.05 * 2**self.step, 0.5)
        self.step += 1
        if time.monotonic() + delay - (self.start or 0.0) > self.client.failover_timeout:
            return False
        time.sleep(delay)
        self.address = address
        return True



class Client:
    """A connection to a resecta planning server over gRPC.

    ``Client("127.0.0.1:50051", token=...)``; with ``tls=True`` (implied by `ca_cert`) the
    channel is TLS, verified against `ca_cert` (a PEM file path or PEM bytes; None: the system's
    roots). Every call sends ``authorization: Bearer <token>`` (when a token is given) and
    ``resecta-api-version: v1``; `timeout` (seconds) bounds every unary call, streaming calls
    take their own. The receive limit is raised to the server's ``max_message_bytes`` after the
    first `server_info` (made lazily before the first other call). Use as a context manager or
    call `close`. Thread-safe: one client may serve several threads.

    **Replicated servers** (docs/deployment.md). `address` is the Service (or one replica);
    `replicas` are other gRPC addresses of the same server (replicas, or the Service again) to
    try when the current one cannot be reached. The client keeps a route per session (session id
    → the address of the replica holding it) and one channel per address. A call naming a
    session goes to its route; when that replica answers `SessionElsewhere` with the holder's
    address the client moves the route there and repeats the call (a few hops at most, then with
    a short backoff). When a replica cannot be reached (the connection cannot be made), or a
    redirect names one just found unreachable (a dead holder whose lease has not expired yet),
    it tries the other known addresses with a short backoff for up to `failover_timeout`
    seconds, then raises `ServerUnavailable` (or `SessionElsewhere`). With no other address
    known, an unreachable server fails at once, as before.

    Only calls the server certainly did not apply are repeated: any call refused with
    SESSION_ELSEWHERE, any call whose connection could not be made, and read-only calls
    (reads, exports, watches) always. An edit, plan import, upload or delete whose connection
    broke after it was sent is raised as `ServerUnavailable`: it may or may not have been
    applied, so re-read the session (`Session.info()` or a watch: the plan version tells)
    before sending it again. `on_session_moved(session_id, address)` (optional) is called
    from the calling thread whenever a session's route changes; `routes()` lists them.

    `api_version` is for tests of the server's version check; leave it alone.
    """

    MAX_HOPS = 4
    """Redirects followed at once in one call; further ones wait a backoff step each."""

    def __init__(
        self,
        address: str,
        token: str | None = None,
        *,
        tls: bool = False,
        ca_cert: str | os.PathLike[str] | bytes | None = None,
        timeout: float = 30.0,
        api_version: str = API_VERSION,
        replicas: Sequence[str] = (),
        failover_timeout: float = 15.0,
        on_session_moved: Callable[[str, str], None] | None = None,
    ) -> None:
        if isinstance(replicas, str):
            replicas = [a for a in (x.strip() for x in replicas.split(",")) if a]
        self.address = address
        self.replicas: tuple[str, ...] = tuple(a for a in dict.fromkeys(replicas) if a != address)
        self.failover_timeout = failover_timeout
        self.on_session_moved = on_session_moved
        self.timeout = timeout
        self.tls = tls or ca_cert is not None
        self._root_certs = _read_pem(ca_cert)
        self._metadata: tuple[tuple[str, str], ...] = (("resecta-api-version", api_version),)
        if token:
            self._metadata += (("authorization", f"Bearer {token}"),)
        self._lock = threading.Lock()
        self._boot = threading.Lock()
        self._retired: list[grpc.Channel] = []  # channels replaced by a larger receive limit
        self._info: ServerInfo | None = None
        self._receive = DEFAULT_RECEIVE_BYTES
        self._channels: dict[str, tuple[grpc.Channel, pb_grpc.PlanningServiceStub]] = {}
        self._routes: dict[str, str] = {}  # session id -> the address of the replica holding it
        self._learned: list[str] = []  # addresses named by redirects
        self._home = address  # where calls naming no session go: the last address that answered
        self._closed = False

    # --- plumbing ---------------------------------------------------------------------------

    def _open(self, receive_bytes: int, address: str | None = None) -> grpc.Channel:
        options = [
            ("grpc.max_receive_message_length", receive_bytes),
            ("grpc.max_send_message_length", max(receive_bytes, CHUNK_BYTES + (1 << 20))),
        ]
        target = self.address if address is None else address
        if self.tls:
            creds = grpc.ssl_channel_credentials(root_certificates=self._root_certs)
            return grpc.secure_channel(target, creds, options=options)
        return grpc.insecure_channel(target, options=options)

    def _stub_at(self, address: str) -> pb_grpc.PlanningServiceStub:
        """The stub of the channel to `address` (opened on first use, with the receive limit)."""
        with self._lock:
            if self._closed:
                raise ValueError("the client is closed")
            held = self._channels.get(address)
            if held is None:
                channel = self._open(self._receive, address)
                held = self._channels[address] = (channel, pb_grpc.PlanningServiceStub(channel))
            return held[1]

    @property
    def _stub(self) -> pb_grpc.PlanningServiceStub:
        return self._stub_at(self._home)

    def _known(self) -> list[str]:
        """Every address this client knows of, the configured ones first."""
        with self._lock:
            return list(dict.fromkeys([self.address, *self.replicas, *self._learned, *self._routes.values()]))

    def route(self, session_id: str | None) -> str:
        """The address calls naming `session_id` go to now (its holder, as far as known)."""
        with self._lock:
            if session_id is not None and session_id in self._routes:
                return self._routes[session_id]
            return self._home

    def routes(self) -> dict[str, str]:
        """Session id → the replica address this client follows it to (sessions it called)."""
        with self._lock:
            return dict(self._routes)

    def _set_route(self, session_id: str | None, address: str) -> None:
        moved = False
        with self._lock:
            if address not in (self.address, *self.replicas) and address not in self._learned:
                self._learned.append(address)
            if session_id is None:
                self._home = address
            else:
                moved = self._routes.get(session_id, self._home) != address
                self._routes[session_id] = address
        if moved and self.on_session_moved is not None:
            try:
                self.on_session_moved(session_id, address)  # type: ignore[arg-type]
            except Exception:  # a listener's bug must not fail the call
                pass

    def _ready(self) -> pb_grpc.PlanningServiceStub:
        """The stub, after the receive limit has been raised to the server's."""
        if self._info is None:
            with self._boot:
                if self._info is None:
                    self.server_info()
        return self._stub

    def _call(
        self,
        method: str,
        request: Any,
        *,
        timeout: float | None = None,
        session: str | None = None,
        read_only: bool = False,
        boot: bool = True,
    ) -> Any:
        """A unary call with the client's metadata, sent to `session`'s route and repeated
        elsewhere when the server certainly did not apply it (see the class); gRPC errors
        become `ResectaError`s."""
        if boot:
            self._ready()
        tries = _Tries(self, session)
        wait = self.timeout if timeout is None else timeout
        while True:
            try:
                stub = self._stub_at(tries.address)
                r = getattr(stub, method)(request, metadata=self._metadata, timeout=wait)
            except grpc.RpcError as e:
                err = from_rpc_error(e)
                if tries.again(e, err, read_only=read_only):
                    continue
                raise err from None
            tries.succeeded()
            return r

    def _stream(
        self, method: str, request: Any, *, timeout: float | None = None, address: str | None = None
    ) -> Any:
        """A server-streaming call (an iterator that is also a `grpc.Call`) at `address` (the
        home address by default)."""
        self._ready()
        stub = self._stub if address is None else self._stub_at(address)
        return getattr(stub, method)(request, metadata=self._metadata, timeout=timeout)

    def close(self) -> None:
        """Closes the channels (open streams end with `Cancelled`)."""
        with self._lock:
            self._closed = True
            channels = [*self._retired, *(c for c, _ in self._channels.values())]
            self._retired, self._channels = [], {}
        for channel in channels:
            channel.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- server and sessions ----------------------------------------------------------------

    def server_info(self) -> ServerInfo:
        """The server's version, API version, capabilities and limits (a fresh call). Raises
        `ServerUnavailable` when the server cannot be reached, `AuthError` on a bad token."""
        r = self._call("GetServerInfo", pb.GetServerInfoRequest(), read_only=True, boot=False)
        info = ServerInfo.from_pb(r)
        with self._lock:
            self._info = info
            wanted = info.limits.max_message_bytes
            if wanted > self._receive:
                # Calls in flight on the old channels finish there; they close with the client.
                self._retired += [c for c, _ in self._channels.values()]
                self._receive, self._channels = wanted, {}
        return info

    def create_session(self, display_name: str = "") -> Session:
        """A new empty session. Do not put patient identifiers in `display_name` on a shared
        server. Raises `QuotaExceeded` beyond the server's session quota."""
        r = self._call("CreateSession", pb.CreateSessionRequest(display_name=display_name))
        with self._lock:  # the replica that made it holds it
            self._routes.setdefault(r.session.id, self._home)
        return Session(self, SessionInfo.from_pb(r.session))

    def list_sessions(self) -> list[SessionInfo]:
        """Every session, most recently used first."""
        r = self._call("ListSessions", pb.ListSessionsRequest(), read_only=True)
        return [SessionInfo.from_pb(s) for s in r.sessions]

    def get_session(self, session_id: str) -> SessionInfo:
        """One session's metadata (`SessionNotFound` for an unknown or expired id)."""
        return SessionInfo.from_pb(
            self._call(
                "GetSession", pb.GetSessionRequest(session_id=session_id), session=session_id, read_only=True
            ).session
        )

    def session(self, session_id: str) -> Session:
        """A handle on an existing session (checked: `SessionNotFound` otherwise)."""
        return Session(self, self.get_session(session_id))

    def delete_session(self, session_id: str) -> None:
        """Deletes a session with its label map, models and plan."""
        self._call("DeleteSession", pb.DeleteSessionRequest(session_id=session_id), session=session_id)
        with self._lock:
            self._routes.pop(session_id, None)

    # --- point clouds -------------------------------------------------------------------------

    def reconstruct_points(
        self,
        positions: Any,
        normals: Any = None,
        depth: int = 5,
        neighbours: int = 10,
        *,
        allow_zstd: bool | None = None,
        allow_quantized: bool = False,
        timeout: float | None = None,
    ) -> PointCloudSurface:
        """The closed surface of a point cloud, e.g. the points a mapping catheter collected on
        an atrium (thesis ch. 9). Needs no session; the server keeps nothing.

        `positions`: (n, 3) array-like of RAS mm points (or their x, y, z values interleaved
        in one flat array); `normals`: outward normals likewise, one per point, of any non-zero
        length, or None to have the server estimate them (local PCA, oriented outward).
        `depth`: screened Poisson depth, the finest grid having 2^depth cells across the
        points' bounding cube (1..=`ServerLimits.max_cloud_depth`, 8 by default; 5 suits a few
        hundred catheter points, 6–7 denser clouds); `neighbours`: points per neighbourhood
        for the normals and point areas (3..=64, fewer than the distinct points).

        Returns a `PointCloudSurface`: positions, normals and triangles as numpy arrays (the
        `RSMS` mesh decoded by `wire.decode_mesh`), the enclosed volume and the server's
        `PointCloudReport`. Raises `InvalidArgument` for a malformed cloud (NaN, a length that
        is not a multiple of 3, normals not one per point, fewer than 4 distinct points, all
        points on one line) or one beyond the server's limits, `QuotaExceeded` when the
        server's memory budget has no room for the grid. Compressed meshes are asked for when
        the `zstandard` package is importable (`allow_zstd`), quantised ones only with
        `allow_quantized`. `timeout` defaults to the client's, at least 300 s."""

        def flat(name: str, values: Any) -> list[float]:
            a = np.asarray(values, dtype=np.float64)
            if a.ndim > 2 or (a.ndim == 2 and a.shape[1] != 3):
                raise ValueError(f"{name}: expected an (n, 3) array or a flat one, got shape {a.shape}")
            return a.reshape(-1).tolist()

        request = pb.ReconstructPointsRequest(
            positions=flat("positions", positions),
            normals=[] if normals is None else flat("normals", normals),
            depth=int(depth),
            neighbours=int(neighbours),
            allow_zstd=wire.ZSTD_AVAILABLE if allow_zstd is None else allow_zstd,
            allow_quantized=allow_quantized,
        )
        wait = max(self.timeout, 300.0) if timeout is None else timeout
        return PointCloudSurface.from_pb(
            self._call("ReconstructPoints", request, timeout=wait, read_only=True)  # keeps nothing
        )


class Session:
    """One planning session on the server, and this client's last known plan version.

    Edits send `base_version` = the last plan version this handle saw (from its own calls and
    from its watches), so that an edit made while someone else changed the plan fails with
    `StaleVersion` instead of overwriting it; pass ``base_version=0`` to skip the check, or an
    explicit version. Every edit returns an `EditResult` and advances `plan_version`.
    """

    def __init__(self, client: Client, info: SessionInfo) -> None:
        self.client = client
        self.id = info.id
        self._lock = threading.Lock()
        self._info = info
        self._version = info.plan_version
        self._read: dict[str, Any] = {"session": self.id, "read_only": True}

    def __repr__(self) -> str:
        return f"Session(id={self.id!r}, plan_version={self.plan_version})"

    @property
    def plan_version(self) -> int:
        """The last plan version this handle saw."""
        return self._version

    @plan_version.setter
    def plan_version(self, version: int) -> None:
        with self._lock:
            self._version = version

    def _saw(self, version: int) -> None:
        with self._lock:
            self._version = max(self._version, version)

    def info(self) -> SessionInfo:
        """The session's metadata now; resets `plan_version` to the server's."""
        info = self.client.get_session(self.id)
        with self._lock:
            self._info, self._version = info, info.plan_version
        return info

    def delete(self) -> None:
        """Deletes the session on the server."""
        self.client.delete_session(self.id)

    # --- label map ----------------------------------------------------------------------------

    def _upload(self, first: pb.UploadLabelMapRequest, data: bytes | memoryview) -> LabelMapSummary:
        view = memoryview(data)

        def chunks() -> Iterator[pb.UploadLabelMapRequest]:
            yield first
            for k in range(0, len(view), CHUNK_BYTES):
                yield pb.UploadLabelMapRequest(data=bytes(view[k : k + CHUNK_BYTES]))

        # Repeated (from the first chunk) only when refused with SESSION_ELSEWHERE or not
        # connected: the server accepted none of it.
        self.client._ready()
        tries = _Tries(self.client, self.id)
        while True:
            try:
                r = self.client._stub_at(tries.address).UploadLabelMap(
                    chunks(), metadata=self.client._metadata, timeout=max(self.client.timeout, 600)
                )
            except grpc.RpcError as e:
                err = from_rpc_error(e)
                if tries.again(e, err, read_only=False):
                    continue
                raise err from None
            tries.succeeded()
            break
        self.info()
        return LabelMapSummary.from_pb(r.label_map)

    def upload_label_map(
        self, labels: Any, ijk_to_ras: Any, roles: Roles, *, axes: Axes = "kji"
    ) -> LabelMapSummary:
        """Uploads a label map from a 3-D integer array indexed [k, j, i] (Slicer's
        `arrayFromVolume` layout; ``axes="ijk"`` for [i, j, k]) with its 4×4 IJK→RAS matrix
        (array-like or vtkMatrix4x4; oblique, anisotropic and flipped grids are fine) and the role
        map. Replaces the session's label map (models must be rebuilt) and returns the server's
        summary. See `resecta_client.geometry` for the conventions."""
        origin, spacing, direction = decompose(ijk_to_ras)
        dims, data_type, data = label_bytes(labels, axes)
        header = label_map_pb2.RawLabelMapHeader(
            session_id=self.id,
            dims=list(dims),
            spacing=list(spacing),
            origin=list(origin),
            direction=direction.reshape(-1).tolist(),
            data_type=data_type,
            roles=role_map(roles),
            total_bytes=len(data),
        )
        return self._upload(pb.UploadLabelMapRequest(raw=header), data)

    def upload_label_map_file(
        self, file: str | os.PathLike[str] | bytes, roles: Roles, *, format: str = "auto"
    ) -> LabelMapSummary:
        """Uploads a label-map file (a path, or its bytes): NIfTI (``.nii``/``.nii.gz``), NRRD,
        Slicer ``.seg.nrrd`` or MetaImage ``.mha``; `format` ``"auto"`` (detected from the
        bytes), ``"nifti"``, ``"nrrd"``, ``"seg_nrrd"`` or ``"metaimage"``."""
        data = file if isinstance(file, bytes) else Path(file).read_bytes()
        name = f"LABEL_MAP_FORMAT_{format.upper()}"
        if name not in label_map_pb2.LabelMapFormat.keys() or name.endswith("UNSPECIFIED"):
            raise ValueError(f"unknown label-map format {format!r}")
        header = label_map_pb2.FileLabelMapHeader(
            session_id=self.id,
            format=label_map_pb2.LabelMapFormat.Value(name),
            roles=role_map(roles),
            total_bytes=len(data),
        )
        return self._upload(pb.UploadLabelMapRequest(file=header), data)

    # --- reconstruction -----------------------------------------------------------------------

    def reconstruct(
        self,
        method: Method | str = Method.PSR,
        *,
        psr_depth: int | None = None,
        smoothing: float | None = None,
        decimation: float | None = None,
        split_components: bool | None = None,
        min_component_mm3: float | None = None,
        progress: ProgressCallback | None = None,
        on_model: Callable[[ModelInfo], None] | None = None,
        cancel: threading.Event | None = None,
        timeout: float | None = None,
    ) -> Reconstruction:
        """Builds the surface models of the label map and returns them once all are built: one
        per vessel label (segment) and per tumour component, or per vessel component with
        `split_components`; components below `min_component_mm3` (vessels; server default 10)
        or 10 mm³ (tumours, as the planning targets) get no model and are counted in the
        result's `dropped`. Absent options take the server's defaults.

        `progress(fraction, stage)` is called for every progress event and `on_model(info)` for
        every model as it comes, from this thread (an exception from them cancels the work and
        propagates). Setting `cancel` (from any thread) cancels the work on the server, which
        keeps the previous models, and raises `Cancelled`.
        `FailedPrecondition` without a label map."""
        options = reconstruction_pb2.ReconstructOptions(
            psr_depth=psr_depth,
            smoothing=smoothing,
            decimation=decimation,
            split_components=split_components,
            min_component_mm3=min_component_mm3,
        )
        request = pb.ReconstructRequest(
            session_id=self.id, method=Method.parse(method).to_pb(), options=options
        )
        tries = _Tries(self.client, self.id)
        call = self.client._stream("Reconstruct", request, timeout=timeout, address=tries.address)
        done = threading.Event()
        if cancel is not None:

            def canceller() -> None:
                while not done.is_set():
                    if cancel.wait(0.05):
                        call.cancel()
                        return

            threading.Thread(target=canceller, name="resecta-reconstruct-cancel", daemon=True).start()
        models: list[ModelInfo] = []
        done_event = reconstruction_pb2.ReconstructDone()
        pending: grpc.RpcError | None = None
        while True:  # reopened at the holder when refused before any event (SESSION_ELSEWHERE)
            try:
                first = next(call, None)
            except grpc.RpcError as e:
                if not (cancel is not None and cancel.is_set()) and tries.again(
                    e, from_rpc_error(e), read_only=False
                ):
                    call = self.client._stream("Reconstruct", request, timeout=timeout, address=tries.address)
                    continue
                first, pending = None, e
            else:
                tries.succeeded()
            break

        def events() -> Iterator[Any]:
            if pending is not None:
                raise pending
            if first is not None:
                yield first
                yield from call

        try:
            for event in events():
                kind = event.WhichOneof("event")
                if kind == "progress" and progress is not None:
                    progress(event.progress.fraction, event.progress.stage)
                elif kind == "model":
                    models.append(ModelInfo.from_pb(event.model))
                    if on_model is not None:
                        on_model(models[-1])
                elif kind == "done":
                    done_event = event.done
                    if progress is not None:
                        progress(1.0, "done")
        except grpc.RpcError as e:
            err = from_rpc_error(e)
            if cancel is not None and cancel.is_set():
                raise Cancelled(
                    "reconstruction cancelled", code="CANCELLED", status=grpc.StatusCode.CANCELLED
                ) from None
            raise err from None
        finally:
            done.set()
            call.cancel()  # a no-op after `done`; stops the server's work if a callback raised
        return Reconstruction.from_pb(models, done_event)

    # --- resection edits ----------------------------------------------------------------------

    def _edit(self, base_version: int | None, **op: Any) -> EditResult:
        base = self.plan_version if base_version is None else base_version
        r = EditResult.from_pb(
            self.client._call(
                "Edit", pb.EditRequest(session_id=self.id, base_version=base, **op), session=self.id
            )
        )
        self._saw(r.plan_version)
        return r

    def init_from_end_point(
        self,
        name: str,
        end_point: Point,
        *,
        target: TargetLike = None,
        grid: tuple[int, int] = (4, 4),
        base_version: int | None = None,
    ) -> EditResult:
        """Adds a resection from an end point (thesis Alg. 1–2): the plane halfway between the
        target tumour's centroid and `end_point`, and a planar m×n control grid over the
        liver's contour on it."""
        op = resection_pb2.InitFromEndPoint(
            name=name, target=_target(target), end_point=vec3(end_point), grid_m=grid[0], grid_n=grid[1]
        )
        return self._edit(base_version, init_from_end_point=op)

    def init_from_plane(
        self,
        name: str,
        plane_point: Point,
        plane_normal: Point,
        *,
        target: TargetLike = None,
        grid: tuple[int, int] = (4, 4),
        base_version: int | None = None,
    ) -> EditResult:
        """Adds a resection on a plane (its normal pointing away from the tumour)."""
        op = resection_pb2.InitFromPlane(
            name=name,
            target=_target(target),
            plane_point=vec3(plane_point),
            plane_normal=vec3(plane_normal),
            grid_m=grid[0],
            grid_n=grid[1],
        )
        return self._edit(base_version, init_from_plane=op)

    def set_control_point(
        self, name: str, i: int, j: int, point: Point, *, base_version: int | None = None
    ) -> EditResult:
        """Moves control point P_ij (row i along u, column j along v) to `point`."""
        op = resection_pb2.SetControlPoint(name=name, i=i, j=j, point=vec3(point))
        return self._edit(base_version, set_control_point=op)

    def set_control_points(self, name: str, points: Any, *, base_version: int | None = None) -> EditResult:
        """Replaces every control point: an (m, n, 3) or (m·n, 3) array, row-major (entry
        i·n + j is P_ij)."""
        import numpy as np

        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        op = resection_pb2.SetControlPoints(name=name, points=[vec3(p) for p in pts])
        return self._edit(base_version, set_control_points=op)

    def move_group(
        self,
        name: str,
        delta: Point,
        *,
        group: ControlGroup | str | None = None,
        ring: int | None = None,
        base_version: int | None = None,
    ) -> EditResult:
        """Moves a group of control points by `delta`: a named `group` (``"inner"``,
        ``"outer"``, ``"all"``) or `ring` k (the points k grid steps from the border)."""
        if (group is None) == (ring is None):
            raise ValueError("move_group needs exactly one of group= and ring=")
        sel: dict[str, Any] = (
            {"ring": ring} if group is None else {"group": ControlGroup.parse(group).to_pb()}
        )
        return self._edit(
            base_version, move_group=resection_pb2.MoveGroup(name=name, delta=vec3(delta), **sel)
        )

    def translate(self, name: str, delta: Point, *, base_version: int | None = None) -> EditResult:
        """Moves the whole surface by `delta` (mm)."""
        return self._edit(base_version, translate=resection_pb2.Translate(name=name, delta=vec3(delta)))

    def rotate(
        self,
        name: str,
        axis: Point,
        angle_deg: float,
        *,
        centre: Point | None = None,
        base_version: int | None = None,
    ) -> EditResult:
        """Rotates every control point by `angle_deg` (right-handed) about `axis` through
        `centre` (default: the control points' centroid)."""
        op = resection_pb2.Rotate(name=name, axis=vec3(axis), angle_deg=angle_deg)
        if centre is not None:
            op.centre.CopyFrom(vec3(centre))
        return self._edit(base_version, rotate=op)

    def set_margin(self, name: str, margin_mm: float, *, base_version: int | None = None) -> EditResult:
        """Sets the safety margin, mm, in (0, 100]."""
        return self._edit(base_version, set_margin=resection_pb2.SetMargin(name=name, margin_mm=margin_mm))

    def set_band(self, name: str, band_mm: float, *, base_version: int | None = None) -> EditResult:
        """Sets the warning band beyond the margin, mm, in [0, 100]."""
        return self._edit(base_version, set_band=resection_pb2.SetBand(name=name, band_mm=band_mm))

    def set_resolution(self, name: str, ru: int, rv: int, *, base_version: int | None = None) -> EditResult:
        """Sets the surface samples along u and v (2..=500 each)."""
        return self._edit(base_version, set_resolution=resection_pb2.SetResolution(name=name, ru=ru, rv=rv))

    def set_target(self, name: str, target: TargetLike, *, base_version: int | None = None) -> EditResult:
        """Replaces the target tumours (None: every tumour)."""
        return self._edit(base_version, set_target=resection_pb2.SetTarget(name=name, target=_target(target)))

    def delete_resection(self, name: str, *, base_version: int | None = None) -> EditResult:
        """Removes a resection from the plan."""
        return self._edit(base_version, delete_resection=resection_pb2.DeleteResection(name=name))

    def add_resection(self, resection: Resection, *, base_version: int | None = None) -> EditResult:
        """Adds `resection` exactly as given (any kind; e.g. one an earlier answer holds)."""
        return self._edit(base_version, add_resection=resection_pb2.AddResection(resection=resection.to_pb()))

    def _add_traced(
        self,
        kind: ResectionKind,
        name: str,
        traces: Iterable[Trace],
        deformations: Iterable[Deformation],
        target: TargetLike,
        margin_mm: float,
        band_mm: float,
        resolution: tuple[int, int],
        base_version: int | None,
    ) -> EditResult:
        op = resection_pb2.Resection(
            name=name,
            kind=kind.to_pb(),
            traces=[trace_pb(t) for t in traces],
            deformations=[d.to_pb() for d in deformations],
            margin_mm=margin_mm,
            band_mm=band_mm,
            target=_target(target),
            ru=resolution[0],
            rv=resolution[1],
        )
        return self._edit(base_version, add_resection=resection_pb2.AddResection(resection=op))

    def add_ds(
        self,
        name: str,
        traces: Iterable[Trace],
        *,
        target: TargetLike = None,
        margin_mm: float = DEFAULT_MARGIN_MM,
        band_mm: float = DEFAULT_BAND_MM,
        resolution: tuple[int, int] = DEFAULT_RESOLUTION,
        base_version: int | None = None,
    ) -> EditResult:
        """Adds a resection drawn on slices (DS): 3..=32 traces of ≥ 3 points, each on its own
        axial (constant S), coronal (constant A) or sagittal (constant R) slice, all of one
        orientation; the surface spans the first to the last trace's slice."""
        return self._add_traced(
            ResectionKind.DS, name, traces, (), target, margin_mm, band_mm, resolution, base_version
        )

    def add_cp(
        self,
        name: str,
        traces: Iterable[Trace],
        deformations: Iterable[Deformation] = (),
        *,
        target: TargetLike = None,
        margin_mm: float = DEFAULT_MARGIN_MM,
        band_mm: float = DEFAULT_BAND_MM,
        resolution: tuple[int, int] = DEFAULT_RESOLUTION,
        base_version: int | None = None,
    ) -> EditResult:
        """Adds a deformable cutting plane (CP): the PCA plane of the traces (typically a ring
        drawn on the liver surface) with a grid fitted to them, then `deformations` in order."""
        return self._add_traced(
            ResectionKind.CP, name, traces, deformations, target, margin_mm, band_mm, resolution, base_version
        )

    def add_trace(self, name: str, trace: Trace, *, base_version: int | None = None) -> EditResult:
        """Appends a trace to a DS or CP resection."""
        op = resection_pb2.AddTrace(name=name, trace=trace_pb(trace))
        return self._edit(base_version, add_trace=op)

    def set_trace(
        self, name: str, index: int, trace: Trace, *, base_version: int | None = None
    ) -> EditResult:
        """Redraws trace `index` (0-based, in the resection's order) of a DS or CP resection."""
        op = resection_pb2.SetTrace(name=name, index=index, trace=trace_pb(trace))
        return self._edit(base_version, set_trace=op)

    def remove_trace(self, name: str, index: int, *, base_version: int | None = None) -> EditResult:
        """Removes trace `index` of a DS or CP resection (a DS resection keeps at least 3)."""
        return self._edit(base_version, remove_trace=resection_pb2.RemoveTrace(name=name, index=index))

    def add_deformation(
        self,
        name: str,
        point: Point,
        offset_mm: float,
        radius_mm: float,
        *,
        base_version: int | None = None,
    ) -> EditResult:
        """Deforms a CP resection: the grid vertex nearest `point` moves `offset_mm` (±100)
        along the plane normal, its neighbours within `radius_mm` (0, 200] with a cosine
        falloff."""
        d = resection_pb2.Deformation(point=vec3(point), offset_mm=offset_mm, radius_mm=radius_mm)
        op = resection_pb2.AddDeformation(name=name, deformation=d)
        return self._edit(base_version, add_deformation=op)

    def undo_deformation(self, name: str, *, base_version: int | None = None) -> EditResult:
        """Takes back the last deformation of a CP resection."""
        return self._edit(base_version, undo_deformation=resection_pb2.UndoDeformation(name=name))

    def undo(self, *, base_version: int | None = None) -> EditResult:
        """Takes back the session's last edit (any resection's; `FailedPrecondition`
        NOTHING_TO_UNDO when there is none)."""
        return self._edit(base_version, undo=resection_pb2.Undo())

    def redo(self, *, base_version: int | None = None) -> EditResult:
        """Restores the last undone edit (NOTHING_TO_REDO when there is none)."""
        return self._edit(base_version, redo=resection_pb2.Redo())

    # --- volumes, plans, exports, slices ------------------------------------------------------

    def volumes(self, *, timeout: float | None = None) -> Volumes:
        """Resected and remnant volumes of the current plan."""
        r = self.client._call(
            "GetVolumes", pb.GetVolumesRequest(session_id=self.id), timeout=timeout, **self._read
        )
        return Volumes.from_pb(r.volumes, r.plan_version)

    def export_plan(self) -> str:
        """The current plan as `resecta-plan/1` JSON text."""
        r = self.client._call("ExportPlan", pb.ExportPlanRequest(session_id=self.id), **self._read)
        self._saw(r.plan_version)
        return str(r.plan_json)

    def import_plan(self, plan: str | Mapping[str, Any], *, base_version: int | None = None) -> int:
        """Replaces the plan by a `resecta-plan/1` document (JSON text or a dict); one undoable
        edit with the same `base_version` rule as the edits. Returns the new plan version."""
        text = plan if isinstance(plan, str) else json.dumps(plan)
        base = self.plan_version if base_version is None else base_version
        r = self.client._call(
            "ImportPlan",
            pb.ImportPlanRequest(session_id=self.id, plan_json=text, base_version=base),
            session=self.id,
        )
        self._saw(r.plan_version)
        return int(r.plan_version)

    def export_model(
        self,
        name: str,
        format: ModelFormat | str = ModelFormat.VTP,
        *,
        resection: bool = False,
        timeout: float | None = None,
    ) -> bytes:
        """A model's (or with ``resection=True`` a resection's) mesh as the bytes of a file in
        `format` (``"vtp"``, ``"vtk"``, ``"stl"``, ``"ply"``, ``"obj"``; RAS coordinates)."""
        which = {"resection": name} if resection else {"model": name}
        request = pb.ExportModelRequest(session_id=self.id, format=ModelFormat.parse(format).to_pb(), **which)
        tries = _Tries(self.client, self.id)
        while True:  # read-only: repeated from the start wherever it broke
            out = bytearray()
            try:
                wait = timeout or max(self.client.timeout, 120)
                for chunk in self.client._stream("ExportModel", request, timeout=wait, address=tries.address):
                    out += chunk.data
            except grpc.RpcError as e:
                err = from_rpc_error(e)
                if tries.again(e, err, read_only=True):
                    continue
                raise err from None
            tries.succeeded()
            return bytes(out)

    def slices(
        self,
        name: str,
        *,
        axial: float | None = None,
        coronal: float | None = None,
        sagittal: float | None = None,
        resection: bool = False,
    ) -> Slices:
        """Contours of a model (or resection) on the axial (RAS z), coronal (y) and sagittal (x)
        planes given."""
        which = {"resection": name} if resection else {"model": name}
        request = pb.GetSlicesRequest(
            session_id=self.id, axial=axial, coronal=coronal, sagittal=sagittal, **which
        )
        return Slices.from_pb(self.client._call("GetSlices", request, **self._read))

    def label_slice(
        self, axis: str | SliceAxis, position_mm: float, *, pixel_mm: float | None = None
    ) -> LabelSlice:
        """One plane of the label map as a raster of labels: `axis` ``"axial"`` (RAS z =
        `position_mm`), ``"coronal"`` (y) or ``"sagittal"`` (x); pixels of `pixel_mm` (default:
        the smallest voxel spacing), coarsened to at most `max_label_slice_side` per side."""
        request = pb.GetLabelSliceRequest(
            session_id=self.id,
            axis=SliceAxis.parse(axis).to_pb(),
            position_mm=position_mm,
            pixel_mm=pixel_mm,
        )
        return LabelSlice.from_pb(self.client._call("GetLabelSlice", request, **self._read))

    def resectogram(self, name: str, width: int = 200, height: int = 200) -> Resectogram:
        """Resection `name` unrolled to its (u, v) square at `width`×`height` pixels (each
        1..=`max_resectogram_side`): margin classes, portal territories, cut vessels, worst point."""
        request = pb.GetResectogramRequest(session_id=self.id, resection=name, width=width, height=height)
        return Resectogram.from_pb(self.client._call("GetResectogram", request, **self._read))

    def risk_map(self, *, timeout: float | None = None) -> RiskMap:
        """The plan's risk per voxel of the functional liver with the portal territories
        (`FailedPrecondition` without vessels or while a cut is incomplete); needs `zstandard`."""
        r = self.client._call(
            "GetRiskMap", pb.GetRiskMapRequest(session_id=self.id), timeout=timeout, **self._read
        )
        return RiskMap.from_pb(r)

    # --- watch --------------------------------------------------------------------------------

    def watch(
        self,
        *,
        since_seq: int | None = None,
        scene: LiveScene | None = None,
        allow_zstd: bool | None = None,
        allow_quantized: bool = False,
        reconnect: int = 3,
    ) -> Watch:
        """Follows the session: an iterator of `SceneUpdate`s, applied to `Watch.scene` before
        each is yielded. See `Watch`."""
        return Watch(
            self,
            since_seq=since_seq,
            scene=scene,
            allow_zstd=allow_zstd,
            allow_quantized=allow_quantized,
            reconnect=reconnect,
        )


class Watch:
    """An iterator over a session's Watch stream, applying every event to `scene` (a
    `LiveScene`, new or given) and yielding what changed (`SceneUpdate`).

    It starts with a snapshot, or, with `since_seq` and the `scene` built so far, with the
    events after that sequence number (the server sends a snapshot instead when it no longer
    has them). When the connection drops (UNAVAILABLE) it reconnects up to `reconnect` times in
    a row with ``since_seq = scene.seq``; on a replicated server, when the stream ends because
    the session moved (SESSION_ELSEWHERE) or its replica died, it reopens at the new holder
    (trying the client's other addresses for up to `Client.failover_timeout` meanwhile), resuming
    after ``scene.seq``: the new replica sends a fresh snapshot, which the iteration yields;
    when a delta does not fit the scene it asks for a fresh snapshot, and a snapshot that does
    not decode raises `wire.WireError`. `stop()` ends the iteration from any thread (the blocked
    `next` returns with StopIteration). Plan versions seen advance the session's `plan_version`. Compressed
    payloads are asked for when the `zstandard` package is importable (`allow_zstd`), quantised
    ones only with `allow_quantized`.
    """

    def __init__(
        self,
        session: Session,
        *,
        since_seq: int | None = None,
        scene: LiveScene | None = None,
        allow_zstd: bool | None = None,
        allow_quantized: bool = False,
        reconnect: int = 3,
    ) -> None:
        self.session = session
        self.scene = scene if scene is not None else LiveScene()
        self._since = since_seq
        self._zstd = wire.ZSTD_AVAILABLE if allow_zstd is None else allow_zstd
        self._quantized = allow_quantized
        self._reconnect = reconnect
        self._lock = threading.Lock()
        self._stopped = threading.Event()
        self._call: Any = None
        self._tries: _Tries | None = None  # where the stream is, and its failovers
        self._fresh = False  # no message yet on the stream opened last
        self.reconnects = 0
        """How many times the stream was reopened after a dropped connection."""

    @property
    def last_seq(self) -> int | None:
        """The `seq` of the last applied event (resume from it with ``since_seq``)."""
        return self.scene.seq

    def __iter__(self) -> Watch:
        return self

    def __enter__(self) -> Watch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        """Ends the iteration; safe from any thread, and more than once."""
        with self._lock:
            self._stopped.set()
            call = self._call
        if call is not None:
            call.cancel()

    def _open(self) -> Any:
        request = pb.WatchRequest(
            session_id=self.session.id,
            since_seq=self._since,
            allow_zstd=self._zstd,
            allow_quantized=self._quantized,
        )
        if self._tries is None:
            self._tries = _Tries(self.session.client, self.session.id)
        self._fresh = True
        call = self.session.client._stream("Watch", request, address=self._tries.address)
        with self._lock:
            if self._stopped.is_set():
                call.cancel()
            self._call = call
        return call

    def __next__(self) -> SceneUpdate:
        failures = 0
        while True:
            if self._stopped.is_set():
                raise StopIteration
            call = self._call
            try:
                if call is None:
                    call = self._open()
                msg = next(call)
            except StopIteration:
                with self._lock:
                    self._call = None
                    self._stopped.set()
                raise
            except grpc.RpcError as e:
                with self._lock:
                    self._call = None
                if self._stopped.is_set():
                    raise StopIteration from None
                err = from_rpc_error(e)
                if isinstance(err, ServerUnavailable):
                    # The session moved (SESSION_ELSEWHERE) or its replica went away: reopen
                    # at the holder (other replicas while it is unreachable), resuming.
                    self._since = self.scene.seq
                    if self._tries is not None and self._tries.again(e, err, read_only=True):
                        self.reconnects += 1
                        continue
                    if failures < self._reconnect:
                        failures += 1
                        self.reconnects += 1
                        self._stopped.wait(min(0.2 * 2**failures, 2.0))  # stop() cuts the wait short
                        continue
                raise err from None
            failures = 0
            if self._fresh and self._tries is not None:
                self._fresh = False
                self._tries.succeeded()
            try:
                update = self.scene.apply(msg)
            except wire.WireError:
                if msg.WhichOneof("event") == "snapshot":
                    # Every fresh start would bring the same unreadable snapshot (a format
                    # version this decoder does not read, say): give up.
                    self.stop()
                    raise
                # The scene cannot follow this stream: start again from a snapshot.
                call.cancel()
                with self._lock:
                    self._call = None
                self._since = None
                continue
            if update is not None:
                self.session._saw(update.plan_version)
                return update

    def updates(self, until: Callable[[SceneUpdate], bool]) -> Iterator[SceneUpdate]:
        """Yields updates until (and including) the first for which `until(update)` is true."""
        for u in self:
            yield u
            if until(u):
                return
