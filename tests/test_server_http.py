"""`resecta serve` end to end over HTTP/JSON: the real binary, real sockets. The same operations and
error codes as the gRPC face, the OpenAPI document, server-sent watch events, restart recovery."""
import base64
import json
import subprocess
import sys
import threading

from google.protobuf import json_format
import nibabel as nib
import numpy as np
import pytest
import requests

from conftest import ROOT
from server_harness import (Server, fibonacci_sphere, generate_stubs, phantom,  # noqa: F401 (fixtures)
                            server)

sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
from resecta_client.wire import apply_delta, decode_mesh  # noqa: E402

ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3]}


@pytest.fixture(scope="module")
def stubs(tmp_path_factory):
    return generate_stubs(tmp_path_factory.mktemp("stubs"))


def problem(r, status, code):
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    p = r.json()
    assert p["code"] == code, p
    return p


def session(url, name="e2e"):
    r = requests.post(f"{url}/v1/sessions", json={"displayName": name}, timeout=30)
    assert r.status_code == 201, r.text
    return r.json()["session"]["id"]


def plan_version(url, sid):
    """A session's plan version (a uint64: a decimal string in proto JSON, absent when 0)."""
    r = requests.get(f"{url}/v1/sessions/{sid}", timeout=60)
    assert r.status_code == 200, r.text
    return int(r.json()["session"].get("planVersion", "0"))


def raw_header(path):
    """The `RawLabelMapHeader` of a NIfTI label map as proto JSON, and its voxels (u16)."""
    img = nib.load(str(path))
    a = img.affine
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    direction = (a[:3, :3] / spacing).reshape(-1)
    data = np.asarray(img.dataobj).astype("<u2").transpose(2, 1, 0).tobytes()
    header = {"dims": list(img.shape), "spacing": spacing.tolist(), "origin": a[:3, 3].tolist(),
              "direction": direction.tolist(), "dataType": "DATA_TYPE_UINT16", "roles": ROLES}
    return header, data


def upload_raw(url, sid, path, cut=0):
    header, data = raw_header(path)
    return requests.put(f"{url}/v1/sessions/{sid}/label-map", params={"raw": json.dumps(header)},
                        data=data[: len(data) - cut], timeout=60)


def edit(url, sid, op, base=0):
    """POST an `EditRequest` (proto JSON): `op` is its operation, e.g. `{"undo": {}}`."""
    return requests.post(f"{url}/v1/sessions/{sid}/edits",
                         json={"baseVersion": str(base), **op}, timeout=60)


INIT = {"initFromEndPoint": {"name": "r1", "endPoint": {"x": -30.0, "y": 0.0, "z": 0.0},
                             "gridM": 4, "gridN": 4}}


def xyz(point):
    return dict(zip("xyz", point))


def drag(point):
    return {"setControlPoint": {"name": "r1", "i": 1, "j": 2, "point": xyz(point)}}


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
    assert r.json()["labelMap"]["dims"] == list(nib.load(str(phantom)).shape)
    version = plan_version(url, sid)
    watch = requests.get(f"{url}/v1/sessions/{sid}/watch", stream=True, timeout=60)
    assert watch.headers["content-type"].startswith("text/event-stream")
    events = sse(watch)
    _, kind, snap = next(events)
    assert kind == "snapshot" and "snapshot" in snap
    out = edit(url, sid, INIT, version)
    assert out.status_code == 200, out.text
    v1 = int(out.json()["planVersion"])
    assert out.json()["resections"][0]["resection"]["name"] == "r1"
    v2 = int(edit(url, sid, drag((-28.0, 3.0, 2.0)), v1).json()["planVersion"])
    mesh, ids = None, []
    for eid, kind, ev in events:
        if kind != "delta":
            continue
        ids.append(int(eid))
        assert ev["seq"] == eid
        (r1,) = [r for r in ev["delta"]["resections"] if r["name"] == "r1"]
        if "fullMesh" in r1:
            mesh = decode_mesh(base64.b64decode(r1["fullMesh"]))
        else:
            mesh = apply_delta(mesh, base64.b64decode(r1["meshDelta"]))
        if int(ev["planVersion"]) == v2:
            break
    watch.close()
    assert ids == sorted(ids) and len(ids) == 2
    assert mesh is not None and mesh["positions"].shape[1] == 3
    # The snapshot + deltas a watcher applied match the resection model the server exports now.
    ply = requests.get(f"{url}/v1/sessions/{sid}/models/r1", params={"format": "MODEL_FORMAT_PLY"},
                       timeout=30)
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
    assert int(vols["planVersion"]) == v2 and vols["volumes"]["totalMl"] > 0
    plan = requests.get(f"{url}/v1/sessions/{sid}/plan", timeout=10).json()
    assert int(plan["planVersion"]) == v2
    document = json.loads(plan["planJson"])
    assert document["resections"][0]["control_points"][6] == pytest.approx([-28.0, 3.0, 2.0])


