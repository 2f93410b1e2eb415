"""Connecting: server info and the receive limit, tokens, the API version check, an unreachable
server, the session lifecycle, and the ErrorInfo trailer decoding."""

from __future__ import annotations

import threading
import time

import grpc
import pytest

import resecta_client as rc
from resecta_client.errors import error_info, from_rpc_error

from server_harness import tls_files

from .conftest import Server, free_port, status_details

TOKEN = "client-token-0123456789abcdef"


def test_server_info_and_receive_limit(client: rc.Client) -> None:
    info = client.server_info()
    assert info.api_version == "resecta.v1"
    assert info.limits.max_chunk_bytes == rc.CHUNK_BYTES
    # The channel's receive limit follows the server's largest message (above gRPC's 4 MiB).
    assert info.limits.max_message_bytes > 4 << 20
    assert client._receive == info.limits.max_message_bytes
    # Without --gpu the planners evaluate on the CPU, in f64.
    assert info.compute == rc.ComputeInfo("cpu", "", True)


def test_token_required_and_checked() -> None:
    s = Server(env={"RESECTA_TOKEN": TOKEN})
    try:
        with rc.Client(s.grpc_addr) as anonymous, pytest.raises(rc.AuthError) as e:
            anonymous.list_sessions()
        assert e.value.code == "UNAUTHENTICATED" and TOKEN not in str(e.value)
        with rc.Client(s.grpc_addr, token="wrong-token-0123456789") as wrong, pytest.raises(rc.AuthError):
            wrong.create_session("x")
        with rc.Client(s.grpc_addr, token=TOKEN) as good:
            assert "auth" in good.server_info().capabilities or good.list_sessions() == []
            assert good.create_session("ok").plan_version == 0
    finally:
        s.stop()


def test_version_mismatch() -> None:
    s = Server()
    try:
        with rc.Client(s.grpc_addr, api_version="v2") as c:
            assert c.server_info().api_version == "resecta.v1"  # answered whatever the header says
            with pytest.raises(rc.VersionMismatch) as e:
                c.list_sessions()
        assert (
            e.value.code == "API_VERSION_MISMATCH" and e.value.status == grpc.StatusCode.FAILED_PRECONDITION
        )
        assert "v2" in e.value.message and "v1" in e.value.message
    finally:
        s.stop()


def test_unreachable_server_fails_fast() -> None:
    with rc.Client(f"127.0.0.1:{free_port()}", timeout=20) as c:
        t = time.monotonic()
        with pytest.raises(rc.ServerUnavailable) as e:
            c.list_sessions()
        assert time.monotonic() - t < 5, "an unreachable server must not wait for the timeout"
        assert e.value.code == "UNAVAILABLE"


def test_session_lifecycle(client: rc.Client) -> None:
    s = client.create_session("lifecycle")
    assert s.plan_version == 0
    info = s.info()
    assert (info.id, info.display_name, info.state, info.label_map) == (
        s.id,
        "lifecycle",
        rc.SessionState.EMPTY,
        None,
    )
    assert [x.id for x in client.list_sessions()] == [s.id]
    assert client.session(s.id).id == s.id
    s.delete()
    with pytest.raises(rc.SessionNotFound) as e:
        s.info()
    assert e.value.code == "SESSION_NOT_FOUND" and isinstance(e.value, rc.NotFound)
    with pytest.raises(rc.SessionNotFound):
        client.session("no-such-session")
    # A session that was never given a label map cannot be planned on.
    other = client.create_session("empty")
    with pytest.raises(rc.FailedPrecondition) as e2:
        other.init_from_end_point("r1", (0, 0, 0))
    assert e2.value.code == "NO_LABEL_MAP"


def test_concurrent_calls_share_one_client(client: rc.Client) -> None:
    errors: list[BaseException] = []

    def work() -> None:
        try:
            for _ in range(5):
                client.create_session("t").delete()
        except BaseException as e:
            errors.append(e)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []


class _FakeCall(grpc.RpcError, grpc.Call):  # type: ignore[misc]
    """A failed call as grpc raises it (for the trailer decoding only; no server is mocked)."""

    def __init__(self, status: grpc.StatusCode, trailer: bytes | None) -> None:
        self._status, self._trailer = status, trailer

    def code(self) -> grpc.StatusCode:
        return self._status

    def details(self) -> str:
        return "details"

    def trailing_metadata(self):  # type: ignore[no-untyped-def]
        return (("grpc-status-details-bin", self._trailer),) if self._trailer is not None else ()

    def initial_metadata(self):  # type: ignore[no-untyped-def]
        return ()

    def is_active(self) -> bool:
        return False

    def time_remaining(self) -> None:
        return None

    def cancel(self) -> bool:
        return False

    def add_callback(self, callback) -> bool:  # type: ignore[no-untyped-def]
        return False


def test_error_info_trailer_decoding() -> None:
    info = error_info(status_details("STALE_VERSION", 7))
    assert info is not None and (info.code, info.field, info.current_plan_version) == (
        "STALE_VERSION",
        "x.y",
        7,
    )
    assert error_info(b"\xff\xff") is None  # malformed: fall back to the status
    e = from_rpc_error(_FakeCall(grpc.StatusCode.ABORTED, status_details("STALE_VERSION", 7)))
    assert isinstance(e, rc.StaleVersion) and e.current_version == 7 and e.field == "x.y"
    e = from_rpc_error(_FakeCall(grpc.StatusCode.RESOURCE_EXHAUSTED, status_details("SESSION_QUOTA")))
    assert isinstance(e, rc.QuotaExceeded) and e.code == "SESSION_QUOTA"
    e = from_rpc_error(_FakeCall(grpc.StatusCode.INVALID_ARGUMENT, None))
    assert isinstance(e, rc.InvalidArgument) and isinstance(e, ValueError) and e.code == "INVALID_ARGUMENT"


def test_tls_with_a_custom_ca(tmp_path) -> None:  # type: ignore[no-untyped-def]
    cert_file, key_file, ca_file = tls_files(tmp_path)
    s = Server("--tls-cert", str(cert_file), "--tls-key", str(key_file))
    try:
        for root in (ca_file, str(ca_file), ca_file.read_bytes()):
            with rc.Client(s.grpc_addr, ca_cert=root) as c:
                assert c.tls and "tls" in c.server_info().capabilities
                assert c.create_session("tls").id
        with rc.Client(s.grpc_addr, tls=True, timeout=10) as untrusted, pytest.raises(rc.ServerUnavailable):
            untrusted.server_info()  # not in the system's roots
        with rc.Client(s.grpc_addr, timeout=10) as plain, pytest.raises(rc.ServerUnavailable):
            plain.server_info()
    finally:
        s.stop()
