"""Meshes from the server → model nodes, created once and then updated in place.

The client hands us numpy arrays (positions (N, 3) float32 in RAS mm, normals (N, 3), triangles
(T, 3) uint32, and for resections margins (N,) float32 mm and classes (N,) uint8). A model node is
made the first time a name appears; later frames of the same name rewrite the arrays of the same
`vtkPolyData` (same node, same polydata object, same point arrays when the vertex count holds), so
views, slice intersections and anything observing the node keep working while the surface is
dragged. Nodes carry the attribute `Resecta.Name` so they are found again after a scene reload.
"""

from __future__ import annotations

import numpy as np
import vtk
from vtk.util import numpy_support

import slicer

NAME_ATTRIBUTE = "Resecta.Name"
KIND_ATTRIBUTE = "Resecta.Kind"
SESSION_ATTRIBUTE = "Resecta.SessionId"

#: Point-data array names on resection models (as `resecta plan --out-dir` writes them in VTP).
MARGIN_ARRAY = "margin_mm"
CLASS_ARRAY = "margin_class"

#: Display colours and opacities per surface kind, close to Slicer-Liver's and the
#: GenericAnatomyColors table (liver brown, portal vein violet-pink, hepatic vein blue, tumour
#: green, unsplit vessels red).
PALETTE: dict[str, tuple[tuple[float, float, float], float]] = {
    "parenchyma": ((0.867, 0.510, 0.396), 0.35),
    "tumor": ((0.306, 0.706, 0.306), 1.0),
    "portal": ((0.788, 0.373, 0.733), 1.0),
    "hepatic": ((0.000, 0.592, 0.808), 1.0),
    "vessel": ((0.847, 0.396, 0.310), 1.0),
    "resection": ((0.75, 0.75, 0.75), 1.0),
}

#: Margin classes (docs/wire/mesh-delta.md) and their colours: outside the liver (does not count),
#: safe (grey), warning band (yellow), violation (red), as the thesis and Slicer-Liver draw them.
MARGIN_CLASSES = (
    ("outside", (0.86, 0.86, 0.86, 0.35)),
    ("safe", (0.62, 0.62, 0.62, 1.0)),
    ("warning", (1.00, 0.85, 0.00, 1.0)),
    ("violation", (0.90, 0.05, 0.05, 1.0)),
)
MARGIN_COLOR_TABLE_NAME = "ResectaMarginClasses"


def kind_name(kind) -> str:
    """'parenchyma', 'tumor', ... from a proto `SurfaceKind` name or number, or a plain string."""
    if isinstance(kind, str):
        k = kind.lower()
        return k.removeprefix("surface_kind_")
    names = {1: "parenchyma", 2: "tumor", 3: "portal", 4: "hepatic", 5: "vessel", 6: "resection"}
    return names.get(int(kind), "vessel")


def margin_color_table(scene):
    """The colour table of margin classes (one per scene, found by name): entry i is class i.

    Its lookup table's range is (0, classes - 1), as Slicer gives its label tables, so that a
    display node mapping scalars through the table's range (`UseColorNodeScalarRange`) sends
    class i to entry i. A new `vtkMRMLColorTableNode` keeps VTK's range (0, 255) instead, which
    sends every class to entry 0. Set on every call, so a table from an older scene is
    repaired."""
    node = next((n for n in _nodes_of_class(scene, "vtkMRMLColorTableNode")
                 if n.GetName() == MARGIN_COLOR_TABLE_NAME), None)
    if node is None:
        node = scene.AddNewNodeByClass("vtkMRMLColorTableNode", MARGIN_COLOR_TABLE_NAME)
        node.SetTypeToUser()
        node.SetAttribute("Category", "Resecta")
    was_modifying = node.StartModify()
    node.SetNumberOfColors(len(MARGIN_CLASSES))
    node.GetLookupTable().SetTableRange(0, len(MARGIN_CLASSES) - 1)
    for i, (name, rgba) in enumerate(MARGIN_CLASSES):
        node.SetColor(i, name, *rgba)
    node.EndModify(was_modifying)
    return node


