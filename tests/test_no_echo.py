"""Errors never carry client-supplied text (issue #19, item 6), end to end on the real binary.

One server (SQLite store, bearer token, JSON logs at debug level) gets, over both faces, sessions
whose display names carry MARKER (a stand-in for a patient's name); NRRD, .nhdr, .seg.nrrd,
MetaImage and NIfTI uploads that carry MARKER in every free-text field and name (comments, free
fields, key/value pairs, segment names and ids, data file names, NIfTI descrip / aux_file /
intent_name / db_name / data_type and an extension), some valid and some made invalid in
different ways so that each error path runs; edits, model exports, slices and plan imports that
name resections MARKER; a 10 KB session id that starts with MARKER; MARKER in header values, an
unknown route, an unknown gRPC method and unknown JSON fields and enum values.

Then MARKER must appear in no error: not in a gRPC status message, its details, its initial or
trailing metadata, nor in an HTTP error's body or headers; not in any line the server logged,
and not in `GET /metrics`. A 10 KB id over gRPC is NOT_FOUND (echoed, it overflowed the client's
metadata limit and came back RESOURCE_EXHAUSTED).

Successful answers are not errors and are *not* checked: they legitimately return the client's
own data (the display name in CreateSession/GetSession/ListSessions, a resection's name in an
Edit answer, the plan in ExportPlan). `ok()` marks each such call."""
import gzip
import io
import json
import threading

import grpc
import nibabel as nib
import numpy as np
import pytest
import requests

from server_harness import Server, generate_stubs, phantom  # noqa: F401 (fixture)

MARKER = "PATIENTMARKER"
TOKEN = "no-echo-token-0123456789"
ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3]}
LONG_ID = MARKER + "x" * 10_000


# ---- the server, its logs, and the checks ------------------------------------------------------

class Logs:
    """Drains the server's stderr (JSON lines) while it runs, so that debug logs never fill the
    pipe, and keeps every line."""

    def __init__(self, proc):
        self.lines = []
        self.thread = threading.Thread(target=self._drain, args=(proc.stderr,), daemon=True)
        self.thread.start()

    def _drain(self, stream):
        for line in stream:
            self.lines.append(line)


@pytest.fixture(scope="module")
def stubs(tmp_path_factory):
    return generate_stubs(tmp_path_factory.mktemp("stubs"))


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    data = tmp_path_factory.mktemp("no-echo") / "data"
    s = Server("--log-json", "--token", TOKEN, data_dir=data, env={"RUST_LOG": "debug"})
    logs = Logs(s.proc)
    yield s, logs
    if s.proc.poll() is None:
        s.kill()


class Seen:
    """Every error answer, checked as it comes: no MARKER anywhere in it."""

    def __init__(self):
        self.errors = 0

    def grpc(self, call, code, *args, **kw):
        """Runs `call`, which must fail with `code`; for streams, reads them to the end."""
        with pytest.raises(grpc.RpcError) as e:
            r = call(*args, **kw)
            if hasattr(r, "__iter__") and not isinstance(r, (bytes, str)):
                for _ in r:
                    pass
        err = e.value
        assert err.code() == code, (err.code(), err.details())
        parts = [err.details() or ""]
        for md in (err.initial_metadata() or (), err.trailing_metadata() or ()):
            for key, value in md:
                parts.append(key)
                parts.append(value.decode("latin-1") if isinstance(value, bytes) else value)
        for p in parts:
            assert MARKER not in p, f"gRPC {code}: client text in {p[:300]!r}"
        self.errors += 1
        return err

    def http(self, r, status, code=None):
        assert r.status_code == status, (r.status_code, r.text[:500])
        assert MARKER not in r.text, f"HTTP {status}: client text in the body {r.text[:500]!r}"
        for key, value in r.headers.items():
            assert MARKER not in key and MARKER not in value, f"HTTP {status}: header {key}"
        if code is not None:
            assert r.json()["code"] == code, r.text
        self.errors += 1
        return r


