"""A `resecta serve` on this machine, started and stopped by the module (the self-test uses it).

`find_binary(setting)` looks for the server program: the Slicer setting `Resecta/ServerBinary`
(passed in by the caller), the `RESECTA_BIN` environment variable, then `resecta` on `PATH`.
`LocalServer(binary)` starts `resecta serve --grpc 127.0.0.1:0 --http 127.0.0.1:0` (loopback, free
ports, in memory, no token), reads the JSON line it prints once both faces listen
(`{"grpc": "127.0.0.1:PORT", "http": ..., "tls": false}`) and stops it on `close()` (or at the end
of a `with` block). No Qt: the caller owns any waiting UI.
"""

from __future__ import annotations

import collections
import json
import os
import queue
import shutil
import subprocess
import threading
from pathlib import Path

SETTING_BINARY = "Resecta/ServerBinary"
ENV_BINARY = "RESECTA_BIN"
NOT_FOUND = (f"no resecta server program found (Slicer setting {SETTING_BINARY}, environment "
             f"variable {ENV_BINARY}, or `resecta` on PATH)")


def find_binary(setting: str | None = None) -> str | None:
    """The server program to start: `setting` (the Slicer setting's value), else `$RESECTA_BIN`,
    else `resecta` on PATH; None when there is none. A named file that is not there is
    skipped, so a stale setting does not hide a server on PATH."""
    for candidate in (setting, os.environ.get(ENV_BINARY)):
        if candidate and Path(candidate).is_file():
            return str(candidate)
    return shutil.which("resecta")


class LocalServer:
    """`resecta serve` on free loopback ports; `grpc` / `http` are the bound addresses."""

    def __init__(self, binary: str, *args: str, timeout: float = 60.0):
        # The server reads RESECTA_* variables (token, TLS, data dir, config): a local test server
        # is plain loopback, so none of them is passed on.
        env = {k: v for k, v in os.environ.items() if not k.startswith("RESECTA_")}
        env.setdefault("RUST_LOG", "warn")
        self.proc = subprocess.Popen(
            [binary, "serve", "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0", *args],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            env=env, text=True, encoding="utf-8", errors="replace")
        self._log: collections.deque[str] = collections.deque(maxlen=40)
        lines: queue.Queue[str] = queue.Queue()
        # Read on threads (select() does not work on Windows pipes): stdout's one line, the bound
        # addresses, and stderr's log to its end (a full pipe would block the server).
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()), daemon=True).start()
        self._stderr = threading.Thread(target=self._drain_stderr, daemon=True)
        self._stderr.start()
        try:
            line = lines.get(timeout=timeout)
            bound = json.loads(line)
            self.grpc: str = bound["grpc"]
            self.http: str = bound["http"]
        except (queue.Empty, ValueError, KeyError, TypeError) as e:
            self.close()
            reason = "did not start in time" if isinstance(e, queue.Empty) else "did not start"
            raise RuntimeError(f"{binary} serve {reason}:\n" + "\n".join(self._log)) from None

    def _drain_stderr(self) -> None:
        for line in self.proc.stderr:
            self._log.append(line.rstrip())

    @property
    def running(self) -> bool:
        return self.proc.poll() is None

    def close(self, timeout: float = 10.0) -> int | None:
        """Stops the server (terminate, then kill after `timeout` s); returns its exit code."""
        if self.running:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._stderr.join(timeout=2)  # the last log lines, for the error of a failed start
        self.proc.stdout.close()
        if not self._stderr.is_alive():
            self.proc.stderr.close()
        return self.proc.returncode

    def __enter__(self) -> LocalServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
