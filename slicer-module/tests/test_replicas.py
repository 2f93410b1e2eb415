"""A replicated server: the Logic takes several addresses, follows its session to the replica
holding it and on to another when that one dies, reporting each move on the status line; the
retries run on the worker and watch threads, never on the main thread."""

import signal
import threading

import pytest


def test_parse_addresses():
    from ResectaLib.logic import parse_addresses

    assert parse_addresses("a:1, b:2,,b:2  c:3\n") == ["a:1", "b:2", "c:3"]
    assert parse_addresses(["a:1", " ", "a:1"]) == ["a:1"]
    assert parse_addresses("") == []


@pytest.fixture
def replicas(tmp_path):
    from conftest import Server

    data = tmp_path / "data"
    a = Server("--replica-id", "a", "--lease-ms", "1000", data_dir=data)
    b = Server("--replica-id", "b", "--lease-ms", "1000", data_dir=data)
    yield a, b
    for s in (a, b):
        if s.proc.poll() is None:
            s.stop()


def test_the_session_follows_its_replica(scene, dispatcher, replicas, phantom):
    from resecta_client import Client

    from ResectaLib.logic import PlanningLogic

    a, b = replicas
    with Client(a.grpc_addr) as on_a:  # the session lives on A
        made = on_a.create_session("replicas")
        made.upload_label_map_file(phantom, {"parenchyma": [1], "tumor": [2], "portal": [3]})
        made.init_from_end_point("r1", (-30.0, 0.0, 0.0))

    main = threading.get_ident()
    statuses, moves = [], []
    s = PlanningLogic(scene, dispatcher)
    s.set_callbacks(status=statuses.append,
                    session_moved=lambda sid, at: moves.append((sid, at, threading.get_ident())))
    try:
        s.connect(b.grpc_addr, replicas=f"{a.grpc_addr}, {b.grpc_addr}")
        dispatcher.wait_until(lambda: s.connected, 30)
        assert s.client.replicas == (a.grpc_addr,)
        s.open_session(made.id)
        dispatcher.wait_until(lambda: s.has_session and "r1" in s.grids, 30)
        assert moves[0][:2] == (made.id, a.grpc_addr)
        assert f"Session moved to replica {a.grpc_addr}" in statuses

        a.proc.send_signal(signal.SIGKILL)  # the watch (on its thread) fails over to B
        a.proc.wait(10)
        dispatcher.wait_until(lambda: (made.id, b.grpc_addr) in [m[:2] for m in moves], 20)
        assert f"Session moved to replica {b.grpc_addr}" in statuses
        assert all(t == main for _sid, _at, t in moves)  # reported on the main thread
        done = []
        s.call(lambda: s.session.set_margin("r1", 12.0), done.append)
        dispatcher.wait_until(lambda: done, 20)
        assert done[0].plan_version == 3 and s.client.route(made.id) == b.grpc_addr
        assert not s.errors, s.errors
    finally:
        s.close()