def ok(value):
    """A successful answer: the client's own data may come back in it (names, plans), so it is
    deliberately not checked for MARKER."""
    return value


def md(version="v1", token=TOKEN):
    m = [("resecta-api-version", version)]
    if token is not None:
        m.append(("authorization", f"Bearer {token}"))
    return m


AUTH = {"authorization": f"Bearer {TOKEN}", "resecta-api-version": "v1"}


# ---- files with MARKER in every free-text field ------------------------------------------------

def phantom_volume(path):
    """The phantom's labels (i fastest, as u16 bytes), dims and RAS affine."""
    img = nib.load(str(path))
    data = np.asarray(img.dataobj).astype("<u2")
    return data.transpose(2, 1, 0).tobytes(), list(data.shape), img.affine


def nrrd_header(dims, affine, **fields):
    """An NRRD header (RAS space) with MARKER in a comment, free fields and key/value pairs;
    `fields` override or add fields (None drops one)."""
    cols = [affine[:3, c] for c in range(3)]
    base = {
        "type": "ushort",
        "dimension": "3",
        "space": "right-anterior-superior",
        "sizes": " ".join(map(str, dims)),
        "space directions": " ".join("(%r,%r,%r)" % tuple(map(float, c)) for c in cols),
        "space origin": "(%r,%r,%r)" % tuple(map(float, affine[:3, 3])),
        "endian": "little",
        "encoding": "raw",
        "content": f"{MARKER} abdomen CT",
        "labels": f'"{MARKER}" "{MARKER}" "{MARKER}"',
    }
    base.update(fields)
    lines = ["NRRD0004", f"# {MARKER} 1970-01-01 scanned"]
    lines += [f"{k}: {v}" for k, v in base.items() if v is not None]
    lines += [f"{MARKER}:={MARKER}", f"PatientName:={MARKER}", f"Segmentation_{MARKER}:={MARKER}"]
    return "\n".join(lines) + "\n"


def nrrd(vol, **fields):
    raw, dims, affine = vol
    return (nrrd_header(dims, affine, **fields) + "\n").encode() + raw


def seg_nrrd(vol, **segment0):
    """A one-layer .seg.nrrd (uchar) whose segment names, ids and tags carry MARKER."""
    raw, dims, affine = vol
    data = np.frombuffer(raw, dtype="<u2").astype("u1").tobytes()
    head = nrrd_header(dims, affine, type="uchar", endian=None)
    for k, label in enumerate((1, 2, 3)):
        keys = {"ID": f"{MARKER}_{k}", "Name": f"{MARKER} segment {k}", "LabelValue": str(label),
                "Layer": "0", "Color": "1 0 0", "Tags": f"patient:{MARKER}|",
                "NameAutoGenerated": "0"}
        if k == 0:
            keys.update(segment0)
        head += "".join(f"Segment{k}_{key}:={value}\n" for key, value in keys.items())
    return (head + "\n").encode() + data


def mha(vol, **fields):
    """A .mha (data LOCAL) with MARKER in its comment, orientation and an unknown key."""
    raw, dims, affine = vol
    spacing = np.linalg.norm(affine[:3, :3], axis=0)
    base = {
        "ObjectType": "Image", "NDims": "3", "Comment": f"{MARKER} 1970-01-01",
        "BinaryData": "True", "BinaryDataByteOrderMSB": "False", "CompressedData": "False",
        "TransformMatrix": "1 0 0 0 1 0 0 0 1", "Offset": "0 0 0",
        "ElementSpacing": " ".join(map(repr, map(float, spacing))),
        "DimSize": " ".join(map(str, dims)), "AnatomicalOrientation": MARKER,
        MARKER: MARKER, "ElementType": "MET_USHORT",
    }
    base.update(fields)
    data_file = base.pop("ElementDataFile", "LOCAL")
    text = "".join(f"{k} = {v}\n" for k, v in base.items() if v is not None)
    return (text + f"ElementDataFile = {data_file}\n").encode() + raw


