"""Anchors for the reconstruction benchmark (issue #4): 3D Slicer's closed-surface conversion and
Kazhdan's Poisson reconstruction (through Open3D), plus the mesh I/O and metrics the harness uses.

Coordinates: everything here is RAS millimetres. Meshes are written as binary little-endian PLY
with a ``comment SPACE=RAS`` line (what resecta's readers expect; untagged files are RAS too).

Slicer (slicer-core wheel): the label map is read with Slicer's own reader
(``vtkITKArchetypeImageSeriesScalarReader``, as ``vtkMRMLVolumeArchetypeStorageNode`` does), its
IJK→RAS matrix is checked against nibabel's affine (NIfTI), and a ``vtkOrientedImageData`` (origin
0, spacing 1, geometry in the image-to-world matrix, as Slicer stores segment labelmaps) is put
into a ``vtkSegment`` of a ``vtkSegmentation``; ``vtkBinaryLabelmapToClosedSurfaceConversionRule``
then runs flying edges in IJK, smoothing, the IJK→RAS transform and normals.

Run ``python anchors.py`` for the geometry self-check on an oblique sphere phantom.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import vtk
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy

# Slicer's parameter defaults (vtkBinaryLabelmapToClosedSurfaceConversionRule, Slicer 5.x).
SLICER_DEFAULTS = {
    "Smoothing factor": "0.5",
    "Decimation factor": "0.0",
    "Compute surface normals": "1",
    "Conversion method": "0",  # 0 = vtkDiscreteFlyingEdges3D
    "SurfaceNets smoothing": "0",
    "Joint smoothing": "0",
}


def _slicer():
    import slicer_core  # noqa: PLC0415 (heavy import, only where needed)

    return slicer_core


# ---------------------------------------------------------------- label maps


def read_label_slicer(path: str | Path):
    """Reads a label map with Slicer's ITK archetype reader.

    Returns ``(vtkOrientedImageData, ijk_to_ras)`` where ``ijk_to_ras`` is a 4×4 numpy array.
    """
    s = _slicer()
    r = s.vtkITKArchetypeImageSeriesScalarReader()
    r.SetArchetype(str(path))
    r.SetSingleFile(1)
    r.SetOutputScalarTypeToNative()
    r.SetDesiredCoordinateOrientationToNative()
    r.SetUseNativeOriginOn()
    r.Update()
    if r.GetErrorCode() != 0 or r.GetOutput().GetNumberOfPoints() == 0:
        raise RuntimeError(f"Slicer's reader could not read {path}")
    m = vtk.vtkMatrix4x4()
    m.DeepCopy(r.GetRasToIjkMatrix())
    m.Invert()
    image = s.vtkOrientedImageData()
    image.ShallowCopy(r.GetOutput())
    image.SetOrigin(0.0, 0.0, 0.0)
    image.SetSpacing(1.0, 1.0, 1.0)
    image.SetImageToWorldMatrix(m)
    return image, _mat(m)


def _mat(m: vtk.vtkMatrix4x4) -> np.ndarray:
    return np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])


def read_label_numpy(path: str | Path):
    """Reads a label map as ``(array[i, j, k], ijk_to_ras)``: nibabel for NIfTI, Slicer's reader
    otherwise (NRRD, MetaImage)."""
    p = str(path)
    if p.endswith((".nii", ".nii.gz")):
        import nibabel as nib  # noqa: PLC0415

        img = nib.load(p)
        return np.asarray(img.dataobj), np.asarray(img.affine, dtype=float)
    image, affine = read_label_slicer(p)
    dims = image.GetDimensions()
    flat = vtk_to_numpy(image.GetPointData().GetScalars())
    return flat.reshape(dims[2], dims[1], dims[0]).transpose(2, 1, 0), affine


def check_geometry(path: str | Path, tol_mm: float = 1e-3) -> float:
    """Largest difference (mm) between Slicer's and nibabel's IJK→RAS over the volume's corners.

    Raises if above ``tol_mm``; returns 0 for non-NIfTI files (no second reader to compare)."""
    p = str(path)
    if not p.endswith((".nii", ".nii.gz")):
        return 0.0
    image, slicer_m = read_label_slicer(p)
    _, nib_m = read_label_numpy(p)
    d = np.array(image.GetDimensions()) - 1
    corners = np.array([[a, b, c, 1.0] for a in (0, d[0]) for b in (0, d[1]) for c in (0, d[2])])
    err = float(np.abs(corners @ slicer_m.T - corners @ nib_m.T).max())
    if err > tol_mm:
        raise RuntimeError(f"{p}: Slicer and nibabel IJK→RAS differ by {err:.4g} mm")
    return err


# ---------------------------------------------------------------- Slicer anchor


def slicer_closed_surface(
    label_path: str | Path,
    label: int,
    smoothing: float = 0.5,
    decimation: float = 0.0,
    out: str | Path | None = None,
):
    """3D Slicer's binary-labelmap → closed-surface conversion of one label.

    Returns ``(polydata, timings)``; timings in seconds: ``read`` (Slicer's reader + oriented image
    + segmentation set-up), ``convert`` (``rule.Convert(segment)`` only) and ``total``. Writes the
    mesh as RAS PLY to ``out`` if given (not timed)."""
    s = _slicer()
    t0 = time.perf_counter()
    image, _ = read_label_slicer(label_path)
    bl = s.vtkSegmentationConverter.GetBinaryLabelmapRepresentationName()
    cs = s.vtkSegmentationConverter.GetClosedSurfaceRepresentationName()
    segmentation = s.vtkSegmentation()
    segmentation.SetSourceRepresentationName(bl)
    segment = s.vtkSegment()
    segment.SetLabelValue(int(label))
    segment.AddRepresentation(bl, image)
    segmentation.AddSegment(segment, f"label{label}")
    rule = s.vtkBinaryLabelmapToClosedSurfaceConversionRule()
    params = dict(SLICER_DEFAULTS)
    params["Smoothing factor"] = repr(float(smoothing))
    params["Decimation factor"] = repr(float(decimation))
    for k, v in params.items():
        rule.SetConversionParameter(k, v)
    t1 = time.perf_counter()
    if not rule.Convert(segment):
        raise RuntimeError(f"Slicer's conversion failed on {label_path} label {label}")
    t2 = time.perf_counter()
    poly = segment.GetRepresentation(cs)
    if poly is None or poly.GetNumberOfPolys() == 0:
        raise RuntimeError(f"Slicer produced no surface for {label_path} label {label}")
    if out is not None:
        v, f = polydata_arrays(poly)
        write_ply(out, v, f)
    return poly, {"read": t1 - t0, "convert": t2 - t1, "total": t2 - t0}


# ---------------------------------------------------------------- Open3D anchor


def open3d_poisson(points_ply: str | Path, depth: int = 7, scale: float = 1.1, out=None):
    """Kazhdan's (screened) Poisson reconstruction as built into Open3D, on oriented points.

    Returns ``((vertices, faces), timings)``: ``read`` (PLY → point cloud), ``convert``
    (``create_from_point_cloud_poisson`` only) and ``total``. Output is RAS like the input."""
    import open3d as o3d  # noqa: PLC0415

    t0 = time.perf_counter()
    pos, nrm = read_points_ply(points_ply)
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(pos)
    pcd.normals = o3d.utility.Vector3dVector(nrm)
    t1 = time.perf_counter()
    mesh, _density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        pcd, depth=depth, width=0, scale=scale, linear_fit=False, n_threads=-1
    )
    t2 = time.perf_counter()
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.triangles)
    if out is not None:
        write_ply(out, v, f)
    return (v, f), {"read": t1 - t0, "convert": t2 - t1, "total": t2 - t0}


# ---------------------------------------------------------------- oriented points (test only)


def gradient_points(label_path: str | Path, labels, shift: bool = True):
    """Oriented points from a mask, for testing the anchors before resecta's ``--points-out``.

    Object voxels with a non-zero central-difference gradient of the binary mask; positions are
    voxel centres in RAS mm (moved half a voxel outward along the normal when ``shift``), normals
    the outward unit gradient in physical units (A^-T g for the IJK→RAS linear part A)."""
    arr, affine = read_label_numpy(label_path)
    mask = np.isin(arr, list(labels)).astype(np.float32)
    m = np.pad(mask, 1)
    g = np.stack(
        [
            (m[2:, 1:-1, 1:-1] - m[:-2, 1:-1, 1:-1]),
            (m[1:-1, 2:, 1:-1] - m[1:-1, :-2, 1:-1]),
            (m[1:-1, 1:-1, 2:] - m[1:-1, 1:-1, :-2]),
        ],
        axis=-1,
    )
    sel = (mask > 0) & (np.abs(g).sum(-1) > 0)
    ijk = np.argwhere(sel).astype(float)
    lin = affine[:3, :3]
    n = -(g[sel] @ np.linalg.inv(lin))  # (A^-T g)^T = g^T A^-1; minus: outward
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    pos = ijk @ lin.T + affine[:3, 3]
    if shift:
        # Distance from the centre to the voxel's boundary along n: t·A^-1 n leaves [-½, ½]³ at
        # t = 0.5 / max_k |(A^-1 n)_k|.
        a = np.abs(n @ np.linalg.inv(lin).T)
        step = 0.5 / np.maximum(a.max(axis=1), 1e-12)
        pos = pos + n * step[:, None]
    return pos, n


# ---------------------------------------------------------------- PLY I/O


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Binary little-endian PLY, float32 coordinates, int32 triangle lists, tagged RAS."""
    v = np.ascontiguousarray(vertices, dtype="<f4")
    f = np.asarray(faces, dtype="<i4")
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment SPACE=RAS\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    rec = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = f
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.tobytes())
        fh.write(rec.tobytes())


