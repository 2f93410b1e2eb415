"""`resecta serve` end to end over HTTP/JSON: the real binary, real sockets. The same operations and
error codes as the gRPC face, the OpenAPI document, server-sent watch events, restart recovery."""
import base64
import json
import subprocess
import sys
import threading
import urllib.parse

import nibabel as nib
import numpy as np
import pytest
import requests

from conftest import ROOT
from server_harness import Server, phantom, server  # noqa: F401 (fixtures)

sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
from resecta_client.wire import apply_delta, decode_mesh  # noqa: E402

ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3]}


def problem(r, status, code):
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    p = r.json()
    assert p["code"] == code, p
    return p


def session(url, name="e2e"):
    r = requests.post(f"{url}/v1/sessions", json={"display_name": name}, timeout=30)
    assert r.status_code == 201, r.text
    return r.json()["id"]


def csv(values):
    return ",".join(repr(float(v)) for v in values)


def upload_raw(url, sid, path, cut=0):
    img = nib.load(str(path))
    a = img.affine
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    direction = (a[:3, :3] / spacing).reshape(-1)
    data = np.asarray(img.dataobj).astype("<u2").transpose(2, 1, 0).tobytes()
    q = urllib.parse.urlencode({
        "format": "raw", "data_type": "u16",
        "dims": ",".join(map(str, img.shape)), "spacing": csv(spacing), "origin": csv(a[:3, 3]), "direction": csv(direction),
        "roles": json.dumps(ROLES)})
    return requests.put(f"{url}/v1/sessions/{sid}/label-map?{q}", data=data[: len(data) - cut],
                        timeout=60)


def edit(url, sid, op, base=0):
    return requests.post(f"{url}/v1/sessions/{sid}/edits", json={"base_version": base, "edit": op},
                         timeout=60)


INIT = {"op": "init_from_end_point", "name": "r1", "end_point": [-30.0, 0.0, 0.0], "grid": [4, 4]}


def drag(point):
    return {"op": "event", "event": {"op": "set_control_point", "name": "r1", "i": 1, "j": 2,
                                     "point": list(point)}}


def sse(response):
    """(id, event, data) of each server-sent event."""
    ev = {}
    for raw in response.iter_lines(decode_unicode=True):
        if raw is None:
            continue
        if raw == "":
            if "data" in ev:
                yield ev.get("id"), ev.get("event"), json.loads(ev["data"])
            ev = {}
        elif not raw.startswith(":"):
            key, _, value = raw.partition(":")
            ev[key] = value[1:] if value.startswith(" ") else value


def test_openapi_lists_what_the_server_answers(server):
    doc = requests.get(f"{server.http_url}/v1/openapi.json", timeout=10).json()
    assert doc["openapi"].startswith("3.1")
    for path, ops in doc["paths"].items():
        concrete = path.replace("{id}", "nope").replace("{name}", "nope")
        for method in ops:
            r = requests.request(method.upper(), f"{server.http_url}{concrete}", timeout=10)
            code = r.json().get("code") if r.headers.get("content-type", "").startswith(
                "application/problem+json") else None
            assert r.status_code != 405 and code != "NO_ROUTE", (method, path, r.status_code)
    problem(requests.get(f"{server.http_url}/v1/nothing", timeout=10), 404, "NO_ROUTE")


def test_edits_watch_and_volumes_over_http(server, phantom, tmp_path):
    url = server.http_url
    sid = session(url)
    r = upload_raw(url, sid, phantom)
    assert r.status_code == 200, r.text
    assert r.json()["dims"] == list(nib.load(str(phantom)).shape)
    version = requests.get(f"{url}/v1/sessions/{sid}", timeout=10).json()["plan_version"]
    watch = requests.get(f"{url}/v1/sessions/{sid}/watch", stream=True, timeout=60)
    assert watch.headers["content-type"].startswith("text/event-stream")
    events = sse(watch)
    _, kind, snap = next(events)
    assert kind == "snapshot"
    out = edit(url, sid, INIT, version)
    assert out.status_code == 200, out.text
    v1 = out.json()["plan_version"]
    assert out.json()["resections"][0]["resection"]["name"] == "r1"
    v2 = edit(url, sid, drag((-28.0, 3.0, 2.0)), v1).json()["plan_version"]
    mesh, ids = None, []
    for eid, kind, ev in events:
        if kind != "delta":
            continue
        ids.append(int(eid))
        (u,) = ev["body"]["updates"]
        data = base64.b64decode(u["bytes"])
        mesh = decode_mesh(data) if u["full"] else apply_delta(mesh, data)
        if ev["plan_version"] == v2:
            break
    watch.close()
    assert ids == sorted(ids) and len(ids) == 2
    assert mesh is not None and mesh["positions"].shape[1] == 3
    # The snapshot + deltas a watcher applied match the resection model the server exports now.
    ply = requests.get(f"{url}/v1/sessions/{sid}/models/r1?format=ply", timeout=30)
    assert ply.status_code == 200
    (tmp_path / "r1.ply").write_bytes(ply.content)
    from conftest import resecta_bin
    info = json.loads(subprocess.run([resecta_bin(), "info", str(tmp_path / "r1.ply"), "--json"],
                                     check=True, capture_output=True, text=True).stdout)
    assert info["vertices"] == len(mesh["positions"])
    assert info["triangles"] == len(mesh["triangles"])
    lo = np.nanmin(mesh["positions"], axis=0)
    assert lo == pytest.approx(info["bounds"][0], abs=1e-3)
    vols = requests.get(f"{url}/v1/sessions/{sid}/volumes", timeout=60).json()
    assert vols["plan_version"] == v2 and vols["volumes"]["total_ml"] > 0
    plan = requests.get(f"{url}/v1/sessions/{sid}/plan", timeout=10)
    assert plan.headers["resecta-plan-version"] == str(v2)
    assert plan.json()["resections"][0]["control_points"][6] == pytest.approx([-28.0, 3.0, 2.0])


