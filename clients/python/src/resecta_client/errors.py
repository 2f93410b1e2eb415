"""Exceptions of the client, and the mapping of gRPC errors onto them.

Every error the server sends is a gRPC status whose `grpc-status-details-bin` trailer holds a
`google.rpc.Status` with one `resecta.v1.ErrorInfo` (proto/README.md, "Errors"). `from_rpc_error`
reads it (with a few lines of protobuf wire decoding, so that no googleapis package is needed)
and raises the subclass of `ResectaError` that matches the `ErrorInfo.code`, or else the gRPC
status code.
"""

from __future__ import annotations

from dataclasses import dataclass

import grpc

from ._gen import error_pb2

ERROR_INFO_TYPE = "type.googleapis.com/resecta.v1.ErrorInfo"


class ResectaError(Exception):
    """Base of every error of the client.

    `code` is the server's stable `ErrorInfo.code` (e.g. ``SESSION_NOT_FOUND``, see
    proto/README.md), or the gRPC status name (``UNAVAILABLE``, ``CANCELLED``,
    ``DEADLINE_EXCEEDED``…) when the server sent none; `status` the gRPC status code (None for
    errors raised by the client itself); `field` the offending request field path, if any;
    `message` the server's message (never a patient identifier)."""

    def __init__(
        self,
        message: str,
        *,
        code: str = "",
        status: grpc.StatusCode | None = None,
        field: str = "",
    ) -> None:
        super().__init__(f"{code}: {message}" if code else message)
        self.message = message
        self.code = code
        self.status = status
        self.field = field


class AuthError(ResectaError):
    """The token is missing or wrong (UNAUTHENTICATED)."""


class VersionMismatch(ResectaError):
    """The server does not speak this client's API version (API_VERSION_MISMATCH)."""


class NotFound(ResectaError):
    """An unknown resection or model name (RESECTION_NOT_FOUND, MODEL_NOT_FOUND)."""


class SessionNotFound(NotFound):
    """An unknown or expired session (SESSION_NOT_FOUND)."""


class ServerUnavailable(ResectaError):
    """The server cannot be reached, or is shutting down (UNAVAILABLE)."""


@dataclass(frozen=True)
class Replica:
    """One replica of a replicated server, as a SESSION_ELSEWHERE error names it: its `id`,
    its gRPC address (``host:port``), its HTTP face's base URL, and the milliseconds left on its
    lease on the session (None when the server did not say)."""

    id: str
    grpc_address: str
    http_url: str
    lease_remaining_ms: int | None = None


