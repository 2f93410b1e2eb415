"""Fixtures of the client tests: the real `resecta serve` binary and phantoms, from the
repository's end-to-end harness (tests/server_harness.py, tests/conftest.py), which these tests
reuse instead of copying."""

from __future__ import annotations

import contextlib
import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # also works when pip-installed

from conftest import resecta_bin  # noqa: E402  (tests/conftest.py)
from server_harness import Server, phantom, server  # noqa: E402,F401 (fixtures)

import resecta_client as rc  # noqa: E402

ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3]}
DEMO_ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3], "hepatic": [4]}


@pytest.fixture(scope="session")
def demo_phantom(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo phantom (liver-sized, oblique 0.8×0.8×2.5 mm grid) as NIfTI."""
    out = tmp_path_factory.mktemp("demo")
    subprocess.run([resecta_bin(), "phantom", "--out", str(out), "--json"], check=True, capture_output=True)
    return out / "phantom.nii.gz"


@pytest.fixture
def client(server: Server) -> Iterator[rc.Client]:  # noqa: F811
    with rc.Client(server.grpc_addr, timeout=60) as c:
        yield c


@pytest.fixture
def ready(client: rc.Client, phantom: Path) -> rc.Session:  # noqa: F811
    """A session with the small phantom uploaded and its models built."""
    s = client.create_session("client-tests")
    s.upload_label_map_file(phantom, ROLES)
    s.reconstruct("psr")
    return s


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def read_ply(data: bytes) -> dict[str, np.ndarray]:
    """Vertices (every property, by name) and triangles of a binary little-endian PLY with
    triangle faces (`list uchar int`), as the server writes it."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    assert "format binary_little_endian 1.0" in header, header[:3]
    types = {"float": "<f4", "double": "<f8", "int": "<i4", "uchar": "u1", "uint": "<u4"}
    n_vertices = n_faces = 0
    props: list[tuple[str, str]] = []
    element = ""
    for line in header:
        w = line.split()
        if w[0] == "element":
            element = w[1]
            if element == "vertex":
                n_vertices = int(w[2])
            else:
                n_faces = int(w[2])
        elif w[0] == "property" and element == "vertex":
            props.append((w[2], types[w[1]]))
    vertices = np.frombuffer(data, np.dtype(props), n_vertices, end)
    face = np.dtype([("n", "u1"), ("v", "<i4", 3)])
    faces = np.frombuffer(data, face, n_faces, end + vertices.nbytes)
    assert (faces["n"] == 3).all()
    out = {name: vertices[name] for name, _ in props}
    out["triangles"] = faces["v"]
    return out


def status_details(code: str, current: int | None = None) -> bytes:
    """A `google.rpc.Status` with one ErrorInfo detail, encoded by hand."""
    info = rc.errors.error_pb2.ErrorInfo(
        code=code, field="x.y", current_plan_version=current
    ).SerializeToString()

    def ld(number: int, payload: bytes) -> bytes:
        return bytes([number << 3 | 2, len(payload)]) + payload

    any_ = ld(1, rc.errors.ERROR_INFO_TYPE.encode()) + ld(2, info)
    return bytes([1 << 3]) + struct.pack("B", 9) + ld(2, b"message") + ld(3, any_)


class Proxy:
    """A TCP relay in front of the server whose connections the test can drop (a network cut),
    so that reconnection is tested against the real server."""

    def __init__(self, upstream: str) -> None:
        host, port = upstream.rsplit(":", 1)
        self.upstream = (host, int(port))
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.address = f"127.0.0.1:{self.listener.getsockname()[1]}"
        self.sockets: list[socket.socket] = []
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                down, _ = self.listener.accept()
            except OSError:
                return
            up = socket.create_connection(self.upstream)
            with self.lock:
                self.sockets += [down, up]
            for a, b in ((down, up), (up, down)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)

    def drop(self) -> None:
        """Cuts every open connection (new ones are accepted)."""
        with self.lock:
            sockets, self.sockets = self.sockets, []
        for s in sockets:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
                s.close()

    def close(self) -> None:
        self.listener.close()
        self.drop()
