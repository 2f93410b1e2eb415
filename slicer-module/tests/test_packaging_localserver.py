"""ResectaLib.localserver against the real `resecta serve`: where the program is found, the bound
addresses it reports, a client session on it, a clean stop, and clear errors when it does not
start."""

import os
import stat

import pytest

from conftest import resecta_bin
from ResectaLib import deps, localserver


def _script(path, body):
    path.write_text("#!/bin/sh\n" + body)
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return str(path)


def test_find_binary_prefers_the_setting_then_the_environment_then_path(tmp_path, monkeypatch):
    setting, env, on_path = (_script(tmp_path / n, "") for n in ("setting", "env", "resecta"))
    monkeypatch.setenv("RESECTA_BIN", env)
    monkeypatch.setenv("PATH", str(tmp_path))
    assert localserver.find_binary(setting) == setting
    assert localserver.find_binary(str(tmp_path / "gone")) == env, "a stale setting is skipped"
    assert localserver.find_binary(None) == env
    monkeypatch.delenv("RESECTA_BIN")
    assert localserver.find_binary("") == on_path
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    assert localserver.find_binary(None) is None


def test_a_local_server_serves_the_client_and_stops_cleanly(monkeypatch):
    # Variables a user may have set for a shared server must not reach the local one.
    monkeypatch.setenv("RESECTA_TOKEN", "a-token-of-more-than-16-characters")
    monkeypatch.setenv("RESECTA_GRPC", "0.0.0.0:1")
    deps.use_client()
    from resecta_client import Client

    with localserver.LocalServer(resecta_bin()) as server:
        host, port = server.grpc.rsplit(":", 1)
        assert host == "127.0.0.1" and int(port) > 0 and server.http != server.grpc
        with Client(server.grpc) as client:  # no token
            assert client.server_info().server_version
            session = client.create_session("local")
            assert session.info().id in {s.id for s in client.list_sessions()}
    assert not server.running and server.proc.returncode == 0, "stopped gracefully (SIGTERM)"
    assert server.close() == 0, "closing twice is harmless"


def test_a_program_that_fails_reports_its_output(tmp_path):
    failing = _script(tmp_path / "resecta", 'echo "error: no such flag --grpc" >&2\nexit 2\n')
    with pytest.raises(RuntimeError, match="did not start:\nerror: no such flag --grpc"):
        localserver.LocalServer(failing)


def test_a_program_that_hangs_is_stopped_after_the_timeout(tmp_path):
    hanging = _script(tmp_path / "resecta", f"echo $$ > {tmp_path / 'pid'}\nexec sleep 60\n")
    with pytest.raises(RuntimeError, match="did not start in time"):
        localserver.LocalServer(hanging, timeout=1.0)
    pid = int((tmp_path / "pid").read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