def test_sigterm_ends_open_watch_streams(tmp_path):
    """Graceful shutdown does not wait for open server-sent event streams: a watch ends with an
    `error` event (503 UNAVAILABLE) and the process exits 0 within a few seconds."""
    s = Server()
    try:
        sid = session(s.http_url)
        watch = requests.get(f"{s.http_url}/v1/sessions/{sid}/watch", stream=True, timeout=60)
        events = sse(watch)
        assert next(events)[1] == "snapshot"
        rest = []
        reader = threading.Thread(target=lambda: rest.extend(events), daemon=True)
        reader.start()
        s.sigterm_while(reader)
        assert rest and rest[-1][1] == "error", rest
        assert rest[-1][2]["status"] == 503 and rest[-1][2]["code"] == "UNAVAILABLE", rest[-1]
    finally:
        if s.proc.poll() is None:
            s.kill()


def test_bad_input_over_http(server, phantom):
    url = server.http_url
    problem(requests.get(f"{url}/v1/sessions/nope", timeout=10), 404, "SESSION_NOT_FOUND")
    sid = session(url)
    problem(upload_raw(url, sid, phantom, cut=1), 400, "BAD_LABEL_MAP")
    problem(edit(url, sid, INIT), 409, "NO_LABEL_MAP")
    assert upload_raw(url, sid, phantom).status_code == 200
    v = edit(url, sid, INIT).json()["plan_version"]
    problem(edit(url, sid, drag(("nan", 0, 0)), v), 400, "INVALID_ARGUMENT")
    body = '{"base_version": %d, "edit": %s}' % (v, json.dumps(drag((0, 0, 0))).replace("[0, 0, 0]", "[1e999, 0, 0]"))
    r = requests.post(f"{url}/v1/sessions/{sid}/edits", data=body, timeout=10,
                      headers={"content-type": "application/json"})
    problem(r, 400, "INVALID_ARGUMENT")
    stale = problem(edit(url, sid, drag((-28.0, 0.0, 0.0)), v - 1), 409, "STALE_VERSION")
    assert stale["current_version"] == v
    r = requests.post(f"{url}/v1/sessions/{sid}/edits", data=b"{not json", timeout=10,
                      headers={"content-type": "application/json"})
    problem(r, 400, "INVALID_ARGUMENT")
    assert requests.get(f"{url}/v1/sessions/{sid}", timeout=10).json()["plan_version"] == v
    r = requests.get(f"{url}/v1/sessions", headers={"resecta-api-version": "v2"}, timeout=10)
    p = problem(r, 400, "API_VERSION_MISMATCH")
    assert "v2" in p["detail"] and "v1" in p["detail"]


def test_restart_keeps_acknowledged_http_edits(tmp_path, phantom):
    data = tmp_path / "data"
    s = Server(data_dir=data)
    try:
        sid = session(s.http_url)
        assert upload_raw(s.http_url, sid, phantom).status_code == 200
        v = edit(s.http_url, sid, INIT).json()["plan_version"]
        for k in range(5):
            v = edit(s.http_url, sid, drag((-30.0 + k, 1.0, 1.0)), v).json()["plan_version"]
        metrics = requests.get(f"{s.http_url}/metrics", timeout=10).text
        assert "resecta_edit_seconds_count 6" in metrics, metrics
        assert "resecta_edits_in_flight 0" in metrics
        assert 'resecta_http_requests_total{route="/v1/sessions/{id}/edits",status="200"} 6' in metrics
    finally:
        s.kill()
    s2 = Server(data_dir=data)
    try:
        info = requests.get(f"{s2.http_url}/v1/sessions/{sid}", timeout=60).json()
        assert info["plan_version"] == v
        plan = requests.get(f"{s2.http_url}/v1/sessions/{sid}/plan", timeout=60).json()
        assert plan["resections"][0]["control_points"][6] == pytest.approx([-26.0, 1.0, 1.0])
        assert requests.get(f"{s2.http_url}/metrics", timeout=10).status_code == 200
    finally:
        s2.stop()


def test_idle_sessions_expire_and_limits_come_from_the_config_file(tmp_path):
    cfg = tmp_path / "resecta.toml"
    cfg.write_text("[limits]\nmax_sessions = 2\nidle_expiry_s = 1\n")
    s = Server("--config", str(cfg))
    try:
        info = requests.get(f"{s.http_url}/v1/info", timeout=10).json()
        assert info["limits"]["max_sessions"] == 2
        a, b = session(s.http_url, "a"), session(s.http_url, "b")
        problem(requests.post(f"{s.http_url}/v1/sessions", json={"display_name": "c"}, timeout=10),
                429, "SESSION_QUOTA")
        import time
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if requests.get(f"{s.http_url}/v1/sessions", timeout=10).json()["sessions"] == []:
                break
            time.sleep(0.5)
        problem(requests.get(f"{s.http_url}/v1/sessions/{a}", timeout=10), 404, "SESSION_NOT_FOUND")
        problem(requests.get(f"{s.http_url}/v1/sessions/{b}", timeout=10), 404, "SESSION_NOT_FOUND")
        assert session(s.http_url, "d")
    finally:
        s.stop()