def nifti(path, gz=True, datatype=None, cut=0):
    """The phantom as NIfTI-1 with MARKER in every text field and in a comment extension."""
    img = nib.load(str(path))
    data = np.asarray(img.dataobj).astype("<u2")
    out = nib.Nifti1Image(data, img.affine)
    h = out.header
    h["descrip"] = f"{MARKER} liver CT".encode()
    h["aux_file"] = MARKER.encode()
    h["intent_name"] = MARKER.encode()
    h["db_name"] = MARKER.encode()
    h["data_type"] = MARKER.encode()[:10]
    h.extensions.append(nib.nifti1.Nifti1Extension("comment", f"{MARKER} 1970".encode()))
    b = bytearray(out.to_bytes())
    if datatype is not None:
        b[70:72] = np.int16(datatype).tobytes()
    if cut:
        b = b[:-cut]
    return gzip.compress(bytes(b)) if gz else bytes(b)


def uploads(phantom_path):
    """(name, format, bytes, valid) of every upload."""
    vol = phantom_volume(phantom_path)
    m = MARKER
    return [
        # Valid: MARKER only in free text.
        ("nrrd", "NRRD", nrrd(vol), True),
        ("seg.nrrd", "SEG_NRRD", seg_nrrd(vol), True),
        ("mha", "METAIMAGE", mha(vol), True),
        ("nii.gz", "NIFTI", nifti(phantom_path), True),
        ("nii auto", "AUTO", nifti(phantom_path, gz=False), True),
        # Invalid, each in another way.
        ("nhdr: data file named after the patient", "NRRD",
         nrrd_header(vol[1], vol[2], **{"data file": f"{m}.raw"}).encode(), False),
        ("nhdr auto", "AUTO",
         nrrd_header(vol[1], vol[2], **{"data file": f"../{m}/{m}.raw.gz"}).encode(), False),
        ("nrrd type", "NRRD", nrrd(vol, type=m), False),
        ("nrrd encoding", "NRRD", nrrd(vol, encoding=m), False),
        ("nrrd space", "NRRD", nrrd(vol, space=m), False),
        ("nrrd sizes", "NRRD", nrrd(vol, sizes=f"2 2 {m}"), False),
        ("nrrd origin", "NRRD", nrrd(vol, **{"space origin": f"({m},0,0)"}), False),
        ("nrrd line", "NRRD", nrrd(vol, **{f"{m} {m}": None}).replace(
            b"\n\n", f"\n{m}\n\n".encode(), 1), False),
        ("nrrd short", "NRRD", nrrd(vol)[:-100], False),
        ("nrrd as nifti", "NIFTI", nrrd(vol), False),
        ("seg label value", "SEG_NRRD", seg_nrrd(vol, LabelValue=m), False),
        ("seg layer", "AUTO", seg_nrrd(vol, Layer=m), False),
        ("seg color", "SEG_NRRD", seg_nrrd(vol, Color=f"1 0 {m}"), False),
        ("mha data file", "METAIMAGE", mha(vol, ElementDataFile=f"{m}.raw"), False),
        ("mha element type", "METAIMAGE", mha(vol, ElementType=m), False),
        ("mha dims", "AUTO", mha(vol, DimSize=f"2 2 {m}"), False),
        ("mha spacing", "METAIMAGE", mha(vol, ElementSpacing=f"1 1 {m}"), False),
        ("nifti datatype", "NIFTI", nifti(phantom_path, datatype=1024), False),
        ("nifti truncated", "NIFTI", nifti(phantom_path, gz=False, cut=7), False),
        ("not an image", "AUTO", f"{m}\n{m}\n".encode(), False),
    ]


# ---- the test ------------------------------------------------------------------------------------

