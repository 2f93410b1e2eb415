"""`resecta info` against nibabel/numpy on real files, and its bad-input contract; the server's
info (limits) on both faces against the OpenAPI document, and its compute backend (`--gpu`)."""
import gzip
import json
import os
import zlib
from pathlib import Path

import nibabel as nib
import numpy as np
import pytest

NIFTI_FILES = [
    "liver/totalsegmentator-example/example_ct.nii.gz",
    "liver/totalsegmentator-example/example_ct_sm.nii.gz",
    "liver/totalsegmentator-example/v1_liver.nii.gz",
    "liver/totalsegmentator-example/example_seg_v2_on_ct_sm.nii.gz",
    "liver/msd-task08-hepaticvessel/hepaticvessel_002_label.nii.gz",
    "liver/msd-task08-hepaticvessel/hepaticvessel_008_liver_pred.nii.gz",
]


@pytest.mark.parametrize("rel", NIFTI_FILES)
def test_nifti_geometry_and_labels_match_nibabel(resecta, test_data, rel):
    path = test_data / rel
    info = resecta("info", path, "--json").json()
    img = nib.load(str(path))
    assert info["kind"] == "image" and info["format"] == "nifti"
    assert info["dims"] == list(img.shape[:3])
    # nibabel's affine is voxel→RAS mm, as ours.
    np.testing.assert_allclose(np.array(info["affine"]), img.affine, atol=1e-4)
    data = np.asarray(img.dataobj)
    if info["labels"] is not None:
        values, counts = np.unique(data, return_counts=True)
        expected = {int(v): int(c) for v, c in zip(values, counts) if v != 0}
        got = {l["value"]: l["voxels"] for l in info["labels"]}
        assert got == expected
        vox_ml = abs(np.linalg.det(img.affine[:3, :3])) / 1000.0
        for l in info["labels"]:
            assert l["ml"] == pytest.approx(l["voxels"] * vox_ml, rel=1e-9)
    else:
        assert info["value_range"] == pytest.approx([float(data.min()), float(data.max())])


def test_metaimage_matches_raw_decode(resecta, test_data):
    mhd = test_data / "heart/lasc2013-b002/gt_std.mhd"
    header = dict(line.split(" = ", 1) for line in mhd.read_text().splitlines() if " = " in line)
    info = resecta("info", mhd, "--json").json()
    assert info["dims"] == [320, 320, 140]
    np.testing.assert_allclose(info["spacing"], [float(s) for s in header["ElementSpacing"].split()], rtol=1e-6)
    ox, oy, oz = (float(s) for s in header["Offset"].split())
    # MetaImage is LPS: RAS flips x and y.
    np.testing.assert_allclose(info["origin"], [-ox, -oy, oz], atol=1e-6)
    raw = zlib.decompress((mhd.parent / header["ElementDataFile"].strip()).read_bytes())
    values, counts = np.unique(np.frombuffer(raw, dtype=np.uint8), return_counts=True)
    expected = {int(v): int(c) for v, c in zip(values, counts) if v != 0}
    assert {l["value"]: l["voxels"] for l in info["labels"]} == expected


def test_vtp_mesh_info(resecta, test_data):
    info = resecta("info", test_data / "heart/vampy-lasc2013-b003/atrium.vtp", "--json").json()
    assert info["kind"] == "mesh"
    assert info["vertices"] == 10516 and info["triangles"] == 20576


def test_human_output_names_dims(resecta, test_data):
    out = resecta("info", test_data / NIFTI_FILES[0]).stdout
    assert "dims" in out and "spacing" in out


def bad(resecta, path: Path):
    r = resecta("info", path, "--json", check=False)
    assert r.code == 2, (r.code, r.stderr)
    assert r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0], r.stderr
    assert "panicked" not in r.stderr
    return lines[0]


