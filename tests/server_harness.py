"""A real `resecta serve` process for end-to-end tests, and the gRPC stubs generated from proto/."""
import hashlib
import json
import os
import select
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import grpc
import pytest

from conftest import ROOT, resecta_bin

PROTO = ROOT / "proto"


def generate_stubs(out: Path):
    """Generates the Python messages and stubs of resecta.v1 into `out` and imports them."""
    from grpc_tools import protoc

    files = sorted(str(p.relative_to(PROTO)) for p in (PROTO / "resecta" / "v1").glob("*.proto"))
    rc = protoc.main(["protoc", f"-I{PROTO}", f"--python_out={out}", f"--grpc_python_out={out}",
                      *files])
    assert rc == 0, "protoc failed"
    sys.path.insert(0, str(out))
    import importlib

    modules = [importlib.import_module(f"resecta.v1.{Path(f).stem}_pb2") for f in files]
    pb_grpc = importlib.import_module("resecta.v1.planning_service_pb2_grpc")
    return Messages(modules), pb_grpc


class Messages:
    """Every message class and enum value of resecta.v1, from whichever file defines it."""

    def __init__(self, modules):
        self._modules = modules

    def __getattr__(self, name):
        for m in self._modules:
            if hasattr(m, name):
                return getattr(m, name)
        raise AttributeError(name)


E2E_STORE = os.environ.get("RESECTA_E2E_STORE")
"""A PostgreSQL server URL (its `postgres` database) to run every test server's store on instead
of SQLite or memory: the end-to-end suite's PostgreSQL pass (scripts/test.sh)."""


def postgres_store(key: str, server: str | None = None) -> str:
    """A database of the PostgreSQL `server` (a URL; default `E2E_STORE`) for `key` (created
    when new), as a store URL: the same `key` (a data directory) gives the same database, as a
    restart on one directory would."""
    server = server or E2E_STORE
    name = "e2e_" + hashlib.sha1(key.encode()).hexdigest()[:16]
    exists = subprocess.run(["psql", server, "-tAc", f"SELECT 1 FROM pg_database WHERE datname = '{name}'"],
                            capture_output=True, text=True, check=True).stdout.strip()
    if exists != "1":
        subprocess.run(["psql", server, "-qc", f"CREATE DATABASE {name}"], capture_output=True,
                       text=True, check=True)
    return server.rsplit("/", 1)[0] + "/" + name


def store_args(data_dir) -> list[str]:
    """The store flags of a test server: `data_dir`'s SQLite (memory without one), or on the
    PostgreSQL pass a database standing for `data_dir` (a fresh one without)."""
    if E2E_STORE:
        key = str(Path(data_dir).resolve()) if data_dir is not None else uuid.uuid4().hex
        # One replica name per store: a restart takes its sessions back at once, as a restarted
        # single server does (a new name would wait for the dead process' leases to expire).
        name = "e2e-" + hashlib.sha1(key.encode()).hexdigest()[:12]
        return ["--store", postgres_store(key), "--replica-id", name]
    return [] if data_dir is None else ["--data-dir", str(data_dir)]


class Server:
    """`resecta serve` on free loopback ports; stopped (SIGTERM) or killed (SIGKILL) by the test."""

    def __init__(self, *args, env=None, data_dir=None):
        # A test naming its own store keeps it on every pass.
        store = [] if "--store" in args else store_args(data_dir)
        self.args = ["serve", "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0", *args, *store]
        self.env = {**os.environ, "RUST_LOG": "warn", **(env or {})}
        self.proc = subprocess.Popen([resecta_bin(), *self.args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, env=self.env, text=True)
        ready, _, _ = select.select([self.proc.stdout], [], [], 120)
        line = self.proc.stdout.readline() if ready else ""
        if not line:
            self.proc.kill()
            raise AssertionError(f"server did not start: {self.proc.stderr.read()}")
        self.bound = json.loads(line)
        self.grpc_addr = self.bound["grpc"]
        scheme = "https" if self.bound["tls"] else "http"
        self.http_url = f"{scheme}://{self.bound['http']}"

    def channel(self, credentials=None, **kw):
        options = [("grpc.max_receive_message_length", 64 << 20)]
        if credentials is not None:
            return grpc.secure_channel(self.grpc_addr, credentials, options=options, **kw)
        return grpc.insecure_channel(self.grpc_addr, options=options, **kw)

    def stop(self, timeout=30):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=timeout)
        return self.proc.returncode

    def sigterm_while(self, reader, limit=5.0):
        """SIGTERM while `reader` (a thread draining an open stream) runs: asserts the server
        exits 0 within `limit` seconds and the reader ends too."""
        time.sleep(0.2)
        start = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(timeout=10)
        took = time.monotonic() - start
        reader.join(timeout=10)
        assert not reader.is_alive(), "the stream did not end"
        assert code == 0, self.stderr()
        assert took < limit, f"exit took {took:.1f} s"

    def kill(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=30)

    def stderr(self):
        return self.proc.stderr.read() if self.proc.poll() is not None else ""


def tls_files(tmp_path: Path) -> tuple[Path, Path, Path]:
    """A throw-away CA and a certificate for 127.0.0.1 / localhost signed by it (trustme; the
    test is skipped without it), written as PEM into `tmp_path`: returns
    `(cert_file, key_file, ca_file)` — the first two for `--tls-cert` / `--tls-key`, the CA for
    the client to pin as its root."""
    trustme = pytest.importorskip("trustme")
    ca = trustme.CA()
    cert = ca.issue_cert("127.0.0.1", "localhost")
    cert_file, key_file, ca_file = tmp_path / "server.crt", tmp_path / "server.key", tmp_path / "ca.pem"
    cert.private_key_pem.write_to_path(str(key_file))
    cert.cert_chain_pems[0].write_to_path(str(cert_file))
    ca.cert_pem.write_to_path(str(ca_file))
    return cert_file, key_file, ca_file


def fibonacci_sphere(n, radius, centre=(0.0, 0.0, 0.0)):
    """`n` points spread evenly on the sphere of `radius` mm about `centre` (a Fibonacci
    lattice) and their outward unit normals, each an (n, 3) float64 array: a synthetic catheter
    cloud with an exact truth."""
    import numpy as np

    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    t = np.pi * (3.0 - np.sqrt(5.0)) * np.arange(n)
    normals = np.stack([r * np.cos(t), r * np.sin(t), z], axis=1)
    return np.asarray(centre, dtype=float) + radius * normals, normals


def wait_for(predicate, timeout=60.0, every=0.1):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    raise AssertionError("condition not met in time")


@pytest.fixture(scope="module")
def phantom(tmp_path_factory):
    """The small phantom as NIfTI (module-wide: the server tests upload it many times)."""
    out = tmp_path_factory.mktemp("phantom")
    subprocess.run([resecta_bin(), "phantom", "--out", str(out), "--preset", "small", "--json"],
                   check=True, capture_output=True)
    return out / "phantom.nii.gz"


@pytest.fixture(scope="module")
def planning_client():
    """A `resecta_client.Client` on an in-memory server shared by a test module."""
    sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
    from resecta_client import Client

    server = Server()
    with Client(server.grpc_addr) as c:
        yield c
    server.stop()


@pytest.fixture
def server(tmp_path):
    """A durable server for one test."""
    s = Server(data_dir=tmp_path / "data")
    yield s
    s.stop()