def _nodes_of_class(scene, cls: str):
    n = scene.GetNumberOfNodesByClass(cls)
    return [scene.GetNthNodeByClass(i, cls) for i in range(n)]


def find_model(scene, name: str, session_id: str | None = None):
    """The model node this module made for surface `name` (of `session_id` when given)."""
    for node in _nodes_of_class(scene, "vtkMRMLModelNode"):
        if node.GetAttribute(NAME_ATTRIBUTE) != name:
            continue
        if session_id is not None and node.GetAttribute(SESSION_ATTRIBUTE) not in (None, session_id):
            continue
        return node
    return None


def model_nodes(scene, session_id: str | None = None) -> list:
    """Every model node this module made (for `session_id` when given)."""
    out = []
    for node in _nodes_of_class(scene, "vtkMRMLModelNode"):
        if node.GetAttribute(NAME_ATTRIBUTE) is None:
            continue
        if session_id is not None and node.GetAttribute(SESSION_ATTRIBUTE) not in (None, session_id):
            continue
        out.append(node)
    return out


def _triangles_to_cells(triangles: np.ndarray) -> vtk.vtkCellArray:
    tri = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    offsets = np.arange(0, 3 * len(tri) + 1, 3, dtype=np.int64)
    cells = vtk.vtkCellArray()
    cells.SetData(numpy_support.numpy_to_vtk(offsets, deep=True, array_type=vtk.VTK_ID_TYPE),
                  numpy_support.numpy_to_vtk(tri.ravel(), deep=True, array_type=vtk.VTK_ID_TYPE))
    return cells


def _cells_equal(cells: vtk.vtkCellArray, triangles: np.ndarray) -> bool:
    conn = cells.GetConnectivityArray()
    if conn is None or cells.GetNumberOfCells() != len(triangles):
        return False
    return np.array_equal(numpy_support.vtk_to_numpy(conn), np.asarray(triangles).ravel())


def _set_array(data: vtk.vtkDataSetAttributes, name: str, values: np.ndarray, vtk_type: int):
    """Writes `values` into the array `name`, in place when its shape holds."""
    values = np.asarray(values)
    comps = 1 if values.ndim == 1 else values.shape[1]
    arr = data.GetArray(name)
    if arr is not None and arr.GetNumberOfTuples() == len(values) \
            and arr.GetNumberOfComponents() == comps and arr.GetDataType() == vtk_type:
        view = numpy_support.vtk_to_numpy(arr)
        view[...] = values.reshape(view.shape)
        arr.Modified()
        return arr
    new = numpy_support.numpy_to_vtk(np.ascontiguousarray(values), deep=True, array_type=vtk_type)
    new.SetName(name)
    if arr is not None:
        data.RemoveArray(name)
    data.AddArray(new)
    return new