def write_points_ply(path: str | Path, pos: np.ndarray, nrm: np.ndarray) -> None:
    """Oriented points as binary little-endian PLY (``x y z nx ny nz`` float32), tagged RAS."""
    data = np.hstack([pos, nrm]).astype("<f4")
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment SPACE=RAS\n"
        f"element vertex {len(data)}\n"
        + "".join(f"property float {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
        + "end_header\n"
    )
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(data.tobytes())


_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "<i2",
    "int16": "<i2",
    "ushort": "<u2",
    "uint16": "<u2",
    "int": "<i4",
    "int32": "<i4",
    "uint": "<u4",
    "uint32": "<u4",
    "float": "<f4",
    "float32": "<f4",
    "double": "<f8",
    "float64": "<f8",
}


def read_points_ply(path: str | Path):
    """Reads ``x y z nx ny nz`` from the vertex element of a binary little-endian (or ASCII) PLY
    whose vertex properties are scalars (float32 or float64). Returns float64 ``(pos, nrm)``."""
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file")
    lines = raw[:end].decode("ascii").splitlines()
    fmt = next(ln.split()[1] for ln in lines if ln.startswith("format"))
    fields, count, in_vertex = [], 0, False
    for ln in lines:
        w = ln.split()
        if w[0] == "element":
            if in_vertex:
                break  # vertex must be the first element for the offset below to hold
            in_vertex = w[1] == "vertex"
            count = int(w[2]) if in_vertex else 0
        elif w[0] == "property" and in_vertex:
            if w[1] == "list":
                raise ValueError(f"{path}: list property in vertex element")
            fields.append((w[2], _PLY_TYPES[w[1]]))
    body = raw[end + len(b"end_header\n") :]
    if fmt == "binary_little_endian":
        rec = np.frombuffer(body, dtype=np.dtype(fields), count=count)
        cols = {name: rec[name].astype(float) for name, _ in fields}
    elif fmt == "ascii":
        tab = np.loadtxt(body.decode("ascii").splitlines()[:count], ndmin=2)
        cols = {name: tab[:, k] for k, (name, _) in enumerate(fields)}
    else:
        raise ValueError(f"{path}: unsupported PLY format {fmt}")
    pos = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
    nrm = np.stack([cols["nx"], cols["ny"], cols["nz"]], axis=1)
    return pos, nrm


