"""Voxel grids: an IJK→RAS matrix split into the origin / spacing / direction of the wire, and a
label array turned into the bytes of a raw upload.

**Array convention.** A label map is a 3-D integer numpy array indexed ``[k, j, i]`` (shape
``(K, J, I)``), the layout of Slicer's ``slicer.util.arrayFromVolume`` and of
``vtkOrientedImageData`` scalars: flattened in C order, ``i`` varies fastest, as the raw upload
requires. Pass ``axes="ijk"`` for an array indexed ``[i, j, k]`` (nibabel's ``img.dataobj``).
Voxel (i, j, k) sits at ``ijk_to_ras @ (i, j, k, 1)`` in RAS millimetres (Slicer's
``GetIJKToRASMatrix``; for a NIfTI file, nibabel's ``img.affine``).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from ._gen import label_map_pb2

Axes = Literal["kji", "ijk"]

_DATA_TYPES = {
    "u1": label_map_pb2.DATA_TYPE_UINT8,
    "i1": label_map_pb2.DATA_TYPE_INT8,
    "u2": label_map_pb2.DATA_TYPE_UINT16,
    "i2": label_map_pb2.DATA_TYPE_INT16,
    "u4": label_map_pb2.DATA_TYPE_UINT32,
    "i4": label_map_pb2.DATA_TYPE_INT32,
}
MAX_LABEL = 65535


def compose(origin: Any, spacing: Any, direction: Any) -> npt.NDArray[np.float64]:
    """The 4×4 IJK→RAS matrix ``[direction · diag(spacing) | origin]`` (inverse of `decompose`)."""
    m = np.eye(4)
    m[:3, :3] = np.asarray(direction, dtype=np.float64).reshape(3, 3) * np.asarray(spacing, dtype=np.float64)
    m[:3, 3] = origin
    return m


def as_matrix(ijk_to_ras: Any) -> npt.NDArray[np.float64]:
    """A 4×4 float64 matrix from an array-like (4×4, or 3×4 without the last row) or a VTK
    ``vtkMatrix4x4`` (anything with ``GetElement(r, c)``)."""
    if hasattr(ijk_to_ras, "GetElement"):
        ijk_to_ras = [[ijk_to_ras.GetElement(r, c) for c in range(4)] for r in range(4)]
    m = np.asarray(ijk_to_ras, dtype=np.float64)
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4):
        raise ValueError(f"the IJK→RAS matrix must be 4×4, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError("the IJK→RAS matrix has non-finite entries")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"the IJK→RAS matrix is not affine: last row {m[3].tolist()}")
    return m


def decompose(
    ijk_to_ras: Any,
) -> tuple[tuple[float, float, float], tuple[float, float, float], npt.NDArray[np.float64]]:
    """(origin, spacing, direction) of an IJK→RAS matrix: ``M[:3, :3] = direction ·
    diag(spacing)``. Spacing is the length of each column (so always > 0); a flipped axis
    (Slicer's negative spacing, or a left-handed grid) stays in the sign of its direction column.
    Oblique and sheared-free anisotropic grids come back exactly; a singular matrix is refused."""
    m = as_matrix(ijk_to_ras)
    a = m[:3, :3]
    spacing = np.linalg.norm(a, axis=0)
    if np.any(spacing <= 0) or abs(np.linalg.det(a / np.where(spacing > 0, spacing, 1))) < 1e-9:
        raise ValueError("the IJK→RAS matrix is singular (an index axis has no direction)")
    direction = a / spacing
    ox, oy, oz = m[:3, 3].tolist()
    sx, sy, sz = spacing.tolist()
    return (ox, oy, oz), (sx, sy, sz), direction


def label_bytes(
    labels: npt.ArrayLike, axes: Axes = "kji"
) -> tuple[tuple[int, int, int], label_map_pb2.DataType, bytes]:
    """((I, J, K), the wire's DataType, the voxels as little-endian bytes with i fastest) of a
    3-D integer label array (see the module's array convention). Integer types the wire has are
    sent as they are; bool, 64-bit and float arrays holding whole numbers in 0..65535 are sent
    as uint8 or uint16. Raises ValueError for anything else."""
    a = np.asarray(labels)
    if a.ndim != 3:
        raise ValueError(f"a label map is a 3-D array, got {a.ndim} dimension(s)")
    if axes == "ijk":
        a = a.transpose(2, 1, 0)
    elif axes != "kji":
        raise ValueError(f"axes must be 'kji' or 'ijk', got {axes!r}")
    if a.dtype.kind == "b":
        a = a.astype(np.uint8)
    code = f"{a.dtype.kind}{a.dtype.itemsize}"
    if code not in _DATA_TYPES:
        if a.dtype.kind not in "iuf":
            raise ValueError(f"label values must be integers, got dtype {a.dtype}")
        if a.size and (
            not np.all(np.isfinite(a)) or np.any(a != np.round(a)) or a.min() < 0 or a.max() > MAX_LABEL
        ):
            raise ValueError(f"label values must be whole numbers in 0..{MAX_LABEL}")
        a = a.astype(np.uint8 if a.size == 0 or a.max() < 256 else np.uint16)
        code = f"u{a.dtype.itemsize}"
    data = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).tobytes()
    k, j, i = a.shape
    return (i, j, k), _DATA_TYPES[code], data
