"""Label maps up (numpy arrays on oblique, anisotropic, flipped grids; NIfTI, NRRD, .seg.nrrd and
MetaImage files) and models back (progress, cancellation)."""

from __future__ import annotations

import math
import subprocess
import threading
from pathlib import Path

import nibabel as nib
import numpy as np
import pytest

import resecta_client as rc
from resecta_client.geometry import compose, decompose, label_bytes

from .conftest import DEMO_ROLES, ROLES, resecta_bin

RADII = np.array([40.0, 30.0, 25.0])  # liver ellipsoid semi-axes, mm
CENTRE = np.array([5.0, -12.0, 30.0])
TUMOUR = (CENTRE + [10.0, 5.0, 0.0], 8.0)
# Functional liver (every role but tumour): the ellipsoid less the tumour ball inside it.
ANALYTIC_ML = (4 / 3 * math.pi * RADII.prod() - 4 / 3 * math.pi * TUMOUR[1] ** 3) / 1000
VOLUME_TOLERANCE = 0.005  # relative; voxelising this ellipsoid on 1.3×0.9×2.1 mm voxels: 0.09 % measured


def rotation(ax: float, ay: float, az: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = (f(math.radians(a)) for a in (ax, ay, az) for f in (math.cos, math.sin))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


ELLIPSOID_AXES = rotation(0, 0, 20)  # columns: the ellipsoid's axes in RAS


def ellipsoid_phantom() -> tuple[np.ndarray, np.ndarray]:
    """A label map indexed [k, j, i] (1 liver, 2 tumour) of the ellipsoid on an oblique,
    anisotropic, left-handed grid (the j axis flipped), and its IJK→RAS matrix."""
    spacing = np.array([1.3, 0.9, 2.1])
    direction = rotation(7, -4, 12) @ np.diag([1.0, -1.0, 1.0])  # det −1
    dims = np.ceil(2 * 46 / spacing).astype(int)  # covers a 46 mm ball around the centre
    origin = CENTRE - direction @ (spacing * (dims - 1) / 2)
    m = compose(origin, spacing, direction)
    k, j, i = np.meshgrid(*(np.arange(n) for n in dims[::-1]), indexing="ij")
    ijk = np.stack([i, j, k], axis=-1).astype(np.float64)
    ras = ijk @ m[:3, :3].T + m[:3, 3]
    local = (ras - CENTRE) @ ELLIPSOID_AXES  # coordinates along the ellipsoid's axes
    labels = np.zeros(ras.shape[:3], np.uint8)
    labels[((local / RADII) ** 2).sum(-1) <= 1] = 1
    labels[((ras - TUMOUR[0]) ** 2).sum(-1) <= TUMOUR[1] ** 2] = 2
    return labels, m


def analytic_bbox() -> tuple[np.ndarray, np.ndarray]:
    half = np.sqrt(((ELLIPSOID_AXES * RADII) ** 2).sum(axis=1))
    return CENTRE - half, CENTRE + half


def snapshot(session: rc.Session) -> rc.LiveScene:
    with session.watch() as w:
        next(w)
        return w.scene


def test_decompose_oblique_anisotropic_and_flipped() -> None:
    direction = rotation(10, 20, 30) @ np.diag([-1.0, 1.0, 1.0])
    m = compose([1, 2, 3], [0.7, 0.8, 2.5], direction)
    origin, spacing, d = decompose(m)
    assert np.allclose(spacing, [0.7, 0.8, 2.5]) and np.allclose(d, direction) and origin == (1, 2, 3)
    assert np.allclose(decompose(m[:3])[2], direction)  # 3×4 is accepted
    # Slicer's negative spacing is a flipped direction column: the same matrix, the same result.
    flipped = m.copy()
    flipped[:3, 0] *= -1
    assert np.allclose(decompose(flipped)[2][:, 0], -direction[:, 0]) and decompose(flipped)[1][0] > 0
    if rc.vtk_available():  # Slicer's GetIJKToRASMatrix gives a vtkMatrix4x4
        from vtkmodules.vtkCommonMath import vtkMatrix4x4

        vm = vtkMatrix4x4()
        vm.DeepCopy(m.reshape(-1).tolist())
        assert np.allclose(decompose(vm)[2], direction)
    for bad in (np.zeros((4, 4)), np.eye(3), np.diag([1.0, 1.0, 0.0, 1.0])):
        with pytest.raises(ValueError):
            decompose(bad)


def test_label_bytes_layout_and_types() -> None:
    a = np.arange(24, dtype=np.int16).reshape(2, 3, 4)  # [k, j, i]
    dims, data_type, data = label_bytes(a)
    assert (
        dims == (4, 3, 2)
        and data_type == rc.geometry.label_map_pb2.DATA_TYPE_INT16
        and data == a.astype("<i2").tobytes()
    )
    assert label_bytes(a.transpose(2, 1, 0), axes="ijk")[2] == data  # [i, j, k] gives the same bytes
    assert label_bytes(a.astype(np.int64))[1:] == label_bytes(a.astype(np.uint8))[1:]  # narrowed
    assert label_bytes(a.astype(np.float32) * 1000)[1] == rc.geometry.label_map_pb2.DATA_TYPE_UINT16
    assert label_bytes(a > 3)[2] == (a > 3).astype(np.uint8).tobytes()
    for bad in (a[0], a + 0.5, -a.astype(np.int64) - 1, a.astype(np.int64) * 10_000):
        with pytest.raises(ValueError):
            label_bytes(bad)


def test_upload_numpy_oblique_anisotropic(client: rc.Client) -> None:
    labels, m = ellipsoid_phantom()
    s = client.create_session("numpy")
    summary = s.upload_label_map(labels, m, ROLES)
    assert summary.dims == labels.shape[::-1]
    assert np.allclose(summary.ijk_to_ras, m, atol=1e-9)
    assert np.linalg.det(summary.direction) < 0  # the flip survived
    counts = {c.label: c.voxels for c in summary.labels}
    assert counts == {v: int((labels == v).sum()) for v in (1, 2)}
    assert summary.roles == ROLES
    assert summary.liver_volume_ml == pytest.approx(ANALYTIC_ML, rel=VOLUME_TOLERANCE)
    assert s.info().state is rc.SessionState.LABEL_MAP
    # The same voxels as an [i, j, k] array, and flipped along i with the matrix to match.
    again = client.create_session("numpy-ijk")
    assert again.upload_label_map(labels.transpose(2, 1, 0), m, ROLES, axes="ijk").labels == summary.labels
    flip = m.copy()
    flip[:3, 3] += m[:3, 0] * (labels.shape[2] - 1)
    flip[:3, 0] *= -1
    mirrored = client.create_session("numpy-flipped")
    mirrored.upload_label_map(labels[:, :, ::-1], flip, ROLES)
    # Models land where the ellipsoid is in RAS, whatever the grid.
    lo, hi = analytic_bbox()
    for session in (s, mirrored):
        session.reconstruct("psr")
        assert session.volumes().total_ml == pytest.approx(ANALYTIC_ML, rel=VOLUME_TOLERANCE)
        liver = snapshot(session).surfaces["parenchyma"].positions
        assert np.allclose(liver.min(0), lo, atol=2.0) and np.allclose(liver.max(0), hi, atol=2.0), (
            liver.min(0),
            lo,
        )
        tumour = snapshot(session).surfaces["tumor_1"].positions
        assert np.allclose(tumour.mean(0), TUMOUR[0], atol=0.5)


def test_upload_files(client: rc.Client, phantom: Path, tmp_path: Path) -> None:
    img = nib.load(str(phantom))
    data = np.asarray(img.dataobj)
    expected = {int(v): int((data == v).sum()) for v in np.unique(data) if v}
    s = client.create_session("files")
    summary = s.upload_label_map_file(phantom, ROLES)
    assert summary.dims == img.shape
    assert np.allclose(summary.ijk_to_ras, img.affine, atol=1e-4)
    assert {c.label: c.voxels for c in summary.labels} == expected
    assert s.upload_label_map_file(phantom.read_bytes(), ROLES, format="nifti").labels == summary.labels
    for name in ("phantom.nrrd", "phantom.seg.nrrd", "phantom.mha"):
        subprocess.run(
            [resecta_bin(), "phantom", "--out", str(tmp_path), "--preset", "small", "--name", name],
            check=True,
            capture_output=True,
        )
        got = s.upload_label_map_file(tmp_path / name, ROLES)
        assert np.allclose(got.ijk_to_ras, summary.ijk_to_ras, atol=1e-4), name
        assert sum(c.voxels for c in got.labels) == sum(expected.values()), name
    with pytest.raises(rc.InvalidArgument) as e:
        s.upload_label_map_file(b"not an image at all", ROLES)
    assert e.value.code == "BAD_LABEL_MAP"
    with pytest.raises(ValueError):
        s.upload_label_map_file(phantom, ROLES, format="dicom")


def test_reconstruct_with_progress(client: rc.Client, phantom: Path) -> None:
    s = client.create_session("recon")
    with pytest.raises(rc.FailedPrecondition):
        s.reconstruct()
    s.upload_label_map_file(phantom, ROLES)
    progress: list[tuple[float, str]] = []
    seen: list[rc.ModelInfo] = []
    models = s.reconstruct("psr", progress=lambda f, stage: progress.append((f, stage)), on_model=seen.append)
    assert [m.name for m in models] == [m.name for m in seen]
    assert {"parenchyma", "tumor_1", "portal_1"} <= {m.name for m in models}
    assert {m.name: m.kind for m in models}["tumor_1"] is rc.SurfaceKind.TUMOR
    # One label per role here: every model names the label it was built from.
    assert {m.name: m.label for m in models} == {"parenchyma": 1, "tumor_1": 2, "portal_1": 3}
    assert all(m.triangle_count > 0 and m.volume_ml > 0 for m in models)
    with s.watch() as w:
        for _ in w:
            if len(w.scene.models) == len(models):
                break
    assert w.scene.models["tumor_1"].label == 2
    assert all(m.color is not None and len(m.color) == 4 for m in w.scene.models.values())
    fractions = [f for f, _ in progress]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and progress[-1][1] == "done"
    assert s.info().state is rc.SessionState.READY

    # A callback that raises ends the call (the server's work is cancelled) and propagates.
    def fail(info: rc.ModelInfo) -> None:
        raise KeyError(info.name)

    with pytest.raises(KeyError):
        s.reconstruct("psr", on_model=fail)
    assert [m.name for m in s.reconstruct("psr")] == [m.name for m in models]


def test_reconstruct_with_mcsd_and_options(client: rc.Client, phantom: Path) -> None:
    s = client.create_session("mcsd")
    s.upload_label_map_file(phantom, ROLES)
    psr = {m.name: m for m in s.reconstruct("psr")}
    mcsd = {m.name: m for m in s.reconstruct("mcsd", smoothing=0.3, decimation=0.5)}
    assert mcsd.keys() == psr.keys()
    liver, ref = mcsd["parenchyma"], psr["parenchyma"]
    assert liver.triangle_count != ref.triangle_count
    assert abs(liver.volume_ml / ref.volume_ml - 1) < 0.05, (liver.volume_ml, ref.volume_ml)
    coarse = {m.name: m for m in s.reconstruct("psr", psr_depth=4)}["parenchyma"]
    assert coarse.triangle_count < ref.triangle_count
    # Out of range: refused before anything is built, the field named.
    for key, value in (("psr_depth", 11), ("smoothing", 1.5), ("decimation", 1.0)):
        with pytest.raises(rc.InvalidArgument) as e:
            s.reconstruct("mcsd", **{key: value})
        assert e.value.field == f"options.{key}"


def test_reconstruct_cancelled_keeps_previous_models(client: rc.Client, demo_phantom: Path) -> None:
    s = client.create_session("cancel")
    s.upload_label_map_file(demo_phantom, DEMO_ROLES)
    first = s.reconstruct("psr")
    cancel = threading.Event()
    threading.Timer(0.1, cancel.set).start()  # the demo's liver takes far longer than that
    with pytest.raises(rc.Cancelled):
        s.reconstruct("psr", cancel=cancel)
    assert s.info().state is rc.SessionState.READY
    assert {n for n in snapshot(s).models} == {m.name for m in first}
    # Cancelling before the call starts works too, and the server is not stuck afterwards.
    early = threading.Event()
    early.set()
    with pytest.raises(rc.Cancelled):
        s.reconstruct("psr", cancel=early)
    assert [m.name for m in s.reconstruct("psr")] == [m.name for m in first]
