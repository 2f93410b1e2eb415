"""GetLabelSlice end to end (#20, the 2D slice views): one plane of the demo patient's label map
on both faces, and its refusals naming the field."""
import base64
import re

import numpy as np
import pytest
import requests

from browser_harness import demo  # noqa: F401 (fixture)

# The demo phantom's larger tumour: a ball of 25 mm about (40, -10, 5) (PhantomSpec::demo).
TUMOUR = (40.0, -10.0, 5.0)
TUMOUR_LABEL = 2


def get(server, sid, **query):
    return requests.get(f"{server.http_url}/v1/sessions/{sid}/label-slice", params=query, timeout=60)


def raster(answer):
    labels = np.frombuffer(base64.b64decode(answer["labels"]), dtype="<u2")
    return labels.reshape(answer["height"], answer["width"])


def test_the_axial_slice_through_the_tumour_holds_it_where_it_is(demo):
    server, sid = demo
    r = get(server, sid, axis="SLICE_AXIS_AXIAL", positionMm=TUMOUR[2], pixelMm=1.0)
    assert r.status_code == 200, r.text
    a = r.json()
    assert a["pixelMm"] == 1.0
    assert a["columnAxis"] == {"x": 1.0} and a["rowAxis"] == {"y": 1.0}
    assert a["minPositionMm"] < TUMOUR[2] < a["maxPositionMm"]
    labels = raster(a)
    rows, cols = np.nonzero(labels == TUMOUR_LABEL)
    # The disc of the 25 mm ball (the smaller tumour, 15 mm about z = 10, adds its own disc).
    near = np.hypot(a["origin"]["x"] + cols - TUMOUR[0], a["origin"]["y"] + rows - TUMOUR[1]) < 30
    assert np.pi * 25**2 * 0.9 < near.sum() < np.pi * 25**2 * 1.1
    assert 1 in labels  # the liver around it


def test_each_axis_has_its_extent_and_the_default_pixel(demo):
    server, sid = demo
    seen = {}
    for axis in ("SLICE_AXIS_CORONAL", "SLICE_AXIS_SAGITTAL"):
        a = get(server, sid, axis=axis, positionMm=0).json()
        assert a["pixelMm"] == 0.8  # the demo's finest spacing
        assert 0 < a["width"] <= 1024 and 0 < a["height"] <= 1024
        assert (raster(a) == 1).any()
        seen[axis] = (a["minPositionMm"], a["maxPositionMm"])
    assert seen["SLICE_AXIS_CORONAL"] != seen["SLICE_AXIS_SAGITTAL"]


@pytest.mark.parametrize("query, field", [
    ({"axis": "SLICE_AXIS_UNSPECIFIED", "positionMm": 0}, "axis"),
    ({"positionMm": 0}, "axis"),
    ({"axis": "SLICE_AXIS_OBLIQUE", "positionMm": 0}, None),  # the query parser's refusal
    ({"axis": "SLICE_AXIS_AXIAL", "positionMm": 5000}, "position_mm"),
    ({"axis": "SLICE_AXIS_AXIAL", "positionMm": "NaN"}, "position_mm"),
    ({"axis": "SLICE_AXIS_AXIAL", "positionMm": 0, "pixelMm": 0}, "pixel_mm"),
    ({"axis": "SLICE_AXIS_AXIAL", "positionMm": 0, "pixelMm": 101}, "pixel_mm"),
    ({"axis": "SLICE_AXIS_AXIAL", "positionMm": 0, "pixelMm": "Infinity"}, "pixel_mm"),
])
def test_bad_requests_are_refused_naming_the_field(demo, query, field):
    server, sid = demo
    r = get(server, sid, **query)
    assert r.status_code == 400, r.text
    problem = r.json()
    assert r.headers["content-type"].startswith("application/problem+json")
    assert problem["code"] == "INVALID_ARGUMENT"
    assert field is None or field in problem["detail"], problem


def test_the_position_refusal_names_the_valid_range(demo):
    server, sid = demo
    a = get(server, sid, axis="SLICE_AXIS_AXIAL", positionMm=0).json()
    detail = get(server, sid, axis="SLICE_AXIS_AXIAL", positionMm=5000).json()["detail"]
    lo, hi = re.search(r"\[(\S+), (\S+)\] mm", detail).groups()
    assert (float(lo), float(hi)) == (a["minPositionMm"], a["maxPositionMm"]), detail


def test_a_session_without_a_label_map_is_a_precondition_failure(demo):
    server, _ = demo
    sid = requests.post(f"{server.http_url}/v1/sessions", json={"displayName": "empty"},
                        timeout=30).json()["session"]["id"]
    r = get(server, sid, axis="SLICE_AXIS_AXIAL", positionMm=0)
    assert r.status_code == 409 and r.json()["code"] == "NO_LABEL_MAP", r.text
    requests.delete(f"{server.http_url}/v1/sessions/{sid}", timeout=30)


def test_the_grpc_face_answers_the_same(demo, tmp_path):
    from google.protobuf import json_format
    from server_harness import generate_stubs

    server, sid = demo
    pb, pb_grpc = generate_stubs(tmp_path)
    stub = pb_grpc.PlanningServiceStub(server.channel())
    g = stub.GetLabelSlice(pb.GetLabelSliceRequest(
        session_id=sid, axis=pb.SLICE_AXIS_SAGITTAL, position_mm=TUMOUR[0], pixel_mm=2.0))
    h = get(server, sid, axis="SLICE_AXIS_SAGITTAL", positionMm=TUMOUR[0], pixelMm=2.0).json()
    assert json_format.MessageToDict(g) == h
    assert TUMOUR_LABEL in raster(h)