class ModelUpdater:
    """Creates and updates the model nodes of one session in a scene."""

    def __init__(self, scene, session_id: str = "", prefix: str = "Resecta"):
        self.scene = scene
        self.session_id = session_id
        self.prefix = prefix
        #: how many times a name's polydata was rebuilt (topology change) vs updated in place
        self.rebuilds: dict[str, int] = {}
        self.updates: dict[str, int] = {}

    def node_name(self, name: str) -> str:
        return f"{self.prefix} {name}"

    def upsert(self, name: str, kind, positions: np.ndarray, triangles: np.ndarray,
               normals: np.ndarray | None = None, margins: np.ndarray | None = None,
               classes: np.ndarray | None = None, color=None):
        """The model node of surface `name`, made or updated from the arrays."""
        kind = kind_name(kind)
        positions = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
        triangles = np.asarray(triangles).reshape(-1, 3)
        node = find_model(self.scene, name, self.session_id)
        created = node is None
        if created:
            node = self.scene.AddNewNodeByClass("vtkMRMLModelNode", self.node_name(name))
            node.SetAttribute(NAME_ATTRIBUTE, name)
            node.SetAttribute(KIND_ATTRIBUTE, kind)
            if self.session_id:
                node.SetAttribute(SESSION_ATTRIBUTE, self.session_id)
            node.CreateDefaultDisplayNodes()
        poly = node.GetPolyData()
        if poly is None or poly.GetNumberOfPoints() != len(positions) \
                or not _cells_equal(poly.GetPolys(), triangles):
            poly = vtk.vtkPolyData()
            points = vtk.vtkPoints()
            points.SetData(numpy_support.numpy_to_vtk(positions, deep=True,
                                                      array_type=vtk.VTK_FLOAT))
            poly.SetPoints(points)
            poly.SetPolys(_triangles_to_cells(triangles))
            self.rebuilds[name] = self.rebuilds.get(name, 0) + 1
            fresh = True
        else:
            fresh = False
            view = numpy_support.vtk_to_numpy(poly.GetPoints().GetData())
            view[...] = positions
            poly.GetPoints().GetData().Modified()
            poly.GetPoints().Modified()
            self.updates[name] = self.updates.get(name, 0) + 1
        pd = poly.GetPointData()
        if normals is not None:
            arr = _set_array(pd, "Normals", np.asarray(normals, dtype=np.float32).reshape(-1, 3),
                             vtk.VTK_FLOAT)
            pd.SetNormals(arr)
        if margins is not None:
            _set_array(pd, MARGIN_ARRAY, np.asarray(margins, dtype=np.float32), vtk.VTK_FLOAT)
        if classes is not None:
            _set_array(pd, CLASS_ARRAY, np.asarray(classes, dtype=np.uint8), vtk.VTK_UNSIGNED_CHAR)
        if fresh:
            node.SetAndObservePolyData(poly)
        else:
            poly.Modified()
            node.Modified()
        if created:
            self._style(node, kind, color)
        return node

    def _style(self, node, kind: str, color=None) -> None:
        display = node.GetDisplayNode()
        rgb, opacity = PALETTE.get(kind, PALETTE["vessel"])
        if color is not None and kind not in PALETTE:
            rgb, opacity = tuple(color[:3]), (color[3] if len(color) > 3 else 1.0)
        display.SetColor(*rgb)
        display.SetOpacity(opacity)
        display.SetVisibility(True)
        display.SetVisibility2D(True)  # slice intersections
        display.SetSliceIntersectionThickness(2)
        if kind == "resection":
            display.SetBackfaceCulling(False)
            table = margin_color_table(self.scene)
            display.SetAndObserveColorNodeID(table.GetID())
            display.SetActiveScalar(CLASS_ARRAY, vtk.vtkAssignAttribute.POINT_DATA)
            # class i → entry i in 3D and on slices: the table's own range (0, classes - 1),
            # as Slicer does for label tables; per-vertex alpha comes from the table.
            display.SetScalarRangeFlag(slicer.vtkMRMLDisplayNode.UseColorNodeScalarRange)
            display.UpdateScalarRange()
            display.SetScalarVisibility(True)
            display.SetSliceIntersectionThickness(3)

    def remove(self, name: str) -> bool:
        node = find_model(self.scene, name, self.session_id)
        if node is None:
            return False
        self.scene.RemoveNode(node)
        return True

    def set_opacity(self, kinds: tuple[str, ...], opacity: float) -> None:
        for node in model_nodes(self.scene, self.session_id):
            if node.GetAttribute(KIND_ATTRIBUTE) in kinds and node.GetDisplayNode():
                node.GetDisplayNode().SetOpacity(float(opacity))


def polydata_arrays(node) -> dict[str, np.ndarray]:
    """Copies of a model node's positions, triangles and point arrays (for tests and export)."""
    poly = node.GetPolyData()
    out = {"positions": numpy_support.vtk_to_numpy(poly.GetPoints().GetData()).copy()}
    conn = poly.GetPolys().GetConnectivityArray()
    out["triangles"] = numpy_support.vtk_to_numpy(conn).reshape(-1, 3).copy()
    pd = poly.GetPointData()
    for i in range(pd.GetNumberOfArrays()):
        arr = pd.GetArray(i)
        out[arr.GetName()] = numpy_support.vtk_to_numpy(arr).copy()
    return out
