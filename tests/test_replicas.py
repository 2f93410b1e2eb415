"""Two replicas of `resecta serve` on one real PostgreSQL (scripts/pg_cluster.sh's, named by
RESECTA_TEST_PG): a session is served by one replica at a time, the other answers UNAVAILABLE
SESSION_ELSEWHERE with the holder's address; `kill -9` of the holder mid-burst loses no
acknowledged edit once the survivor takes over; a paused former holder cannot write; 100
sessions spread over both; SIGTERM drains (the other replica takes over at once)."""
import json
import os
import signal
import time
import uuid

import grpc
import pytest

from conftest import ROOT
from server_harness import Server, generate_stubs, phantom, postgres_store, wait_for  # noqa: F401
from test_server_grpc import (assert_acknowledged_kept, burst_until_killed, client, drag, init_edit, md,
                              new_session, raw_upload)

PG = os.environ.get("RESECTA_TEST_PG")
if not PG:
    if os.environ.get("CI"):
        raise RuntimeError("RESECTA_TEST_PG is not set: scripts/test.sh starts PostgreSQL for these tests")
    pytest.skip("SKIPPED: RESECTA_TEST_PG not set (scripts/pg_cluster.sh start DIR)", allow_module_level=True)

LEASE_MS = 1000


@pytest.fixture(scope="module")
def stubs(tmp_path_factory):
    return generate_stubs(tmp_path_factory.mktemp("stubs"))


@pytest.fixture
def store():
    return postgres_store(uuid.uuid4().hex, PG)


def replica(store, name, *args, lease_ms=LEASE_MS):
    return Server("--store", store, "--replica-id", name, "--lease-ms", str(lease_ms), *args)


def elsewhere(err):
    """The holder's address of an UNAVAILABLE SESSION_ELSEWHERE error (None when not given)."""
    import sys

    sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
    from resecta_client.errors import error_info

    assert err.code() == grpc.StatusCode.UNAVAILABLE, (err.code(), err.details())
    details = dict(err.trailing_metadata() or ()).get("grpc-status-details-bin")
    info = error_info(details)
    assert info is not None and info.code == "SESSION_ELSEWHERE", (info, err.details())
    return info.replica if info.HasField("replica") else None


def held_session(a, b, stubs, phantom):
    """A session created on replica `a` with the phantom and a first resection: the messages,
    stubs of `a` and `b`, its id and plan version."""
    pb, on_a = client(a, stubs)
    _, on_b = client(b, stubs)
    sid = new_session(pb, on_a)
    on_a.UploadLabelMap(iter(raw_upload(pb, sid, phantom)), metadata=md())
    return pb, on_a, on_b, sid, on_a.Edit(init_edit(pb, sid), metadata=md()).plan_version


def kill_all(*servers):
    for s in servers:
        if s.proc.poll() is None:
            s.kill()


def test_kill_9_mid_burst_the_survivor_has_every_acknowledged_edit(store, stubs, phantom):
    a, b = replica(store, "a"), replica(store, "b")
    try:
        pb, on_a, on_b, sid, v = held_session(a, b, stubs, phantom)
        # B knows where the session is, and changes nothing.
        with pytest.raises(grpc.RpcError) as e:
            on_b.Edit(drag(pb, sid, v, (-29.0, 0.5, 0.5)), metadata=md())
        at = elsewhere(e.value)
        assert at.grpc_address == a.grpc_addr and at.http_url == a.http_url, at
        assert 0 < at.lease_remaining_ms <= LEASE_MS

        acked = burst_until_killed(a, pb, on_a, sid, v)
        killed = time.monotonic()
        # The client goes on at B: until A's lease ends B names A (unreachable now), then B
        # restores the session from the log.
        while True:
            try:
                on_b.GetSession(pb.GetSessionRequest(session_id=sid), metadata=md())
                break
            except grpc.RpcError as err:
                assert elsewhere(err) is None or elsewhere(err).grpc_address == a.grpc_addr
                assert time.monotonic() - killed < 10 * LEASE_MS / 1000, "no take-over"
                time.sleep(0.05)
        assert_acknowledged_kept(pb, on_b, sid, acked)
    finally:
        kill_all(a, b)


