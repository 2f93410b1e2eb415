"""A segmentation node → what the server's raw label-map upload needs.

The server takes a label array with its geometry (voxel (i, j, k) at `IJKToRAS · (i, j, k, 1)`,
`i` fastest in the data) and a role map by label value (`{"parenchyma": [1], "tumor": [2], ...}`).
A Slicer segmentation holds segments, possibly sharing labelmap layers, on an oriented image grid
(`vtkOrientedImageData`: any direction matrix, anisotropic spacing). We merge the segments the user
mapped to a role into one labelmap on the segmentation's own grid (no resampling: the oblique,
anisotropic geometry travels as is) and number them 1, 2, ... in the order of the role table, so
the role map refers to those numbers.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import vtk
from vtk.util import numpy_support

import slicer

#: The server's roles (proto `RoleMap`), in the order the panel offers them.
ROLES = ("parenchyma", "tumor", "portal", "hepatic", "vessel")
#: What the role table shows for a segment that is not uploaded.
IGNORE = "ignore"

_GUESSES = (
    ("tumor", re.compile(r"tumou?r|lesion|metasta|cancer|neoplasm|hcc", re.I)),
    ("portal", re.compile(r"portal", re.I)),
    ("hepatic", re.compile(r"hepatic.?vein|hepatic|\bhv\b|ivc|cava", re.I)),
    ("vessel", re.compile(r"vessel|vein|arter|vascul", re.I)),
    ("parenchyma", re.compile(r"liver|parenchyma|hepar", re.I)),
)


def guess_role(segment_name: str) -> str:
    """A first guess of a segment's role from its name (`ignore` when nothing matches)."""
    for role, pattern in _GUESSES:
        if pattern.search(segment_name):
            return role
    return IGNORE


@dataclasses.dataclass
class LabelMap:
    """A merged label map ready for upload.

    `labels` has shape (k, j, i) (numpy C order: `i` fastest, as the server reads raw voxels),
    `ijk_to_ras` is 4×4 (columns: the index axes in RAS scaled by the spacing, then the origin),
    `roles` maps role → label values, `segments` maps label value → segment id."""

    labels: np.ndarray
    ijk_to_ras: np.ndarray
    roles: dict[str, list[int]]
    segments: dict[int, str]

    @property
    def spacing(self) -> np.ndarray:
        return np.linalg.norm(self.ijk_to_ras[:3, :3], axis=0)

    @property
    def direction(self) -> np.ndarray:
        return self.ijk_to_ras[:3, :3] / self.spacing

    @property
    def origin(self) -> np.ndarray:
        return self.ijk_to_ras[:3, 3].copy()

    def voxel_volume_ml(self) -> float:
        return abs(float(np.linalg.det(self.ijk_to_ras[:3, :3]))) / 1000.0

    def role_volume_ml(self, role: str) -> float:
        values = self.roles.get(role, [])
        return float(np.isin(self.labels, values).sum()) * self.voxel_volume_ml()


def segments_of(segmentation_node) -> list[tuple[str, str]]:
    """(segment id, segment name) of every segment, in the segmentation's order."""
    seg = segmentation_node.GetSegmentation()
    return [(seg.GetNthSegmentID(i), seg.GetNthSegment(i).GetName())
            for i in range(seg.GetNumberOfSegments())]


def default_role_table(segmentation_node) -> dict[str, str]:
    """segment id → guessed role, for every segment."""
    return {sid: guess_role(name) for sid, name in segments_of(segmentation_node)}


def matrix_to_numpy(m: vtk.vtkMatrix4x4) -> np.ndarray:
    return np.array([[m.GetElement(r, c) for c in range(4)] for r in range(4)])


def numpy_to_matrix(a: np.ndarray) -> vtk.vtkMatrix4x4:
    m = vtk.vtkMatrix4x4()
    for r in range(4):
        for c in range(4):
            m.SetElement(r, c, float(a[r, c]))
    return m


def oriented_image_to_array(image) -> tuple[np.ndarray, np.ndarray]:
    """(array (k, j, i), IJK→RAS 4×4 of index (0, 0, 0) of the array) of a `vtkOrientedImageData`.

    The image's extent need not start at 0: the returned matrix is shifted to the extent's first
    voxel, so the array's index (0, 0, 0) maps correctly."""
    m = vtk.vtkMatrix4x4()
    image.GetImageToWorldMatrix(m)
    ijk_to_ras = matrix_to_numpy(m)
    ext = image.GetExtent()
    dims = (ext[1] - ext[0] + 1, ext[3] - ext[2] + 1, ext[5] - ext[4] + 1)
    if min(dims) <= 0:
        raise ValueError("the merged labelmap is empty: no segment holds any voxel")
    scalars = numpy_support.vtk_to_numpy(image.GetPointData().GetScalars())
    labels = scalars.reshape(dims[2], dims[1], dims[0]).copy()
    ijk_to_ras[:3, 3] = ijk_to_ras[:3, :3] @ np.array(ext[0::2], dtype=float) + ijk_to_ras[:3, 3]
    return labels, ijk_to_ras


