"""The vascular risk analysis in the scene (MRML only; the Logic fetches the data off the main
thread and calls these on it).

- Cut vessels: one markups fiducial node, a control point per vessel a resection cuts.
- Risk map: a segmentation "Resecta risk" with one segment per risk class present (functional
  remnant, resected, devascularised, congested, both), the at-risk classes opaque and the rest
  faint; and "Resecta territories", one segment per portal territory. Both are imported from a
  label-map volume node on the risk map's own (oblique) grid.
- Resectogram: the resection unrolled to its (u, v) square as a one-slice label-map volume of
  margin classes (the margin colours of the 3D surface), territory boundaries as a second label
  map (a slice view's label layer) and markers for the cut vessels and the closest point. It lies
  in its own axial plane far from the patient (`RESECTOGRAM_S`), 100 mm square, u to the right
  and v downwards in an axial slice view, so no model crosses it.

Nodes are found by name and refilled, never added twice; names carry no patient identifiers.
"""

from __future__ import annotations

import colorsys

import numpy as np
import vtk
from vtk.util import numpy_support

import slicer

from . import models
from .segmentation import numpy_to_matrix

CUT_VESSELS_NODE = "Resecta cut vessels"
RISK_NODE = "Resecta risk"
TERRITORIES_NODE = "Resecta territories"
RESECTOGRAM_NODE = "Resecta resectogram"
BOUNDARIES_NODE = "Resecta resectogram territories"
MARKERS_NODE = "Resecta resectogram markers"
RESECTOGRAM_COLORS = "ResectaResectogramClasses"
BOUNDARY_COLORS = "ResectaResectogramBoundaries"

#: `RiskClass` code → segment name, colour, 3D opacity: what is at risk stands out.
RISK_SEGMENTS = {
    1: ("Functional remnant", (0.20, 0.75, 0.30), 0.15),
    2: ("Resected", (0.55, 0.55, 0.55), 0.10),
    3: ("Devascularised", (0.90, 0.10, 0.10), 1.0),
    4: ("Congested", (0.60, 0.25, 0.80), 1.0),
    5: ("Both", (0.45, 0.00, 0.05), 1.0),
}
TERRITORY_OPACITY = 0.3
#: Resectogram class → colour: the margin classes of the 3D surface, outside opaque here.
RESECTOGRAM_CLASSES = tuple((name, (*rgba[:3], 1.0)) for name, rgba in models.MARGIN_CLASSES)
BOUNDARY_COLOR = (0.05, 0.15, 0.60)
RESECTOGRAM_SIDE_MM = 100.0
RESECTOGRAM_S = -1000.0


def _nodes(scene, cls: str):
    return [scene.GetNthNodeByClass(i, cls) for i in range(scene.GetNumberOfNodesByClass(cls))]


def _named(scene, cls: str, name: str, display: bool = True):
    """The node of class `cls` named `name`, made (with display nodes) when missing."""
    node = next((n for n in _nodes(scene, cls) if n.GetName() == name), None)
    if node is None:
        node = scene.AddNewNodeByClass(cls, name)
        if display:
            node.CreateDefaultDisplayNodes()
    return node


def vessel_label(vessel) -> str:
    return f"{vessel.system} {vessel.radius_mm:.1f} mm"


def _set_points(node, points, labels) -> None:
    was = node.StartModify()
    node.RemoveAllControlPoints()
    for p, label in zip(points, labels):
        node.AddControlPoint(vtk.vtkVector3d(*map(float, p)), label)
    node.SetLocked(True)
    node.EndModify(was)


# --- cut vessels -------------------------------------------------------------------------------


def update_cut_vessels(scene, risk):
    """The markups node of the cut vessels (`risk.cut_vessels`; none without risk), or None
    when there is nothing to show and no node yet."""
    vessels = risk.cut_vessels if risk is not None else ()
    node = next((n for n in _nodes(scene, "vtkMRMLMarkupsFiducialNode")
                 if n.GetName() == CUT_VESSELS_NODE), None)
    if node is None and not vessels:
        return None
    node = node or _named(scene, "vtkMRMLMarkupsFiducialNode", CUT_VESSELS_NODE)
    _set_points(node, [v.point for v in vessels], [vessel_label(v) for v in vessels])
    node.GetDisplayNode().SetSelectedColor(0.1, 0.1, 0.1)
    return node


# --- risk map ----------------------------------------------------------------------------------


