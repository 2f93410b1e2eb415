"""Connection hygiene of `resecta serve` end to end (docs/connections.md): idle connections closed
by the handshake timeout while a client keeps editing, a flood of idle connections beyond the
unauthenticated cap evicting its own oldest connections and never an authenticated client's, and
slow request heads closed. Raw sockets against the real binary; the editing client is the Python
client (gRPC) and `requests` (HTTP)."""
import re
import socket
import sys
import threading
import time

import requests

from conftest import ROOT
from server_harness import Server, phantom, wait_for  # noqa: F401 (fixture)

sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
from resecta_client import Client  # noqa: E402

TOKEN = "connections-e2e-token-0123456789"
ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3]}


def host_port(addr):
    host, port = addr.rsplit(":", 1)
    return host, int(port)


def idle_socket(addr):
    """A TCP connection that never sends a byte (non-blocking, for `is_closed`)."""
    s = socket.create_connection(host_port(addr), timeout=10)
    s.setblocking(False)
    return s


def is_closed(sock):
    """Whether the server closed `sock`: end of stream or reset. What it sent before (the gRPC
    face's HTTP/2 settings) is read and dropped."""
    try:
        while True:
            if not sock.recv(65536):
                return True
    except BlockingIOError:
        return False
    except (ConnectionResetError, BrokenPipeError):
        return True


def closed_until(sock, limit):
    """Blocks until the server closes `sock` (True) or `limit` seconds pass (False); a response
    (e.g. 408) before the close is fine."""
    sock.settimeout(limit)
    try:
        while sock.recv(65536):
            pass
        return True
    except (ConnectionResetError, BrokenPipeError):
        return True
    except socket.timeout:
        return False


def edit_session(client, phantom):
    """A session of the small phantom with models and resection `r1`; returns it and its plan
    version."""
    s = client.create_session("connections")
    s.upload_label_map_file(phantom, ROLES)
    s.reconstruct("psr", timeout=300)
    r = s.init_from_end_point("r1", (-30.0, 0.0, 0.0))
    return s, r.plan_version


class Editor:
    """Edits one session alternately over gRPC (the Python client) and HTTP (one keep-alive
    `requests` session); every edit must succeed and advance the plan version by one."""

    def __init__(self, server, session, version, token=None):
        self.url = server.http_url
        self.session = session
        self.version = version
        self.http = requests.Session()
        self.http.headers["resecta-api-version"] = "v1"
        if token:
            self.http.headers["authorization"] = f"Bearer {token}"
        self.count = 0

    def point(self):
        return (-28.0 + (self.count % 5) * 0.5, 3.0, 2.0)

    def grpc_edit(self):
        r = self.session.set_control_point("r1", 1, 2, self.point(), base_version=self.version)
        assert r.plan_version == self.version + 1
        self.version = r.plan_version
        self.count += 1

    def http_edit(self):
        x, y, z = self.point()
        body = {"baseVersion": str(self.version),
                "setControlPoint": {"name": "r1", "i": 1, "j": 2,
                                    "point": {"x": x, "y": y, "z": z}}}
        r = self.http.post(f"{self.url}/v1/sessions/{self.session.id}/edits", json=body, timeout=60)
        assert r.status_code == 200, r.text
        assert int(r.json()["planVersion"]) == self.version + 1
        self.version += 1
        self.count += 1

    def metrics(self):
        """`resecta_connections_closed_total` by (face, reason), over the editor's admitted
        connection (a new one would itself be an unauthenticated connection)."""
        text = self.http.get(f"{self.url}/metrics", timeout=30).text
        pattern = r'resecta_connections_closed_total\{face="(\w+)",reason="(\w+)"\} (\d+)'
        return {(f, r): int(n) for f, r, n in re.findall(pattern, text)}


def test_idle_connections_are_closed_within_30s_while_a_client_edits(phantom):
    """Default settings: 50 silent connections to each face are all closed by the server within
    30 s, while a client editing over both faces is never disturbed."""
    server = Server()
    idle = []
    try:
        with Client(server.grpc_addr, timeout=60) as client:
            editor = Editor(server, *edit_session(client, phantom))
            editor.http_edit()  # the HTTP client's connection is in use before the flood
            idle = [idle_socket(server.grpc_addr) for _ in range(50)]
            idle += [idle_socket(server.bound["http"]) for _ in range(50)]
            opened = time.monotonic()
            still_open = idle
            while still_open and time.monotonic() - opened < 30:
                editor.grpc_edit()
                editor.http_edit()
                still_open = [s for s in still_open if not is_closed(s)]
            took = time.monotonic() - opened
            assert not still_open, f"{len(still_open)} of 100 idle connections open after {took:.0f} s"
            assert editor.count >= 4
            # Every connection the server closed was one of the idle ones (by the handshake
            # timeout): neither editing client's connection was among them.
            assert editor.metrics() == {("grpc", "handshake_timeout"): 50,
                                        ("http", "handshake_timeout"): 50}
            editor.grpc_edit()
            editor.http_edit()
    finally:
        for s in idle:
            s.close()
        server.stop()