def labelmap_from_segmentation(segmentation_node, role_table: dict[str, str],
                               pad: bool = True) -> LabelMap:
    """Merges the segments mapped to a role into one label map on the segmentation's grid.

    `role_table` maps segment id → role (one of `ROLES`, or `ignore`). Labels are numbered
    1, 2, ... in segment order. Raises ValueError when no segment is mapped, a role is unknown,
    no segment is mapped to `parenchyma`, or the mapped segments are empty."""
    seg = segmentation_node.GetSegmentation()
    ids = vtk.vtkStringArray()
    values = vtk.vtkIntArray()
    roles: dict[str, list[int]] = {}
    segments: dict[int, str] = {}
    for sid, _name in segments_of(segmentation_node):
        role = role_table.get(sid, IGNORE)
        if role == IGNORE:
            continue
        if role not in ROLES:
            raise ValueError(f"segment {sid!r}: unknown role {role!r} (one of {', '.join(ROLES)})")
        label = len(segments) + 1
        ids.InsertNextValue(sid)
        values.InsertNextValue(label)
        roles.setdefault(role, []).append(label)
        segments[label] = sid
    unknown = set(role_table) - {sid for sid, _ in segments_of(segmentation_node)}
    if unknown:
        raise ValueError(f"role table names segments not in the segmentation: {sorted(unknown)}")
    if not segments:
        raise ValueError("no segment is mapped to a role")
    if "parenchyma" not in roles:
        raise ValueError("no segment is mapped to the parenchyma role (the liver)")
    if not seg.ContainsRepresentation(
            slicer.vtkSegmentationConverter.GetSegmentationBinaryLabelmapRepresentationName()):
        if not segmentation_node.CreateBinaryLabelmapRepresentation():
            raise ValueError("the segmentation cannot be converted to a binary labelmap")
    merged = slicer.vtkOrientedImageData()
    mode = (slicer.vtkSegmentation.EXTENT_UNION_OF_EFFECTIVE_SEGMENTS_PADDED if pad
            else slicer.vtkSegmentation.EXTENT_UNION_OF_EFFECTIVE_SEGMENTS)
    # Without a reference geometry (segmentations made by scripts, or imported without a
    # reference volume) the merge would log an error looking for one: give it the first mapped
    # segment's own grid instead (Slicer's segmentations normally have one).
    geometry = None
    name = slicer.vtkSegmentationConverter.GetReferenceImageGeometryParameterName()
    if name not in (seg.SerializeAllConversionParameters() or ""):
        geometry = slicer.vtkOrientedImageData()
        segmentation_node.GetBinaryLabelmapRepresentation(ids.GetValue(0), geometry)
    if not segmentation_node.GenerateMergedLabelmapForAllSegments(merged, mode, geometry, ids,
                                                                  values):
        raise ValueError("the segments could not be merged into one labelmap")
    labels, ijk_to_ras = oriented_image_to_array(merged)
    # A segmentation under a linear transform: the upload is in world RAS.
    parent = segmentation_node.GetParentTransformNode()
    if parent is not None:
        if not parent.IsTransformToWorldLinear():
            raise ValueError("the segmentation is under a non-linear transform: harden it first")
        to_world = vtk.vtkMatrix4x4()
        parent.GetMatrixTransformToWorld(to_world)
        ijk_to_ras = matrix_to_numpy(to_world) @ ijk_to_ras
    for label in segments:
        if not np.any(labels == label):
            raise ValueError(f"segment {segments[label]!r} is empty")
    return LabelMap(labels=labels, ijk_to_ras=ijk_to_ras, roles=roles, segments=segments)


def segmentation_from_labelmap_array(scene, labels: np.ndarray, ijk_to_ras: np.ndarray,
                                     names: dict[int, str], node_name: str = "Segmentation"):
    """A segmentation node holding one segment per label value of `labels` (shape (k, j, i)),
    on the oblique grid `ijk_to_ras`; used by the self-test and the tests to make input."""
    image = slicer.vtkOrientedImageData()
    k, j, i = labels.shape
    image.SetDimensions(i, j, k)
    spacing = np.linalg.norm(ijk_to_ras[:3, :3], axis=0)
    directions = ijk_to_ras[:3, :3] / spacing
    image.SetSpacing(*spacing)
    image.SetOrigin(*ijk_to_ras[:3, 3])
    dm = vtk.vtkMatrix4x4()
    for r in range(3):
        for c in range(3):
            dm.SetElement(r, c, float(directions[r, c]))
    image.SetDirectionMatrix(dm)
    data = numpy_support.numpy_to_vtk(np.ascontiguousarray(labels, dtype=np.int16).ravel(),
                                      deep=True, array_type=vtk.VTK_SHORT)
    image.GetPointData().SetScalars(data)
    node = scene.AddNewNodeByClass("vtkMRMLSegmentationNode", node_name)
    node.CreateDefaultDisplayNodes()
    seg = node.GetSegmentation()
    for value, name in sorted(names.items()):
        segment = slicer.vtkSegment()
        segment.SetName(name)
        mask = slicer.vtkOrientedImageData()
        mask.DeepCopy(image)
        arr = numpy_support.vtk_to_numpy(mask.GetPointData().GetScalars())
        arr[:] = (arr == value).astype(np.int16)
        mask.GetPointData().GetScalars().Modified()
        segment.AddRepresentation(
            slicer.vtkSegmentationConverter.GetSegmentationBinaryLabelmapRepresentationName(), mask)
        seg.AddSegment(segment, f"{name}")
    return node