def labelmap_volume(scene, name: str, labels: np.ndarray, ijk_to_ras: np.ndarray,
                    display: bool = True):
    """A label-map volume node from a (k, j, i) array (i fastest, as VTK's x) on `ijk_to_ras`."""
    node = _named(scene, "vtkMRMLLabelMapVolumeNode", name, display)
    k, j, i = labels.shape
    image = vtk.vtkImageData()
    image.SetDimensions(i, j, k)
    scalars = numpy_support.numpy_to_vtk(np.ascontiguousarray(labels).ravel(), deep=True)
    image.GetPointData().SetScalars(scalars)
    node.SetAndObserveImageData(image)
    node.SetIJKToRASMatrix(numpy_to_matrix(np.asarray(ijk_to_ras, float)))
    return node


def _fill_segmentation(scene, name: str, labels: np.ndarray, ijk_to_ras: np.ndarray,
                       segments: dict) -> object:
    """Segmentation `name` refilled from `labels`: one segment per value in `segments`
    (value → (segment name, colour, opacity)) that occurs."""
    node = _named(scene, "vtkMRMLSegmentationNode", name)
    segmentation = node.GetSegmentation()
    segmentation.RemoveAllSegments()
    present = [v for v in np.unique(labels) if int(v) in segments]
    if not present:
        return node
    volume = labelmap_volume(scene, f"{name} labels", labels, ijk_to_ras, display=False)
    try:
        node.SetReferenceImageGeometryParameterFromVolumeNode(volume)
        if not slicer.vtkSlicerSegmentationsModuleLogic.ImportLabelmapToSegmentationNode(
                volume, node):
            raise RuntimeError(f"could not import the label map into {name!r}")
    finally:
        scene.RemoveNode(volume)
    display = node.GetDisplayNode()
    for n in range(segmentation.GetNumberOfSegments()):
        segment_id = segmentation.GetNthSegmentID(n)
        segment = segmentation.GetSegment(segment_id)
        label, color, opacity = segments[int(segment.GetLabelValue())]
        segment.SetName(label)
        segment.SetColor(*color)
        display.SetSegmentOpacity3D(segment_id, opacity)
    node.CreateClosedSurfaceRepresentation()
    return node


def territory_segments(ids) -> dict:
    """Territory id → (name, distinct colour by the golden angle, opacity)."""
    return {int(t): (f"Territory {int(t)}",
                     colorsys.hsv_to_rgb((0.1 + 0.618034 * n) % 1.0, 0.65, 0.9), TERRITORY_OPACITY)
            for n, t in enumerate(sorted(int(t) for t in ids if t))}


def update_risk(scene, risk_map) -> tuple:
    """The segmentations "Resecta risk" and "Resecta territories" from a `RiskMap`."""
    risk = _fill_segmentation(scene, RISK_NODE, risk_map.classes, risk_map.ijk_to_ras,
                              RISK_SEGMENTS)
    territories = _fill_segmentation(
        scene, TERRITORIES_NODE, risk_map.territories, risk_map.ijk_to_ras,
        territory_segments(np.unique(risk_map.territories)))
    return risk, territories


# --- resectogram -------------------------------------------------------------------------------


def resectogram_ijk_to_ras(height: int, width: int) -> np.ndarray:
    """Pixel (r, c) = voxel (i = c, j = r, 0) → RAS: u along L (right in an axial view), v
    along P (down), the square centred on (0, 0, `RESECTOGRAM_S`)."""
    su, sv = RESECTOGRAM_SIDE_MM / width, RESECTOGRAM_SIDE_MM / height
    m = np.diag([-su, -sv, 1.0, 1.0])
    m[:3, 3] = (RESECTOGRAM_SIDE_MM / 2 - su / 2, RESECTOGRAM_SIDE_MM / 2 - sv / 2, RESECTOGRAM_S)
    return m


def uv_to_ras(uv) -> tuple[float, float, float]:
    u, v = uv
    half = RESECTOGRAM_SIDE_MM / 2
    return half - RESECTOGRAM_SIDE_MM * u, half - RESECTOGRAM_SIDE_MM * v, RESECTOGRAM_S