def test_http_bodies_are_the_grpc_messages_in_proto_json(server, phantom, stubs):
    """The same requests on both faces of one server: the HTTP body is `MessageToJson` of the
    gRPC request, and the answers are equal once the gRPC one is mapped to JSON the same way."""
    pb, pb_grpc = stubs
    stub = pb_grpc.PlanningServiceStub(server.channel())
    url = server.http_url

    volatile = ("id", "sessionId", "createdMs", "lastAccessMs")

    def close(a, b, path=""):
        """`a` equals `b` but for volatile keys; floats within a relative 1e-9."""
        if isinstance(a, dict) and isinstance(b, dict):
            keys = (a.keys() | b.keys()) - set(volatile)
            for k in keys:
                assert k in a and k in b, f"{path}/{k}: {a.get(k)!r} vs {b.get(k)!r}"
                close(a[k], b[k], f"{path}/{k}")
        elif isinstance(a, list) and isinstance(b, list):
            assert len(a) == len(b), f"{path}: {len(a)} vs {len(b)} items"
            for k, (x, y) in enumerate(zip(a, b)):
                close(x, y, f"{path}/{k}")
        elif isinstance(a, float) or isinstance(b, float):
            assert a == pytest.approx(b, rel=1e-9), f"{path}: {a} vs {b}"
        else:
            assert a == b, f"{path}: {a!r} vs {b!r}"

    def same(message, body):
        close(json.loads(json_format.MessageToJson(message)), body)

    same(stub.GetServerInfo(pb.GetServerInfoRequest()),
         requests.get(f"{url}/v1/info", timeout=10).json())
    a = stub.CreateSession(pb.CreateSessionRequest(display_name="side")).session.id
    b = session(url, "side")
    header, data = raw_header(phantom)
    grpc_header = json_format.ParseDict(header, pb.RawLabelMapHeader())
    grpc_header.session_id, grpc_header.total_bytes = a, len(data)
    chunks = [pb.UploadLabelMapRequest(raw=grpc_header)] + [
        pb.UploadLabelMapRequest(data=data[k:k + (1 << 20)]) for k in range(0, len(data), 1 << 20)]
    same(stub.UploadLabelMap(iter(chunks)), upload_raw(url, b, phantom).json())
    same(stub.GetSession(pb.GetSessionRequest(session_id=a)),
         requests.get(f"{url}/v1/sessions/{a}", timeout=10).json())

    requests_ = [
        pb.EditRequest(base_version=1, init_from_end_point=pb.InitFromEndPoint(
            name="r1", end_point=pb.Vec3(x=-30.0))),
        pb.EditRequest(base_version=2, set_control_point=pb.SetControlPoint(
            name="r1", i=1, j=2, point=pb.Vec3(x=-28.0, y=3.0, z=2.0))),
        pb.EditRequest(base_version=3, set_margin=pb.SetMargin(name="r1", margin_mm=5.0)),
        pb.EditRequest(base_version=4, undo=pb.Undo()),
    ]
    for request in requests_:
        request.session_id = a
        answer = stub.Edit(request)
        request.session_id = b
        body = json_format.MessageToJson(request)
        r = requests.post(f"{url}/v1/sessions/{b}/edits", data=body, timeout=60,
                          headers={"content-type": "application/json"})
        assert r.status_code == 200, r.text
        same(answer, r.json())
    assert json.loads(json_format.MessageToJson(requests_[0])) == {
        "sessionId": b, "baseVersion": "1", "initFromEndPoint": {"name": "r1", "endPoint": {"x": -30.0}}}
    # add_resection on both faces: the resection an answer held, under a new name.
    r1 = stub.Edit(pb.EditRequest(session_id=a, base_version=5, set_band=pb.SetBand(
        name="r1", band_mm=4.0))).resections[0].resection
    requests.post(f"{url}/v1/sessions/{b}/edits", timeout=60, json={
        "baseVersion": "5", "setBand": {"name": "r1", "bandMm": 4.0}}).raise_for_status()
    r1.name = "copy"
    add = pb.EditRequest(session_id=a, base_version=6, add_resection=pb.AddResection(resection=r1))
    answer = stub.Edit(add)
    add.session_id = b
    r = requests.post(f"{url}/v1/sessions/{b}/edits", data=json_format.MessageToJson(add),
                      timeout=60, headers={"content-type": "application/json"})
    assert r.status_code == 200, r.text
    same(answer, r.json())
    assert [s.resection.name for s in answer.resections] == ["copy"]
    same(stub.GetVolumes(pb.GetVolumesRequest(session_id=a)),
         requests.get(f"{url}/v1/sessions/{b}/volumes", timeout=60).json())
    same(stub.ExportPlan(pb.ExportPlanRequest(session_id=a)),
         requests.get(f"{url}/v1/sessions/{b}/plan", timeout=60).json())
    same(stub.GetSlices(pb.GetSlicesRequest(session_id=a, resection="r1", axial=0.0)),
         requests.get(f"{url}/v1/sessions/{b}/slices", params={"resection": "r1", "axial": "0"},
                      timeout=60).json())


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
    problem(upload_raw(url, sid, phantom, cut=1), 400, "INVALID_ARGUMENT")
    problem(edit(url, sid, INIT), 409, "NO_LABEL_MAP")
    assert upload_raw(url, sid, phantom).status_code == 200
    v = int(edit(url, sid, INIT).json()["planVersion"])
    problem(edit(url, sid, drag(("NaN", 0, 0)), v), 400, "INVALID_ARGUMENT")
    problem(edit(url, sid, {"undo": {}, "redo": {}}, v), 400, "INVALID_ARGUMENT")
    problem(edit(url, sid, {"edit": {"op": "undo"}}, v), 400, "INVALID_ARGUMENT")
    body = '{"baseVersion": "%d", "setControlPoint": {"name": "r1", "i": 1, "j": 2, "point": {"x": 1e999}}}' % v
    r = requests.post(f"{url}/v1/sessions/{sid}/edits", data=body, timeout=10,
                      headers={"content-type": "application/json"})
    problem(r, 400, "INVALID_ARGUMENT")
    stale = problem(edit(url, sid, drag((-28.0, 0.0, 0.0)), v - 1), 409, "STALE_VERSION")
    assert stale["current_version"] == v
    r = requests.post(f"{url}/v1/sessions/{sid}/edits", data=b"{not json", timeout=10,
                      headers={"content-type": "application/json"})
    problem(r, 400, "INVALID_ARGUMENT")
    assert plan_version(url, sid) == v
    r = requests.get(f"{url}/v1/sessions", headers={"resecta-api-version": "v2"}, timeout=10)
    p = problem(r, 400, "API_VERSION_MISMATCH")
    assert "v2" in p["detail"] and "v1" in p["detail"]