def test_a_paused_former_holder_cannot_write(store, stubs, phantom):
    a, b = replica(store, "a"), replica(store, "b")
    try:
        pb, on_a, on_b, sid, v = held_session(a, b, stubs, phantom)
        a.proc.send_signal(signal.SIGSTOP)
        try:
            time.sleep(1.5 * LEASE_MS / 1000)
            # B takes over and edits.
            v = on_b.Edit(drag(pb, sid, v, (-25.0, 1.0, 1.0)), metadata=md(), timeout=30).plan_version
        finally:
            a.proc.send_signal(signal.SIGCONT)
        # A wakes up believing it holds the session: its edit is refused, naming B.
        with pytest.raises(grpc.RpcError) as e:
            on_a.Edit(drag(pb, sid, v - 1, (-40.0, 1.0, 1.0)), metadata=md(), timeout=30)
        at = elsewhere(e.value)
        assert at is None or at.grpc_address == b.grpc_addr, at
        sess = on_b.GetSession(pb.GetSessionRequest(session_id=sid), metadata=md()).session
        assert sess.plan_version == v
        plan = json.loads(on_b.ExportPlan(pb.ExportPlanRequest(session_id=sid), metadata=md()).plan_json)
        assert plan["resections"][0]["control_points"][1 * 4 + 2] == pytest.approx([-25.0, 1.0, 1.0])
    finally:
        kill_all(a, b)


def test_100_sessions_spread_over_two_replicas_and_draining_hands_them_over(store, stubs, phantom, tmp_path):
    # The session quota is the shared store's (64 by default): room for 100.
    config = tmp_path / "resecta.toml"
    config.write_text("[limits]\nmax_sessions = 100\n")
    # A long lease: the hand-over on SIGTERM must not wait for it.
    a, b = (replica(store, name, "--config", str(config), lease_ms=30_000) for name in ("a", "b"))
    try:
        pb, on_a = client(a, stubs)
        _, on_b = client(b, stubs)
        ids = []
        for k in range(100):
            stub = on_a if k % 2 == 0 else on_b
            sid = new_session(pb, stub, name=f"spread {k}")
            ids.append(sid)
            if k % 10 < 2:  # a tenth of each replica's sessions get a plan
                stub.UploadLabelMap(iter(raw_upload(pb, sid, phantom)), metadata=md())
                stub.Edit(init_edit(pb, sid), metadata=md())
        assert len(on_a.ListSessions(pb.ListSessionsRequest(), metadata=md()).sessions) == 100
        # The quota counts both replicas' sessions.
        with pytest.raises(grpc.RpcError) as e:
            new_session(pb, on_b, name="one too many")
        assert e.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        for k, sid in enumerate(ids):
            holder, other, other_server = (on_a, on_b, a) if k % 2 == 0 else (on_b, on_a, b)
            holder.GetSession(pb.GetSessionRequest(session_id=sid), metadata=md())
            with pytest.raises(grpc.RpcError) as e:
                other.GetSession(pb.GetSessionRequest(session_id=sid), metadata=md())
            assert elsewhere(e.value).grpc_address == other_server.grpc_addr
        # A drains: B serves A's sessions at once, long before their 30 s lease would end.
        assert a.stop() == 0
        started = time.monotonic()
        for k, sid in enumerate(ids):
            sess = on_b.GetSession(pb.GetSessionRequest(session_id=sid), metadata=md()).session
            assert sess.plan_version == (2 if k % 10 < 2 else 0), (k, sess.plan_version)
        assert time.monotonic() - started < 20
    finally:
        kill_all(a, b)