def test_no_error_log_line_or_metric_carries_client_text(served, stubs, phantom):
    s, logs = served
    pb, pb_grpc = stubs
    stub = pb_grpc.PlanningServiceStub(s.channel())
    url = s.http_url
    seen = Seen()
    NOT_FOUND, INVALID = grpc.StatusCode.NOT_FOUND, grpc.StatusCode.INVALID_ARGUMENT

    # Sessions named after the patient, on both faces.
    g_sid = ok(stub.CreateSession(pb.CreateSessionRequest(display_name=f"{MARKER} Jane Roe"),
                                  metadata=md())).session.id
    r = ok(requests.post(f"{url}/v1/sessions", json={"displayName": f"{MARKER} John Roe"},
                         headers=AUTH, timeout=30))
    assert r.status_code == 201, r.text
    h_sid = r.json()["session"]["id"]
    assert ok(stub.GetSession(pb.GetSessionRequest(session_id=g_sid), metadata=md())
              ).session.display_name.startswith(MARKER)
    seen.grpc(stub.CreateSession, INVALID, pb.CreateSessionRequest(display_name=f"{MARKER}\a"),
              metadata=md())
    seen.http(requests.post(f"{url}/v1/sessions", json={"displayName": f"{MARKER}\u0007"},
                            headers=AUTH, timeout=30), 400)

    # Uploads.
    def grpc_upload(sid, fmt, data):
        header = pb.FileLabelMapHeader(session_id=sid, format=getattr(pb, f"LABEL_MAP_FORMAT_{fmt}"),
                                       roles=pb.RoleMap(**ROLES), total_bytes=len(data))
        msgs = [pb.UploadLabelMapRequest(file=header)] + [
            pb.UploadLabelMapRequest(data=data[k:k + (1 << 20)]) for k in range(0, len(data), 1 << 20)]
        return stub.UploadLabelMap(iter(msgs), metadata=md(), timeout=120)

    def http_upload(sid, fmt, data):
        header = {"format": f"LABEL_MAP_FORMAT_{fmt}", "roles": ROLES}
        return requests.put(f"{url}/v1/sessions/{sid}/label-map", params={"file": json.dumps(header)},
                            data=data, headers=AUTH, timeout=120)

    for name, fmt, data, valid in uploads(phantom):
        if valid:
            ok(grpc_upload(g_sid, fmt, data))
            r = ok(http_upload(h_sid, fmt, data))
            assert r.status_code == 200, (name, r.text)
        else:
            err = seen.grpc(grpc_upload, INVALID, g_sid, fmt, data)
            seen.http(http_upload(h_sid, fmt, data), 400)
            assert err.details(), name
    # The last valid upload stays: the sessions hold the phantom (plan version 5 each: five loads).
    version = ok(stub.GetSession(pb.GetSessionRequest(session_id=g_sid), metadata=md())
                 ).session.plan_version
    h_version = int(ok(requests.get(f"{url}/v1/sessions/{h_sid}", headers=AUTH, timeout=30))
                    .json()["session"]["planVersion"])
    # A header naming an unknown format (the client's text) and an unknown query parameter.
    seen.http(requests.put(f"{url}/v1/sessions/{h_sid}/label-map",
                           params={"file": json.dumps({"format": MARKER})}, data=b"x",
                           headers=AUTH, timeout=30), 400)
    seen.http(requests.put(f"{url}/v1/sessions/{h_sid}/label-map", params={MARKER: "1"},
                           data=b"x", headers=AUTH, timeout=30), 400)

    # Resections named after the patient.
    end = pb.Vec3(x=-30.0, y=0.0, z=0.0)
    answer = ok(stub.Edit(pb.EditRequest(session_id=g_sid, base_version=version,
                                         init_from_end_point=pb.InitFromEndPoint(name=MARKER, end_point=end)),
                          metadata=md(), timeout=300))
    assert answer.resections[0].resection.name == MARKER
    version = answer.plan_version
    seen.grpc(stub.Edit, INVALID, pb.EditRequest(
        session_id=g_sid, base_version=version,
        init_from_end_point=pb.InitFromEndPoint(name=MARKER, end_point=end)), metadata=md())
    seen.grpc(stub.Edit, NOT_FOUND, pb.EditRequest(
        session_id=g_sid, base_version=version,
        set_margin=pb.SetMargin(name=f"{MARKER}_2", margin_mm=5.0)), metadata=md())
    seen.grpc(stub.Edit, INVALID, pb.EditRequest(
        session_id=g_sid, base_version=version, set_control_point=pb.SetControlPoint(
            name=MARKER, i=1, j=2, point=pb.Vec3(x=float("nan")))), metadata=md())
    seen.grpc(stub.ExportModel, NOT_FOUND, pb.ExportModelRequest(
        session_id=g_sid, resection=f"{MARKER}_2", format=pb.MODEL_FORMAT_STL), metadata=md())
    seen.grpc(stub.GetSlices, NOT_FOUND, pb.GetSlicesRequest(
        session_id=g_sid, resection=f"{MARKER}_2", axial=0.0), metadata=md())
    for plan in (json.dumps({"format": MARKER, "roles": {}, "resections": []}),
                 json.dumps({"format": "resecta-plan/1", "roles": MARKER}),
                 json.dumps({"format": "resecta-plan/1", MARKER: 1}),
                 '{"' + MARKER):
        seen.grpc(stub.ImportPlan, INVALID, pb.ImportPlanRequest(
            session_id=g_sid, plan_json=plan, base_version=version), metadata=md())
        seen.http(requests.put(f"{url}/v1/sessions/{h_sid}/plan", json={"planJson": plan},
                               headers=AUTH, timeout=30), 400)

    r = ok(requests.post(f"{url}/v1/sessions/{h_sid}/edits", headers=AUTH, timeout=300, json={
        "baseVersion": str(h_version), "initFromEndPoint": {"name": MARKER, "endPoint": {"x": -30.0}}}))
    assert r.status_code == 200, r.text
    h_version = int(r.json()["planVersion"])
    for body, status in [
        ({"initFromEndPoint": {"name": MARKER, "endPoint": {"x": -30.0}}}, 400),
        ({"setMargin": {"name": f"{MARKER}_2", "marginMm": 5.0}}, 404),
        ({"setMargin": {"name": MARKER, "marginMm": MARKER}}, 400),
        ({"setMargin": {"name": MARKER, MARKER: 5.0}}, 400),
        ({MARKER: {}}, 400),
    ]:
        seen.http(requests.post(f"{url}/v1/sessions/{h_sid}/edits", headers=AUTH, timeout=60,
                                json={"baseVersion": str(h_version), **body}), status)
    seen.http(requests.get(f"{url}/v1/sessions/{h_sid}/models/{MARKER}_2",
                           params={"format": "MODEL_FORMAT_STL"}, headers=AUTH, timeout=30), 404)
    seen.http(requests.get(f"{url}/v1/sessions/{h_sid}/models/{MARKER}",
                           params={"format": MARKER}, headers=AUTH, timeout=30), 400)
    seen.http(requests.get(f"{url}/v1/sessions/{h_sid}/slices",
                           params={"resection": f"{MARKER}_2", "axial": "0"}, headers=AUTH,
                           timeout=30), 404)
    seen.http(requests.get(f"{url}/v1/sessions/{h_sid}/slices", params={MARKER: "1"},
                           headers=AUTH, timeout=30), 400)
    seen.http(requests.post(f"{url}/v1/sessions", json={MARKER: 1}, headers=AUTH, timeout=30), 400)

    # A 10 KB session id: NOT_FOUND on every call, not RESOURCE_EXHAUSTED (metadata overflow).
    for call, request in [
        (stub.GetSession, pb.GetSessionRequest(session_id=LONG_ID)),
        (stub.DeleteSession, pb.DeleteSessionRequest(session_id=LONG_ID)),
        (stub.Edit, pb.EditRequest(session_id=LONG_ID, undo=pb.Undo())),
        (stub.GetVolumes, pb.GetVolumesRequest(session_id=LONG_ID)),
        (stub.ExportPlan, pb.ExportPlanRequest(session_id=LONG_ID)),
        (stub.ExportModel, pb.ExportModelRequest(session_id=LONG_ID, resection=MARKER,
                                                 format=pb.MODEL_FORMAT_STL)),
        (stub.Watch, pb.WatchRequest(session_id=LONG_ID)),
        (stub.Reconstruct, pb.ReconstructRequest(session_id=LONG_ID)),
    ]:
        seen.grpc(call, NOT_FOUND, request, metadata=md(), timeout=60)
    seen.grpc(grpc_upload, NOT_FOUND, LONG_ID, "NRRD", nrrd(phantom_volume(phantom)))
    for method, path in [("GET", ""), ("DELETE", ""), ("GET", "/volumes"), ("GET", "/plan"),
                         ("GET", "/watch"), ("POST", "/reconstruct")]:
        seen.http(requests.request(method, f"{url}/v1/sessions/{LONG_ID}{path}", headers=AUTH,
                                   json={} if method == "POST" else None, timeout=30), 404,
                  "SESSION_NOT_FOUND")
    seen.http(requests.get(f"{url}/v1/sessions/Jane%20{MARKER}", headers=AUTH, timeout=30), 404)
    # A body naming another session than the path.
    seen.http(requests.post(f"{url}/v1/sessions/{h_sid}/edits", headers=AUTH, timeout=30,
                            json={"sessionId": LONG_ID, "undo": {}}), 400)

    # Header values, routes and methods.
    seen.grpc(stub.ListSessions, grpc.StatusCode.FAILED_PRECONDITION, pb.ListSessionsRequest(),
              metadata=md(version=f"v2-{MARKER}"))
    seen.grpc(stub.ListSessions, grpc.StatusCode.UNAUTHENTICATED, pb.ListSessionsRequest(),
              metadata=md(token=f"{MARKER}-0123456789abcdef"))
    seen.http(requests.get(f"{url}/v1/sessions", timeout=30,
                           headers={**AUTH, "resecta-api-version": f"v2-{MARKER}"}), 400)
    seen.http(requests.get(f"{url}/v1/sessions", timeout=30,
                           headers={"authorization": f"Bearer {MARKER}-0123456789"}), 401)
    seen.http(requests.get(f"{url}/v1/{MARKER}", headers=AUTH, timeout=30), 404, "NO_ROUTE")
    seen.http(requests.get(f"{url}/v1/sessions/{h_sid}/{MARKER}", headers=AUTH, timeout=30), 404)
    seen.http(requests.patch(f"{url}/v1/sessions/{MARKER}", headers=AUTH, timeout=30), 405)
    unknown = s.channel().unary_unary(f"/resecta.v1.PlanningService/{MARKER}")
    seen.grpc(unknown, grpc.StatusCode.UNIMPLEMENTED, b"", metadata=md())
    unknown = s.channel().unary_unary(f"/{MARKER}.Service/Call")
    seen.grpc(unknown, grpc.StatusCode.UNIMPLEMENTED, b"", metadata=md())
    assert seen.errors >= 90, seen.errors

    # Metrics: no label value is client text.
    metrics = requests.get(f"{url}/metrics", timeout=30)
    assert metrics.status_code == 200
    assert "resecta_http_requests_total" in metrics.text
    assert MARKER not in metrics.text, [l for l in metrics.text.splitlines() if MARKER in l][:5]

    # Logs: every line the server wrote, JSON at debug level.
    assert s.stop() == 0
    logs.thread.join(timeout=30)
    lines = [l for l in logs.lines if l.strip()]
    records = [json.loads(l) for l in lines]
    levels = {r.get("level") for r in records}
    assert "DEBUG" in levels, levels
    assert any("label map decoded" in json.dumps(r) for r in records), "no debug line of the server"
    leaks = [l[:400] for l in lines if MARKER in l]
    assert not leaks, f"{len(leaks)} log line(s) carry client text:\n" + "\n".join(leaks[:10])