def test_restart_keeps_acknowledged_http_edits(tmp_path, phantom):
    data = tmp_path / "data"
    s = Server(data_dir=data)
    try:
        sid = session(s.http_url)
        assert upload_raw(s.http_url, sid, phantom).status_code == 200
        v = int(edit(s.http_url, sid, INIT).json()["planVersion"])
        for k in range(5):
            v = int(edit(s.http_url, sid, drag((-30.0 + k, 1.0, 1.0)), v).json()["planVersion"])
        metrics = requests.get(f"{s.http_url}/metrics", timeout=10).text
        assert "resecta_edit_seconds_count 6" in metrics, metrics
        assert "resecta_edits_in_flight 0" in metrics
        assert 'resecta_http_requests_total{route="/v1/sessions/{id}/edits",status="200"} 6' in metrics
    finally:
        s.kill()
    s2 = Server(data_dir=data)
    try:
        assert plan_version(s2.http_url, sid) == v
        plan = requests.get(f"{s2.http_url}/v1/sessions/{sid}/plan", timeout=60).json()
        document = json.loads(plan["planJson"])
        assert document["resections"][0]["control_points"][6] == pytest.approx([-26.0, 1.0, 1.0])
        assert requests.get(f"{s2.http_url}/metrics", timeout=10).status_code == 200
    finally:
        s2.stop()