class SessionElsewhere(ServerUnavailable):
    """The session is held by another replica of a replicated server (UNAVAILABLE,
    SESSION_ELSEWHERE): the call was refused, not applied, and may be repeated at
    `replica.grpc_address`. `replica` is None when the answering replica does not know where
    the session is (it just moved): repeat the call. `Client` follows these by itself; it
    raises this only when it could not reach the holder within its `failover_timeout`."""

    def __init__(self, message: str, *, replica: Replica | None = None, **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.replica = replica


class StaleVersion(ResectaError):
    """An edit against an old plan version (ABORTED, STALE_VERSION): never rebased by the server.
    `current_version` is the session's plan version now; re-read the state and decide again."""

    def __init__(self, message: str, *, current_version: int | None = None, **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.current_version = current_version


class InvalidArgument(ResectaError, ValueError):
    """Bad input: NaN or out-of-range numbers, wrong lengths, a malformed upload or plan
    (INVALID_ARGUMENT, BAD_CHUNK, BAD_LABEL_MAP, BAD_PLAN)."""


class QuotaExceeded(ResectaError):
    """A server limit: sessions, voxels, upload bytes, memory, plan size (RESOURCE_EXHAUSTED)."""


class FailedPrecondition(ResectaError):
    """The session is not in the needed state: no label map, nothing to undo or redo
    (NO_LABEL_MAP, NOTHING_TO_UNDO, NOTHING_TO_REDO, FAILED_PRECONDITION)."""


class Cancelled(ResectaError):
    """The call was cancelled (by this client, e.g. a cancelled reconstruction)."""


class DeadlineExceeded(ResectaError):
    """The call took longer than its timeout."""


class Unsupported(ResectaError):
    """The server does not offer this (UNIMPLEMENTED, code UNSUPPORTED), e.g. slices of a model,
    which this server build lacks."""


class ServerError(ResectaError):
    """A storage failure (STORAGE: retry) or a bug in the server (INTERNAL)."""


_BY_CODE: dict[str, type[ResectaError]] = {
    "UNAUTHENTICATED": AuthError,
    "API_VERSION_MISMATCH": VersionMismatch,
    "SESSION_NOT_FOUND": SessionNotFound,
    "RESECTION_NOT_FOUND": NotFound,
    "MODEL_NOT_FOUND": NotFound,
    "STALE_VERSION": StaleVersion,
    "UNSUPPORTED": Unsupported,
    "SESSION_ELSEWHERE": SessionElsewhere,
}
_BY_STATUS: dict[grpc.StatusCode, type[ResectaError]] = {
    grpc.StatusCode.UNAUTHENTICATED: AuthError,
    grpc.StatusCode.NOT_FOUND: NotFound,
    grpc.StatusCode.UNAVAILABLE: ServerUnavailable,
    grpc.StatusCode.ABORTED: StaleVersion,
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgument,
    grpc.StatusCode.OUT_OF_RANGE: InvalidArgument,
    grpc.StatusCode.RESOURCE_EXHAUSTED: QuotaExceeded,
    grpc.StatusCode.FAILED_PRECONDITION: FailedPrecondition,
    grpc.StatusCode.CANCELLED: Cancelled,
    grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceeded,
    grpc.StatusCode.UNIMPLEMENTED: Unsupported,
    grpc.StatusCode.INTERNAL: ServerError,
    grpc.StatusCode.UNKNOWN: ServerError,
}


def _fields(buf: bytes) -> list[tuple[int, int | bytes]]:
    """The (field number, value) pairs of a protobuf message: varints as ints, length-delimited
    fields as bytes (enough for google.rpc.Status and google.protobuf.Any)."""
    out: list[tuple[int, int | bytes]] = []
    pos = 0

    def varint() -> int:
        nonlocal pos
        value = shift = 0
        while True:
            if pos >= len(buf) or shift > 63:
                raise ValueError("truncated varint")
            b = buf[pos]
            pos += 1
            value |= (b & 0x7F) << shift
            shift += 7
            if b < 0x80:
                return value

    while pos < len(buf):
        key = varint()
        number, wire_type = key >> 3, key & 7
        if wire_type == 0:
            out.append((number, varint()))
        elif wire_type == 2:
            n = varint()
            if pos + n > len(buf):
                raise ValueError("truncated field")
            out.append((number, buf[pos : pos + n]))
            pos += n
        elif wire_type in (1, 5):
            pos += 8 if wire_type == 1 else 4
        else:
            raise ValueError(f"unsupported wire type {wire_type}")
    return out


def error_info(status_details: bytes) -> error_pb2.ErrorInfo | None:
    """The `resecta.v1.ErrorInfo` in the bytes of a `grpc-status-details-bin` trailer (a
    `google.rpc.Status`: field 3 holds `google.protobuf.Any` details), or None."""
    try:
        for number, detail in _fields(status_details):
            if number != 3 or not isinstance(detail, bytes):
                continue
            parts = dict(_fields(detail))
            if parts.get(1) == ERROR_INFO_TYPE.encode():
                value = parts.get(2, b"")
                info = error_pb2.ErrorInfo()
                info.ParseFromString(value if isinstance(value, bytes) else b"")
                return info
    except Exception:  # a malformed trailer: fall back to the status code
        return None
    return None


def from_rpc_error(err: grpc.RpcError) -> ResectaError:
    """The `ResectaError` for a failed gRPC call (raise it `from err`)."""
    status = err.code() if isinstance(err, grpc.Call) else None
    message = (err.details() if isinstance(err, grpc.Call) else None) or str(err)
    info = None
    if isinstance(err, grpc.Call):
        for key, value in err.trailing_metadata() or ():
            if key == "grpc-status-details-bin" and isinstance(value, bytes):
                info = error_info(value)
    code = info.code if info and info.code else (status.name if status else "")
    cls = _BY_CODE.get(code) or (_BY_STATUS.get(status) if status else None) or ResectaError
    kw = {"code": code, "status": status, "field": info.field if info else ""}
    if cls is StaleVersion:
        current = info.current_plan_version if info and info.HasField("current_plan_version") else None
        return StaleVersion(message, current_version=current, **kw)
    if cls is SessionElsewhere:
        replica = None
        if info is not None and info.HasField("replica"):
            r = info.replica
            replica = Replica(r.id, r.grpc_address, r.http_url, int(r.lease_remaining_ms))
        return SessionElsewhere(message, replica=replica, **kw)
    return cls(message, **kw)  # type: ignore[arg-type]
