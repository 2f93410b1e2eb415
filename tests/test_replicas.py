"""Two replicas of `resecta serve` on one real PostgreSQL (scripts/pg_cluster.sh's, named by
RESECTA_TEST_PG): a session is served by one replica at a time, the other answers UNAVAILABLE
SESSION_ELSEWHERE with the holder's address; `kill -9` of the holder mid-burst loses no
acknowledged edit once the survivor takes over; a paused former holder cannot write; 100
sessions spread over both; SIGTERM drains (the other replica takes over at once)."""
import os
import signal
import threading
import time
import uuid

import grpc
import pytest

from conftest import ROOT
from server_harness import Server, generate_stubs, phantom, postgres_store, wait_for  # noqa: F401
from test_server_grpc import client, drag, init_edit, md, new_session, raw_upload

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


def replica(store, name, lease_ms=LEASE_MS):
    return Server("--store", store, "--replica-id", name, "--lease-ms", str(lease_ms))


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


def test_kill_9_mid_burst_the_survivor_has_every_acknowledged_edit(store, stubs, phantom):
    a, b = replica(store, "a"), replica(store, "b")
    try:
        pb, on_a = client(a, stubs)
        _, on_b = client(b, stubs)
        sid = new_session(pb, on_a)
        on_a.UploadLabelMap(iter(raw_upload(pb, sid, phantom)), metadata=md())
        v = on_a.Edit(init_edit(pb, sid), metadata=md()).plan_version
        # B knows where the session is, and changes nothing.
        with pytest.raises(grpc.RpcError) as e:
            on_b.Edit(drag(pb, sid, v, (-29.0, 0.5, 0.5)), metadata=md())
        at = elsewhere(e.value)
        assert at.grpc_address == a.grpc_addr and at.http_url == a.http_url, at
        assert 0 < at.lease_remaining_ms <= LEASE_MS

        acked = {}
        stop = threading.Event()

        def burst():
            nonlocal v
            k = 0
            while not stop.is_set():
                p = (-30.0 + 0.01 * k, 0.5, 0.25)
                try:
                    v = on_a.Edit(drag(pb, sid, v, p), metadata=md(), timeout=30).plan_version
                except grpc.RpcError:
                    return
                acked[v] = p
                k += 1

        t = threading.Thread(target=burst)
        t.start()
        wait_for(lambda: len(acked) >= 15, timeout=120)
        a.kill()
        killed = time.monotonic()
        stop.set()
        t.join(timeout=60)
        last = max(acked)
        # The client goes on at B: until A's lease ends B names A (unreachable now), then B
        # restores the session from the log.
        while True:
            try:
                sess = on_b.GetSession(pb.GetSessionRequest(session_id=sid), metadata=md()).session
                break
            except grpc.RpcError as err:
                assert elsewhere(err) is None or err.code() == grpc.StatusCode.UNAVAILABLE
                assert time.monotonic() - killed < 10 * LEASE_MS / 1000, "no take-over"
                time.sleep(0.05)
        assert sess.plan_version in (last, last + 1), (sess.plan_version, last)
        import json
        plan = json.loads(on_b.ExportPlan(pb.ExportPlanRequest(session_id=sid), metadata=md()).plan_json)
        point = plan["resections"][0]["control_points"][1 * 4 + 2]
        if sess.plan_version == last:
            assert point == pytest.approx(list(acked[last]))
        else:
            assert point[0] == pytest.approx(acked[last][0] + 0.01)
        # Undo on B walks back through A's acknowledged edits.
        w = on_b.Edit(pb.EditRequest(session_id=sid, base_version=sess.plan_version, undo=pb.Undo()),
                      metadata=md()).plan_version
        assert w == sess.plan_version + 1
    finally:
        for s in (a, b):
            if s.proc.poll() is None:
                s.kill()


def test_a_paused_former_holder_cannot_write(store, stubs, phantom):
    a, b = replica(store, "a"), replica(store, "b")
    try:
        pb, on_a = client(a, stubs)
        _, on_b = client(b, stubs)
        sid = new_session(pb, on_a)
        on_a.UploadLabelMap(iter(raw_upload(pb, sid, phantom)), metadata=md())
        v = on_a.Edit(init_edit(pb, sid), metadata=md()).plan_version
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
        import json
        plan = json.loads(on_b.ExportPlan(pb.ExportPlanRequest(session_id=sid), metadata=md()).plan_json)
        assert plan["resections"][0]["control_points"][1 * 4 + 2] == pytest.approx([-25.0, 1.0, 1.0])
    finally:
        for s in (a, b):
            if s.proc.poll() is None:
                s.kill()


def test_100_sessions_spread_over_two_replicas_and_draining_hands_them_over(store, stubs, phantom):
    # A long lease: the hand-over on SIGTERM must not wait for it.
    a, b = replica(store, "a", lease_ms=30_000), replica(store, "b", lease_ms=30_000)
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
        for s in (a, b):
            if s.proc.poll() is None:
                s.kill()