def test_idle_sessions_expire_and_limits_come_from_the_config_file(tmp_path):
    cfg = tmp_path / "resecta.toml"
    cfg.write_text("[limits]\nmax_sessions = 2\nidle_expiry_s = 1\n")
    s = Server("--config", str(cfg))
    try:
        info = requests.get(f"{s.http_url}/v1/info", timeout=10).json()
        assert info["limits"]["maxSessions"] == 2
        a, b = session(s.http_url, "a"), session(s.http_url, "b")
        problem(requests.post(f"{s.http_url}/v1/sessions", json={"displayName": "c"}, timeout=10),
                429, "SESSION_QUOTA")
        import time
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if requests.get(f"{s.http_url}/v1/sessions", timeout=10).json().get("sessions") is None:
                break
            time.sleep(0.5)
        problem(requests.get(f"{s.http_url}/v1/sessions/{a}", timeout=10), 404, "SESSION_NOT_FOUND")
        problem(requests.get(f"{s.http_url}/v1/sessions/{b}", timeout=10), 404, "SESSION_NOT_FOUND")
        assert session(s.http_url, "d")
    finally:
        s.stop()


def test_point_clouds_close_over_http(server):
    """`POST /v1/point-clouds/reconstruct`: 2,000 points of a 20 mm sphere as JSON, with and
    without normals → the mesh (base64 RSMS), every vertex within 0.3 mm of the sphere."""
    points, normals = fibonacci_sphere(2000, 20.0, (0.0, 10.0, -5.0))
    for given in (False, True):
        body = {"positions": points.reshape(-1).tolist(), "depth": 6}
        if given:
            body["normals"] = normals.reshape(-1).tolist()
        r = requests.post(f"{server.http_url}/v1/point-clouds/reconstruct", json=body, timeout=300)
        assert r.status_code == 200, r.text
        v = r.json()
        mesh = decode_mesh(base64.b64decode(v["mesh"]))
        d = np.linalg.norm(mesh["positions"].astype(np.float64) - (0.0, 10.0, -5.0), axis=1)
        assert np.abs(d - 20.0).max() < 0.3, np.abs(d - 20.0).max()
        assert int(v["vertexCount"]) == mesh["vertex_count"]
        rep = v["report"]
        assert rep["normals"] == ("NORMAL_SOURCE_GIVEN" if given else "NORMAL_SOURCE_ESTIMATED")
        assert (rep["points"], rep["depth"], rep["neighbours"]) == (2000, 6, 10)
        assert ("components" in rep) != given


def test_bad_point_clouds_over_http_are_problems(tmp_path):
    """Malformed clouds, clouds beyond the configured limits, an empty body and absurd numbers:
    400 problem documents naming the problem, never a 5xx."""
    cfg = tmp_path / "resecta.toml"
    cfg.write_text("[limits]\nmax_cloud_points = 1000\nmax_cloud_depth = 6\n")
    s = Server("--config", str(cfg))
    url = f"{s.http_url}/v1/point-clouds/reconstruct"
    try:
        info = requests.get(f"{s.http_url}/v1/info", timeout=10).json()
        assert (info["limits"]["maxCloudPoints"], info["limits"]["maxCloudDepth"]) == (1000, 6)
        points, normals = fibonacci_sphere(600, 15.0)
        flat, nflat = points.reshape(-1).tolist(), normals.reshape(-1).tolist()
        cases = [
            ({"positions": flat[:-2]}, "positions: needs x, y, z per point"),
            ({"positions": ["NaN"] + flat[1:]}, "positions[0]: must be finite"),
            ({"positions": flat, "normals": nflat[:3]}, "normals: must be empty or hold as many"),
            ({"positions": flat, "normals": [0.0] * len(nflat)}, "normal 0 is zero"),
            ({"positions": fibonacci_sphere(1001, 15.0)[0].reshape(-1).tolist()},
             "max_cloud_points (1000)"),
            ({"positions": flat, "depth": 7}, "max_cloud_depth"),
            ({"positions": flat, "depth": 4294967295}, "max_cloud_depth"),
            ({"positions": [1e300] * 12}, "max_coordinate_mm"),
            ({"positions": [1.0, 2.0, 3.0] * 20}, "1 distinct points given"),
            ({"positions": [float(k) for k in range(60)]}, "one line"),
            ({}, "0 distinct points given"),
        ]
        for body, message in cases:
            p = problem(requests.post(url, json=body, timeout=60), 400, "INVALID_ARGUMENT")
            assert message in p["detail"], (message, p)
        # An empty body, and one that is no JSON.
        p = problem(requests.post(url, data=b"", timeout=60), 400, "INVALID_ARGUMENT")
        assert "distinct points" in p["detail"], p
        problem(requests.post(url, data=b"{", timeout=60), 400, "INVALID_ARGUMENT")
        assert requests.post(url, json={"positions": flat, "depth": 6}, timeout=300).status_code == 200
    finally:
        s.stop()