def read_mesh(path: str | Path):
    """Any mesh VTK reads (.ply/.vtp/.vtk/.stl/.obj) as ``(vertices, triangles)``; no LPS handling
    (only used for meshes this harness or resecta wrote, which are RAS)."""
    p = str(path)
    readers = {
        ".ply": vtk.vtkPLYReader,
        ".vtp": vtk.vtkXMLPolyDataReader,
        ".vtk": vtk.vtkPolyDataReader,
        ".stl": vtk.vtkSTLReader,
        ".obj": vtk.vtkOBJReader,
    }
    r = readers[Path(p).suffix.lower()]()
    r.SetFileName(p)
    r.Update()
    tri = vtk.vtkTriangleFilter()
    tri.SetInputData(r.GetOutput())
    tri.Update()
    return polydata_arrays(tri.GetOutput())


def polydata_arrays(poly) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices float64 (n,3), triangles int64 (m,3))`` of a triangle vtkPolyData."""
    v = vtk_to_numpy(poly.GetPoints().GetData()).astype(float)
    polys = poly.GetPolys()
    offsets = vtk_to_numpy(polys.GetOffsetsArray())
    if not np.all(np.diff(offsets) == 3):
        raise ValueError("mesh has non-triangle polygons")
    f = vtk_to_numpy(polys.GetConnectivityArray()).reshape(-1, 3).astype(np.int64)
    return v, f


def arrays_polydata(v: np.ndarray, f: np.ndarray):
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(v, dtype=float), deep=True))
    cells = vtk.vtkCellArray()
    offsets = np.arange(0, 3 * len(f) + 1, 3, dtype=np.int64)
    cells.SetData(
        numpy_to_vtk(offsets, deep=True, array_type=vtk.VTK_ID_TYPE),
        numpy_to_vtk(
            np.ascontiguousarray(f, dtype=np.int64).ravel(), deep=True, array_type=vtk.VTK_ID_TYPE
        ),
    )
    poly = vtk.vtkPolyData()
    poly.SetPoints(pts)
    poly.SetPolys(cells)
    return poly


# ---------------------------------------------------------------- metrics (cross-check)


def mesh_metrics(v: np.ndarray, f: np.ndarray, ref_points: np.ndarray | None = None) -> dict:
    """Python-side metrics: triangle count, enclosed volume (divergence theorem, ml), watertight
    (every undirected edge in exactly two triangles, once in each direction; counts of boundary
    and non-manifold edges are returned too), and when
    ``ref_points`` is given the mean / p95 / max unsigned distance (mm) from them to the surface
    (exact point-to-triangle, VTK's static cell locator)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    volume_ml = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0 / 1000.0)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    directed = np.unique(e, axis=0)
    und, counts = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    watertight = bool(len(directed) == len(e) and np.all(counts == 2))
    out = {
        "polys": int(len(f)),
        "points": int(len(v)),
        "volume_ml": volume_ml,
        "watertight": watertight,
        "boundary_edges": int((counts == 1).sum()),
        "nonmanifold_edges": int((counts > 2).sum()),
    }
    if ref_points is not None:
        d = point_to_surface(v, f, ref_points)
        out.update(
            mean_mm=float(d.mean()), p95_mm=float(np.percentile(d, 95)), max_mm=float(d.max())
        )
    return out


def point_to_surface(v: np.ndarray, f: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Unsigned distances from ``pts`` to the triangle mesh (exact closest point per triangle)."""
    poly = arrays_polydata(v, f)
    loc = vtk.vtkStaticCellLocator()
    loc.SetDataSet(poly)
    loc.BuildLocator()
    closest = [0.0, 0.0, 0.0]
    cid, sub, d2 = vtk.reference(0), vtk.reference(0), vtk.reference(0.0)
    out = np.empty(len(pts))
    for k, p in enumerate(pts):
        loc.FindClosestPoint(p, closest, cid, sub, d2)
        out[k] = d2.get()
    return np.sqrt(out)


def mask_volume_ml(label_path: str | Path, labels) -> float:
    arr, affine = read_label_numpy(label_path)
    return float(np.isin(arr, list(labels)).sum() * abs(np.linalg.det(affine[:3, :3])) / 1000.0)


# ---------------------------------------------------------------- self-check


def _self_check() -> None:
    """Oblique, anisotropic sphere phantom: Slicer's surface must sit on the analytic sphere in
    RAS (mean |r - R| ≤ 0.5 mm, max ≤ 1.5 mm at 0.9×1.1×1.6 mm voxels) and its volume within 2 %."""
    import tempfile

    import nibabel as nib  # noqa: PLC0415

    rot = np.linalg.qr(np.array([[1.0, 0.3, -0.2], [0.2, 1.0, 0.4], [-0.1, 0.3, 1.0]]))[0]
    rot *= np.sign(np.linalg.det(rot))
    spacing = np.array([0.9, 1.1, 1.6])
    affine = np.eye(4)
    affine[:3, :3] = rot * spacing
    affine[:3, 3] = [-40.0, 25.0, 110.0]
    dims = (70, 70, 50)
    centre = affine[:3, :3] @ ((np.array(dims) - 1) / 2 + [2.3, -1.7, 0.6]) + affine[:3, 3]
    radius = 20.0
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in dims], indexing="ij"), -1).reshape(-1, 3)
    ras = ijk @ affine[:3, :3].T + affine[:3, 3]
    mask = (np.linalg.norm(ras - centre, axis=1) <= radius).reshape(dims).astype(np.uint8) * 3
    if (
        mask.sum() < 1000
        or mask[0].any()
        or mask[-1].any()
        or mask[:, 0].any()
        or mask[:, -1].any()
    ):
        raise RuntimeError("self-check sphere touches the border")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sphere.nii.gz"
        img = nib.Nifti1Image(mask, affine)
        img.set_sform(affine, 1)
        img.set_qform(affine, 1)
        nib.save(img, path)
        geo = check_geometry(path)
        poly, t = slicer_closed_surface(path, 3, out=Path(tmp) / "s.ply")
        v, f = read_mesh(Path(tmp) / "s.ply")
    r = np.linalg.norm(v - centre, axis=1)
    m = mesh_metrics(v, f)
    exact = 4.0 / 3.0 * np.pi * radius**3 / 1000.0
    print(f"geometry Slicer vs nibabel: {geo:.2e} mm; convert {t['convert'] * 1e3:.1f} ms")
    print(
        f"|r-R| mean {np.abs(r - radius).mean():.3f} max {np.abs(r - radius).max():.3f} mm; "
        f"volume {m['volume_ml']:.3f} ml vs {exact:.3f}; watertight {m['watertight']}"
    )
    if np.abs(r - radius).mean() > 0.5 or np.abs(r - radius).max() > 1.5:
        raise RuntimeError("Slicer surface is not on the analytic sphere: wrong IJK→RAS?")
    if abs(m["volume_ml"] / exact - 1.0) > 0.02 or not m["watertight"]:
        raise RuntimeError("Slicer surface volume or topology off")
    print("self-check passed")


if __name__ == "__main__":
    _self_check()