def _color_table(scene, name: str, entries) -> object:
    """A user colour table `name` (entry i = value i), range (0, n - 1) as Slicer's label
    tables (see `models.margin_color_table`)."""
    node = _named(scene, "vtkMRMLColorTableNode", name, display=False)
    node.SetTypeToUser()
    was = node.StartModify()
    node.SetNumberOfColors(len(entries))
    node.GetLookupTable().SetTableRange(0, len(entries) - 1)
    for i, (label, rgba) in enumerate(entries):
        node.SetColor(i, label, *rgba)
    node.EndModify(was)
    return node


def _label_display(volume, color_node) -> None:
    """`volume` drawn through `color_node` (its display node made when missing)."""
    display = volume.GetDisplayNode()
    if display is None:
        display = volume.GetScene().AddNewNodeByClass("vtkMRMLLabelMapVolumeDisplayNode")
        volume.SetAndObserveDisplayNodeID(display.GetID())
    display.SetAndObserveColorNodeID(color_node.GetID())


def territory_boundaries(territories: np.ndarray) -> np.ndarray:
    """1 on pixels of a portal territory next to (4-neighbourhood) another territory, else 0."""
    edge = np.zeros(territories.shape, np.uint8)
    for a, b in (((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
                 ((slice(None), slice(None, -1)), (slice(None), slice(1, None)))):
        differs = (territories[a] > 0) & (territories[b] > 0) & (territories[a] != territories[b])
        edge[a] |= differs
        edge[b] |= differs
    return edge


def update_resectogram(scene, gram) -> tuple:
    """The resectogram's class volume, boundary volume and markers from a `Resectogram`."""
    h, w = gram.classes.shape
    ijk_to_ras = resectogram_ijk_to_ras(h, w)
    classes = labelmap_volume(scene, RESECTOGRAM_NODE, gram.classes[None], ijk_to_ras, False)
    _label_display(classes, _color_table(scene, RESECTOGRAM_COLORS, RESECTOGRAM_CLASSES))
    boundaries = labelmap_volume(
        scene, BOUNDARIES_NODE, territory_boundaries(gram.territories)[None],
        ijk_to_ras, False)
    _label_display(boundaries, _color_table(
        scene, BOUNDARY_COLORS, (("none", (0.0, 0.0, 0.0, 0.0)),
                                 ("boundary", (*BOUNDARY_COLOR, 1.0)))))
    markers = _named(scene, "vtkMRMLMarkupsFiducialNode", MARKERS_NODE)
    points = [uv_to_ras(v.uv) for v in gram.cut_vessels]
    labels = [vessel_label(v) for v in gram.cut_vessels]
    if gram.worst_uv is not None:
        points.append(uv_to_ras(gram.worst_uv))
        labels.append("closest" if gram.min_margin_mm is None
                      else f"closest {gram.min_margin_mm:.1f} mm")
    _set_points(markers, points, labels)
    markers.GetDisplayNode().SetSelectedColor(0.0, 0.3, 1.0)
    return classes, boundaries, markers


def show_resectogram_in(scene, layout: str = "Red") -> None:
    """Puts the resectogram into slice view `layout`: classes as background, territory
    boundaries as label layer, the plane and field of view on the image."""
    composite = next((n for n in _nodes(scene, "vtkMRMLSliceCompositeNode")
                      if n.GetLayoutName() == layout), None)
    slice_node = next((n for n in _nodes(scene, "vtkMRMLSliceNode")
                       if n.GetLayoutName() == layout), None)
    classes = next((n for n in _nodes(scene, "vtkMRMLLabelMapVolumeNode")
                    if n.GetName() == RESECTOGRAM_NODE), None)
    if composite is None or slice_node is None or classes is None:
        raise ValueError(f"no slice view {layout!r} or no resectogram yet")
    boundaries = next(n for n in _nodes(scene, "vtkMRMLLabelMapVolumeNode")
                      if n.GetName() == BOUNDARIES_NODE)
    composite.SetBackgroundVolumeID(classes.GetID())
    composite.SetForegroundVolumeID(None)
    composite.SetLabelVolumeID(boundaries.GetID())
    composite.SetLabelOpacity(1.0)
    slice_node.SetOrientation("Axial")
    dims = slice_node.GetDimensions()
    fov = 1.1 * RESECTOGRAM_SIDE_MM
    slice_node.SetFieldOfView(fov * max(1.0, dims[0] / dims[1]), fov * max(1.0, dims[1] / dims[0]),
                              1.0)
    slice_node.JumpSliceByCentering(0.0, 0.0, RESECTOGRAM_S)
    slice_node.UpdateMatrices()