def test_a_flood_beyond_the_unauthenticated_cap_does_not_stop_an_authenticated_client(
        tmp_path, phantom):
    """With a token and `max_unauthenticated = 16`, idle connections beyond the cap close their
    own oldest (the handshake timeout is far away), and a client with the token connects and
    edits on both faces while the flood goes on; none of its connections is ever closed."""
    config = tmp_path / "resecta.toml"
    config.write_text("[connections]\nmax_unauthenticated = 16\nhandshake_timeout_s = 120\n")
    server = Server("--token", TOKEN, "--config", str(config))
    flood = []
    stop = threading.Event()

    def keep_flooding():
        faces = [server.grpc_addr, server.bound["http"]]
        while not stop.wait(0.05) and len(flood) < 200:
            flood.append(idle_socket(faces[len(flood) % 2]))

    flooder = threading.Thread(target=keep_flooding)
    try:
        flood += [idle_socket(server.grpc_addr) for _ in range(40)]
        flood += [idle_socket(server.bound["http"]) for _ in range(40)]
        # Each connection past the cap evicted the oldest unauthenticated one.
        wait_for(lambda: sum(not is_closed(s) for s in flood) == 16, timeout=30)
        flooder.start()
        with Client(server.grpc_addr, token=TOKEN, timeout=60) as client:
            editor = Editor(server, *edit_session(client, phantom), token=TOKEN)
            # Edits go on while the flood adds 80 more connections.
            while len(flood) < 160:
                editor.grpc_edit()
                editor.http_edit()
            stop.set()
            flooder.join()
            # Every connection the server closed is a flood connection, evicted.
            closed = lambda: sum(is_closed(s) for s in flood)  # noqa: E731
            wait_for(lambda: sum(editor.metrics().values()) == closed(), timeout=30)
            by_reason = editor.metrics()
            assert set(r for _, r in by_reason) == {"evicted"}, by_reason
            assert len(flood) - closed() == 16
            editor.grpc_edit()
            editor.http_edit()
    finally:
        stop.set()
        if flooder.is_alive():
            flooder.join()
        for s in flood:
            s.close()
        server.stop()


def test_slow_request_heads_are_closed(tmp_path):
    """A request line whose headers never end, on a fresh connection (handshake timeout) or on
    a connection that served a request already, headers trickling in faster than the idle
    timeout (the HTTP/1 head timeout); a partial HTTP/2 preface on the gRPC face."""
    config = tmp_path / "resecta.toml"
    config.write_text("[connections]\nhandshake_timeout_s = 2\nidle_timeout_s = 3\n")
    server = Server("--config", str(config))
    try:
        http = host_port(server.bound["http"])
        fresh = socket.create_connection(http, timeout=10)
        fresh.sendall(b"GET /healthz HTTP/1.1\r\nHost: resecta\r\n")
        grpc = socket.create_connection(host_port(server.grpc_addr), timeout=10)
        grpc.sendall(b"PRI * HTTP/2.0\r\n")
        assert closed_until(fresh, 20), "a request head that never ends kept its connection"
        assert closed_until(grpc, 20), "a partial HTTP/2 preface kept its connection"

        used = socket.create_connection(http, timeout=10)
        used.sendall(b"GET /healthz HTTP/1.1\r\nHost: resecta\r\n\r\n")
        assert used.recv(65536).startswith(b"HTTP/1.1 200")
        used.sendall(b"GET /healthz HTTP/1.1\r\nHost: resecta\r\n")
        used.setblocking(False)
        start = time.monotonic()
        closed = False
        while not closed and time.monotonic() - start < 20:
            time.sleep(0.5)
            closed = is_closed(used)
            if not closed:
                try:
                    used.send(b"x-slow: 1\r\n")
                except (BrokenPipeError, ConnectionResetError):
                    closed = True
        assert closed, "a trickling request head kept its connection for 20 s"
    finally:
        server.stop()