def test_bad_inputs_exit_2_naming_the_file(resecta, tmp_path):
    bad(resecta, tmp_path / "missing.nii.gz")
    unknown = tmp_path / "x.txt"
    unknown.write_text("hello")
    assert "unknown file type" in bad(resecta, unknown)

    good = tmp_path / "ok.nii.gz"
    arr = np.zeros((10, 10, 10), np.uint8)
    nib.save(nib.Nifti1Image(arr, np.diag([2.0, 2.0, 2.0, 1.0])), str(good))
    blob = good.read_bytes()
    trunc = tmp_path / "trunc.nii.gz"
    trunc.write_bytes(blob[: len(blob) // 2])
    bad(resecta, trunc)

    corrupt = tmp_path / "corrupt.nii.gz"
    corrupt.write_bytes(gzip.compress(b"\x00" * 400))
    bad(resecta, corrupt)

    nrrd = tmp_path / "huge.nrrd"
    nrrd.write_bytes(b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 100000 100000 100000\n"
                     b"encoding: raw\nspacing: 1 1 1\n\n\x00")
    assert "voxel" in bad(resecta, nrrd)

    nan = tmp_path / "nan.nrrd"
    nan.write_bytes(b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n"
                    b"space: RAS\nspace directions: (nan,0,0) (0,1,0) (0,0,1)\n\n" + b"\x00" * 8)
    bad(resecta, nan)

    obj = tmp_path / "bad.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    bad(resecta, obj)


# ---- the server's info: GetServerInfo and GET /v1/info -------------------------------------

def test_both_faces_report_the_limits_the_document_states(tmp_path):
    """`GetServerInfo` (gRPC) and `GET /v1/info` carry the same limits, the configured ones
    (sessions, idle expiry) and the fixed ones of the plan and uploads, and the OpenAPI
    document states the fixed ones as its bounds."""
    import requests
    from google.protobuf import json_format
    from server_harness import Server, generate_stubs

    (tmp_path / "stubs").mkdir()
    pb, pb_grpc = generate_stubs(tmp_path / "stubs")
    cfg = tmp_path / "resecta.toml"
    cfg.write_text("[limits]\nmax_sessions = 3\nidle_expiry_s = 90\n")
    s = Server("--config", str(cfg))
    try:
        info = pb_grpc.PlanningServiceStub(s.channel()).GetServerInfo(pb.GetServerInfoRequest())
        grpc_limits = json_format.MessageToDict(info.limits)
        http_limits = requests.get(f"{s.http_url}/v1/info", timeout=10).json()["limits"]
        doc = requests.get(f"{s.http_url}/v1/openapi.json", timeout=10).json()
    finally:
        s.stop()
    assert grpc_limits == http_limits
    assert info.limits.max_sessions == 3 and info.limits.session_idle_timeout_s == 90
    assert http_limits["sessionIdleTimeoutS"] == "90"

    schemas = doc["components"]["schemas"]

    def bound(message, field, key="maximum", items=False):
        s = schemas[f"resecta.v1.{message}"]["properties"][field]
        return (s["items"] if items else s)[key]

    stated = {
        "minControlPoints": bound("Resection", "gridM", "minimum"),
        "maxControlPoints": bound("Resection", "gridN"),
        "minResolution": bound("SetResolution", "ru", "minimum"),
        "maxResolution": bound("Resection", "rv"),
        "maxMarginMm": bound("SetMargin", "marginMm"),
        "maxBandMm": bound("SetBand", "bandMm"),
        "maxNameBytes": bound("InitFromEndPoint", "name", "maxLength"),
        "maxCoordinateMm": bound("Vec3", "z"),
        "maxRotationDeg": bound("Rotate", "angleDeg"),
        "maxDisplayNameChars": bound("CreateSessionRequest", "displayName", "maxLength"),
        "minPsrDepth": bound("ReconstructOptions", "psrDepth", "minimum"),
        "maxPsrDepth": bound("ReconstructOptions", "psrDepth"),
        "minSpacingMm": bound("RawLabelMapHeader", "spacing", "minimum", items=True),
        "maxSpacingMm": bound("RawLabelMapHeader", "spacing", items=True),
        "maxOriginMm": bound("RawLabelMapHeader", "origin", items=True),
        "maxLabelSlicePixelMm": bound("GetLabelSliceRequest", "pixelMm"),
        "maxResections": schemas["PlanDocument"]["properties"]["resections"]["maxItems"],
    }
    for name, value in stated.items():
        assert value > 0 and http_limits[name] == value, (name, http_limits.get(name), value)
    assert f"at most {http_limits['maxPlanBytes']} bytes" in json.dumps(doc, ensure_ascii=False)
    assert f"longer than {http_limits['maxExtentMm']:g} mm" in json.dumps(doc, ensure_ascii=False)


# ---- the compute backend: --gpu ---------------------------------------------------------------

def test_gpu_required_plans_on_the_adapter_as_the_cpu_does(tmp_path):
    """`--gpu required` under `WGPU_BACKEND=vulkan` (lavapipe in CI) reports its adapter on both
    faces and plans the demo patient's edits with the verdicts of a `--gpu off` server; with no
    adapter for the backends searched it refuses to start (exit 1, naming the GPU)."""
    import requests
    from server_harness import Server, wait_for

    vulkan = {"WGPU_BACKEND": "vulkan"}
    try:
        gpu = Server("--demo", "--gpu", "required", env=vulkan)
    except AssertionError as e:
        # As the Rust GPU tests: a machine without lavapipe skips, unless it asked for Vulkan.
        if os.environ.get("WGPU_BACKEND"):
            raise
        pytest.skip(f"SKIP: no Vulkan adapter ({e}); install lavapipe (mesa-vulkan-drivers)")
    cpu = Server("--demo", env={"RESECTA_GPU": "off"})
    try:
        verdicts, infos = [], []
        for s in (gpu, cpu):
            infos.append(requests.get(f"{s.http_url}/v1/info", timeout=10).json())

            def planned(s=s):
                got = requests.get(f"{s.http_url}/v1/sessions", timeout=30).json()
                sessions = got.get("sessions", [])
                sid = sessions and sessions[0]["id"]
                plan = sid and requests.get(f"{s.http_url}/v1/sessions/{sid}/plan", timeout=60)
                return plan and plan.ok and '"r1"' in plan.json().get("planJson", "") and sid

            sid = wait_for(planned, timeout=300)
            for delta in ({"x": 2.0, "y": 0.0, "z": 0.5}, {"x": -1.0, "y": 1.0, "z": 0.0}):
                r = requests.post(f"{s.http_url}/v1/sessions/{sid}/edits",
                                  json={"translate": {"name": "r1", "delta": delta}}, timeout=120)
                assert r.status_code == 200, r.text
            verdicts.append(r.json()["resections"][0]["verdict"])
    finally:
        gpu.stop()
        cpu.stop()
    g, c = infos
    assert g["compute"]["backend"] == "wgpu" and g["compute"]["adapter"], g
    assert "gpu" in g["capabilities"]
    assert c["compute"] == {"backend": "cpu", "f64": True}, c  # proto JSON omits the empty adapter
    assert "gpu" not in c["capabilities"]
    gv, cv = verdicts
    assert abs(gv["minMarginMm"] - cv["minMarginMm"]) <= 1e-6, (gv, cv)
    assert gv.get("violation", False) == cv.get("violation", False)
    # The GPU measures every distance exactly; the CPU's far samples are within 0.25 mm, which
    # moves the clipped lines of the cells next to them a little: areas within 1 %.
    for area in ("violatingAreaMm2", "warningAreaMm2", "insideAreaMm2"):
        assert abs(gv.get(area, 0.0) - cv.get(area, 0.0)) <= 1e-2 * max(cv.get(area, 0.0), 1.0), area

    # No adapter (no Metal on Linux): refused with a clear error.
    with pytest.raises(AssertionError, match="GPU: --gpu required"):
        Server("--gpu", "required", env={"WGPU_BACKEND": "metal"})


def test_gpu_auto_leaves_a_software_adapter_alone():
    """`--gpu auto` plans on the CPU when the only adapter is a software rasteriser
    (lavapipe here), and says so in its log; `required` is what uses one."""
    import requests
    from server_harness import Server

    server = Server("--gpu", "auto", env={"WGPU_BACKEND": "vulkan", "RUST_LOG": "info"})
    try:
        info = requests.get(f"{server.http_url}/v1/info", timeout=10).json()
    finally:
        server.stop()
    log = server.proc.stderr.read()
    if "planning on the GPU" in log:
        pytest.skip("SKIP: this machine has a hardware Vulkan adapter, which auto uses")
    assert info["compute"]["backend"] == "cpu", info
    assert "gpu" not in info["capabilities"]
    # lavapipe (CI) is seen and left alone; a machine without it has no adapter at all.
    assert "only a software GPU adapter" in log or "no GPU adapter" in log, log[-2000:]
